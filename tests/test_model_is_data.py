"""A model file runs no code by itself; a plugin's failure is located and keeps what was
solved; nothing non-finite is written silently; a wrong Jacobian is named; the memory limit
bounds the whole process. Each test asserts the behaviour against a closed form, a message or
the file system, never against earlier output of the program."""

import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

import mechdsl
from closed_forms import slider_crank
from conftest import EXAMPLES, ROOT
from mechdsl.cli import main
from mechdsl.errors import MechError
from mechdsl.solve import SolverOptions
from mechdsl.plugins import build_registry, hookimpl

SLIDER = (EXAMPLES / "slider_crank.mech").read_text()
OMEGA = 4 * np.pi


def cli(*args, env=None, cwd=ROOT):
    return subprocess.run([sys.executable, "-m", "mechdsl", *map(str, args)],
                          capture_output=True, text=True, cwd=cwd, timeout=120,
                          env={**os.environ, **(env or {})})


def plugin_module(folder, name, body=""):
    """A module that, when imported, leaves a marker file: proof that it ran."""
    marker = folder / f"{name}.ran"
    (folder / f"{name}.py").write_text(
        f"open({str(marker)!r}, 'w').close()\n" + textwrap.dedent(body))
    return marker


# -- code is opt-in ------------------------------------------------------------------------------

def model_naming(folder, module):
    f = folder / "m.mech"
    f.write_text(f'plugin "{module}"\n' + SLIDER)
    return f


def test_a_plugin_line_imports_nothing_unless_allowed(tmp_path):
    marker = plugin_module(tmp_path, "sneaky")
    f = model_naming(tmp_path, "sneaky")
    env = {"PYTHONPATH": str(tmp_path)}
    for command in ("run", "check"):
        r = cli(command, f, env=env, cwd=tmp_path)
        assert r.returncode == 1, r.stderr
        assert f"{f}:1:8: error: the model asks to import the Python module 'sneaky'" in r.stderr
        assert "--allow-plugin sneaky" in r.stderr and "MECHDSL_ALLOW_PLUGINS=sneaky" in r.stderr
        assert not marker.exists()
    with pytest.raises(MechError, match="asks to import the Python module 'sneaky'") as err:
        mechdsl.load(f).compile()
    assert err.value.span.line == 1
    assert not marker.exists()


@pytest.mark.parametrize("how", ["option", "environment"])
def test_an_allowed_plugin_module_is_imported(tmp_path, how):
    marker = plugin_module(tmp_path, "trusted")
    f = model_naming(tmp_path, "trusted")
    env = {"PYTHONPATH": str(tmp_path)}
    extra = ["--allow-plugin", "trusted"] if how == "option" else []
    if how == "environment":
        env["MECHDSL_ALLOW_PLUGINS"] = "other, trusted"
    r = cli("run", f, "-q", *extra, env=env)
    assert r.returncode == 0, r.stderr
    assert marker.exists()


def test_a_stdlib_module_named_by_a_model_is_not_imported(tmp_path):
    f = model_naming(tmp_path, "antigravity")
    r = cli("check", f, env={"BROWSER": "false"})
    assert r.returncode == 1
    assert "asks to import the Python module 'antigravity'" in r.stderr


def test_a_plugin_calling_sys_exit_on_import_is_a_located_error(tmp_path):
    plugin_module(tmp_path, "quitter", "import sys\nsys.exit(0)\n")
    f = model_naming(tmp_path, "quitter")
    r = cli("run", f, "--allow-plugin", "quitter", "-o", tmp_path / "out.csv",
            env={"PYTHONPATH": str(tmp_path)})
    assert r.returncode == 1
    assert (f"{f}:1:8: error: cannot load the plugin 'quitter': it called sys.exit(0) while "
            "loading") in r.stderr
    assert not (tmp_path / "out.csv").exists()


# -- plugin types that misbehave, registered directly ------------------------------------------

def registry_with(registry, *types):
    class Plugin:
        @hookimpl
        def mechdsl_constraint_types(self):
            return list(types)

    return registry.merged(build_registry([Plugin()], entry_points=False))


def revolute():
    import mechdsl_revolute

    return mechdsl_revolute.Revolute


def joint_b_as(type_name):
    return SLIDER.replace("joint B: revolute", f"joint B: {type_name}")


def test_a_validate_that_raises_is_located_and_names_the_plugin(registry):
    class Picky(revolute()):
        name = "picky"

        def validate(self, p):
            raise TypeError("unsupported operand")

    mech = mechdsl.loads(joint_b_as("picky"), "s.mech", registry=registry_with(registry, Picky()))
    with pytest.raises(MechError) as err:
        mech.simulate()
    assert err.value.span.line == 24
    assert ("the joint type 'picky' failed in validate() for B: TypeError: unsupported operand"
            in err.value.message)
    assert "plugin" in err.value.notes[0]


