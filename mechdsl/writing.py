"""Writing what a run produces without harming anything.

* Files are written under a temporary name in the target's own folder and renamed over it
  when complete (:func:`atomic_path`): a reader sees the old file or the new one, never a
  part, and an error or an interrupt leaves no temporary file behind. The new file gets the
  mode a plain ``open()`` would give it, an existing one keeps its mode, and a symbolic link
  is written through (the file it points to is replaced; the link stays a link).
* :func:`check_distinct` refuses, before a run, an output that is an input of the run or
  another output of it, comparing files by identity, not by spelling.
* :class:`SignalGuard` makes SIGTERM stop a run as Ctrl-C does, and holds both back while a
  file must not be cut short.
* :class:`StdoutError` tells a failure to write standard output (a closed pipe, a full disk)
  from the failure of a file.
"""

from __future__ import annotations

import contextlib
import os
import re
import secrets
import signal
import stat
import sys
import threading
from dataclasses import dataclass
from typing import IO, Callable, Iterator, Sequence

from .errors import MechError

# ---------------------------------------------------------------------------------------------
# atomic files

#: Names that stand for one of the process's own streams: written in place, never replaced.
_STREAM_NAME = re.compile(r"^/(dev/(stdout|stderr|fd/\d+)|proc/(self|\d+)/fd/\d+)$")


def is_direct(path: str | os.PathLike) -> bool:
    """Whether ``path`` is written in place instead of replaced: it exists and is not a
    regular file (a device such as /dev/null, a named pipe, a terminal: it cannot be
    replaced, and its folder is no place for temporary files), or it names one of the
    process's streams (/dev/stdout, /dev/fd/N), whatever that stream is redirected to."""
    path = os.fspath(path)
    if _STREAM_NAME.match(os.path.abspath(path)):
        return True
    try:
        return not stat.S_ISREG(os.stat(path).st_mode)
    except OSError:  # absent (or unreadable): created as a regular file
        return False


def _create_temp(folder: str, name: str) -> tuple[int, str]:
    """Create an empty file with a new name in ``folder`` and open it. The name ends with
    the target's extension, by which matplotlib's animation writers (Pillow, ffmpeg) choose
    the format. Mode 0o666 as open() would ask for: the umask (and a default ACL) applies."""
    stem, ext = os.path.splitext(name)
    flags = os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0)
    for _ in range(100):
        tmp = os.path.join(folder, f".{stem[:100]}.{secrets.token_hex(4)}.tmp{ext[:20]}")
        try:
            return os.open(tmp, flags, 0o666), tmp
        except FileExistsError:
            continue
    raise FileExistsError(f"no free temporary name in {folder}")


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[str]:
    """Give a path to write the new content of ``path`` into; when the block ends normally
    the content replaces ``path`` at once (os.replace), else it is removed.

    A symbolic link is resolved (os.path.realpath): the file it points to is replaced and
    the link stays a link. The file keeps the mode it had; a new file gets the mode a plain
    open() would give it (0o666 less the umask). A target written in place
    (:func:`is_direct`) is given as it is."""
    path = os.fspath(path)
    if is_direct(path):
        yield path
        return
    target = os.path.realpath(path)
    folder, name = os.path.split(target)
    fd, tmp, replaced = -1, None, False
    # SIGINT and SIGTERM wait while the file is created, and are let through only inside the
    # try: whenever one comes, the finally below removes the file
    unblock = _block_signals()
    try:
        fd, tmp = _create_temp(folder, name)
        unblock()
        try:
            mode = stat.S_IMODE(os.stat(target).st_mode)
        except FileNotFoundError:
            mode = stat.S_IMODE(os.fstat(fd).st_mode)
        os.close(fd)
        fd = -1
        yield tmp
        # again: a writer may have removed and recreated the file (with its own mode)
        os.chmod(tmp, mode)
        os.replace(tmp, target)
        replaced = True
    finally:
        unblock()
        if fd >= 0:
            os.close(fd)
        if tmp is not None and not replaced:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)


