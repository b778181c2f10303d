"""Set-up of the worker processes of the local cluster (``--workers N``), loaded by Dask in
each of them as a preload module (``distributed.worker.preload``).

Ctrl-C at a terminal signals the whole foreground process group, the workers included:
each would die printing a KeyboardInterrupt traceback, where the run itself is interrupted
and then closes its cluster. A worker of the local cluster ignores SIGINT; its nanny still
stops it (SIGTERM, or the closing of its pipe).
"""

from __future__ import annotations

import signal
import threading


def dask_setup(worker) -> None:
    """Ignore SIGINT in this worker process (called by Dask once the worker has started)."""
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGINT, signal.SIG_IGN)
