"""The version of the plugin contract, and how a plugin written for another one is told so.

The contract is what :mod:`mechdsl.plugins` offers a plugin and asks of it: the hooks, the
classes a type subclasses (:class:`~mechdsl.plugins.ConstraintType`,
:class:`~mechdsl.plugins.ForceType`), the methods it writes, the names it imports. Its
version, :data:`CONTRACT_VERSION`, changes whenever a plugin written for the old one would
no longer work; from contract 2 on, mechdsl's minor version (0.x) changes with it, so that a
plugin's dependency range (``mechdsl >= 0.1, < 0.2``) names the releases of its contract
(contract 1 was never released: the declaration, not the range, tells it apart).

A plugin module declares the version it was written for, ``MECHDSL_CONTRACT = 2``. One that
declares another version is not loaded: the types it would give are errors at the line that
uses them, saying the contract changed and where the migration notes are
(:data:`MIGRATION`). So is one that fails to import a name mechdsl no longer has (the
contract 1 plugins import ``block`` from ``mechdsl.plugins.geometry``), and a type written
for contract 1 (``phi``, ``jacobian`` and ``gamma`` methods, no ``equations``). A module
that declares no version is loaded as long as its types fit the contract.

The versions:

1. ``phi(q, p)``, ``jacobian(q, p)`` and ``gamma(q, qd, p)`` on arrays, written by the type.
2. ``equations(bodies, args)`` on scalars, written once; the Jacobian and gamma derived
   exactly (optionally ``jacobian_terms``, ``gamma_terms``); force types' ``loads``.
"""

from __future__ import annotations

#: The version of the plugin contract this mechdsl implements.
CONTRACT_VERSION = 2
#: The module attribute by which a plugin declares the contract it was written for.
DECLARATION = "MECHDSL_CONTRACT"
#: Where the migration notes are.
MIGRATION = "docs/plugins.md#contract-versions-and-migration"


def _changed(why: str) -> str:
    return (f"{why}; mechdsl implements plugin contract {CONTRACT_VERSION}: the contract "
            f"changed (migration notes: {MIGRATION})")


def declared_problem(plugin: object) -> str | None:
    """Why ``plugin`` (a module) cannot be loaded for the version it declares, or None (the
    current version, or none declared)."""
    declared = getattr(plugin, DECLARATION, None)
    if declared is None or declared == CONTRACT_VERSION:
        return None
    return _changed(f"it was written for plugin contract {declared!r} "
                    f"({DECLARATION} = {declared!r})")


def import_problem(err: BaseException) -> str | None:
    """Why a plugin failed to import, where the failure is a name of mechdsl that the current
    contract does not have (an ImportError or AttributeError naming a mechdsl module), or
    None."""
    if isinstance(err, ImportError) and (err.name or "").split(".")[0] == "mechdsl":
        return _changed(f"it imports what mechdsl no longer has ({err}): it was written for "
                        "an earlier plugin contract")
    if isinstance(err, AttributeError) and \
            getattr(getattr(err, "obj", None), "__name__", "").split(".")[0] == "mechdsl":
        return _changed(f"it uses what mechdsl no longer has ({err}): it was written for "
                        "an earlier plugin contract")
    return None


def old_contract(ctype: object) -> str | None:
    """Why ``ctype`` is a type of contract 1 (its own ``phi``, ``jacobian`` or ``gamma``, no
    ``equations``), or None."""
    from .contract import ConstraintType

    if not isinstance(ctype, ConstraintType) or ctype.supplies_equations():
        return None
    own = [m for m in ("phi", "jacobian", "gamma")
           if getattr(type(ctype), m) is not getattr(ConstraintType, m)]
    if not own:
        return None
    return _changed(f"type {getattr(ctype, 'name', ctype)!r} writes {', '.join(own)}() "
                    "and no equations(): it was written for plugin contract 1")
