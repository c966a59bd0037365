"""Run in every worker process of `rmbuild build`'s local Dask cluster as it starts (a Dask preload).

On Linux the worker asks the kernel to kill it when the process that started it (rmbuild's, which holds the
cluster's nannies) dies, however it dies (kill -9 included): no worker outlives the command. Dask's own
warnings in the worker (a task cancelled when a peer died, ...) are not shown: rmbuild reports what failed.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import logging
import os
import signal
import sys
from typing import Any

#: prctl(2) option: the signal the calling process gets when its parent dies
_PR_SET_PDEATHSIG = 1


def die_with_parent() -> bool:
    """Ask for SIGKILL when the parent dies (Linux); False where that is not available."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
        if libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) != 0:
            return False
    except (OSError, AttributeError):
        return False
    if os.getppid() == 1:  # the parent died before the request: go now
        os.kill(os.getpid(), signal.SIGKILL)
    return True


def dask_setup(worker: Any) -> None:
    """Dask's preload hook."""
    die_with_parent()
    logging.getLogger("distributed").setLevel(logging.ERROR)
