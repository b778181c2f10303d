"""The Python API: ``load``/``loads`` give a :class:`Mechanism`, which compiles, checks and
simulates.

>>> import mechdsl
>>> mech = mechdsl.load("examples/slider_crank.mech")
>>> res = mech.simulate(span=(0, 0.5), step=0.01, l=3.0)
>>> res["t"], res["slider.x"]
>>> print(mech.check())       # what `mechdsl check` prints
"""

from __future__ import annotations

import os
from dataclasses import dataclass, fields
from typing import Iterable, Mapping, Sequence

import numpy as np

from .compiled import equations as eq
from .compiled.compile import check_structure, compile_model
from .compiled.files import read_files, read_tables
from .compiled.kernels import Kernels
from .compiled.system import System
from .compiled.variants import Overrides, known_param
from .errors import MechError, NumericalError, Source, Span
from .grammar import (Model, normalise, parse, parse_expr, parse_expr_list, parse_reductions,
                      parse_traces)
from .grammar.expr import to_text
from .plugins.manager import allowed_plugins, build_registry
from .plugins.registry import Registry
from .results import Results
from .solve import SolverOptions, assemble, simulate
from .solve.diagnose import col_scale, singularity
from .solve.linalg import factor
from .solve.mobility import Freedom, freedom, redundancy_warning, report
from .solve.newton import use_sparse


#: the compiled models a Mechanism keeps (distinct overrides, the last used kept) ...
KEEP_COMPILED = 4
#: ... each of at most this many sweep variants (a study's chunks are compiled once each)
KEEP_VARIANTS = 64


class _Compiled:
    """The compiled models a :class:`Mechanism` keeps, by the key of their overrides: the
    last :data:`KEEP_COMPILED` used. A lock keeps it whole where threads share the mechanism
    (a server re-solving on every request)."""

    def __init__(self) -> None:
        import threading

        self._lock = threading.Lock()
        self._systems: dict[tuple, System] = {}
        #: counts the models: what was compiled for an earlier one is not kept for this one
        self.generation = 0
        #: per family of overrides (all but the params' values): None once compiled, then
        #: the model compiled without folded values that serves new values
        self._families: dict[tuple, System | None] = {}
        #: the compiled form of the model's expressions (compile_model's ``memo``)
        self.memo: dict = {}

    def get(self, key: tuple | None) -> System | None:
        if key is None:
            return None
        with self._lock:
            kernels = self._systems.pop(key, None)
            if kernels is not None:
                self._systems[key] = kernels  # the most recently used last
            return kernels

    def put(self, key: tuple, kernels: Kernels, generation: int) -> None:
        with self._lock:
            if generation != self.generation:
                return  # compiled from a model replaced meanwhile
            self._systems.pop(key, None)
            self._systems[key] = kernels
            while len(self._systems) > KEEP_COMPILED:
                del self._systems[next(iter(self._systems))]

    def seen(self, family: tuple) -> bool:
        """Whether a model of this family (the same overrides but for param values) was
        compiled before."""
        with self._lock:
            return family in self._families

    def template(self, family: tuple) -> Kernels | None:
        """The family's model compiled without folded values, if one was."""
        with self._lock:
            return self._families.get(family)

    def note(self, family: tuple, template: Kernels | None, generation: int) -> None:
        with self._lock:
            if generation != self.generation:
                return
            self._families.pop(family, None)
            self._families[family] = template
            while len(self._families) > KEEP_COMPILED:
                del self._families[next(iter(self._families))]

    def clear(self) -> None:
        with self._lock:
            self.generation += 1
            self._systems.clear()
            self._families.clear()
            self.memo.clear()

    def __getstate__(self) -> dict:
        return {}  # a copy sent to another process compiles there (a lock does not travel)

    def __setstate__(self, state: dict) -> None:
        self.__init__()


def _exact(value: object) -> object:
    """A value of the overrides as part of a key: a number by its bits (0.0 and -0.0 differ,
    as they may in atan2), a mapping and a list item by item, anything else (an expression)
    by its identity; TypeError for what is not compared (an array)."""
    if value is None or isinstance(value, (bool, str)):
        return value
    if isinstance(value, (int, float, np.number)):
        return ("number", float(value).hex())
    if isinstance(value, Mapping):
        return ("map", tuple(sorted((str(k), _exact(v)) for k, v in value.items())))
    if isinstance(value, (list, tuple)):
        return ("list", tuple(_exact(v) for v in value))
    if isinstance(value, np.ndarray):
        raise TypeError("an array is not compared")
    return ("object", _Same(value))


