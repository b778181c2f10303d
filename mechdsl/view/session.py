"""The file a view shows, and the values its sliders set: the view's only mutable state.

A :class:`Session` loads the file as ``mechdsl run`` does (the same plugin permissions: a
model file imports no module by itself), keeps the last :class:`~mechdsl.api.Mechanism`
that loaded (it keeps its compiled models: a slider moved back to a value is not compiled
again), and answers each request with one message of :mod:`.payload`: a run, or the errors
that stopped one. A file that no longer loads keeps the last good mechanism for the page,
which keeps its drawing and shows the errors.
"""

from __future__ import annotations

import math
import os
import threading
from typing import Mapping

from ..errors import MechError, format_error
from ..outputs import payload

#: The largest number of sliders a page gets (a model with more params shows the first).
MAX_SLIDERS = 64


class Session:
    """The view of ``path`` (module docstring). ``plugins`` and ``allow_plugins`` are those
    of ``mechdsl run``; ``options`` the solver's (None: the file's)."""

    def __init__(self, path: str, *, plugins: tuple[str, ...] = (),
                 allow_plugins: tuple[str, ...] = (), options=None) -> None:
        self.path = os.path.abspath(path)
        self.display = os.path.basename(path)
        self.plugins, self.allow_plugins, self.options = plugins, allow_plugins, options
        self.mech = None
        self.values: dict[str, float] = {}
        self._sliders: list[payload.Slider] = []
        self._lock = threading.Lock()  # one load or solve at a time

    # -- what the page may set ----------------------------------------------------------------
    def sliders(self) -> list[payload.Slider]:
        """The params given sliders (those whose value is a number or an expression of
        numbers alone), each at its value now."""
        return [payload.Slider(s.name, self.values.get(s.name, s.value), s.lo, s.hi)
                for s in self._sliders]

    def watched(self) -> set[str]:
        """The files whose change reloads the view: the model file, and the tables and meshes
        it names (as the last model that parsed names them)."""
        files = {os.path.realpath(self.path)}
        if self.mech is not None:
            files.update(self.mech.model.files)
        return files

    def check_values(self, given: Mapping[str, object]) -> dict[str, float]:
        """``given`` as param values: ValueError naming what is wrong (an unknown name, a
        value that is not a finite number)."""
        known = {s.name for s in self._sliders}
        out: dict[str, float] = {}
        for name, value in given.items():
            if not isinstance(name, str) or name not in known:
                shown = name if isinstance(name, str) else type(name).__name__
                raise ValueError(f"no slider '{shown[:80]}'; sliders: "
                                 f"{', '.join(sorted(known)) or 'none'}")
            try:  # (a JSON integer may have a thousand digits: float() overflows)
                number = float(value) if isinstance(value, (int, float)) and \
                    not isinstance(value, bool) else math.nan
            except OverflowError:
                number = math.inf
            if not math.isfinite(number):
                raise ValueError(f"the value of '{name}' must be a finite number")
            out[name] = number
        return out

    # -- loading and solving ------------------------------------------------------------------
    def load(self) -> bytes:
        """Read and parse the file again, then solve it with the sliders' values: the run's
        message, or the file's errors (every one that can be found at once)."""
        with self._lock:
            failed = self._read()
            return failed if failed is not None else self._solve()

    def read(self) -> bytes | None:
        """Read and parse the file again without solving it (what the watcher needs to know
        the files it names): None, or the message of its errors."""
        with self._lock:
            return self._read()

    def _read(self) -> bytes | None:
        from ..api import load

        try:
            mech = load(self.path, plugins=self.plugins, allow_plugins=self.allow_plugins,
                        check=False)
            mech.check_names()
            sliders = _sliders(mech)
        except MechError as err:
            return payload.error_message("error", self._all_errors(err), self.sliders())
        except OSError as err:  # pragma: no cover - read_data reports these as MechError
            return payload.error_message("error", [f"{self.display}: error: {err}"])
        self.mech = mech
        self._sliders = sliders
        names = {s.name for s in self._sliders}
        self.values = {k: v for k, v in self.values.items() if k in names}
        return None

    def solve(self, values: Mapping[str, float]) -> bytes:
        """Solve the last good model with ``values`` set (checked by :meth:`check_values`)."""
        with self._lock:
            names = {s.name for s in self._sliders}  # (a reload may have renamed one)
            self.values.update({k: v for k, v in values.items() if k in names})
            if self.mech is None:
                return payload.error_message("error", ["the file has not loaded yet"])
            return self._solve()

    def reset(self) -> bytes:
        """Every slider back to the file's value, and the run."""
        with self._lock:
            self.values = {}
            if self.mech is None:
                return payload.error_message("error", ["the file has not loaded yet"])
            return self._solve()

    def _solve(self) -> bytes:
        mech = self.mech
        try:
            ov = _overrides(mech, self.values)
            prepared = mech.prepare(ov)
            system = prepared.system
            if prepared.total <= prepared.chunk:
                # one run: the traced points' velocities and accelerations too
                sk = system.sketch
                results = prepared.solve(self.options, poses=True,
                                         rates=bool(sk and (sk.traces or sk.centrodes)))
            else:  # a sweep of many chunks: as the API solves it, without the vectors
                results = mech.simulate(params=dict(self.values), poses=True,
                                        rates=bool(system.sketch and system.sketch.centrodes),
                                        options=self.options)
                system = mech.compile(ov).system
        except MechError as err:
            return payload.error_message("failed", [format_error(err)], self.sliders())
        return payload.run_message(system, results, self.sliders(), file=self.display)

    def _all_errors(self, err: MechError) -> list[str]:
        """Every located error of the file, as ``mechdsl check`` prints them."""
        from ..diagnostics import every_error

        source = err.source
        found = every_error(err, source.text if source is not None else None,
                            source.name if source is not None else self.path,
                            bool(self.plugins))
        return [format_error(e) for e in found]


def _overrides(mech, values: Mapping[str, float]):
    """The overrides :meth:`~mechdsl.api.Mechanism.simulate` makes of ``params=values`` (the
    same key: its compiled model is the one the run used)."""
    return mech._overrides(None, None, None, dict(values), None)


def _sliders(mech) -> list[payload.Slider]:
    """A slider for each param whose value reads no other param (``param l = 3.5``,
    ``param omega = 4*pi``), over the range the file gives it (``param l = 3.5 in 2 .. 6``)
    or else :func:`.payload.default_range` of its value. MechError where a range is wrong."""
    from ..compiled.variants import Overrides, evaluate
    from ..grammar import expr as E

    model = mech.model
    try:
        var = evaluate(model, Overrides())
    except MechError as err:
        raise err.with_source(model.source) from None
    out = []
    for p in model.params:
        if E.free_names(p.value):
            continue  # follows other params: moved by theirs
        value = float(var.env[p.name][0])
        if not math.isfinite(value):
            continue
        lo, hi = var.ranges.get(p.name) or payload.default_range(value)
        out.append(payload.Slider(p.name, value, lo, hi))
    return out[:MAX_SLIDERS]
