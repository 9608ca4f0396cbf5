"""Detection tables on disk: the boxes CSV.

The CSV has the header ``frame,x1,y1,x2,y2,track_id,score`` and one row per box:

* ``frame``: 0-based decoded frame index (integer >= 0);
* ``x1, y1, x2, y2``: the box in whole pixels, ``x2 > x1`` and ``y2 > y1``, x2/y2 exclusive;
* ``track_id``: integer >= 0, or -1 when the box is not tracked;
* ``score``: a finite float, written with 4 decimals.

Frames without detections have no rows. In memory a file is a
:class:`~vehicle_detection.detections.Detections`.

The CSV of a folder of images has one more column, ``file``: the image's file name (quoted as
in RFC 4180 when it holds a comma, a quote or a line break), and ``frame`` is the image's
position in sorted order (``frame,x1,y1,x2,y2,track_id,score,file``). The CSV of a video or of
one image has no ``file`` column. :func:`read_boxes_csv` reads both; the names land in
``data["file"]``.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from ._files import atomic_output, read_text
from .detections import Detections
from .errors import InputError
from .geometry import MAX_COORD

__all__ = ["BOXES_CSV_HEADER", "FILES_CSV_HEADER", "write_boxes_csv", "read_boxes_csv"]

BOXES_CSV_HEADER = "frame,x1,y1,x2,y2,track_id,score"
FILES_CSV_HEADER = BOXES_CSV_HEADER + ",file"
_COLUMNS = tuple(BOXES_CSV_HEADER.split(","))
_INT = re.compile(r"-?[0-9]+", re.ASCII)
_FLOAT = re.compile(r"[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][-+]?[0-9]+)?", re.ASCII)


def _format_score(score: float) -> str:
    text = f"{score:.4f}"
    return "0.0000" if text == "-0.0000" else text


def write_boxes_csv(
    path: str | os.PathLike,
    detections: Detections,
    *,
    overwrite: bool = False,
    inputs: Iterable[str | os.PathLike] = (),
    files: Iterable[str] | None = None,
) -> Path:
    """Write detection boxes to a CSV file, atomically.

    Parameters
    ----------
    path : path-like
        Output CSV file; missing parent folders are created.
    detections : Detections
        The boxes, written in their order (``track_id`` -1 for every row when untracked).
    overwrite : bool, default False
        Replace an existing file at ``path``.
    inputs : iterable of path-like
        Files the run reads; ``path`` may never be one of them.
    files : iterable of str, optional
        One file name per row (images of a folder): adds the ``file`` column.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    OutputError
        If ``path`` exists (without ``overwrite``), is an input or a folder, or cannot be written.
        Nothing is left under ``path`` on failure.
    """
    names = None if files is None else [str(f) for f in files]
    if names is not None and len(names) != len(detections):
        raise ValueError(f"files: one name per row ({len(detections)}), got {len(names)}")
    lines = [BOXES_CSV_HEADER if names is None else FILES_CSV_HEADER]
    for i, (frame, x1, y1, x2, y2, track_id, score) in enumerate(detections.rows()):
        row = f"{frame},{x1},{y1},{x2},{y2},{track_id},{_format_score(score)}"
        lines.append(row if names is None else f"{row},{_quote(names[i])}")
    text = "\n".join(lines) + "\n"
    with atomic_output(path, overwrite=overwrite, inputs=inputs) as tmp:
        tmp.write_text(text, encoding="utf-8", newline="\n")
    return Path(path)


def _quote(text: str) -> str:
    if any(c in text for c in ',"\r\n'):
        return '"' + text.replace('"', '""') + '"'
    return text


def _parse_line(line: str, lineno: int, path: Path) -> tuple[int, int, int, int, int, int, float]:
    fields = line.split(",")
    if len(fields) != len(_COLUMNS):
        raise InputError(
            f"{path}: line {lineno}: expected {len(_COLUMNS)} fields ({BOXES_CSV_HEADER}), got {len(fields)}"
        )
    ints = []
    for name, text in zip(_COLUMNS[:6], fields[:6]):
        if not _INT.fullmatch(text):
            raise InputError(f"{path}: line {lineno}: {name} {text!r} is not an integer")
        value = int(text)
        if abs(value) > MAX_COORD:
            raise InputError(f"{path}: line {lineno}: {name} {text} is out of range")
        ints.append(value)
    score_text = fields[6]
    score = float(score_text) if _FLOAT.fullmatch(score_text) else float("nan")
    if not np.isfinite(score):
        raise InputError(f"{path}: line {lineno}: score {score_text!r} is not a finite number")
    frame, x1, y1, x2, y2, track_id = ints
    problem = None
    if frame < 0:
        problem = f"frame {frame} is negative"
    elif x2 <= x1:
        problem = f"x2 ({x2}) <= x1 ({x1}); boxes need x2 > x1 (x2 is exclusive)"
    elif y2 <= y1:
        problem = f"y2 ({y2}) <= y1 ({y1}); boxes need y2 > y1 (y2 is exclusive)"
    elif track_id < -1:
        problem = f"track_id {track_id} is below -1 (-1 means untracked)"
    if problem:
        raise InputError(f"{path}: line {lineno}: {problem}")
    return frame, x1, y1, x2, y2, track_id, score


def read_boxes_csv(path: str | os.PathLike) -> Detections:
    """Read a boxes CSV file, with validation.

    Parameters
    ----------
    path : path-like
        CSV with the header ``frame,x1,y1,x2,y2,track_id,score`` exactly (a UTF-8 byte-order
        mark and CRLF line ends are accepted). Blank lines are allowed only at the end.

    Returns
    -------
    Detections
        The rows in file order; untracked (``track_id`` None) when every row's id is -1.

    Raises
    ------
    InputError
        If the file is missing or unreadable, the header differs, or a line has the wrong number
        of fields, a malformed number, or an invalid box; the message names the file and the
        1-based line number (the header is line 1).
    """
    path = Path(path)
    lines = read_text(path, "boxes file", "CSV", encoding="utf-8-sig").split("\n")

    while lines and not lines[-1].strip():
        lines.pop()
    if not lines:
        raise InputError(f"{path}: line 1: empty file; expected the header {BOXES_CSV_HEADER}")
    if lines[0] == FILES_CSV_HEADER:
        return _read_files_csv(path, lines)
    if lines[0] != BOXES_CSV_HEADER:
        raise InputError(f"{path}: line 1: header is {lines[0]!r}; expected {BOXES_CSV_HEADER!r}")
    rows = []
    for lineno, line in enumerate(lines[1:], start=2):
        if not line.strip():
            raise InputError(f"{path}: line {lineno}: blank line inside the data")
        rows.append(_parse_line(line, lineno, path))
    return Detections.from_rows(rows)


def _read_files_csv(path: Path, lines: list[str]) -> Detections:
    """The CSV of a folder of images: the last column names each row's image file."""
    import csv

    rows, names = [], []
    for lineno, fields in enumerate(csv.reader(lines[1:]), start=2):
        if not fields:
            raise InputError(f"{path}: line {lineno}: blank line inside the data")
        if len(fields) != len(_COLUMNS) + 1:
            raise InputError(f"{path}: line {lineno}: expected {len(_COLUMNS) + 1} fields ({FILES_CSV_HEADER}), got {len(fields)}")
        rows.append(_parse_line(",".join(fields[:-1]), lineno, path))
        names.append(fields[-1])
    table = Detections.from_rows(rows)
    return table.replace(data={"file": np.array(names, dtype=str)}) if rows else table
