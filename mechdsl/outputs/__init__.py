"""What a run writes, one module per kind: the CSV of the results and its reader
(:mod:`.csv`), time-history plots (:mod:`.plot`), drawings and animations of the mechanism
(:mod:`.draw`), meshes for ParaView (:mod:`.export`), a page to open offline (:mod:`.html`).
matplotlib and meshio are imported in
those modules only, and only when something is drawn or written.

:data:`FORMATS` is the one registry of them: for each kind of output, the option of
``mechdsl run`` that asks for it, the file names it writes (by suffix) and its writer,
imported when first used. A new format is an entry here and a module beside these.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from importlib import import_module

from ..errors import MechError

#: Image formats matplotlib writes without extra software, by file suffix.
IMAGES = frozenset({"png", "pdf", "svg", "svgz", "eps", "ps", "jpg", "jpeg", "tif", "tiff",
                    "webp", "pgf"})


@dataclass(frozen=True)
class Format:
    """One kind of output.

    ``option`` asks for it on the command line (``arg``: its attribute in the parsed
    arguments); ``suffixes`` are the file suffixes it writes, lower case without the dot
    (None: any name), and ``refusal`` says what to write instead of another one
    (``{suffix}`` and ``{choices}`` are filled in). ``writer`` is its function, as
    ``module:name`` in this package. A writer of the ``mechanism`` (a drawing, an export)
    is called as ``writer(results, system, path, **options)`` and needs every body's pose
    at every solved instant (``simulate(..., poses=True)``) and at least one such instant;
    the others as ``writer(results, path, **options)``.
    """

    kind: str
    option: str
    arg: str
    suffixes: frozenset[str] | None
    refusal: str
    writer: str
    mechanism: bool = False

    def check(self, path: str, option: str | None = None) -> None:
        """Refuse a file name whose suffix this format does not write (a MechError naming
        ``option``, by default the format's own)."""
        suffix = os.path.splitext(path)[1].lstrip(".").lower()
        if self.suffixes is not None and suffix not in self.suffixes:
            choices = ", ".join(sorted(self.suffixes))
            raise MechError(f"{option or self.option} {path}: "
                            + self.refusal.format(suffix=suffix, choices=choices))

    def write(self, results, system, path: str, **options):
        """Write ``results`` (of ``system``) to ``path`` with this format's writer."""
        module, name = self.writer.split(":")
        function = getattr(import_module(f"{__name__}.{module}"), name)
        if self.mechanism:
            return function(results, system, path, **options)
        return function(results, path, **options)


_IMAGE = "unknown image format '{suffix}'; use one of {choices}"

#: Every kind of output, in the order ``mechdsl run`` writes them: the CSV first.
FORMATS: dict[str, Format] = {f.kind: f for f in (
    Format("csv", "-o", "output", None, "", "csv:write_csv"),
    Format("plot", "--plot", "plot", IMAGES, _IMAGE, "plot:plot_results"),
    Format("snapshot", "--snapshot", "snapshot", IMAGES, _IMAGE, "draw:snapshot",
           mechanism=True),
    Format("animation", "--animate", "animate", frozenset({"gif", "mp4"}),
           "an animation is a .gif or an .mp4", "draw:animate", mechanism=True),
    Format("export", "--export", "export", frozenset({"xdmf", "vtu", "dxf", "svg"}),
           "use .xdmf (one time series) or .vtu (one file per instant, with a .pvd index) "
           "for ParaView, .dxf or .svg for a drawing", "export:export", mechanism=True),
    Format("page", "--html", "html", frozenset({"html", "htm"}),
           "a page is an .html file", "html:write_page", mechanism=True),
)}
