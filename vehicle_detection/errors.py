"""Exceptions raised for bad input, bad files and refused outputs.

Every error that a user can cause derives from :class:`VehicleDetectionError`; the command-line
interface prints such an error as one line on stderr and exits with the code in ``exit_code``.
Anything else that escapes is a bug.
"""

from __future__ import annotations

__all__ = [
    "VehicleDetectionError",
    "UsageError",
    "InputError",
    "ModelError",
    "OutputError",
    "DownloadError",
    "one_line",
]


class VehicleDetectionError(Exception):
    """Base class of the errors a user can cause; ``exit_code`` is the CLI's exit status."""

    exit_code = 3


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


def one_line(exc: BaseException) -> str:
    """The message of ``exc`` on one line (ffmpeg and file names can bring line breaks)."""
    return " | ".join(part.strip() for part in str(exc).splitlines() if part.strip())
