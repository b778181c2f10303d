"""Pictures of the mechanism itself: snapshots over traced paths, and animations.

Each body is drawn through its points (:func:`outlines`): the points it declares, in order,
after the points a joint or drive attaches that it does not declare (its origin, for a
crank pivoted at ``crank.origin``) -- a marker for one point, a bar for two, a plate (the
polygon) for three or more -- with the outline of its shape where it has one, each point a
joint or drive attaches as a small circle, the ground's points as hatched supports, and the
points named by ``trace`` with their paths. The variants of a sweep are overlaid in their own
colours, named in a legend by their parameter values. Coordinates come from the run's poses:
r^P = r + A(phi) s'^P for every point (Haug eq. 2.6.4).

An animation draws its fixed parts (axes, grid, supports, title) once and, at every frame,
only what moves over a copy of them (blitting on the Agg canvas); a GIF keeps its frames as
palette indices (one palette for the whole animation), compressed, until it is written, when
Pillow holds each as a palette image (one byte a pixel).
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from ..compiled.system import Sketch, System
from ..errors import MechError
from ..results import Results
from .centrodes import Centrode, centrodes, pieces, within_reach
from .plot import figure_parts, literal, save_figure
from .styles import decorate, variant_styles

#: Frames of an animation at most (instants are sampled evenly when there are more).
MAX_FRAMES = 100
#: Frames per second of an animation.
FPS = 25


def snapshot_options(settings: dict, path: str) -> dict:
    """The snapshot's keywords from the run's settings (:func:`mechdsl.outputs.settings`)."""
    return {"at": settings["at"], "labels": settings["labels"]}


def animation_options(settings: dict, path: str) -> dict:
    """The animation's keywords: at most ``frames`` frames (default :data:`MAX_FRAMES`)."""
    frames = settings["frames"]
    return {"max_frames": MAX_FRAMES if frames is None else frames,
            "labels": settings["labels"]}


def snapshot_summary(results: Results, path: str, settings: dict) -> str:
    """The line ``mechdsl run`` prints of the snapshot written to ``path``: its instants."""
    ks = snapshot_instants(results, settings["at"])
    return f"{path}: snapshot at t = " + ", ".join(f"{results.times[k]:g}" for k in ks)


def animation_summary(results: Results, path: str, settings: dict) -> str:
    """The line ``mechdsl run`` prints of the animation written to ``path``: its frames."""
    n = frame_count(results, animation_options(settings, path)["max_frames"])
    return f"{path}: animation of {n} frame{'s' if n != 1 else ''}"


def drawing_bytes(system: System) -> int:
    """The world coordinates of every drawn point of every variant at every instant (with
    two temporary copies): what drawing the mechanism holds."""
    sk = system.sketch
    drawn = sum(o.shape[1] + 1 for o in sk.outlines) + sum(p.shape[1] for _, p in sk.pins)
    drawn += len(sk.traces) + 2 * len(sk.centrodes) \
        + sum(2 * e.shape[1] for e in sk.shapes if e is not None)
    return 3 * 2 * 8 * system.n_variants * len(system.times) * drawn


def snapshot_memory(system: System, path: str, settings: dict) -> dict[str, int]:
    """What the snapshot adds to the run (:attr:`mechdsl.outputs.Format.memory`)."""
    return {**figure_parts(), "the drawing": drawing_bytes(system)}


def animation_memory(system: System, path: str, settings: dict) -> dict[str, int]:
    """What the animation adds: its frames too, all of them for a GIF (kept until the file
    is written), one for an MP4 (streamed)."""
    frames = min(animation_options(settings, path)["max_frames"], len(system.times))
    return {**figure_parts(frames if path.lower().endswith(".gif") else 1),
            "the drawing": drawing_bytes(system)}
#: Colour of a ground support shared by every variant (a variant's own are in its colour).
SUPPORT_COLOR = "0.35"


def outlines(sketch: Sketch) -> tuple[np.ndarray, ...]:
    """The points each body is drawn and exported through (the ground last), (V, P, 2) in its
    frame: first the points a joint or drive attaches that the body does not declare (in
    practice its origin: a crank pivoted at ``crank.origin``, a lever at ``lever.origin``),
    in the order of the joints, then the points it declares, in order. A body that declares
    no point is drawn through its origin alone. A declared point at the origin (in every
    variant) stands for the origin."""
    attached: dict[int, list[np.ndarray]] = {}
    for body, xy in sketch.pins:
        attached.setdefault(body, []).append(xy)
    drawn = []
    for i, declared in enumerate(sketch.outlines):
        points = [declared[:, p] for p in range(declared.shape[1])]
        extra: list[np.ndarray] = []
        for xy in attached.get(i, ()):
            if not any(np.array_equal(xy, p) for p in (*points, *extra)):
                extra.append(xy)
        drawn.append(np.stack((*extra, *points), axis=1) if extra else declared)
    return tuple(drawn)