class _Same:
    """An object as part of a key by its identity (an expression given as text is parsed
    anew at each call: it never matches another, and nothing recurses over its tree, which
    may be thousands of levels deep)."""

    __slots__ = ("obj",)

    def __init__(self, obj: object) -> None:
        self.obj = obj  # held: its id cannot be reused while the key lives

    def __hash__(self) -> int:
        return id(self.obj)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, _Same) and other.obj is self.obj


def _family_key(ov: Overrides | None, need_times: bool) -> tuple | None:
    """The key of the overrides but for the params' values: models that differ only in
    those share traced code. None for sweeps and tables (compiled for their values)."""
    from dataclasses import replace

    ov = ov or Overrides()
    if ov.sweeps or ov.table is not None or ov.variant_range is not None:
        return None
    return _overrides_key(replace(ov, params={}), need_times)


#: the fields of :class:`Overrides`, in order (what a key of overrides is made of)
_FIELDS = tuple(f.name for f in fields(Overrides))


def _overrides_key(ov: Overrides | None, need_times: bool) -> tuple | None:
    """What identifies a compiled model of this mechanism: every field of the overrides,
    exactly; None where they cannot be compared (a table of variants, numpy arrays: an
    optimiser's population, compiled once each)."""
    ov = ov or Overrides()
    if ov.table is not None:
        return None
    try:
        return (bool(need_times), *((name, _exact(getattr(ov, name))) for name in _FIELDS))
    except TypeError:
        return None


