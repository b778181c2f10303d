"""Centrodes drawn as traces (``trace ic(A, B)``, issue 30), against closed forms:

* the elliptic trammel (a rod of length L whose ends slide on the x and y axes): its instant
  centre is (-L cos phi, L sin phi), the fixed centrode the circle of radius L about the
  origin, the moving centrode the circle of radius L/2 about the rod's middle (the Cardan
  circles), at the angle pi - 2 phi in the rod's frame;
* the four-bar: the coupler's instant centre lies on the crank's line and on the rocker's
  (Kennedy's theorem), and its curves break where the coupler's angular velocity changes
  sign (the centre passes through infinity);
* drawn in snapshots, animations, DXF and SVG, and in the live view's message.
"""

from __future__ import annotations

import numpy as np
import pytest

from conftest import EXAMPLES
from test_cli import mechdsl

L = 2.0
TRAMMEL = f"""
param L = {L}
ground {{ }}
body rod {{ guess = (-0.8, 0.5, 0.6)  point A = (-L/2, 0)  point B = (L/2, 0) }}
joint on_x: pin_slot(ground.origin, rod.A, axis = (1, 0))
joint on_y: pin_slot(ground.origin, rod.B, axis = (0, 1))
drive turn: angle(rod) = pi/6 + t
simulate t = 0 .. 1 step 0.01
units length = "m", time = "s"
output rod.phi
trace ic(rod, ground), rod.A
"""
FOURBAR = (EXAMPLES / "fourbar.mech").read_text() + "\ntrace ic(coupler, ground)\n"


def _run(loads, text: str):
    from mechdsl.outputs.draw import frames
    from mechdsl.solve import simulate

    kernels = loads(text).compile()
    res = simulate(kernels, poses=True, rates=True)
    return kernels, res, frames(res, kernels.system)


def test_the_trammels_centrodes_are_the_cardan_circles(loads):
    _, res, fr = _run(loads, TRAMMEL)
    (c,) = fr.centrodes
    phi = np.pi / 6 + res["t"]
    np.testing.assert_allclose(res["rod.phi"], phi, atol=1e-12)
    exact = np.stack((-L * np.cos(phi), L * np.sin(phi)), axis=-1)
    np.testing.assert_allclose(c.centre[0], exact, atol=1e-12)
    # no break: omega = 1 throughout, so the curves are the instants themselves
    assert c.fixed.shape[1] == c.moving.shape[1] == len(phi)
    np.testing.assert_allclose(np.linalg.norm(c.fixed[0], axis=-1), L, atol=1e-12)
    moving = L / 2 * np.stack((-np.cos(2 * phi), np.sin(2 * phi)), axis=-1)
    np.testing.assert_allclose(c.moving[0], moving, atol=1e-12)
    # at every instant both curves, carried by their frames, pass through the centre, where
    # they touch: their tangents there are parallel (the moving one rolls on the fixed)
    for k in (0, 37, 100):
        fixed_w, moving_w = c.at(0, k)
        np.testing.assert_allclose(fixed_w[k], exact[k], atol=1e-12)
        np.testing.assert_allclose(moving_w[k], exact[k], atol=1e-12)
        if k in (0, 100):
            continue
        tf, tm = fixed_w[k + 1] - fixed_w[k - 1], moving_w[k + 1] - moving_w[k - 1]
        assert abs(tf[0] * tm[1] - tf[1] * tm[0]) < 1e-3 * np.linalg.norm(tf) ** 2


def test_the_four_bars_instant_centre_is_where_crank_and_rocker_lines_meet(loads):
    """Kennedy: I(coupler, ground) is on the line O2-A (crank) and on O4-B (rocker)."""
    from mechdsl.outputs.draw import world

    kernels, res, fr = _run(loads, FOURBAR)
    (c,) = fr.centrodes
    names = list(kernels.system.body_names)
    sk = kernels.system.sketch
    crank_a = world(res.poses, names.index("crank"), sk.outlines[names.index("crank")][:, 1])
    rocker_b = world(res.poses, names.index("rocker"), sk.outlines[names.index("rocker")][:, 0])
    o2, o4 = np.array([0.0, 0.0]), np.array([4.0, 0.0])

    def off_line(p, q, r):  # distance of r from the line through p and q
        d, e = q - p, r - p
        return np.abs(d[..., 0] * e[..., 1] - d[..., 1] * e[..., 0]) / np.linalg.norm(d, axis=-1)

    ic = c.centre[0]
    near = np.linalg.norm(ic, axis=-1) < 100  # far off, round-off in omega grows
    assert near.sum() > 900
    assert off_line(o2, crank_a[0], ic)[near].max() < 1e-9
    assert off_line(o4, rocker_b[0], ic)[near].max() < 1e-9
    # one break (a NaN row) per sign change of the coupler's angular velocity
    w = res.rates[0, :, 0, names.index("coupler"), 2]
    changes = int((w[:-1] * w[1:] < 0).sum())
    assert changes == 2
    assert c.fixed.shape[1] == len(w) + changes
    assert int(np.isnan(c.fixed[0]).any(axis=1).sum()) == changes


