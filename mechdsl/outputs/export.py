"""Results as meshes for ParaView and other VTK tools, written with meshio.

Every body becomes cells through the points it is drawn through
(:func:`mechdsl.outputs.draw.outlines`: the points it declares and those a joint or drive
attaches, its origin included): one line segment for a bar, the closed loop of edges for a
plate, the segments between successive points for the ground, a vertex cell for a body of
one point; and line cells along the outline of its shape, if it has one. Every point carries
its velocity and acceleration
(rd^P = rd + phid B s', rdd^P = rdd + phidd B s' - phid^2 A s', Haug eq. 2.6.4 differentiated)
and every cell the index of its body (-1 for the ground), so that ParaView can colour the
mechanism by speed or by body.

* ``.xdmf``: one time series (meshio's TimeSeriesWriter, the data inline as XML). XDMF keeps
  one geometry for the series, so the points are those at t0 and each instant carries
  ``position`` (and ``displacement`` from t0, for ParaView's Warp By Vector) as point data.
  With vertex cells
  besides the lines the topology is XDMF's "Mixed" one, each cell its type, its number of
  points and its points (Polyvertex 1, 1, p; Polyline 2, 2, a, b), as ParaView reads it
  (meshio's XDMF reader expects no count for a vertex, and cannot read it back).
* ``.vtu``: one file per instant, ``NAME_0000.vtu``, ``NAME_0001.vtu``, ..., with the points
  where they are at that instant, and ``NAME.pvd``, the index ParaView opens as a series.

With a sweep, every variant gets its own files: ``NAME_v0.xdmf``, ``NAME_v1.xdmf``, ...
(``NAME_v0_0000.vtu``, ``NAME_v0.pvd``, ...); :func:`series` tells these names.

Every file is written atomically (:func:`mechdsl.writing.atomic_path`), the XDMF with its data
inline (no companion ``.h5`` file); the files of a series are written one after the other, so
an interrupted ``.vtu`` export leaves the instants written so far, each file whole, and the
``.pvd`` index, written last, of the previous export if there was one.
"""

from __future__ import annotations

import os
import re
from typing import Callable

import numpy as np

from ..compiled.system import System
from ..results import Results
from ..writing import atomic_path, write_text
from . import FORMATS


def _variant_stem(stem: str, v: int, n_variants: int) -> str:
    return stem if n_variants == 1 else f"{stem}_v{v}"


def _vtu_name(stem: str, k: int) -> str:
    return f"{stem}_{k:04d}.vtu"


#: the exports of one file per variant (the others: a .vtu per instant and a .pvd index)
SINGLE = (".xdmf", ".dxf", ".svg")


def series(path: str, n_variants: int, n_instants: int) -> Callable[[str], bool]:
    """Whether a file name (in the folder of ``path``) is one :func:`export` may write for
    ``path`` with ``n_variants`` variants of ``n_instants`` instants at most."""
    stem, ext = os.path.splitext(os.path.basename(path))
    ext = ext.lower()
    variant = "" if n_variants == 1 else r"_v(?P<v>\d+)"
    if ext in SINGLE:
        pattern = re.compile(re.escape(stem) + variant + re.escape(ext))
    else:
        pattern = re.compile(re.escape(stem) + variant + r"(?:_(?P<k>\d+)\.vtu|\.pvd)")

    def member(name: str) -> bool:
        m = pattern.fullmatch(name)
        if m is None:
            return False
        v, k = m.groupdict().get("v"), m.groupdict().get("k")
        if v is not None and not (str(int(v)) == v and int(v) < n_variants):
            return False
        return k is None or (f"{int(k):04d}" == k and int(k) < n_instants)

    return member


