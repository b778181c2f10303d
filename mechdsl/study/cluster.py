"""The Dask clusters a study runs on: a local one that only this run can use, or a scheduler
given by address, which is trusted.

Trust. Dask moves pickles: whoever can talk to a scheduler can run code in every process of
its cluster, the client's included. So

* the local cluster of ``--workers N`` is made with TLS and temporary credentials
  (distributed's :meth:`~distributed.Security.temporary`: a key and a self-signed certificate
  made in memory for this run, handed to the worker processes through their pipes, written
  nowhere). Every connection between its scheduler, nannies, workers and this client is
  mutual TLS with that certificate: another process of the machine, of any user, can reach
  the ports but cannot complete a handshake. Its HTTP servers serve no route.
* a scheduler given by address (``--scheduler tcp://HOST:PORT`` or ``tls://HOST:PORT``) is
  trusted with code execution in this process, as any Dask client trusts its scheduler. TLS
  comes from Dask's configuration (``distributed.comm.tls.*``, e.g.
  ``DASK_DISTRIBUTED__COMM__TLS__CA_FILE``) or from ``--tls-ca-file``, ``--tls-cert`` and
  ``--tls-key``.

Timeouts. Dask bounds the TCP connect by its timeout but waits for the scheduler's
handshake without one: a port that accepts and never answers hangs a client for ever. Before
a client is made, :func:`probe` does the first steps itself on a plain socket, each bounded
by the deadline and the size of what it reads (connect, TLS handshake, the scheduler's
handshake message, whose length is read first and must be that of a handshake), and
refuses an answer that is not Dask's handshake, unpickling nothing. The client is then made
within the same timeout; while chunks are solved, a scheduler silent for longer ends the run
(:mod:`mechdsl.study.run`).

distributed is imported only by the functions that make a client.
"""

from __future__ import annotations

import logging
import os
import socket
import ssl
import struct
import threading
import time
from contextlib import contextmanager
from typing import Iterator

from ..errors import MechError

#: Seconds each connection step to a scheduler may take (connect, TLS handshake, Dask's
#: handshake, the first reply), and the longest a scheduler may stay silent while chunks
#: are being solved (``--scheduler-timeout``)
SCHEDULER_TIMEOUT = 10.0
#: Bytes a scheduler's handshake message may claim. Dask's handshake is a msgpack map of a
#: few settings (about 100 bytes in distributed 2026.8); a reply claiming more is not one,
#: and is refused before anything is allocated for it
HANDSHAKE_BYTES = 64 * 2**10
#: Loggers of Dask's that report, at ERROR and with tracebacks, what an interrupt or a lost
#: peer does to connections and tasks; the run reports those itself, in one line
DASK_LOGGERS = ("distributed", "tornado", "asyncio")


def import_distributed(option: str):
    """The ``distributed`` module, or a MechError saying how to install it."""
    try:
        import distributed
    except ImportError:
        raise MechError(f"{option} needs Dask's distributed scheduler, which is not "
                        "installed: pip install \"mechdsl[cluster]\"") from None
    return distributed


