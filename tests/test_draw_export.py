"""Pictures and meshes of the motion: traced paths, snapshots, animations, and the meshio
export read back, each checked against the four-bar's closed form (loop closure)."""

from __future__ import annotations

import numpy as np
import pytest

from closed_forms import four_bar
from conftest import EXAMPLES
from test_cli import mechdsl

FOURBAR = EXAMPLES / "fourbar.mech"
A, B = 1.0, 3.5  # crank and coupler of examples/fourbar.mech; P = (0, 1) in the coupler frame


def coupler_point(t: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Position, velocity, acceleration (K, 2) of the coupler point P by loop closure:
    P = a e2 + (b/2) e3 + n3, differentiated with e' = w perp(e), n3' = -w3 e3."""
    th2 = np.pi / 4 + 2 * np.pi * t
    w2 = 2 * np.pi
    (th3, w3, al3), _ = four_bar(A, B, 3.0, 4.0, th2, w2, 0.0)
    e2 = np.stack((np.cos(th2), np.sin(th2)), -1)
    e3 = np.stack((np.cos(th3), np.sin(th3)), -1)
    p2, n3 = e2[:, ::-1] * [-1, 1], e3[:, ::-1] * [-1, 1]
    w3, al3 = w3[:, None], al3[:, None]
    pos = A * e2 + B / 2 * e3 + n3
    vel = A * w2 * p2 + B / 2 * w3 * n3 - w3 * e3
    acc = (-A * w2**2 * e2 + B / 2 * (al3 * n3 - w3**2 * e3) - (al3 * e3 + w3**2 * n3))
    return pos, vel, acc


def test_traced_path_is_the_coupler_curve(loads):
    from mechdsl.outputs.draw import paths
    from mechdsl.solve import simulate

    text = FOURBAR.read_text() + "\ntrace rocker\n"  # the file itself traces coupler.P
    kernels = loads(text).compile()
    res = simulate(kernels, poses=True)
    traced = paths(res, kernels.system.sketch)
    assert set(traced) == {"coupler.P", "rocker"}
    np.testing.assert_allclose(traced["coupler.P"][0], coupler_point(res["t"])[0], atol=1e-13)
    # the rocker's origin, the middle of B-O4, stays at c/2 = 1.5 from O4 = (4, 0)
    r = np.linalg.norm(traced["rocker"][0] - [4.0, 0.0], axis=-1)
    np.testing.assert_allclose(r, 1.5, atol=1e-13)


def test_trace_of_an_unknown_point_is_a_located_error(loads):
    from mechdsl.errors import MechError

    text = FOURBAR.read_text() + "\ntrace coupler.Q\n"
    with pytest.raises(MechError) as err:
        loads(text).compile()
    assert "no point 'Q'" in str(err.value)
    assert err.value.span is not None and err.value.span.line == text.count("\n")


def test_snapshot_and_animation_are_written(tmp_path):
    from PIL import Image

    snap, gif = tmp_path / "coupler.png", tmp_path / "fourbar.gif"
    r = mechdsl("run", FOURBAR, "--step", "0.01", "--trace", "crank.A", "--snapshot", snap,
                "--at", "0,0.25,0.5", "--animate", gif, "--frames", "20", "-q")
    assert r.returncode == 0, r.stderr
    with Image.open(snap) as im:
        assert im.format == "PNG" and im.size[0] > 300
    with Image.open(gif) as im:
        assert im.format == "GIF" and im.n_frames == 20
    assert not list(tmp_path.glob(".mechdsl-*"))  # no temporary file left behind


@pytest.mark.parametrize("args, message", [
    (["--animate", "out.avi"], "an animation is a .gif or an .mp4"),
    (["--snapshot", "out.xyz"], "unknown image format 'xyz'"),
    (["--export", "out.stl"], "use .xdmf"),
    (["--at", "0,1"], "--at chooses the instants of --snapshot"),
    (["--snapshot", "s.png", "--at", "0,x"], "expected times separated by commas"),
    (["--snapshot", "s.png", "--trace", "coupler.Q"], "body 'coupler' has no point 'Q'"),
    (["--snapshot", "s.png", "--trace", "couplr.P"], "did you mean 'coupler'"),
])
def test_drawing_options_are_checked_before_solving(tmp_path, args, message):
    r = mechdsl("run", FOURBAR, *args, cwd=tmp_path)
    assert r.returncode == 1
    assert message in r.stderr and "Traceback" not in r.stderr


def test_mp4_needs_ffmpeg(tmp_path):
    from matplotlib import animation

    r = mechdsl("run", FOURBAR, "--step", "0.05", "--animate", tmp_path / "a.mp4", "-q")
    if animation.writers.is_available("ffmpeg"):
        assert r.returncode == 0 and (tmp_path / "a.mp4").stat().st_size > 0
    else:
        assert r.returncode == 1 and "needs ffmpeg" in r.stderr


def _coupler_p_index(kernels) -> int:
    from mechdsl.outputs.export import _layout

    owners, _, _ = _layout(kernels.system)
    coupler = kernels.system.body_names.index("coupler")
    return next(j for j, (body, s) in enumerate(owners)
                if body == coupler and np.allclose(s[0], [0.0, 1.0]))


def test_xdmf_time_series_reads_back(tmp_path, load_example):
    import meshio

    r = mechdsl("run", FOURBAR, "--step", "0.05", "--export", tmp_path / "fb.xdmf", "-q")
    assert r.returncode == 0, r.stderr
    kernels = load_example("fourbar.mech").compile()
    j = _coupler_p_index(kernels)
    t = np.arange(21) * 0.05
    pos, vel, acc = coupler_point(t)
    with meshio.xdmf.TimeSeriesReader(str(tmp_path / "fb.xdmf")) as reader:
        points, cells = reader.read_points_cells()
        assert reader.num_steps == 21 and cells[0].type == "line"
        np.testing.assert_allclose(points[j, :2], pos[0], atol=1e-13)
        for k in range(reader.num_steps):
            tk, pd, cd = reader.read_data(k)
            assert tk == pytest.approx(t[k])
            np.testing.assert_allclose(pd["position"][j, :2], pos[k], atol=1e-12)
            np.testing.assert_allclose(pd["velocity"][j, :2], vel[k], atol=1e-11)
            np.testing.assert_allclose(pd["acceleration"][j, :2], acc[k], atol=1e-9)
            np.testing.assert_allclose(pd["speed"][j], np.linalg.norm(vel[k]), atol=1e-11)
            assert set(cd["body"][0]) == {-1, 0, 1, 2}


def test_vtu_files_and_pvd_index(tmp_path, load_example):
    import xml.etree.ElementTree as ET

    import meshio

    r = mechdsl("run", FOURBAR, "--step", "0.25", "--export", tmp_path / "fb.vtu", "-q")
    assert r.returncode == 0, r.stderr
    kernels = load_example("fourbar.mech").compile()
    j = _coupler_p_index(kernels)
    entries = ET.parse(tmp_path / "fb.pvd").getroot().findall(".//DataSet")
    assert [float(e.get("timestep")) for e in entries] == pytest.approx([0, 0.25, 0.5, 0.75, 1])
    pos, vel, _ = coupler_point(np.array([0, 0.25, 0.5, 0.75, 1.0]))
    for k, e in enumerate(entries):
        mesh = meshio.read(tmp_path / e.get("file"))
        np.testing.assert_allclose(mesh.points[j, :2], pos[k], atol=1e-12)
        np.testing.assert_allclose(mesh.point_data["velocity"][j, :2], vel[k], atol=1e-11)


class _Tty:
    def __init__(self, tty: bool) -> None:
        self.tty, self.text = tty, ""

    def isatty(self) -> bool:
        return self.tty

    def write(self, s: str) -> None:
        self.text += s

    def flush(self) -> None:
        pass


def test_progress_bar_only_on_a_terminal_and_only_for_long_runs(load_example):
    from mechdsl.commands import ProgressBar
    from mechdsl.solve import simulate

    kernels = load_example("slider_crank.mech").compile()
    tty, pipe, short = _Tty(True), _Tty(False), _Tty(True)
    for stream, delay in ((tty, 0.0), (pipe, 0.0), (short, 3600.0)):
        bar = ProgressBar(stream, delay=delay, rate=1e9)
        assert simulate(kernels, progress=bar).ok
        bar.close()
    assert "%" in tty.text and "instants" in tty.text and tty.text.endswith("\r")
    assert pipe.text == "" and short.text == ""


def test_plot_redraws_a_sweep_csv_without_solving(tmp_path):
    from PIL import Image

    from closed_forms import slider_crank
    from mechdsl.outputs.csv import read_csv

    csv = tmp_path / "sweep.csv"
    r = mechdsl("run", EXAMPLES / "slider_crank.mech", "--sweep", "l=3.5,2.5", "--step", "0.01",
                "-o", csv, "-q")
    assert r.returncode == 0, r.stderr
    res = read_csv(str(csv))
    assert list(res.sweep["l"]) == [3.5, 2.5] and res.labels == ("slider.x", "slider.vx",
                                                                 "slider.ax")
    for v, l in enumerate((3.5, 2.5)):
        x, _, ax = slider_crank(2.0, l, np.pi / 4 + 4 * np.pi * res["t"], 4 * np.pi, 0.0)
        np.testing.assert_allclose(res["slider.x"][v], x, atol=1e-12)
        np.testing.assert_allclose(res["slider.ax"][v], ax, rtol=1e-10, atol=1e-9)
    r = mechdsl("plot", csv, "--only", "slider.x,slider.ax")
    assert r.returncode == 0, r.stderr
    with Image.open(tmp_path / "sweep.png") as im:
        assert im.format == "PNG"
    r = mechdsl("plot", csv, "--only", "slider.q")
    assert r.returncode == 1 and "no column 'slider.q'" in r.stderr
    (tmp_path / "bad.csv").write_text("a,b\n1,x\n")
    r = mechdsl("plot", tmp_path / "bad.csv")
    assert r.returncode == 1 and "Traceback" not in r.stderr


def test_units_label_every_quantity(loads):
    from mechdsl.solve import simulate

    text = (EXAMPLES / "fourbar.mech").read_text().replace(
        'units length = "m", time = "s"', 'units length = "mm", time = "ms"')
    res = simulate(loads(text).compile(__import__("mechdsl").compiled.variants.Overrides(step=0.5)))
    assert res.units == {"rocker.phi": "rad", "rocker.omega": "rad/ms", "rocker.alpha":
                         "rad/ms^2", "coupler.phi": "rad", "coupler.P.x": "mm",
                         "coupler.P.y": "mm"}
    assert res.time_unit == "ms"


def test_the_summary_lists_every_output_written(tmp_path):
    """-o with --plot, --snapshot, --animate and --export: one line each on standard error,
    in the order written (the CSV's rows, the plot's quantities, the snapshot's instants, the
    animation's frames, the export's files); nothing with -q; without -o the summary table
    on standard output and the other outputs on standard error."""
    slider_crank = EXAMPLES / "slider_crank.mech"
    outputs = ["-o", "out.csv", "--plot", "p.png", "--snapshot", "s.png", "--at", "0,0.5",
               "--animate", "a.gif", "--frames", "5", "--export", "e.vtu"]
    r = mechdsl("run", slider_crank, "--step", "0.01", *outputs, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    lines = r.stderr.splitlines()
    assert lines[0].startswith("out.csv: 101 rows (") and lines[0].endswith(" ms)")
    assert lines[1:] == ["p.png: plot of 3 quantities", "s.png: snapshot at t = 0, 0.5",
                         "a.gif: animation of 5 frames",
                         # --at chooses the export's instants too
                         "e.vtu: export of 2 instants in 3 files: e_0000.vtu .. "
                         "e_0050.vtu and e.pvd"]
    assert r.stdout == ""
    written = {p.name for p in tmp_path.iterdir()}
    assert {"out.csv", "p.png", "s.png", "a.gif", "e.pvd", "e_0000.vtu", "e_0050.vtu"} <= written
    assert len([n for n in written if n.endswith(".vtu")]) == 2
    r = mechdsl("run", slider_crank, "--step", "0.01", *outputs, "-q", cwd=tmp_path)
    assert r.returncode == 0 and r.stderr == "" and r.stdout == ""
    r = mechdsl("run", slider_crank, "--step", "0.05", "--sweep", "l=2.5,3.5", "--plot", "p.png",
                "--animate", "a.gif", "--export", "e.xdmf", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert "slider.x" in r.stdout  # the summary table
    assert r.stderr.splitlines() == [
        "p.png: plot of 3 quantities", "a.gif: animation of 21 frames",
        "e.xdmf: export of 2 variants (42 instants) in 2 files: e_v0.xdmf; e_v1.xdmf"]


def test_a_sweep_in_chunks_draws_and_exports_every_variant_as_in_one(tmp_path):
    # the run is solved a chunk of variants at a time (--chunk 1), its pictures and meshes
    # drawn from every variant's geometry: the same snapshot, byte for byte, as in one batch
    def run(*extra):
        return mechdsl("run", EXAMPLES / "fourbar.mech", "--sweep", "d=3.8,4.0,4.2",
                       "--t1", "0.5", "-q", "-o", tmp_path / "o.csv", *extra)

    one, chunks = tmp_path / "one.png", tmp_path / "chunks.png"
    assert run("--snapshot", str(one), "--at", "0,0.25").returncode == 0
    r = run("--chunk", "1", "--snapshot", str(chunks), "--at", "0,0.25")
    assert r.returncode == 0, r.stderr
    assert one.read_bytes() == chunks.read_bytes()
    r = run("--chunk", "1", "--export", str(tmp_path / "e.xdmf"))
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in tmp_path.glob("e_v*.xdmf")) == \
        ["e_v0.xdmf", "e_v1.xdmf", "e_v2.xdmf"]


# -- drawings for CAD, and the instants of an export (issue 30) -------------------------------

def _csv_columns(path):
    import csv as _csv

    with open(path) as f:
        rows = [r for r in _csv.reader(f) if r and not r[0].startswith("#")]
    return {name: np.array([float(r[j]) for r in rows[1:]]) for j, name in enumerate(rows[0])}


def test_dxf_and_svg_read_back_give_the_runs_positions(tmp_path):
    """--export out.dxf / out.svg at --at instants: read back (ezdxf, an XML parser), the
    coupler plate's point P at each instant and the traced path of coupler.P equal the CSV
    of the same run (the positions mechdsl run writes) to 1e-12; the DXF says metres."""
    import xml.etree.ElementTree as ET

    import ezdxf

    at = [0.25, 0.5]
    r = mechdsl("run", EXAMPLES / "fourbar.mech", "-o", tmp_path / "o.csv", "--export",
                tmp_path / "f.dxf", "--at", "0.25,0.5", "-q")
    assert r.returncode == 0, r.stderr
    r = mechdsl("run", EXAMPLES / "fourbar.mech", "--export", tmp_path / "f.svg", "--at",
                "0.25,0.5", "-q")
    assert r.returncode == 0, r.stderr
    cols = _csv_columns(tmp_path / "o.csv")
    k = [int(np.argmin(np.abs(cols["t"] - a))) for a in at]
    P = np.column_stack((cols["coupler.P.x"], cols["coupler.P.y"]))

    doc = ezdxf.readfile(tmp_path / "f.dxf")
    assert doc.header["$INSUNITS"] == 6  # metres
    for a, kk in zip(at, k):
        plates = [e for e in doc.modelspace().query(f'LWPOLYLINE[layer=="t {a:g}"]')
                  if e.get_xdata("MECHDSL")[0].value == "coupler"]
        (plate,) = plates
        assert plate.closed
        pts = np.array([(x, y) for x, y, *_ in plate.get_points()])
        assert np.abs(pts - P[kk]).sum(axis=1).min() <= 1e-12  # P is a vertex
    (path,) = doc.modelspace().query('LWPOLYLINE[layer=="paths"]')
    traced = np.array([(x, y) for x, y, *_ in path.get_points()])
    np.testing.assert_allclose(traced, P, atol=1e-12, rtol=0)

    svg = ET.parse(tmp_path / "f.svg").getroot()
    ns = {"s": "http://www.w3.org/2000/svg"}

    def points(el):
        return np.array([[float(v) for v in xy.split(",")] for xy in el.get("points").split()])
    for a, kk in zip(at, k):
        group = svg.find(f".//s:g[@id='t_{a:g}']", ns)
        assert float(group.get("data-t")) == pytest.approx(cols["t"][kk], abs=1e-15)
        plate = group.find("s:polygon[@data-body='coupler']", ns)
        assert np.abs(points(plate) - P[kk]).sum(axis=1).min() == 0.0  # exact: repr
    traced = points(svg.find(".//s:polyline[@data-path='coupler.P']", ns))
    np.testing.assert_array_equal(traced, P)


def test_export_honours_frames_and_at_for_every_format(tmp_path):
    """1001 instants: --frames 5 writes five .vtu files (named by their instant) and the
    index; --at 0.1,0.3 an XDMF series of those two instants; the default of a mesh export
    is --frames' 100."""
    import meshio

    r = mechdsl("run", EXAMPLES / "slider_crank.mech", "--export", tmp_path / "s.vtu",
                "--frames", "5", "-q")
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in tmp_path.glob("s_*.vtu")) == \
        [f"s_{k:04d}.vtu" for k in (0, 250, 500, 750, 1000)]
    assert 'file="s_0750.vtu"' in (tmp_path / "s.pvd").read_text()
    r = mechdsl("run", EXAMPLES / "slider_crank.mech", "--export", tmp_path / "x.xdmf",
                "--at", "0.1,0.3", "-q")
    assert r.returncode == 0, r.stderr
    with meshio.xdmf.TimeSeriesReader(str(tmp_path / "x.xdmf")) as reader:
        reader.read_points_cells()
        times = [reader.read_data(i)[0] for i in range(reader.num_steps)]
    np.testing.assert_allclose(times, [0.1, 0.3], atol=1e-12)
    r = mechdsl("run", EXAMPLES / "slider_crank.mech", "--export", tmp_path / "d.vtu", "-q")
    assert r.returncode == 0, r.stderr
    assert len(list(tmp_path.glob("d_*.vtu"))) == 100