def world(poses: np.ndarray, body: int, local: np.ndarray) -> np.ndarray:
    """Global coordinates r + A(phi) s' of body-frame points ``local`` (V, ..., 2) of ``body``
    for poses (V, K, bodies, 3); a body index past the last is the ground (identity).
    Returns (V, K, ..., 2)."""
    V, K, nb, _ = poses.shape
    local = np.asarray(local, dtype=float)
    extra = local.ndim - 2  # axes between the variant axis and the (2,)
    s = local.reshape((V, 1) + local.shape[1:])
    if body >= nb:
        return np.broadcast_to(s, (V, K) + local.shape[1:]).copy()
    q = poses[:, :, body].reshape((V, K) + (1,) * extra + (3,))
    c, sn = np.cos(q[..., 2:3]), np.sin(q[..., 2:3])
    rot = np.concatenate((c * s[..., :1] - sn * s[..., 1:], sn * s[..., :1] + c * s[..., 1:]),
                         axis=-1)
    return q[..., :2] + rot


def paths(results: Results, sketch: Sketch) -> dict[str, np.ndarray]:
    """The traced points' paths, label -> (V, K, 2)."""
    _need_poses(results)
    return {label: world(results.poses, body, xy) for label, body, xy in sketch.traces}


@dataclass(frozen=True)
class Frames:
    """Every drawn point at every instant: outlines (V, K, P, 2) per body, pins (V, K, 2)."""

    outlines: list[np.ndarray]
    pins: list[np.ndarray]
    traces: dict[str, np.ndarray]
    #: the ground's points (V, K, G, 2), each with its support
    ground: np.ndarray
    #: per body with a shape: its outline's edges (V, K, E, 2, 2)
    shapes: list[np.ndarray]
    #: per spring-like force element: its two ends (V, K, 2) each
    links: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)
    #: per guide (a slider's rail, a slot): the ends (V, K, 2) of its line over the sliding
    #: point's travel, and whether the line is the ground's (fixed)
    guides: list[tuple[np.ndarray, np.ndarray, bool]] = field(default_factory=list)
    #: each moving body's name and where it is labelled (V, K, 2): its points' mean
    names: list[tuple[str, np.ndarray]] = field(default_factory=list)
    #: each joint's name and its pin (V, K, 2), once per place
    pin_names: list[tuple[str, np.ndarray]] = field(default_factory=list)
    #: the unit of length ("" where the model names none)
    unit: str = ""
    #: ``trace ic(A, B)``: the centrodes (:mod:`mechdsl.outputs.centrodes`)
    centrodes: list[Centrode] = field(default_factory=list)


def frames(results: Results, system: System) -> Frames:
    """Every drawn point of ``system`` at every instant of ``results`` (with poses), in
    world coordinates (:class:`Frames`): what snapshots, animations and the view draw."""
    sk = system.sketch
    nb = system.n_bodies
    poses = results.poses
    drawn = outlines(sk)
    bodies = [world(poses, i, drawn[i]) for i in range(nb)]
    pins = [world(poses, body, xy) for body, xy in sk.pins]
    # a support under each pivot of the ground (not under a guide's reference point)
    pivots = [p for (body, _), p in zip(sk.pins, pins) if body >= nb]
    V, K = poses.shape[:2]
    ground = np.stack(pivots, axis=2) if pivots else np.zeros((V, K, 0, 2))
    shapes = [world(poses, i, e) for i, e in enumerate(sk.shapes) if e is not None]
    links = [(world(poses, b1, xy1), world(poses, b2, xy2)) for b1, xy1, b2, xy2 in sk.links]
    guides = [_rail(poses, *g, fixed=g[0] >= nb) for g in sk.guides]
    names = [(name, bodies[i].mean(axis=2)) for i, name in enumerate(sk.names)]
    seen: list[np.ndarray] = []
    pin_names = []
    for name, p in zip(sk.pin_names, pins):
        if not any(np.allclose(p, q, equal_nan=True) for q in seen):
            seen.append(p)
            pin_names.append((name, p))
    rolling = []
    if sk.centrodes:
        if results.rates is None:
            raise ValueError("centrodes need the bodies' velocities: the run kept no rates "
                             "(simulate(..., poses=True, rates=True))")
        rolling = centrodes(poses, results.rates, sk.centrodes)
    return Frames(bodies, pins, paths(results, sk), ground, shapes, links, guides, names,
                  pin_names, sk.length_unit, rolling)


def _rail(poses: np.ndarray, body: int, p1: np.ndarray, axis: np.ndarray, slider: int,
          p2: np.ndarray, fixed: bool) -> tuple[np.ndarray, np.ndarray, bool]:
    """The ends (V, K, 2) of a guide's line through P1 along the axis (both in the frame of
    ``body``), over the travel of P2 (on ``slider``) in the run, a tenth longer on each
    side (the line's own frame: a slot in a moving body moves with it)."""
    origin = world(poses, body, p1)
    u = world(poses, body, p1 + axis) - origin
    with np.errstate(all="ignore"):
        u = u / np.linalg.norm(u, axis=-1, keepdims=True)
        s = ((world(poses, slider, p2) - origin) * u).sum(-1)  # (V, K)
        lo, hi = np.nanmin(s, axis=1, keepdims=True), np.nanmax(s, axis=1, keepdims=True)
    travel = np.where(np.isfinite(hi - lo), hi - lo, 0.0)
    margin = 0.1 * travel + 0.05 * np.where(travel > 0, travel, 1.0)
    lo, hi = np.nan_to_num(lo) - margin, np.nan_to_num(hi) + margin
    return origin + lo[..., None] * u, origin + hi[..., None] * u, fixed