@dataclass(frozen=True)
class CheckReport:
    """What ``mechdsl check`` prints (:meth:`Mechanism.check`): what the model declares,
    its assembly at t0, the mobility by rank and the conditioning there.

    Counts of the compiled model: ``bodies`` (moving), their ``coordinates`` (3 each),
    ``joints`` and their ``equations``, ``drives``. Once assembled at ``t0``: ``mobility`` =
    coordinates - ``rank`` (the rank of the joint equations' Jacobian at the assembled
    configuration of the first variant), ``redundant`` naming the redundant equations ('' if
    none), ``condition`` the largest condition number of the scaled Jacobian over the
    variants. ``lines`` are what was found, ``verdict`` the conclusion ("ok: assembles at
    t = ..."), '' when ``error`` stopped the check: the mechanism does not assemble, is not
    fully driven, or is singular at t0 (the MechError the command line reports). ``warnings``
    are for the user although the check went on (redundant constraints left out).
    """

    source: str
    bodies: int
    coordinates: int
    joints: int
    equations: int
    drives: int
    t0: float
    lines: tuple[str, ...]
    verdict: str = ""
    mobility: int | None = None
    rank: int | None = None
    redundant: str = ""
    condition: float | None = None
    warnings: tuple[str, ...] = ()
    error: MechError | None = None
    #: the degrees of freedom left to the forward dynamics (n - rank of the joints' and
    #: drives' equations); None for a fully driven model
    free: int | None = None

    @property
    def ok(self) -> bool:
        return self.error is None

    @property
    def text(self) -> str:
        """The report as ``mechdsl check`` prints it."""
        return "\n".join(self.lines + ((self.verdict,) if self.verdict else ()))

    def __str__(self) -> str:
        return self.text


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
        self._compiled = _Compiled()
        self.model = model
        self._registry = registry
        self._plugins = tuple(plugins)
        self._allowed = tuple(allow_plugins) + tuple(p for p in self._plugins
                                                     if isinstance(p, str))
        # a registry given by the caller still needs the model's own plugin lines
        self._pending_model_plugins = registry is not None and bool(model.plugins)

    @property
    def model(self) -> Model:
        """The parsed model (plain data). Setting another one forgets the compiled models
        kept for the old one."""
        return self._model

    @model.setter
    def model(self, model: Model) -> None:
        self._model = model
        self._compiled.clear()

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
                wanted = {c.type_name for c in
                          (*self.model.joints, *self.model.drives, *self.model.forces,
                           *self.model.initials)}
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

    def check_names(self) -> None:
        """Resolve every name of the model (joint and drive types, their arguments, bodies,
        points, outputs) against the registry, evaluating nothing: the located MechError the
        command line gives for the same mistake (see
        :func:`mechdsl.compiled.compile.check_structure`). :func:`load` and :func:`loads`
        call it."""
        check_structure(self.model, self.registry, self._compiled.memo)

    def check(self, overrides: Overrides | None = None) -> CheckReport:
        """Compile (with ``overrides``) and check the mechanism as ``mechdsl check`` does:
        what it declares, its assembly at t0 (the simulated span's start, else 0), the
        mobility by rank and redundancy at the assembled configuration, and the conditioning
        of the Jacobian there. A model that cannot be compiled raises its MechError; a
        mechanism that does not assemble, is not fully driven or is singular at t0 gives a
        report whose ``error`` says so."""
        kernels = self.compile(overrides, need_times=self.model.simulate is not None)
        system = kernels.system
        drives = len(system.drive_rows)
        lines = _structure(self.model, kernels)
        t0 = float(system.times[0]) if system.times is not None else 0.0

        def done(**found) -> CheckReport:
            found["warnings"] = (*system.warnings, *found.get("warnings", ()))
            return CheckReport(source=system.source.name, bodies=len(system.body_names),
                               coordinates=system.n, joints=len(system.constraints) - drives,
                               equations=system.m - drives, drives=drives, t0=t0,
                               lines=tuple(lines), **found)

        opts = SolverOptions().for_size(system.n_bodies)
        from .solve.mobility import NotFullyDriven
        from .solve.run import method_for

        # the run's own choice: forward dynamics where the count or, at the assembly, the
        # rank leaves degrees of freedom and the model has masses
        if method_for(kernels) == "dynamic":
            return self._check_dynamic(kernels, lines, done, opts)
        try:
            asm = assemble(kernels, t0, opts)
        except NotFullyDriven as err:
            if kernels.dynamics is not None:
                return self._check_dynamic(kernels, lines, done, opts)
            return done(error=err)
        except MechError as err:  # not fully driven, a plugin's defect
            return done(error=err)
        if not asm.ok.all():
            return done(error=NumericalError(asm.messages[0], source=system.source))
        lines.append(f"assembled at t = {t0:g}:")
        width = max(len(b) for b in system.body_names)
        for i, b in enumerate(system.body_names):
            x, y, phi = (0.0 if abs(c) < 1e-14 * s else c for c, s in
                         zip(asm.q[0, 3 * i : 3 * i + 3], (system.scale[0], system.scale[0], 1)))
            lines.append(f"  {b:<{width}}  x = {x:< 12.6g} y = {y:< 12.6g} phi = {phi:.6g}")
        D = col_scale(system)
        mobility, rank, redundant = report(kernels.variant(0), asm.q[0], D[0, 0])
        equations = system.m - drives
        extra = f", {equations - rank} redundant" if equations > rank else ""
        lines.append(f"mobility {mobility} = {system.n} coordinates - {rank} independent joint "
                     f"equations ({equations} in all{extra}, rank of Phi_q at the assembled "
                     f"configuration); {_count(drives, 'drive')}: fully driven")
        if redundant:
            lines.append(f"redundant: {redundant}")
        found = dict(mobility=mobility, rank=rank, redundant=redundant)
        warning = redundancy_warning(system, asm.mobility) if asm.mobility is not None else None
        if warning:
            found["warnings"] = (warning,)
        rows = asm.mobility.rows
        jac = eq.solver_jacobian(kernels, asm.q[:, None], rows, use_sparse(system, opts, rows))
        rcond = factor(jac, D).rcond[:, 0]
        bad = np.flatnonzero(~(rcond >= opts.singular_rcond))
        if bad.size:
            v = int(bad[0])
            cond, names = singularity(kernels, asm.q[v], v)
            return done(**found, error=NumericalError(
                f"the Jacobian is singular at the assembled configuration (condition number "
                f"{cond:.3g}); dependent equations involve {names}", source=system.source))
        variants = f" (all {system.n_variants} sweep variants)" if system.n_variants > 1 else ""
        return done(**found, condition=float(1 / rcond.min()),
                    verdict=f"ok: assembles at t = {t0:g}{variants}; scaled Jacobian "
                            f"condition number {1 / rcond.min():.3g}")

    def _check_dynamic(self, kernels: Kernels, lines: list[str], done, opts) -> "CheckReport":
        """:meth:`check` of a mechanism with free degrees of freedom and masses: its
        assembly, its mobility, and whether its equations of motion can be solved at t0."""
        from .solve.dynamic import DynamicRun

        system = kernels.system
        run = DynamicRun(kernels, opts)
        q0, trouble = run.initial_state()
        if q0 is None:
            return done(error=NumericalError(trouble, source=system.source))
        t0 = float(system.times[0]) if system.times is not None else 0.0
        lines.append(f"assembled at t = {t0:g}:")
        width = max(len(b) for b in system.body_names)
        for i, b in enumerate(system.body_names):
            x, y, phi = q0[3 * i : 3 * i + 3]
            lines.append(f"  {b:<{width}}  x = {x:< 12.6g} y = {y:< 12.6g} phi = {phi:.6g}")
        D = col_scale(system)
        mobility, rank, redundant = report(kernels.variant(0), q0, D[0, 0])
        # the drives fix some of the joints' degrees of freedom: n - rank of the joints' and
        # drives' equations together are left
        dof = freedom(kernels.variant(0), q0, D[0, 0])
        lines.append(_freedom_line(dof))
        found = dict(mobility=mobility, rank=rank, redundant=redundant, free=dof.free)
        warnings = list(run.warnings)
        if trouble is None:  # the velocities it starts with, stated
            from .solve.initial import velocities

            warnings += velocities(kernels, 0, t0, q0, D[0, 0], opts)[1]
        if warnings:
            found["warnings"] = tuple(warnings)
        if trouble is not None:
            return done(**found, error=NumericalError(trouble, source=system.source))
        return done(**found, verdict=f"ok: assembles at t = {t0:g}; the equations of motion "
                                     "are regular there")

    def compile(self, overrides: Overrides | None = None, *, need_times: bool = True
                ) -> Kernels:
        """Resolve the model against the registry (see
        :func:`mechdsl.compiled.compile.compile_model`): the compiled model's data
        (``.system``, plain and read-only) and the code generated for it.

        The solvers keep their state apart from both. The mechanism keeps the last few it
        compiled (of at most :data:`KEEP_VARIANTS` variants: a single run or a small sweep,
        not a study's chunks), each with the plans its first solve made, and gives the same
        object again for the same overrides (numbers compared by their bits, expressions by
        identity), so that solving a model again costs the solve alone. New values of params
        alone run code traced once for them all (:meth:`_template`)."""
        key = _overrides_key(overrides, need_times)
        generation = self._compiled.generation
        found = self._compiled.get(key)
        if found is not None:
            return found
        family = _family_key(overrides, need_times)
        if family is None or not self._compiled.seen(family):
            # the first values of these overrides (or a sweep): the code for them, folded
            kernels = compile_model(self.model, self.registry, overrides, need_times=need_times,
                                    memo=self._compiled.memo)
            if family is not None:
                self._compiled.note(family, None, generation)
        else:
            # other values of params seen before: code traced once where every value that a
            # param changes is a param of the code serves them all (compile_model's reuse)
            template = self._compiled.template(family)
            if template is None:
                template = self._template(overrides, need_times)
                self._compiled.note(family, template, generation)
            kernels = compile_model(self.model, self.registry, overrides, need_times=need_times,
                                    reuse=template, memo=self._compiled.memo)
        if key is not None and kernels.system.n_variants <= KEEP_VARIANTS:
            self._compiled.put(key, kernels, generation)
        return kernels

    def _template(self, overrides: Overrides | None, need_times: bool) -> Kernels:
        """The model compiled to serve other values of its params: for two variants, these
        values and every param moved a little (each by its own small fraction), so that the
        traced code holds as constants only the values no param changes; where that cannot
        be compiled (a param sets the time grid, which must be the same in all variants),
        compiled without folding any value."""
        from dataclasses import replace

        from .compiled.variants import evaluate

        ov = overrides or Overrides()
        try:
            env = evaluate(self.model, ov).env
            table = {}
            for k, (name, value) in enumerate(env.items()):
                x = float(value[0])
                nudge = 1e-3 * (1 + (0.6180339887498949 * (k + 1)) % 1)
                table[name] = np.array([x, x + (abs(x) + 1.0) * nudge])
            return compile_model(self.model, self.registry,
                                 replace(ov, params={}, table=table or None),
                                 need_times=need_times)
        except MechError:
            return compile_model(self.model, self.registry, ov, need_times=need_times,
                                 fold=False)

    def simulate(
        self,
        *,
        span: tuple[float, float] | None = None,
        step: float | None = None,
        sweep: Mapping[str, Sequence[float]] | None = None,
        params: Mapping[str, float] | None = None,
        options: SolverOptions | None = None,
        poses: bool = False,
        rates: bool = False,
        reduce: str | Sequence[str] | None = None,
        trace: str | Sequence[str] | None = None,
        client=None,
        chunk: int | None = None,
        store: str | os.PathLike | None = None,
        **param_values: float,
    ):
        """Compile with the given overrides and solve.

        ``span = (t0, t1)`` and ``step`` replace the file's ``simulate`` line. Params are
        overridden by keyword (``l=2.5``) or through ``params`` (for names that clash with
        the keywords here); ``sweep`` maps param names to lists of values. Every value may
        be a number or, as on the command line (``--set l=3*2``), the text of an expression
        of the params before it (``l="3*2"``, ``sweep={"l": ["r", "2*r"]}``). ``poses``
        keeps every body's pose at every instant in ``Results.poses``, ``rates`` their
        velocities and accelerations too in ``Results.rates`` (as ``mechdsl run`` keeps
        them for ``--export`` and for centrodes). ``reduce`` replaces
        the file's outputs by reductions, as ``mechdsl run --reduce`` (``"max(abs(slider.ax)),
        stroke = range(slider.x)"``, or a list of such texts): one value per variant, in
        ``Results.reduced``. ``trace`` adds traced points and centrodes to the model's
        ``trace`` statements, as ``mechdsl run --trace`` (``"coupler.P"``, ``"ic(coupler,
        ground)"``, or a list of such texts).

        A sweep is solved in chunks of ``chunk`` variants (by default chosen from the model's
        size, at most 1000), as ``mechdsl run`` does: on the cluster of the Dask ``client``
        (``distributed.Client``) if one is given, else in this process; the results are the
        same bit for bit either way. With ``store`` (a ``.zarr`` or ``.parquet`` path) each
        chunk is written there where it was solved, nothing is held whole, and the stored
        results are returned, read lazily (:class:`mechdsl.outputs.store.StoredResults`);
        an earlier store there is replaced only when the run is complete (an interrupted
        run's store goes beside it, ``out.interrupted.zarr``, and is the one returned).
        """
        ov = self._overrides(span, step, sweep, {**(params or {}), **param_values}, options)
        mech = self.reducing(reduce) if reduce is not None else self
        mech = mech.tracing(trace) if trace else mech
        prepared = mech.prepare(ov, chunk)
        if store is not None:
            from .outputs.store import open_store, store_kind

            store = os.fspath(store)
            if store_kind(store) is None:
                raise MechError(f"store={store!r}: a store is a .zarr or .parquet path")
        placed: list[str] = []  # where the store went: beside store if interrupted
        results = prepared.solve(options, client=client, store=store, poses=poses,
                                 rates=rates, placed=placed.append)
        return results if store is None else open_store(placed[-1] if placed else store)

    def prepare(self, overrides: Overrides | None = None, chunk: int | None = None
                ) -> "PreparedRun":
        """The run of these overrides compiled and cut into chunks of ``chunk`` variants,
        not yet solved (:class:`PreparedRun`): what :meth:`simulate` and ``mechdsl run``
        both solve."""
        from .study import plan

        ov = overrides or Overrides()
        kernels, total, size, sweep = plan(self, ov, chunk)
        return PreparedRun(self, ov, kernels, total, size, sweep)

    def search(self, overrides: Overrides | None = None, options: SolverOptions | None = None,
               **kwargs):
        """:func:`mechdsl.study.optimize.optimize` of this mechanism with these overrides
        (its keywords: ``client``, ``chunk``, ``popsize``, ``maxiter``, ``tol``, ``seed``,
        ``refine``, ``run``, ``grid``, ``progress``): what :meth:`optimize` and ``mechdsl
        optimize`` both call."""
        from .study.optimize import optimize

        return optimize(self, overrides, options, **kwargs)

    def portable(self) -> "PortableModel":
        """What the processes that solve a study's chunks need of this mechanism: its model
        and its plugins by module name (:class:`PortableModel`); a MechError where a plugin
        was given as a Python object, which cannot be sent to another process."""
        objects = [p for p in self._plugins if not isinstance(p, str)]
        if objects:
            raise MechError(f"a plugin given as a Python object ({objects[0]!r}) cannot be "
                            "sent to another process; give its module name")
        return PortableModel(self.model, tuple(self._plugins), tuple(self._allowed), self)

    def optimize(self, *, span: tuple[float, float] | None = None, step: float | None = None,
                 params: Mapping[str, float] | None = None,
                 options: SolverOptions | None = None, client=None, chunk: int | None = None,
                 popsize: int = 15, maxiter: int = 200, tol: float = 1e-6, seed: int = 0,
                 refine: bool = True, grid: int | None = None, **param_values: float):
        """The best design of the model's ``optimize``, ``minimize``/``maximize`` and
        ``subject to`` statements, as ``mechdsl optimize`` finds it
        (:func:`mechdsl.study.optimize.optimize`; the options are that command's): an
        :class:`~mechdsl.study.optimize.Optimum`, with the run at the best params in
        ``.run``. The other arguments are those of :meth:`simulate`.

        Ctrl-C (KeyboardInterrupt) during the search does not propagate, as in
        :meth:`simulate`, which returns what it solved: the search stops and the Optimum of
        the best design solved so far is returned, its ``interrupted`` set to the signal and
        its ``.run`` made there (a second Ctrl-C stops that run, keeping what it solved). An
        objective that is a finite number for no design raises
        :class:`~mechdsl.errors.NumericalError`."""
        ov = self._overrides(span, step, None, {**(params or {}), **param_values}, options)
        return self.search(ov, options, client=client, chunk=chunk, popsize=popsize,
                           maxiter=maxiter, tol=tol, seed=seed, refine=refine, grid=grid)

    def _overrides(self, span, step, sweep, values, options) -> Overrides:
        """The overrides of :meth:`simulate`'s arguments: numbers, or texts of expressions of
        the params before them, as on the command line."""
        names = [p.name for p in self.model.params]

        def value(v, what: str):
            return parse_value(v, what, names) if isinstance(v, str) else v

        for what, given in (("cannot sweep", sweep or {}), ("cannot set", values)):
            for k in given:
                if k not in names and k in {f.name for f in fields(SolverOptions)}:
                    raise MechError(f"{what} '{k}': there is no param of that name ('{k}' is "
                                    f"a solver option: options=SolverOptions({k}=...))")
                known_param(k, names, what)
        sweeps = {k: [value(x, k) for x in ([vs] if isinstance(vs, str) else vs)]
                  for k, vs in (sweep or {}).items()}
        t0, t1 = span if span is not None else (None, None)
        ov = Overrides(params={k: value(v, k) for k, v in values.items()}, sweeps=sweeps,
                       t0=value(t0, "span"), t1=value(t1, "span"), step=value(step, "step"))
        if options is not None:  # one memory limit for the time grid and the run
            ov.max_memory = options.max_memory
        return ov

    def reducing(self, reduce: str | Sequence[str]) -> "Mechanism":
        """This mechanism with its outputs replaced by the reductions of ``reduce`` (the text
        of ``mechdsl run --reduce``, or a list of such texts), sharing its plugins."""
        from dataclasses import replace

        texts = [reduce] if isinstance(reduce, str) else list(reduce)
        names = [p.name for p in self.model.params]
        self.check_names()  # the file's own mistakes, located in the file
        outputs = []
        for text in texts:
            found = parse_reductions(text, "--reduce", names)
            try:  # what is left to find is in this text: locate it here
                check_structure(replace(self.model, outputs=found), self.registry)
            except MechError as err:
                err.source = Source("--reduce", normalise(text))
                raise
            outputs.extend(found)
        return self.sharing(replace(self.model, outputs=tuple(outputs)))

    def tracing(self, trace: str | Sequence[str]) -> "Mechanism":
        """This mechanism with the traces of ``trace`` added to its ``trace`` statements (the
        text of ``mechdsl run --trace``, or a list of such texts: ``"coupler.P"``,
        ``"ic(coupler, ground)"``), sharing its plugins; a mistake in them is located in
        their text."""
        from dataclasses import replace

        texts = [trace] if isinstance(trace, str) else list(trace)
        self.check_names()  # the file's own mistakes, located in the file
        traces = list(self.model.traces)
        for text in texts:
            found = parse_traces(text, "--trace")
            try:  # what is left to find is in this text: locate it here
                check_structure(replace(self.model, traces=(*traces, *found)), self.registry)
            except MechError as err:
                err.source = Source("--trace", normalise(text))
                raise
            traces.extend(found)
        return self.sharing(replace(self.model, traces=tuple(traces)))

    def sharing(self, model: Model) -> "Mechanism":
        """``model``, this mechanism's model with other outputs or sweeps (the same plugin
        lines), with this mechanism's plugins, the modules it allows and its registry, built
        already: a study or an optimisation sends the plugins' names on to its workers."""
        other = Mechanism(model, registry=self.registry, plugins=self._plugins,
                          allow_plugins=self._allowed)
        other._pending_model_plugins = False  # the registry has the model's plugin lines
        return other


