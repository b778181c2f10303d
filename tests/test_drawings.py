"""What snapshots and animations draw, checked on the artists of the figure (not on pixels):
every point a joint attaches, a body's origin included, is on the body's drawing at the
coordinates of the closed-form pose; every attached ground point has its hatched support, in
every variant of a sweep; a sweep's variants are named in a legend; no warning; an animation
draws its fixed parts once and keeps its frames as palette images."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from conftest import EXAMPLES
from test_cli import mechdsl

# A slider-crank whose crank is pivoted at its origin (it declares only its pin B), beside a
# bell crank pivoted at its origin on the ground point Q; the ground declares Q only, and
# the crank and the slider's line are attached at ground.origin.
PINNED = """
param r = 2
param l = 3.5
ground { point Q = (6, 0) }
body crank  { guess = (0, 0, 0.8)   point B = (r, 0) }
body rod    { guess = (3, 0.7, -0.3)  point B = (-l/2, 0)  point C = (l/2, 0) }
body slider { guess = (4.6, 0, 0) }
body lever  { guess = (6, 0, 0)  point A = (1, 0)  point B = (0, 1) }
joint A: revolute(ground.origin, crank.origin)
joint B: revolute(crank.B, rod.B)
joint C: revolute(rod.C, slider.origin)
joint D: prismatic(ground.origin, slider.origin, axis = (1, 0))
joint E: revolute(ground.Q, lever.origin)
drive turn: angle(crank) = pi/4 + 2*pi*t
drive tilt: angle(lever) = t
simulate t = 0 .. 1 step 0.05
"""
R, L = 2.0, 3.5
Q = np.array([6.0, 0.0])


def pose(t: float) -> dict[str, np.ndarray]:
    """The drawn points of PINNED at time t, in closed form: the crank from its origin (0, 0)
    to B at angle pi/4 + 2 pi t; the slider where the rod of length l meets the x axis; the
    bell crank turned by t about Q: origin, A, B."""
    th = np.pi / 4 + 2 * np.pi * t
    b = R * np.array([np.cos(th), np.sin(th)])
    c = np.array([b[0] + np.sqrt(L**2 - b[1] ** 2), 0.0])
    rot = np.array([[np.cos(t), -np.sin(t)], [np.sin(t), np.cos(t)]])
    return {"crank": np.array([[0.0, 0.0], b]), "rod": np.array([b, c]), "slider": c,
            "lever": np.array([Q, Q + rot @ [1.0, 0.0], Q + rot @ [0.0, 1.0]])}


@pytest.fixture
def figures(monkeypatch):
    """The matplotlib figures drawn while the test runs (snapshots and animations)."""
    import mechdsl.outputs.plot

    made = []
    original = mechdsl.outputs.plot.new_figure

    def new_figure(**kwargs):
        made.append(original(**kwargs))
        return made[-1]

    monkeypatch.setattr(mechdsl.outputs.plot, "new_figure", new_figure)
    return made


def solve(loads, text: str, **sweeps):
    from mechdsl.solve import simulate
    from mechdsl.compiled.variants import Overrides

    kernels = loads(text).compile(Overrides(sweeps=sweeps))
    return kernels, simulate(kernels, poses=True, rates=True)


def segments(ax) -> list[np.ndarray]:
    """Every straight segment of the bars (the line collections three points wide) drawn in
    ``ax``."""
    from matplotlib.collections import LineCollection

    return [np.asarray(s) for c in ax.collections if isinstance(c, LineCollection)
            and len(c.get_linewidths()) and c.get_linewidths()[0] == 3
            for s in c.get_segments()]


def rails(ax) -> list[np.ndarray]:
    """The sides of the guides' rails: segments of the thin grey line collections."""
    from matplotlib.collections import LineCollection

    return [np.asarray(s) for c in ax.collections if isinstance(c, LineCollection)
            and len(c.get_linewidths()) and c.get_linewidths()[0] == 1.0
            and np.allclose(c.get_edgecolor()[0][:3], 0.35) for s in c.get_segments()]


def plates(ax) -> list[np.ndarray]:
    """The outline of every polygon of the polygon collections (the plates), unclosed."""
    from matplotlib.collections import PolyCollection

    return [np.asarray(p.vertices)[: len(p.vertices) - 1 if p.codes is not None and
                                   p.codes[-1] == p.CLOSEPOLY else None]
            for c in ax.collections if isinstance(c, PolyCollection) for p in c.get_paths()]


