"""Running Blender in a child process (bpy-free helpers).

Cycles catches the ``KeyboardInterrupt`` raised inside its render callback and carries on, so a render running in the
main process cannot be stopped with Ctrl-C. :func:`simulator.render_pipeline.render_dataset` therefore runs Blender
in a child process that it can kill; the helpers here prepare such a child:

* :func:`spotlessgs.io.processes.die_with_parent`: the kernel kills the child when its parent dies, however the parent
  dies (also SIGKILL);
* :func:`spotlessgs.io.processes.drop_blender_script_paths`: a parent that imported bpy hands Blender's script folders
  to a spawned child, where they would shadow the compiled module;
* :func:`silenced_output`: Blender's C code prints straight to file descriptors 1 and 2 (Cycles' GPU probing, for
  instance), which ``sys.stdout`` redirection does not catch.
"""

from __future__ import annotations

import contextlib
import os
import sys
from typing import Iterator


def _flush_c_streams() -> None:
    """Flush the C library's stdio buffers, so that text printed before a redirection goes where it was meant to."""
    with contextlib.suppress(OSError, AttributeError, TypeError):  # TypeError: no CDLL(None) on Windows
        import ctypes

        ctypes.CDLL(None).fflush(None)


@contextlib.contextmanager
def silenced_output(enabled: bool = True) -> Iterator[None]:
    """Send everything written to file descriptors 1 and 2 (C code included) to ``/dev/null`` inside the block.

    The descriptors are restored afterwards, also on an exception; Python's ``sys.stdout`` / ``sys.stderr`` and the C
    library's buffers are flushed on both sides of the redirection. Does nothing when ``enabled`` is False.
    """
    if not enabled:
        yield
        return
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(AttributeError, OSError, ValueError):
            stream.flush()
    _flush_c_streams()
    saved = [os.dup(1), os.dup(2)]
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        try:
            os.dup2(devnull, 1)
            os.dup2(devnull, 2)
        finally:
            os.close(devnull)
        yield
    finally:
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(AttributeError, OSError, ValueError):
                stream.flush()
        _flush_c_streams()
        os.dup2(saved[0], 1)
        os.dup2(saved[1], 2)
        for fd in saved:
            os.close(fd)
