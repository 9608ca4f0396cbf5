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

When the detections carry distances (``data["distance_m"]`` and ``data["relative_speed_mps"]``,
from ``detect --lanes``), two more columns follow the score, ``distance_m,relative_speed_mps`` (metres and
metres per second, 2 decimals; an empty field where unknown, read back as NaN). Without them the
file is exactly the 7-column format above; :func:`read_boxes_csv` accepts each form.

The lanes CSV (:func:`write_lanes_csv`) has the header ``frame,curvature_m,offset_m``, one row
per frame, empty fields where no lane was found.
"""

from __future__ import annotations

import csv
import io
import os
import re
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from ..detections import Detections
from ..errors import InputError, shorten
from ..geometry import MAX_COORD
from ._files import atomic_output, read_text

__all__ = [
    "BOXES_CSV_HEADER",
    "DISTANCE_COLUMNS",
    "FILES_CSV_HEADER",
    "LANES_CSV_HEADER",
    "write_boxes_csv",
    "read_boxes_csv",
    "write_lanes_csv",
    "read_lanes_csv",
]

BOXES_CSV_HEADER = "frame,x1,y1,x2,y2,track_id,score"
FILES_CSV_HEADER = BOXES_CSV_HEADER + ",file"
DISTANCE_COLUMNS = ("distance_m", "relative_speed_mps")
#: The largest magnitude a table's distance, speed, radius or offset may have (metres, metres a
#: second): a straight road's radius is written empty, not as 1e308, which no chart can scale to.
MAX_METRES = 1e9
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
    extended = all(c in detections.data for c in DISTANCE_COLUMNS)
    extra = [np.asarray(detections.data[c], dtype=np.float64) for c in DISTANCE_COLUMNS] if extended else []
    lines = [_header(extended, names is not None)]
    for i, (frame, x1, y1, x2, y2, track_id, score) in enumerate(detections.rows()):
        line = f"{frame},{x1},{y1},{x2},{y2},{track_id},{_format_score(score)}"
        line += "".join("," + (f"{col[i]:.2f}" if np.isfinite(col[i]) else "") for col in extra)
        lines.append(line if names is None else f"{line},{_quote(as_text_cell(names[i]))}")
    text = "\n".join(lines) + "\n"
    with atomic_output(path, overwrite=overwrite, inputs=inputs) as tmp:
        tmp.write_text(text, encoding="utf-8", newline="\n")
    return Path(path)


def _header(distances: bool, files: bool) -> str:
    return BOXES_CSV_HEADER + ("," + ",".join(DISTANCE_COLUMNS) if distances else "") + (",file" if files else "")


_HEADERS = {_header(d, f): (d, f) for d in (False, True) for f in (False, True)}


#: First characters that make a spreadsheet read a cell as a formula (the OWASP list), and the
#: apostrophe that marks a cell written as text.
_FORMULA_START = ("=", "+", "-", "@", "\t", "\r", "'")


def as_text_cell(text: str) -> str:
    """A text cell a spreadsheet shows as text: an apostrophe before a first character that
    would start a formula (``=``, ``+``, ``-``, ``@``, tab, carriage return) or before a first
    apostrophe; :func:`from_text_cell` takes it back off.

    >>> as_text_cell("=cmd|calc!A0.jpg"), from_text_cell(as_text_cell("=cmd|calc!A0.jpg"))
    ("'=cmd|calc!A0.jpg", '=cmd|calc!A0.jpg')
    >>> as_text_cell("test1.jpg")
    'test1.jpg'
    """
    return "'" + text if text.startswith(_FORMULA_START) else text


def from_text_cell(text: str) -> str:
    """The inverse of :func:`as_text_cell`."""
    return text[1:] if text.startswith("'") else text


def _quote(text: str) -> str:
    if any(c in text for c in ',"\r\n'):
        return '"' + text.replace('"', '""') + '"'
    return text


def _parse_extra(fields: list[str], lineno: int, path: Path) -> tuple[float, ...]:
    out = []
    for name, text in zip(DISTANCE_COLUMNS, fields):
        if text == "":
            out.append(float("nan"))
        elif _FLOAT.fullmatch(text) and abs(float(text)) <= MAX_METRES:
            out.append(float(text))
        elif _FLOAT.fullmatch(text):
            raise InputError(f"{path}: line {lineno}: {name} {shorten(text)} is beyond {MAX_METRES:g} in magnitude")
        else:
            raise InputError(f"{path}: line {lineno}: {name} {shorten(repr(text))} is not a number (leave it empty when unknown)")
    return tuple(out)


def _parse_line(fields: list[str], lineno: int, path: Path, header: str) -> tuple[int, int, int, int, int, int, float]:
    n_fields = header.count(",") + 1
    if len(fields) != n_fields:
        raise InputError(f"{path}: line {lineno}: expected {n_fields} fields ({header}), got {len(fields)}")
    fields = fields[: len(_COLUMNS)]
    ints = []
    for name, text in zip(_COLUMNS[:6], fields[:6]):
        if not _INT.fullmatch(text):
            raise InputError(f"{path}: line {lineno}: {name} {shorten(repr(text))} is not an integer")
        value = int(text) if len(text) <= 20 else MAX_COORD + 1  # no conversion of a 10 MB number
        if abs(value) > MAX_COORD:
            raise InputError(f"{path}: line {lineno}: {name} {shorten(text)} is out of range")
        ints.append(value)
    score_text = fields[6]
    score = float(score_text) if _FLOAT.fullmatch(score_text) else float("nan")
    if not np.isfinite(score):
        raise InputError(f"{path}: line {lineno}: score {shorten(repr(score_text))} is not a finite number")
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
    header = lines[0]
    if header not in _HEADERS:
        raise InputError(
            f"{path}: line 1: header is {shorten(repr(header))}; expected {BOXES_CSV_HEADER!r} "
            f"(optionally followed by ,{','.join(DISTANCE_COLUMNS)} and/or ,file)"
        )
    distances, files = _HEADERS[header]
    if files:  # file names may be quoted (RFC 4180), line breaks included

        reader = csv.reader(io.StringIO("\n".join(lines[1:]), newline=""))
        records = [(reader.line_num + 1, fields) for fields in reader]  # line of the record's end
    else:
        records = list(enumerate((line.split(",") for line in lines[1:]), start=2))
    rows, extra, names = [], [], []
    for lineno, fields in records:
        if not fields or (len(fields) == 1 and not fields[0].strip()):
            raise InputError(f"{path}: line {lineno}: blank line inside the data")
        rows.append(_parse_line(fields, lineno, path, header))
        if distances:
            extra.append(_parse_extra(fields[len(_COLUMNS) : len(_COLUMNS) + len(DISTANCE_COLUMNS)], lineno, path))
        if files:
            names.append(from_text_cell(fields[-1]))
    table = Detections.from_rows(rows)
    if not rows:
        return table
    data = {}
    if distances:
        cols = np.array(extra, dtype=np.float64).reshape(-1, len(DISTANCE_COLUMNS))
        data.update({name: cols[:, i] for i, name in enumerate(DISTANCE_COLUMNS)})
    if files:
        data["file"] = np.array(names, dtype=str)
    return table.replace(data=data) if data else table


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


def read_lanes_csv(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Read a lanes CSV (:func:`write_lanes_csv`), with validation.

    Parameters
    ----------
    path : path-like
        CSV with the header ``frame,curvature_m,offset_m`` and one row per frame (a UTF-8
        byte-order mark and CRLF line ends are accepted; blank lines only at the end).

    Returns
    -------
    dict of str to ndarray, shape (n,)
        ``"frame"`` (int64, >= 0, increasing), ``"curvature_m"`` (the radius of curvature in
        metres) and ``"offset_m"`` (metres right of the lane centre), float64, NaN where the
        field is empty (no lane found).

    Raises
    ------
    InputError
        If the file is missing or unreadable, the header differs, or a line is malformed or out
        of order; the message names the file and the 1-based line number.
    """
    path = Path(path)
    lines = read_text(path, "lanes file", "CSV", encoding="utf-8-sig").split("\n")
    while lines and not lines[-1].strip():
        lines.pop()
    if not lines or lines[0] != LANES_CSV_HEADER:
        got = repr(lines[0]) if lines else "an empty file"
        raise InputError(f"{path}: line 1: header is {shorten(got)}; expected {LANES_CSV_HEADER!r}")
    frames, values = [], []
    for lineno, line in enumerate(lines[1:], start=2):
        fields = line.split(",")
        if len(fields) != 3:
            raise InputError(f"{path}: line {lineno}: expected 3 fields ({LANES_CSV_HEADER}), got {len(fields)}")
        if not _INT.fullmatch(fields[0]) or int(fields[0]) < 0:
            raise InputError(f"{path}: line {lineno}: frame {shorten(repr(fields[0]))} is not an integer >= 0")
        frame = int(fields[0])
        if frames and frame <= frames[-1]:
            raise InputError(f"{path}: line {lineno}: frame {frame} does not follow frame {frames[-1]}")
        row = []
        for name, text in zip(("curvature_m", "offset_m"), fields[1:]):
            value = float("nan") if text == "" else float(text) if _FLOAT.fullmatch(text) else None
            if value is None or np.isinf(value):
                raise InputError(f"{path}: line {lineno}: {name} {shorten(repr(text))} is not a number (leave it empty when unknown)")
            if abs(value) > MAX_METRES:
                raise InputError(f"{path}: line {lineno}: {name} {shorten(text)} is beyond {MAX_METRES:g} in magnitude")
            row.append(value)
        frames.append(frame)
        values.append(row)
    cols = np.array(values, np.float64).reshape(-1, 2)
    return {"frame": np.array(frames, np.int64), "curvature_m": cols[:, 0], "offset_m": cols[:, 1]}