@dataclass(frozen=True)
class PreparedRun:
    """A run compiled and cut into chunks, not yet solved: the one use case behind both
    :meth:`Mechanism.simulate` and ``mechdsl run`` (which reads ``system`` to check its
    outputs and estimate its drawings before it solves). ``kernels`` is the compiled model
    of the first chunk (of the whole run without a sweep), ``total`` the number of variants,
    ``chunk`` the variants per chunk, ``sweep`` the whole sweep table."""

    mechanism: Mechanism
    overrides: Overrides
    kernels: Kernels
    total: int
    chunk: int
    sweep: dict

    @property
    def system(self) -> System:
        """The compiled model's data (of the first chunk)."""
        return self.kernels.system

    def solve(self, options: SolverOptions | None = None, *, client=None,
              store: str | None = None, poses: bool = False, rates: bool = False,
              progress=None, extra_memory: int = 0, placed=None) -> Results:
        """Solve the run: in one piece here (:func:`mechdsl.solve.simulate`), or chunk by
        chunk (:func:`mechdsl.study.solve_sweep`) where it has more variants than a chunk,
        a Dask ``client`` or a ``store`` (``placed`` is called with where the store went).
        ``progress(done, total)`` follows it; ``extra_memory`` is what the caller's outputs
        will add (the run is refused before it starts where the sum exceeds the limit)."""
        if store is None and client is None and self.total <= self.chunk:
            return simulate(self.kernels, options, poses=poses, rates=rates, progress=progress,
                            extra_memory=extra_memory)
        from .study import solve_sweep

        return solve_sweep(self.mechanism, self.overrides, options, client=client, store=store,
                           poses=poses, rates=rates, progress=progress,
                           planned=(self.kernels, self.total, self.chunk, self.sweep),
                           extra_memory=extra_memory, placed=placed)