def zigzag(p: np.ndarray, q: np.ndarray, turns: int = 8) -> np.ndarray:
    """A spring's drawing from p to q: straight ends and ``turns`` zigzags between them, a
    tenth of its length wide."""
    d = q - p
    length = float(np.hypot(*d))
    if not length > 0:
        return np.array([p, q])
    u, n = d / length, np.array([-d[1], d[0]]) / length
    s = np.concatenate(([0.0, 0.15], np.linspace(0.15, 0.85, 2 * turns + 1)[1:-1], [0.85, 1.0]))
    side = np.zeros(len(s))
    side[2:-2] = np.where(np.arange(len(s) - 4) % 2 == 0, 1.0, -1.0)
    return p + np.outer(s * length, u) + np.outer(side * 0.05 * length, n)


def _need_poses(results: Results) -> None:
    if results.poses is None:
        raise ValueError("the run kept no poses: simulate(..., poses=True)")


def _limits(fr: Frames) -> tuple[float, float, float, float]:
    pts = [a.reshape(-1, 2) for a in (*fr.outlines, *fr.pins, *fr.traces.values(), fr.ground,
                                      *fr.shapes, *(e for a, b, _ in fr.guides for e in (a, b)))]
    allp = np.concatenate(pts)
    allp = allp[np.isfinite(allp).all(axis=1)]
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    lo, hi = within_reach(lo, hi, [c.centre for c in fr.centrodes])
    pad = 0.08 * max(float((hi - lo).max()), 1e-9)
    return lo[0] - pad, hi[0] + pad, lo[1] - pad, hi[1] + pad


def _instants(results: Results, count: int) -> np.ndarray:
    last = int(results.n_solved.max(initial=0))
    if last == 0:
        raise MechError("no instant was solved: there is nothing to draw")
    return np.unique(np.linspace(0, last - 1, min(count, last)).round().astype(int))


def frame_count(results: Results, max_frames: int = MAX_FRAMES) -> int:
    """The number of frames :func:`animate` writes for ``results``: ``max_frames`` instants
    at most, evenly spread over those solved (0 if none was)."""
    if int(results.n_solved.max(initial=0)) == 0:
        return 0
    return len(_instants(results, max_frames))


def snapshot_instants(results: Results, at: list[float] | None = None,
                      count: int = 6) -> np.ndarray:
    """The instants :func:`snapshot` draws: those nearest the times ``at``, or ``count``
    evenly spread over the instants solved."""
    if at:
        t = results.times[: int(results.n_solved.max(initial=0))]
        return np.unique([int(np.argmin(np.abs(t - a))) for a in at])
    return _instants(results, count)


def variant_labels(results: Results) -> list[str]:
    """Each variant's name in a legend: its swept params' values ("" without a sweep)."""
    if not results.sweep:
        return [""]
    return [", ".join(f"{k} = {v[i]:g}" for k, v in results.sweep.items())
            for i in range(results.n_variants)]


#: where the axes end on the right: alone, beside a colour bar, beside a legend (and a bar)
RIGHT = {None: 0.97, "bar": 0.86, "legend": 0.72}


def _figure(fr: Frames, title: str, colors: list, side: str | None = None):
    """The figure, its axes (equal, fixed, labelled with the unit of length) and the size of
    a support; ``side``: room on the right for a colour bar ("bar") or a legend and maybe a
    bar ("legend"), outside the data."""
    from .plot import new_figure

    # a fixed layout: a layout engine would run again at every frame of an animation
    fig = new_figure(figsize=(8.8, 5.5) if side == "legend" else (7.6, 5.5) if side
                     else (7, 5.5))
    fig.subplots_adjust(left=0.09, right=RIGHT[side], bottom=0.09, top=0.93)
    ax = fig.subplots()
    x0, x1, y0, y1 = _limits(fr)
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal", adjustable="box")
    unit = f" [{fr.unit}]" if fr.unit else ""
    ax.set_xlabel("x" + unit, parse_math=False)
    ax.set_ylabel("y" + unit, parse_math=False)
    ax.set_title(title, fontsize=10, parse_math=False)  # a file name is no mathtext
    ax.grid(True, lw=0.3, alpha=0.5)
    size = 0.03 * max(x1 - x0, y1 - y0)
    _supports(ax, fr.ground, colors, size)
    _ground_rails(ax, fr, colors, size)
    return fig, ax, size


