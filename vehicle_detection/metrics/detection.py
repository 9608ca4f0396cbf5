"""Score detected vehicle boxes against hand-labelled frames.

The annotation format is described in ``data/README.md`` of the shared data: a JSON object whose
``frames`` maps a 0-based decoded frame index (a string) to ``cars`` (boxes that must be found) and
``ignore`` (far, truncated or oncoming vehicles). An unmatched detection lying mostly inside one
ignore box is neither a true nor a false positive; it is counted as ``ignored``.

Boxes are ``(n, 4)`` arrays ``[x1, y1, x2, y2]`` in pixels with ``x2`` and ``y2`` exclusive, so a
box covers ``(x2 - x1) * (y2 - y1)`` pixels.

Scoring conventions
-------------------
* Matching is one-to-one between detections and cars, among pairs whose IoU is at least the
  threshold. The matching first maximises the number of matched pairs (true positives) and, among
  matchings of that size, the total IoU (see :func:`match_frame`).
* ``precision = tp / (tp + fp)``, defined as 1.0 when there are no scored detections
  (``tp + fp == 0``: no detections at all, or every one ignored).
* ``recall = tp / (tp + fn)``, defined as 1.0 when there are no cars.
* ``f1`` is the harmonic mean of precision and recall, 0.0 when both are 0.
* ``fp_per_frame = fp / n_frames``, 0.0 when no frame was scored.

Cameras and failures
--------------------
Several labels files are pooled per camera (:func:`pool_by_camera`): the file's ``camera`` key,
else its frame size (:func:`camera_name`). :func:`find_failures` lists what a contact sheet shows
(:mod:`vehicle_detection.metrics.reporting`): misses and false positives at IoU 0.5, and loose matches
(matched at 0.5 with IoU below 0.7).
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from ..io import read_text
from ..detections import Detections
from ..errors import InputError, shorten
from ..geometry import MAX_COORD, as_boxes, box_area, box_intersection, box_iou, match_boxes

__all__ = [
    "FrameLabels",
    "Annotations",
    "FrameMatch",
    "Scores",
    "load_annotations",
    "check_boxes_inside",
    "match_frame",
    "evaluate_detections",
    "average_precision",
    "tracking_frames",
    "evaluation_report",
    "camera_name",
    "pool_reports",
    "pool_by_camera",
    "Failure",
    "FAILURE_KINDS",
    "frame_failures",
    "find_failures",
]

_FRAME_KEY = re.compile(r"0|[1-9][0-9]*", re.ASCII)
_BOX_FIELDS = ("cars", "ignore")
_FRAME_FIELDS = ("cars", "ignore", "ids", "file")
#: What a camera name may be: it names a file (``failures_<camera>.png``).
_CAMERA_NAME = re.compile(r"[A-Za-z0-9][A-Za-z0-9._-]{0,63}", re.ASCII)


def _frozen_int_boxes(boxes: ArrayLike, name: str) -> np.ndarray:
    arr = np.array(as_boxes(boxes, name, integer=True), dtype=np.int64, copy=True)
    arr.setflags(write=False)
    return arr


# --------------------------------------------------------------------------------------------
# Annotations
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class FrameLabels:
    """The labelled boxes of one frame.

    Parameters
    ----------
    cars : array_like, shape (n, 4)
        Vehicles that must be found. Stored as a read-only ``int64`` array.
    ignore : array_like, shape (m, 4)
        Regions (far, truncated or oncoming vehicles) in which an unmatched detection is not a
        false positive. Stored as a read-only ``int64`` array; defaults to none.
    ids : array_like of int, shape (n,), optional
        Track id of each car (the same vehicle has the same id in every frame), for tracking
        metrics; None when the frame's cars are not identified.
    file : str, optional
        For a folder of images: the image file the frame is.

    Raises
    ------
    ValueError
        If a box is not 4 whole numbers with ``x2 > x1`` and ``y2 > y1``, or ``ids`` does not
        give one distinct integer per car.

    Notes
    -----
    Equality is identity (comparing arrays element-wise is left to the caller).
    """

    cars: np.ndarray
    ignore: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), dtype=np.int64))
    ids: np.ndarray | None = None
    file: str | None = None

    def __post_init__(self) -> None:
        for name in _BOX_FIELDS:
            arr = _frozen_int_boxes(getattr(self, name), name)
            empty = np.flatnonzero((arr[:, 2] == arr[:, 0]) | (arr[:, 3] == arr[:, 1]))
            if empty.size:
                i = int(empty[0])
                raise ValueError(f"{name}[{i}] = {arr[i].tolist()} has zero area (x2 == x1 or y2 == y1)")
            object.__setattr__(self, name, arr)
        if self.ids is not None:
            ids = np.array(self.ids, dtype=np.int64).reshape(-1)
            if len(ids) != len(self.cars) or len(set(ids.tolist())) != len(ids):
                raise ValueError(f"ids must give one distinct integer per car ({len(self.cars)}); got {ids.tolist()}")
            ids.setflags(write=False)
            object.__setattr__(self, "ids", ids)


@dataclass(frozen=True, eq=False)
class Annotations:
    """Hand-labelled frames of one video.

    Parameters
    ----------
    video : str or None
        The annotated video (or folder of images) as written in the file, if given.
    frames : dict of int to FrameLabels
        Labels by 0-based decoded frame index, in increasing frame order.
    path : Path, optional
        The annotation file, when read from one; ``video`` is relative to its folder.
    camera : str, optional
        The camera that filmed the frames (the file's ``camera`` key): a short name of letters,
        digits, ``.``, ``_`` and ``-``. Files of the same camera are pooled together by
        :func:`pool_by_camera`; see :func:`camera_name` for files without one.
    """

    video: str | None
    frames: dict[int, FrameLabels]
    path: Path | None = None
    camera: str | None = None

    @property
    def source(self) -> Path | None:
        """The video or image folder the labels are of: ``video`` relative to the file's folder."""
        if self.video is None:
            return None
        base = self.path.parent if self.path is not None else Path(".")
        return base / self.video

    @property
    def tracked(self) -> bool:
        """Every labelled frame identifies its cars (``ids``): tracking metrics apply."""
        return bool(self.frames) and all(f.ids is not None for f in self.frames.values())

    @property
    def n_cars(self) -> int:
        """Total number of ``cars`` boxes over all frames."""
        return sum(len(f.cars) for f in self.frames.values())


def _reject_constant(name: str) -> float:
    raise ValueError(f"{name} is not a number allowed in annotations")


def _no_duplicate_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in pairs:
        if key in out:
            raise ValueError(f"duplicate key {shorten(repr(key))}")
        out[key] = value
    return out


def _parse_box(value: Any, where: str, path: Path) -> list[int]:
    def fail(problem: str) -> InputError:
        return InputError(f"{path}: {where} = {shorten(json.dumps(value), 80)}: {problem}")

    if not isinstance(value, list) or len(value) != 4:
        raise fail("a box must be a list of 4 numbers [x1, y1, x2, y2]")
    coords = []
    for name, v in zip(("x1", "y1", "x2", "y2"), value):
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise fail(f"{name} is not a number")
        if isinstance(v, float) and not v.is_integer():
            raise fail(f"{name} = {shorten(v)} is not a whole pixel")
        if v < 0 or v > MAX_COORD:
            raise fail(f"{name} = {shorten(v)} is outside 0..{MAX_COORD}")
        coords.append(int(v))
    x1, y1, x2, y2 = coords
    if x2 <= x1:
        raise fail(f"x2 ({x2}) <= x1 ({x1}); boxes need x2 > x1 (x2 is exclusive)")
    if y2 <= y1:
        raise fail(f"y2 ({y2}) <= y1 ({y1}); boxes need y2 > y1 (y2 is exclusive)")
    return coords


def _parse_frame(key: str, value: Any, path: Path) -> FrameLabels:
    where = f"frames[{json.dumps(key)}]"
    if not isinstance(value, dict):
        raise InputError(f"{path}: {where} must be an object with 'cars' and 'ignore'")
    unknown = sorted(set(value) - set(_FRAME_FIELDS))
    if unknown:
        raise InputError(f"{path}: {where} has unknown key(s) {unknown}; expected 'cars', 'ignore', 'ids' and 'file'")
    if "cars" not in value:
        raise InputError(f"{path}: {where} has no 'cars' list (write \"cars\": [] for a frame without cars)")
    lists = {}
    for name in _BOX_FIELDS:
        boxes = value.get(name, [])
        if not isinstance(boxes, list):
            raise InputError(f"{path}: {where}.{name} must be a list of boxes")
        lists[name] = [_parse_box(b, f"{where}.{name}[{i}]", path) for i, b in enumerate(boxes)]
    ids = value.get("ids")
    if ids is not None:
        if not isinstance(ids, list) or any(isinstance(i, bool) or not isinstance(i, int) or not 0 <= i <= MAX_COORD for i in ids):
            raise InputError(f"{path}: {where}.ids must be a list of whole numbers 0..{MAX_COORD}, one per car")
        if len(ids) != len(lists["cars"]) or len(set(ids)) != len(ids):
            raise InputError(f"{path}: {where}.ids must give one distinct id per car ({len(lists['cars'])}); got {ids}")
    file = value.get("file")
    if file is not None and (not isinstance(file, str) or not file or "/" in file or "\\" in file):
        raise InputError(f"{path}: {where}.file must be a file name (no folders)")
    return FrameLabels(cars=lists["cars"], ignore=lists["ignore"], ids=ids, file=file)


def load_annotations(path: str | os.PathLike) -> Annotations:
    """Read and validate a JSON annotation file.

    Parameters
    ----------
    path : path-like
        JSON object with ``frames`` (required) mapping frame index strings (``"0"``, ``"50"``; no
        sign, spaces or leading zeros) to objects with ``cars`` (required) and ``ignore``
        (optional) lists of ``[x1, y1, x2, y2]`` boxes of whole, non-negative pixels with
        ``x2 > x1`` and ``y2 > y1``, ``ids`` (optional, one distinct track id per car) and
        ``file`` (optional, the image file of a folder's frame); and optionally ``video``
        (string or null: the video or image folder, relative to the JSON file). Other top-level
        keys (e.g. ``format``) are allowed and ignored; other keys inside a frame are refused, so
        that a misspelt ``"ignroe"`` cannot silently drop labels. An optional ``camera`` (a
        short name: 1 to 64 letters, digits, ``.``, ``_`` or ``-``, starting with a letter or
        digit) says which camera filmed the frames.

    Returns
    -------
    Annotations
        With ``frames`` sorted by frame index.

    Raises
    ------
    InputError
        If the file cannot be read, is not JSON (including ``NaN``/``Infinity`` and duplicate
        keys), or breaks the format; the message names the file and the frame and box at fault,
        e.g. ``frames["50"].cars[1]``.
    """
    path = Path(path)
    text = read_text(path, "annotation file", "JSON")
    try:
        doc = json.loads(text, object_pairs_hook=_no_duplicate_keys, parse_constant=_reject_constant)
    except json.JSONDecodeError as exc:
        raise InputError(f"{path}: invalid JSON at line {exc.lineno} column {exc.colno}: {exc.msg}") from None
    except ValueError as exc:  # from the hooks above
        raise InputError(f"{path}: invalid annotation JSON: {exc}") from None
    except RecursionError:
        raise InputError(f"{path}: JSON nested too deeply") from None

    if not isinstance(doc, dict):
        raise InputError(f"{path}: expected a JSON object with 'frames', got {type(doc).__name__}")
    if "frames" not in doc:
        raise InputError(f"{path}: no 'frames' key; expected {{\"frames\": {{\"<frame index>\": ...}}}}")
    video = doc.get("video")
    if video is not None and (not isinstance(video, str) or not video.strip() or "\0" in video):
        raise InputError(f"{path}: 'video' must be the path of a video or image folder (relative to this file), or null")
    camera = doc.get("camera")
    if camera is not None and (not isinstance(camera, str) or not _CAMERA_NAME.fullmatch(camera)):
        raise InputError(
            f"{path}: 'camera' must be a short name (1 to 64 letters, digits, '.', '_' or '-', starting "
            f"with a letter or digit); got {json.dumps(camera)}"
        )
    raw_frames = doc["frames"]
    if not isinstance(raw_frames, dict):
        raise InputError(f"{path}: 'frames' must be an object mapping frame indices to labels")

    frames: dict[int, FrameLabels] = {}
    for key, value in raw_frames.items():
        if not _FRAME_KEY.fullmatch(key):
            raise InputError(
                f"{path}: frame key {shorten(json.dumps(key))} is not a non-negative integer "
                "(a 0-based frame index written without sign, spaces or leading zeros)"
            )
        if len(key) > 10 or int(key) > MAX_COORD:
            raise InputError(f"{path}: frame key {shorten(key)} is beyond the largest frame index {MAX_COORD}")
        frames[int(key)] = _parse_frame(key, value, path)
    return Annotations(video=video, frames=dict(sorted(frames.items())), path=path, camera=camera)


def check_boxes_inside(annotations: Annotations, width: int, height: int, frames: Iterable[int] | None = None, source=None) -> None:
    """Refuse labelled boxes that reach beyond the frames they label.

    A box beyond the frame cannot be matched (detections are clipped to the frame), and cutting
    training patches at it would read outside the picture: such labels are of another video or
    another frame size.

    Parameters
    ----------
    annotations : Annotations
    width, height : int
        The frame size of the labelled video or image.
    frames : iterable of int, optional
        Check only these labelled frames (default: every one).
    source : path-like, optional
        The video or image the frames are of, for the message.

    Raises
    ------
    InputError
        Naming the file, the frame and the box, e.g. ``frames["50"].cars[1]``.
    """
    for index in annotations.frames if frames is None else frames:
        labels = annotations.frames.get(index)
        if labels is None:
            continue
        for name in _BOX_FIELDS:
            boxes = getattr(labels, name)
            bad = np.flatnonzero((boxes[:, 2] > width) | (boxes[:, 3] > height))
            if bad.size:
                k = int(bad[0])
                of = f" of {source}" if source is not None else ""
                raise InputError(
                    f"{annotations.path}: frames[\"{index}\"].{name}[{k}] = {boxes[k].tolist()} reaches beyond the "
                    f"{width}x{height} frame{of} (x2 <= {width} and y2 <= {height}); labels of another video?"
                )


# --------------------------------------------------------------------------------------------
# Matching and scores
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class FrameMatch:
    """The outcome of matching one frame's detections to its labels.

    Attributes
    ----------
    matches : ndarray of intp, shape (tp, 2)
        Matched pairs ``(detection index, car index)``, sorted by detection index.
    match_iou : ndarray of float64, shape (tp,)
        IoU of each matched pair.
    false_positives : ndarray of intp, shape (fp,)
        Indices of unmatched detections not inside an ignore box.
    ignored_detections : ndarray of intp, shape (ignored,)
        Indices of unmatched detections lying inside an ignore box.
    missed : ndarray of intp, shape (fn,)
        Indices of cars that no detection matched.
    """

    matches: np.ndarray
    match_iou: np.ndarray
    false_positives: np.ndarray
    ignored_detections: np.ndarray
    missed: np.ndarray

    @property
    def tp(self) -> int:
        """Number of true positives (matched pairs)."""
        return len(self.matches)

    @property
    def fp(self) -> int:
        """Number of false positives."""
        return len(self.false_positives)

    @property
    def fn(self) -> int:
        """Number of false negatives (missed cars)."""
        return len(self.missed)

    @property
    def ignored(self) -> int:
        """Number of unmatched detections inside an ignore box."""
        return len(self.ignored_detections)


def _check_fraction(value: float, name: str) -> float:
    value = float(value)
    if not 0.0 < value <= 1.0:
        raise ValueError(f"{name} must be in (0, 1]; got {value}")
    return value


def match_frame(
    detections: ArrayLike,
    labels: FrameLabels | ArrayLike,
    iou_threshold: float = 0.5,
    ignore_overlap: float = 0.5,
) -> FrameMatch:
    """Match one frame's detections to its labelled cars, one to one.

    Parameters
    ----------
    detections : array_like, shape (k, 4)
        Detected boxes ``[x1, y1, x2, y2]`` (x2, y2 exclusive).
    labels : FrameLabels or array_like of shape (n, 4)
        The frame's labels; a plain array is taken as ``cars`` with no ignore regions.
    iou_threshold : float, default 0.5
        A detection and a car can be matched only if their IoU is at least this, in ``(0, 1]``.
    ignore_overlap : float, default 0.5
        An unmatched detection is ignored (not a false positive) if at least this fraction of its
        area lies inside one single ignore box, in ``(0, 1]``. A zero-area detection is never
        ignored.

    Returns
    -------
    FrameMatch
        The matched pairs and the indices of false positives, ignored detections and missed cars.

    Notes
    -----
    Among the pairs with IoU >= ``iou_threshold`` the matching has the largest possible number
    of pairs and, among such matchings, the largest total IoU (an assignment problem solved with
    :func:`scipy.optimize.linear_sum_assignment`). Maximising total IoU alone could trade two
    valid matches for one tighter match at low thresholds, turning a true positive into a false
    positive plus a false negative.

    Cars take precedence over ignore regions: a detection matched to a car is a true positive
    even if it lies inside an ignore box.
    """
    iou_threshold = _check_fraction(iou_threshold, "iou_threshold")
    ignore_overlap = _check_fraction(ignore_overlap, "ignore_overlap")
    dets = as_boxes(detections, "detections")
    if not isinstance(labels, FrameLabels):
        labels = FrameLabels(cars=labels)
    cars = labels.cars.astype(np.float64)
    n_det, n_car = len(dets), len(cars)

    det_idx = np.zeros(0, dtype=np.intp)
    car_idx = np.zeros(0, dtype=np.intp)
    pair_iou = np.zeros(0, dtype=np.float64)
    if n_det and n_car:
        iou = box_iou(dets, cars)
        det_idx, car_idx = match_boxes(iou, iou_threshold)
        pair_iou = iou[det_idx, car_idx]

    unmatched = np.setdiff1d(np.arange(n_det, dtype=np.intp), det_idx)
    inside = np.zeros(len(unmatched), dtype=bool)
    if len(unmatched) and len(labels.ignore):
        cand = dets[unmatched]
        area = box_area(cand)
        inter = box_intersection(cand, labels.ignore.astype(np.float64))
        frac = np.zeros_like(inter)
        np.divide(inter, area[:, None], out=frac, where=area[:, None] > 0)
        inside = (frac >= ignore_overlap).any(axis=1)

    missed = np.setdiff1d(np.arange(n_car, dtype=np.intp), car_idx)
    order = np.argsort(det_idx, kind="stable")
    return FrameMatch(
        matches=np.stack([det_idx[order], car_idx[order]], axis=1).reshape(-1, 2),
        match_iou=pair_iou[order],
        false_positives=unmatched[~inside],
        ignored_detections=unmatched[inside],
        missed=missed,
    )


@dataclass(frozen=True)
class Scores:
    """Detection counts and rates over a set of frames at one IoU threshold.

    Parameters
    ----------
    tp, fp, fn, ignored : int
        True positives, false positives, false negatives (missed cars), and unmatched detections
        inside ignore regions.
    n_frames : int
        Number of frames scored.
    iou_sum : float
        Sum of the IoUs of the matched pairs (``mean_iou`` is ``iou_sum / tp``).

    Notes
    -----
    The rates are derived from the counts (module docstring): ``precision`` is 1.0 when
    ``tp + fp == 0``, ``recall`` is 1.0 when ``tp + fn == 0``, ``f1`` is 0.0 when both are 0, and
    ``fp_per_frame`` is 0.0 when ``n_frames == 0``.
    """

    tp: int
    fp: int
    fn: int
    ignored: int
    n_frames: int
    iou_sum: float = 0.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "iou_sum", float(self.iou_sum))
        for name in ("tp", "fp", "fn", "ignored", "n_frames"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
                raise ValueError(f"{name} must be a non-negative integer; got {value!r}")
            object.__setattr__(self, name, int(value))

    @property
    def precision(self) -> float:
        """``tp / (tp + fp)``; 1.0 when there are no scored detections."""
        scored = self.tp + self.fp
        return self.tp / scored if scored else 1.0

    @property
    def recall(self) -> float:
        """``tp / (tp + fn)``; 1.0 when there are no cars."""
        cars = self.tp + self.fn
        return self.tp / cars if cars else 1.0

    @property
    def f1(self) -> float:
        """Harmonic mean of precision and recall; 0.0 when both are 0."""
        p, r = self.precision, self.recall
        return 2 * p * r / (p + r) if p + r else 0.0

    @property
    def mean_iou(self) -> float:
        """Mean IoU of the matched pairs; 0.0 when nothing matched."""
        return self.iou_sum / self.tp if self.tp else 0.0

    @property
    def fp_per_frame(self) -> float:
        """False positives per scored frame; 0.0 when no frame was scored."""
        return self.fp / self.n_frames if self.n_frames else 0.0

    def as_dict(self) -> dict[str, int | float]:
        """Counts and rates as a JSON-ready dict of plain ``int`` and ``float``."""
        return {
            "tp": self.tp,
            "fp": self.fp,
            "fn": self.fn,
            "ignored": self.ignored,
            "n_frames": self.n_frames,
            "precision": self.precision,
            "recall": self.recall,
            "f1": self.f1,
            "mean_iou": self.mean_iou,
            "fp_per_frame": self.fp_per_frame,
        }


def evaluate_detections(
    detections: Detections | Mapping[int, ArrayLike],
    annotations: Annotations,
    iou_thresholds: Iterable[float] = (0.5, 0.7),
    *,
    ignore_overlap: float = 0.5,
) -> dict[float, Scores]:
    """Score detections on every annotated frame, at one or more IoU thresholds.

    Parameters
    ----------
    detections : Detections, or mapping of int to array_like of shape (k, 4)
        Detected boxes with their 0-based decoded frame indexes (e.g. from
        :func:`vehicle_detection.io.tables.read_boxes_csv`), or boxes by frame index. Only
        annotated frames are scored: an
        annotated frame missing here counts as a frame with no detections, and frames that are not
        annotated are skipped.
    annotations : Annotations
        From :func:`load_annotations`.
    iou_thresholds : iterable of float, default (0.5, 0.7)
        Each in ``(0, 1]``; the frames are matched separately at each.
    ignore_overlap : float, default 0.5
        As for :func:`match_frame`.

    Returns
    -------
    dict of float to Scores
        One :class:`Scores` per threshold, keyed by the threshold as a float, in the order given.
        For JSON: ``{str(t): s.as_dict() for t, s in result.items()}``.

    Raises
    ------
    ValueError
        If a threshold is outside ``(0, 1]``, no threshold is given, or a detection array is
        malformed (the message names the frame).
    """
    thresholds = [_check_fraction(t, "iou_threshold") for t in iou_thresholds]
    if not thresholds:
        raise ValueError("iou_thresholds is empty; give at least one threshold")
    ignore_overlap = _check_fraction(ignore_overlap, "ignore_overlap")

    by_frame = {f: d.xyxy for f, d in detections.by_frame().items()} if isinstance(detections, Detections) else detections
    dets: dict[int, np.ndarray] = {}
    for frame in annotations.frames:
        dets[frame] = as_boxes(by_frame.get(frame, ()), f"detections of frame {frame}")

    result: dict[float, Scores] = {}
    for t in thresholds:
        tp = fp = fn = ignored = 0
        ious: list[float] = []
        for frame, labels in annotations.frames.items():
            m = match_frame(dets[frame], labels, iou_threshold=t, ignore_overlap=ignore_overlap)
            tp, fp, fn, ignored = tp + m.tp, fp + m.fp, fn + m.fn, ignored + m.ignored
            ious.extend(m.match_iou.tolist())
        # fsum: correctly rounded, so the mean IoU does not depend on the order of the boxes
        # (a tie between equal boxes may pair them in either order)
        result[t] = Scores(tp=tp, fp=fp, fn=fn, ignored=ignored, n_frames=len(annotations.frames), iou_sum=math.fsum(ious))
    return result


def average_precision(
    detections: Detections, annotations: Annotations, iou_threshold: float = 0.5, *, ignore_overlap: float = 0.5
) -> float:
    """Average precision of scored detections over the labelled frames (AP50 at 0.5).

    Detections of all labelled frames are ranked by ``score``. In each frame, in that order, a
    detection is a true positive if its best-overlapping car not yet taken has IoU >=
    ``iou_threshold``; otherwise it is dropped if it lies in an ignore region (as in
    :func:`match_frame`) and is a false positive if not. AP is the area under the precision-recall
    curve with precision made monotone (the all-point interpolation of PASCAL VOC 2010 on).

    Returns
    -------
    float
        In ``[0, 1]``; 0.0 when there are no cars.

    Examples
    --------
    >>> ann = Annotations(None, {0: FrameLabels(cars=[[0, 0, 10, 10], [20, 0, 30, 10]])})
    >>> dets = Detections([[0, 0, 10, 10], [50, 50, 60, 60], [20, 0, 30, 10]], score=[0.9, 0.8, 0.7])
    >>> round(average_precision(dets, ann), 4)  # recall 0.5 at precision 1, then 1.0 at 2/3
    0.8333
    """
    iou_threshold = _check_fraction(iou_threshold, "iou_threshold")
    n_cars = annotations.n_cars
    if n_cars == 0:
        return 0.0
    outcomes = []  # (score, 1 for TP / 0 for FP)
    for frame, labels in annotations.frames.items():
        dets = detections.at_frame(frame)
        order = np.argsort(-dets.score, kind="stable")
        boxes, scores = dets.xyxy[order], dets.score[order]
        iou = box_iou(boxes, labels.cars)
        taken = np.zeros(len(labels.cars), bool)
        for i in range(len(boxes)):
            cand = np.where(taken, -1.0, iou[i]) if len(labels.cars) else np.zeros(0)
            j = int(np.argmax(cand)) if cand.size else -1
            if j >= 0 and cand[j] >= iou_threshold:
                taken[j] = True
                outcomes.append((scores[i], 1))
                continue
            area = box_area(boxes[i : i + 1].astype(np.float64))
            if len(labels.ignore) and area[0] > 0:
                frac = box_intersection(boxes[i : i + 1].astype(np.float64), labels.ignore.astype(np.float64))[0] / area[0]
                if (frac >= ignore_overlap).any():
                    continue
            outcomes.append((scores[i], 0))
    if not outcomes:
        return 0.0
    outcomes.sort(key=lambda o: -o[0])
    hits = np.array([o[1] for o in outcomes], np.float64)
    tp = np.cumsum(hits)
    precision = tp / np.arange(1, len(hits) + 1)
    recall = tp / n_cars
    precision = np.maximum.accumulate(precision[::-1])[::-1]  # the best precision at >= this recall
    steps = np.diff(np.concatenate([[0.0], recall]))
    return float(np.sum(steps * precision))


def tracking_frames(detections: Detections, annotations: Annotations, *, ignore_overlap: float = 0.5) -> list:
    """The labelled frames as ``(gt_ids, gt_boxes, tracker_ids, tracker_boxes)`` for
    :func:`~vehicle_detection.metrics.tracking.tracking_scores`.

    Detections that match no car at IoU >= 0.5 and lie in an ignore region are left out, as
    :func:`match_frame` leaves them out of the false positives.

    Raises
    ------
    ValueError
        If the annotations carry no ``ids`` or the detections no ``track_id``.
    """
    if not annotations.tracked:
        raise ValueError("the labels carry no track ids ('ids'); tracking metrics need them")
    if detections.track_id is None:
        raise ValueError("the detections are not tracked (no track_id)")
    out = []
    for frame, labels in annotations.frames.items():
        dets = detections.at_frame(frame)
        m = match_frame(dets.xyxy, labels, iou_threshold=0.5, ignore_overlap=ignore_overlap)
        keep = np.setdiff1d(np.arange(len(dets)), m.ignored_detections)
        out.append((labels.ids, labels.cars, dets.track_id[keep], dets.xyxy[keep]))
    return out


def evaluation_report(detections: Detections, annotations: Annotations, *, fps: float | None = None) -> dict:
    """Every detection and tracking figure of detections against one annotation file.

    Returns
    -------
    dict
        ``n_frames``, ``n_cars``; ``at_iou_0.5`` and ``at_iou_0.7``: the :class:`Scores` of
        :func:`evaluate_detections` as dicts (precision, recall, F1, mean IoU of matched boxes,
        false positives per frame); ``ap50``; ``fp_per_minute`` when ``fps`` is given (false
        positives per frame times frames per minute); and ``tracking`` (MOTA, IDF1, HOTA, ...)
        when the labels carry track ids and the detections are tracked.
    """
    from .tracking import tracking_scores  # scipy, only for labels with track ids

    scores = evaluate_detections(detections, annotations, (0.5, 0.7))
    report = {
        "n_frames": len(annotations.frames),
        "n_cars": annotations.n_cars,
        "at_iou_0.5": scores[0.5].as_dict(),
        "at_iou_0.7": scores[0.7].as_dict(),
        "ap50": average_precision(detections, annotations, 0.5),
    }
    if fps:
        report["fp_per_minute"] = scores[0.5].fp_per_frame * fps * 60.0
    if annotations.tracked and detections.track_id is not None:
        report["tracking"] = tracking_scores(tracking_frames(detections, annotations)).as_dict()
    return report


# --------------------------------------------------------------------------------------------
# Cameras: several labels files pooled
# --------------------------------------------------------------------------------------------
#: The pooled figures of :func:`pool_reports`, at each IoU threshold.
POOLED_THRESHOLDS = ("at_iou_0.5", "at_iou_0.7")


def camera_name(annotations: Annotations, frame_size: tuple[int, int] | None) -> str:
    """The camera a labels file is pooled under.

    Parameters
    ----------
    annotations : Annotations
    frame_size : (int, int) or None
        ``(width, height)`` in pixels of the labelled video or images, if known.

    Returns
    -------
    str
        The file's ``camera`` key; else the frame size as ``"WIDTHxHEIGHT"`` (``"1280x720"``);
        else ``"unknown"``.

    Examples
    --------
    >>> camera_name(Annotations(None, {}), (1280, 720))
    '1280x720'
    >>> camera_name(Annotations(None, {}, camera="highway"), (1280, 720))
    'highway'
    """
    if annotations.camera:
        return annotations.camera
    if frame_size is None:
        return "unknown"
    return f"{int(frame_size[0])}x{int(frame_size[1])}"


def pool_reports(reports: Iterable[Mapping[str, Any]]) -> dict[str, Any]:
    """Several files' :func:`evaluation_report` dicts pooled into one: counts summed, rates recomputed.

    Parameters
    ----------
    reports : iterable of mapping
        Each with ``n_cars`` and ``at_iou_0.5`` / ``at_iou_0.7`` (``tp``, ``fp``, ``fn``,
        ``ignored``, ``n_frames`` and ``mean_iou``).

    Returns
    -------
    dict
        ``n_frames``, ``n_cars``, and ``at_iou_0.5`` / ``at_iou_0.7``: :meth:`Scores.as_dict`
        of the summed counts, the matched IoUs summed as ``mean_iou * tp`` of each file (so the
        mean IoU is that of every matched box of every file). Empty input gives zero counts.
    """
    reports = list(reports)
    pooled: dict[str, Any] = {}
    for key in POOLED_THRESHOLDS:
        total = {f: sum(int(r[key][f]) for r in reports) for f in ("tp", "fp", "fn", "ignored", "n_frames")}
        iou_sum = sum(r[key]["mean_iou"] * r[key]["tp"] for r in reports)
        pooled[key] = Scores(**total, iou_sum=iou_sum).as_dict()
    return {
        "n_frames": pooled["at_iou_0.5"]["n_frames"],
        "n_cars": sum(int(r["n_cars"]) for r in reports),
        **pooled,
    }


def pool_by_camera(reports: Mapping[str, Mapping[str, Any]], cameras: Mapping[str, str]) -> dict[str, dict[str, Any]]:
    """Each camera's files pooled (:func:`pool_reports`).

    Parameters
    ----------
    reports : mapping of str to mapping
        :func:`evaluation_report` dicts by labels file name.
    cameras : mapping of str to str
        The camera of each labels file name (:func:`camera_name`).

    Returns
    -------
    dict of str to dict
        By camera, in the order the cameras first appear in ``reports``: the pooled figures and
        ``labels``, the list of the camera's labels file names.

    Raises
    ------
    KeyError
        If a file of ``reports`` has no camera.
    """
    names: dict[str, list[str]] = {}
    for name in reports:
        names.setdefault(cameras[name], []).append(name)
    return {cam: {**pool_reports(reports[n] for n in files), "labels": files} for cam, files in names.items()}


# --------------------------------------------------------------------------------------------
# Failures: what a contact sheet shows
# --------------------------------------------------------------------------------------------
#: The kinds of :class:`Failure`, most serious first.
FAILURE_KINDS = ("miss", "false positive", "loose")


@dataclass(frozen=True, eq=False)
class Failure:
    """A labelled car missed, a false positive, or a loose match, in one frame.

    Attributes
    ----------
    frame : int
        The 0-based frame index (as in the labels).
    kind : str
        ``"miss"`` (a car matched by no reported box at IoU 0.5), ``"false positive"`` (a
        reported box matched to no car and not mostly inside an ignore box) or ``"loose"``
        (matched at IoU 0.5 with an IoU below the loose threshold, 0.7).
    box : ndarray of float64, shape (4,)
        The labelled car (miss, loose) or the reported box (false positive).
    iou : float
        Miss: the car's best IoU with any reported box; false positive: the box's best IoU with
        any labelled car; loose: the IoU of the matched pair. 0.0 when there is nothing to
        overlap.
    partner : ndarray of float64, shape (4,), or None
        The box ``iou`` was measured against (the matched reported box of a loose match), None
        when ``iou`` is 0.
    """

    frame: int
    kind: str
    box: np.ndarray
    iou: float
    partner: np.ndarray | None = None


def _best(iou: np.ndarray, others: np.ndarray) -> tuple[float, np.ndarray | None]:
    """The largest IoU of one box's row ``(m,)`` and the box ``(4,)`` of ``others`` giving it."""
    if not iou.size or iou.max() <= 0:
        return 0.0, None
    j = int(np.argmax(iou))
    return float(iou[j]), others[j]


def frame_failures(
    detections: ArrayLike,
    labels: FrameLabels,
    frame: int = 0,
    *,
    loose_below: float = 0.7,
    ignore_overlap: float = 0.5,
) -> list[Failure]:
    """The misses, false positives and loose matches of one frame, matched at IoU 0.5.

    Parameters
    ----------
    detections : array_like, shape (k, 4)
        The frame's reported boxes.
    labels : FrameLabels
    frame : int
        Stored in each :class:`Failure`.
    loose_below : float, default 0.7
        A matched pair with IoU below this is ``"loose"``, in ``(0, 1]``.
    ignore_overlap : float, default 0.5
        As for :func:`match_frame`.

    Returns
    -------
    list of Failure
        Misses (in car order), then false positives and loose matches (in detection order).
    """
    loose_below = _check_fraction(loose_below, "loose_below")
    dets = as_boxes(detections, "detections")
    cars = labels.cars.astype(np.float64)
    m = match_frame(dets, labels, iou_threshold=0.5, ignore_overlap=ignore_overlap)
    iou = box_iou(dets, cars) if len(dets) and len(cars) else np.zeros((len(dets), len(cars)))
    out = [Failure(frame, "miss", cars[c], *_best(iou[:, c], dets)) for c in m.missed.tolist()]
    out += [Failure(frame, "false positive", dets[d], *_best(iou[d], cars)) for d in m.false_positives.tolist()]
    out += [
        Failure(frame, "loose", cars[c], float(v), dets[d])
        for (d, c), v in zip(m.matches.tolist(), m.match_iou.tolist())
        if v < loose_below
    ]
    return out


def find_failures(
    detections: Detections | Mapping[int, ArrayLike],
    annotations: Annotations,
    *,
    loose_below: float = 0.7,
    ignore_overlap: float = 0.5,
) -> list[Failure]:
    """:func:`frame_failures` of every labelled frame, in frame order.

    Parameters
    ----------
    detections : Detections, or mapping of int to array_like of shape (k, 4)
        As for :func:`evaluate_detections`.
    annotations : Annotations
    loose_below, ignore_overlap : float
        As for :func:`frame_failures`.

    Returns
    -------
    list of Failure

    Examples
    --------
    >>> ann = Annotations(None, {3: FrameLabels(cars=[[0, 0, 10, 10], [50, 0, 60, 10]])})
    >>> dets = Detections([[0, 0, 10, 8], [200, 0, 240, 40]], frame=[3, 3])
    >>> [(f.frame, f.kind, round(f.iou, 2)) for f in find_failures(dets, ann)]
    [(3, 'miss', 0.0), (3, 'false positive', 0.0)]
    """
    by_frame = {f: d.xyxy for f, d in detections.by_frame().items()} if isinstance(detections, Detections) else detections
    out: list[Failure] = []
    for frame, labels in annotations.frames.items():
        dets = as_boxes(by_frame.get(frame, ()), f"detections of frame {frame}")
        out += frame_failures(dets, labels, frame, loose_below=loose_below, ignore_overlap=ignore_overlap)
    return out