def supports(ax) -> list[tuple[np.ndarray, tuple]]:
    """(apex, edge colour) of every hatched triangle: the ground's pivots."""
    from matplotlib.patches import Polygon

    return [(np.asarray(p.get_xy())[0], p.get_edgecolor()) for p in ax.patches
            if isinstance(p, Polygon) and p.get_hatch() and len(p.get_xy()) == 4]


def has(shapes: list[np.ndarray], expected: np.ndarray, atol: float = 1e-12) -> bool:
    return any(s.shape == expected.shape and np.allclose(s, expected, atol=atol, rtol=0)
               for s in shapes)


def check_pinned_drawing(ax, t: float) -> None:
    exact = pose(t)
    # the crank is a bar from its pivot at the origin to its pin; the rod a bar B-C
    assert has(segments(ax), exact["crank"]), segments(ax)
    assert has(segments(ax), exact["rod"])
    # the bell crank a plate through its origin (the pivot, first) and its points A, B
    assert has(plates(ax), exact["lever"]), plates(ax)
    # every ground point attached has its support: ground.origin and Q
    apexes = [a for a, _ in supports(ax)]
    assert len(apexes) == 2
    assert has(apexes, np.zeros(2)) and has(apexes, Q)


def test_bodies_pinned_at_their_origin_are_drawn_through_it_in_a_snapshot(loads, figures,
                                                                          tmp_path):
    from mechdsl.outputs.draw import snapshot

    kernels, res = solve(loads, PINNED)
    assert res.ok
    snapshot(res, kernels.system, str(tmp_path / "s.png"), at=[0.3])
    (fig,) = figures
    check_pinned_drawing(fig.axes[0], 0.3)
    # one instant, drawn once: no other bar, plate or support
    assert len(segments(fig.axes[0])) == 2 and len(plates(fig.axes[0])) == 1


def test_bodies_pinned_at_their_origin_are_drawn_through_it_in_an_animation(loads, figures,
                                                                            tmp_path):
    from mechdsl.outputs.draw import animate

    kernels, res = solve(loads, PINNED)
    animate(res, kernels.system, str(tmp_path / "a.gif"), max_frames=5)
    (fig,) = figures
    check_pinned_drawing(fig.axes[0], 1.0)  # the artists hold the last frame, t = 1


def test_outlines_put_attached_points_first_then_the_declared_ones(loads):
    from mechdsl.outputs.draw import outlines

    kernels = loads(PINNED).compile()
    drawn = dict(zip((*kernels.system.body_names, "ground"), outlines(kernels.system.sketch)))
    np.testing.assert_array_equal(drawn["crank"][0], [[0, 0], [R, 0]])
    np.testing.assert_array_equal(drawn["rod"][0], [[-L / 2, 0], [L / 2, 0]])
    np.testing.assert_array_equal(drawn["slider"][0], [[0, 0]])
    np.testing.assert_array_equal(drawn["lever"][0], [[0, 0], [1, 0], [0, 1]])
    np.testing.assert_array_equal(drawn["ground"][0], [[0, 0], Q])
    # a point declared at the origin stands for it: not drawn twice
    text = PINNED.replace("point B = (r, 0) }", "point O = (0, 0)  point B = (r, 0) }")
    text = text.replace("crank.origin)", "crank.O)")
    crank = outlines(loads(text).compile().system.sketch)[0]
    np.testing.assert_array_equal(crank[0], [[0, 0], [R, 0]])


@pytest.mark.parametrize("ext", [".vtu", ".xdmf"])
def test_exported_cells_join_the_origin_and_none_has_zero_length(loads, tmp_path, ext):
    from mechdsl.outputs.export import export

    kernels, res = solve(loads, PINNED)
    export(res, kernels.system, str(tmp_path / f"e{ext}"))
    k = 7
    t = res["t"][k]
    if ext == ".vtu":
        import meshio

        mesh = meshio.read(tmp_path / f"e_{k:04d}.vtu")
        points = mesh.points[:, :2]
        cells = {c.type: c.data for c in mesh.cells}
        body = dict(zip((c.type for c in mesh.cells), mesh.cell_data["body"]))
    else:
        points, cells, body = read_xdmf(tmp_path / "e.xdmf", k)
    lines = points[cells["line"]]  # (cells, 2, 2)
    assert (np.linalg.norm(lines[:, 1] - lines[:, 0], axis=-1) > 1e-9).all()
    exact = pose(t)
    index = {name: i for i, name in enumerate(kernels.system.body_names)} | {"ground": -1}
    by_body = {name: [lines[j] for j in np.flatnonzero(body["line"] == i)]
               for name, i in index.items()}
    assert len(by_body["crank"]) == 1 and has(by_body["crank"], exact["crank"], 1e-11)
    assert len(by_body["rod"]) == 1 and has(by_body["rod"], exact["rod"], 1e-11)
    lever = exact["lever"]
    assert len(by_body["lever"]) == 3  # the closed loop origin-A-B
    for a, b in ((0, 1), (1, 2), (2, 0)):
        assert has(by_body["lever"], lever[[a, b]], 1e-11)
    assert len(by_body["ground"]) == 1 and has(by_body["ground"], np.array([[0, 0], Q]))
    # the slider, a body of one point, is a vertex cell where the rod's end is
    (vertex,) = cells["vertex"]
    np.testing.assert_allclose(points[vertex[0]], exact["slider"], atol=1e-11)
    assert list(body["vertex"]) == [kernels.system.body_names.index("slider")]