def _supports(ax, ground: np.ndarray, colors: list, size: float) -> None:
    """A hatched triangle under every pivot of the ground (V, K, G, 2), fixed over time: one
    in grey where the point is the same in every variant of a sweep, else one per variant in
    its colour."""
    from matplotlib.patches import Polygon

    for j in range(ground.shape[2]):
        where = ground[:, 0, j]  # (V, 2)
        shared = bool(np.all(where == where[0]))
        for v in [0] if shared else range(len(where)):
            x, y = where[v]
            tri = [(x, y), (x - size, y - 1.6 * size), (x + size, y - 1.6 * size)]
            ax.add_patch(Polygon(tri, closed=True, fill=False, hatch="////", lw=0.8,
                                 color=SUPPORT_COLOR if shared else colors[v], zorder=1))


def _rail_lines(a: np.ndarray, b: np.ndarray, w: float) -> list[np.ndarray]:
    """The two sides of a rail from a to b, ``w`` either side of its line."""
    d = b - a
    length = float(np.hypot(*d))
    if not length > 0:
        return []
    n = np.array([-d[1], d[0]]) / length * w
    return [np.array([a + n, b + n]), np.array([a - n, b - n])]


def _ground_rails(ax, fr: Frames, colors: list, size: float) -> None:
    """Each guide of the ground, fixed: a rail (two lines) over the slider's travel with
    the ground hatched under it; one per variant where the variants' rails differ."""
    from matplotlib.collections import LineCollection
    from matplotlib.patches import Polygon

    w = 0.45 * size
    for a, b, fixed in fr.guides:
        if not fixed:
            continue
        ends = np.stack((a[:, 0], b[:, 0]), axis=1)  # (V, 2, 2)
        d = ends[:, 1] - ends[:, 0]
        with np.errstate(all="ignore"):
            u = d / np.linalg.norm(d, axis=-1, keepdims=True)
            # the variants' rails on one line (their travels differ): one rail over all
            cross = (ends[:, 0] - ends[0, 0]) @ np.array([-u[0, 1], u[0, 0]])
        shared = bool(np.allclose(u, u[0]) and np.allclose(cross, 0.0))
        if shared:
            s = (ends - ends[0, 0]) @ u[0]
            ends = (ends[0, 0] + np.array([s.min(), s.max()])[:, None] * u[0])[None]
        for v in [0] if shared else range(len(ends)):
            sides = _rail_lines(ends[v, 0], ends[v, 1], w)
            if not sides:
                continue
            color = SUPPORT_COLOR if shared else colors[v]
            ax.add_collection(LineCollection(sides, colors=[color], linewidths=1.0, zorder=1))
            lower = sides[1]
            off = lower[0] - sides[0][0]  # two w across, away from the rail
            ax.add_patch(Polygon([lower[0], lower[1], lower[1] + off, lower[0] + off],
                                 closed=True, fill=False, hatch="////", lw=0, color=color,
                                 zorder=1))


def _collinear(outline: np.ndarray) -> bool:
    """Whether a body's points (V, K, P, 2) lie on one line in every variant (a rigid body:
    the first instant solved says it): the cross products of their offsets from the first
    point vanish to round-off of the body's size."""
    for v in range(outline.shape[0]):
        good = np.flatnonzero(np.isfinite(outline[v]).all(axis=(1, 2)))
        if not len(good):
            continue
        d = outline[v, good[0]] - outline[v, good[0], 0]
        u = d[np.argmax(np.hypot(d[:, 0], d[:, 1]))]  # the farthest point's direction
        size = float(np.hypot(*u)) or 1.0
        if np.abs(d[:, 0] * u[1] - d[:, 1] * u[0]).max() > 1e-9 * size**2:
            return False
    return True


