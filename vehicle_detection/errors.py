"""Exceptions raised for bad input, bad files and refused outputs.

Every error that a user can cause derives from :class:`VehicleDetectionError`; the command-line
interface prints such an error as one line on stderr and exits with the code in ``exit_code``.
Anything else that escapes is a bug. :func:`require` imports an optional dependency, or raises
:class:`MissingDependencyError` naming the extra that installs it (the command-line install has
no plotting library: matplotlib comes with the ``report`` and ``notebooks`` extras, scikit-image
with ``notebooks``).
"""

from __future__ import annotations

import importlib
from types import ModuleType

__all__ = [
    "VehicleDetectionError",
    "UsageError",
    "InputError",
    "ModelError",
    "OutputError",
    "DownloadError",
    "ClusterError",
    "MissingDependencyError",
    "one_line",
    "cli_message",
    "output_exists",
    "require",
]


class VehicleDetectionError(Exception):
    """Base class of the errors a user can cause; ``exit_code`` is the CLI's exit status.

    Parameters
    ----------
    *args
        As for :class:`Exception`: the message (the Python API's words, e.g. ``overwrite=True``).
    cli : str, optional
        The same message in the command line's words (its flags, e.g. ``--overwrite``), when
        they differ; the command line prints it (:func:`cli_message`).
    """

    exit_code = 3

    def __init__(self, *args, cli: str | None = None) -> None:
        super().__init__(*args)
        self.cli = cli


class UsageError(VehicleDetectionError, ValueError):
    """A command-line option has a value that cannot work (exit status 2, like argparse's errors).

    The message names the option and the problem.
    """

    exit_code = 2


class InputError(VehicleDetectionError, ValueError):
    """An input file or argument is missing, unreadable or of the wrong kind.

    The message names the file and the problem.
    """

    exit_code = 3


class ModelError(InputError):
    """A model file is malformed, tampered with, or does not match the running code."""

    exit_code = 4


class OutputError(VehicleDetectionError, OSError):
    """An output would overwrite an input or an existing file, or cannot be written."""

    exit_code = 5


class DownloadError(VehicleDetectionError, OSError):
    """A download failed, was cut short, or did not match its checksum."""

    exit_code = 6


class ClusterError(VehicleDetectionError, ConnectionError):
    """A dask scheduler cannot be reached, or it or a worker went away during the run (exit status 8).

    The message names the scheduler's (or the worker's) address; the inputs it left unfinished
    have no output (not even a hidden ``.partial`` file).
    """

    exit_code = 8


class MissingDependencyError(VehicleDetectionError, ImportError):
    """A feature needs an optional package that is not installed (exit status 2, like a usage error).

    The message names the feature, the package and the extra that installs it.
    """

    exit_code = 2


def one_line(exc: BaseException) -> str:
    """The message of ``exc`` on one line (ffmpeg and file names can bring line breaks)."""
    return " | ".join(part.strip() for part in str(exc).splitlines() if part.strip())


def cli_message(exc: BaseException) -> str:
    """The one-line message of ``exc`` as the command line says it: its ``cli`` form when it has one.

    >>> cli_message(output_exists("out.csv"))
    'out.csv: output exists; pass --overwrite to replace it'
    >>> str(output_exists("out.csv"))
    'out.csv: output exists; pass overwrite=True to replace it'
    """
    cli = getattr(exc, "cli", None)
    return one_line(cli if cli is not None else exc)


def output_exists(dest, what: str = "output exists", remedy: str = "to replace it") -> OutputError:
    """The error for an output that exists and may not be replaced, in the API's and the CLI's words.

    Parameters
    ----------
    dest : path-like
        The output.
    what : str
        What is there (``"report folder exists and is not empty"``).
    remedy : str
        What the flag would do (``"to replace its files"``).
    """
    return OutputError(f"{dest}: {what}; pass overwrite=True {remedy}", cli=f"{dest}: {what}; pass --overwrite {remedy}")


def require(module: str, extra: str, feature: str) -> ModuleType:
    """Import ``module``, or say which extra installs it.

    Parameters
    ----------
    module : str
        Module to import (``"matplotlib.figure"``).
    extra : str
        The extra of ``vehicle-detection`` that installs it (``"report"``).
    feature : str
        What needs it, for the message (``"the HTML report"``).

    Returns
    -------
    module

    Raises
    ------
    MissingDependencyError
        If the module (or one it needs) cannot be imported; also an ``ImportError``.

    Examples
    --------
    >>> require("json", "report", "this example").__name__
    'json'
    """
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        package = (exc.name or module).split(".")[0]
        raise MissingDependencyError(
            f"{feature} needs {package}, which is not installed: pip install \"vehicle-detection[{extra}]\""
        ) from None


def shorten(value, limit: int = 40) -> str:
    """``value`` as text for a one-line message: at most about ``limit`` characters, its start
    and end kept (a 400-digit number or a 10 MB CSV field must not fill the terminal).

    >>> shorten(10**50)
    '1000000000000000000000000...0000000000 (51 characters)'
    >>> shorten("9x6")
    '9x6'
    """
    text = str(value)
    if len(text) <= limit:
        return text
    return f"{text[: limit * 5 // 8]}...{text[-limit // 4:]} ({len(text)} characters)"
