"""The Python API: ``load``/``loads`` give a :class:`Mechanism`, which compiles and simulates.

>>> import mechdsl
>>> mech = mechdsl.load("examples/slider_crank.mech")
>>> res = mech.simulate(span=(0, 0.5), step=0.01, l=3.0)
>>> res["t"], res["slider.x"]
"""

from __future__ import annotations

import os
from typing import Iterable, Mapping, Sequence

from . import expr as E
from .compile import check_structure, compile_model
from .errors import MechError, Source, Span
from .model import Model
from .parse import parse, parse_expr
from .plugins.manager import allowed_plugins, build_registry
from .plugins.registry import Registry
from .results import Results
from .system import System
from .variants import Overrides
from .options import SolverOptions
from .solve import simulate


class Mechanism:
    """A parsed model (``.model``, plain data) and the plugin registry it is run with.

    The registry is built on first use from the entry points (importing only the plugins of
    the types the model uses), plus ``plugins`` given here; pass ``registry`` to share one.
    The model's own ``plugin "module"`` lines import a module only if it is an installed
    entry-point plugin, is given in ``plugins``, or is named in ``allow_plugins`` (or in the
    environment variable ``MECHDSL_ALLOW_PLUGINS``): a model file runs no code by itself.
    """

    def __init__(self, model: Model, *, registry: Registry | None = None,
                 plugins: Iterable[object | str] = (),
                 allow_plugins: Iterable[str] = ()) -> None:
        self.model = model
        self._registry = registry
        self._plugins = tuple(plugins)
        self._allowed = tuple(allow_plugins) + tuple(p for p in self._plugins
                                                     if isinstance(p, str))
        # a registry given by the caller still needs the model's own plugin lines
        self._pending_model_plugins = registry is not None and bool(model.plugins)

    @property
    def registry(self) -> Registry:
        """The plugin registry: entry points (only the plugins of the types the model uses),
        the plugins given to the constructor and the model's ``plugin "module"`` lines."""
        if self._registry is None or self._pending_model_plugins:
            refused = allowed_plugins(self.model.plugins, self._allowed)
            if refused:
                module, span = refused[0]
                raise MechError(
                    f"the model asks to import the Python module '{module}', which is not an "
                    "installed mechdsl plugin; a model file runs no code unless you allow it",
                    span, self.model.source,
                    notes=[f"if you trust it: mechdsl run --allow-plugin {module} ..., "
                           f"MECHDSL_ALLOW_PLUGINS={module}, or "
                           f"mechdsl.load(..., allow_plugins=['{module}'])"])
            asked = list(self._plugins) + [m for m, _ in self.model.plugins]
            if self._registry is None:
                wanted = {c.type_name for c in (*self.model.joints, *self.model.drives)}
                registry = build_registry(asked, wanted=wanted)
            else:
                registry = self._registry.merged(
                    build_registry([m for m, _ in self.model.plugins], entry_points=False))
            spans = {m: span for m, span in self.model.plugins}
            names = {p if isinstance(p, str) else getattr(p, "__name__", "") for p in asked}
            for broken in registry.broken:
                if broken.provider.plugin in names:
                    raise MechError(f"cannot load the plugin '{broken.provider.plugin}': "
                                    f"{broken.reason}", spans.get(broken.provider.plugin),
                                    self.model.source)
            self._registry = registry
            self._pending_model_plugins = False
        return self._registry

    def check(self) -> None:
        """Resolve every name of the model (joint and drive types, their arguments, bodies,
        points, outputs) against the registry, evaluating nothing: the located MechError the
        command line gives for the same mistake (see :func:`mechdsl.compile.check_structure`).
        :func:`load` and :func:`loads` call it."""
        check_structure(self.model, self.registry)

    def compile(self, overrides: Overrides | None = None, *, need_times: bool = True) -> System:
        """Resolve the model against the registry (see :func:`mechdsl.compile.compile_model`)."""
        return compile_model(self.model, self.registry, overrides, need_times=need_times)

    def simulate(
        self,
        *,
        span: tuple[float, float] | None = None,
        step: float | None = None,
        sweep: Mapping[str, Sequence[float]] | None = None,
        params: Mapping[str, float] | None = None,
        options: SolverOptions | None = None,
        poses: bool = False,
        **param_values: float,
    ) -> Results:
        """Compile with the given overrides and solve.

        ``span = (t0, t1)`` and ``step`` replace the file's ``simulate`` line. Params are
        overridden by keyword (``l=2.5``) or through ``params`` (for names that clash with
        the keywords here); ``sweep`` maps param names to lists of values. Every value may
        be a number or, as on the command line (``--set l=3*2``), the text of an expression
        of the params before it (``l="3*2"``, ``sweep={"l": ["r", "2*r"]}``). ``poses``
        keeps every body's pose at every instant in ``Results.poses``.
        """
        names = [p.name for p in self.model.params]

        def value(v, what: str):
            return parse_expr(v, what, names) if isinstance(v, str) else v

        values = {k: value(v, k) for k, v in {**(params or {}), **param_values}.items()}
        sweeps = {k: [value(x, k) for x in ([vs] if isinstance(vs, str) else vs)]
                  for k, vs in (sweep or {}).items()}
        t0, t1 = span if span is not None else (None, None)
        ov = Overrides(params=values, sweeps=sweeps, t0=value(t0, "span"),
                       t1=value(t1, "span"), step=value(step, "step"))
        if options is not None:  # one memory limit for the time grid and the run
            ov.max_memory = options.max_memory
        return simulate(self.compile(ov), options, poses=poses)


def loads(text: str, name: str = "<string>", *, check: bool = True, **kwargs) -> Mechanism:
    """Parse ``.mech`` text and, with ``check``, resolve its names against the plugins
    (:meth:`Mechanism.check`), so that a mistake is a located :class:`MechError` here, not
    later; keyword arguments go to :class:`Mechanism`."""
    mech = Mechanism(parse(text, name), **kwargs)
    if check:
        mech.check()
    return mech


def load(path: str | os.PathLike, *, max_memory: int | None = None, **kwargs) -> Mechanism:
    """Read and parse a ``.mech`` file; keyword arguments go to :func:`loads`. With
    ``max_memory`` (bytes), a file whose parsing could take more is refused before it starts.

    The file is read as data (:func:`mechdsl.reading.read_data`): a regular file of at most
    :data:`mechdsl.reading.MAX_MODEL_BYTES`, else a :class:`MechError` naming it.
    """
    from .parse import normalise
    from .reading import read_data

    path = os.fspath(path)
    raw = read_data(path, "", "MAX_MODEL_BYTES")
    if max_memory is not None:
        from .memory import PARSE_BYTES_PER_BYTE, resident_bytes, within

        try:
            within({"the process so far": resident_bytes(),
                    "parsing the model": PARSE_BYTES_PER_BYTE * len(raw)}, max_memory)
        except MechError as err:
            raise err.with_source(Source(path, "")) from None
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as err:
        # where an editor shows the byte: lines and columns of the text before it, as parsed
        before = normalise(raw[: err.start].decode("utf-8"))
        line = before.count("\n") + 1
        col = len(before) - (before.rfind("\n") + 1) + 1
        raise MechError(f"the file is not valid UTF-8 (byte 0x{raw[err.start]:02x})",
                        Span(line, col, line, col + 1),
                        Source(path, normalise(raw.decode("utf-8", "replace")))) from None
    return loads(text, path, **kwargs)