class _Artists:
    """One variant's drawing, as a few artists whatever the number of bodies (so that a
    frame of an animation costs a few updates, not one artist per body): the bars (two-point
    bodies) as a line collection, the plates (three points or more) as a polygon collection,
    single points as square markers, the pins as circle markers, the shapes' outlines, the
    springs and the moving guides as line collections; with ``labels``, the bodies' and the
    joints' names."""

    def __init__(self, ax, fr: Frames, color, alpha: float, size: float = 0.0,
                 labels: bool = False, linestyle: str = "-") -> None:
        from matplotlib.collections import LineCollection, PolyCollection

        self.fr, self.w = fr, 0.45 * size
        # points on one line (a rod with a point beyond its end) are a bar, not a plate
        self.bars = [i for i, o in enumerate(fr.outlines)
                     if o.shape[2] == 2 or (o.shape[2] >= 3 and _collinear(o))]
        self.plates = [i for i, o in enumerate(fr.outlines)
                       if o.shape[2] >= 3 and i not in self.bars]
        self.dots = [i for i, o in enumerate(fr.outlines) if o.shape[2] == 1]
        self.bar_art = ax.add_collection(LineCollection([], colors=[color], linewidths=3,
                                                        alpha=alpha, capstyle="round",
                                                        linestyles=linestyle, zorder=2))
        self.plate_art = ax.add_collection(PolyCollection([], facecolors=[color],
                                                          edgecolors=[color], alpha=0.3 * alpha,
                                                          linewidths=1.5, zorder=2))
        self.dot_art = ax.plot([], [], "s", color=color, ms=7, alpha=alpha, zorder=2)[0]
        self.pin_art = ax.plot([], [], "o", mfc="white", mec="black", mew=0.8, ms=6,
                               alpha=alpha, zorder=3)[0]
        self.shape_art = ax.add_collection(LineCollection([], colors=["0.2"], linewidths=1.0,
                                                          alpha=alpha, zorder=2))
        self.link_art = ax.add_collection(LineCollection([], colors=["0.35"], linewidths=1.0,
                                                         alpha=alpha, zorder=1))
        self.rail_art = ax.add_collection(LineCollection([], colors=[SUPPORT_COLOR],
                                                         linewidths=1.0, alpha=alpha, zorder=1))
        # centrodes: the moving ones (dotted) and the fixed ones of a moving frame (dashed),
        # the instant centre a cross where they touch
        self.centrode_art = ax.add_collection(LineCollection([], colors=[color], linewidths=1.0,
                                                             alpha=alpha, zorder=1))
        self.ic_art = ax.plot([], [], "x", color=color, ms=6, mew=1.2, alpha=alpha,
                              zorder=3)[0]
        self.artists = [self.bar_art, self.plate_art, self.dot_art, self.pin_art,
                        self.shape_art, self.link_art, self.rail_art]
        if fr.centrodes:
            self.artists += [self.centrode_art, self.ic_art]
        self.texts = []
        if labels:  # dark on a white halo, a few points off the spot they name
            from matplotlib import patheffects

            halo = [patheffects.withStroke(linewidth=2.5, foreground="white")]
            style = dict(textcoords="offset points", zorder=4, annotation_clip=True,
                         path_effects=halo)
            self.texts = [(ax.annotate(name, (0, 0), xytext=(0, 6), fontsize=8, ha="center",
                                       fontweight="bold", color="0.1", **style), at)
                          for name, at in fr.names]
            self.texts += [(ax.annotate(name, (0, 0), xytext=(5, -5), fontsize=7, ha="left",
                                        va="top", color="0.35", **style), at)
                           for name, at in fr.pin_names]
            for text, _ in self.texts:
                text.set_parse_math(False)  # a name is no mathtext
            self.artists += [t for t, _ in self.texts]

    def update(self, v: int, k: int) -> list:
        fr = self.fr
        self.bar_art.set_segments([fr.outlines[i][v, k] for i in self.bars])
        self.plate_art.set_verts([fr.outlines[i][v, k] for i in self.plates])
        dots = np.array([fr.outlines[i][v, k, 0] for i in self.dots]).reshape(-1, 2)
        self.dot_art.set_data(dots[:, 0], dots[:, 1])
        pins = np.array([p[v, k] for p in fr.pins]).reshape(-1, 2)
        self.pin_art.set_data(pins[:, 0], pins[:, 1])
        edges = [e for shape in fr.shapes for e in shape[v, k]]
        self.shape_art.set_segments(edges)
        self.link_art.set_segments([zigzag(a[v, k], b[v, k]) for a, b in fr.links])
        self.rail_art.set_segments([side for a, b, fixed in fr.guides if not fixed
                                    for side in _rail_lines(a[v, k], b[v, k], self.w)])
        if fr.centrodes:
            segments, styles = [], []
            for c in fr.centrodes:
                fixed, moving = c.at(v, k)
                for curve, style, drawn in ((moving, ":", True),
                                            (fixed, "--", c.b < len(fr.outlines))):
                    if drawn:
                        runs = pieces(curve)
                        segments += runs
                        styles += [style] * len(runs)
            self.centrode_art.set_segments(segments)
            self.centrode_art.set_linestyles(styles or "-")
            ics = np.array([c.centre[v, k] for c in fr.centrodes]).reshape(-1, 2)
            self.ic_art.set_data(ics[:, 0], ics[:, 1])
        for text, at in self.texts:
            x, y = at[v, k]
            text.xy = (x, y)
            text.set_visible(bool(np.isfinite([x, y]).all()))
        return self.artists


def _ground_centrodes(ax, fr: Frames, v: int, color, linestyle: str = "--") -> list:
    """The fixed centrodes of variant v whose frame is the ground: drawn once, whole, as the
    traced paths are."""
    lines = []
    for c in fr.centrodes:
        if c.b >= len(fr.outlines):
            for piece in pieces(c.fixed[v]):
                lines += ax.plot(piece[:, 0], piece[:, 1], ls=linestyle, lw=1.2, color=color,
                                 alpha=0.9, zorder=1)
    return lines