def local_client(workers: int, timeout: float = SCHEDULER_TIMEOUT):
    """A Dask client of a new cluster of ``workers`` processes on this machine, one thread
    each, on the loopback interface, reachable only with this run's temporary TLS
    credentials (see the module's documentation); a MechError saying how to install dask
    (and cryptography, which makes the credentials) where it is missing."""
    if workers < 1:
        raise MechError(f"--workers {workers}: give at least 1")
    distributed = import_distributed("--workers")
    import dask

    try:
        security = distributed.Security.temporary()
    except ImportError:
        raise MechError("--workers makes the cluster's TLS credentials with cryptography, "
                        "which is not installed: pip install \"mechdsl[cluster]\"") from None
    # distributed's nannies set MALLOC_TRIM_THRESHOLD_=65536 in their workers by default,
    # which pins glibc's mmap threshold at 128 KiB: every large temporary of the numpy path is
    # then mapped and page-faulted afresh, and a chunk takes 1.7 times as long (measured on
    # the slider-crank's sweep): the workers here keep glibc's own adaptive threshold.
    #
    # The nannies also write their workers' environment into this process's os.environ
    # (OMP_NUM_THREADS=1, ...), where it would outlive the cluster: it is put back. The
    # scheduler's HTTP server takes a free port, not 8787, which another cluster may hold;
    # it and the workers' serve no route (their pages are not behind the TLS).
    config = {"distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_": None,
              "distributed.scheduler.http.routes": [],
              "distributed.worker.http.routes": [],
              "distributed.comm.timeouts.connect": f"{timeout}s",
              # the workers ignore Ctrl-C, which reaches them too (mechdsl.study.worker)
              "distributed.worker.preload": ["mechdsl.study.worker"]}
    saved = dict(os.environ)
    os.environ.pop("MALLOC_TRIM_THRESHOLD_", None)  # nor inherited (an earlier cluster's)
    try:
        with dask.config.set(config), quiet_dask(), _starting() as received:
            cluster = distributed.LocalCluster(
                n_workers=workers, threads_per_worker=1, processes=True, host="127.0.0.1",
                protocol="tls://", security=security, dashboard_address="127.0.0.1:0",
                silence_logs=logging.CRITICAL)
            client = distributed.Client(cluster, security=security, timeout=timeout)
    finally:
        os.environ.clear()
        os.environ.update(saved)
    if received:
        from ..writing import Interrupted

        close(client)
        raise Interrupted(received[0])
    return client


@contextmanager
def _starting() -> Iterator[list[int]]:
    """While the local cluster starts: SIGINT ignored, SIGTERM recorded in the list given.

    Ctrl-C at a terminal signals the whole foreground process group, the worker processes
    included, and a worker it reaches while Python starts dies with a traceback, before its
    preload (:mod:`mechdsl.study.worker`) can make it ignore SIGINT. A disposition of
    SIG_IGN is inherited through fork and exec, and Python then leaves it alone, so the
    workers are started with it; this process ignores a Ctrl-C meanwhile (the cluster's
    start, 2-3 s here) and heeds the next. SIGTERM, sent to this process alone, is
    recorded, and the caller stops once the cluster is whole (a cluster interrupted while
    it starts cannot be closed)."""
    import signal
    import threading

    received: list[int] = []
    if threading.current_thread() is not threading.main_thread():
        yield received
        return
    previous = {signal.SIGINT: signal.signal(signal.SIGINT, signal.SIG_IGN)}
    if signal.getsignal(signal.SIGTERM) is not signal.SIG_IGN:
        previous[signal.SIGTERM] = signal.signal(
            signal.SIGTERM, lambda signum, frame: received.append(signum))
    try:
        yield received
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


def security_of(ca_file: str | None = None, cert: str | None = None, key: str | None = None):
    """The ``distributed.Security`` of a client: Dask's configuration
    (``distributed.comm.tls.*``), with the CA, certificate and key files given here in
    place of the configured ones."""
    distributed = import_distributed("--scheduler")
    given = {"tls_ca_file": ca_file, "tls_client_cert": cert, "tls_client_key": key}
    for option, path in zip(("--tls-ca-file", "--tls-cert", "--tls-key"), given.values()):
        if path is not None and not os.path.isfile(path):
            raise MechError(f"{option} {path}: no such file")
    given = {k: v for k, v in given.items() if v is not None}
    try:
        return distributed.Security(**given, require_encryption=bool(given) or None)
    except (OSError, ValueError, ssl.SSLError) as err:
        raise MechError(f"the TLS configuration of the client is not usable: {err}") from None


