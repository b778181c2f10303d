"""Plugin failures are contained: a broken plugin does not stop the others, a plugin's defect
during a run is reported as the plugin's, at the joint it fails for, and two plugins claiming
one type name is an error naming both."""

import os
import subprocess
import sys
import textwrap

import pytest

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


# -- the plugin contract's version (issue 31) --------------------------------------------------

#: A plugin of contract 1, as third parties wrote them: phi, jacobian and gamma on arrays.
OLD_CONTRACT = '''
    import numpy as np
    from mechdsl.plugins import Arg, ConstraintType, hookimpl

    class CircleSlot(ConstraintType):
        name = "circle_slot"
        kind = "joint"
        signature = (Arg("centre", "point"), Arg("pin", "point"), Arg("radius", "scalar"))
        n_eq = 1

        def phi(self, q, p):
            return np.zeros(q[0].shape[:-1] + (1,))

        def jacobian(self, q, p):
            return np.zeros(q[0].shape[:-1] + (1, 6))

        def gamma(self, q, qd, p):
            return np.zeros(q[0].shape[:-1] + (1,))

    @hookimpl
    def mechdsl_constraint_types():
        return [CircleSlot()]
'''
#: The same plugin as it fails on import: contract 1's helpers are gone from mechdsl.
OLD_IMPORT = "\n    from mechdsl.plugins.geometry import block" + OLD_CONTRACT

SLOT_MODEL = """\
body a { point P = (1, 0) }
joint pa: revolute(ground.origin, a.origin)
joint slot: circle_slot(ground.origin, a.P, radius = 1)
simulate t = 0 .. 1 step 0.1
"""


def _located_contract_error(tmp_path, r):
    assert r.returncode == 1, r.stderr
    assert "Traceback" not in r.stderr
    first = r.stderr.splitlines()[0]
    assert first.startswith(f"{tmp_path / 'slot.mech'}:3:13: error: the joint type "
                            "'circle_slot' comes from the plugin mechdsl_circle_slot "
                            "(mechdsl-circle-slot 0.1), which cannot be loaded: "), first
    assert "mechdsl implements plugin contract 2: the contract changed (migration notes: " \
           "docs/plugins.md#contract-versions-and-migration)" in first
    return first


def test_an_old_contract_plugin_gets_the_located_contract_error(tmp_path):
    fake_distribution(tmp_path, "mechdsl-circle-slot", "mechdsl_circle_slot", OLD_CONTRACT,
                      ["circle_slot"])
    (tmp_path / "slot.mech").write_text(SLOT_MODEL)
    r = mechdsl(tmp_path, "run", tmp_path / "slot.mech")
    first = _located_contract_error(tmp_path, r)
    assert "type 'circle_slot' writes phi, jacobian, gamma() and no equations(): it was " \
           "written for plugin contract 1" in first
    listing = mechdsl(tmp_path, "plugins").stdout
    assert listing.startswith("plugin contract 2 (a plugin declares MECHDSL_CONTRACT = 2)")
    assert "mechdsl_circle_slot (mechdsl-circle-slot 0.1): type 'circle_slot' writes" in listing


def test_a_plugin_that_imports_what_the_old_contract_had_gets_the_contract_error(tmp_path):
    fake_distribution(tmp_path, "mechdsl-circle-slot", "mechdsl_circle_slot", OLD_IMPORT,
                      ["circle_slot"])
    (tmp_path / "slot.mech").write_text(SLOT_MODEL)
    first = _located_contract_error(tmp_path, mechdsl(tmp_path, "run", tmp_path / "slot.mech"))
    assert "it imports what mechdsl no longer has (cannot import name 'block' from " \
           "'mechdsl.plugins.geometry'" in first


def test_a_plugin_declaring_another_contract_is_not_loaded_and_the_current_one_is(tmp_path):
    current = (EXAMPLES / "plugins" / "curve_slot" / "mechdsl_curve_slot"
               / "__init__.py").read_text()
    assert "MECHDSL_CONTRACT = 2" in current
    fake_distribution(tmp_path, "mechdsl-circle-slot", "mechdsl_circle_slot",
                      current.replace("MECHDSL_CONTRACT = 2", "MECHDSL_CONTRACT = 3")
                      .replace('name = "curve_slot"', 'name = "circle_slot"'), ["circle_slot"])
    (tmp_path / "slot.mech").write_text(SLOT_MODEL)
    first = _located_contract_error(tmp_path, mechdsl(tmp_path, "run", tmp_path / "slot.mech"))
    assert "it was written for plugin contract 3 (MECHDSL_CONTRACT = 3)" in first
    # declaring the current version: it loads and runs as today (the example's own model)
    site = tmp_path / "site"
    site.mkdir()
    fake_distribution(site, "mechdsl-curve-slot", "mechdsl_curve_slot", current,
                      ["curve_slot"])
    model = EXAMPLES / "plugins" / "curve_slot" / "curve_slot.mech"
    r = mechdsl(site, "run", model, "-o", tmp_path / "o.csv", "-q")
    assert r.returncode == 0, r.stderr


