"""Stopping cleanly: SIGTERM becomes an exception, like SIGINT's KeyboardInterrupt.

Python's default SIGTERM ends the process without running ``finally`` blocks, so atomic writes would leave their
temporary files and child processes would run on. :func:`raise_on_sigterm` turns SIGTERM into :class:`Terminated`
(a ``KeyboardInterrupt``, so that every clean-up that handles Ctrl-C also handles it); the command-line layer exits
130 after SIGINT and 143 after SIGTERM.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from typing import Iterator


class Terminated(KeyboardInterrupt):
    """The process received SIGTERM."""


def _raise_terminated(signum, _frame) -> None:
    raise Terminated(f"received signal {signal.Signals(signum).name}")


def raise_on_sigterm():
    """Make SIGTERM raise :class:`Terminated` in the main thread (call from the main thread, else ValueError).

    Returns:
        the previous handler, for ``signal.signal(signal.SIGTERM, previous)`` (None: one installed by C code).
    """
    return signal.signal(signal.SIGTERM, _raise_terminated)


def exit_code(interrupt: KeyboardInterrupt) -> int:
    """The conventional exit status of a process stopped by this interrupt: 128 + the signal number."""
    return 128 + (signal.SIGTERM if isinstance(interrupt, Terminated) else signal.SIGINT)


class StopRequest:
    """Set by :func:`deferred_interrupts` when SIGINT or SIGTERM arrived; see there."""

    def __init__(self) -> None:
        self.signum: int | None = None

    @property
    def requested(self) -> bool:
        """Whether a stop was asked for."""
        return self.signum is not None

    def raise_if_requested(self) -> None:
        """Raise the interrupt the signal stands for (KeyboardInterrupt or Terminated), if one arrived."""
        if self.signum == signal.SIGTERM:
            raise Terminated("received signal SIGTERM")
        if self.signum is not None:
            raise KeyboardInterrupt


@contextlib.contextmanager
def deferred_interrupts() -> Iterator[StopRequest]:
    """Let the work in the block reach a consistent point before it stops.

    Inside the block SIGINT and SIGTERM only set ``request.signum``; the loop checks ``request.requested`` at a safe
    point (after a step), saves what it has and calls ``request.raise_if_requested()``; a signal that arrived after
    the last check is raised when the block ends. A second signal raises at once (an impatient user is not kept
    waiting). Outside the main thread the block changes nothing. The previous handlers are put back when the block
    ends, except one that C code installed (Python cannot reinstall it; the block's handler stays).
    """
    request = StopRequest()
    if threading.current_thread() is not threading.main_thread():
        yield request
        return

    def handler(signum, _frame) -> None:
        if request.signum is not None:
            request.signum = signum
            request.raise_if_requested()
        request.signum = signum

    previous = {s: signal.signal(s, handler) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield request
    finally:
        for s, old in previous.items():
            if old is not None:  # None: a handler installed by C code, which Python cannot put back
                signal.signal(s, old)
    request.raise_if_requested()  # a signal during the block's last part: the work is finished, still stop
