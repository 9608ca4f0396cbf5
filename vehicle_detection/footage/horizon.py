"""Where a camera's horizon is, from the road's lines: so that one search plan fits any dashcam.

The search bands (:class:`~vehicle_detection.search.SearchPlan`) are written for the project
camera, whose road vanishes at ``SearchPlan.reference_horizon`` of the frame height. A camera
mounted higher, lower or tilted sees the road's vanishing point elsewhere, and the bands must
move with it (``SearchPlan.horizon``).

The vanishing row of one frame comes from its straight edges (Canny, probabilistic Hough): the
lane lines and road edges rise towards the vanishing point from the left and from the right, so
every pair of a left-hand and a right-hand segment that reaches into the lower part of the
frame meets near it. The row is the length-weighted median of those crossings. One frame can
be wrong (a car hiding the lane lines, other edges crossing): over a video, the estimate is the
value most frames agree on, and only when enough of them do.

Where the road's lines give no horizon (no lane markings, dusk, a car hiding them, a zoomed
shot), the cars do (:class:`CarHorizon`, :func:`horizon_from_cars`): on a flat road a car's
bottom lies below the horizon by its width times the camera's height over the car's width
(Hoiem, Efros and Hebert, "Putting Objects in Perspective", CVPR 2006). The detector searches a
few frames with its bands at several candidate horizons, and the cars it finds there with a
clear margin, each consistent with the candidate it was found at, say where the horizon is.
Otherwise there is none, and the plan stays as written. Single images are searched where the
plan says, unless a horizon is given.
"""

from __future__ import annotations

from collections.abc import Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np

from .._settings import JsonSettings, number_in
from ..io.images import as_rgb_uint8

__all__ = ["vanishing_row", "estimate_horizon", "TOLERANCE", "CarHorizon", "implied_horizon", "horizon_from_cars"]

_HEIGHT = 540  # frames are measured at this height, where the thresholds below are set
#: The estimate's precision, a fraction of the frame height: crossings of one frame, and rows of
#: several frames, this close together agree; a horizon this close to the plan's reference is it.
TOLERANCE = 0.015


def vanishing_row(frame: np.ndarray) -> float | None:
    """The row where the road's lines meet, as a fraction of the frame height from the top.

    Parameters
    ----------
    frame : ndarray of uint8, shape (H, W, 3)
        RGB frame of a road ahead.

    Returns
    -------
    float or None
        In ``[0.25, 0.75]``; None when the frame shows no pair of lines rising from the lower
        part of the frame towards a common point (no lane lines or road edges), or when the
        crossings scatter (less than half their weight within 1.5 % of the height of the median).
    """
    frame = as_rgb_uint8(frame, name="frame")  # grey converted, anything else refused in one line
    h, w = frame.shape[:2]
    if h < 16 or w < 16:
        return None
    scale = _HEIGHT / h
    img = cv2.resize(np.ascontiguousarray(frame), (max(1, round(w * scale)), _HEIGHT), interpolation=cv2.INTER_AREA)
    height, width = img.shape[:2]
    top, bottom = int(0.35 * height), int(0.95 * height)
    gray = cv2.cvtColor(img[top:bottom], cv2.COLOR_RGB2GRAY)
    edges = cv2.Canny(cv2.GaussianBlur(gray, (5, 5), 0), 50, 150)
    lines = cv2.HoughLinesP(edges, 1, np.pi / 180, 30, minLineLength=30, maxLineGap=15)
    if lines is None:
        return None
    seg = lines.reshape(-1, 4).astype(np.float64)
    seg[:, [1, 3]] += top
    dx, dy = seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1]
    angle = np.degrees(np.arctan2(dy, dx)) % 180.0  # 0..180, image rows grow downwards
    length = np.hypot(dx, dy)
    low = np.maximum(seg[:, 1], seg[:, 3]) > 0.65 * height  # reaches into the road near the car
    left = np.flatnonzero(low & (angle > 110) & (angle < 160))  # rises to the right: left of the lane
    right = np.flatnonzero(low & (angle > 20) & (angle < 70))
    if not len(left) or not len(right):
        return None
    a, b = seg[left][:, None, :], seg[right][None, :, :]
    x1, y1, x2, y2 = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    x3, y3, x4, y4 = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    den = (x1 - x2) * (y3 - y4) - (y1 - y2) * (x3 - x4)
    with np.errstate(divide="ignore", invalid="ignore"):
        p = x1 * y2 - y1 * x2
        q = x3 * y4 - y3 * x4
        px = (p * (x3 - x4) - (x1 - x2) * q) / den
        py = (p * (y3 - y4) - (y1 - y2) * q) / den
    upper = np.minimum(np.minimum(y1, y2), np.minimum(y3, y4))
    ok = (
        (np.abs(den) > 1e-6) & (px > 0.2 * width) & (px < 0.8 * width)
        & (py > 0.25 * height) & (py < 0.75 * height) & (upper > py - 5)  # both segments below the crossing
    )
    if not ok.any():
        return None
    rows = py[ok]
    weights = (length[left][:, None] * length[right][None, :])[ok]
    median, total = _weighted_median(rows, weights)
    if weights[np.abs(rows - median) <= TOLERANCE * height].sum() < 0.5 * total:
        return None  # the crossings scatter: no single point the lines run to
    return float(median / height)


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> tuple[float, float]:
    """The value at which the cumulative weight of the sorted ``values`` reaches half the total,
    and the total."""
    order = np.argsort(values, kind="stable")
    cum = np.cumsum(weights[order])
    return values[order][np.searchsorted(cum, cum[-1] / 2)], cum[-1]