class PortableModel:
    """A mechanism as a study sends it to the processes that solve its chunks: the model
    and the plugins by module name (and the modules allowed); it pickles without its
    registry, and :meth:`compile` builds the :class:`Mechanism` once in each process."""

    def __init__(self, model: Model, plugins: tuple[str, ...], allowed: tuple[str, ...],
                 mechanism: Mechanism | None = None) -> None:
        import threading

        self.model, self.plugins, self.allowed = model, plugins, allowed
        self._mechanism = mechanism
        self._lock = threading.Lock()  # a worker's threads build one Mechanism, not several

    def __getstate__(self) -> dict:
        # the registry is rebuilt where it is unpickled, from that side's plugins
        return {"model": self.model, "plugins": self.plugins, "allowed": self.allowed}

    def __setstate__(self, state: dict) -> None:
        self.__init__(state["model"], state["plugins"], state["allowed"])

    def compile(self, overrides: Overrides) -> Kernels:
        """:meth:`Mechanism.compile` of the model with these overrides."""
        with self._lock:
            if self._mechanism is None:
                self._mechanism = Mechanism(self.model, plugins=self.plugins,
                                            allow_plugins=self.allowed)
            mechanism = self._mechanism
        return mechanism.compile(overrides)


def local_cluster(workers: int, timeout: float):
    """A Dask client of a new local cluster of ``workers`` processes
    (:func:`mechdsl.study.cluster.local_client`), for ``client=``."""
    from .study.cluster import local_client

    return local_client(workers, timeout)


