"""Plugin discovery: entry points -> pluggy -> a :class:`~mechdsl.plugins.registry.Registry`.

Plugins are found through the ``mechdsl`` entry-point group, built-in joints included. By
convention each entry point is named after a type its module provides (a module providing
several types has one entry point per type, all naming the module), so that a run imports
only the plugins of the types its model uses; when a wanted type is not found that way, every
entry point is loaded. Nothing here runs at import time: the caller builds a registry once and
passes it on.

Set ``MECHDSL_DISABLE_PLUGIN_AUTOLOAD=1`` to ignore entry points (only plugins given
explicitly are registered), as pytest does for its own plugins.

A model file's ``plugin "module"`` lines import nothing by themselves (:func:`allowed_plugins`):
a module is imported only when the user installed it as an entry-point plugin or allowed it
(``--allow-plugin MODULE``, the ``allow_plugins`` argument of the API, or the environment
variable ``MECHDSL_ALLOW_PLUGINS=mod1,mod2``). A file opened is data, not code.
"""

from __future__ import annotations

import os
from dataclasses import replace
from importlib import import_module
from typing import Collection, Iterable

import pluggy

from . import hookspecs
from .discover import entry_points as find_entry_points
from .registry import BrokenPlugin, PluginConflict, Provider, Registry
from .version import declared_problem, import_problem, old_contract

ENTRY_POINT_GROUP = "mechdsl"
AUTOLOAD_ENV = "MECHDSL_DISABLE_PLUGIN_AUTOLOAD"
ALLOW_ENV = "MECHDSL_ALLOW_PLUGINS"
#: Raised by plugin code and contained: a plugin that calls sys.exit() on import is broken,
#: not the end of the run. KeyboardInterrupt is not contained.
PLUGIN_FAILURES = (Exception, SystemExit)


def installed_plugin_modules() -> set[str]:
    """The modules that the entry points of the ``mechdsl`` group name: code the user
    installed as mechdsl plugins (read from the metadata; nothing is imported)."""
    return {ep.value.split(":")[0].strip() for ep in find_entry_points(ENTRY_POINT_GROUP)}


def allowed_plugins(requested: Iterable[tuple[str, object]], allowed: Iterable[str] = ()
                    ) -> list[tuple[str, object]]:
    """The ``(module, span)`` pairs of a model's ``plugin`` lines that the user did not allow:
    a module is allowed when it is an installed entry-point plugin, is named in ``allowed``,
    or in the environment variable MECHDSL_ALLOW_PLUGINS (comma-separated)."""
    requested = list(requested)
    if not requested:
        return []
    ok = {m.strip() for m in allowed}
    ok |= {m.strip() for m in os.environ.get(ALLOW_ENV, "").split(",") if m.strip()}
    pending = [(m, span) for m, span in requested if m not in ok]
    if pending:
        installed = installed_plugin_modules()
        pending = [(m, span) for m, span in pending if m not in installed]
    return pending


def plugin_manager() -> pluggy.PluginManager:
    """A fresh plugin manager that knows mechdsl's hook specifications."""
    pm = pluggy.PluginManager(hookspecs.PROJECT)
    pm.add_hookspecs(hookspecs)
    return pm


def build_registry(
    plugins: Iterable[object | str] = (),
    *,
    entry_points: bool | None = None,
    wanted: Collection[str] | None = None,
) -> Registry:
    """Register ``plugins`` (modules, or module names to import) and, unless disabled, the
    entry-point plugins; collect their constraint types into a new :class:`Registry`.

    ``wanted`` names the types a run needs: entry points named after other types are then not
    imported. A plugin that fails to import, to register or to declare its types is recorded
    in ``registry.broken`` with the reason and does not stop the others.
    """
    if entry_points is None:
        entry_points = not os.environ.get(AUTOLOAD_ENV)
    pm = plugin_manager()
    registry = Registry()
    providers: dict[str, Provider] = {}

    for plugin in plugins:
        if isinstance(plugin, str):
            try:
                plugin = import_module(plugin)
            except PLUGIN_FAILURES as err:  # any failure of a plugin is contained
                registry.broken.append(_failed(Provider(str(plugin)), err))
                continue
        name = getattr(plugin, "__name__", repr(plugin))
        _register(pm, registry, plugin, Provider(name), providers)

    if entry_points:
        eps = find_entry_points(ENTRY_POINT_GROUP)
        if wanted is not None:
            first = [ep for ep in eps if ep.name in wanted]
            _load_entry_points(pm, registry, first, providers)
            _collect(pm, registry, providers)
            found = {n for (_k, n) in registry.types}
            if set(wanted) <= found:
                return registry
            eps = [ep for ep in eps if ep not in first]
        _load_entry_points(pm, registry, eps, providers)
    _collect(pm, registry, providers)
    return registry


