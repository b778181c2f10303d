"""What a run writes, one module per kind: the CSV of the results and its reader
(:mod:`.csv`), time-history plots (:mod:`.plot`), drawings and animations of the mechanism
(:mod:`.draw`), meshes for ParaView (:mod:`.export`), a page to open offline (:mod:`.html`).
matplotlib and meshio are imported in
those modules only, and only when something is drawn or written.

:data:`FORMATS` is the one registry of them: for each kind of output, the option of
``mechdsl run`` that asks for it (the command line's flag is made from the entry), the file
names it writes (by suffix), its writer, the settings of the run it takes and what writing it
adds to the run's memory (:func:`outputs_bytes` adds them up for the memory plan), each a
function of its module imported when first used. A new format is one module beside these and
one entry here (``--html``'s page, :mod:`.html`, is written that way).
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
    at every solved instant (``simulate(..., poses=True)``; and their rates,
    ``rates=True``, where the model traces centrodes, ``trace ic(A, B)``) and at least one
    such instant; the others as ``writer(results, path, **options)``.
    """

    kind: str
    option: str
    arg: str
    suffixes: frozenset[str] | None
    refusal: str
    writer: str
    mechanism: bool = False
    #: its writer shows the bodies' velocities and accelerations too
    #: (``simulate(..., rates=True)``)
    rates: bool = False
    #: the flag's other names, its metavar and its help (``mechdsl run --help``)
    aliases: tuple[str, ...] = ()
    metavar: str = "FILE"
    help: str = ""
    #: ``module:name`` of ``options(settings, path) -> dict``: the writer's keywords from the
    #: run's settings (:func:`settings`); None: the writer takes none
    options: str | None = None
    #: ``module:name`` of ``memory(system, path, settings) -> {part: bytes}``: what writing
    #: it adds to the run (a library's import as the part ``"import NAME"``, NAME a key of
    #: :data:`mechdsl.memory.IMPORT_BYTES`, its value ignored); parts of the same name are
    #: shared between formats (matplotlib is imported once): :func:`outputs_bytes` takes
    #: each part's largest value
    memory: str | None = None
    #: ``module:name`` of ``summary(results, path, settings) -> str``: the line ``mechdsl
    #: run`` prints of what it wrote (None: it prints none)
    summary: str | None = None

    def check(self, path: str, option: str | None = None) -> None:
        """Refuse a file name whose suffix this format does not write (a MechError naming
        ``option``, by default the format's own)."""
        suffix = os.path.splitext(path)[1].lstrip(".").lower()
        if self.suffixes is not None and suffix not in self.suffixes:
            choices = ", ".join(sorted(self.suffixes))
            raise MechError(f"{option or self.option} {path}: "
                            + self.refusal.format(suffix=suffix, choices=choices))

    def add_flag(self, parser) -> None:
        """This format's flag on an argparse parser (``mechdsl run``)."""
        parser.add_argument(self.option, *self.aliases, dest=self.arg, metavar=self.metavar,
                            help=self.help)

    def write(self, results, system, path: str, settings: dict | None = None, **options):
        """Write ``results`` (of ``system``) to ``path`` with this format's writer, with its
        keywords from the run's ``settings`` (:func:`settings`) and ``options``."""
        if settings is not None:
            options = {**self.options_of(settings, path), **options}
        function = _function(self.writer)
        if self.mechanism:
            return function(results, system, path, **options)
        return function(results, path, **options)

    def options_of(self, settings: dict, path: str) -> dict:
        """The writer's keywords from the run's ``settings`` for ``path``."""
        return {} if self.options is None else _function(self.options)(settings, path)

    def summary_of(self, results, path: str, settings: dict) -> str | None:
        """The line that says what was written to ``path`` (None where the format has
        none)."""
        return None if self.summary is None else _function(self.summary)(results, path,
                                                                          settings)

    def memory_parts(self, system, path: str, settings: dict) -> dict[str, int]:
        """What writing ``path`` adds to the run of ``system``, by part (bytes)."""
        return {} if self.memory is None else _function(self.memory)(system, path, settings)


def _function(spec: str):
    """The function ``module:name`` of this package, its module imported now."""
    module, name = spec.split(":")
    return getattr(import_module(f"{__name__}.{module}"), name)


def settings(*, title: str | None = None, at: list[float] | None = None, labels: bool = False,
             frames: int | None = None) -> dict:
    """The run's settings that the formats read (each takes those it needs: its
    ``options``): the plot's ``title``, the instants ``at`` of drawings and exports, whether
    drawings name the bodies (``labels``), and the frames (``frames``: of an animation, of
    an export at most; None: each format's default)."""
    return {"title": title, "at": at, "labels": labels, "frames": frames}


def outputs_bytes(system, asked: dict[str, str], run_settings: dict) -> int:
    """What writing the outputs ``asked`` ({kind: path}) adds to the run of ``system``: for
    each part named by a format, its largest value (a library is imported once, a figure
    drawn at a time), summed over the parts; the libraries' sizes from
    :data:`mechdsl.memory.IMPORT_BYTES`."""
    from ..memory import IMPORT_BYTES

    parts: dict[str, int] = {}
    for kind, path in asked.items():
        for part, size in FORMATS[kind].memory_parts(system, path, run_settings).items():
            parts[part] = max(parts.get(part, 0), size)
    return sum(IMPORT_BYTES[part[7:]] if part.startswith("import ") else size
               for part, size in parts.items())


_IMAGE = "unknown image format '{suffix}'; use one of {choices}"

#: Every kind of output, in the order ``mechdsl run`` writes them: the CSV first.
FORMATS: dict[str, Format] = {f.kind: f for f in (
    Format("csv", "-o", "output", None, "", "csv:write_csv", aliases=("--output",),
           metavar="OUT.csv", help="write the results as CSV ('-' for standard output)"),
    Format("plot", "--plot", "plot", IMAGES, _IMAGE, "plot:plot_results", metavar="OUT.png",
           help="draw the time histories", options="plot:options", memory="plot:memory",
           summary="plot:summary"),
    Format("snapshot", "--snapshot", "snapshot", IMAGES, _IMAGE, "draw:snapshot",
           mechanism=True, metavar="OUT.png",
           help="draw the mechanism at a few instants over the traced paths",
           options="draw:snapshot_options", memory="draw:snapshot_memory",
           summary="draw:snapshot_summary"),
    Format("animation", "--animate", "animate", frozenset({"gif", "mp4"}),
           "an animation is a .gif or an .mp4", "draw:animate", mechanism=True,
           metavar="OUT.gif", help="write an animation of the motion (.gif; .mp4 with ffmpeg)",
           options="draw:animation_options", memory="draw:animation_memory",
           summary="draw:animation_summary"),
    Format("export", "--export", "export", frozenset({"xdmf", "vtu", "dxf", "svg"}),
           "use .xdmf (one time series) or .vtu (one file per instant, with a .pvd index) "
           "for ParaView, .dxf or .svg for a drawing", "export:export", mechanism=True,
           rates=True,
           metavar="OUT.xdmf",
           help="write the motion as meshes for ParaView: .xdmf (a time series) or .vtu (a "
                "file per instant and a .pvd index)",
           options="export:options", memory="export:memory", summary="export:summary"),
    Format("page", "--html", "html", frozenset({"html", "htm"}),
           "a page is an .html file", "html:write_page", mechanism=True, rates=True,
           metavar="OUT.html",
           help="write one page that animates the run and plots its outputs, offline, "
                "without a server (every variant of a sweep)", memory="html:memory",
           summary="html:summary"),
)}