def written_files(path: str, n_solved, ks=None) -> list[list[str]]:
    """The files :func:`export` writes for ``path``, per variant, given the number of
    instants each variant solved (none for a variant that solved none) and the instants
    exported (``ks``, indices into the run's; None: all)."""
    stem, ext = os.path.splitext(path)
    names = []
    for v, k in enumerate(int(k) for k in n_solved):
        name = _variant_stem(stem, v, len(n_solved))
        chosen = range(k) if ks is None else [i for i in ks if i < k]
        if k == 0 or not len(chosen):
            names.append([])
        elif ext.lower() in SINGLE:
            names.append([name + ext])
        else:
            names.append([*(_vtu_name(name, i) for i in chosen), name + ".pvd"])
    return names


def options(settings: dict, path: str) -> dict:
    """The export's keywords from the run's settings (:func:`mechdsl.outputs.settings`): the
    instants ``at``, else ``frames`` at most (default: the animation's for meshes, a
    snapshot's six for a drawing, .dxf or .svg)."""
    from .draw import MAX_FRAMES

    frames = settings["frames"]
    if frames is None and not path.lower().endswith((".dxf", ".svg")):
        frames = MAX_FRAMES
    return {"at": settings["at"], "max_frames": frames}


def memory(system: System, path: str, settings: dict) -> dict[str, int]:
    """What the export adds to the run: meshio, and the positions, velocities and
    accelerations of every exported point at every instant of one variant (with one
    temporary copy); for XDMF, whose XML meshio builds whole, about 25 characters per number
    held four times over."""
    sk = system.sketch
    K = len(system.times)
    points = sum(2 * o.shape[1] for o in sk.outlines)
    points += sum(4 * e.shape[1] for e in sk.shapes if e is not None)
    size = 2 * 9 * 8 * K * points
    if path.lower().endswith(".xdmf"):
        size += 4 * 25 * 9 * K * points
    return {"import meshio": 0, "the export": size}


def summary(results: Results, path: str, settings: dict) -> str:
    """The line ``mechdsl run`` prints of the export written to ``path``: its instants and
    files."""
    ks = export_instants(results, path, **options(settings, path))
    per_variant = [f for f in written_files(path, results.n_solved, ks) if f]
    count = sum(len(f) for f in per_variant)
    names = "; ".join(_file_range(f) for f in per_variant)
    instants = int(sum(int((ks < k).sum()) for k in results.n_solved))
    what = (f"{len(per_variant)} variants ({instants} instants)" if results.sweep
            else f"{instants} instants")
    return (f"{path}: export of {what} in {count} file{'s' if count != 1 else ''}"
            + ("" if names == path else f": {names}"))


def _file_range(names: list[str]) -> str:
    """'a_0000.vtu .. a_0100.vtu and a.pvd' for a .vtu series, the name of a lone file."""
    if len(names) <= 2:
        return " and ".join(names)
    return f"{names[0]} .. {names[-2]} and {names[-1]}"


def export_instants(results: Results, path: str, at: list[float] | None = None,
                    max_frames: int | None = None) -> np.ndarray:
    """The instants an export writes (indices into the run's): those nearest the times
    ``at``; else ``max_frames`` at most, evenly spread (:func:`mechdsl.outputs.draw.frame_count`'s
    rule); else every instant solved, except a drawing (.dxf, .svg), which gets a snapshot's
    six."""
    from .draw import _instants, snapshot_instants

    if at:
        return snapshot_instants(results, at)
    if max_frames is None and os.path.splitext(path)[1].lower() in (".dxf", ".svg"):
        return snapshot_instants(results)
    if max_frames is None:
        return np.arange(int(results.n_solved.max(initial=0)))
    return _instants(results, max_frames)


