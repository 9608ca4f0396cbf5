"""Per-frame detection boxes: a CSV file format, and drawing boxes on frames.

The CSV has the header ``frame,x1,y1,x2,y2,track_id,score`` and one row per box:

* ``frame``: 0-based decoded frame index (integer >= 0);
* ``x1, y1, x2, y2``: the box in whole pixels, ``x2 > x1`` and ``y2 > y1``, x2/y2 exclusive;
* ``track_id``: integer >= 0, or -1 when the box is not tracked;
* ``score``: a finite float, written with 4 decimals.

Frames without detections have no rows. In memory a file is a :class:`BoxTable` (parallel
columns), or, for scoring, a ``dict`` mapping frame index to an ``(k, 4)`` box array
(:func:`read_boxes_csv`), as :func:`vehicle_detection.evaluate.evaluate_detections` takes.
"""

from __future__ import annotations

import os
import re
from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike

from ._files import atomic_output, read_text
from .errors import InputError
from .evaluate import _as_boxes

__all__ = [
    "BOXES_CSV_HEADER",
    "BoxTable",
    "write_boxes_csv",
    "read_boxes_csv",
    "read_boxes_table",
    "draw_boxes",
]

BOXES_CSV_HEADER = "frame,x1,y1,x2,y2,track_id,score"
_COLUMNS = tuple(BOXES_CSV_HEADER.split(","))
_INT = re.compile(r"-?[0-9]+", re.ASCII)
_FLOAT = re.compile(r"[-+]?(?:[0-9]+(?:\.[0-9]*)?|\.[0-9]+)(?:[eE][-+]?[0-9]+)?", re.ASCII)
# Coordinates and ids must fit cv2's and most writers' 32-bit ints.
_MAX_INT = 2**31 - 1

#: One box row: ``(frame, box (4,), track_id, score)``.
BoxRow = tuple[int, ArrayLike, int, float]