def _path_entries(fr: Frames, color) -> list:
    """The legend's entries of what is traced: each point's path, and each pair of
    centrodes (fixed dashed, moving dotted), as (text, colour, line style, width)."""
    entries = [(f"path of {label}", color, "-", 1.2) for label in fr.traces]
    for c in fr.centrodes:  # named where there are several
        of = f" {c.label}" if len(fr.centrodes) > 1 else ""
        entries += [(f"fixed centrode{of}", color, "--", 1.2),
                    (f"moving centrode{of}", color, ":", 1.2)]
    return entries


def _side(fig, ax, legend: list, colorbar: tuple | None):
    """The legend and the colour bar beside the axes of a fixed layout (the bar in an axes
    of its own at the figure's right); the legend."""
    cax = (fig.add_axes([0.9 if legend else 0.885, 0.14, 0.018, 0.72])
           if colorbar is not None else None)
    return decorate(fig, ax, legend, colorbar, cax=cax, fontsize=7)


def _sweep_legend(styles, fr: Frames | None) -> list:
    """The legend's entries: the variants (their styles' entries, thick), then what is
    traced (thin, in grey: the colours name the variants, or the instants), if ``fr``."""
    entries = [(text, c, ls, 3) for text, c, ls in styles.legend]
    return entries + (_path_entries(fr, "0.3") if fr is not None else [])


#: the colour map of the instants of a snapshot (its light end left out: bars on white)
TIME_CMAP = "viridis"
TIME_CMAP_RANGE = (0.0, 0.8)


def _time_cmap():
    import matplotlib
    from matplotlib.colors import ListedColormap

    base = matplotlib.colormaps[TIME_CMAP]
    return ListedColormap(base(np.linspace(*TIME_CMAP_RANGE, 256)))


def snapshot(results: Results, system: System, path: str, at: list[float] | None = None,
             count: int = 6, labels: bool = False) -> None:
    """Draw the mechanism at the instants ``at`` (or ``count`` instants evenly spread over
    the run) over the full paths of the traced points: the coupler-curve figure of the
    mechanism textbooks. A single run's instants are told apart by colour, with a colour bar
    of the time; the variants of a sweep each in its own colour (their instants the later
    darker), told apart as :mod:`mechdsl.outputs.styles` says. With ``labels``, the bodies
    and joints are named (at the last instant drawn)."""
    _need_poses(results)
    fr = frames(results, system)
    ks = snapshot_instants(results, at, count)
    styles = variant_styles(results)
    timed = not results.sweep and len(ks) > 1
    tu = f" [{results.time_unit}]" if results.time_unit else ""
    colorbar = (("t" + tu, _time_cmap(), float(results.times[ks[0]]),
                 float(results.times[ks[-1]])) if timed else styles.colorbar)
    legend = _sweep_legend(styles, fr if results.sweep or timed else None)
    side = "legend" if legend else "bar" if colorbar is not None else None
    fig, ax, size = _figure(fr, f"{os.path.basename(results.source_name)}: "
                            f"t = {', '.join(f'{results.times[k]:g}' for k in ks)}",
                            styles.colors, side)
    cmap = _time_cmap() if timed else None
    for v in range(results.n_variants):
        path_color = "0.3" if timed else styles.colors[v]
        for p in fr.traces.values():
            ax.plot(p[v, :, 0], p[v, :, 1], ls=styles.linestyles[v], lw=1.2,
                    color=path_color, alpha=0.9)
        _ground_centrodes(ax, fr, v, path_color)
        drawn = [k for k in ks if k < results.n_solved[v]]
        for i, k in enumerate(drawn):
            last = i == len(drawn) - 1
            if timed:
                color, alpha = cmap((results.times[k] - results.times[ks[0]])
                                    / max(results.times[ks[-1]] - results.times[ks[0]],
                                          1e-300)), 1.0
            else:
                color, alpha = styles.colors[v], 0.25 + 0.75 * (i + 1) / len(ks)
            _Artists(ax, fr, color, alpha, size, labels and last and v == 0,
                     styles.linestyles[v]).update(v, k)
    if not side:  # a single run at one instant: its traced paths named inside
        _legend(ax, _path_entries(fr, styles.colors[0]), "best")
    _side(fig, ax, legend, colorbar)
    _save(fig, path)