def _layout(system: System) -> tuple[list[tuple[int, np.ndarray]], list, list]:
    """Which body and body-frame point each exported point is ((body, (V, 2)) per point), the
    cell blocks and the body index of each cell, per block. The points of each body are
    those it is drawn through (:func:`mechdsl.outputs.draw.outlines`), so that every point a joint
    or drive attaches is in its cells. A bar is one line segment, a plate the closed loop of
    its edges, the ground the segments between its successive points, a body (or a ground)
    of one point a vertex cell: no line cell has zero length."""
    from .draw import outlines

    sk = system.sketch
    nb = system.n_bodies
    owners: list[tuple[int, np.ndarray]] = []
    segments: list[list[int]] = []
    segment_body: list[int] = []
    vertices: list[list[int]] = []
    vertex_body: list[int] = []
    for i, outline in enumerate(outlines(sk)):
        start = len(owners)
        P = outline.shape[1]
        owners.extend((i, outline[:, p]) for p in range(P))
        index = i if i < nb else -1
        if P == 1:
            vertices.append([start])
            vertex_body.append(index)
        else:
            if P == 2 or i == nb:
                pairs = [(a, a + 1) for a in range(P - 1)]
            else:
                pairs = [(a, (a + 1) % P) for a in range(P)]
            segments.extend([start + a, start + b] for a, b in pairs)
            segment_body.extend([index] * len(pairs))
        edges = sk.shapes[i] if sk.shapes else None
        if edges is not None:  # the shape's outline: a segment per edge
            start = len(owners)
            for e in range(edges.shape[1]):
                owners.extend([(i, edges[:, e, 0]), (i, edges[:, e, 1])])
                segments.append([start + 2 * e, start + 2 * e + 1])
            segment_body.extend([index] * edges.shape[1])
    blocks = [("line", np.array(segments, dtype=np.int64).reshape(-1, 2))]
    bodies = [np.array(segment_body, dtype=np.int64)]
    if vertices:
        blocks.append(("vertex", np.array(vertices, dtype=np.int64)))
        bodies.append(np.array(vertex_body, dtype=np.int64))
    if not segments:  # only vertices
        blocks, bodies = blocks[1:], bodies[1:]
    return owners, blocks, bodies


def _kinematics(results: Results, owners, v: int) -> tuple[np.ndarray, ...]:
    """Positions, velocities, accelerations (K, points, 3) of variant v's exported points."""
    poses = results.poses[v]
    K = poses.shape[0]
    nb = poses.shape[1]
    rates = results.rates[v] if results.rates is not None else np.zeros((K, 2, nb, 3))
    pos = np.zeros((K, len(owners), 3))
    vel, acc = np.zeros_like(pos), np.zeros_like(pos)
    for j, (body, s) in enumerate(owners):
        if body >= nb:  # the ground
            pos[:, j, :2] = s[v]
            continue
        x, y, phi = poses[:, body].T
        c, sn = np.cos(phi), np.sin(phi)
        asx, asy = c * s[v, 0] - sn * s[v, 1], sn * s[v, 0] + c * s[v, 1]
        (vx, vy, w), (ax, ay, al) = rates[:, 0, body].T, rates[:, 1, body].T
        pos[:, j, 0], pos[:, j, 1] = x + asx, y + asy
        vel[:, j, 0], vel[:, j, 1] = vx - w * asy, vy + w * asx
        acc[:, j, 0] = ax - al * asy - w * w * asx
        acc[:, j, 1] = ay + al * asx - w * w * asy
    return pos, vel, acc


def export(results: Results, system: System, path: str, at: list[float] | None = None,
           max_frames: int | None = None) -> list[str]:
    """Write the run as meshes (see the module's docstring), or as a drawing for CAD (.dxf,
    .svg: :mod:`mechdsl.outputs.cad`), at the instants of :func:`export_instants`; returns
    the files written."""
    if results.poses is None:
        raise ValueError("the run kept no poses: simulate(..., poses=True, rates=True)")
    FORMATS["export"].check(path)
    stem, ext = os.path.splitext(path)
    ext = ext.lower()
    ks = export_instants(results, path, at, max_frames)
    written = []
    if ext in (".dxf", ".svg"):
        from . import cad
        from .draw import frames

        fr = frames(results, system)  # every variant's, once
        for v in range(results.n_variants):
            chosen = ks[ks < int(results.n_solved[v])]
            if not len(chosen):
                continue
            name = _variant_stem(stem, v, results.n_variants) + ext
            d = cad.drawing(fr, results, system, v, chosen)
            (cad.write_dxf if ext == ".dxf" else cad.write_svg)(d, name)
            written.append(name)
        return written
    import meshio

    owners, blocks, bodies = _layout(system)
    for v in range(results.n_variants):
        chosen = ks[ks < int(results.n_solved[v])]
        if not len(chosen):
            continue
        name = _variant_stem(stem, v, results.n_variants)
        pos, vel, acc = (a[chosen] for a in _kinematics(results, owners, v))
        times = results.times[chosen]
        if ext == ".xdmf":
            written.append(_xdmf(meshio, name + ext, pos, vel, acc, times, blocks, bodies))
        else:
            written.extend(_vtu(meshio, name, pos, vel, acc, times, blocks, bodies, chosen))
    return written