def estimate_horizon(
    frames: Iterable[np.ndarray],
    *,
    tolerance: float = TOLERANCE,
    min_share: float = 0.6,
    min_frames: int = 1,
    workers: int = 1,
) -> float | None:
    """The horizon most of ``frames`` agree on (:func:`vanishing_row`), or None.

    Parameters
    ----------
    frames : iterable of ndarray of uint8, shape (H, W, 3)
        Frames of one camera (a video's first frames, or one image).
    tolerance : float
        Two frames agree when their rows differ by at most this fraction of the frame height.
    min_share : float
        The largest group of agreeing frames must hold at least this share of the frames that
        gave a row.
    min_frames : int
        Fewest frames that must give a row.
    workers : int
        Frames measured at once, in threads (OpenCV releases the GIL); the result is the same.

    Returns
    -------
    float or None
        The median row of the largest agreeing group, as a fraction of the frame height.
    """
    if workers > 1:
        with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="horizon") as pool:
            found = list(pool.map(vanishing_row, frames))
    else:
        found = [vanishing_row(f) for f in frames]
    rows = np.array([r for r in found if r is not None])
    if len(rows) < max(1, min_frames):
        return None
    agree = np.abs(rows[:, None] - rows[None, :]) <= tolerance
    best = int(np.argmax(agree.sum(axis=1)))
    group = rows[agree[best]]
    if len(group) < min_share * len(rows):
        return None
    return float(np.median(group))


