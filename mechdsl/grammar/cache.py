"""A per-user cache of the parser's tables, stored as JSON.

Building the LALR tables of the grammar costs about 50 ms at every start-up; loading them
from this cache about 6 ms. lark's own cache (``cache=True``) is a pickle at a predictable
path in the shared temporary folder, unpickled before anything is checked: whoever can write
there runs code as the next user of mechdsl. This cache is not that:

* it is JSON: decoding it runs no code, whatever the file holds;
* it lives in ``$XDG_CACHE_HOME/mechdsl`` (default ``~/.cache/mechdsl``), a folder created
  with mode 0700 and used only if it belongs to the current user and nobody else may write
  to it; the file is checked likewise, on the descriptor that is read (no race on the path);
* the file holds a digest of the grammar, of lark's version and of the options, checked
  before use; any problem (a foreign file, a read-only home, no such folder on this system)
  means the tables are built in memory, silently.
"""

from __future__ import annotations

import hashlib
import json
import os
import stat
from typing import Any, Callable

#: Bumped when the layout of the file changes.
FORMAT = 1
#: A cache file larger than this is not ours (the tables take about 120 kB).
MAX_CACHE_BYTES = 4 * 2**20

_DIR_FLAGS = (os.O_RDONLY | getattr(os, "O_DIRECTORY", 0) | getattr(os, "O_NOFOLLOW", 0)
              | getattr(os, "O_CLOEXEC", 0))
_READ_FLAGS = (os.O_RDONLY | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_NONBLOCK", 0)
               | getattr(os, "O_CLOEXEC", 0))
_WRITE_FLAGS = (os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_NOFOLLOW", 0)
                | getattr(os, "O_CLOEXEC", 0))


def cached_tables(key_text: str, build: Callable[[], Any]) -> Any:
    """The JSON-able data ``build()`` returns, from the cache when a file there was made
    from the same ``key_text`` (the grammar, versions and options), else built and stored."""
    key = hashlib.sha256(f"{FORMAT}\n{key_text}".encode()).hexdigest()
    name = f"parser-{key[:32]}.json"
    dir_fd = _cache_dir()
    if dir_fd is None:
        return build()
    try:
        data = _read(dir_fd, name, key)
        if data is None:
            data = build()
            _write(dir_fd, name, key, data)
        return data
    finally:
        os.close(dir_fd)


def cache_dir_path() -> str | None:
    """The folder of the cache: ``$XDG_CACHE_HOME/mechdsl`` or ``~/.cache/mechdsl``; None
    without a home folder (never a folder relative to the working one)."""
    base = os.environ.get("XDG_CACHE_HOME", "")
    if not os.path.isabs(base):  # the XDG rule: a relative value is ignored
        base = os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(base, "mechdsl") if os.path.isabs(base) else None


def safe_folder(name: str) -> str | None:
    """A subfolder ``name`` of the cache folder, created private (0700), if it and the cache
    folder are the user's own and writable by nobody else; else None."""
    if not hasattr(os, "getuid"):
        return None
    base = cache_dir_path()
    if base is None:
        return None
    path = os.path.join(base, name)
    try:
        os.makedirs(path, mode=0o700, exist_ok=True)
        ok = all(_safe(os.lstat(p), stat.S_ISDIR) for p in (base, path))
    except OSError:
        return None
    return path if ok else None


def _safe(st: os.stat_result, kind: Callable[[int], bool]) -> bool:
    """Ours and writable by nobody else: no one else can have put or changed anything."""
    return kind(st.st_mode) and st.st_uid == os.getuid() and not st.st_mode & 0o022


def _cache_dir() -> int | None:
    """A descriptor of the cache folder if it is safe to use (created if missing), else None."""
    if not hasattr(os, "getuid") or os.open not in os.supports_dir_fd:
        return None  # no owners or no dir_fd here (Windows): build in memory
    path = cache_dir_path()
    if path is None:
        return None
    try:
        os.makedirs(path, mode=0o700, exist_ok=True)
        fd = os.open(path, _DIR_FLAGS)
    except OSError:
        return None
    try:
        if _safe(os.fstat(fd), stat.S_ISDIR):
            return fd
    except OSError:
        pass
    os.close(fd)
    return None


def _read(dir_fd: int, name: str, key: str) -> Any:
    try:
        fd = os.open(name, _READ_FLAGS, dir_fd=dir_fd)
    except OSError:
        return None
    try:
        st = os.fstat(fd)
        if not _safe(st, stat.S_ISREG) or st.st_size > MAX_CACHE_BYTES:
            return None
        raw = os.read(fd, MAX_CACHE_BYTES + 1)
        doc = json.loads(raw, object_hook=_decode)
        return doc["data"] if isinstance(doc, dict) and doc.get("key") == key else None
    except (OSError, ValueError, KeyError, TypeError, RecursionError):
        return None
    finally:
        os.close(fd)


def _write(dir_fd: int, name: str, key: str, data: Any) -> None:
    """Store ``data`` atomically (a temporary file renamed over the old one); failures are
    ignored: the cache only saves time."""
    tmp = f".{name}.{os.getpid()}.tmp"
    try:
        text = json.dumps(_encode({"key": key, "data": data}), separators=(",", ":"))
        fd = os.open(tmp, _WRITE_FLAGS, 0o600, dir_fd=dir_fd)
    except (OSError, TypeError, ValueError):
        return
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        os.replace(tmp, name, src_dir_fd=dir_fd, dst_dir_fd=dir_fd)
    except OSError:
        try:
            os.unlink(tmp, dir_fd=dir_fd)
        except OSError:
            pass


# JSON has no tuples and only string keys; lark's serialised tables have both.
def _encode(x: Any) -> Any:
    if isinstance(x, dict):
        if all(isinstance(k, str) for k in x) and not {"#d", "#t"} & x.keys():
            return {k: _encode(v) for k, v in x.items()}
        return {"#d": [[_encode(k), _encode(v)] for k, v in x.items()]}
    if isinstance(x, tuple):
        return {"#t": [_encode(v) for v in x]}
    if isinstance(x, list):
        return [_encode(v) for v in x]
    if x is None or isinstance(x, (str, int, float, bool)):
        return x
    raise TypeError(f"cannot store {type(x).__name__}")


def _decode(obj: dict) -> Any:
    if len(obj) == 1:
        if "#d" in obj:
            return {k: v for k, v in obj["#d"]}
        if "#t" in obj:
            return tuple(obj["#t"])
    return obj