def test_the_rod_of_the_slider_crank_relative_to_the_crank_turns_about_their_pin(loads):
    """Relative to the crank, the rod's instant centre is their common pin B: the fixed
    centrode (in the crank's frame) is the one point B' = (r/2, 0), the moving one (in the
    rod's) the one point (-l/2, 0)."""
    text = (EXAMPLES / "slider_crank.mech").read_text() + "\ntrace ic(rod, crank)\n"
    _, res, fr = _run(loads, text)
    (c,) = fr.centrodes
    np.testing.assert_allclose(c.fixed[0], np.broadcast_to([1.0, 0.0], c.fixed[0].shape),
                               atol=1e-9)
    np.testing.assert_allclose(c.moving[0], np.broadcast_to([-1.75, 0.0], c.moving[0].shape),
                               atol=1e-9)


@pytest.mark.parametrize("trace, message, at", [
    ("ic(rod, nobody)", "unknown body 'nobody'", len("ic(rod, ")),  # at the name
    ("centre(rod, ground)", "'centre' cannot be traced; trace body.P (a point's path) or "
                            "ic(A, B)", 0),
    ("ic(rod, rod)", "the centrodes of 'rod' relative to itself", 0),
])
def test_a_wrong_centrode_is_a_located_error(loads, trace, message, at):
    from mechdsl.errors import MechError

    text = TRAMMEL.replace("trace ic(rod, ground), rod.A", f"trace rod.A, {trace}")
    with pytest.raises(MechError) as err:
        loads(text).compile()
    assert message in str(err.value)
    line = text.splitlines().index(f"trace rod.A, {trace}") + 1
    assert err.value.span is not None and err.value.span.line == line
    assert err.value.span.column == len("trace rod.A, ") + 1 + at


def test_centrodes_drawn_by_the_command_line(tmp_path):
    """--trace ic(A,B) on the command line as in the file; a snapshot, an animation, an SVG
    and a DXF whose centrodes read back lie on the Cardan circles."""
    import xml.etree.ElementTree as ET

    import ezdxf
    from PIL import Image

    f = tmp_path / "trammel.mech"
    f.write_text(TRAMMEL.replace("trace ic(rod, ground), rod.A", "trace rod.A"))
    out = tmp_path / "o.csv"
    r = mechdsl("run", str(f), "-o", str(out), "--trace", "ic(rod,ground)",
                "--snapshot", str(tmp_path / "s.png"), "--animate", str(tmp_path / "a.gif"),
                "--frames", "5", "--export", str(tmp_path / "e.svg"), "--at", "0.5")
    assert r.returncode == 0, r.stderr
    assert Image.open(tmp_path / "s.png").size[0] > 400
    assert Image.open(tmp_path / "a.gif").n_frames == 5
    svg = ET.parse(tmp_path / "e.svg").getroot()
    curves = {p.get("data-centrode"): np.array([[float(v) for v in xy.split(",")]
                                                for xy in p.get("points").split()])
              for p in svg.iter("{http://www.w3.org/2000/svg}polyline")
              if p.get("data-centrode") is not None}
    fixed, moving = curves["fixed centrode of ic(rod, ground)"], \
        curves["moving centrode of ic(rod, ground)"]
    np.testing.assert_allclose(np.linalg.norm(fixed, axis=1), L, atol=1e-12)
    # the moving circle at t = 0.5, carried by the rod: radius L/2 about its middle
    phi = np.pi / 6 + 0.5
    middle = np.array([-L / 2 * np.cos(phi), L / 2 * np.sin(phi)])
    np.testing.assert_allclose(np.linalg.norm(moving - middle, axis=1), L / 2, atol=1e-12)

    r = mechdsl("run", str(f), "-o", str(out), "--trace", "ic(rod,ground)",
                "--export", str(tmp_path / "e.dxf"))
    assert r.returncode == 0, r.stderr
    doc = ezdxf.readfile(tmp_path / "e.dxf")
    labelled = [e for e in doc.modelspace().query("LWPOLYLINE")
                if e.has_xdata("MECHDSL")
                and "centrode" in str(e.get_xdata("MECHDSL")[0].value)]
    assert any(e.dxf.layer == "paths" for e in labelled)
    fixed = np.array([p[:2] for e in labelled if e.dxf.layer == "paths"
                      for p in e.get_points()])
    np.testing.assert_allclose(np.linalg.norm(fixed, axis=1), L, atol=1e-12)

    r = mechdsl("run", str(f), "-o", str(out), "--trace", "ic(rod,nobody)")
    assert r.returncode == 1 and "--trace:1:8: error: unknown body 'nobody'" in r.stderr
    assert "Traceback" not in r.stderr


