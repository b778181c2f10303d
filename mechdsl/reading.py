"""Reading the files a model names, and the model file itself, as data.

A ``.mech`` file comes from anywhere (downloaded, mailed), so opening it must be as harmless
as opening a CSV, and so must reading the tables and meshes it names:

* only regular files are read: a FIFO would block for ever, ``/dev/zero`` would never end, a
  directory or a socket is no data. They are refused before anything is read (the file is
  opened with ``O_NONBLOCK``, so that even a FIFO swapped in at the last moment cannot block).
* the size is checked before reading against a named limit (:data:`MAX_MODEL_BYTES`,
  :data:`MAX_DATA_BYTES`), and reading stops one byte past it (a file that grows, or that
  reports no size, is still bounded).
* messages name the file and the reason, never its content; callers that point at a bad
  token show at most a few characters of it (:func:`excerpt`).

The limits are module attributes, read at each call: a program that needs bigger files may
raise them (``mechdsl.reading.MAX_MODEL_BYTES = 64 * 2**20``).
"""

from __future__ import annotations

import os
import stat

from .errors import MechError, Source, Span
from .memory import size_text

#: The largest ``.mech`` file read. Parsing (lark's parse tree, then the model) costs about
#: 3.5 s and 130 MB of memory per MB of an ordinary model (measured on the 10,001-body chain
#: of the benchmarks, 1.6 MB, and on a file of params), and at worst, for text that is
#: nothing but tiny expressions ("min(1,1,1,..."), about 27 s and 480 MB per MB. 4 MiB holds
#: a chain of some 25,000 bodies.
MAX_MODEL_BYTES = 4 * 2**20

#: The largest table (``table("data.csv", t)``) or mesh (``shape = "plate.msh"``) file read:
#: a million table points, or a mesh of about a million triangles.
MAX_DATA_BYTES = 64 * 2**20

_KINDS = ((stat.S_ISDIR, "a directory"), (stat.S_ISFIFO, "a FIFO (named pipe)"),
          (stat.S_ISCHR, "a character device"), (stat.S_ISBLK, "a block device"),
          (stat.S_ISSOCK, "a socket"))
_FLAGS = (os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_NOCTTY", 0)
          | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_BINARY", 0))


def read_data(path: str, what: str, limit: str = "MAX_DATA_BYTES", span: Span | None = None,
              source: Source | None = None, shown: str | None = None) -> bytes:
    """The bytes of the regular file ``path``, at most the limit named ``limit`` of them
    (:data:`MAX_DATA_BYTES` or :data:`MAX_MODEL_BYTES`).

    ``what`` names the file in messages ("the table ", "the shape ", "" for the model),
    ``shown`` is the name as the user wrote it (default ``path``), and ``span``/``source``
    where the error points. Anything else than a regular file, a file over the limit, or an
    OS error (no such file, no permission) is a :class:`MechError` there.
    """
    shown = path if shown is None else shown
    fd = _open(path, what, limit, span, source, shown)
    limit_bytes = globals()[limit]
    try:
        chunks, total = [], 0
        while total <= limit_bytes:  # one byte past the limit tells a file that grew
            chunk = os.read(fd, min(1 << 20, limit_bytes + 1 - total))
            if not chunk:
                break
            chunks.append(chunk)
            total += len(chunk)
    except OSError as err:
        raise MechError(f"cannot read {what}{shown}: {err.strerror}", span, source) from None
    finally:
        os.close(fd)
    if total > limit_bytes:
        raise _too_big(what, shown, total, limit, span, source, " or more")
    return b"".join(chunks)


def check_data(path: str, what: str, limit: str = "MAX_DATA_BYTES", span: Span | None = None,
               source: Source | None = None, shown: str | None = None) -> None:
    """Make the checks of :func:`read_data` (a regular file, within ``limit``) without
    reading: for a reader that takes a path, such as meshio."""
    os.close(_open(path, what, limit, span, source, path if shown is None else shown))


def excerpt(text: str, width: int = 12) -> str:
    """``text`` quoted, cut to ``width`` characters with '...': how a message shows a bad
    token of a data file without echoing the file."""
    text = text if len(text) <= width else text[:width] + "..."
    return repr(text)


def _open(path: str, what: str, limit: str, span: Span | None, source: Source | None,
          shown: str) -> int:
    """A descriptor open for reading on the regular file ``path`` within the limit named
    ``limit``, or a MechError."""
    try:
        # stat first: opening a device may itself do something (a tape rewinds)
        _check(os.stat(path), what, limit, span, source, shown)
        fd = os.open(path, _FLAGS)
    except OSError as err:
        raise MechError(f"cannot read {what}{shown}: {err.strerror}", span, source) from None
    except ValueError:  # a NUL character in the name: no file can have it
        raise MechError(f"cannot read {what}{shown}: a file name has no NUL character",
                        span, source) from None
    try:  # again on what was opened: the path may have changed in between
        _check(os.fstat(fd), what, limit, span, source, shown)
    except BaseException:
        os.close(fd)
        raise
    return fd


def _check(st: os.stat_result, what: str, limit: str, span: Span | None,
           source: Source | None, shown: str) -> None:
    if not stat.S_ISREG(st.st_mode):
        kind = next((name for test, name in _KINDS if test(st.st_mode)), "not a plain file")
        raise MechError(f"cannot read {what}{shown}: it is {kind}, not a regular file",
                        span, source)
    if st.st_size > globals()[limit]:
        raise _too_big(what, shown, st.st_size, limit, span, source, "")


def _too_big(what: str, shown: str, size: int, limit: str, span: Span | None,
             source: Source | None, more: str) -> MechError:
    return MechError(f"cannot read {what}{shown}: it has {size_text(size, exact=True)}{more}, "
                     f"more than the limit of {size_text(globals()[limit], exact=True)} "
                     f"(mechdsl.reading.{limit})",
                     span, source)
