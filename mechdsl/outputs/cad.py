"""Drawings for fabrication and CAD: the mechanism at chosen instants and the traced paths, as
polylines in the model's length unit, in DXF (written with ezdxf) or SVG.

What is drawn is what a snapshot draws (:func:`mechdsl.outputs.draw.frames`), in world
coordinates r^P = r + A(phi) s'^P (Haug eq. 2.6.4): every body through its points (an open
polyline for a bar, a closed one for a plate, a point for a body of one point), the pins as
small circles, the guides' rails as lines, the ground's pivots as points, and each traced
point's whole path as one polyline; with ``trace ic(A, B)``, the fixed centrode (dashed in
SVG) on ``paths`` where its frame is the ground, and at each instant the moving centrode
(dotted; and the fixed one of a moving frame). Each instant is its own layer (DXF, named ``t 0.25``)
or group (SVG, ``id="t_0.25"``, ``data-t`` its time); the paths are on ``paths``, the
ground on ``ground``. Coordinates are
written to round-trip (repr of each double), so a file read back gives the run's positions
exactly.

* DXF (R2010): ``$INSUNITS`` is the model's length unit where DXF knows it (m, mm, cm, km,
  in, ft, um; else unitless); LWPOLYLINE entities, CIRCLE for pins (radius 1 % of the
  drawing's extent), POINT for ground pivots and one-point bodies.
* SVG: the ``viewBox`` in model units with y up (a ``scale(1, -1)`` group), ``width`` and
  ``height`` in millimetres where the unit converts to them (m, mm, cm, in, ft), else as
  the bare model numbers; ``polyline``, ``circle`` elements; names as ``id`` and
  ``data-`` attributes, escaped.

With a sweep, each variant is its own file, ``NAME_v0.dxf``, ... as for the other exports.
Every file is written atomically.
"""

from __future__ import annotations

import math
import os
from xml.sax.saxutils import escape, quoteattr

import numpy as np

from ..compiled.system import System
from ..errors import MechError
from ..results import Results
from ..writing import atomic_path, write_text
from .centrodes import pieces, within_reach

#: DXF $INSUNITS codes of the length units it knows
DXF_UNITS = {"in": 1, "ft": 2, "mi": 3, "mm": 4, "cm": 5, "m": 6, "km": 7, "um": 13,
             "µm": 13, "dm": 14}
#: millimetres per length unit, for an SVG's physical size
MM_PER = {"m": 1000.0, "mm": 1.0, "cm": 10.0, "dm": 100.0, "km": 1e6, "in": 25.4,
          "ft": 304.8, "um": 1e-3, "µm": 1e-3}


def _num(x: float) -> str:
    return repr(float(x))


def _layer(t: float) -> str:
    """The DXF layer of an instant ('=' is not allowed in a layer's name)."""
    return f"t {float(t):g}"


def drawing(fr, results: Results, system: System, v: int, ks) -> dict:
    """What variant v's drawing holds, from the run's frames ``fr``
    (:func:`mechdsl.outputs.draw.frames`), in world coordinates: per instant k of ``ks`` its
    bodies (name, points (P, 2)), pins (J, 2), rails ((2, 2) each) and centrodes that move
    (label, piece (M, 2), whether it is a moving centrode: SVG dots those and dashes the
    fixed ones); the ground's pivots (G, 2); each traced point's path (label,
    (K, 2)); the pieces of each fixed centrode whose frame is the ground (``centrodes``,
    label and piece); the instant centres drawn (``centres``, for the extent)."""
    names = list(system.body_names)
    nb = len(fr.outlines)
    out = {"instants": [], "ground": fr.ground[v, 0], "paths": [], "centres": [],
           "unit": system.sketch.length_unit if system.sketch else ""}
    for k in ks:
        bodies = [(names[i], o[v, k]) for i, o in enumerate(fr.outlines)]
        pins = np.array([p[v, k] for p in fr.pins]).reshape(-1, 2)
        rails = [np.array([a[v, k], b[v, k]]) for a, b, _ in fr.guides]
        curves = []
        for c in fr.centrodes:
            fixed, moving = c.at(v, k)
            curves += [(f"moving centrode of {c.label}", p, True) for p in pieces(moving)]
            if c.b < nb:
                curves += [(f"fixed centrode of {c.label}", p, False) for p in pieces(fixed)]
            out["centres"].append(c.centre[v, k])
        out["instants"].append((float(results.times[k]), bodies, pins, rails, curves))
    n = int(results.n_solved[v])
    out["paths"] = [(label, p[v, :n]) for label, p in fr.traces.items()]
    out["centrodes"] = [(f"fixed centrode of {c.label}", p) for c in fr.centrodes
                        if c.b >= nb for p in pieces(c.fixed[v])]
    out["centres"] += [c.centre[v, :n] for c in fr.centrodes]
    return out