def read_xdmf(path, k: int):
    """Points at instant k, cells by type and body index by cell type of an XDMF time series
    with a "Mixed" topology as XDMF defines it (type, number of points, points)."""
    import xml.etree.ElementTree as ET

    def numbers(item):
        return np.array(item.text.split(), dtype=float)

    root = ET.parse(path).getroot()
    mesh = root.find(".//Grid[@Name='mesh']")
    topology = mesh.find("Topology")
    assert topology.get("TopologyType") == "Mixed"
    flat = numbers(topology.find("DataItem")).astype(int)
    kinds, conn, j = [], [], 0
    while j < len(flat):
        code, n = flat[j], flat[j + 1]
        assert (code, n) in ((1, 1), (2, 2)), (code, n)
        kinds.append("vertex" if code == 1 else "line")
        conn.append(flat[j + 2 : j + 2 + n])
        j += 2 + n
    assert len(kinds) == int(topology.get("NumberOfElements"))
    steps = root.findall(".//Grid[@CollectionType='Temporal']/Grid")
    step = steps[k]
    position = numbers(step.find("Attribute[@Name='position']/DataItem")).reshape(-1, 3)
    body = numbers(step.find("Attribute[@Name='body']/DataItem")).astype(int)
    kinds = np.array(kinds)
    cells = {kind: np.array([c for c, t in zip(conn, kinds) if t == kind]) for kind in
             ("line", "vertex")}
    return position[:, :2], cells, {kind: body[kinds == kind] for kind in ("line", "vertex")}


def test_a_pivot_at_the_ground_origin_has_its_support_beside_the_declared_ones(
        load_example, loads, figures, tmp_path):
    """The four-bar with its crank's pivot at ground.origin instead of a declared O2: a
    support under the origin and under O4, in the snapshot and in the export's ground cell."""
    import meshio

    from mechdsl.outputs.draw import snapshot
    from mechdsl.outputs.export import export
    from mechdsl.solve import simulate

    text = (EXAMPLES / "fourbar.mech").read_text()
    text = text.replace("    point O2 = (0, 0)\n", "").replace("ground.O2", "ground.origin")
    assert "O2 =" not in text and "ground.origin" in text
    kernels = loads(text).compile()
    res = simulate(kernels, poses=True, rates=True)
    snapshot(res, kernels.system, str(tmp_path / "s.png"))
    apexes = [a for a, _ in supports(figures[0].axes[0])]
    assert len(apexes) == 2 and has(apexes, np.zeros(2)) and has(apexes, np.array([4.0, 0]))
    export(res, kernels.system, str(tmp_path / "e.vtu"))
    mesh = meshio.read(tmp_path / "e_0000.vtu")
    (lines,) = [c.data for c in mesh.cells if c.type == "line"]
    ground = lines[mesh.cell_data["body"][0] == -1]
    np.testing.assert_array_equal(mesh.points[ground][..., :2], [[[0, 0], [4, 0]]])


def legend_texts(ax) -> list[str]:
    legend = ax.get_legend()
    return [] if legend is None else [t.get_text() for t in legend.get_texts()]


