"""Helpers for worker and child processes (bpy-free, numpy-free): tie a child's life to its parent's, and keep a
parent's Blender script folders out of a spawned child's import path.

Used by the simulator's Blender child process (:mod:`simulator.render_pipeline`) and by the job executors' workers
(:mod:`spotlessgs.jobs`).
"""

from __future__ import annotations

import os
import signal
import sys
from pathlib import Path


def drop_blender_script_paths() -> None:
    """Remove Blender's script folders from ``sys.path``.

    A parent that has imported bpy has ``.../bpy/<version>/scripts/...`` on its path, and a spawned child inherits it:
    there ``import bpy`` would find the pure-Python ``scripts/modules/bpy`` package before the compiled module and
    fail with "No module named '_bpy'". The child's own ``import bpy`` puts the folders back in the right order.
    """
    sys.path[:] = [p for p in sys.path if not ("bpy" in Path(p).parts and "scripts" in Path(p).parts)]


def die_with_parent(signum: int = signal.SIGKILL, parent_pid: int | None = None) -> bool:
    """Linux: ask the kernel to send ``signum`` to this process when its parent dies (``prctl(PR_SET_PDEATHSIG)``).

    When ``parent_pid`` is given and the parent is already gone (it died before this call), the signal is sent at
    once. Returns False where the call is not available (not Linux).
    """
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        pr_set_pdeathsig = 1
        if libc.prctl(pr_set_pdeathsig, int(signum), 0, 0, 0) != 0:
            return False
    except (OSError, AttributeError):
        return False
    if parent_pid is not None and os.getppid() != parent_pid:
        os.kill(os.getpid(), signum)
    return True
