"""How the variants of a sweep are told apart in every figure: colours, line styles, and a
colour bar where a colour stands for a number.

* Up to ten variants: the ten colours of matplotlib's ``tab10``, named in a legend.
* One swept param with more: a continuous colour map (``viridis``) over the param's value,
  with a colour bar, so that neighbouring values have neighbouring colours and every value
  is read off the bar instead of a legend of tens of entries.
* Two swept params with more than ten combinations (the seed paper's study: three ramps
  times four rod lengths): the colour for the first param (one of ten colours per value, or
  the colour map over more values), the line style for the second (four styles at most),
  each value named once in the legend.
* Any other sweep: ``tab20`` up to twenty variants, else the colour map over the variant's
  index with a colour bar of it.

A legend of a sweep stands outside the data (right of the axes).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..results import Results

#: the line styles that tell a second swept param's values apart
LINESTYLES = ("-", "--", ":", "-.")
#: the continuous colour map of a swept number
CMAP = "viridis"


@dataclass(frozen=True)
class VariantStyles:
    """Per variant its colour (RGBA) and line style; the legend's entries (label, colour,
    line style); and the colour bar (param name, the colour map, its low and high values)
    where the colour stands for a number."""

    colors: list
    linestyles: list
    legend: list = field(default_factory=list)
    colorbar: tuple | None = None


def variant_styles(results: Results) -> VariantStyles:
    """The styles of ``results``' variants (module docstring)."""
    import matplotlib

    V = results.n_variants
    sweep = {k: np.asarray(v, dtype=float) for k, v in results.sweep.items()}
    tab10 = matplotlib.colormaps["tab10"]
    if not sweep or V <= 10:
        colors = [tab10(v % 10) for v in range(V)]
        legend = [(_label(sweep, v), colors[v], "-") for v in range(V)] if sweep else []
        return VariantStyles(colors, ["-"] * V, legend)
    cmap = matplotlib.colormaps[CMAP]
    names = list(sweep)
    if len(names) <= 2:
        first = sweep[names[0]]
        second = sweep[names[1]] if len(names) == 2 else None
        styles_of = (dict.fromkeys(second.tolist()) if second is not None else {})
        if len(names) == 1 or len(styles_of) <= len(LINESTYLES):
            lo, hi = float(first.min()), float(first.max())
            values = list(dict.fromkeys(first.tolist()))
            if second is None:
                colors = [cmap(_unit(first[v], lo, hi)) for v in range(V)]
                return VariantStyles(colors, ["-"] * V, [], (names[0], cmap, lo, hi))
            style = {value: LINESTYLES[i] for i, value in enumerate(styles_of)}
            linestyles = [style[second[v]] for v in range(V)]
            legend = []
            if len(values) <= 10:  # few values: a colour each, named in the legend
                hue = {value: tab10(i) for i, value in enumerate(values)}
                colors = [hue[first[v]] for v in range(V)]
                legend = [(f"{names[0]} = {value:g}", c, "-") for value, c in hue.items()]
                bar = None
            else:
                colors = [cmap(_unit(first[v], lo, hi)) for v in range(V)]
                bar = (names[0], cmap, lo, hi)
            legend += [(f"{names[1]} = {value:g}", "0.3", ls) for value, ls in style.items()]
            return VariantStyles(colors, linestyles, legend, bar)
    if V <= 20:
        tab20 = matplotlib.colormaps["tab20"]
        colors = [tab20(v) for v in range(V)]
        return VariantStyles(colors, ["-"] * V,
                             [(_label(sweep, v), colors[v], "-") for v in range(V)])
    colors = [cmap(v / (V - 1)) for v in range(V)]
    return VariantStyles(colors, ["-"] * V, [], ("variant", cmap, 0.0, float(V - 1)))


def _unit(x: float, lo: float, hi: float) -> float:
    return 0.5 if hi == lo else (x - lo) / (hi - lo)


def _label(sweep: dict, v: int) -> str:
    return ", ".join(f"{k} = {a[v]:g}" for k, a in sweep.items())


def decorate(fig, axes, legend: list, colorbar: tuple | None, *, cax=None,
             fontsize="small"):
    """The colour bar (label, colour map, low, high) and the legend (entries (label, colour,
    line style, line width)) beside the data, where they have anything to show: the bar in
    ``cax`` (a fixed layout) or beside ``axes`` (a list or one axes), the legend outside the
    first axes, on its right. Returns the legend (None without entries)."""
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize
    from matplotlib.lines import Line2D

    from .plot import literal

    axes = list(np.ravel(axes))
    if colorbar is not None:
        name, cmap, lo, hi = colorbar
        mappable = ScalarMappable(Normalize(lo, hi if hi > lo else lo + 1), cmap)
        bar = (fig.colorbar(mappable, cax=cax) if cax is not None else
               fig.colorbar(mappable, ax=axes, shrink=0.9, pad=0.02))
        bar.set_label(name, parse_math=False)
    if not legend:
        return None
    handles = [Line2D([], [], color=c, ls=ls, lw=lw, label=label)
               for label, c, ls, lw in legend]
    return literal(axes[0].legend(handles=handles, fontsize=fontsize, loc="upper left",
                                  bbox_to_anchor=(1.02, 1.0), borderaxespad=0.0))