THRESHOLD = np.pi / 4 + OMEGA * 0.0565  # the crank's angle between instants 56 and 57


def fragile(raises: bool):
    """A revolute joint whose equations raise when traced (``raises``), or are not defined
    once the first body's angle passes THRESHOLD (the square root of a negative number)."""
    from mechdsl.plugins import Arg, ConstraintType

    class Fragile(ConstraintType):
        name = "fragile"
        signature = (Arg("p1", "point"), Arg("p2", "point"))
        n_eq = 2

        def equations(self, bodies, args):
            if raises:
                raise RuntimeError("out of range")
            d = bodies[0].point(args.p1) - bodies[1].point(args.p2)
            w = np.sqrt(THRESHOLD - bodies[0].phi)
            return d.x * w / w, d.y

    return Fragile()


def test_a_plugin_that_raises_is_located_before_anything_runs(registry):
    reg = registry_with(registry, fragile(raises=True))
    mech = mechdsl.loads(joint_b_as("fragile"), "s.mech", registry=reg)
    with pytest.raises(MechError) as err:
        mech.simulate()
    assert err.value.span.line == 24
    assert ("the joint type 'fragile' failed in equations() for joint 'B': RuntimeError: out "
            "of range" in err.value.message)
    assert "defect of the plugin" in err.value.notes[0]


def test_equations_undefined_mid_run_keep_every_instant_before_them(registry):
    reg = registry_with(registry, fragile(raises=False))
    res = mechdsl.loads(joint_b_as("fragile"), "s.mech", registry=reg).simulate()
    assert res.status == "failed" and res.n_solved[0] == 57
    assert res.messages[0].startswith("the equations of joint B (fragile, line 24) are not "
                                      "defined (not a number) near t = 0.0565")
    t = res["t"]
    x, v, a = slider_crank(2.0, 3.5, np.pi / 4 + OMEGA * t, OMEGA, 0.0)
    np.testing.assert_allclose(res["slider.x"], x, atol=1e-13)
    np.testing.assert_allclose(res["slider.ax"], a, atol=1e-10 * np.abs(a).max())


def test_a_gamma_returning_nan_stops_the_run_and_names_the_joint(registry):
    class NanGamma(revolute()):
        name = "nan_gamma"

        def gamma_terms(self, bodies, rates, args):
            return np.nan, np.nan

    reg = registry_with(registry, NanGamma())
    res = mechdsl.loads(joint_b_as("nan_gamma"), "s.mech", registry=reg).simulate()
    assert res.status == "failed" and res.n_solved[0] == 0
    message = res.messages[0]
    assert message.startswith("slider.ax is nan at t = 0 (instant 1 of 1001)")
    assert "acceleration equation (gamma) in the equations of joint B (nan_gamma, line 24)" in message


def test_a_drive_with_an_unbounded_derivative_is_not_written_silently(loads, tmp_path):
    text = SLIDER.replace("pi/4 + omega*t", "pi/4 + 1e-3*sqrt(t)")
    res = loads(text).simulate()
    assert res.status == "failed" and res.n_solved[0] == 0
    assert res.messages[0].startswith("slider.vx is -inf at t = 0 (instant 1 of 1001)")
    assert "drive crank_angle (angle, line 28)" in res.messages[0]
    f = tmp_path / "sqrt.mech"
    f.write_text(text)
    out = tmp_path / "out.csv"
    assert main(["run", str(f), "-q", "-o", str(out)]) == 2
    assert main(["run", str(f), "-q", "-o", str(out), "--keep-nonfinite"]) == 0
    rows = out.read_text().splitlines()
    assert rows[1].startswith("# units: ")
    assert len(rows) == 1003 and rows[2].split(",")[2] == "-inf"
    # from the second instant on, the closed form: theta = pi/4 + 1e-3 sqrt(t)
    data = np.loadtxt(rows[3:], delimiter=",")
    t = data[:, 0]
    x, v, _ = slider_crank(2.0, 3.5, np.pi / 4 + 1e-3 * np.sqrt(t), 0.5e-3 / np.sqrt(t), 0.0)
    np.testing.assert_allclose(data[:, 1], x, atol=1e-13)
    np.testing.assert_allclose(data[:, 2], v, rtol=1e-9)


# -- a Jacobian that is not the derivative of Phi ----------------------------------------------