def _extent(d: dict) -> tuple[np.ndarray, np.ndarray]:
    """The box of the drawing: the mechanism and the traced points' paths, and the instant
    centres of centrodes within reach of them (:func:`within_reach`; the curves themselves
    may run far away, to infinity)."""
    pts = [d["ground"].reshape(-1, 2)]
    for _, bodies, pins, rails, _ in d["instants"]:
        pts += [b for _, b in bodies] + [pins] + rails
    pts += [p for _, p in d["paths"]]
    allp = np.concatenate([p.reshape(-1, 2) for p in pts if p.size])
    allp = allp[np.isfinite(allp).all(axis=1)]
    if not len(allp):
        return np.zeros(2), np.ones(2)
    return within_reach(allp.min(axis=0), allp.max(axis=0), d["centres"])


def write_dxf(d: dict, path: str) -> None:
    """The drawing ``d`` (:func:`drawing`) as a DXF file."""
    try:
        import ezdxf
    except ImportError:  # pragma: no cover - the extra not installed
        raise MechError(f"cannot write {path}: a .dxf needs ezdxf (pip install "
                        "'mechdsl[cad]')") from None
    doc = ezdxf.new("R2010")
    doc.header["$INSUNITS"] = DXF_UNITS.get(d["unit"], 0)
    msp = doc.modelspace()
    lo, hi = _extent(d)
    radius = 0.01 * float(max(hi - lo)) or 0.01
    for name in ("ground", "paths"):
        doc.layers.add(name)
    for x, y in d["ground"]:
        msp.add_point((x, y), dxfattribs={"layer": "ground"})
    for label, p in d["paths"]:
        good = p[np.isfinite(p).all(axis=1)]
        if len(good) >= 2:
            msp.add_lwpolyline([tuple(q) for q in good],
                               dxfattribs={"layer": "paths"}).set_xdata(
                "MECHDSL", [(1000, f"path of {label}")])
    for label, p in d["centrodes"]:
        msp.add_lwpolyline([tuple(q) for q in p], dxfattribs={"layer": "paths"}).set_xdata(
            "MECHDSL", [(1000, label)])
    for t, bodies, pins, rails, curves in d["instants"]:
        layer = _layer(t)
        if layer not in doc.layers:
            doc.layers.add(layer)
        attrs = {"layer": layer}
        for name, pts in bodies:
            if not np.isfinite(pts).all():
                continue
            if len(pts) == 1:
                msp.add_point(tuple(pts[0]), dxfattribs=attrs)
            else:
                line = msp.add_lwpolyline([tuple(q) for q in pts], close=len(pts) >= 3,
                                          dxfattribs=attrs)
                line.set_xdata("MECHDSL", [(1000, name)])
        for x, y in pins:
            if math.isfinite(x) and math.isfinite(y):
                msp.add_circle((x, y), radius, dxfattribs=attrs)
        for rail in rails:
            if np.isfinite(rail).all():
                msp.add_line(tuple(rail[0]), tuple(rail[1]), dxfattribs=attrs)
        for label, p, _ in curves:
            msp.add_lwpolyline([tuple(q) for q in p], dxfattribs=attrs).set_xdata(
                "MECHDSL", [(1000, label)])
    doc.appids.add("MECHDSL")
    with atomic_path(path) as tmp:
        doc.saveas(tmp)