def _block_signals() -> Callable[[], None]:
    """Hold SIGINT and SIGTERM until the returned function is called (once or more): a step
    that must not be cut in two. The signals' handlers are replaced by one that only notes
    them, and the noted ones are raised again once the old handlers are back. (Blocking them
    with pthread_sigmask is not enough: it blocks them in this thread only, and numpy's BLAS
    threads, started by a matrix product, would receive them, Python then running the
    handler in this thread all the same.)"""
    if threading.current_thread() is not threading.main_thread():
        return lambda: None
    noted: list[int] = []
    old = {s: signal.signal(s, lambda signum, frame: noted.append(signum))
           for s in (signal.SIGINT, signal.SIGTERM)}
    done: list[bool] = []

    def unblock() -> None:
        if not done:
            done.append(True)
            for s, handler in old.items():
                signal.signal(s, handler)
            for s in noted:
                signal.raise_signal(s)

    return unblock


def write_text(path: str | os.PathLike, write: Callable[[IO[str]], None]) -> None:
    """Write a text file (UTF-8) through :func:`atomic_path`: ``write(f)`` writes the
    content into the open file ``f``."""
    with atomic_path(path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as f:
        write(f)


# ---------------------------------------------------------------------------------------------
# outputs that would destroy inputs


@dataclass(frozen=True)
class Output:
    """A file a run writes, named ``path`` on the command line after ``option``; or, with
    ``member``, a family of files in the folder of ``path`` (an export's files), ``member``
    telling whether a file name is one of them; with ``folder``, the folder ``path`` and all
    it holds (a store, replaced whole)."""

    option: str
    path: str
    member: Callable[[str], bool] | None = None
    folder: bool = False

    def describe(self) -> str:
        return f"{'a file of ' if self.member else 'the output of '}{self.option} {self.path}"


def _same(a: str, b: str) -> bool:
    """One file under two names: the same path once links and '..' are resolved, or (both
    existing) the same inode, which also catches hard links."""
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist (yet)
        return False


def _inside(path: str, folder: str) -> bool:
    """Whether ``path`` lies somewhere below ``folder`` (links resolved)."""
    return os.path.realpath(path).startswith(os.path.realpath(folder) + os.sep)


def _series_hit(path: str, series: Output) -> str | None:
    """The name of the file of ``series`` that ``path`` is, if it is one."""
    folder = os.path.dirname(os.path.realpath(series.path))
    real = os.path.realpath(path)
    if os.path.dirname(real) == folder and series.member(os.path.basename(real)):
        return os.path.basename(real)
    try:  # an existing file of the series may be a link to ``path`` or share its inode
        with os.scandir(folder) as entries:
            for entry in entries:
                if series.member(entry.name) and _same(entry.path, path):
                    return entry.name
    except OSError:
        pass
    return None


def _clash(path: str, other: Output) -> str | None:
    if other.member is None:
        return other.path if _same(path, other.path) else None
    return _series_hit(path, other)


def check_distinct(inputs: Sequence[tuple[str, str]], outputs: Sequence[Output]) -> None:
    """Refuse (MechError) an output that is one of the ``inputs`` ((what, path): the model
    file, the files it reads) or another output of the same run. Outputs written in place
    (:func:`is_direct`, /dev/null for instance) replace nothing and are not compared."""
    outs = [o for o in outputs if o.folder or not is_direct(o.path)]  # a store is a folder
    for i, out in enumerate(outs):
        if out.member is None:
            for what, path in inputs:
                if _same(out.path, path) or (out.folder and _inside(path, out.path)):
                    raise MechError(f"{out.option} {out.path} would overwrite {what} {path}; "
                                    "choose another file name")
        else:
            for what, path in inputs:
                hit = _series_hit(path, out)
                if hit:
                    raise MechError(f"{out.option} {out.path} would overwrite {what} {path} "
                                    f"(it writes {hit}); choose another file name")
        for other in outs[:i]:
            if out.member is None:
                hit = _clash(out.path, other)
            elif other.member is None:
                hit = _series_hit(other.path, out)
            else:
                hit = None  # a run has one export: two families never meet
            if hit:
                raise MechError(f"{out.option} {out.path} would overwrite "
                                f"{other.describe()}; give each output its own file name")


# ---------------------------------------------------------------------------------------------
# signals


class Interrupted(KeyboardInterrupt):
    """The KeyboardInterrupt of :class:`SignalGuard`: ``signum`` is SIGINT or SIGTERM.
    A KeyboardInterrupt, so that whatever stops cleanly on Ctrl-C (the solver keeps its
    instants, a temporary file is removed) does so on SIGTERM as well."""

    def __init__(self, signum: int) -> None:
        super().__init__(signal.Signals(signum).name)
        self.signum = signum


def exit_status(err: BaseException) -> int:
    """The conventional exit status of a process stopped by a signal: 128 + its number
    (130 for SIGINT or a plain KeyboardInterrupt, 143 for SIGTERM)."""
    return 128 + int(getattr(err, "signum", signal.SIGINT))


class SignalGuard:
    """While entered (a context manager, in the main thread), the first SIGINT or SIGTERM
    raises :class:`Interrupted` and later ones are only recorded (the run is stopping and
    writes what it solved); inside :meth:`held` they are recorded and raised when it ends.
    A signal ignored by whoever started the process (nohup, a background job) stays ignored.
    ``received`` is the last signal received, if any."""

    def __init__(self, signums: Sequence[int] = (signal.SIGINT, signal.SIGTERM)) -> None:
        self.signums = tuple(signums)
        self.received: int | None = None
        #: how many signals were received
        self.count = 0
        self._pending: int | None = None
        self._holding = False
        self._previous: dict[int, object] = {}

    def __enter__(self) -> SignalGuard:
        if threading.current_thread() is threading.main_thread():
            for signum in self.signums:
                if signal.getsignal(signum) is not signal.SIG_IGN:
                    self._previous[signum] = signal.signal(signum, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        for signum, handler in self._previous.items():
            signal.signal(signum, handler)
        self._previous.clear()

    def hold(self) -> None:
        """From now on, record SIGINT and SIGTERM instead of raising them (what was solved is
        about to be written), until :meth:`release`."""
        self._holding = True

    def release(self) -> None:
        """Raise :class:`Interrupted` for a signal recorded while holding, if any; else let
        the next one raise again (it may stop the pictures, never the CSV, written by then)."""
        self._holding = False
        if self._pending is not None:
            signum, self._pending = self._pending, None
            self._holding = True
            raise Interrupted(signum)

    def _handle(self, signum: int, frame) -> None:
        self.received = signum
        self.count += 1
        if self._holding:
            self._pending = signum
            return
        # one interrupt stops the run; those that follow while what was solved is being
        # written must not cut that short: from now on they are only recorded
        self._holding = True
        raise Interrupted(signum)

    @contextlib.contextmanager
    def held(self) -> Iterator[None]:
        """Hold SIGINT and SIGTERM back while the block runs; when it ends normally, raise
        :class:`Interrupted` for the last one received meanwhile."""
        outer = self._holding
        self._holding = True
        try:
            yield
        finally:
            self._holding = outer
        if not outer and self._pending is not None:
            signum, self._pending = self._pending, None
            self._holding = True  # as in _handle: the run stops once
            raise Interrupted(signum)


# ---------------------------------------------------------------------------------------------
# standard output


class StdoutError(Exception):
    """Standard output cannot be written: the reader closed the pipe (``errno`` EPIPE) or
    the disk is full. Not an OSError, so that no handler of file errors takes it."""

    def __init__(self, err: OSError) -> None:
        super().__init__(f"cannot write to standard output: {err.strerror or err}")
        self.errno = err.errno
        self.strerror = err.strerror or str(err)


@contextlib.contextmanager
def stdout_errors() -> Iterator[None]:
    """Turn an OSError of the block, which writes to standard output only, into
    :class:`StdoutError`."""
    try:
        yield
    except OSError as err:
        raise StdoutError(err) from None


def emit(*lines: str) -> None:
    """Print ``lines`` on standard output; a failure to write there raises StdoutError."""
    with stdout_errors():
        for line in lines:
            print(line)


def silence_stdout() -> None:
    """Point file descriptor 1 at /dev/null, after standard output failed: what is still
    buffered for it is then flushed there at exit, instead of failing again and printing
    'Exception ignored' from the interpreter's shutdown."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(devnull, sys.stdout.fileno())
        finally:
            os.close(devnull)
    except (OSError, ValueError, AttributeError):  # no real descriptor: nothing to flush
        pass
