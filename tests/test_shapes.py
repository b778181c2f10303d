"""Body shapes: polygons and meshes, their area, centroid and polar moment against the closed
forms of a rectangle and a right triangle, and every way a shape can be wrong."""

from __future__ import annotations

import numpy as np
import pytest

from mechdsl.errors import MechError

BODY = """
body link {{
    point A = (0, 0)
    point B = (4, 0)
    {items}
}}
joint A: revolute(ground.origin, link.A)
drive d: angle(link) = t
simulate t = 0 .. 1 step 0.5
output link.phi
"""


def rectangle(x0, y0, w, h):
    """Area, centroid, polar moment about the centroid: w h, (x0 + w/2, y0 + h/2),
    w h (w^2 + h^2) / 12."""
    return w * h, (x0 + w / 2, y0 + h / 2), w * h * (w * w + h * h) / 12


def write_rectangle_mesh(path, x0, y0, w, h, nx=7, ny=3, quads=False):
    """A structured mesh of the rectangle, in any format meshio writes (by extension)."""
    import meshio

    xs, ys = np.linspace(x0, x0 + w, nx + 1), np.linspace(y0, y0 + h, ny + 1)
    pts = np.array([(x, y, 0.0) for y in ys for x in xs])
    cells = []
    for j in range(ny):
        for i in range(nx):
            a = j * (nx + 1) + i
            quad = [a, a + 1, a + nx + 2, a + nx + 1]
            cells.append(quad if quads else [quad[0], quad[1], quad[2]])
            if not quads:
                cells.append([quad[0], quad[2], quad[3]])
    meshio.write_points_cells(str(path), pts, [("quad" if quads else "triangle",
                                                 np.array(cells))])


def props(kernels, body="link"):
    return kernels.system.mass[kernels.system.body_names.index(body)]


@pytest.mark.parametrize("ext, quads", [(".vtu", False), (".msh", False), (".vtk", True)])
def test_meshed_rectangle_matches_closed_form(loads, tmp_path, ext, quads):
    mesh = tmp_path / f"plate{ext}"
    write_rectangle_mesh(mesh, 0.5, -0.25, 3.0, 0.5, quads=quads)
    text = BODY.format(items=f'shape = "{mesh.name}"\n    density = 2700')
    (tmp_path / "link.mech").write_text(text)
    import mechdsl
    kernels = mechdsl.load(tmp_path / "link.mech", registry=loads("").registry).compile()
    area, centroid, polar = rectangle(0.5, -0.25, 3.0, 0.5)
    mp = props(kernels)
    assert mp.area[0] == pytest.approx(area, rel=1e-14)
    np.testing.assert_allclose(mp.centroid[0], centroid, rtol=1e-14, atol=1e-15)
    assert mp.polar[0] == pytest.approx(polar, rel=1e-13)
    assert mp.mass[0] == pytest.approx(2700 * area, rel=1e-14)
    assert mp.inertia[0] == pytest.approx(2700 * polar, rel=1e-13)


def test_degenerate_cells_add_nothing(loads, tmp_path):
    """Cells of no area, as some mesh writers produce (a triangle written as a quad with a
    repeated vertex, a sliver on an edge), leave the properties and the outline exact."""
    import meshio

    # the square [0, 2] x [0, 1] as two quads with their last vertex repeated (triangles),
    # plus a zero-area triangle on its bottom edge
    pts = np.array([[0, 0, 0], [2, 0, 0], [2, 1, 0], [0, 1, 0], [1, 0, 0.0]])
    meshio.write_points_cells(str(tmp_path / "sq.vtu"), pts, [
        ("quad", np.array([[0, 1, 2, 2], [0, 2, 3, 3]])), ("triangle", np.array([[0, 4, 1]]))])
    (tmp_path / "link.mech").write_text(
        BODY.format(items='shape = "sq.vtu"\n    density = 2'))
    import mechdsl
    kernels = mechdsl.load(tmp_path / "link.mech", registry=loads("").registry).compile()
    area, centroid, polar = rectangle(0.0, 0.0, 2.0, 1.0)
    mp = props(kernels)
    assert mp.area[0] == pytest.approx(area, rel=1e-14)
    np.testing.assert_allclose(mp.centroid[0], centroid, rtol=1e-14)
    assert mp.polar[0] == pytest.approx(polar, rel=1e-13)
    edges = kernels.system.sketch.shapes[kernels.system.body_names.index("link")][0]
    assert len(edges) == 4  # the square's four sides, the diagonal and the sliver gone
    assert sum(np.linalg.norm(e[1] - e[0]) for e in edges) == pytest.approx(6.0)