def remote_client(address: str, timeout: float = SCHEDULER_TIMEOUT, security=None):
    """A Dask client of the cluster whose scheduler is at ``address`` (``tcp://`` or
    ``tls://``), made with ``security`` (default: Dask's configuration); every step within
    ``timeout`` seconds, else a MechError naming the scheduler (:func:`probe`)."""
    distributed = import_distributed("--scheduler")
    security = security if security is not None else security_of()
    deadline = time.monotonic() + timeout
    probe(address, security, timeout)
    made: dict = {}

    def make() -> None:
        try:
            with quiet_dask():
                made["client"] = distributed.Client(address, timeout=timeout,
                                                    security=security)
        except BaseException as err:  # noqa: BLE001 - reported by the caller's thread
            made["error"] = err

    # the client's own handshake is again unbounded in distributed: it is made on a thread
    # of its own, and abandoned (a daemon) if the deadline passes first
    thread = threading.Thread(target=make, name="mechdsl-connect", daemon=True)
    thread.start()
    thread.join(max(deadline - time.monotonic(), 0.0) + 1.0)
    if "client" in made:
        return made["client"]
    if "error" not in made:
        raise MechError(f"--scheduler {address}: the scheduler did not finish the client's "
                        f"connection within {timeout:g} s (--scheduler-timeout)")
    err = made["error"]
    if isinstance(err, KeyboardInterrupt):
        raise err
    if isinstance(err, MemoryError):
        # distributed allocates what a frame's header claims before reading it
        raise MechError(f"--scheduler {address}: a reply from the scheduler claimed more "
                        "memory than this process could allocate (distributed raised "
                        "MemoryError while reading it): is it a Dask scheduler, of a version "
                        "compatible with this client's?") from None
    # whatever distributed raises while it connects (closed streams, a garbled reply, a
    # protocol mismatch) is the scheduler's answer, not a defect of this run
    raise MechError(f"--scheduler {address}: cannot connect to a Dask scheduler there "
                    f"({type(err).__name__}: {_short(err)})") from None


def probe(address: str, security, timeout: float) -> None:
    """Check that a Dask scheduler answers at ``address`` before a client is made: connect,
    the TLS handshake for ``tls://``, and the first message the scheduler sends on a new
    connection (Dask's handshake: an 8-byte length, at most :data:`HANDSHAKE_BYTES`, then
    frames whose first is a msgpack map), all within ``timeout`` seconds; a MechError naming
    the scheduler and the step otherwise. Nothing read is unpickled."""
    scheme, host, port = _host_port(address)
    deadline = time.monotonic() + timeout
    try:
        sock = socket.create_connection((host, port), timeout=timeout)
    except socket.timeout:
        raise _silent(address, timeout, "to accept the connection") from None
    except OSError as err:
        raise MechError(f"--scheduler {address}: cannot connect there ({_short(err)})") from None
    try:
        if scheme == "tls":
            context = security.get_connection_args("client")["ssl_context"]
            if context is None:
                raise MechError(f"--scheduler {address}: a tls:// scheduler needs the CA "
                                "that signed its certificate and this client's own: give "
                                "--tls-ca-file, --tls-cert and --tls-key, or set them in "
                                "Dask's configuration (distributed.comm.tls)")
            sock.settimeout(_left(deadline, address, timeout, "to complete the TLS handshake"))
            try:
                sock = context.wrap_socket(sock, server_hostname=host)
            except socket.timeout:
                raise _silent(address, timeout, "to complete the TLS handshake") from None
            except (ssl.SSLError, OSError) as err:
                raise MechError(f"--scheduler {address}: the TLS handshake failed "
                                f"({_short(err)})") from None
        head = _read(sock, 8, deadline, address, timeout)
        (size,) = struct.unpack("<Q", head)
        if not 16 <= size <= HANDSHAKE_BYTES:
            raise MechError(f"--scheduler {address}: what answered there is not a Dask "
                            f"scheduler: its first message claims {size} bytes, where Dask's "
                            f"handshake takes 16 to {HANDSHAKE_BYTES}")
        _check_handshake(_read(sock, size, deadline, address, timeout), address)
    finally:
        sock.close()


def _check_handshake(body: bytes, address: str) -> None:
    """Refuse ``body`` unless it is Dask's handshake: frames (a count, their lengths, their
    bytes) whose first is a msgpack map (read with msgpack's own bounds, no extension
    types: nothing is unpickled)."""
    import msgpack

    wrong = MechError(f"--scheduler {address}: what answered there is not a Dask scheduler "
                      "(its first message is not Dask's handshake)")
    (count,) = struct.unpack_from("<Q", body)
    if not 1 <= count <= (len(body) - 8) // 8:
        raise wrong
    lengths = struct.unpack_from(f"<{count}Q", body, 8)
    offset = 8 + 8 * count
    if sum(lengths) != len(body) - offset:
        raise wrong
    try:
        header = msgpack.unpackb(body[offset:offset + lengths[0]], raw=False,
                                 strict_map_key=False, max_ext_len=0)
    except (ValueError, TypeError, msgpack.ExtraData, msgpack.FormatError,
            msgpack.StackError):
        raise wrong from None
    if not isinstance(header, dict):
        raise wrong


