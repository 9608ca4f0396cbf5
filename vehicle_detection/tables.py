"""Detection tables on disk: the boxes CSV.

The CSV has the header ``frame,x1,y1,x2,y2,track_id,score`` and one row per box:

* ``frame``: 0-based decoded frame index (integer >= 0);
* ``x1, y1, x2, y2``: the box in whole pixels, ``x2 > x1`` and ``y2 > y1``, x2/y2 exclusive;
* ``track_id``: integer >= 0, or -1 when the box is not tracked;
* ``score``: a finite float, written with 4 decimals.

Frames without detections have no rows. In memory a file is a
:class:`~vehicle_detection.detections.Detections`.

When the detections carry distances (``data["distance_m"]`` and ``data["relative_speed_mps"]``,
from ``detect --lanes``), two more columns follow, ``distance_m,relative_speed_mps`` (metres and
metres per second, 2 decimals; an empty field where unknown, read back as NaN). Without them the
file is exactly the 7-column format above; :func:`read_boxes_csv` accepts both.

The lanes CSV (:func:`write_lanes_csv`) has the header ``frame,curvature_m,offset_m``, one row
per frame, empty fields where no lane was found.
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

__all__ = ["BOXES_CSV_HEADER", "DISTANCE_COLUMNS", "LANES_CSV_HEADER", "write_boxes_csv", "read_boxes_csv", "write_lanes_csv"]

BOXES_CSV_HEADER = "frame,x1,y1,x2,y2,track_id,score"
DISTANCE_COLUMNS = ("distance_m", "relative_speed_mps")
_EXTENDED_HEADER = BOXES_CSV_HEADER + "," + ",".join(DISTANCE_COLUMNS)
LANES_CSV_HEADER = "frame,curvature_m,offset_m"
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
    extended = all(c in detections.data for c in DISTANCE_COLUMNS)
    lines = [_EXTENDED_HEADER if extended else BOXES_CSV_HEADER]
    extra = [np.asarray(detections.data[c], dtype=np.float64) for c in DISTANCE_COLUMNS] if extended else None
    for i, (frame, x1, y1, x2, y2, track_id, score) in enumerate(detections.rows()):
        line = f"{frame},{x1},{y1},{x2},{y2},{track_id},{_format_score(score)}"
        if extra is not None:
            line += "".join("," + (f"{col[i]:.2f}" if np.isfinite(col[i]) else "") for col in extra)
        lines.append(line)
    text = "\n".join(lines) + "\n"
    with atomic_output(path, overwrite=overwrite, inputs=inputs) as tmp:
        tmp.write_text(text, encoding="utf-8", newline="\n")
    return Path(path)


def _parse_extra(fields: list[str], lineno: int, path: Path) -> tuple[float, ...]:
    out = []
    for name, text in zip(DISTANCE_COLUMNS, fields):
        if text == "":
            out.append(float("nan"))
        elif _FLOAT.fullmatch(text):
            out.append(float(text))
        else:
            raise InputError(f"{path}: line {lineno}: {name} {text!r} is not a number (leave it empty when unknown)")
    return tuple(out)


def _parse_line(line: str, lineno: int, path: Path, header: str = BOXES_CSV_HEADER) -> tuple[int, int, int, int, int, int, float]:
    fields = line.split(",")
    n_fields = header.count(",") + 1
    if len(fields) != n_fields:
        raise InputError(
            f"{path}: line {lineno}: expected {n_fields} fields ({header}), got {len(fields)}"
        )
    fields = fields[: len(_COLUMNS)]
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
        CSV with the header ``frame,x1,y1,x2,y2,track_id,score`` exactly, or that header followed
        by ``,distance_m,relative_speed_mps`` (a UTF-8 byte-order mark and CRLF line ends are
        accepted). Blank lines are allowed only at the end.

    Returns
    -------
    Detections
        The rows in file order; untracked (``track_id`` None) when every row's id is -1. With
        the distance columns, ``data`` holds them (float64, NaN for empty fields).

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
    if lines[0] not in (BOXES_CSV_HEADER, _EXTENDED_HEADER):
        raise InputError(f"{path}: line 1: header is {lines[0]!r}; expected {BOXES_CSV_HEADER!r} (optionally followed by ,{','.join(DISTANCE_COLUMNS)})")
    header = lines[0]
    rows, extra = [], []
    for lineno, line in enumerate(lines[1:], start=2):
        if not line.strip():
            raise InputError(f"{path}: line {lineno}: blank line inside the data")
        rows.append(_parse_line(line, lineno, path, header))
        if header != BOXES_CSV_HEADER:
            extra.append(_parse_extra(line.split(",")[len(_COLUMNS) :], lineno, path))
    table = Detections.from_rows(rows)
    if header != BOXES_CSV_HEADER:
        cols = np.array(extra, dtype=np.float64).reshape(-1, len(DISTANCE_COLUMNS))
        table = table.replace(data={name: cols[:, i] for i, name in enumerate(DISTANCE_COLUMNS)})
    return table


def write_lanes_csv(
    path: str | os.PathLike,
    rows: Iterable[tuple[int, float, float]],
    *,
    overwrite: bool = False,
    inputs: Iterable[str | os.PathLike] = (),
) -> Path:
    """Write ``frame,curvature_m,offset_m`` rows atomically (NaN or None: an empty field)."""

    def fmt(v, digits):
        return f"{v:.{digits}f}" if v is not None and np.isfinite(v) else ""

    lines = [LANES_CSV_HEADER] + [f"{int(f)},{fmt(c, 1)},{fmt(o, 3)}" for f, c, o in rows]
    with atomic_output(path, overwrite=overwrite, inputs=inputs) as tmp:
        tmp.write_text("\n".join(lines) + "\n", encoding="utf-8", newline="\n")
    return Path(path)