def test_polygon_triangle_and_rectangle_in_a_sweep(loads):
    # a right triangle with legs b (swept) and 1.5, vertices clockwise: orientation must not
    # matter
    text = BODY.format(items="shape = polygon((0, 0), (0, 1.5), (b, 0))") \
        + "param b = 2\nsweep b = [2, 3]\n"
    text = "param b = 2\n" + text.replace("param b = 2\n", "")
    kernels = loads(text).compile()
    mp = props(kernels)
    for v, b in enumerate((2.0, 3.0)):
        h = 1.5
        assert mp.area[v] == pytest.approx(b * h / 2)
        np.testing.assert_allclose(mp.centroid[v], (b / 3, h / 3))
        assert mp.polar[v] == pytest.approx(b * h / 2 * (b * b + h * h) / 18)
        assert np.isnan(mp.mass[v])
    rect = loads(BODY.format(items="shape = polygon((0, -0.1), (4, -0.1), (4, 0.1), (0, 0.1))"))
    area, centroid, polar = rectangle(0, -0.1, 4, 0.2)
    mp = props(rect.compile())
    assert (mp.area[0], mp.polar[0]) == pytest.approx((area, polar))
    np.testing.assert_allclose(mp.centroid[0], centroid, atol=1e-15)


def test_check_reports_mass_properties(tmp_path):
    from test_cli import mechdsl

    path = tmp_path / "link.mech"
    path.write_text(BODY.format(items="shape = polygon((0, -0.1), (4, -0.1), (4, 0.1), "
                                      "(0, 0.1))\n    density = 10"))
    r = mechdsl("check", path)
    assert r.returncode == 0, r.stderr
    area, _, polar = rectangle(0, -0.1, 4, 0.2)
    line = next(x for x in r.stdout.splitlines() if x.strip().startswith("link") and "area" in x)
    assert f"area {area:.6g}" in line and f"J {polar:.6g}" in line
    assert f"mass {10 * area:.6g}" in line and f"inertia {10 * polar:.6g}" in line


def test_a_shaped_body_is_drawn(tmp_path):
    from PIL import Image

    from test_cli import mechdsl

    write_rectangle_mesh(tmp_path / "plate.vtu", -0.2, -0.2, 4.4, 0.4)
    path = tmp_path / "link.mech"
    path.write_text(BODY.format(items='shape = "plate.vtu"') + "trace link.B\n")
    r = mechdsl("run", path, "--snapshot", tmp_path / "s.png", "--export",
                tmp_path / "m.xdmf", "-q")
    assert r.returncode == 0, r.stderr
    with Image.open(tmp_path / "s.png") as im:
        assert im.format == "PNG"


def test_mesh_boundary_is_the_outline():
    from mechdsl.compiled.shapes import boundary

    # two triangles of a square: the diagonal is inner, the four sides are the boundary
    edges = boundary(np.array([[0, 1, 2], [0, 2, 3]]))
    assert sorted(map(tuple, edges)) == [(0, 1), (0, 3), (1, 2), (2, 3)]


def _solid_stl(path):
    import meshio

    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    meshio.write_points_cells(str(path), pts, [("triangle", np.array([[0, 1, 2], [0, 1, 3],
                                                                       [0, 2, 3], [1, 2, 3]]))])


def _lines_only(path):
    import meshio

    meshio.write_points_cells(str(path), np.array([[0, 0, 0], [1, 0, 0.0]]),
                              [("line", np.array([[0, 1]]))])


@pytest.mark.parametrize("make, items, message", [
    (None, 'shape = "missing.msh"', "no such file"),
    (_solid_stl, 'shape = "solid.stl"', "not planar"),
    (_lines_only, 'shape = "lines.vtu"', "no triangles or quads"),
    (None, "shape = polygon((0, 0), (1, 0))", "at least three vertices"),
    (None, "shape = polygon((0, 0), (1, 0), (2, 0))", "has no area"),
    (None, "shape = polygon((0, 0), (1, 0), (0, 1))\n shape = polygon((0, 0), (1, 0), (0, 1))",
     "two shapes"),
    (None, "density = 3", "a density but no shape"),
    (None, "shape = polygon((0, 0), (1, 0), (0, 1))\n density = -1", "must be positive"),
])
def test_bad_shapes_are_located_errors(tmp_path, make, items, message):
    import mechdsl

    if make is not None:
        make(tmp_path / items.split('"')[1])
    path = tmp_path / "bad.mech"
    path.write_text(BODY.format(items=items))
    with pytest.raises(MechError) as err:
        mechdsl.load(path).compile()
    assert message in str(err.value)
    assert err.value.span is not None


def test_shape_outline_is_exported(tmp_path):
    import meshio

    from test_cli import mechdsl

    path = tmp_path / "link.mech"
    path.write_text(BODY.format(items="shape = polygon((0, -0.1), (4, -0.1), (4, 0.1), "
                                      "(0, 0.1))"))
    r = mechdsl("run", path, "--export", tmp_path / "m.vtu", "-q")
    assert r.returncode == 0, r.stderr
    mesh = meshio.read(tmp_path / "m_0002.vtu")  # t = 1: the link turned by 1 rad
    c, s = np.cos(1.0), np.sin(1.0)
    corner = np.array([4 * c + 0.1 * s, 4 * s - 0.1 * c])  # (4, -0.1) rotated
    assert np.min(np.linalg.norm(mesh.points[:, :2] - corner, axis=1)) < 1e-12
    # the bar A-B and the four edges of the shape; the ground's one point is a vertex cell
    assert [(c.type, len(c.data)) for c in mesh.cells] == [("line", 1 + 4), ("vertex", 1)]