def flipped(base, beyond=-np.inf):
    """The revolute joint with the sign of d Phi / d phi_j wrong once body i's angle passes
    ``beyond``: Newton cannot converge with it."""

    class Flipped(base):
        name = "flipped"

        def jacobian_terms(self, bodies, args):
            i, j = bodies
            # -1 once phi_i > beyond, +1 before: a sign, not a branch
            flip = -1.0 if beyond == -np.inf else np.sign(beyond - i.phi)
            bi, bj = i.rotate(args.p1).perp(), j.rotate(args.p2).perp()  # B s' = perp(A s')
            return ([[1, 0, bi.x], [0, 1, bi.y]],
                    [[-1, 0, -bj.x * flip], [0, -1, -bj.y * flip]])

    return Flipped()


def test_a_wrong_jacobian_is_named_when_the_assembly_fails(registry):
    reg = registry_with(registry, flipped(revolute()))
    res = mechdsl.loads(joint_b_as("flipped"), "s.mech", registry=reg).simulate()
    assert res.status == "failed"
    assert ("the Jacobian of joint B (flipped, line 24) is not the derivative of its equations"
            in res.messages[0])
    assert "defect of the plugin" in res.messages[0]


def test_a_wrong_jacobian_is_named_when_newton_fails_mid_run(registry):
    reg = registry_with(registry, flipped(revolute(), beyond=np.pi / 4 + OMEGA * 0.1))
    res = mechdsl.loads(joint_b_as("flipped"), "s.mech", registry=reg).simulate()
    # (Newton may still converge for a while after the defect appears: its start is good)
    assert res.status == "failed" and res.n_solved[0] >= 100
    assert "Newton-Raphson does not converge" in res.messages[0]
    assert "the Jacobian of joint B (flipped, line 24) is not the derivative" in res.messages[0]


def test_a_correct_jacobian_is_not_called_wrong(load_example):
    from mechdsl.solve.diagnose import jacobian_defects

    kernels = load_example("fourbar.mech").compile()
    res = load_example("fourbar.mech").simulate(poses=True)
    q = res.poses[0, 37].ravel()
    assert jacobian_defects(kernels, q, float(res["t"][37]), 0) is None


# -- memory ---------------------------------------------------------------------------------------

# the peak resident size of this program alone: VmHWM (ru_maxrss would count the parent's
# memory at the fork that started the child)
MEASURE = """
import sys
from mechdsl.cli import main
code = main(sys.argv[1:])
with open("/proc/self/status") as f:
    kb = next(int(line.split()[1]) for line in f if line.startswith("VmHWM:"))
print("maxrss", kb * 1024, file=sys.stderr)
sys.exit(code)
"""


def measured(*args):
    r = subprocess.run([sys.executable, "-c", MEASURE, *map(str, args)], capture_output=True,
                       text=True, cwd=ROOT, timeout=300)
    peak = int(r.stderr.rsplit("maxrss ", 1)[1])
    return r, peak


def sweep_model(tmp_path, count):
    f = tmp_path / "sweep.mech"
    f.write_text(SLIDER.replace("param l = 3.5", f"param l = 3.5\nsweep l = 3 .. 4 count {count}"))
    return f


def test_a_run_over_the_memory_limit_is_refused_with_the_figure(tmp_path):
    # 50,000 variants of 101 instants: 121 MB of results, solved a chunk at a time but held
    # whole for the CSV (a store or reductions would not be)
    f = sweep_model(tmp_path, 50_000)
    r, peak = measured("run", f, "--step", "0.01", "--max-memory", "64M", "-o", tmp_path / "o.csv")
    assert r.returncode == 1
    assert "error: this run needs about " in r.stderr and "more than the limit of 64.0 MiB" in r.stderr
    assert peak <= 64 * 2**20
    assert not (tmp_path / "o.csv").exists()


@pytest.mark.parametrize("count, step, limit", [(50_000, "0.5", "420M"), (1000, "0.01", "120M")])
def test_the_memory_limit_bounds_the_whole_process(tmp_path, count, step, limit):
    f = sweep_model(tmp_path, count)
    out = tmp_path / "o.csv"
    r, peak = measured("run", f, "--step", step, "--max-memory", limit, "-q", "-o", out)
    assert r.returncode == 0, r.stderr
    assert peak <= int(limit[:-1]) * 2**20
    lines = out.read_text().count("\n")
    assert lines == 2 + count * (round(1 / float(step)) + 1)  # the header, the units


@pytest.mark.parametrize("value", ["inf", "nan", "-5M", "1e30", "lots"])
def test_a_meaningless_memory_limit_is_refused(value, capsys):
    assert main(["run", str(EXAMPLES / "slider_crank.mech"), f"--max-memory={value}"]) == 1
    assert f"--max-memory takes a size such as 16G or 500M, not '{value}'" in capsys.readouterr().err