def remote_cluster(address: str, timeout: float, tls: tuple = (None, None, None)):
    """A Dask client of the scheduler at ``address``, with the TLS files (CA, certificate,
    key) given (:func:`mechdsl.study.cluster.remote_client`), for ``client=``."""
    from .study.cluster import remote_client, security_of

    return remote_client(address, timeout, security_of(*tls))


def integrators_help() -> str:
    """The integrators of the registry and the automatic choice, for ``--method``'s help
    (:func:`mechdsl.solve.integrators.help_text`)."""
    from .solve.integrators import help_text

    return help_text()


def close_cluster(client) -> None:
    """Close a client, and the local cluster it started (not a remote one)."""
    from .study.cluster import close

    close(client)


def parse_value(text: str, what: str, params: Iterable[str], many: bool = False):
    """A value given as text on the command line or to the API (``--set l=2*r``,
    ``l="2*r"``): one expression of ``params`` (with ``many``, a comma-separated list of
    them), with the table files it names read. Errors are located in ``text``, named
    ``what``."""
    value = (parse_expr_list if many else parse_expr)(text, what, params)
    return read_tables(value, Source(what, normalise(text)))


def loads(text: str, name: str = "<string>", *, check: bool = True, **kwargs) -> Mechanism:
    """Parse ``.mech`` text, read the files it names (tables, meshes:
    :func:`mechdsl.compiled.files.read_files`) and, with ``check``, resolve its names against
    the plugins (:meth:`Mechanism.check_names`), so that a mistake is a located
    :class:`MechError` here, not later; keyword arguments go to :class:`Mechanism`."""
    mech = Mechanism(read_files(parse(text, name)), **kwargs)
    if check:
        mech.check_names()
    return mech


