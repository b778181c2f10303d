"""Time-history figures of results. matplotlib is imported here and nowhere else, and only
when a figure is drawn.

Every text mechdsl gives matplotlib (labels with the model's units, titles with file names
and --set values, legends) is drawn with ``parse_math=False``, as written: matplotlib would
read text between two '$' as mathtext, and fail on a bad formula when saving."""

from __future__ import annotations

import math
import os

import numpy as np

from ..results import Results
from .styles import decorate, variant_styles

#: A matplotlib figure being drawn (canvas, artists, the renderer's buffer), and one frame of
#: an animation as the GIF writer keeps it until the file is written (a 700 x 550 palette
#: image, 0.38 MiB measured, with margin).
FIGURE_BYTES = 20 * 2**20
FRAME_BYTES = 2**19


def options(settings: dict, path: str) -> dict:
    """The writer's keywords from the run's settings (:func:`mechdsl.outputs.settings`)."""
    return {"title": settings["title"]}


def figure_parts(frames: int = 1) -> dict[str, int]:
    """What a figure adds to a run: matplotlib, a figure drawn and ``frames`` frames kept."""
    return {"import matplotlib": 0, "a figure": FIGURE_BYTES + FRAME_BYTES * frames}


def memory(system, path: str, settings: dict) -> dict[str, int]:
    """What the plot adds to the run (:attr:`mechdsl.outputs.Format.memory`)."""
    return figure_parts()


def summary(results: Results, path: str, settings: dict) -> str:
    """The line ``mechdsl run`` prints of the plot written to ``path``."""
    n = len(results.labels)
    return f"{path}: plot of {n} quantit{'ies' if n != 1 else 'y'}"

def _constant_range(ax, values) -> None:
    """A quantity constant up to round-off is drawn flat, not as magnified noise."""
    finite = values[np.isfinite(values)]
    if not finite.size:
        return
    lo, hi = float(finite.min()), float(finite.max())
    size = max(abs(lo), abs(hi))
    if hi - lo <= 1e-9 * size or hi == lo:
        mid = 0.5 * (lo + hi)
        pad = 0.1 * abs(mid) if mid else 1.0
        ax.set_ylim(mid - pad, mid + pad)
        ax.ticklabel_format(axis="y", useOffset=False)


def plot_results(results: Results, path: str | os.PathLike, title: str | None = None,
                 labels: list[str] | None = None) -> None:
    """One panel per output quantity against time, sweep variants overlaid, told apart as
    :mod:`mechdsl.outputs.styles` says (a legend outside the data, a colour bar where a
    colour stands for a swept number).

    The format follows the file name's extension (png, pdf, svg); the file is written under a
    temporary name and renamed when complete.
    """
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    labels = list(labels or results.labels)
    if results.reduced:
        return plot_reduced(results, path, title, labels)
    n = max(1, len(labels))
    ncols = 1 if n <= 4 else 3
    nrows = math.ceil(n / ncols)
    fig = Figure(figsize=(5.2 * ncols if ncols > 1 else 7.0, 1.1 + 2.1 * nrows),
                 layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(nrows, ncols, sharex=True, squeeze=False).ravel()
    t = results.times
    styles = variant_styles(results)
    for ax, label in zip(axes, labels):
        for v in range(results.n_variants):
            k = int(results.n_solved[v])
            ax.plot(t[:k], results.data[label][v, :k], lw=1.4, color=styles.colors[v],
                    ls=styles.linestyles[v])
        unit = results.units.get(label)
        ax.set_ylabel(f"{label} [{unit}]" if unit else label, parse_math=False)
        ax.grid(True, alpha=0.3)
        ax.margins(x=0)
        _constant_range(ax, results.data[label])
    for ax in axes[len(labels):]:
        ax.set_visible(False)
    # the lowest panel of each column carries the time axis
    for col in range(ncols):
        shown = [i for i in range(col, len(labels), ncols)]
        if shown:
            bottom = axes[shown[-1]]
            bottom.set_xlabel(f"t [{results.time_unit}]" if results.time_unit else "t",
                              parse_math=False)
            bottom.xaxis.set_tick_params(labelbottom=True)
    decorate(fig, axes[:len(labels)], [(text, c, ls, 2) for text, c, ls in styles.legend],
             styles.colorbar)
    fig.suptitle(title or os.path.basename(results.source_name), parse_math=False)
    save_figure(fig, path)


def plot_reduced(results: Results, path: str | os.PathLike, title: str | None,
                 labels: list[str]) -> None:
    """One panel per reduction against the first swept param; with a second swept param, a
    curve per value of it (a study of more params is a table: read its CSV or store)."""
    params = list(results.sweep)
    fig = new_figure(figsize=(7.0, 1.1 + 2.1 * len(labels)), layout="constrained")
    axes = fig.subplots(len(labels), 1, sharex=True, squeeze=False).ravel()
    x = np.asarray(results.sweep[params[0]])
    groups = [np.ones(len(x), bool)]
    if len(params) > 1:
        y = np.asarray(results.sweep[params[1]])
        groups = [(y == value) for value in dict.fromkeys(y.tolist())]
    for ax, label in zip(axes, labels):
        values = np.asarray(results.reduced[label])
        for members in groups:
            legend = (f"{params[1]} = {results.sweep[params[1]][members][0]:g}"
                      if len(params) > 1 else None)
            ax.plot(x[members], values[members], marker="." if members.sum() < 60 else None,
                    lw=1.4, label=legend)
        unit = results.units.get(label)
        ax.set_ylabel(f"{label} [{unit}]" if unit else label, parse_math=False)
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel(params[0], parse_math=False)
    if len(params) > 1 and len(groups) <= 12:
        literal(axes[0].legend(fontsize="small", loc="best"))
    fig.suptitle(title or os.path.basename(results.source_name), parse_math=False)
    save_figure(fig, path)


def literal(legend):
    """Show a legend's entries as written: a '$' in them is no mathtext. Returns the legend."""
    for text in legend.get_texts():
        text.set_parse_math(False)
    return legend


def new_figure(**kwargs):
    """A matplotlib Figure on the Agg canvas, outside pyplot's global state."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(**kwargs)
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig, path: str | os.PathLike) -> None:
    """Save in the format of the file name's extension (png by default), atomically
    (:func:`mechdsl.writing.atomic_path`)."""
    from ..writing import atomic_path

    path = os.fspath(path)
    ext = os.path.splitext(path)[1].lstrip(".").lower() or "png"
    with atomic_path(path) as tmp:
        fig.savefig(tmp, format=ext, dpi=110)