def _readonly(arr: np.ndarray) -> np.ndarray:
    arr = np.array(arr, copy=True)
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class BoxTable:
    """Detection boxes of a video as parallel columns, one entry per box.

    Parameters
    ----------
    frame : array_like of int, shape (n,)
        0-based decoded frame index of each box, >= 0.
    boxes : array_like of int, shape (n, 4)
        ``[x1, y1, x2, y2]`` in whole pixels with ``x2 > x1`` and ``y2 > y1`` (exclusive ends).
    track_id : array_like of int, shape (n,)
        Track of each box, >= 0, or -1 when untracked.
    score : array_like of float, shape (n,)
        Finite detection score of each box.

    All columns are stored as read-only arrays: ``int64`` except ``score`` (``float64``).
    Equality is identity.

    Raises
    ------
    ValueError
        If the columns have mismatched lengths or break the rules above; the message gives the
        index of the first offending row.
    """

    frame: np.ndarray
    boxes: np.ndarray
    track_id: np.ndarray
    score: np.ndarray

    def __post_init__(self) -> None:
        frame = _int_column(self.frame, "frame")
        track_id = _int_column(self.track_id, "track_id")
        score = np.asarray(self.score)
        if score.size == 0:
            score = score.reshape(0)
        if score.ndim != 1 or score.dtype == bool or not np.issubdtype(score.dtype, np.number):
            raise ValueError(f"score must be a 1-D array of numbers; got shape {score.shape}, dtype {score.dtype}")
        score = score.astype(np.float64)
        boxes = _as_boxes(self.boxes, "boxes", integer=True)
        n = len(frame)
        if not len(boxes) == len(track_id) == len(score) == n:
            raise ValueError(
                f"columns differ in length: frame {n}, boxes {len(boxes)}, "
                f"track_id {len(track_id)}, score {len(score)}"
            )
        checks = [
            (frame < 0, "frame must be >= 0"),
            ((boxes[:, 2] <= boxes[:, 0]) | (boxes[:, 3] <= boxes[:, 1]), "box needs x2 > x1 and y2 > y1"),
            (np.abs(boxes).max(axis=1, initial=0) > _MAX_INT, f"box coordinates must be within +-{_MAX_INT}"),
            (track_id < -1, "track_id must be >= 0, or -1 when untracked"),
            (~np.isfinite(score), "score must be finite"),
        ]
        for bad, problem in checks:
            if bad.any():
                i = int(np.flatnonzero(bad)[0])
                raise ValueError(
                    f"row {i} (frame {frame[i]}, box {boxes[i].tolist()}, track_id {track_id[i]}, "
                    f"score {score[i]}): {problem}"
                )
        for name, arr in (("frame", frame), ("boxes", boxes), ("track_id", track_id), ("score", score)):
            object.__setattr__(self, name, _readonly(arr))

    def __len__(self) -> int:
        return len(self.frame)

    @classmethod
    def empty(cls) -> BoxTable:
        """A table with no boxes."""
        return cls(frame=[], boxes=[], track_id=[], score=[])

    @classmethod
    def from_rows(cls, rows: Iterable[BoxRow]) -> BoxTable:
        """Build a table from ``(frame, box, track_id, score)`` tuples.

        Parameters
        ----------
        rows : iterable of tuple
            ``frame`` int, ``box`` array_like of 4 whole numbers, ``track_id`` int (-1 when
            untracked), ``score`` float.

        Raises
        ------
        ValueError
            If a row is not a 4-tuple of that form (the message gives its index).
        """
        frames, boxes, track_ids, scores = [], [], [], []
        for i, row in enumerate(rows):
            try:
                frame, box, track_id, score = row
            except (TypeError, ValueError):
                raise ValueError(f"row {i}: expected (frame, box, track_id, score); got {row!r}") from None
            box = np.asarray(box)
            if box.shape != (4,):
                raise ValueError(f"row {i}: box must have 4 coordinates [x1, y1, x2, y2]; got {box.tolist()!r}")
            for name, value in (("frame", frame), ("track_id", track_id)):
                if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
                    raise ValueError(f"row {i}: {name} must be an integer; got {value!r}")
            if isinstance(score, (bool, np.bool_)) or not isinstance(score, (int, float, np.integer, np.floating)):
                raise ValueError(f"row {i}: score must be a number; got {score!r}")
            frames.append(int(frame))
            boxes.append(box)
            track_ids.append(int(track_id))
            scores.append(float(score))
        if not frames:
            return cls.empty()
        try:
            box_arr = np.stack(boxes)
        except (TypeError, ValueError) as exc:  # mixed object boxes
            raise ValueError(f"boxes are not numeric: {exc}") from None
        return cls(frame=frames, boxes=box_arr, track_id=track_ids, score=scores)

    def rows(self) -> Iterator[tuple[int, np.ndarray, int, float]]:
        """Yield ``(frame, box, track_id, score)`` per box, ``box`` an ``int64`` array (4,)."""
        for i in range(len(self)):
            yield int(self.frame[i]), self.boxes[i], int(self.track_id[i]), float(self.score[i])

    def split_by_frame(self) -> dict[int, BoxTable]:
        """Sub-tables by frame index, in increasing frame order, rows in table order."""
        order = np.argsort(self.frame, kind="stable")
        frames, starts = np.unique(self.frame[order], return_index=True)
        groups = np.split(order, starts[1:])
        return {
            int(f): BoxTable(
                frame=self.frame[idx], boxes=self.boxes[idx], track_id=self.track_id[idx], score=self.score[idx]
            )
            for f, idx in zip(frames, groups)
        }

    def by_frame(self) -> dict[int, np.ndarray]:
        """Boxes by frame index: ``{frame: int64 array (k, 4)}``, frames in increasing order.

        Frames without boxes are absent.
        """
        return {f: t.boxes for f, t in self.split_by_frame().items()}


def _int_column(values: ArrayLike, name: str) -> np.ndarray:
    arr = np.asarray(values)
    if arr.size == 0:
        arr = arr.reshape(0)
    if arr.ndim != 1:
        raise ValueError(f"{name} must be 1-D; got shape {arr.shape}")
    if arr.dtype == bool or not np.issubdtype(arr.dtype, np.number):
        raise ValueError(f"{name} must hold integers; got dtype {arr.dtype}")
    if not np.issubdtype(arr.dtype, np.integer):
        if not np.all(np.isfinite(arr)) or np.any(arr != np.round(arr)):
            raise ValueError(f"{name} must hold whole numbers")
    return arr.astype(np.int64)