def write_svg(d: dict, path: str) -> None:
    """The drawing ``d`` (:func:`drawing`) as an SVG file."""
    lo, hi = _extent(d)
    span = np.maximum(hi - lo, 1e-12)
    pad = 0.05 * float(max(span))
    x0, y0 = lo - pad
    w, h = span + 2 * pad
    radius = 0.01 * float(max(span))
    mm = MM_PER.get(d["unit"])
    size = (f'width="{_num(w * mm)}mm" height="{_num(h * mm)}mm" ' if mm else "")
    stroke = _num(0.004 * float(max(span)))
    dash, gap = _num(0.02 * float(max(span))), _num(0.01 * float(max(span)))  # centrodes

    def points(p: np.ndarray) -> str:
        return " ".join(f"{_num(x)},{_num(y)}" for x, y in p)

    lines = ['<?xml version="1.0" encoding="UTF-8"?>',
             f'<svg xmlns="http://www.w3.org/2000/svg" {size}'
             f'viewBox="{_num(x0)} {_num(-(y0 + h))} {_num(w)} {_num(h)}" '
             f'data-unit={quoteattr(d["unit"])}>',
             f'<g transform="scale(1,-1)" fill="none" stroke="black" stroke-width="{stroke}">',
             '<g id="ground">']
    lines += [f'<circle cx="{_num(x)}" cy="{_num(y)}" r="{_num(radius)}"/>'
              for x, y in d["ground"]]
    lines += ['</g>', '<g id="paths" stroke="gray">']
    for label, p in d["paths"]:
        good = p[np.isfinite(p).all(axis=1)]
        lines.append(f'<polyline data-path={quoteattr(label)} points="{points(good)}"/>')

    def centrode(label: str, p: np.ndarray, moving: bool) -> str:
        # the fixed centrodes dashed, the moving ones dotted (as the pictures draw them)
        return (f'<polyline data-centrode={quoteattr(label)} points="{points(p)}" '
                f'stroke="gray" stroke-dasharray="{gap if moving else dash} {gap}"/>')

    lines += [centrode(label, p, False) for label, p in d["centrodes"]]
    lines.append('</g>')
    for t, bodies, pins, rails, curves in d["instants"]:
        lines.append(f'<g id={quoteattr(f"t_{float(t):g}")} data-t="{_num(t)}">')
        for name, pts in bodies:
            if not np.isfinite(pts).all():
                continue
            tag = "polygon" if len(pts) >= 3 else "polyline"
            if len(pts) == 1:
                x, y = pts[0]
                lines.append(f'<circle data-body={quoteattr(name)} cx="{_num(x)}" '
                             f'cy="{_num(y)}" r="{_num(radius)}" fill="black"/>')
            else:
                lines.append(f'<{tag} data-body={quoteattr(name)} points="{points(pts)}"/>')
        lines += [f'<circle data-pin="" cx="{_num(x)}" cy="{_num(y)}" r="{_num(radius)}"/>'
                  for x, y in pins if math.isfinite(x) and math.isfinite(y)]
        lines += [f'<polyline data-rail="" points="{points(r)}" stroke="gray"/>'
                  for r in rails if np.isfinite(r).all()]
        lines += [centrode(label, p, moving) for label, p, moving in curves]
        lines.append('</g>')
    lines += ['</g>', f'<title>{escape(os.path.basename(path))}</title>', '</svg>']
    write_text(path, lambda f: f.write("\n".join(lines) + "\n"))