def load(path: str | os.PathLike, *, max_memory: int | None = None, **kwargs) -> Mechanism:
    """Read and parse a ``.mech`` file; keyword arguments go to :func:`loads`. With
    ``max_memory`` (bytes), a file whose parsing could take more is refused before it starts.

    The file is read as data (:func:`mechdsl.reading.read_data`): a regular file of at most
    :data:`mechdsl.reading.MAX_MODEL_BYTES`, else a :class:`MechError` naming it.
    """
    from .reading import read_data

    path = os.fspath(path)
    raw = read_data(path, "", "MAX_MODEL_BYTES")
    if max_memory is not None:
        from .grammar.parser import PARSE_BYTES_PER_BYTE
        from .memory import resident_bytes, within

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


def _freedom_line(dof: Freedom) -> str:
    """'mobility 2 = 6 coordinates - 4 independent joint equations; 1 drive: 1 degree of
    freedom left to the forward dynamics' (and the initial statements that fix it at t0)."""
    s = "s" if dof.free != 1 else ""
    line = (f"mobility {dof.mobility} = {dof.n} coordinates - {dof.joint_rank} independent "
            f"joint equations; {_count(dof.drives, 'drive')}")
    if dof.drive_rank < dof.drives:
        line += f" ({dof.drives - dof.drive_rank} on coordinates already fixed)"
    line += f": {dof.free} degree{s} of freedom left to the forward dynamics"
    if dof.initials:
        line += f", {dof.initials} fixed at t0 by {_count(dof.initials, 'initial statement')}"
    return line