@dataclass(frozen=True)
class CarHorizon(JsonSettings):
    """How the horizon is read off the cars, where the road's lines give none.

    A camera ``h`` metres above a flat road sees a car ``W`` metres wide, ``w`` pixels wide in the
    picture, with its bottom ``(h / W) w`` pixels below the horizon: both are the focal length
    over the car's distance times ``h`` and ``W``. So each car found says where the horizon is
    (:func:`implied_horizon`).

    Parameters
    ----------
    ratio : float, default 0.57
        The camera's height over a car's width, in ``(0, 2]``. Both dev cameras' labelled cars
        give it (medians 0.55 and 0.59: a dashcam about a metre up, cars 1.8 m wide with their
        mirrors); a camera mounted higher, on a lorry, has a larger one.
    min_margin : float, default 1.0
        Only windows with at least this SVM margin count (the margin boundary of the SVM):
        clusters of far cars and scenery score above the search threshold at a wrong horizon
        more often than real cars at the right one.
    candidates : tuple of float, default (0.35, 0.43, 0.51, 0.59, 0.67)
        The horizons (fractions of the picture height) the bands are moved to for the search.
    agree : float, default 0.06
        A car counts at a candidate only if the horizon it implies lies this close to it (a
        fraction of the picture height, in ``(0, 0.5)``): a window found with the bands in the
        wrong place is rarely a car seen where the bands expect one.
    min_hits : int, default 5
        Fewest cars (hot windows) that must count.
    frames : int, default 4
        Frames of the first ones searched (spread over them), >= 1.

    Raises
    ------
    ValueError
        If a value is out of range; the message names the field.
    """

    ratio: float = 0.57
    min_margin: float = 1.0
    candidates: tuple[float, ...] = (0.35, 0.43, 0.51, 0.59, 0.67)
    agree: float = 0.06
    min_hits: int = 5
    frames: int = 4

    def __post_init__(self) -> None:
        object.__setattr__(self, "ratio", number_in(self, "ratio", 0.0, 2.0, high_in=True))
        object.__setattr__(self, "min_margin", number_in(self, "min_margin", -np.inf))
        object.__setattr__(self, "agree", number_in(self, "agree", 0.0, 0.5))
        c = self.candidates
        if (isinstance(c, (str, bytes)) or not hasattr(c, "__len__") or not len(c)
                or not all(isinstance(v, (int, float)) and not isinstance(v, bool) and 0.0 < v < 1.0 for v in c)):
            raise ValueError(f"CarHorizon.candidates must be a non-empty sequence of numbers in (0, 1); got {c!r}")
        object.__setattr__(self, "candidates", tuple(float(v) for v in c))
        for name in ("min_hits", "frames"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
                raise ValueError(f"CarHorizon.{name} must be an integer >= 1; got {v!r}")
            object.__setattr__(self, name, int(v))


def implied_horizon(boxes: np.ndarray, height: int, ratio: float) -> np.ndarray:
    """The horizon each car's box implies, as a fraction of the picture height from the top.

    Parameters
    ----------
    boxes : ndarray, shape (n, 4)
        Cars ``[x1, y1, x2, y2]`` in picture pixels.
    height : int
        The picture's height in pixels.
    ratio : float
        The camera's height over a car's width (:attr:`CarHorizon.ratio`).

    Returns
    -------
    ndarray of float64, shape (n,)
        ``(y2 - ratio * (x2 - x1)) / height``.
    """
    b = np.asarray(boxes, np.float64).reshape(-1, 4)
    return (b[:, 3] - ratio * (b[:, 2] - b[:, 0])) / float(height)


def horizon_from_cars(
    found: Iterable[tuple[float, np.ndarray, np.ndarray]], height: int, rule: CarHorizon | None = None
) -> float | None:
    """The horizon the cars found at several candidate horizons agree on, or None.

    Parameters
    ----------
    found : iterable of (float, ndarray (n, 4), ndarray (n,))
        For each search: the candidate horizon the bands were moved to, the boxes of its hot
        windows in picture pixels (refined, where the model refines them) and their margins.
    height : int
        The picture's height in pixels.
    rule : CarHorizon, optional
        Default settings if None.

    Returns
    -------
    float or None
        The margin-weighted median of the implied horizons (:func:`implied_horizon`) of the
        windows with at least ``rule.min_margin`` that agree with their candidate; None when
        fewer than ``rule.min_hits`` count, or when no more than half their weight lies within
        twice :data:`TOLERANCE` of the median (the cars do not agree).
    """
    rule = rule or CarHorizon()
    rows, weights = [np.zeros(0)], [np.zeros(0)]
    for candidate, boxes, margins in found:
        implied = implied_horizon(boxes, height, rule.ratio)
        margins = np.asarray(margins, np.float64).reshape(-1)
        keep = (margins >= rule.min_margin) & (np.abs(implied - candidate) <= rule.agree)
        rows.append(implied[keep])
        weights.append(margins[keep])
    row, weight = np.concatenate(rows), np.concatenate(weights)
    if len(row) < rule.min_hits:
        return None
    median, total = _weighted_median(row, weight)
    if weight[np.abs(row - median) <= 2 * TOLERANCE].sum() <= 0.5 * total:
        return None  # no majority of the cars agrees
    return float(median)