def test_the_view_message_carries_the_centrodes(loads):
    from mechdsl.solve import simulate
    from mechdsl.outputs.payload import decode, run_message

    kernels = loads(TRAMMEL).compile()
    res = simulate(kernels, poses=True, rates=True)
    header, data = decode(run_message(kernels.system, res, [], file="t.mech"))
    (item,) = [i for i in header["items"] if i["kind"] == "centrode"]
    assert item["ground"] and item["m"] == len(res.times)
    fixed = data[item["fixed"]: item["fixed"] + 2 * item["m"]].reshape(-1, 2)
    np.testing.assert_allclose(np.linalg.norm(fixed, axis=1), L, atol=1e-12)
    # the drawing's bounds take in the centres (on the circle of radius L)
    x0, y0, x1, y1 = header["bounds"]
    assert x0 <= -L * np.cos(np.pi / 6 + 1) + 1e-9 and y1 >= L * np.sin(np.pi / 6 + 1) - 1e-9


def test_a_sweep_draws_each_variants_centrodes(tmp_path):
    f = tmp_path / "trammel.mech"
    f.write_text(TRAMMEL + "sweep L = [1.5, 2]\n")
    r = mechdsl("run", str(f), "-o", str(tmp_path / "o.csv"), "--snapshot",
                str(tmp_path / "s.png"), "--export", str(tmp_path / "e.svg"), "--at", "0.5")
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "e_v0.svg").exists() and (tmp_path / "e_v1.svg").exists()


def test_the_api_traces_what_the_command_line_traces(tmp_path):
    """simulate(trace=...) takes --trace's text: the centrodes drawn by the API's snapshot
    are the Cardan circles, and a mistake is located in the text given, as on the command
    line."""
    import mechdsl
    from mechdsl.errors import MechError
    from mechdsl.outputs import FORMATS
    from mechdsl.outputs.draw import frames

    mech = mechdsl.loads(TRAMMEL.replace("trace ic(rod, ground), rod.A", ""), "trammel.mech")
    res = mech.simulate(trace=["ic(rod, ground)", "rod.A"], poses=True, rates=True)
    kernels = mech.tracing(["ic(rod, ground)", "rod.A"]).compile()
    (c,) = frames(res, kernels.system).centrodes
    np.testing.assert_allclose(np.linalg.norm(c.fixed[0], axis=-1), L, atol=1e-12)
    FORMATS["snapshot"].write(res, kernels.system, str(tmp_path / "s.png"))
    assert (tmp_path / "s.png").stat().st_size > 0
    with pytest.raises(MechError) as err:
        mech.simulate(trace="rod.A, ic(rod, nobody)")
    # located at the unknown name, not the whole call
    assert err.value.source.name == "--trace" and err.value.span.column == 16
    assert "unknown body 'nobody'" in str(err.value)


def test_a_body_that_only_translates_has_no_centrode_drawn(loads):
    """The parallelogram's coupler translates: omega is round-off (1e-14), its instant
    centre at infinity throughout; no point, no piece of curve is drawn for it."""
    from mechdsl.compiled.variants import Overrides
    from mechdsl.outputs.draw import frames
    from mechdsl.solve import simulate

    text = (EXAMPLES / "parallelogram.mech").read_text() + "\ntrace ic(coupler, ground)\n"
    kernels = loads(text).compile(Overrides(t1=0.2))
    res = simulate(kernels, poses=True, rates=True)
    (c,) = frames(res, kernels.system).centrodes
    assert np.abs(res.rates[0, :, 0, kernels.system.body_names.index("coupler"), 2]).max() < 1e-9
    assert not np.isfinite(c.centre).any() and not np.isfinite(c.fixed).any()


def test_the_drawn_instant_centre_is_the_ic_output(loads):
    """The centre the drawings compute from the run's poses and rates
    (centrodes.instant_centre) is the one the expression functions ic_x, ic_y give as
    outputs (the motion functions' symbolic form): the two are written apart, in numpy and
    in expressions, and must agree, on the four-bar's coupler (whose centre moves far
    away) relative to the ground and to the crank."""
    from mechdsl.outputs.centrodes import instant_centre

    text = (EXAMPLES / "fourbar.mech").read_text() + (
        "\noutput gx = ic_x(coupler, ground), gy = ic_y(coupler, ground), "
        "cx = ic_x(coupler, crank), cy = ic_y(coupler, crank)\n")
    kernels = loads(text).compile()
    from mechdsl.solve import simulate

    res = simulate(kernels, poses=True, rates=True)
    names = kernels.system.body_names
    for other, (x, y) in (("ground", ("gx", "gy")), ("crank", ("cx", "cy"))):
        b = len(names) if other == "ground" else names.index(other)
        centre, _ = instant_centre(res.poses, res.rates, names.index("coupler"), b)
        expected = np.stack((res[x], res[y]), axis=-1)
        finite = np.isfinite(centre[0]).all(axis=-1)
        assert finite.sum() > 0.9 * len(res["t"])
        scale = np.maximum(1.0, np.linalg.norm(expected[finite], axis=-1))[:, None]
        np.testing.assert_allclose(centre[0][finite] / scale, expected[finite] / scale,
                                   rtol=0, atol=1e-9)