def animate(results: Results, system: System, path: str, fps: int = FPS,
            max_frames: int = MAX_FRAMES, labels: bool = False) -> int:
    """Write an animation (.gif with Pillow; .mp4 with ffmpeg): the mechanism moving, traced
    paths growing, the time shown; axes equal and fixed over the whole motion; the variants
    of a sweep overlaid, told apart as :mod:`mechdsl.outputs.styles` says, the legend and
    colour bar beside the data; with ``labels``, the bodies and joints named. The file is
    written atomically (:func:`mechdsl.writing.atomic_path`): an error or an interrupt
    leaves no part of it. Returns the number of frames written (:func:`frame_count`)."""
    from matplotlib import animation

    _need_poses(results)
    ext = os.path.splitext(path)[1].lower()
    if ext == ".mp4" and not animation.writers.is_available("ffmpeg"):
        raise MechError(f"cannot write {path}: an .mp4 needs ffmpeg on the PATH, which is "
                        "not there; install ffmpeg or write a .gif")
    if ext not in (".gif", ".mp4"):
        raise MechError(f"cannot write {path}: an animation is a .gif or an .mp4")
    fr = frames(results, system)
    ks = _instants(results, max_frames)
    styles = variant_styles(results)
    colors = styles.colors
    legend_entries = _sweep_legend(styles, fr if results.sweep else None)
    side = "legend" if legend_entries else "bar" if styles.colorbar is not None else None
    fig, ax, size = _figure(fr, os.path.basename(results.source_name), colors, side)
    clock = ax.text(0.02, 0.96, "", transform=ax.transAxes, fontsize=9, va="top",
                    parse_math=False)
    lines = {(v, label): ax.plot([], [], ls=styles.linestyles[v], lw=1.2, color=colors[v])[0]
             for v in range(results.n_variants) for label in fr.traces}
    arts = [_Artists(ax, fr, colors[v], 1.0, size, labels and v == 0, styles.linestyles[v])
            for v in range(results.n_variants)]
    for v in range(results.n_variants):  # fixed over the whole animation
        _ground_centrodes(ax, fr, v, colors[v])
    if side:
        legend = _side(fig, ax, legend_entries, styles.colorbar)
    else:
        legend = _legend(ax, _path_entries(fr, colors[0]), "upper right")
    moving = [clock, *lines.values(), *(a for art in arts for a in art.artists)]
    if legend is not None and not side:  # drawn over the moving parts, as in a figure
        moving.append(legend)

    def frame(k: int) -> None:
        for v in range(results.n_variants):
            kv = min(int(k), int(results.n_solved[v]) - 1)
            if kv < 0:
                continue
            arts[v].update(v, kv)
            for label, p in fr.traces.items():
                lines[v, label].set_data(p[v, : kv + 1, 0], p[v, : kv + 1, 1])
        tu = f" {results.time_unit}" if results.time_unit else ""
        clock.set_text(f"t = {results.times[k]:.4g}{tu}")

    if ext == ".gif":
        _write_gif(fig, moving, frame, ks, path, fps)
    else:
        _write_frames(fig, animation.FFMpegWriter(fps=fps), frame, ks, path)
    return len(ks)


def _legend(ax, entries: list, loc: str):
    """The legend inside the axes of a single run's traced paths and centrodes
    (:func:`_path_entries`); None without a trace: an empty legend would only be a box (and
    a warning)."""
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], lw=lw, color=c, ls=ls, label=text)
               for text, c, ls, lw in entries]
    if not handles:
        return None
    return literal(ax.legend(handles=handles, fontsize=7, loc=loc))


class _Blit:
    """The figure's fixed parts drawn once; :meth:`render` draws the ``moving`` artists (in
    the order of their z-order) over a copy of them and gives the canvas's RGBA buffer."""

    def __init__(self, fig, moving: list) -> None:
        self.fig, self.canvas = fig, fig.canvas
        self.moving = sorted(moving, key=lambda a: a.get_zorder())  # stable: ties in order
        for a in self.moving:
            a.set_animated(True)  # left out of a canvas.draw()
        self.canvas.draw()
        self.background = self.canvas.copy_from_bbox(fig.bbox)

    def render(self) -> np.ndarray:
        self.canvas.restore_region(self.background)
        for a in self.moving:
            self.fig.draw_artist(a)
        return np.asarray(self.canvas.buffer_rgba())