def _failed(provider: Provider, err: BaseException, types: tuple[str, ...] = ()
            ) -> BrokenPlugin:
    """A plugin that failed to import: written for another contract where it imports what
    mechdsl no longer has."""
    contract = import_problem(err)
    return BrokenPlugin(provider, contract or _reason(err), types, contract is not None)


def _reason(err: BaseException) -> str:
    if isinstance(err, SystemExit):
        return f"it called sys.exit({err.code!r}) while loading"
    return f"{type(err).__name__}: {str(err)[:300]}"


def _register(pm, registry: Registry, plugin: object, provider: Provider,
              providers: dict[str, Provider], types: tuple[str, ...] = ()) -> None:
    if pm.is_registered(plugin):
        return
    try:
        other = declared_problem(plugin)
    except PLUGIN_FAILURES as err:  # a declaration whose attribute raises
        registry.broken.append(BrokenPlugin(provider, _reason(err), types))
        return
    if other is not None:  # written for another contract: not registered at all
        registry.broken.append(BrokenPlugin(provider, other, types, True))
        return
    try:
        pm.register(plugin, name=provider.plugin)
        pm.check_pending()
    except PLUGIN_FAILURES as err:
        if pm.is_registered(plugin):
            pm.unregister(plugin)
        registry.broken.append(BrokenPlugin(provider, _reason(err)))
        return
    providers[provider.plugin] = provider


def _load_entry_points(pm, registry: Registry, eps: list, providers: dict[str, Provider]) -> None:
    for ep in eps:
        module_name = ep.value.split(":")[0].strip()
        provider = Provider(module_name, ep.dist_name, ep.dist_version)
        if module_name in providers or pm.has_plugin(module_name):
            continue
        # a module behind several entry points (a type each) that failed once: listed once,
        # with all the types it would have given
        k = next((k for k, b in enumerate(registry.broken) if b.provider == provider), None)
        if k is not None:
            old = registry.broken[k]
            registry.broken[k] = replace(old, types=(*old.types, ep.name))
            continue
        try:
            plugin = ep.load()
        except PLUGIN_FAILURES as err:
            registry.broken.append(_failed(provider, err, (ep.name,)))
            continue
        _register(pm, registry, plugin, provider, providers, (ep.name,))


def _collect(pm, registry: Registry, providers: dict[str, Provider]) -> None:
    """Ask each registered plugin, one by one, for its types (so each is attributed)."""
    for hook, kinds in ((pm.hook.mechdsl_constraint_types, ("joint", "drive")),
                        (pm.hook.mechdsl_force_types, ("force",))):
        done = {p for (k, _n), (_c, p) in registry.types.items() if k in kinds}
        for impl in hook.get_hookimpls():
            provider = providers.get(impl.plugin_name, Provider(impl.plugin_name))
            if provider in done:
                continue
            try:
                types = list(impl.function())
            except PLUGIN_FAILURES as err:
                registry.broken.append(BrokenPlugin(provider, _reason(err)))
                continue
            for ctype in types:
                try:
                    if getattr(ctype, "kind", None) not in kinds:
                        raise ValueError(f"type {getattr(ctype, 'name', ctype)!r}: a "
                                         f"{hook.name} hook returned a type of kind "
                                         f"{getattr(ctype, 'kind', None)!r}")
                    old = old_contract(ctype)
                    if old is not None:
                        registry.broken.append(BrokenPlugin(
                            provider, old, (str(getattr(ctype, "name", "")),), True))
                        continue
                    registry.add(ctype, provider)
                except (ValueError, PluginConflict) as err:
                    registry.broken.append(BrokenPlugin(provider, str(err)))
                except PLUGIN_FAILURES as err:  # a declaration whose attributes raise
                    registry.broken.append(BrokenPlugin(provider, _reason(err)))
            done.add(provider)