def _xdmf(meshio, path, pos, vel, acc, times, blocks, bodies) -> str:
    # the data inline in the XML (HDF5 would need h5py, which meshio does not require, and
    # a companion .h5 file): the .xdmf names no other file, so its temporary copy is whole
    with atomic_path(path) as tmp, _xdmf_writer(meshio)(tmp, data_format="XML") as w:
        w.write_points_cells(pos[0], blocks)
        for k, t in enumerate(times):
            w.write_data(float(t), point_data={
                "position": pos[k], "displacement": pos[k] - pos[0], "velocity": vel[k],
                "acceleration": acc[k], "speed": np.linalg.norm(vel[k], axis=1)},
                cell_data={"body": bodies})
    return path


def _xdmf_writer(meshio):
    """meshio's XDMF time-series writer, with a "Mixed" topology written as XDMF defines it:
    meshio's own fails on line cells among others (and would give a vertex no count)."""
    from xml.etree import ElementTree as ET

    class Writer(meshio.xdmf.TimeSeriesWriter):
        def cells(self, cells, grid) -> None:
            if len(cells) == 1:
                return super().cells(cells, grid)
            codes = {"vertex": 1, "line": 2}  # XDMF's Polyvertex and Polyline
            flat = np.concatenate([
                np.hstack((np.full((len(data), 1), codes[kind]),
                           np.full((len(data), 1), data.shape[1]), data)).ravel()
                for kind, data in cells]).astype(np.int64)
            topology = ET.SubElement(grid, "Topology", TopologyType="Mixed",
                                     NumberOfElements=str(sum(len(d) for _, d in cells)))
            item = ET.SubElement(topology, "DataItem", DataType="Int",
                                 Dimensions=str(len(flat)), Format=self.data_format,
                                 Precision="8")
            item.text = self.numpy_to_xml_string(flat)
            return None

    return Writer


def _vtu(meshio, stem, pos, vel, acc, times, blocks, bodies, ks) -> list[str]:
    """A .vtu per exported instant, named by its index in the run (``ks``), and the index."""
    files = []
    for k in range(len(times)):
        name = _vtu_name(stem, int(ks[k]))
        mesh = meshio.Mesh(pos[k], blocks, point_data={
            "velocity": vel[k], "acceleration": acc[k],
            "speed": np.linalg.norm(vel[k], axis=1)}, cell_data={"body": bodies})
        with atomic_path(name) as tmp:
            mesh.write(tmp, file_format="vtu")
        files.append(name)
    # (imported here: xml.sax.saxutils brings urllib.request and http.client, 20 ms of
    # every run's start-up)
    from xml.sax.saxutils import quoteattr

    index = stem + ".pvd"
    entries = "\n".join(
        f'    <DataSet timestep="{t:.17g}" part="0" file={quoteattr(os.path.basename(f))}/>'
        for t, f in zip(times, files))
    write_text(index, lambda f: f.write(
        '<?xml version="1.0"?>\n<VTKFile type="Collection" version="0.1">\n'
        f"  <Collection>\n{entries}\n  </Collection>\n</VTKFile>\n"))
    return [*files, index]
