"""Plugin failures are contained: a broken plugin does not stop the others, a plugin's defect
during a run is reported as the plugin's, at the joint it fails for, and two plugins claiming
one type name is an error naming both."""

import os
import subprocess
import sys
import textwrap

from conftest import EXAMPLES, ROOT


def fake_distribution(site, name, module, source, entry_points):
    """A minimal installed distribution: its module and a dist-info with entry points."""
    (site / f"{module}.py").write_text(textwrap.dedent(source))
    info = site / f"{name.replace('-', '_')}-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {name}\nVersion: 0.1\n")
    lines = "".join(f"{ep} = {module}\n" for ep in entry_points)
    (info / "entry_points.txt").write_text("[mechdsl]\n" + lines)


def mechdsl(site, *args):
    env = {**os.environ, "PYTHONPATH": str(site)}
    return subprocess.run([sys.executable, "-m", "mechdsl", *map(str, args)], capture_output=True,
                          text=True, cwd=ROOT, env=env, timeout=120)


def test_a_plugin_that_fails_to_import_is_listed_as_broken(tmp_path):
    fake_distribution(tmp_path, "mechdsl-broken", "mechdsl_broken",
                      "raise ImportError('needs libgears.so')\n", ["gearbox"])
    r = mechdsl(tmp_path, "plugins")
    assert r.returncode == 0
    assert "broken plugins:" in r.stdout
    assert "mechdsl_broken (mechdsl-broken 0.1): ImportError: needs libgears.so" in r.stdout
    assert "revolute(p1: point, p2: point)" in r.stdout  # the others still work
    r = mechdsl(tmp_path, "run", EXAMPLES / "slider_crank.mech", "-q")
    assert r.returncode == 0, r.stderr


WRONG_SHAPE = '''
    from mechdsl.plugins import Arg, ConstraintType, hookimpl

    class Lazy(ConstraintType):
        """x of a point equals c; breaks (two values for one equation) for a point whose
        body coordinate is exactly 2: a defect that shows for one constraint only."""
        name = "lazy_x"
        kind = "drive"
        signature = (Arg("point", "point"),)
        n_eq = 1
        invariant = False

        def equations(self, bodies, args):
            if getattr(args.point.x, "value", None) == 2.0:
                return bodies[0].point(args.point).x, 0.0
            return (bodies[0].point(args.point).x,)

    @hookimpl
    def mechdsl_constraint_types():
        return [Lazy()]
'''


def test_a_plugin_defect_names_the_plugin_the_constraint_and_the_line(tmp_path):
    fake_distribution(tmp_path, "mechdsl-lazy", "mechdsl_lazy", WRONG_SHAPE, ["lazy_x"])
    f = tmp_path / "lazy.mech"
    f.write_text(textwrap.dedent("""\
        body a { point P = (1, 0) }
        body b { point P = (2, 0) }
        joint pa: revolute(ground.origin, a.origin)
        joint pb: revolute(ground.origin, b.origin)
        drive first: lazy_x(a.P) = cos(t)
        drive second: lazy_x(b.P) = 2*cos(t)
        simulate t = 0 .. 1 step 0.1
        """))
    r = mechdsl(tmp_path, "run", f)
    assert r.returncode == 1
    assert "Traceback" not in r.stderr
    first = r.stderr.splitlines()[0]
    assert first == (f"{f}:6:1: error: the drive type 'lazy_x' failed in equations() for "
                     "drive 'second': equations() gave 2 values, expected 1")
    assert "the plugin mechdsl_lazy" in r.stderr and "defect of the plugin" in r.stderr


def test_two_plugins_claiming_one_name_is_an_error_naming_both(tmp_path):
    fake_distribution(tmp_path, "mechdsl-other-revolute", "mechdsl_other_revolute", '''
        from mechdsl_revolute import Revolute
        from mechdsl.plugins import hookimpl

        class Copy(Revolute):
            pass

        @hookimpl
        def mechdsl_constraint_types():
            return [Copy()]
        ''', ["revolute"])
    r = mechdsl(tmp_path, "run", EXAMPLES / "slider_crank.mech")
    assert r.returncode == 1
    assert "joint type 'revolute' is provided twice" in r.stderr
    assert "mechdsl-revolute 0.1.0" in r.stderr and "mechdsl-other-revolute 0.1" in r.stderr
    r = mechdsl(tmp_path, "plugins")
    assert "provided twice" in r.stdout
