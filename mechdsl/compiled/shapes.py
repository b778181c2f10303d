"""Body shapes and their mass properties: area, centroid and polar moment of area.

For a polygon with vertices p_i = (x_i, y_i), i = 0..n-1 (p_n = p_0), and c_i = x_i y_(i+1) -
x_(i+1) y_i (Green's theorem; exact):

    A    = 1/2  sum c_i
    x_c  = 1/(6A)  sum (x_i + x_(i+1)) c_i,      y_c likewise
    I_x  = 1/12 sum (y_i^2 + y_i y_(i+1) + y_(i+1)^2) c_i     (= integral of y^2 dA)
    I_y  = 1/12 sum (x_i^2 + x_i x_(i+1) + x_(i+1)^2) c_i     (= integral of x^2 dA)
    J_O  = I_x + I_y,   J_c = J_O - A |r_c|^2    (polar moment about the centroid)

A mesh is the sum of its triangles (each a polygon of three vertices), so its properties are
exact for straight-sided shapes too. With a density rho (mass per area): m = rho A and the
moment of inertia about the centroid is rho J_c.
"""

from __future__ import annotations

import contextlib
import io
import os
import pathlib
import warnings
from dataclasses import dataclass

import numpy as np

from .. import reading
from ..errors import MechError, Span, cut, listing
from ..grammar.model import Body, Polygon
from ..reading import check_data
from .variants import Variants


@dataclass(frozen=True)
class MeshShape:
    """A planar mesh read from a file: points (N, 2) and triangles (T, 3)."""

    path: str
    points: np.ndarray
    triangles: np.ndarray
    span: Span | None = None


@dataclass(frozen=True)
class MassProperties:
    """Per variant: area A, centroid (x_c, y_c) in the body frame, polar moment of area J_c
    about the centroid; mass and moment of inertia where a density is given (else NaN)."""

    area: np.ndarray
    centroid: np.ndarray
    polar: np.ndarray
    mass: np.ndarray
    inertia: np.ndarray


