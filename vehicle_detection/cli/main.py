"""The ``vehicle-detection`` command.

Subcommands: ``download``, ``train``, ``refine``, ``sweep``, ``calibrate``, ``detect``, ``report``, ``evaluate``, ``mine-negatives``,
each in a module of its own (imported when it runs, so that ``--help`` and the other commands do
not load what one command needs). Errors a user can cause, usage errors included, print one line
on stderr (``vehicle-detection: error: ...``) and exit non-zero; ``--debug`` prints the traceback
before that line (the exit code stays the same).

Exit codes: 0 success; 1 internal error (a bug: please report it); 2 bad command line;
3 bad input file; 4 bad or mismatched model file; 5 output refused or not writable;
6 download failed; 7 some inputs of a batch failed (each named on stderr); 8 a dask scheduler
cannot be reached, or it or a worker went away during the run; 130 interrupted (Ctrl-C, SIGTERM or SIGHUP).

A closed standard output (``vehicle-detection ... | head -1``) does not stop a run: the rest of
the report is discarded, the outputs are written, and the exit status is the run's own.
"""

from __future__ import annotations

import gc
import importlib
import os
import sys
import traceback
from collections.abc import Callable
from contextlib import contextmanager

from .. import warmup
from ..errors import VehicleDetectionError, cli_message, one_line
from ..io import interrupt_on_signals

__all__ = ["main", "run", "COMMANDS", "SEARCHING"]

#: Command -> the module of this package that runs it (``run(args) -> exit code``).
COMMANDS = {
    "download": "download",
    "train": "train",
    "refine": "refine",
    "sweep": "sweep",
    "calibrate": "calibrate",
    "detect": "detect",
    "report": "report",
    "evaluate": "evaluate",
    "mine-negatives": "mine_negatives",
}


def command(name: str) -> Callable[..., int]:
    """The function that runs command ``name``; its module is imported now, not at start-up."""
    return importlib.import_module(f"{__package__}.{COMMANDS[name]}").run


class _GuardedStdout:
    """Standard output that turns quiet, instead of failing, once its reader has gone.

    On the first ``BrokenPipeError`` (``... | head -1``) the file descriptor is pointed at
    ``os.devnull``, so that the rest of the report, and the interpreter's final flush, are
    discarded silently while the run finishes its real outputs.
    """

    def __init__(self, stream) -> None:
        self._stream = stream
        self.broken = False

    def _mute(self) -> None:
        self.broken = True
        try:
            fd = self._stream.fileno()
            devnull = os.open(os.devnull, os.O_WRONLY)
        except (OSError, ValueError, AttributeError):
            return
        try:
            os.dup2(devnull, fd)
        finally:
            os.close(devnull)

    def write(self, text: str) -> int:
        if not self.broken:
            try:
                return self._stream.write(text)
            except BrokenPipeError:
                self._mute()
        return len(text)

    def flush(self) -> None:
        if not self.broken:
            try:
                self._stream.flush()
            except BrokenPipeError:
                self._mute()

    def __getattr__(self, name):
        return getattr(self._stream, name)


@contextmanager
def _guarded_stdout():
    real = sys.stdout
    if real is None:
        yield
        return
    guard = sys.stdout = _GuardedStdout(real)
    try:
        yield
    finally:
        guard.flush()  # a pipe closed early shows up here when stdout is block-buffered
        if sys.stdout is guard:
            sys.stdout = real


#: Commands whose first search a user waits for: on a fresh install, the helper process compiling
#: half the search's kernels starts before anything else is imported (:func:`warmup.start_helper`),
#: unless the searches run in other processes (``--jobs``, ``--scheduler``) or none runs (boxes read).
SEARCHING = frozenset({"detect", "evaluate"})


def _searches(argv: list[str]) -> bool:
    """Whether ``argv`` runs a searching command in this process (read before the parser exists)."""
    words = [a for a in argv if not a.startswith("-")]
    if not words or words[0] not in SEARCHING:
        return False
    for i, a in enumerate(argv):
        if a == "-h" or (a.startswith("--he") and "--help".startswith(a)):  # argparse takes --he, --hel
            return False
        name = a.split("=")[0]
        if name == "--scheduler" or (name == "--boxes" and words[0] == "evaluate"):
            return False
        if name == "--jobs":
            value = a.partition("=")[2] or (argv[i + 1] if i + 1 < len(argv) else "")
            if value != "1":
                return False
    return True


def main(argv=None) -> int:
    """Run the command line; returns the exit code (see module docstring)."""
    argv = sys.argv[1:] if argv is None else list(argv)
    try:
        # From the first moment, for the whole run: a signal while the parser and the command are
        # imported ends the run as one during the command does (130), and the helper with it.
        with interrupt_on_signals():
            if _searches(argv):
                warmup.start_helper()
            from .parser import build_parser  # the features' defaults: numba and NumPy

            with _guarded_stdout():
                parser = build_parser()
                args = parser.parse_args(argv)
                return _run(args)
    except KeyboardInterrupt:  # before _run's own handling
        print("vehicle-detection: interrupted", file=sys.stderr)
        return 130
    finally:
        warmup.stop_helper()  # one the command did not take over (it failed or ended before searching)


def run() -> None:
    """The console script (and ``python -m vehicle_detection.cli``): :func:`main`, then exit with its code.

    The collector is frozen first: the interpreter's exit then does not walk every object numba
    and the codecs made (about 0.3 s of a run). Every output is closed by then.
    """
    code = main()
    gc.freeze()
    sys.exit(code)


def _run(args) -> int:
    # With --debug the traceback comes first, then the same one-line message and exit code.
    # SIGTERM (timeout, docker stop, systemd) and SIGHUP (a closed terminal) stop a run like
    # Ctrl-C (main's interrupt_on_signals): KeyboardInterrupt, so the same clean-up runs and the
    # exit status is 130.
    try:
        return command(args.command)(args)
    except KeyboardInterrupt:
        if args.debug:
            traceback.print_exc()
        print("vehicle-detection: interrupted", file=sys.stderr)
        return 130
    except VehicleDetectionError as exc:
        if args.debug:
            traceback.print_exc()
        print(f"vehicle-detection: error: {cli_message(exc)}", file=sys.stderr)  # in the CLI's words (its flags)
        return exc.exit_code
    except Exception as exc:  # a bug: one line, and how to see more
        if args.debug:
            traceback.print_exc()
        hint = "" if args.debug else " (rerun with --debug for the traceback)"
        print(f"vehicle-detection: internal error: {type(exc).__name__}: {one_line(exc)}{hint}", file=sys.stderr)
        return 1


if __name__ == "__main__":  # pragma: no cover
    run()
