"""Dask worker preload of ``lesmc campaign``'s local cluster: Ctrl-C is the client's.

The terminal sends SIGINT to every process of the job, the workers included. The
client stops the cluster; a worker that took the signal itself would print a
KeyboardInterrupt traceback. A worker started (or restarted after a crash) with
this preload ignores SIGINT; SIGTERM keeps its default, a silent exit.
"""

from __future__ import annotations

import signal
import threading

if threading.current_thread() is threading.main_thread():
    signal.signal(signal.SIGINT, signal.SIG_IGN)