def polygon_properties(xy: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(A, centroid (..., 2), J_c) of polygons ``xy`` (..., n, 2) by the formulas above; the
    vertices may turn either way (the area is then taken positive)."""
    x, y = xy[..., 0], xy[..., 1]
    x1, y1 = np.roll(x, -1, axis=-1), np.roll(y, -1, axis=-1)
    c = x * y1 - x1 * y
    area = 0.5 * c.sum(axis=-1)
    with np.errstate(invalid="ignore", divide="ignore"):  # a degenerate polygon: NaN centroid
        cx = ((x + x1) * c).sum(axis=-1) / (6 * area)
        cy = ((y + y1) * c).sum(axis=-1) / (6 * area)
    ix = ((y * y + y * y1 + y1 * y1) * c).sum(axis=-1) / 12
    iy = ((x * x + x * x1 + x1 * x1) * c).sum(axis=-1) / 12
    sign = np.sign(area)  # clockwise vertices give negative signed integrals
    area, j_o = sign * area, sign * (ix + iy)
    return area, np.stack((cx, cy), axis=-1), j_o - area * (cx * cx + cy * cy)


def mesh_properties(points: np.ndarray, triangles: np.ndarray
                    ) -> tuple[float, np.ndarray, float]:
    """(A, centroid (2,), J_c) of a triangle mesh: the sums over its triangles."""
    a, c, j = polygon_properties(points[triangles])  # no cell of no area: see read_mesh
    area = float(a.sum())
    centroid = (a[:, None] * c).sum(axis=0) / area
    # each triangle's J about its own centroid, moved to the shape's centroid (parallel axes)
    polar = float((j + a * ((c - centroid) ** 2).sum(axis=1)).sum())
    return area, centroid, polar


def boundary(triangles: np.ndarray) -> np.ndarray:
    """The edges (E, 2) that belong to one triangle only: the outline of a mesh."""
    edges = np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]],
                                    triangles[:, [2, 0]]]), axis=1)
    unique, counts = np.unique(edges, axis=0, return_counts=True)
    return unique[counts == 1]


#: meshio formats refused for a shape: they make meshio read files the model does not name
#: (XDMF's data files, Abaqus' *INCLUDE, TetGen's sibling file, HDF5's external links), which
#: could be a FIFO, a device or anybody's file, beyond the checks of :mod:`mechdsl.reading`.
FORMATS_READING_OTHER_FILES = frozenset(
    {"xdmf", "abaqus", "tetgen", "h5m", "hmf", "med", "cgns", "exodus", "dolfin-xml"})


def read_mesh(path: str, base_dir: str, span: Span | None) -> MeshShape:
    """Read a planar mesh with meshio (Gmsh, VTK/VTU, OBJ, ... most of what meshio reads): its
    triangles, and its quads split in two. A mesh that does not lie in the plane z = 0 (an
    STL of a solid, say) is refused: a body's shape is planar.

    The file is read as data (:mod:`mechdsl.reading`: a regular file within
    :data:`~mechdsl.reading.MAX_DATA_BYTES`); formats that would read other files, and
    compressed ones, are refused. What meshio prints is discarded (standard output may be
    the CSV stream), and whatever it raises, ``sys.exit`` included, becomes a located error
    naming the format and the kind of failure only: some readers' messages quote the file.
    """
    import meshio

    shown = cut(path)
    full = path if os.path.isabs(path) else os.path.join(base_dir, path)
    if not os.path.lexists(full):
        raise MechError(f"cannot read the shape {shown}: no such file (looked for "
                        f"{cut(full, 200)})", span)
    check_data(full, "the shape ", "MAX_DATA_BYTES", span, shown=shown)
    formats = _formats(full, meshio.extension_to_filetypes)
    if not formats:
        raise MechError(f"cannot read the shape {shown}: its extension names no mesh format "
                        "meshio reads (.msh, .vtu, .vtk, .obj, .stl, ...)", span)
    refused = sorted(set(formats) & FORMATS_READING_OTHER_FILES)
    if refused or full.lower().endswith(".gz"):
        why = (f"{refused[0]} files can make meshio read other files" if refused else
               "a compressed file can expand without bound")
        raise MechError(f"cannot read the shape {shown}: {why}; convert the mesh to a "
                        "single plain file (.msh, .vtu, .obj, ...)", span)
    sink = _Discard()
    try:
        with np.errstate(all="ignore"), warnings.catch_warnings(), \
                contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink), \
                _bounded_inflation(reading.MAX_DATA_BYTES):
            warnings.simplefilter("ignore")  # numpy's, in meshio's format sniffing
            mesh = meshio.read(full)
    except (Exception, SystemExit) as err:  # noqa: BLE001 - any failure of a reader
        raise MechError(f"cannot read the shape {shown}: it is not a mesh meshio can read as "
                        f"{' or '.join(formats)} ({type(err).__name__})", span) from None
    pts = np.asarray(mesh.points, dtype=float)
    if pts.ndim != 2 or pts.shape[1] not in (2, 3) or not len(pts):
        raise MechError(f"the shape {shown} has no points", span)
    if not np.isfinite(pts).all():
        raise MechError(f"the shape {shown} has points that are not finite numbers", span)
    if pts.shape[1] == 3:
        extent = float(np.ptp(pts[:, :2], axis=0).max()) or 1.0
        if np.abs(pts[:, 2]).max() > 1e-9 * extent:
            raise MechError(f"the shape {shown} is not planar (its points leave the plane z = 0): "
                            "a body's shape is a 2-D mesh; projecting a 3-D one is not done "
                            "for you", span)
    tris = [c.data for c in mesh.cells if c.type == "triangle"]
    tris += [q[:, [0, 1, 2]] for q in (c.data for c in mesh.cells if c.type == "quad")]
    tris += [q[:, [0, 2, 3]] for q in (c.data for c in mesh.cells if c.type == "quad")]
    if not tris:
        raise MechError(f"the shape {shown} has no triangles or quads (cells: "
                        f"{listing(sorted({c.type for c in mesh.cells})) or 'none'})", span)
    triangles = np.concatenate(tris).astype(np.int64)
    if len(triangles) and (triangles.min() < 0 or triangles.max() >= len(pts)):
        raise MechError(f"the shape {shown} has cells made of points it does not have", span)
    # cells of no area (a triangle written as a quad with a repeated vertex, say) add nothing
    # to the shape but would make its centroid 0/0 and hide edges of its outline
    xy = pts[:, :2]
    extent = float(np.ptp(xy, axis=0).max()) or 1.0
    p0, p1, p2 = (xy[triangles[:, k]] for k in range(3))
    doubled = np.abs((p1[:, 0] - p0[:, 0]) * (p2[:, 1] - p0[:, 1])
                     - (p1[:, 1] - p0[:, 1]) * (p2[:, 0] - p0[:, 0]))
    triangles = triangles[doubled > 1e-12 * extent * extent]
    if not len(triangles):
        raise MechError(f"the shape {shown} has no area: all its cells are degenerate", span)
    return MeshShape(path, xy.copy(), triangles, span)


@contextlib.contextmanager
def _bounded_inflation(limit: int):
    """While the block runs, zlib.decompress and lzma.decompress (with which meshio inflates
    the compressed blocks of VTK XML files) give at most ``limit`` bytes in all, then raise:
    a small file must not expand into gigabytes."""
    import lzma
    import zlib

    left = [limit]

    def take(out: bytes, more: bool) -> bytes:
        left[0] -= len(out)
        if left[0] < 0 or more:
            raise ValueError(f"compressed data expanding beyond {limit} bytes")
        return out

    def inflate(data, *args, **kwargs):
        d = zlib.decompressobj(*args[:1])
        out = d.decompress(data, left[0] + 1)
        return take(out, bool(d.unconsumed_tail))

    def unxz(data, *args, **kwargs):
        d = lzma.LZMADecompressor()
        out = d.decompress(data, max_length=left[0] + 1)
        return take(out, not d.eof and not d.needs_input)

    saved = zlib.decompress, lzma.decompress
    zlib.decompress, lzma.decompress = inflate, unxz
    try:
        yield
    finally:
        zlib.decompress, lzma.decompress = saved


class _Discard(io.TextIOBase):
    """A text stream that drops what is written to it (and keeps no copy)."""

    def write(self, text: str) -> int:
        return len(text)


def _formats(path: str, by_extension: dict[str, list[str]]) -> list[str]:
    """The meshio formats of a file name, as meshio deduces them (all its suffixes)."""
    ext, out = "", []
    for suffix in reversed(pathlib.Path(path).suffixes):
        ext = (suffix + ext).lower()
        out += by_extension.get(ext, [])
    return out


def _readonly(a) -> np.ndarray:
    a = np.ascontiguousarray(a, dtype=float)
    a.flags.writeable = False
    return a


def _vertices(body: Body, var: Variants) -> np.ndarray:
    """The vertices (V, n, 2) of a body's polygon shape, for every sweep variant."""
    return np.stack([var.vector(v, f"a vertex of the shape of {body.name}")
                     for v in body.shape.vertices], axis=1)


def shape_edges(body: Body, var: Variants) -> np.ndarray | None:
    """The edges (V, E, 2, 2) of a body's shape outline in its frame (None without a shape):
    a polygon's sides, or the edges of a mesh that belong to one triangle only."""
    if body.shape is None:
        return None
    if isinstance(body.shape, Polygon):
        xy = _vertices(body, var)
        return _readonly(np.stack((xy, np.roll(xy, -1, axis=1)), axis=2))
    edges = body.shape.points[boundary(body.shape.triangles)]  # (E, 2, 2)
    return _readonly(np.broadcast_to(edges, (var.count,) + edges.shape))


def mass_properties(body: Body, var: Variants) -> MassProperties | None:
    """Area, centroid and polar moment of a body's shape, and mass and inertia from its
    density, for every sweep variant (``var``: the evaluated params); None without a shape."""
    if body.shape is None:
        return None
    V = var.count
    if isinstance(body.shape, Polygon):
        area, centroid, polar = polygon_properties(_vertices(body, var))
    else:
        a, c, j = mesh_properties(body.shape.points, body.shape.triangles)
        area, centroid, polar = np.full(V, a), np.broadcast_to(c, (V, 2)), np.full(V, j)
    if not np.all(area > 0):
        raise MechError(f"the shape of {body.name} has no area", body.shape.span)
    rho = (var.values(body.density, f"the density of {body.name}", body.density.span)
           if body.density is not None else np.full(V, np.nan))
    if body.density is not None and not np.all(rho > 0):
        raise MechError(f"the density of {body.name} must be positive", body.density.span)
    return MassProperties(*(_readonly(x) for x in
                            (area, centroid, polar, rho * area, rho * polar)))