@pytest.mark.parametrize("source, reason", [
    (OLD_IMPORT, "it imports what mechdsl no longer has"),
    (OLD_CONTRACT.replace("    import numpy as np", "    import numpy as np\n    MECHDSL_CONTRACT = 1"),
     "it was written for plugin contract 1 (MECHDSL_CONTRACT = 1)"),
])
def test_a_plugin_loaded_by_name_of_another_contract_gets_the_contract_error(tmp_path, source,
                                                                           reason):
    # --plugin MODULE, a model's plugin line (located) and plugins=[...]: no entry point
    # says which types it gives, and the load itself fails with the contract's message
    (tmp_path / "old_slot.py").write_text(textwrap.dedent(source))
    (tmp_path / "slot.mech").write_text(SLOT_MODEL)
    (tmp_path / "line.mech").write_text('plugin "old_slot"\n' + SLOT_MODEL)
    contract = ("mechdsl implements plugin contract 2: the contract changed (migration "
                "notes: docs/plugins.md#contract-versions-and-migration)")
    for args, where in (((tmp_path / "slot.mech", "--plugin", "old_slot"), "slot.mech: "),
                        ((tmp_path / "line.mech", "--allow-plugin", "old_slot"),
                         "line.mech:1:8: ")):
        r = mechdsl(tmp_path, "run", *args)
        assert r.returncode == 1 and "Traceback" not in r.stderr, r.stderr
        first = r.stderr.splitlines()[0]
        assert first.startswith(f"{tmp_path / where.split(':')[0].rstrip(': ')}") and \
            f"{where}error: cannot load the plugin 'old_slot': {reason}" in first, first
        assert contract in first, first
    r = subprocess.run([sys.executable, "-c", "import mechdsl, sys\ntry:\n    mechdsl.loads("
                        f"open(sys.argv[1]).read(), plugins=['old_slot'])\nexcept "
                        "mechdsl.MechError as e:\n    print(e)", tmp_path / "slot.mech"],
                       capture_output=True, text=True, cwd=ROOT, timeout=120,
                       env={**os.environ, "PYTHONPATH": str(tmp_path)})
    assert f"cannot load the plugin 'old_slot': {reason}" in r.stdout and contract in r.stdout, \
        r.stdout + r.stderr


def test_a_broken_module_behind_several_entry_points_is_listed_once(tmp_path):
    fake_distribution(tmp_path, "mechdsl-broken", "mechdsl_broken",
                      "raise ImportError('needs libgears.so')\n", ["gear_a", "gear_b"])
    r = mechdsl(tmp_path, "plugins")
    assert r.returncode == 0
    assert r.stdout.count("mechdsl_broken (mechdsl-broken 0.1): ImportError") == 1, r.stdout
    # with the old contract's import, either type's model line gets the contract error
    fake = tmp_path / "old"
    fake.mkdir()
    fake_distribution(fake, "mechdsl-circle-slot", "mechdsl_circle_slot", OLD_IMPORT,
                      ["other_slot", "circle_slot"])
    (tmp_path / "slot.mech").write_text(SLOT_MODEL)
    r = mechdsl(fake, "run", tmp_path / "slot.mech")
    assert "'circle_slot' comes from the plugin mechdsl_circle_slot" in r.stderr, r.stderr


def test_every_plugin_of_the_library_declares_the_current_contract():
    import importlib

    from mechdsl.plugins import CONTRACT_VERSION
    from mechdsl.plugins.discover import entry_points

    modules = {ep.value.split(":")[0].strip() for ep in entry_points("mechdsl")}
    assert {"mechdsl_revolute", "mechdsl_prismatic", "mechdsl_forces"} <= modules
    for name in modules:
        assert importlib.import_module(name).MECHDSL_CONTRACT == CONTRACT_VERSION, name