class _Palette:
    """Frames as palette images (mode P, one byte a pixel) that share one palette of 256
    colours at most: the colours of the figure's fixed parts and of a few sample frames,
    exact where they are 256 at most, else chosen by median cut (Pillow's, as for a GIF of
    full-colour frames). Every pixel gets the nearest colour of the palette; pixels equal to
    the fixed parts' get theirs without a search, and the colours met are remembered."""

    def __init__(self, background: np.ndarray, samples: list[np.ndarray]) -> None:
        """``background`` (H, W, 4): the fixed parts; ``samples`` (N, 4): the pixels of a few
        frames that differ from them."""
        from PIL import Image

        self.size = (background.shape[1], background.shape[0])
        self.background = _keys(background).copy()
        pixels = np.concatenate([background.reshape(-1, 4), *samples])
        pixels = Image.fromarray(_over_white(pixels)[None])
        colours = pixels.getcolors(256)  # None when there are more
        if colours is not None:
            palette = np.array([c for _, c in colours], dtype=np.uint8)
        else:
            median_cut = getattr(getattr(Image, "Quantize", None), "MEDIANCUT", 0)
            quantized = pixels.quantize(256, method=median_cut)
            used = max(i for _, i in quantized.getcolors(256)) + 1
            palette = np.array(quantized.getpalette()[: 3 * used], dtype=np.uint8).reshape(-1, 3)
        self.palette = palette.astype(float)
        self.palette_bytes = palette.tobytes()
        self.known: dict[int, int] = {}
        self.background_index = self._index_of(self.background)

    def _lookup(self, keys: np.ndarray) -> np.ndarray:
        """Palette indices of distinct colour keys."""
        out = np.empty(len(keys), dtype=np.uint8)
        new = []
        for j, key in enumerate(keys.tolist()):
            idx = self.known.get(key)
            if idx is None:
                new.append(j)
            else:
                out[j] = idx
        for start in range(0, len(new), 4096):  # the nearest colour of the palette
            chosen = keys[new[start : start + 4096]]
            rgb = _over_white(chosen.view(np.uint8).reshape(-1, 4)).astype(float)
            nearest = ((rgb[:, None, :] - self.palette[None]) ** 2).sum(axis=-1).argmin(axis=1)
            out[new[start : start + 4096]] = nearest
            self.known.update(zip(chosen.tolist(), nearest.tolist()))
        return out

    def _index_of(self, keys: np.ndarray) -> np.ndarray:
        """Palette indices of colour keys, by blocks: np.unique's inverse would take 8 bytes
        a pixel, twice over."""
        distinct = np.unique(keys)
        lookup = self._lookup(distinct)
        flat = keys.reshape(-1)
        out = np.empty(flat.shape, dtype=np.uint8)
        for start in range(0, flat.size, 1 << 15):
            block = flat[start : start + (1 << 15)]
            out[start : start + (1 << 15)] = lookup[np.searchsorted(distinct, block)]
        return out.reshape(keys.shape)

    def indices(self, rgba: np.ndarray) -> np.ndarray:
        """The palette index (H, W) of every pixel of the frame ``rgba`` (H, W, 4)."""
        keys = _keys(rgba)
        changed = keys != self.background
        index = self.background_index.copy()
        if changed.any():
            index[changed] = self._index_of(keys[changed])
        return index

    def image(self, indices: bytes):
        """A palette image of the indices (H * W bytes)."""
        from PIL import Image

        im = Image.frombytes("P", self.size, indices)
        im.putpalette(self.palette_bytes)
        return im


def _keys(rgba: np.ndarray) -> np.ndarray:
    """Each pixel's four bytes as one integer (H, W)."""
    return np.ascontiguousarray(rgba).view(np.uint32)[..., 0]


def _over_white(rgba: np.ndarray) -> np.ndarray:
    """RGB (N, 3) of RGBA pixels (N, 4) composed over white (a GIF has no partial alpha)."""
    a = rgba[:, 3:].astype(np.uint16)
    if (a == 255).all():
        return np.ascontiguousarray(rgba[:, :3])
    return ((rgba[:, :3] * a + 255 * (255 - a) + 127) // 255).astype(np.uint8)


#: Sample frames whose colours, with the fixed parts', choose a GIF's palette.
PALETTE_SAMPLES = 4


def _write_gif(fig, moving: list, frame, ks, path: str, fps: int) -> None:
    """Draw frame(k) for every k by blitting, keep its palette indices (compressed: mostly
    the fixed parts' white), and write the GIF with Pillow (which copies each frame as it
    reads it: one palette image of one byte a pixel per frame while the file is written),
    into a temporary file renamed to ``path`` when complete: an error or an interrupt
    leaves no part of it."""
    import zlib

    from ..writing import atomic_path

    with atomic_path(path) as tmp:
        blit = _Blit(fig, moving)
        background = np.array(blit.canvas.buffer_rgba())  # the fixed parts alone
        fixed = _keys(background)
        samples = []  # the pixels of a few frames that differ from the fixed parts
        for k in ks[np.unique(np.linspace(0, len(ks) - 1, PALETTE_SAMPLES).round()
                              .astype(int))]:
            frame(k)
            rgba = blit.render()
            samples.append(rgba[_keys(rgba) != fixed])
        palette = _Palette(background, samples)
        del samples, background
        kept = []
        for k in ks:
            frame(k)
            kept.append(zlib.compress(palette.indices(blit.render()).tobytes(), 1))

        def images():
            for i in range(len(kept)):
                data, kept[i] = kept[i], b""  # Pillow keeps its own copy of the frame
                yield palette.image(zlib.decompress(data))

        frames = images()
        next(frames).save(tmp, format="GIF", save_all=True, append_images=frames,
                          duration=int(1000 / fps), loop=0)


def _write_frames(fig, writer, frame, ks, path: str) -> None:
    """Draw frame(k) for every k and give it to the animation ``writer`` (ffmpeg's, which
    draws the whole figure), into a temporary file renamed to ``path`` when complete; after
    an error or an interrupt the writer is stopped (ffmpeg is left to end) and the
    temporary file removed."""
    import matplotlib

    from ..writing import atomic_path

    with atomic_path(path) as tmp, matplotlib.rc_context({"savefig.bbox": None}):
        writer.setup(fig, tmp, dpi=fig.dpi)
        try:
            for k in ks:
                frame(k)
                writer.grab_frame()
        except BaseException:
            try:  # stop the writer; the first error is the one to report
                writer.finish()
            except Exception:  # noqa: BLE001
                pass
            raise
        writer.finish()


def _save(fig, path: str) -> None:
    save_figure(fig, path)
