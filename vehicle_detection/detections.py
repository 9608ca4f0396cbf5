"""The one result type: boxes with scores, track ids and frame indexes.

:class:`Detections` is what every stage hands to the next: the sliding-window search returns the
windows it scored as vehicles, the heat map and the tracker turn them into one box per vehicle,
and the boxes CSV, the drawing code and the evaluation take it as it is. A table of a whole video
is one :class:`Detections` whose ``frame`` column says which frame each box belongs to.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from .errors import require
from .geometry import MAX_COORD, as_boxes, box_area

__all__ = ["Detections", "to_supervision", "from_supervision", "score_to_confidence"]


def _readonly(arr: np.ndarray) -> np.ndarray:
    if arr.flags.writeable or not arr.flags.c_contiguous:
        arr = np.array(arr, order="C", copy=True)
        arr.setflags(write=False)
    return arr


def _column(values: Any, n: int, name: str, dtype, *, integer: bool) -> np.ndarray:
    arr = np.asarray(values)
    if arr.ndim == 0:  # one value for every box
        arr = np.full(n, arr)
    if arr.size == 0:
        arr = arr.reshape(0)
    if arr.ndim != 1 or len(arr) != n:
        raise ValueError(f"{name} must have one value per box ({n}); got shape {arr.shape}")
    if arr.dtype == bool or not np.issubdtype(arr.dtype, np.number):
        raise ValueError(f"{name} must hold numbers; got dtype {arr.dtype}")
    if integer and not np.issubdtype(arr.dtype, np.integer):
        if not np.all(np.isfinite(arr)) or np.any(arr != np.round(arr)):
            raise ValueError(f"{name} must hold whole numbers")
    if integer and n and np.abs(arr).max() > MAX_COORD:
        raise ValueError(f"{name} holds values beyond {MAX_COORD}")
    return arr.astype(dtype, copy=False)


@dataclass(frozen=True, eq=False)
class Detections:
    """Vehicle boxes, one row per box, as read-only parallel columns.

    Parameters
    ----------
    xyxy : array_like of int, shape (n, 4)
        ``[x1, y1, x2, y2]`` in whole pixels, ``x2 > x1`` and ``y2 > y1`` (x2, y2 exclusive).
    score : array_like of float, shape (n,), optional
        Finite score of each box: a window's SVM margin, a blob's peak heat. Default 1.0.
    track_id : array_like of int, shape (n,), or None
        Track of each box (>= 0; -1 for a box that no track holds), or None when the boxes are
        not tracked.
    frame : int or array_like of int, shape (n,)
        0-based decoded frame index of each box (for a folder of images, the image's position in
        sorted order); one int applies to every box. Default 0.
    data : mapping of str to array_like, shape (n, ...), optional
        Further per-box columns (the search adds ``scale_index``, the window size each box was
        found at).

    Attributes
    ----------
    xyxy : ndarray of int64, shape (n, 4)
    score : ndarray of float64, shape (n,)
    track_id : ndarray of int64, shape (n,), or None
    frame : ndarray of int64, shape (n,)
    data : mapping of str to ndarray
        All arrays are read-only.

    Raises
    ------
    ValueError
        If a column has the wrong length or breaks the rules above; the message names the first
        offending row.

    Examples
    --------
    >>> d = Detections([[10, 20, 74, 84], [100, 20, 164, 84]], score=[0.5, 2.0])
    >>> len(d), d.xyxy.dtype.name, d.frame.tolist()
    (2, 'int64', [0, 0])
    >>> d[d.score > 1].xyxy.tolist()
    [[100, 20, 164, 84]]
    >>> len(Detections.concatenate([d, d]))
    4
    """

    xyxy: np.ndarray
    score: np.ndarray | None = None
    track_id: np.ndarray | None = None
    frame: np.ndarray | int = 0
    data: Mapping[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self) -> None:
        xyxy = as_boxes(self.xyxy, "xyxy", integer=True)
        n = len(xyxy)
        score = _column(1.0 if self.score is None else self.score, n, "score", np.float64, integer=False)
        frame = _column(self.frame, n, "frame", np.int64, integer=True)
        track_id = None if self.track_id is None else _column(self.track_id, n, "track_id", np.int64, integer=True)
        checks = [
            ((xyxy[:, 2] <= xyxy[:, 0]) | (xyxy[:, 3] <= xyxy[:, 1]), "a box needs x2 > x1 and y2 > y1"),
            (np.abs(xyxy).max(axis=1, initial=0) > MAX_COORD, f"box coordinates must be within +-{MAX_COORD}"),
            (~np.isfinite(score), "score must be finite"),
            (frame < 0, "frame must be >= 0"),
        ]
        if track_id is not None:
            checks.append((track_id < -1, "track_id must be >= 0, or -1 for a box no track holds"))
        for bad, problem in checks:
            if bad.any():
                i = int(np.flatnonzero(bad)[0])
                raise ValueError(f"row {i} (frame {frame[i]}, box {xyxy[i].tolist()}, score {score[i]}): {problem}")
        data = {}
        for key, values in dict(self.data).items():
            arr = np.asarray(values)
            if arr.ndim == 0 or len(arr) != n:
                raise ValueError(f"data[{key!r}] must have one entry per box ({n}); got shape {arr.shape}")
            data[str(key)] = _readonly(arr)
        set_ = object.__setattr__
        set_(self, "xyxy", _readonly(xyxy))
        set_(self, "score", _readonly(score))
        set_(self, "frame", _readonly(frame))
        set_(self, "track_id", None if track_id is None else _readonly(track_id))
        set_(self, "data", MappingProxyType(data))

    # --- construction --------------------------------------------------------------------------
    @classmethod
    def empty(cls, *, tracked: bool = False) -> Detections:
        """No boxes (with an empty ``track_id`` column when ``tracked``)."""
        return cls(np.zeros((0, 4), np.int64), track_id=np.zeros(0, np.int64) if tracked else None)

    @classmethod
    def concatenate(cls, parts: Iterable[Detections]) -> Detections:
        """The rows of several :class:`Detections`, in order.

        The result is tracked if any part is (the rows of untracked parts get ``-1``) and keeps
        the ``data`` columns that every part with rows has (every part, when none has rows).
        """
        parts = list(parts)
        tracked = any(p.track_id is not None for p in parts)
        if len(parts) == 1:
            return parts[0]
        if not parts:
            return cls.empty()
        # Columns that every part with rows has; with no rows at all, that every part has (parts
        # without rows then keep their columns, e.g. a search's scale_index).
        rows = [p for p in parts if len(p)] or parts
        keys = set.intersection(*(set(p.data) for p in rows))
        return cls(
            np.concatenate([p.xyxy for p in rows]),
            score=np.concatenate([p.score for p in rows]),
            track_id=np.concatenate([p.track_id if p.track_id is not None else np.full(len(p), -1) for p in rows])
            if tracked
            else None,
            frame=np.concatenate([p.frame for p in rows]),
            data={k: np.concatenate([p.data[k] for p in rows]) for k in sorted(keys)},
        )


    def replace(self, **changes: Any) -> Detections:
        """A copy with some fields replaced, e.g. ``d.replace(frame=7)``."""
        return replace(self, **changes)

    # --- access --------------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self.xyxy)

    def __getitem__(self, index) -> Detections:
        """Rows by an int, a slice, an integer array or a boolean mask (always a Detections)."""
        if isinstance(index, (int, np.integer)):
            index = [int(index)]
        index = np.asarray(index) if not isinstance(index, slice) else index
        if isinstance(index, np.ndarray) and index.dtype == bool and index.shape != (len(self),):
            raise IndexError(f"boolean mask of shape {index.shape} for {len(self)} detections")
        return Detections(
            self.xyxy[index],
            score=self.score[index],
            track_id=None if self.track_id is None else self.track_id[index],
            frame=self.frame[index],
            data={k: v[index] for k, v in self.data.items()},
        )

    def __eq__(self, other: object) -> bool:
        """Same rows in the same order, exactly (data columns included)."""
        if not isinstance(other, Detections):
            return NotImplemented
        same_ids = (self.track_id is None) == (other.track_id is None) and (
            self.track_id is None or np.array_equal(self.track_id, other.track_id)
        )
        return (
            same_ids
            and np.array_equal(self.xyxy, other.xyxy)
            and np.array_equal(self.score, other.score)
            and np.array_equal(self.frame, other.frame)
            and self.data.keys() == other.data.keys()
            and all(np.array_equal(v, other.data[k]) for k, v in self.data.items())
        )

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        frames = np.unique(self.frame).tolist()
        shown = frames if len(frames) <= 6 else [*frames[:3], "...", *frames[-2:]]
        ids = "None" if self.track_id is None else self.track_id.tolist()
        extra = f", data={sorted(self.data)}" if self.data else ""
        if len(self) > 8:
            return f"Detections(n={len(self)}, frames={shown}, tracked={self.track_id is not None}{extra})"
        return (
            f"Detections(n={len(self)}, frames={shown}, xyxy={self.xyxy.tolist()}, "
            f"score={np.round(self.score, 3).tolist()}, track_id={ids}{extra})"
        )

    @property
    def area(self) -> np.ndarray:
        """Box areas in pixels, ``int64`` shape (n,)."""
        return box_area(self.xyxy)

    def frames(self) -> np.ndarray:
        """The distinct frame indexes, increasing, ``int64``."""
        return np.unique(self.frame)

    def at_frame(self, index: int) -> Detections:
        """The rows of one frame."""
        return self[self.frame == index]

    def by_frame(self) -> dict[int, Detections]:
        """Rows by frame index, frames increasing, rows in table order; frames without rows absent."""
        order = np.argsort(self.frame, kind="stable")
        frames, starts = np.unique(self.frame[order], return_index=True)
        return {int(f): self[idx] for f, idx in zip(frames, np.split(order, starts[1:]))}

    def rows(self) -> Iterator[tuple[int, int, int, int, int, int, float]]:
        """``(frame, x1, y1, x2, y2, track_id, score)`` per row as Python numbers (-1: untracked)."""
        ids = self.track_id if self.track_id is not None else np.full(len(self), -1)
        for f, (x1, y1, x2, y2), t, s in zip(self.frame.tolist(), self.xyxy.tolist(), ids.tolist(), self.score.tolist()):
            yield f, x1, y1, x2, y2, t, s

    @classmethod
    def from_rows(cls, rows: Iterable[ArrayLike]) -> Detections:
        """Build from ``(frame, x1, y1, x2, y2, track_id, score)`` rows (as :meth:`rows` yields).

        The result is tracked unless every ``track_id`` is -1.
        """
        arr = np.array([tuple(r) for r in rows], dtype=object)
        if not len(arr):
            return cls.empty()
        if arr.ndim != 2 or arr.shape[1] != 7:
            raise ValueError("rows must be (frame, x1, y1, x2, y2, track_id, score)")
        ids = arr[:, 5].astype(np.int64)
        return cls(
            arr[:, 1:5].astype(np.float64),
            score=arr[:, 6].astype(np.float64),
            track_id=None if np.all(ids == -1) else ids,
            frame=arr[:, 0].astype(np.float64),
        )

    # --- other libraries -------------------------------------------------------------------------
    def to_pandas(self):
        """This table as a ``pandas.DataFrame`` (needs ``pip install "vehicle-detection[pandas]"``).

        Returns
        -------
        pandas.DataFrame
            One row per box, in order, with the columns of the boxes CSV: ``frame``, ``x1``,
            ``y1``, ``x2``, ``y2``, ``track_id`` (int64; -1 for every row when untracked) and
            ``score`` (float64), then each ``data`` column under its name (a column of shape
            ``(n, k)`` as ``name_0`` ... ``name_{k-1}``).

        Raises
        ------
        MissingDependencyError
            If pandas is not installed.

        Examples
        --------
        >>> d = Detections([[10, 20, 74, 84]], score=[0.5], track_id=[3], frame=7)
        >>> d.to_pandas().to_dict("records")
        [{'frame': 7, 'x1': 10, 'y1': 20, 'x2': 74, 'y2': 84, 'track_id': 3, 'score': 0.5}]
        """
        pd = require("pandas", "pandas", "Detections.to_pandas()")
        clash = [k for k in self.data if k in ("frame", "x1", "y1", "x2", "y2", "track_id", "score")]
        if clash:
            raise ValueError(f"data column {clash[0]!r} has the name of a main column")
        columns: dict[str, np.ndarray] = {"frame": self.frame}
        columns.update({name: self.xyxy[:, j] for j, name in enumerate(("x1", "y1", "x2", "y2"))})
        columns["track_id"] = self.track_id if self.track_id is not None else np.full(len(self), -1, np.int64)
        columns["score"] = self.score
        for key, values in self.data.items():
            if values.ndim == 1:
                columns[key] = values
            else:
                flat = values.reshape(len(self), -1)
                columns.update({f"{key}_{j}": flat[:, j] for j in range(flat.shape[1])})
        return pd.DataFrame({k: np.array(v) for k, v in columns.items()})

    def to_supervision(self):
        """This table as a ``supervision.Detections`` (needs ``pip install "vehicle-detection[supervision]"``).

        ``confidence`` is the score mapped into 0..1 (:func:`score_to_confidence`); the score
        itself travels in ``data["score"]``. See :func:`to_supervision`.
        """
        return to_supervision(self)

    @classmethod
    def from_supervision(cls, sv_detections, frame: int | None = None) -> Detections:
        """A table from a ``supervision.Detections`` (see :func:`from_supervision`)."""
        return from_supervision(sv_detections, frame)


# --- supervision ------------------------------------------------------------------------------------
#
# A box's ``score`` is not a probability, and not even one quantity: a search window's score is
# its SVM margin (about 0.3 to 3 with the embedded model), a box of an image or of a track is the
# peak heat of its blob (about 3 to 200). supervision's users expect ``confidence`` in 0..1
# (annotators print it as a fraction, trackers and filters take thresholds such as 0.25), so
# to_supervision maps the score with score_to_confidence, the "softsign"
# ``0.5 + 0.5 * s / (1 + |s|)``: increasing, 0.5 at a score of 0, never exactly 0 or 1 for a
# finite score, so the order of the boxes survives (a logistic would round every tracked box's
# heat to 1.0 and tie them). It is a squashing, not a calibration. The score itself travels in
# ``data["score"]``, and from_supervision takes it back from there exactly. The MOT and COCO
# files and the Parquet table keep the score as it is.


def score_to_confidence(score) -> np.ndarray:
    """A score mapped into 0..1 for supervision's ``confidence``: ``0.5 + 0.5 * s / (1 + |s|)``.

    Increasing in the score, 0.5 at 0: a squashing that keeps the boxes' order, not a
    calibration (``confidence > 0.5`` only says ``score > 0``).

    Parameters
    ----------
    score : array_like of float, shape (n,)

    Returns
    -------
    ndarray of float64, shape (n,)
        In (0, 1) for finite scores.

    Examples
    --------
    >>> score_to_confidence([-1.0, 0.0, 1.0, 3.0]).tolist()
    [0.25, 0.5, 0.75, 0.875]
    """
    s = np.asarray(score, dtype=np.float64)
    return 0.5 + 0.5 * s / (1.0 + np.abs(s))


def to_supervision(detections: Detections):
    """A ``supervision.Detections`` of the boxes.

    ``xyxy`` (float), ``confidence`` the score mapped into 0..1 by :func:`score_to_confidence`,
    ``tracker_id`` (None when untracked), ``class_id`` 0 (car), and ``data``: ``"frame"``,
    ``"score"`` (the score as it is) and the other data columns.
    """
    sv = require("supervision", "supervision", "Detections.to_supervision()")
    n = len(detections)
    data = {"frame": np.asarray(detections.frame), "score": np.asarray(detections.score, np.float64)}
    data.update({k: np.asarray(v) for k, v in detections.data.items()})
    return sv.Detections(
        xyxy=detections.xyxy.astype(np.float64),
        confidence=score_to_confidence(detections.score),
        class_id=np.zeros(n, dtype=int),
        tracker_id=None if detections.track_id is None else detections.track_id.astype(int),
        data=data,
    )


def from_supervision(sv_detections, frame: int | None = None) -> Detections:
    """A :class:`Detections` from a ``supervision.Detections``.

    Boxes are rounded to whole pixels (halves up); ``score`` is ``data["score"]`` when present
    (what :func:`to_supervision` stores), else ``confidence`` as it is (another detector's
    confidence is its score; 1.0 when None); ``tracker_id`` becomes ``track_id``; ``frame`` is
    ``data["frame"]`` when present, else ``frame`` (default 0). Other 1-D ``data`` columns are kept.
    """
    xyxy = np.floor(np.asarray(sv_detections.xyxy, dtype=np.float64).reshape(-1, 4) + 0.5).astype(np.int64)
    n = len(xyxy)
    conf = sv_detections.confidence
    data = dict(getattr(sv_detections, "data", {}) or {})
    frames = data.pop("frame", None)
    if frames is None:
        frames = 0 if frame is None else frame
    scores = data.pop("score", None)
    if scores is None:
        scores = np.ones(n) if conf is None else conf
    ids = sv_detections.tracker_id
    return Detections(
        xyxy,
        score=np.asarray(scores, np.float64),
        track_id=None if ids is None else np.asarray(ids, np.int64),
        frame=frames,
        data={k: np.asarray(v) for k, v in data.items() if np.ndim(v) == 1 and len(v) == n},
    )