def _format_score(score: float) -> str:
    text = f"{score:.4f}"
    return "0.0000" if text == "-0.0000" else text


def write_boxes_csv(
    path: str | os.PathLike,
    rows: BoxTable | Iterable[BoxRow],
    *,
    overwrite: bool = False,
    inputs: Iterable[str | os.PathLike] = (),
) -> Path:
    """Write detection boxes to a CSV file, atomically.

    Parameters
    ----------
    path : path-like
        Output CSV file; missing parent folders are created.
    rows : BoxTable or iterable of (frame, box, track_id, score)
        The boxes, written in the order given (see :meth:`BoxTable.from_rows` for the tuple form).
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
    ValueError
        If a row is malformed (checked before anything is written).
    OutputError
        If ``path`` exists (without ``overwrite``), is an input or a folder, or cannot be written.
        Nothing is left under ``path`` on failure.
    """
    table = rows if isinstance(rows, BoxTable) else BoxTable.from_rows(rows)
    lines = [BOXES_CSV_HEADER]
    for frame, (x1, y1, x2, y2), track_id, score in table.rows():
        lines.append(f"{frame},{x1},{y1},{x2},{y2},{track_id},{_format_score(score)}")
    text = "\n".join(lines) + "\n"
    with atomic_output(path, overwrite=overwrite, inputs=inputs) as tmp:
        tmp.write_text(text, encoding="utf-8", newline="\n")
    return Path(path)


def _parse_line(line: str, lineno: int, path: Path) -> tuple[int, list[int], int, float]:
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
        if abs(value) > _MAX_INT:
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
    return frame, [x1, y1, x2, y2], track_id, score