def _count(k: int, what: str, plural: str | None = None) -> str:
    """'1 drive', '3 drives', '2 moving bodies'."""
    return f"{k} {what if k == 1 else plural or what + 's'}"


def _structure(model: Model, kernels: Kernels) -> list[str]:
    """The lines of what the model declares; the mobility, which needs the rank at the
    assembled configuration, is reported once, after the assembly."""
    system = kernels.system
    drives = len(system.drive_rows)
    joints = len(system.constraints) - drives
    bodies = _count(len(system.body_names), "moving body", "moving bodies")
    lines = [f"{system.source.name}: {bodies} ({system.n} coordinates); "
             f"{_count(joints, 'joint')} ({_count(system.m - drives, 'equation')}) and "
             f"{_count(drives, 'drive')}"]
    lines.append("bodies:")
    for b in (model.ground, *model.bodies):
        pts = ", ".join(p.name for p in b.points)
        guess = "fixed" if b.is_ground else ("guess " + _fmt(system.guess[0][
            3 * system.body_names.index(b.name): 3 * system.body_names.index(b.name) + 3]))
        lines.append(f"  {b.name:<12} {guess:<28} points: origin{', ' + pts if pts else ''}")
    lines.append("joints and drives:")
    functions = {d.name: d.function for d in model.drives}
    for c in system.constraints:
        neq = c.rows[1] - c.rows[0]
        extra = f"  = {to_text(functions[c.name])}" if c.name in functions else ""
        lines.append(f"  {c.kind:<5} {c.name:<14} {c.type_name:<10} {', '.join(c.bodies):<22} "
                     f"{neq} equation{'s' if neq != 1 else ''}{extra}")
    for c in model.initials:  # the start of a forward dynamics, at t0 only
        rate = f", rate = {to_text(c.rate)}" if c.rate is not None else ""
        lines.append(f"  initial {c.name:<12} {c.type_name:<10} at t0 = {to_text(c.value)}"
                     f"{rate}")
    shaped = [(name, mp) for name, mp in zip(system.body_names, system.mass) if mp is not None]
    if shaped:
        lines.append("shapes (body frame; polar moment J about the centroid):")
        for name, mp in shaped:
            mass = ("" if not np.isfinite(mp.mass[0]) else
                    f"  mass {mp.mass[0]:.6g}  inertia {mp.inertia[0]:.6g}")
            size = float(np.sqrt(mp.area[0]))
            centroid = np.where(np.abs(mp.centroid[0]) < 1e-12 * size, 0.0, mp.centroid[0])
            lines.append(f"  {name:<12} area {mp.area[0]:.6g}  centroid {_fmt(centroid)}  "
                         f"J {mp.polar[0]:.6g}{mass}")
    d = kernels.dynamics
    if d is not None:
        lines.append("masses (inertia about the centre of mass; centroid in the body frame):")
        for i, name in enumerate(system.body_names):
            lines.append(f"  {name:<12} mass {d.mass[0, i]:.6g}  inertia {d.inertia[0, i]:.6g}"
                         f"  centroid {_fmt(d.centroid[0, i])}")
        if d.forces:
            lines.append("forces:")
            for f in d.forces:
                lines.append(f"  force {f.name:<14} {f.type_name:<10} {', '.join(f.bodies)}")
        if np.any(d.gravity[0] != 0):
            lines.append(f"gravity {_fmt(d.gravity[0])}")
    return lines


def _fmt(v: np.ndarray) -> str:
    return "(" + ", ".join(f"{x:g}" for x in v) + ")"
