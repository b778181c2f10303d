"""The integrators of the forward dynamics: one registry, and the automatic choice.

:data:`INTEGRATORS` maps the name ``--method`` takes to the :class:`~mechdsl.solve.stepper.Stepper`
subclass that steps; the options' validation, the command line's help and :func:`choose`
read it, and nothing else lists the names. Adding an integrator is a module with one
subclass (the rules are in :mod:`mechdsl.solve.stepper`) and one line here.

Importing this module is cheap (the command line's help reads it): the steppers' modules
import numpy, which the package has already loaded, and read their coefficients or build
their factorisations only when they first step.
"""

from __future__ import annotations

from .explicit import Dop853, Dopri5, Vern9
from .relative import Radau
from .stepper import Stepper

#: Every integrator by its name, one line each.
INTEGRATORS: dict[str, type[Stepper]] = {
    Vern9.name: Vern9,
    Dop853.name: Dop853,
    Dopri5.name: Dopri5,
    Radau.name: Radau,
}


def names() -> list[str]:
    """What ``--method`` takes: "auto", then the registry's names."""
    return ["auto", *INTEGRATORS]


def help_text() -> str:
    """The command line's help for ``--method``, from the registry and the automatic rule."""
    from .options import SolverOptions

    auto = [cls for cls in INTEGRATORS.values() if cls.auto]
    explicit = [cls for cls in auto if not cls.implicit]
    low = min(explicit, key=lambda cls: cls.order).name
    high = max(explicit, key=lambda cls: cls.order).name
    threshold = f"{SolverOptions.dopri5_from:.0e}".replace("e-0", "e-")  # 1e-4
    rule = f"{low} for an rtol of {threshold} or more, else {high}"
    robust = [cls for cls in explicit if cls.robust]
    if robust:
        rule += (f" ({max(robust, key=lambda cls: cls.order).name} for large or redundant "
                 "models)")
    later = stiff_method()
    if later is not None:
        rule += f"; {later.name} where the run proves stiff"
    listed = ", ".join(f"{name} ({cls.summary})" if cls.summary else name
                       for name, cls in INTEGRATORS.items())
    return f"forward dynamics: the integrator, auto (default: {rule}) or one of {listed}"


def choose(method: str, rtol: float, *, dopri5_from: float, stiff: bool = False,
           large: bool = False, redundant: bool = False) -> tuple[str, str]:
    """The integrator of a run and why: (name in :data:`INTEGRATORS`, reason).

    ``method`` other than "auto" is taken as named. "auto" reads the registry's classes
    (those whose ``auto`` is set): for a model that is ``stiff``, ``large`` or has
    ``redundant`` constraints, an implicit stepper (one with ``redundant`` set where the
    constraints are redundant) where one is registered -- the hook for the implicit method;
    otherwise, and for every other model, an explicit pair by the tolerance: at rtol >=
    ``dopri5_from`` the pair of lowest order (fewest evaluations per step: it wins where
    the steps are few and long, dopri5), below it the one of highest order (its number of
    steps grows only as tol^(-1/(q+1)), vern9); but for a ``large`` or ``redundant``
    model, integrated on the augmented Lagrangian, below ``dopri5_from`` the highest-order
    pair among the ``robust`` ones (dop853). The choice is measured on Andrews' mechanism
    and on A02 and the chain (docs/dynamics.md)."""
    if method != "auto":
        validate(method)
        return method, f"{method}, as the options name it"
    candidates = [cls for cls in INTEGRATORS.values() if cls.auto]
    needs = [why for why, flag in (("is stiff", stiff), ("is large", large),
                                   ("has redundant constraints", redundant)) if flag]
    if needs:
        implicit = [cls for cls in candidates
                    if cls.implicit and (cls.redundant or not redundant)]
        if implicit:
            best = max(implicit, key=lambda cls: cls.order)
            return best.name, f"{best.name}: the model {' and '.join(needs)}"
    explicit = [cls for cls in candidates if not cls.implicit]
    if (large or redundant) and rtol < dopri5_from and any(c.robust for c in explicit):
        # the augmented Lagrangian's accelerations (module docstring of solve/motion.py)
        best = max((c for c in explicit if c.robust), key=lambda cls: cls.order)
        why = (f"{best.name}: rtol {rtol:g} < {dopri5_from:g} on the augmented Lagrangian, "
               "where the explicit pair of highest order whose error estimate stays "
               "reliable on its accelerations takes the fewest evaluations")
        return best.name, why + _later(needs)
    if rtol >= dopri5_from:
        best = min(explicit, key=lambda cls: cls.order)
        why = (f"{best.name}: rtol {rtol:g} >= {dopri5_from:g}, where the explicit pair of "
               "lowest order takes the fewest evaluations")
    else:
        best = max(explicit, key=lambda cls: cls.order)
        why = (f"{best.name}: rtol {rtol:g} < {dopri5_from:g}, where the explicit pair of "
               "highest order takes the fewest evaluations")
    return best.name, why + _later(needs)


def _later(needs: list[str]) -> str:
    """What the reason adds for a model that is stiff, large or redundant: the implicit
    method taking over where the run proves stiff."""
    if not needs:
        return ""
    later = stiff_method()
    return (f" (the model {' and '.join(needs)}; "
            + (f"{later.name} takes over where the run proves stiff: from the start it "
               "is not chosen, being slower on such models)" if later is not None else
               "no implicit method is registered)"))


def stiff_method() -> type[Stepper] | None:
    """The implicit stepper the automatic choice goes on with where an explicit pair finds
    the model stiff during the run (rule 7 of :mod:`mechdsl.solve.stepper`): the registered
    implicit one of highest order that tolerates redundant constraints, None if there is
    none."""
    implicit = [cls for cls in INTEGRATORS.values() if cls.implicit and cls.redundant]
    return max(implicit, key=lambda cls: cls.order) if implicit else None


def _listed() -> str:
    quoted = [f"'{name}'" for name in names()]
    return ", ".join(quoted[:-1]) + " or " + quoted[-1]


def validate(method: str) -> None:
    """ValueError unless ``method`` is "auto" or a registered integrator's name."""
    if method != "auto" and method not in INTEGRATORS:
        raise ValueError(f"method must be {_listed()}, not {method!r}")
