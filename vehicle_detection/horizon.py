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
value most frames agree on, and only when enough of them do; otherwise there is none, and the
plan stays as written. Single images are searched where the plan says, unless a horizon is given.
"""

from __future__ import annotations

from collections.abc import Iterable
from concurrent.futures import ThreadPoolExecutor

import cv2
import numpy as np

__all__ = ["vanishing_row", "estimate_horizon", "TOLERANCE"]

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
    order = np.argsort(rows)
    cum = np.cumsum(weights[order])
    median = rows[order][np.searchsorted(cum, cum[-1] / 2)]
    if weights[np.abs(rows - median) <= TOLERANCE * height].sum() < 0.5 * cum[-1]:
        return None  # the crossings scatter: no single point the lines run to
    return float(median / height)


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