def read_boxes_table(path: str | os.PathLike) -> BoxTable:
    """Read a detection-box CSV file into a :class:`BoxTable`, with validation.

    Parameters
    ----------
    path : path-like
        CSV with the header ``frame,x1,y1,x2,y2,track_id,score`` exactly (a UTF-8 byte-order
        mark and CRLF line ends are accepted). Blank lines are allowed only at the end.

    Returns
    -------
    BoxTable
        The rows in file order.

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
    if lines[0] != BOXES_CSV_HEADER:
        raise InputError(f"{path}: line 1: header is {lines[0]!r}; expected {BOXES_CSV_HEADER!r}")
    rows = []
    for lineno, line in enumerate(lines[1:], start=2):
        if not line.strip():
            raise InputError(f"{path}: line {lineno}: blank line inside the data")
        rows.append(_parse_line(line, lineno, path))
    if not rows:
        return BoxTable.empty()
    frame, boxes, track_id, score = zip(*rows)
    return BoxTable(frame=list(frame), boxes=list(boxes), track_id=list(track_id), score=list(score))


def read_boxes_csv(path: str | os.PathLike) -> dict[int, np.ndarray]:
    """Read a detection-box CSV file as boxes by frame.

    Parameters
    ----------
    path : path-like
        As for :func:`read_boxes_table`.

    Returns
    -------
    dict of int to ndarray of int64, shape (k, 4)
        Boxes by 0-based frame index, frames in increasing order; frames without boxes are absent.
        Use :func:`read_boxes_table` for the track ids and scores.

    Raises
    ------
    InputError
        As for :func:`read_boxes_table`.
    """
    return read_boxes_table(path).by_frame()


# --------------------------------------------------------------------------------------------
# Drawing
# --------------------------------------------------------------------------------------------
def _check_color(color: Any) -> tuple[int, int, int]:
    try:
        values = [int(c) for c in color]
    except (TypeError, ValueError):
        raise ValueError(f"color must be 3 integers in 0..255; got {color!r}") from None
    if len(values) != 3 or any(not 0 <= c <= 255 for c in values) or any(int(c) != c for c in color):
        raise ValueError(f"color must be 3 integers in 0..255; got {color!r}")
    return values[0], values[1], values[2]


def draw_boxes(
    image: np.ndarray,
    boxes: ArrayLike,
    *,
    color: Sequence[int] = (0, 255, 0),
    thickness: int = 3,
    labels: Sequence[str | int] | None = None,
) -> np.ndarray:
    """Draw rectangles, optionally labelled, on a copy of an image.

    Parameters
    ----------
    image : ndarray of uint8, shape (H, W, 3)
        RGB image; it is not modified.
    boxes : array_like, shape (n, 4)
        ``[x1, y1, x2, y2]`` (x2, y2 exclusive); float coordinates are rounded to whole pixels.
        The rectangle's outer edge covers exactly the box's pixels; parts outside the image are
        clipped.
    color : sequence of 3 int, default (0, 255, 0)
        Line colour in the image's channel order (RGB: green by default).
    thickness : int, default 3
        Line width in pixels, >= 1; the lines lie inside the box, growing inward from its edge.
    labels : sequence of str or int, optional
        One label per box (e.g. track ids), written on a filled tag of ``color`` above the box's
        top-left corner (inside the box when there is no room above).

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
        A new C-contiguous array.

    Raises
    ------
    ValueError
        If the image is not ``uint8`` of shape ``(H, W, 3)``, the boxes are malformed, ``labels``
        does not have one entry per box, or ``color``/``thickness`` are invalid.
    """
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"image must be uint8 of shape (H, W, 3); got {image.dtype} of shape {image.shape}")
    col = _check_color(color)
    if isinstance(thickness, bool) or not isinstance(thickness, (int, np.integer)) or thickness < 1:
        raise ValueError(f"thickness must be an integer >= 1; got {thickness!r}")
    thickness = int(thickness)
    box_arr = np.rint(_as_boxes(boxes, "boxes"))
    if labels is not None:
        labels = [str(label) for label in labels]
        if len(labels) != len(box_arr):
            raise ValueError(f"labels has {len(labels)} entries for {len(box_arr)} boxes")

    out = np.array(image, dtype=np.uint8, order="C", copy=True)
    h, w = out.shape[:2]
    # Keep coordinates within cv2's int range but well outside the image, so clipping is invisible.
    margin = 2 * thickness + 2
    lo = np.array([-margin, -margin, -margin, -margin])
    hi = np.array([w + margin, h + margin, w + margin, h + margin])
    box_int = np.clip(box_arr, lo, hi).astype(np.int64)

    font = cv2.FONT_HERSHEY_SIMPLEX
    font_scale = 0.6
    text_thickness = max(1, thickness // 2)
    # Black text on light colours, white on dark (Rec. 601 luma).
    text_color = (0, 0, 0) if 0.299 * col[0] + 0.587 * col[1] + 0.114 * col[2] > 127 else (255, 255, 255)
    for i, (x1, y1, x2, y2) in enumerate(box_int.tolist()):
        # cv2's thick lines are centred on their path and wider than asked; four filled bands
        # give edges exactly `thickness` pixels wide, inside the box [x1, x2 - 1] x [y1, y2 - 1].
        xr, yb = max(x2 - 1, x1), max(y2 - 1, y1)
        tx, ty = min(thickness, xr - x1 + 1), min(thickness, yb - y1 + 1)
        for p1, p2 in (
            ((x1, y1), (xr, y1 + ty - 1)),  # top
            ((x1, yb - ty + 1), (xr, yb)),  # bottom
            ((x1, y1), (x1 + tx - 1, yb)),  # left
            ((xr - tx + 1, y1), (xr, yb)),  # right
        ):
            cv2.rectangle(out, p1, p2, col, cv2.FILLED)
        if labels is None or not labels[i]:
            continue
        (tw, th), baseline = cv2.getTextSize(labels[i], font, font_scale, text_thickness)
        tag_h = th + baseline + 4
        top = y1 - tag_h if y1 - tag_h >= 0 else y1
        cv2.rectangle(out, (x1, top), (x1 + tw + 4, top + tag_h - 1), col, cv2.FILLED)
        origin = (x1 + 2, top + 2 + th)  # bottom-left of the text
        cv2.putText(out, labels[i], origin, font, font_scale, text_color, text_thickness, cv2.LINE_AA)
    return out