def test_messages_about_a_large_model_are_bounded(tmp_path, capsys):
    f = tmp_path / "loose.mech"
    f.write_text("".join(f"body b{i} {{ }}\n" for i in range(3000))
                 + "simulate t = 0 .. 1 step 0.1\n")
    assert main(["run", str(f)]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"{f}: error: the mechanism is not fully driven: 9000 coordinates "
                          "and 0 equations")
    assert err.count("is attached to nothing") == 8
    assert "note: and 2992 more bodies are attached to nothing" in err
    assert len(err) < 1500


@pytest.mark.parametrize("name, write", [
    # meshio's dolfin-xml reader opens every plate_*.xml beside the mesh (a FIFO would hang)
    ("plate.xml", lambda meshio, path, mesh: meshio.write(path, mesh, file_format="dolfin-xml")),
])
def test_meshes_that_read_other_files_are_refused(tmp_path, name, write):
    import meshio

    mesh = meshio.Mesh(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]]),
                       [("triangle", np.array([[0, 1, 2]]))])
    write(meshio, str(tmp_path / name), mesh)
    f = tmp_path / "m.mech"
    f.write_text(f'body b {{ shape = "{name}" }}\n' + "joint j: revolute(ground.origin, b.origin)\n"
                 "drive d: angle(b) = t\nsimulate t = 0 .. 1 step 0.5\n")
    with pytest.raises(MechError) as err:
        mechdsl.load(f)
    assert err.value.message.startswith(f"cannot read the shape {name}: ")
    assert (err.value.line, err.value.column) == (1, 18)


def test_a_table_whose_name_holds_a_nul_is_a_located_error(tmp_path):
    f = tmp_path / "m.mech"
    f.write_bytes(b'body b { }\njoint j: revolute(ground.origin, b.origin)\n'
                  b'drive d: angle(b) = table("a\x00b.csv", t)\nsimulate t = 0 .. 1 step 0.5\n')
    with pytest.raises(MechError) as err:
        mechdsl.load(f)
    assert "a file name has no NUL character" in err.value.message and err.value.line == 3


def test_drawings_and_exports_count_in_the_memory_estimate(tmp_path):
    # 300 variants x 5001 instants: the world coordinates of a snapshot's every point, and
    # the XML meshio builds for an XDMF export, are counted before the run
    f = tmp_path / "rods.mech"
    f.write_text((EXAMPLES / "rod_sweep.mech").read_text().replace(
        "sweep l = [3.5, 2.5, 2.2, 2.1]", "sweep l = 2.5 .. 4 count 300"))
    r, peak = measured("run", f, "--step", "2e-4", "--snapshot", tmp_path / "s.png",
                       "--max-memory", "700M")
    assert r.returncode == 1 and "drawings and exports 3." in r.stderr
    assert peak <= 700 * 2**20 and not (tmp_path / "s.png").exists()
    r, peak = measured("run", EXAMPLES / "fourbar.mech", "--step", "0.00002", "--export",
                       tmp_path / "big.xdmf", "--max-memory", "200M")
    assert r.returncode == 1 and "more than the limit of 200.0 MiB" in r.stderr
    assert peak <= 200 * 2**20 and not (tmp_path / "big.xdmf").exists()


def test_a_model_whose_parsing_could_exceed_the_memory_limit_is_refused_first(tmp_path):
    f = tmp_path / "mins.mech"
    f.write_text("param r = min(" + "1," * 300_000 + "1)\n")  # 600 kB of tiny expressions
    r, peak = measured("run", f, "--max-memory", "100M")
    assert r.returncode == 1
    assert "parsing the model 286.1 MiB), more than the limit of 100.0 MiB" in r.stderr
    assert peak <= 100 * 2**20


def test_a_compressed_mesh_that_expands_beyond_the_limit_is_refused(tmp_path, monkeypatch):
    import meshio

    from mechdsl import reading

    mesh = meshio.Mesh(np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0], [1.0, 1.0]]),
                       [("triangle", np.array([[0, 1, 2], [1, 3, 2]] * 2000))])
    for name, compression in (("z.vtu", "zlib"), ("x.vtu", "lzma")):
        meshio.write(str(tmp_path / name), mesh, compression=compression)
        f = tmp_path / "m.mech"
        f.write_text(f'body b {{ shape = "{name}" }}\n')
        assert mechdsl.load(f).model.bodies[0].shape.triangles.shape == (4000, 3)
        # the same file, with a limit below what its blocks inflate to (48 kB of cells)
        monkeypatch.setattr(reading, "MAX_DATA_BYTES", 20_000)
        with pytest.raises(MechError, match=f"cannot read the shape {name}: it is not a mesh"):
            mechdsl.load(f)
        monkeypatch.undo()
