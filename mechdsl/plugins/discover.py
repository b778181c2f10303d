"""Entry points of one group, read straight from the installed distributions' metadata.

``importlib.metadata`` would do the same, but importing it (with the ``email`` package it
parses headers with) costs about 40 ms, an eighth of ``mechdsl run``'s start-up. The files
are simple: each ``*.dist-info`` or ``*.egg-info`` folder on ``sys.path`` may hold an
``entry_points.txt`` (INI sections named after groups, ``name = module:attr`` lines), and
its ``METADATA`` or ``PKG-INFO`` header names the distribution and its version. As with
``importlib.metadata``, the first distribution of a name on ``sys.path`` wins, the name
taken from the folder's (``name-version.dist-info``), as importlib.metadata takes it.
"""

from __future__ import annotations

import os
import re
import sys
from dataclasses import dataclass
from importlib import import_module
from typing import Iterable

_INFO_SUFFIXES = (".dist-info", ".egg-info")


@dataclass(frozen=True)
class EntryPoint:
    """``name = value`` in a group, where value is ``module`` or ``module:attr.attr``."""

    name: str
    value: str
    dist_name: str | None
    dist_version: str | None

    def load(self) -> object:
        """Import the module and return the object that ``value`` names."""
        module, _, attrs = self.value.partition(":")
        obj: object = import_module(module.strip())
        for attr in filter(None, (a.strip() for a in attrs.split("."))):
            obj = getattr(obj, attr)
        return obj


def entry_points(group: str, path: Iterable[str] | None = None) -> list[EntryPoint]:
    """Every entry point of ``group`` of the distributions found on ``path`` (sys.path)."""
    found: list[EntryPoint] = []
    seen: set[str] = set()
    for base in sys.path if path is None else path:
        try:
            names = sorted(os.listdir(base or "."))
        except OSError:  # not a folder (a zip, a missing entry): nothing installed there
            continue
        for folder in names:
            if not folder.endswith(_INFO_SUFFIXES):
                continue
            # the distribution's name from its folder (``name-version.dist-info``), as
            # importlib.metadata keys it: the header is read only where the group has
            # entries (about 120 headers a call otherwise, 7 ms of every model's loading)
            key = _normalise(os.path.splitext(folder)[0].partition("-")[0])
            if key in seen:
                continue
            seen.add(key)
            info = os.path.join(base or ".", folder)
            entries = _group(os.path.join(info, "entry_points.txt"), group)
            if entries:
                name, version = _header(info)
                found += [EntryPoint(n, v, name, version) for n, v in entries]
    return found


def _normalise(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def _header(info: str) -> tuple[str | None, str | None]:
    """Name and Version from the metadata header (the lines before the first blank one)."""
    name = version = None
    for file in ("METADATA", "PKG-INFO"):
        try:
            with open(os.path.join(info, file), encoding="utf-8", errors="replace") as f:
                for line in f:
                    if not line.strip():
                        break
                    key, _, value = line.partition(":")
                    if key == "Name":
                        name = value.strip()
                    elif key == "Version":
                        version = value.strip()
            return name, version
        except OSError:
            continue
    return name, version


def _group(file: str, group: str) -> list[tuple[str, str]]:
    """The ``name = value`` lines of section ``[group]`` of an entry_points.txt."""
    try:
        with open(file, encoding="utf-8", errors="replace") as f:
            lines = f.read().splitlines()
    except OSError:
        return []
    out, inside = [], False
    for line in lines:
        line = line.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("[") and line.endswith("]"):
            inside = line[1:-1].strip() == group
        elif inside and "=" in line:
            name, _, value = line.partition("=")
            # "module:attr [extra1, extra2]": extras name optional dependencies, not the object
            out.append((name.strip(), re.sub(r"\s*\[.*\]\s*$", "", value).strip()))
    return out
