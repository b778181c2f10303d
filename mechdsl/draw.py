"""Pictures of the mechanism itself: snapshots over traced paths, and animations.

Each body is drawn as the polygon (three or more points) or the bar (two) through its points
in declaration order, with the outline of its shape where it has one, each point a joint or drive attaches as a small circle, the ground's
points as hatched supports, and the points named by ``trace`` with their paths. Coordinates
come from the run's poses: r^P = r + A(phi) s'^P for every point (Haug eq. 2.6.4).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from .errors import MechError
from .plot import literal, save_figure
from .results import Results
from .system import Sketch, System

#: Frames of an animation at most (instants are sampled evenly when there are more).
MAX_FRAMES = 100
#: Frames per second of an animation.
FPS = 25


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
class _Frames:
    """Every drawn point at every instant: outlines (V, K, P, 2) per body, pins (V, K, 2)."""

    outlines: list[np.ndarray]
    pins: list[np.ndarray]
    traces: dict[str, np.ndarray]
    ground: np.ndarray
    #: per body with a shape: its outline's edges (V, K, E, 2, 2)
    shapes: list[np.ndarray]


def _frames(results: Results, system: System) -> _Frames:
    sk = system.sketch
    nb = system.n_bodies
    outlines = [world(results.poses, i, sk.outlines[i]) for i in range(nb)]
    ground = world(results.poses, nb, sk.outlines[nb])
    pins = [world(results.poses, body, xy) for body, xy in sk.pins]
    shapes = [world(results.poses, i, e) for i, e in enumerate(sk.shapes) if e is not None]
    return _Frames(outlines, pins, paths(results, sk), ground, shapes)


def _need_poses(results: Results) -> None:
    if results.poses is None:
        raise ValueError("the run kept no poses: simulate(..., poses=True)")


def _limits(fr: _Frames) -> tuple[float, float, float, float]:
    pts = [a.reshape(-1, 2) for a in (*fr.outlines, *fr.pins, *fr.traces.values(), fr.ground,
                                      *fr.shapes)]
    allp = np.concatenate(pts)
    allp = allp[np.isfinite(allp).all(axis=1)]
    lo, hi = allp.min(axis=0), allp.max(axis=0)
    pad = 0.08 * max(float((hi - lo).max()), 1e-9)
    return lo[0] - pad, hi[0] + pad, lo[1] - pad, hi[1] + pad


def _instants(results: Results, count: int) -> np.ndarray:
    last = int(results.n_solved.max(initial=0))
    if last == 0:
        raise MechError("no instant was solved: there is nothing to draw")
    return np.unique(np.linspace(0, last - 1, min(count, last)).round().astype(int))


def _variant_labels(results: Results) -> list[str]:
    if not results.sweep:
        return [""]
    return [", ".join(f"{k} = {v[i]:g}" for k, v in results.sweep.items())
            for i in range(results.n_variants)]


def _figure(fr: _Frames, title: str):
    from .plot import new_figure

    # a fixed layout: a layout engine would run again at every frame of an animation
    fig = new_figure(figsize=(7, 5.5))
    fig.subplots_adjust(left=0.1, right=0.97, bottom=0.09, top=0.93)
    ax = fig.subplots()
    x0, x1, y0, y1 = _limits(fr)
    ax.set_xlim(x0, x1)
    ax.set_ylim(y0, y1)
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_title(title, fontsize=10, parse_math=False)  # a file name is no mathtext
    ax.grid(True, lw=0.3, alpha=0.5)
    # ground supports: a hatched triangle under every ground point, fixed over time
    size = 0.03 * max(x1 - x0, y1 - y0)
    from matplotlib.patches import Polygon
    for p in fr.ground[0, 0]:
        tri = [(p[0], p[1]), (p[0] - size, p[1] - 1.6 * size), (p[0] + size, p[1] - 1.6 * size)]
        ax.add_patch(Polygon(tri, closed=True, fill=False, hatch="////", lw=0.8,
                             color="0.35", zorder=1))
    return fig, ax, size


class _Artists:
    """One variant's drawing, as four artists whatever the number of bodies (so that a frame
    of an animation costs a few updates, not one artist per body): the bars (two-point bodies)
    as a line collection, the plates (three points or more) as a polygon collection, single
    points as square markers and the pins as circle markers."""

    def __init__(self, ax, fr: _Frames, color, alpha: float, size: float) -> None:
        from matplotlib.collections import LineCollection, PolyCollection

        self.fr = fr
        self.bars = [i for i, o in enumerate(fr.outlines) if o.shape[2] == 2]
        self.plates = [i for i, o in enumerate(fr.outlines) if o.shape[2] >= 3]
        self.dots = [i for i, o in enumerate(fr.outlines) if o.shape[2] == 1]
        self.bar_art = ax.add_collection(LineCollection([], colors=[color], linewidths=3,
                                                        alpha=alpha, capstyle="round",
                                                        zorder=2))
        self.plate_art = ax.add_collection(PolyCollection([], facecolors=[color],
                                                          edgecolors=[color], alpha=0.3 * alpha,
                                                          linewidths=1.5, zorder=2))
        self.dot_art = ax.plot([], [], "s", color=color, ms=7, alpha=alpha, zorder=2)[0]
        self.pin_art = ax.plot([], [], "o", mfc="white", mec="black", mew=0.8, ms=6,
                               alpha=alpha, zorder=3)[0]
        self.shape_art = ax.add_collection(LineCollection([], colors=["0.2"], linewidths=1.0,
                                                          alpha=alpha, zorder=2))

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
        return [self.bar_art, self.plate_art, self.dot_art, self.pin_art, self.shape_art]


def snapshot(results: Results, system: System, path: str, at: list[float] | None = None,
             count: int = 6) -> None:
    """Draw the mechanism at the instants ``at`` (or ``count`` instants evenly spread over
    the run), the later ones darker, over the full paths of the traced points: the
    coupler-curve figure of the mechanism textbooks. Every variant of a sweep is overlaid in
    its own colour."""
    _need_poses(results)
    fr = _frames(results, system)
    last = int(results.n_solved.max(initial=0))
    if at:
        t = results.times[:last]
        ks = np.unique([int(np.argmin(np.abs(t - a))) for a in at])
    else:
        ks = _instants(results, count)
    fig, ax, size = _figure(fr, f"{os.path.basename(results.source_name)}: "
                            f"t = {', '.join(f'{results.times[k]:g}' for k in ks)}")
    colors = _colors(results.n_variants)
    labels = _variant_labels(results)
    for v in range(results.n_variants):
        for label, p in fr.traces.items():
            ax.plot(p[v, :, 0], p[v, :, 1], "-", lw=1.2, color=colors[v], alpha=0.9,
                    label=f"path of {label}" + (f" ({labels[v]})" if labels[v] else ""))
        for i, k in enumerate(ks):
            if k < results.n_solved[v]:
                _Artists(ax, fr, colors[v], 0.25 + 0.75 * (i + 1) / len(ks), size).update(v, k)
    if fr.traces or results.sweep:
        literal(ax.legend(fontsize=7, loc="best"))
    _save(fig, path)


def animate(results: Results, system: System, path: str, fps: int = FPS,
            max_frames: int = MAX_FRAMES) -> None:
    """Write an animation (.gif with Pillow; .mp4 with ffmpeg): the mechanism moving, traced
    paths growing, the time shown; axes equal and fixed over the whole motion; the variants
    of a sweep overlaid, each in its own colour. The file is written atomically
    (:func:`mechdsl.writing.atomic_path`): an error or an interrupt leaves no part of it."""
    from matplotlib import animation

    _need_poses(results)
    ext = os.path.splitext(path)[1].lower()
    if ext == ".gif":
        writer = _gif_writer(fps)
    elif ext == ".mp4":
        if not animation.writers.is_available("ffmpeg"):
            raise MechError(f"cannot write {path}: an .mp4 needs ffmpeg on the PATH, which is "
                            "not there; install ffmpeg or write a .gif")
        writer = animation.FFMpegWriter(fps=fps)
    else:
        raise MechError(f"cannot write {path}: an animation is a .gif or an .mp4")
    fr = _frames(results, system)
    ks = _instants(results, max_frames)
    fig, ax, size = _figure(fr, os.path.basename(results.source_name))
    colors = _colors(results.n_variants)
    clock = ax.text(0.02, 0.96, "", transform=ax.transAxes, fontsize=9, va="top")
    lines = {(v, label): ax.plot([], [], "-", lw=1.2, color=colors[v])[0]
             for v in range(results.n_variants) for label in fr.traces}
    if results.sweep:
        for v, label in enumerate(_variant_labels(results)):
            ax.plot([], [], "-", color=colors[v], lw=3, label=label)
        literal(ax.legend(fontsize=7, loc="upper right"))
    arts = [_Artists(ax, fr, colors[v], 1.0, size) for v in range(results.n_variants)]

    def frame(k: int):
        changed = [clock]
        for v in range(results.n_variants):
            kv = min(k, int(results.n_solved[v]) - 1)
            if kv < 0:
                continue
            changed += arts[v].update(v, kv)
            for label, p in fr.traces.items():
                lines[v, label].set_data(p[v, : kv + 1, 0], p[v, : kv + 1, 1])
        clock.set_text(f"t = {results.times[k]:.4g}")
        return changed

    _write_frames(fig, writer, frame, ks, path)


def _gif_writer(fps: int):
    """Pillow's GIF writer, which writes its frames only once all were grabbed: its finish()
    would otherwise write a partial GIF after an error or an interrupt (or fail, with none)."""
    from matplotlib import animation

    class Gif(animation.PillowWriter):
        complete = False

        def finish(self) -> None:
            if self.complete:
                super().finish()

    return Gif(fps=fps)


def _write_frames(fig, writer, frame, ks, path: str) -> None:
    """Draw frame(k) for every k and give it to the animation ``writer``, into a temporary
    file renamed to ``path`` when complete; after an error or an interrupt the writer is
    stopped (ffmpeg is left to end) and the temporary file removed."""
    import matplotlib

    from .writing import atomic_path

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
        writer.complete = True
        writer.finish()


def _colors(n: int) -> list:
    import matplotlib
    cmap = matplotlib.colormaps["tab10"]
    return [cmap(i % 10) for i in range(n)]


def _save(fig, path: str) -> None:
    save_figure(fig, path)
