"""A run as the page draws it: one binary message, a JSON header and float64 arrays.

Layout of a message (little-endian)::

    b"MDV1" | uint32 n | n bytes of JSON (UTF-8), padded with spaces to a multiple of 8 |
    float64 array

The header says where each quantity lies in the array (``o``, its offset in values) and its
shape; the page reads them as views (``new Float64Array(buffer, 8 + n + 8 o, size)``), with
no parsing of numbers: the seed's 1001 instants travel as 0.24 MB and are ready as soon as
they arrive. Positions are the run's own, to the last bit (float64, the world coordinates
r^P = r + A(phi) s'^P of every drawn point, Haug eq. 2.6.4, as :mod:`mechdsl.outputs.draw`
computes them for ``--snapshot``).

Every name (bodies, points, outputs, params, messages) is a JSON string: the page shows it as
text, never as markup.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from typing import Iterable, Sequence

import numpy as np

from ..compiled.system import System
from .centrodes import within_reach
from .draw import frames, variant_labels
from ..results import Results, summary

MAGIC = b"MDV1"


@dataclass(frozen=True)
class Slider:
    """A param the page gives a slider: its value now and its range [lo, hi]."""

    name: str
    value: float
    lo: float
    hi: float


def default_range(value: float) -> tuple[float, float]:
    """The slider range of a param without one in the file: from 0 to twice the value (the
    value's sign kept: a length, a speed, a mass can be halved to zero or doubled), and
    [-1, 1] around a value of 0."""
    if value == 0 or not math.isfinite(value):
        return -1.0, 1.0
    return (0.0, 2.0 * value) if value > 0 else (2.0 * value, 0.0)


class _Packer:
    """Arrays appended to one float64 buffer, each remembered by its offset."""

    def __init__(self) -> None:
        self.parts: list[np.ndarray] = []
        self.points: list[np.ndarray] = []  # the positions drawn, for the drawing's bounds
        self.size = 0

    def add(self, a: np.ndarray, points: bool = False) -> int:
        a = np.ascontiguousarray(a, dtype="<f8").ravel()
        at = self.size
        self.parts.append(a)
        if points:
            self.points.append(a)
        self.size += a.size
        return at

    def bytes(self) -> bytes:
        return np.concatenate(self.parts).tobytes() if self.parts else b""


def encode(header: dict, packer: _Packer | None = None) -> bytes:
    """The message: magic, the header's length, the header, the arrays."""
    text = json.dumps(header, allow_nan=False, separators=(",", ":")).encode("utf-8")
    text += b" " * (-len(text) % 8)
    return MAGIC + len(text).to_bytes(4, "little") + text + (packer.bytes() if packer else b"")


def decode(message: bytes) -> tuple[dict, np.ndarray]:
    """The header and the array of a message (the tests read what the page reads)."""
    if message[:4] != MAGIC:
        raise ValueError("not a mechdsl view message")
    n = int.from_bytes(message[4:8], "little")
    return json.loads(message[8:8 + n]), np.frombuffer(message[8 + n:], dtype="<f8")


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _point_rates(poses: np.ndarray, rates: np.ndarray, body: int, at: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The velocity and acceleration (K, 2) of a point of ``body`` that is at ``at`` (K, 2),
    from the body's pose (K, bodies, 3) and rates (K, 2, bodies, 3) (Haug eq. 2.6.5 and
    2.6.6): with d = A s' the point's arm from the body's frame and d_perp = (-d_y, d_x),
    v^P = r' + phi' d_perp and a^P = r'' + phi'' d_perp - phi'^2 d. The ground's are 0."""
    if body >= poses.shape[1]:
        return np.zeros_like(at), np.zeros_like(at)
    d = at - poses[:, body, :2]
    perp = np.stack((-d[:, 1], d[:, 0]), axis=-1)
    vel, acc = rates[:, 0, body], rates[:, 1, body]
    return (vel[:, :2] + vel[:, 2:3] * perp,
            acc[:, :2] + acc[:, 2:3] * perp - vel[:, 2:3] ** 2 * d)


def run_message(system: System, results: Results, sliders: Sequence[Slider], *,
                file: str, warnings: Iterable[str] = ()) -> bytes:
    """The page's message for a run (module docstring): the mechanism's drawn points at every
    instant, the outputs, the sliders, how the run ended."""
    if results.poses is None:
        raise ValueError("the view needs the run's poses: simulate(..., poses=True)")
    pk = _Packer()
    sk = system.sketch
    fr = frames(results, system)  # the drawings' geometry, in world coordinates
    V, K = results.poses.shape[:2]
    items: list[dict] = []
    for v in range(V):
        for name, xy in zip(system.body_names, fr.outlines):
            items.append({"kind": "body", "name": name, "v": v, "p": int(xy.shape[2]),
                          "o": pk.add(xy[v], True)})
        for xy in fr.pins:
            items.append({"kind": "pin", "v": v, "o": pk.add(xy[v], True)})
        for edges in fr.shapes:
            items.append({"kind": "shape", "v": v, "p": int(edges.shape[2]),
                          "o": pk.add(edges[v], True)})
        for a, b in fr.links:
            items.append({"kind": "spring", "v": v,
                          "o": pk.add(np.stack((a[v], b[v]), -2), True)})
        for c in fr.centrodes:  # local curves, carried by their frames' poses on the page
            items.append({"kind": "centrode", "name": c.label, "v": v,
                          "m": int(c.fixed.shape[1]), "ground": bool(c.b >= len(fr.outlines)),
                          "fixed": pk.add(c.fixed[v]), "moving": pk.add(c.moving[v]),
                          "pa": pk.add(c.pose_a[v]), "pb": pk.add(c.pose_b[v]),
                          "ic": pk.add(c.centre[v])})
        for label, body, _ in sk.traces:
            at = fr.traces[label][v]
            item = {"kind": "trace", "name": label, "v": v, "o": pk.add(at, True)}
            if results.rates is not None:
                vel, acc = _point_rates(results.poses[v], results.rates[v], body, at)
                item["vo"], item["ao"] = pk.add(vel), pk.add(acc)
            items.append(item)
        ground = fr.ground[v, 0]  # fixed: its points once
        items.append({"kind": "ground", "v": v, "p": int(ground.shape[0]),
                      "o": pk.add(ground, True)})
    # every drawn position ends in (x, y): the bounds of the finite points of them all
    pts = np.concatenate([p.reshape(-1, 2) for p in pk.points]) if pk.points else \
        np.zeros((0, 2))
    pts = pts[np.isfinite(pts).all(axis=1)]
    lo, hi = (pts.min(axis=0), pts.max(axis=0)) if pts.size else ((-1.0, -1.0), (1.0, 1.0))
    lo, hi = within_reach(np.asarray(lo), np.asarray(hi), [c.centre for c in fr.centrodes])
    bounds = [float(lo[0]), float(lo[1]), float(hi[0]), float(hi[1])]
    series = []
    for name in results.data:
        a = np.asarray(results.data[name], dtype=float).reshape(V, K)
        for v in range(V):
            series.append({"name": name, "unit": results.units.get(name, ""), "v": v,
                           "o": pk.add(a[v])})
    header = {
        "type": "run", "file": file, "K": int(K), "V": int(V), "t": pk.add(results.times),
        "time_unit": results.time_unit, "solved": [int(n) for n in results.n_solved],
        "status": results.status, "messages": list(results.messages),
        "warnings": [*results.warnings, *warnings],
        "summary": _summary(results, file),
        "variants": variant_labels(results), "bodies": list(system.body_names),
        "sweep": {k: [float(x) for x in np.asarray(a, dtype=float).ravel()]
                  for k, a in results.sweep.items()},
        "items": items, "series": series, "bounds": bounds,
        "sliders": _sliders(sliders),
    }
    return encode(header, pk)


def error_message(kind: str, texts: Sequence[str], sliders: Sequence[Slider] = ()) -> bytes:
    """A message without a run: ``kind`` "error" (the file's located errors, as ``mechdsl
    check`` prints them, or a failure of the solve) with the texts to show."""
    return encode({"type": kind, "errors": list(texts), "sliders": _sliders(sliders)})


def _sliders(sliders: Sequence[Slider]) -> list[dict]:
    return [{"name": s.name, "value": _finite(s.value), "lo": _finite(s.lo),
             "hi": _finite(s.hi)} for s in sliders]


def _summary(results: Results, file: str) -> str:
    """The run's summary, naming the file as the page does."""
    text = summary(results)
    return text.replace(results.source_name, file, 1) if results.source_name else text
