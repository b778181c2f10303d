"""The registry: constraint types by kind and name, each with the plugin that provides it."""

from __future__ import annotations

from dataclasses import dataclass, field

from .contract import ConstraintType, contract_problems
from .force import ForceType, force_problems


@dataclass(frozen=True)
class Provider:
    """Where a type comes from: the plugin (module) name and its distribution."""

    plugin: str
    distribution: str | None = None
    version: str | None = None

    def __str__(self) -> str:
        if self.distribution is None:
            return self.plugin
        return f"{self.distribution} {self.version or ''}".strip()


@dataclass(frozen=True)
class BrokenPlugin:
    """A plugin that could not be loaded or returned a malformed type, and why; ``types``:
    the type names it would have given, where known (its entry points' names, or the
    malformed type's); ``contract``: whether it was written for another plugin contract
    (:mod:`mechdsl.plugins.version`)."""

    provider: Provider
    reason: str
    types: tuple[str, ...] = ()
    contract: bool = False


class PluginConflict(Exception):
    """Two plugins claim the same type name."""


@dataclass
class Registry:
    """Constraint types keyed by ``(kind, name)``. Filled once by the plugin manager, then only
    read; :meth:`add` rejects a second type of the same kind and name, naming both providers."""

    types: dict[tuple[str, str], tuple[ConstraintType | ForceType, Provider]] = field(default_factory=dict)
    broken: list[BrokenPlugin] = field(default_factory=list)
    #: (kind, name) -> message, for names that two plugins claim; using one is an error.
    conflicts: dict[tuple[str, str], str] = field(default_factory=dict)

    def add(self, ctype: ConstraintType | ForceType, provider: Provider) -> None:
        """Register ``ctype``; raises ValueError (malformed) or PluginConflict (duplicate)."""
        problems = (force_problems(ctype) if getattr(ctype, "kind", None) == "force"
                    else contract_problems(ctype))
        if problems:
            raise ValueError(f"type {getattr(ctype, 'name', ctype)!r}: " + "; ".join(problems))
        key = (ctype.kind, ctype.name)
        if key in self.types:
            other = self.types[key][1]
            if other == provider and type(self.types[key][0]) is type(ctype):
                return  # the same module reached through two entry points
            message = (f"{ctype.kind} type '{ctype.name}' is provided twice: by {other} "
                       f"(plugin {other.plugin}) and by {provider} (plugin {provider.plugin}); "
                       "uninstall one of them")
            self.conflicts[key] = message
            raise PluginConflict(message)
        self.types[key] = (ctype, provider)

    def merged(self, other: "Registry") -> "Registry":
        """A new registry with the types of both; a name in both is a conflict, recorded."""
        out = Registry(dict(self.types), self.broken + other.broken, dict(self.conflicts))
        for ctype, provider in other.types.values():
            try:
                out.add(ctype, provider)
            except PluginConflict as err:
                out.broken.append(BrokenPlugin(provider, str(err)))
        return out

    def broken_for(self, name: str) -> BrokenPlugin | None:
        """The plugin written for another contract that would have given the type ``name``,
        or None."""
        return next((b for b in self.broken if b.contract and name in b.types), None)

    def get(self, kind: str, name: str) -> ConstraintType | ForceType | None:
        """The type of that kind and name, or None."""
        entry = self.types.get((kind, name))
        return entry[0] if entry else None

    def provider(self, kind: str, name: str) -> Provider | None:
        entry = self.types.get((kind, name))
        return entry[1] if entry else None

    def names(self, kind: str) -> list[str]:
        """The registered names of ``kind``, sorted."""
        return sorted(n for k, n in self.types if k == kind)