def _read(sock, n: int, deadline: float, address: str, timeout: float) -> bytes:
    """``n`` bytes from ``sock``, each piece within what is left of ``deadline``."""
    parts, got = [], 0
    while got < n:
        sock.settimeout(_left(deadline, address, timeout, "to send its handshake"))
        try:
            part = sock.recv(min(n - got, 2**16))
        except socket.timeout:
            raise _silent(address, timeout, "to send its handshake") from None
        except OSError as err:
            raise MechError(f"--scheduler {address}: the connection failed while the "
                            f"scheduler's handshake was read ({_short(err)})") from None
        if not part:
            raise MechError(f"--scheduler {address}: the connection was closed before a "
                            "Dask handshake arrived: is a Dask scheduler listening there, "
                            "with this protocol (tcp:// or tls://)?")
        parts.append(part)
        got += len(part)
    return b"".join(parts)


def _left(deadline: float, address: str, timeout: float, step: str) -> float:
    left = deadline - time.monotonic()
    if left <= 0:
        raise _silent(address, timeout, step)
    return left


def _silent(address: str, timeout: float, step: str) -> MechError:
    return MechError(f"--scheduler {address}: no answer within {timeout:g} s, waiting "
                     f"for the scheduler {step} (--scheduler-timeout)")


def _host_port(address: str) -> tuple[str, str, int]:
    """(scheme, host, port) of ``tcp://HOST:PORT`` or ``tls://HOST:PORT`` (tcp:// if none)."""
    scheme, _, rest = address.rpartition("://")
    scheme = scheme or "tcp"
    host, _, port = rest.rpartition(":")
    host = host.strip("[]")
    if scheme not in ("tcp", "tls") or not host or not port.isdigit() \
            or not 0 < int(port) < 65536:
        raise MechError(f"--scheduler {address}: give the scheduler's address as "
                        "tcp://HOST:PORT or tls://HOST:PORT")
    return scheme, host, int(port)


def _short(err: BaseException) -> str:
    text = str(err) or type(err).__name__
    return text if len(text) <= 200 else text[:200] + "..."


def close(client) -> None:
    """Close ``client``, and the local cluster it started (not a remote one), in silence:
    closing has nothing to tell (after an interrupt, the scheduler logged at CRITICAL, with
    a traceback, each cancelled chunk it could no longer report to the closed client)."""
    with quiet_dask(logging.CRITICAL + 1):
        cluster = client.cluster
        # each part on its own and best-effort: on a busy machine, after a Ctrl-C, the
        # client's close took longer than its 20 s (twice the connect timeout) and its
        # TimeoutError ended an interrupted run as an internal error, exit 3 (the fresh
        # clone's suite, 2026-11-29); the local cluster is closed all the same
        try:
            client.close()
        except (TimeoutError, OSError):
            pass
        if cluster is not None and type(cluster).__name__ == "LocalCluster":
            try:
                cluster.close()
            except (TimeoutError, OSError):
                pass


@contextmanager
def quiet_dask(level: int = logging.CRITICAL) -> Iterator[None]:
    """Dask's loggers silent below ``level`` (CRITICAL) while this lasts: an interrupt, a
    closed connection or a lost worker is reported by the run in one line, not by
    tracebacks."""
    # distributed's configuration gives some of its loggers levels of their own
    # (distributed.client: warning): each one under the names is set, not only the roots
    names = [n for n in list(logging.root.manager.loggerDict)
             if any(n == root or n.startswith(root + ".") for root in DASK_LOGGERS)]
    loggers = [logging.getLogger(name) for name in {*DASK_LOGGERS, *names}]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(level)
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels):
            lg.setLevel(level)
