"""What every command-line program of the project shares: one line per user error, clean stops, exit codes.

``SafeGroup`` is a click group whose ``main`` turns

* a user's error (bad file or value, missing dependency, a busy or full output, an interrupted input) into one line
  on stderr that names the file and the problem: exit 2 for usage and input errors, 1 for the environment's
  (disk full, permission, a locked folder, a failed stage);
* Ctrl-C (SIGINT) and SIGTERM into a clean stop: finished outputs stay valid, temporary files are removed by the
  writers' ``finally`` blocks, exit 130 or 143;
* anything else (a bug) into its traceback, saying that it is a bug.

``--debug`` (before the sub-command) shows the traceback of every error.
"""

from __future__ import annotations

import os
import signal
import sys
import traceback
from typing import Any

import click

from spotlessgs.io.errors import FolderLockedError, InputError
from spotlessgs.io.signals import exit_code, raise_on_sigterm

USAGE_ERROR = 2
ENVIRONMENT_ERROR = 1

#: Exceptions whose message is the whole story for the user (the library raises them with the file named).
_INPUT_ERRORS = (InputError, ValueError, FileNotFoundError, FileExistsError, NotADirectoryError, IsADirectoryError,
                 UnicodeDecodeError)
_ENVIRONMENT_ERRORS = (FolderLockedError, OSError, RuntimeError, ImportError, MemoryError, FloatingPointError)
_BUGS_AMONG_THEM = (NotImplementedError, RecursionError)


def one_line(exc: BaseException) -> str:
    """The exception as one line: ``FILE: problem`` where the exception knows its file."""
    if isinstance(exc, ModuleNotFoundError):
        return (f"missing dependency {exc.name!r} ({exc}); install the project with `bash scripts/install.sh` "
                "or `pip install -e .[all]`")
    if isinstance(exc, OSError) and exc.filename is not None and exc.strerror and str(exc).startswith("[Errno"):
        text = f"{exc.filename}: {exc.strerror}"
    else:
        text = str(exc) or type(exc).__name__
    return " ".join(text.split())


def classify(exc: BaseException) -> int | None:
    """The exit code of a user's or the environment's error, or None for a bug."""
    if isinstance(exc, _BUGS_AMONG_THEM):
        return None
    if isinstance(exc, _INPUT_ERRORS):
        return USAGE_ERROR
    if isinstance(exc, _ENVIRONMENT_ERRORS):
        return ENVIRONMENT_ERROR
    return None


class SafeGroup(click.Group):
    """A click group with the project's error handling, clean signal stops and a ``--debug`` flag."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.params.append(click.Option(["--debug"], is_flag=True, expose_value=False, is_eager=True,
                                        help="Show the full traceback of any error."))

    def main(self, args: Any = None, prog_name: str | None = None, **extra: Any) -> Any:  # noqa: D102
        argv = list(sys.argv[1:] if args is None else args)
        debug = "--debug" in argv or os.environ.get("SPOTLESS_DEBUG") == "1"
        name = prog_name or os.path.basename(sys.argv[0]) or self.name or "spotless"
        try:
            previous_sigterm = raise_on_sigterm()
            installed = True
        except ValueError:  # not the main thread (an embedding application): leave SIGTERM alone
            previous_sigterm, installed = None, False
        try:
            result = self._main_handling_errors(argv, prog_name, debug, name, **extra)
        finally:  # an embedding application (or a test's CliRunner) gets its own SIGTERM handler back
            if installed and previous_sigterm is not None:
                signal.signal(signal.SIGTERM, previous_sigterm)
        if args is None and installed:  # the program itself, its work done: a signal during the interpreter's
            for signum in (signal.SIGINT, signal.SIGTERM):  # shutdown changes nothing (exit 0, no "Exception
                signal.signal(signum, signal.SIG_IGN)  # ignored ... KeyboardInterrupt" from a finaliser)
        return result

    def _main_handling_errors(self, argv: list[str], prog_name: str | None, debug: bool, name: str,
                              **extra: Any) -> Any:
        """click's ``main`` with errors, interrupts and exit codes handled as the module docstring says."""
        try:
            return super().main(args=argv, prog_name=prog_name, standalone_mode=False, **extra)
        except click.exceptions.Exit as exc:
            sys.exit(exc.exit_code)
        except click.ClickException as exc:
            exc.show()
            sys.exit(exc.exit_code)
        except (click.Abort, KeyboardInterrupt) as exc:
            interrupt = exc if isinstance(exc, KeyboardInterrupt) else exc.__context__
            if not isinstance(interrupt, KeyboardInterrupt):
                interrupt = KeyboardInterrupt()
            code = exit_code(interrupt)
            if debug:
                traceback.print_exc()
            resume = " (with --resume)" if "train" in argv and "train" in getattr(self, "commands", {}) else ""
            click.echo(f"{name}: stopped by signal ({code - 128}); finished outputs are kept, rerun the same "
                       f"command to resume{resume}", err=True)
            sys.exit(code)
        except BrokenPipeError:  # `spotless ... | head`
            sys.stderr.close()
            sys.exit(ENVIRONMENT_ERROR)
        except Exception as exc:  # noqa: BLE001 - the one place that decides how an error is shown
            code = classify(exc)
            if code is None or debug:
                traceback.print_exc()
            if code is None:
                click.echo(f"{name}: internal error (a bug, please report it with the traceback above): "
                           f"{type(exc).__name__}: {one_line(exc)}", err=True)
                sys.exit(ENVIRONMENT_ERROR)
            click.echo(f"{name}: error: {one_line(exc)}", err=True)
            sys.exit(code)



class FiniteFloatRange(click.FloatRange):
    """click's FloatRange that also refuses NaN and ±inf (FloatRange lets NaN through any bound, and inf through an
    open upper one), for every numeric option of the command-line programs."""

    name = "finite float range"

    def convert(self, value: Any, param: click.Parameter | None, ctx: click.Context | None) -> Any:
        number = super().convert(value, param, ctx)
        if number != number or number in (float("inf"), float("-inf")):
            self.fail(f"{value!r} is not a finite number.", param, ctx)
        return number


#: The most threads a command-line option accepts: torch and OpenMP crash or hang when asked for tens of thousands.
MAX_THREADS = 1024
#: The type of every ``--threads`` option: a whole number in 1..MAX_THREADS.
THREAD_COUNT = click.IntRange(1, MAX_THREADS)