def test_a_sweep_snapshot_names_its_variants_and_draws_their_supports(load_example, figures,
                                                                      tmp_path):
    from mechdsl.outputs.draw import snapshot
    from mechdsl.outputs.styles import variant_styles
    from mechdsl.solve import simulate
    from mechdsl.compiled.variants import Overrides

    kernels = load_example("fourbar.mech").compile(Overrides(sweeps={"d": [3.8, 4.2]}))
    res = simulate(kernels, poses=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        snapshot(res, kernels.system, str(tmp_path / "s.png"), at=[0, 0.5])
    (fig,) = figures
    ax = fig.axes[0]
    assert legend_texts(ax) == ["d = 3.8", "d = 4.2", "path of coupler.P"]
    colors = variant_styles(res).colors
    handles = ax.get_legend().legend_handles
    assert [h.get_color() for h in handles[:2]] == colors
    # O2 = (0, 0) is the same in both variants: one support; O4 = (d, 0) one per variant,
    # in the variant's colour
    drawn = supports(ax)
    assert len(drawn) == 3
    for apex, color in ((np.zeros(2), None), ((3.8, 0), colors[0]), ((4.2, 0), colors[1])):
        (match,) = [c for a, c in drawn if np.allclose(a, apex, atol=1e-12)]
        if color is not None:
            assert np.allclose(match, color)


def test_a_sweep_without_traces_has_a_legend_and_no_warning(loads, figures, tmp_path):
    from mechdsl.outputs.draw import animate, snapshot

    kernels, res = solve(loads, PINNED, l=[3.5, 4.0])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        snapshot(res, kernels.system, str(tmp_path / "s.png"))
        animate(res, kernels.system, str(tmp_path / "a.gif"), max_frames=3)
        # without a sweep or a trace there is nothing to name: no legend (and no warning)
        system1, res1 = solve(loads, PINNED)
        snapshot(res1, system1.system, str(tmp_path / "s1.png"))
    snap, anim, single = figures
    for fig in (snap, anim):
        assert legend_texts(fig.axes[0]) == ["l = 3.5", "l = 4"]
    assert single.axes[0].get_legend() is None
    # the variants share their ground points: a support each, drawn once
    assert len(supports(snap.axes[0])) == 2 and len(supports(anim.axes[0])) == 2


def test_sweep_snapshot_on_the_command_line_warns_nothing_even_quiet(tmp_path):
    r = mechdsl("run", EXAMPLES / "slider_crank.mech", "--sweep", "l=2.5,3.5", "--step", "0.05",
                "--snapshot", tmp_path / "s.png", "--animate", tmp_path / "a.gif", "--frames",
                "3", "-q")
    assert r.returncode == 0 and r.stderr == "" and r.stdout == ""


def test_an_animation_draws_its_fixed_parts_once_and_keeps_palette_frames(
        load_example, figures, tmp_path, monkeypatch):
    """Redraw only what moves: the whole figure is drawn once (not at every frame), and the
    frames are kept as palette images sharing one palette (1 byte a pixel, not RGB(A)).
    The last frame is still what the whole figure looks like when drawn."""
    from matplotlib.figure import Figure
    from PIL import Image

    from mechdsl.outputs.draw import animate
    from mechdsl.solve import simulate

    draws = []
    original_draw = Figure.draw
    monkeypatch.setattr(Figure, "draw", lambda self, renderer: (draws.append(self),
                                                                original_draw(self, renderer)))
    saved = []
    original_save = Image.Image.save

    def save(self, fp, format=None, **params):  # noqa: A002 - Pillow's name
        params["append_images"] = list(params.get("append_images", []))
        saved.append([self, *params["append_images"]])
        return original_save(self, fp, format, **params)

    monkeypatch.setattr(Image.Image, "save", save)
    kernels = load_example("fourbar.mech").compile()
    res = simulate(kernels, poses=True)
    gif = tmp_path / "a.gif"
    animate(res, kernels.system, str(gif), max_frames=12)
    (fig,) = figures
    assert len(draws) == 1  # the fixed parts; the moving ones are drawn over a copy
    (frames,) = saved
    assert len(frames) == 12
    assert {im.mode for im in frames} == {"P"}
    assert len({bytes(im.getpalette()) for im in frames}) == 1
    monkeypatch.setattr(Image.Image, "save", original_save)
    # the last frame against the figure drawn whole in its last state
    for artist in fig.axes[0].get_children():
        artist.set_animated(False)
    fig.canvas.draw()
    whole = np.asarray(fig.canvas.buffer_rgba())[..., :3].astype(int)
    with Image.open(gif) as im:
        assert im.n_frames == 12
        im.seek(11)
        last = np.asarray(im.convert("RGB")).astype(int)
    assert last.shape == whole.shape
    off = np.abs(last - whole).max(axis=-1)
    assert (off > 40).mean() < 1e-3 and off.mean() < 0.5


# -- drawings that look like the mechanism (issue 30) -----------------------------------------

def test_a_guide_is_a_rail_over_the_sliders_travel_and_its_reference_no_pivot(loads, figures,
                                                                               tmp_path):
    """The slider's guide is drawn as a rail (two lines either side of y = 0) from before
    its least to beyond its largest x over the run; a ground point that is only a guide's
    reference (G) gets no pivot's support; the axes carry the unit of length."""
    from mechdsl.outputs.draw import snapshot

    text = PINNED.replace("ground { point Q = (6, 0) }",
                          "ground { point Q = (6, 0)  point G = (1, 0) }")
    text = text.replace("prismatic(ground.origin,", "prismatic(ground.G,")
    text += 'units length = "m", time = "s"\n'
    kernels, res = solve(loads, text)
    snapshot(res, kernels.system, str(tmp_path / "s.png"), at=[0.3])
    ax = figures[0].axes[0]
    sides = rails(ax)
    assert len(sides) == 2
    x = res.poses[0, :, 2, 0]  # the slider's x over the run
    for side in sides:
        assert side[0, 0] < x.min() and side[1, 0] > x.max()
        assert abs(side[0, 1]) == pytest.approx(abs(side[1, 1])) and side[0, 1] != 0
    assert {round(float(side[0, 1]), 12) for side in sides} == \
        {round(float(sides[0][0, 1]), 12), -round(float(sides[0][0, 1]), 12)}
    apexes = [a for a, _ in supports(ax)]
    assert len(apexes) == 2 and has(apexes, np.zeros(2)) and has(apexes, Q)  # not G
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("x [m]", "y [m]")


def test_a_snapshots_instants_are_told_apart_by_a_colour_bar_of_time(loads, figures, tmp_path):
    from mechdsl.outputs.draw import snapshot

    kernels, res = solve(loads, PINNED + 'units length = "m", time = "s"\n')
    snapshot(res, kernels.system, str(tmp_path / "s.png"), at=[0, 0.5, 1])
    fig = figures[0]
    ax, bar = fig.axes
    assert bar.get_ylabel() == "t [s]"
    from matplotlib.collections import LineCollection
    colours = {tuple(np.round(c.get_edgecolor()[0], 6)) for c in ax.collections
               if isinstance(c, LineCollection) and c.get_linewidths()[0] == 3}
    assert len(colours) == 3  # one per instant


def test_labels_name_the_bodies_and_the_joints(loads, figures, tmp_path):
    from mechdsl.outputs.draw import animate, snapshot

    kernels, res = solve(loads, PINNED)
    snapshot(res, kernels.system, str(tmp_path / "s.png"), at=[0.3], labels=True)
    animate(res, kernels.system, str(tmp_path / "a.gif"), max_frames=3, labels=True)
    for fig, t in zip(figures, (0.3, 1.0)):
        texts = {a.get_text(): np.asarray(a.xy) for a in fig.axes[0].texts
                 if hasattr(a, "xy")}
        assert {"crank", "rod", "slider", "lever", "A", "B", "C", "E"} <= set(texts)
        exact = pose(t)
        np.testing.assert_allclose(texts["rod"], exact["rod"].mean(axis=0), atol=1e-9)
        np.testing.assert_allclose(texts["B"], exact["rod"][0], atol=1e-9)
    # a joint's two pins at one place are named once
    assert [a.get_text() for a in figures[0].axes[0].texts].count("B") == 1


def test_twelve_variants_of_two_params_are_each_their_own_style():
    """The seed paper's study, three ramps times four rods: the rod length's colour and the
    ramp's line style tell every variant apart; one param of twelve values is a colour map
    with its bar."""
    from mechdsl.outputs.styles import variant_styles
    from mechdsl.results import Results

    ls, t1 = np.repeat([3.5, 2.5, 2.2, 2.1], 3), np.tile([0.5, 1.0, 1.5], 4)

    def results(sweep):
        V = len(next(iter(sweep.values())))
        return Results(times=np.zeros(1), data={}, sweep=sweep, n_solved=np.ones(V, int),
                       status="ok", messages=(), solve_time=0.0, residual=0.0,
                       source_name="m.mech")
    styles = variant_styles(results({"l": ls, "t1": t1}))
    pairs = {(tuple(c), s) for c, s in zip(styles.colors, styles.linestyles)}
    assert len(pairs) == 12 and styles.colorbar is None
    assert [e[0] for e in styles.legend] == ["l = 3.5", "l = 2.5", "l = 2.2", "l = 2.1",
                                            "t1 = 0.5", "t1 = 1", "t1 = 1.5"]
    one = variant_styles(results({"l": np.linspace(2, 4, 12)}))
    assert one.colorbar[0] == "l" and one.colorbar[2:] == (2.0, 4.0)
    assert len({tuple(c) for c in one.colors}) == 12 and one.legend == []
