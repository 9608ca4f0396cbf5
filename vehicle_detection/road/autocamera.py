"""The bird's-eye transform of a dashcam from its own footage: lanes and distances without a chessboard.

:func:`~vehicle_detection.lanes.birds_eye_from_straight` needs frames of a straight road taken
with a calibrated camera. Here the same transform is estimated from a sample of a video's frames
(:func:`sample_frames`: up to 60, spread over the first seconds), in three steps:

1. **Paint.** Lane paint is narrower than the road and brighter than it: a horizontal
   morphological top-hat of the grey frame, thresholded at a high percentile of the road's
   response (:func:`paint_mask`), then probabilistic Hough segments, kept when they slope like
   lane lines.
2. **Vanishing point and the two lane lines near the car.** Over all frames, every pair of a
   left-leaning and a right-leaning segment crosses near the vanishing point; the median of each
   frame's length-weighted median crossing is a first estimate. In each frame, the segments
   whose lines pass near it are sorted by where their ray from it meets the bottom row; the
   peaks nearest the camera's centre column, one on each side, are the lines of the car's own
   lane. Each is fitted as a straight line ``x = a*y + b`` (weighted least squares); their
   crossing is the frame's vanishing point. Frames without two such lines, with a crossing far
   from the first estimate, or with a lane width at the bottom row more than 20 % off the median
   are rejected. The estimate is the median over the remaining frames of the vanishing point,
   of the lane width and of the lane centre at the bottom row.
3. **Scale.** The source quadrilateral lies between the two lines, from the bottom row up to
   ``top`` of the way from the bottom row to the vanishing row (0.1: ten times the distance of the
   bottom row); it is mapped onto a rectangle (:class:`~vehicle_detection.lanes.BirdsEye`).
   Across the road: the lane width, 3.7 m, over the lines' distance in the warped view. Along
   it: the dash period, 12 m (a 3 m dash and a 9 m gap), over the dash-to-dash period measured
   in each frame's warped paint (the median over the frames that show dashes). Without dashes
   there is no scale along the road, and no estimate.

No lens distortion is estimated: frames are used as they are, unless a :class:`Camera` is given
(its undistortion is applied first). The estimate comes with a :class:`RoadEstimate`: the
figures, the frames they came from, their spread across frames (interquartile range) and a
bootstrap interval of each median; or, when no estimate is possible, the reason. It can be saved
as a camera file (:func:`camera_from_estimate`, :func:`save_estimate`) that ``--camera`` loads;
:func:`road_transform` lets a given camera file win over the estimate.

The camera implied by the estimate (:attr:`RoadEstimate.camera_height_m`,
:attr:`RoadEstimate.focal_px`, :attr:`RoadEstimate.pitch_deg`) follows from the pinhole model
of a camera level across the road (no roll) with its principal point at the image centre: a
check of plausibility, not used by the transform.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..errors import require
from ..io import atomic_output
from ..io.video import probe_video, read_frames
from .camera import Camera
from .lanes import DASH_PERIOD_M, LANE_WIDTH_M, BirdsEye, _dash_period, _view_from_lines, draw_lane

__all__ = [
    "EstimateSettings",
    "RoadEstimate",
    "FrameLines",
    "paint_mask",
    "paint_segments",
    "frame_lines",
    "sample_frames",
    "estimate_birds_eye",
    "estimate_birds_eye_from_video",
    "camera_from_estimate",
    "save_estimate",
    "road_transform",
    "road_figure",
]

_HEIGHT = 540  # frames are searched at this height (at most), where the thresholds are set


@dataclass(frozen=True)
class FrameLines:
    """The lane lines of the car's own lane in one frame, in camera pixels.

    Attributes
    ----------
    index : int
        Position of the frame in the sample.
    left, right : (float, float)
        ``(a, b)`` of ``x = a*y + b``.
    vanishing_point : (float, float)
        ``(x, y)`` where the two lines cross.
    bottom : (float, float)
        ``x`` of the left and the right line at the bottom row.
    """

    index: int
    left: tuple[float, float]
    right: tuple[float, float]
    vanishing_point: tuple[float, float]
    bottom: tuple[float, float]

    @property
    def width_px(self) -> float:
        return self.bottom[1] - self.bottom[0]

    @property
    def centre_px(self) -> float:
        return (self.bottom[0] + self.bottom[1]) / 2


@dataclass(frozen=True)
class RoadEstimate:
    """What :func:`estimate_birds_eye` found: the estimate, its frames and its uncertainty.

    Attributes
    ----------
    reason : str or None
        Why there is no estimate (None when there is one).
    image_size : (int, int)
        ``(width, height)`` of the frames.
    frames_sampled : int
        Frames looked at.
    frames_used : tuple of int
        Positions in the sample of the frames that gave both lane lines (and agreed).
    frames_with_dashes : int
        Of those, the frames whose dashes gave a period.
    vanishing_point : (float, float) or None
        ``(x, y)`` in camera pixels: the median over the frames used.
    left_line, right_line : (float, float) or None
        ``(a, b)`` of ``x = a*y + b``, through the vanishing point and the median lane edges at the
        bottom row.
    xm_per_px, ym_per_px : float or None
        Metres per warped pixel across and along the road.
    spread : dict
        Interquartile range across the frames used: ``vanishing_x_px``, ``vanishing_y_px``,
        ``lane_width_px`` (at the bottom row), ``ym_rel`` (of the per-frame metres per pixel along
        the road, relative to the median).
    interval : dict
        Bootstrap 90 % interval (over frames) of the median: ``vanishing_y_px``,
        ``lane_width_px``, ``ym_per_px``, each a ``(low, high)`` pair.
    camera_height_m, focal_px, pitch_deg : float or None
        The pinhole camera the estimate implies (see the module docstring); ``pitch_deg`` is
        positive for a camera looking down (the horizon above the principal point).
    lane_width_m, dash_period_m : float
        The road's assumed dimensions.
    source : str
        Where the transform came from: ``"footage"``, or ``"camera file"`` (see
        :func:`road_transform`).
    """

    reason: str | None
    image_size: tuple[int, int]
    frames_sampled: int
    frames_used: tuple[int, ...] = ()
    frames_with_dashes: int = 0
    vanishing_point: tuple[float, float] | None = None
    left_line: tuple[float, float] | None = None
    right_line: tuple[float, float] | None = None
    xm_per_px: float | None = None
    ym_per_px: float | None = None
    spread: dict = field(default_factory=dict)
    interval: dict = field(default_factory=dict)
    camera_height_m: float | None = None
    focal_px: float | None = None
    pitch_deg: float | None = None
    lane_width_m: float = LANE_WIDTH_M
    dash_period_m: float = DASH_PERIOD_M
    source: str = "footage"

    @property
    def ok(self) -> bool:
        return self.reason is None

    def to_dict(self) -> dict:
        """Plain JSON types (lists for pairs)."""

        def plain(v):
            if isinstance(v, dict):
                return {k: plain(x) for k, x in v.items()}
            if isinstance(v, (tuple, list, np.ndarray)):
                return [plain(x) for x in v]
            if isinstance(v, (np.floating, float)):
                return None if not math.isfinite(v) else float(v)
            if isinstance(v, np.integer):
                return int(v)
            return v

        keys = (
            "source", "reason", "image_size", "frames_sampled", "frames_used", "frames_with_dashes", "vanishing_point",
            "left_line", "right_line", "xm_per_px", "ym_per_px", "spread", "interval", "camera_height_m", "focal_px",
            "pitch_deg", "lane_width_m", "dash_period_m",
        )
        return {k: plain(getattr(self, k)) for k in keys}

    def summary(self) -> list[str]:
        """Human-readable lines: the estimate, its frames and its uncertainty (or why there is none)."""
        if self.source == "camera file":
            return ["bird's-eye view: from the camera file"]
        if not self.ok:
            return [f"no lanes: {self.reason} ({len(self.frames_used)} of {self.frames_sampled} sampled frames showed both lane lines)"]
        vx, vy = self.vanishing_point
        iv, sp = self.interval, self.spread
        lines = [
            f"bird's-eye view from the footage: both lane lines in {len(self.frames_used)} of {self.frames_sampled} sampled "
            f"frames, dashes in {self.frames_with_dashes}",
            f"  vanishing point ({vx:.0f}, {vy:.0f}) px, row {vy / self.image_size[1]:.3f} of the height "
            f"(90 % interval {iv['vanishing_y_px'][0]:.0f} to {iv['vanishing_y_px'][1]:.0f}; IQR across frames {sp['vanishing_y_px']:.1f} px)",
            f"  lane width at the bottom row {_width(self):.0f} px = {self.lane_width_m} m "
            f"(90 % interval {iv['lane_width_px'][0]:.0f} to {iv['lane_width_px'][1]:.0f})",
            f"  {100 * self.xm_per_px:.2f} cm per pixel across, {100 * self.ym_per_px:.2f} cm per pixel along the road "
            f"(dash period {self.dash_period_m} m; 90 % interval {100 * iv['ym_per_px'][0]:.2f} to {100 * iv['ym_per_px'][1]:.2f}; "
            f"IQR across frames {100 * sp['ym_rel']:.0f} %)",
        ]
        if self.focal_px is not None:
            lines.append(
                f"  implied camera: {self.camera_height_m:.2f} m above the road, focal length {self.focal_px:.0f} px, "
                f"pitched {abs(self.pitch_deg):.1f} deg {'down' if self.pitch_deg >= 0 else 'up'} (a level pinhole camera)"
            )
        return lines


def _width(est: RoadEstimate) -> float:
    h = est.image_size[1]
    return float(np.polyval(est.right_line, h) - np.polyval(est.left_line, h))


# --- paint and segments -------------------------------------------------------------------------


def paint_mask(rgb: np.ndarray, *, road_rows: tuple[float, float] = (0.5, 0.9), percentile: float = 95.0, floor: int = 8) -> np.ndarray:
    """Pixels of lane paint: narrow horizontal runs brighter than the road on both sides.

    Parameters
    ----------
    rgb : ndarray of uint8, shape (H, W, 3)
    road_rows : (float, float)
        Rows (fractions of the height) whose response sets the threshold.
    percentile, floor : float, int
        Threshold: this percentile of the top-hat response in ``road_rows``, at least ``floor``
        grey levels.

    Returns
    -------
    ndarray of uint8, shape (H, W)
        0 or 1.
    """
    import cv2

    h, w = rgb.shape[:2]
    gray = cv2.GaussianBlur(cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2GRAY), (5, 5), 0)  # not the noise
    k = max(5, int(round(w * 0.032)) | 1)  # wider than a near lane line
    top_hat = cv2.morphologyEx(gray, cv2.MORPH_TOPHAT, cv2.getStructuringElement(cv2.MORPH_RECT, (k, 1)))
    band = top_hat[int(road_rows[0] * h) : max(int(road_rows[1] * h), int(road_rows[0] * h) + 1)]
    threshold = max(float(floor), float(np.percentile(band, percentile)))
    return (top_hat > threshold).view(np.uint8)


def paint_segments(rgb: np.ndarray) -> np.ndarray:
    """Straight segments of lane paint below the top 30 % of the frame, sloping like lane lines.

    Parameters
    ----------
    rgb : ndarray of uint8, shape (H, W, 3)

    Returns
    -------
    ndarray of float64, shape (n, 4)
        ``x1, y1, x2, y2`` in the frame's pixels (probabilistic Hough on :func:`paint_mask`, at
        most 540 rows high); neither near-vertical (poles) nor near-horizontal (a bonnet's edge).
    """
    import cv2

    h, w = rgb.shape[:2]
    scale = min(1.0, _HEIGHT / h)
    img = rgb if scale == 1.0 else cv2.resize(np.ascontiguousarray(rgb), (round(w * scale), round(h * scale)), interpolation=cv2.INTER_AREA)
    mask = paint_mask(img)
    hh = img.shape[0]
    mask[: int(0.3 * hh)] = 0
    lines = cv2.HoughLinesP(mask * 255, 1, np.pi / 180, 20, minLineLength=max(10, hh // 27), maxLineGap=max(5, hh // 54))
    if lines is None:
        return np.zeros((0, 4))
    seg = lines.reshape(-1, 4).astype(np.float64) / scale
    dx, dy = seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1]
    with np.errstate(divide="ignore", invalid="ignore"):
        slope = np.abs(dx / dy)
    keep = (dy != 0) & (slope > 0.2) & (slope < 4.0)  # neither poles nor the bonnet's edge
    return seg[keep]


def _slope(seg: np.ndarray) -> np.ndarray:
    """dx/dy of each segment: negative for a line leaning like the left lane line."""
    return (seg[:, 2] - seg[:, 0]) / (seg[:, 3] - seg[:, 1])


def _crossing(seg: np.ndarray, height: int) -> tuple[float, float] | None:
    """The length-weighted median crossing of left- and right-leaning segments below it.

    Only segments reaching into the lower 40 % of the frame count (the road near the car, not
    the buildings, bridges and cars beyond).
    """
    s = _slope(seg)
    length = np.hypot(seg[:, 2] - seg[:, 0], seg[:, 3] - seg[:, 1])
    low = np.maximum(seg[:, 1], seg[:, 3]) > 0.6 * height
    left, right = np.flatnonzero(low & (s < 0)), np.flatnonzero(low & (s > 0))
    if not len(left) or not len(right):
        return None
    # x = a*y + b for each segment
    a = s
    b = seg[:, 0] - a * seg[:, 1]
    al, bl = a[left][:, None], b[left][:, None]
    ar, br = a[right][None, :], b[right][None, :]
    y = (br - bl) / (al - ar)
    x = al * y + bl
    upper = np.minimum(np.minimum(seg[:, 1], seg[:, 3])[left][:, None], np.minimum(seg[:, 1], seg[:, 3])[right][None, :])
    ok = np.isfinite(y) & (upper > y) & (y > 0.1 * height) & (y < 0.8 * height)
    if not ok.any():
        return None
    wts = (length[left][:, None] * length[right][None, :])[ok]
    return _wmedian(x[ok], wts), _wmedian(y[ok], wts)


def _wmedian(values: np.ndarray, weights: np.ndarray) -> float:
    order = np.argsort(values)
    cum = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cum, cum[-1] / 2)])


def _rays(seg: np.ndarray, vanishing_point, image_size, tolerance_deg: float):
    """Segments below the vanishing point that point at it: ``(seg, length, x at the bottom row)``.

    A segment points at the vanishing point when its direction is within ``tolerance_deg``
    (plus the direction error of a segment that short: two pixels at either end) of the ray from
    the vanishing point through its middle.
    """
    w, h = image_size
    vx, vy = vanishing_point
    x1, y1, x2, y2 = seg.T
    length = np.hypot(x2 - x1, y2 - y1)
    mx, my = (x1 + x2) / 2, (y1 + y2) / 2
    cross = np.abs((x2 - x1) * (my - vy) - (y2 - y1) * (mx - vx))
    ray = np.hypot(mx - vx, my - vy)
    angle = np.degrees(np.arcsin(np.clip(cross / np.maximum(length * ray, 1e-9), 0, 1)))
    keep = (angle < tolerance_deg + np.degrees(np.arctan(4 / np.maximum(length, 1)))) & (np.minimum(y1, y2) > vy + 0.02 * h)
    xb = vx + (mx[keep] - vx) * (h - vy) / (my[keep] - vy)  # where the ray from the VP through the segment meets the bottom row
    return seg[keep], length[keep], xb


def _peaks(xb: np.ndarray, weights: np.ndarray, width: int, min_weight: float) -> tuple[np.ndarray, np.ndarray]:
    """Positions and weights of the peaks of a weighted histogram of ``xb`` (1 % of ``width`` per bin, lightly smoothed)."""
    bin_w = 0.01 * width
    edges = np.arange(-width, 2 * width + bin_w, bin_w)
    hist, _ = np.histogram(xb, edges, weights=weights)
    hist = np.convolve(hist, [0.25, 0.5, 1.0, 0.5, 0.25], mode="same")
    centres = (edges[:-1] + edges[1:]) / 2
    is_peak = (hist > 0) & (hist >= np.r_[0, hist[:-1]]) & (hist >= np.r_[hist[1:], 0]) & (hist >= min_weight)
    return centres[is_peak], hist[is_peak]


def _lane_pair(peaks: np.ndarray, weights: np.ndarray, width: int, *, lane_px=(0.4, 1.3), off_centre: float = 0.35):
    """The two peaks either side of the centre column that best make the car's lane, or None.

    A pair must be plausible: as wide as ``lane_px`` (fractions of the frame width) at the bottom
    row, with its centre within ``off_centre`` of its width of the frame's centre column (the
    car is in it). Its score is its weaker line's weight less the strongest peak between the two
    (a lane has no line inside it); the best pair must score above zero.
    """
    best, score = None, 0.0
    for i in np.flatnonzero(peaks < width / 2):
        for j in np.flatnonzero(peaks > width / 2):
            a, b = peaks[i], peaks[j]
            span = b - a
            if not lane_px[0] * width <= span <= lane_px[1] * width or abs((a + b) / 2 - width / 2) > off_centre * span:
                continue
            inside = weights[(peaks > a) & (peaks < b)]
            value = min(weights[i], weights[j]) - (inside.max() if len(inside) else 0.0)
            if value > score:
                best, score = (float(a), float(b)), value
    return best


def frame_lines(
    seg: np.ndarray, vanishing_point, image_size, index: int = 0, *, tolerance_deg: float = 2.0
) -> FrameLines | None:
    """The two lines of the car's own lane among one frame's paint segments, or None.

    Parameters
    ----------
    seg : ndarray, shape (n, 4)
        Segments ``x1, y1, x2, y2`` in camera pixels.
    vanishing_point : (float, float)
        A first estimate (camera pixels): segments that do not point at it (within
        ``tolerance_deg``, see :func:`_rays`) are not lane lines of this road.
    image_size : (int, int)
    index : int
        Recorded in the result.

    Returns
    -------
    FrameLines or None
        None when no pair of lines makes a plausible lane around the centre column (see
        :func:`_lane_pair`), or the two lines do not cross above the bottom row.
    """
    w, h = image_size
    if not len(seg):
        return None
    seg, length, xb = _rays(seg, vanishing_point, image_size, tolerance_deg)
    if not len(seg):
        return None
    pair = _lane_pair(*_peaks(xb, length, w, 0.03 * h), w)
    if pair is None:
        return None
    fits = []
    for peak in pair:
        mine = np.abs(xb - peak) < 0.025 * w
        s = seg[mine]
        ys, xs = np.r_[s[:, 1], s[:, 3]], np.r_[s[:, 0], s[:, 2]]
        wt = np.sqrt(np.r_[length[mine], length[mine]])
        if len(ys) < 2 or np.ptp(ys) < 0.02 * h:
            return None
        fits.append(tuple(float(v) for v in np.polyfit(ys, xs, 1, w=wt)))
    (al, bl), (ar, br) = fits
    if not al < 0 < ar:
        return None
    y = (br - bl) / (al - ar)
    if not y < h:
        return None
    return FrameLines(index, fits[0], fits[1], (al * y + bl, y), (al * h + bl, ar * h + br))


# --- the estimate -------------------------------------------------------------------------------


def sample_frames(path: str | os.PathLike, *, seconds: float = 10.0, max_frames: int = 60, start: int = 0) -> tuple[list[int], list[np.ndarray]]:
    """Up to ``max_frames`` frames spread evenly over the first ``seconds`` of a video.

    Parameters
    ----------
    path : path-like
        A video FFmpeg reads.
    seconds : float
        Length of the stretch sampled, from frame ``start`` (the whole video when shorter).
    max_frames : int
    start : int
        First decoded frame of the stretch.

    Returns
    -------
    indices : list of int
        Decoded frame indices.
    frames : list of ndarray of uint8, shape (H, W, 3)
        RGB frames.
    """

    info = probe_video(path)
    span = max(1, int(round(seconds * (info.fps or 25.0))))
    if info.n_frames is not None:
        span = max(1, min(span, info.n_frames - start))
    wanted = set(np.unique(np.linspace(start, start + span - 1, min(max_frames, span)).round().astype(int)).tolist())
    indices, frames = [], []
    gen = read_frames(path)
    try:
        for i, frame in enumerate(gen):
            if i in wanted:
                indices.append(i)
                frames.append(frame)
            if i >= start + span - 1:
                break
    finally:
        gen.close()
    return indices, frames


@dataclass(frozen=True)
class EstimateSettings:
    """The road's dimensions, and how :func:`estimate_birds_eye` makes its estimate.

    Parameters
    ----------
    lane_width_m, dash_period_m : float
        The road's lane width and the period of its dashed lines (dash plus gap).
    top : float
        Top of the source quadrilateral, as a fraction of the way from the bottom row up to the
        vanishing row.
    warped_size : (int, int), optional
        Default: half the frame's width and height.
    margin : float
        The lines land at ``margin`` and ``1 - margin`` of the warped width.
    min_frames, min_share : int, float
        Fewest frames (and share of the frames) that must show both lane lines.
    min_dash_frames : int
        Fewest of those whose dashes must give a period (also at least half of ``min_frames``).
    window : int
        The lane lines of a frame are fitted to the paint segments of it and its neighbours in
        the sample, ``window`` frames in all (dashes move along their line, so neighbouring frames
        fill the gaps between them).
    bootstrap : int
        Resamples of the frames for the intervals.
    seed : int
        Of the bootstrap's random generator.
    """

    lane_width_m: float = LANE_WIDTH_M
    dash_period_m: float = DASH_PERIOD_M
    top: float = 0.1
    warped_size: tuple[int, int] | None = None
    margin: float = 0.25
    min_frames: int = 5
    min_share: float = 0.2
    min_dash_frames: int = 3
    window: int = 3
    bootstrap: int = 200
    seed: int = 0


def estimate_birds_eye(
    frames: Iterable[np.ndarray], camera=None, settings: EstimateSettings | None = None
) -> tuple[BirdsEye | None, RoadEstimate]:
    """The bird's-eye transform of a camera, from frames of the road ahead (see the module docstring).

    Parameters
    ----------
    frames : iterable of ndarray of uint8, shape (H, W, 3)
        RGB frames of one camera, all of one size (e.g. :func:`sample_frames`).
    camera : Camera, optional
        Undistort the frames first; its own ``birds_eye`` is not used (see :func:`road_transform`).
    settings : EstimateSettings, optional
        The road's lane width and dash period, and how the estimate is made (default:
        :class:`EstimateSettings` ()).

    Returns
    -------
    birds_eye : BirdsEye or None
        None when the lane lines or their dashes are not seen in enough frames.
    estimate : RoadEstimate
        The figures and their uncertainty, or the ``reason`` there are none.
    """
    cfg = settings if settings is not None else EstimateSettings()
    frames = [camera.undistort(f) if camera is not None else np.asarray(f) for f in frames]
    if not frames:
        return None, RoadEstimate("no frames", (0, 0), 0)
    h, w = frames[0].shape[:2]
    for f in frames:
        if f.shape[:2] != (h, w) or f.ndim != 3 or f.dtype != np.uint8:
            raise ValueError(f"frames must be RGB uint8 of one size; got {f.shape} {f.dtype} after {w}x{h}")
    n = len(frames)
    size = (w, h)
    needed = max(cfg.min_frames, int(math.ceil(cfg.min_share * n)))
    segs = [paint_segments(f) for f in frames]
    crossings = [c for c in (_crossing(s, h) for s in segs) if c is not None]
    if len(crossings) < needed:
        return None, RoadEstimate(f"no lane lines seen: lines converging ahead in {len(crossings)} of {n} frames (need {needed})", size, n)
    first = np.median(np.array(crossings), axis=0)
    half = cfg.window // 2
    pooled = [np.concatenate(segs[max(0, i - half) : i + half + 1]) for i in range(n)]  # dashes move along their line
    for _ in range(2):  # the lane lines of each frame, then again around their own median crossing
        found = [fl for fl in (frame_lines(s, first, size, i) for i, s in enumerate(pooled)) if fl is not None]
        found = [fl for fl in found if abs(fl.vanishing_point[1] - first[1]) < 0.05 * h and abs(fl.vanishing_point[0] - first[0]) < 0.1 * w]
        if len(found) < needed:
            break
        first = np.median([fl.vanishing_point for fl in found], axis=0)
    if found:
        width = np.median([fl.width_px for fl in found])
        found = [fl for fl in found if abs(fl.width_px / width - 1) <= 0.2]
    used = tuple(fl.index for fl in found)
    if len(found) < needed:
        return None, RoadEstimate(f"no lane lines seen: both lines of the lane in {len(found)} of {n} frames (need {needed})", size, n, used)
    vp = np.array([fl.vanishing_point for fl in found])
    widths = np.array([fl.width_px for fl in found])
    centres = np.array([fl.centre_px for fl in found])

    def view_of(vx, vy, width, centre):
        if not vy < h - 10:
            return None
        left = _line_through((vx, vy), (centre - width / 2, h))
        right = _line_through((vx, vy), (centre + width / 2, h))
        ww, wh = cfg.warped_size or (w // 2, h // 2)
        return _view_from_lines(left, right, size, vy + cfg.top * (h - vy), (ww, wh), cfg.margin, cfg.lane_width_m), left, right

    vx, vy = np.median(vp, axis=0)
    made = view_of(vx, vy, np.median(widths), np.median(centres))
    if made is None:
        return None, RoadEstimate("the lane lines do not meet above the bottom row", size, n, used)
    view, left, right = made
    per_frame = {}  # frame position -> metres per pixel along the road
    for fl in found:
        period = _frame_period(frames[fl.index], view)
        if period is not None:
            per_frame[fl.index] = cfg.dash_period_m / period
    if len(per_frame) < max(cfg.min_dash_frames, needed // 2):
        reason = f"no lane dashes seen (a period in {len(per_frame)} of {len(found)} frames): the scale along the road is unknown"
        return None, RoadEstimate(reason, size, n, used, len(per_frame), (float(vx), float(vy)), left, right, view.xm_per_px,
                                  lane_width_m=cfg.lane_width_m, dash_period_m=cfg.dash_period_m)
    ym_frames = np.array(list(per_frame.values()))
    ym = float(np.median(ym_frames))
    view = view.replace(ym_per_px=ym)
    rng = np.random.default_rng(cfg.seed)
    boot = {"vanishing_y_px": [], "lane_width_px": [], "ym_per_px": []}
    for _ in range(cfg.bootstrap):
        pick = rng.integers(0, len(found), len(found))
        boot["vanishing_y_px"].append(np.median(vp[pick, 1]))
        boot["lane_width_px"].append(np.median(widths[pick]))
        boot["ym_per_px"].append(np.median(rng.choice(ym_frames, len(ym_frames))))
    interval = {k: tuple(float(q) for q in np.percentile(v, [5, 95])) for k, v in boot.items()}
    spread = {
        "vanishing_x_px": _iqr(vp[:, 0]),
        "vanishing_y_px": _iqr(vp[:, 1]),
        "lane_width_px": _iqr(widths),
        "ym_rel": _iqr(ym_frames) / ym,
    }
    height_m, focal, pitch = _implied_camera(view, (vx, vy), float(np.median(widths)), cfg.lane_width_m, camera)
    estimate = RoadEstimate(
        None, size, n, used, len(per_frame), (float(vx), float(vy)), left, right, view.xm_per_px, ym, spread, interval,
        height_m, focal, pitch, cfg.lane_width_m, cfg.dash_period_m,
    )
    return view, estimate


def _iqr(v) -> float:
    q1, q3 = np.percentile(v, [25, 75])
    return float(q3 - q1)


def _line_through(p, q) -> tuple[float, float]:
    """``(a, b)`` of ``x = a*y + b`` through two points ``(x, y)``."""
    a = (q[0] - p[0]) / (q[1] - p[1])
    return float(a), float(p[0] - a * p[1])


def _frame_period(frame: np.ndarray, view: BirdsEye) -> float | None:
    """Dash-to-dash period (warped pixels) of the dashed lane line(s) of one frame, or None."""
    import cv2

    warped = cv2.warpPerspective(paint_mask(frame) * 255, view.M, view.warped_size, flags=cv2.INTER_LINEAR)
    binary = (warped > 127).view(np.uint8)
    ww, wh = view.warped_size
    hist = binary[wh // 3 :].sum(axis=0)
    periods = []
    for x in (view.dst[0, 0], view.dst[3, 0]):
        lo, hi = int(max(0, x - 0.1 * ww)), int(min(ww, x + 0.1 * ww))
        if hi <= lo or not hist[lo:hi].any():
            continue
        p = _dash_period(binary, lo + int(np.argmax(hist[lo:hi])))
        if p is not None:
            periods.append(p)
    return float(np.median(periods)) if periods else None


def _implied_camera(view: BirdsEye, vp, width_px: float, lane_width_m: float, camera) -> tuple[float, float, float]:
    """Height (m), focal length (px) and pitch (degrees, down) of a level pinhole camera with this view."""
    w, h = view.image_size
    vx, vy = vp
    height = lane_width_m * (h - vy) / width_px
    rows = np.array([h, vy + 0.3 * (h - vy)])
    d = view.ground_distance(np.c_[[vx, vx], rows])
    focal = (d[1] - d[0]) / (height * (1 / (rows[1] - vy) - 1 / (rows[0] - vy)))
    cy = camera.matrix[1, 2] if camera is not None else h / 2
    f_pitch = camera.matrix[1, 1] if camera is not None else focal
    return float(height), float(focal), float(math.degrees(math.atan2(cy - vy, f_pitch)))


def estimate_birds_eye_from_video(
    path: str | os.PathLike, camera=None, *, seconds: float = 10.0, max_frames: int = 60, start: int = 0, **kwargs
) -> tuple[BirdsEye | None, RoadEstimate]:
    """:func:`estimate_birds_eye` on :func:`sample_frames` of a video (keyword arguments go to the former)."""
    _, frames = sample_frames(path, seconds=seconds, max_frames=max_frames, start=start)
    if not frames:
        return None, RoadEstimate(f"{path}: no frames", (0, 0), 0)
    return estimate_birds_eye(frames, camera, **kwargs)


# --- camera files -------------------------------------------------------------------------------


def camera_from_estimate(birds_eye: BirdsEye, estimate: RoadEstimate | None = None, camera=None):
    """A :class:`~vehicle_detection.camera.Camera` carrying ``birds_eye``, to save and reuse.

    Parameters
    ----------
    birds_eye : BirdsEye
    estimate : RoadEstimate, optional
        Supplies the focal length of the camera matrix (else the frame width).
    camera : Camera, optional
        The camera the frames were undistorted with: kept, with ``birds_eye`` added.

    Returns
    -------
    Camera
        Without ``camera``: no lens distortion (undistortion changes nothing) and a pinhole
        matrix with the principal point at the image centre.
    """

    if camera is not None:
        return camera.replace(birds_eye=birds_eye)
    w, h = birds_eye.image_size
    f = estimate.focal_px if estimate is not None and estimate.focal_px else float(w)
    matrix = [[f, 0.0, w / 2], [0.0, f, h / 2], [0.0, 0.0, 1.0]]
    return Camera((w, h), matrix, np.zeros(5), birds_eye=birds_eye)


def save_estimate(
    path: str | os.PathLike, birds_eye: BirdsEye, estimate: RoadEstimate, camera=None, *, overwrite: bool = False, inputs: Sequence = ()
) -> Path:
    """Write the estimate as a camera file (``--camera`` and :meth:`Camera.load` read it), atomically.

    The file is :meth:`Camera.to_dict` of :func:`camera_from_estimate` plus a ``road_estimate``
    entry (:meth:`RoadEstimate.to_dict`: the frames and the uncertainty), which loading ignores.
    """
    d = camera_from_estimate(birds_eye, estimate, camera).to_dict()
    d["road_estimate"] = estimate.to_dict()
    text = json.dumps(d, indent=1) + "\n"
    with atomic_output(path, overwrite=overwrite, inputs=inputs) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def road_transform(path: str | os.PathLike, camera=None, **kwargs) -> tuple[BirdsEye | None, RoadEstimate]:
    """The bird's-eye transform for a video: the camera file's when it has one, else estimated from the video.

    Parameters
    ----------
    path : path-like
        The video.
    camera : Camera, optional
        Loaded from a camera file; its ``birds_eye`` wins. Without one, the footage is undistorted
        with it before the estimate.
    **kwargs
        Passed to :func:`estimate_birds_eye_from_video`.

    Returns
    -------
    birds_eye : BirdsEye or None
        None when neither the camera file nor the footage gives one: run without lanes
        (``estimate.reason`` says why).
    estimate : RoadEstimate
        ``source`` is ``"camera file"`` when the camera's transform was used.
    """
    if camera is not None and camera.birds_eye is not None:
        return camera.birds_eye, RoadEstimate(None, camera.birds_eye.image_size, 0, source="camera file")
    return estimate_birds_eye_from_video(path, camera, **kwargs)


# --- figure -------------------------------------------------------------------------------------


def road_figure(frames: Sequence[np.ndarray], birds_eye: BirdsEye, estimate: RoadEstimate, *, lanes=None, detections=None, titles=None,
                distances=None):
    """A figure of a road estimate: frames with the lane and the distances, the warped view, and distances over time.

    Parameters
    ----------
    frames : sequence of ndarray of uint8, shape (H, W, 3)
        A few frames to show (2 to 4), as the transform sees them (undistorted if it was).
    birds_eye : BirdsEye
    estimate : RoadEstimate
        Its lines and vanishing point are drawn on the first frame.
    lanes : sequence of Lane or None, optional
        The lane of each frame (:class:`~vehicle_detection.lanes.LaneTracker`), drawn.
    detections : sequence of Detections, optional
        Boxes of each frame, labelled with ``data["distance_m"]`` when present.
    titles : sequence of str, optional
    distances : mapping of str to (ndarray, ndarray), optional
        Curves ``label -> (frames, distance_m)`` for a panel of distances over time.

    Returns
    -------
    matplotlib.figure.Figure
    """
    plt = require("matplotlib.pyplot", "notebooks", "the road figure")


    k = len(frames)
    extra = 1 + (distances is not None)
    fig, axes = plt.subplots(1, k + extra, figsize=(4.2 * (k + extra), 3.2), squeeze=False)
    axes = axes[0]
    h = frames[0].shape[0]
    for i, frame in enumerate(frames):
        ax = axes[i]
        shown = frame
        if lanes is not None:
            shown = draw_lane(frame, lanes[i], birds_eye) if lanes[i] is not None else frame
        ax.imshow(shown)
        if detections is not None and len(detections[i]):
            dist = detections[i].data.get("distance_m")
            for j, (x1, y1, x2, y2) in enumerate(detections[i].xyxy):
                ax.add_patch(plt.Rectangle((x1, y1), x2 - x1, y2 - y1, fill=False, color="lime", lw=1.2))
                if dist is not None and np.isfinite(dist[j]):
                    ax.text(x1, y1 - 3, f"{dist[j]:.0f} m", color="lime", fontsize=7, va="bottom")
        if i == 0 and estimate.ok and estimate.left_line is not None:
            vx, vy = estimate.vanishing_point
            ys = np.array([vy, h])
            for line in (estimate.left_line, estimate.right_line):
                ax.plot(np.polyval(line, ys), ys, color="yellow", lw=0.8, ls="--")
            ax.plot([vx], [vy], "+", color="red", ms=8)
        ax.set_title(titles[i] if titles is not None else f"frame {i}", fontsize=8)
        ax.set_axis_off()
    ax = axes[k]
    ax.imshow(birds_eye.warp(frames[0]))
    ww, wh = birds_eye.warped_size
    for x in (birds_eye.dst[0, 0], birds_eye.dst[3, 0]):
        ax.axvline(x, color="yellow", lw=0.8, ls="--")
    ticks = np.arange(0, wh * birds_eye.ym_per_px, 10.0)
    ax.set_yticks(wh - ticks / birds_eye.ym_per_px, [f"{t:.0f}" for t in ticks], fontsize=7)
    ax.set_xticks([])
    ax.set_ylabel("metres beyond the bottom row", fontsize=7)
    ax.set_title(f"bird's-eye view ({100 * birds_eye.xm_per_px:.1f} x {100 * birds_eye.ym_per_px:.1f} cm/px)", fontsize=8)
    if distances is not None:
        ax = axes[k + 1]
        for label, (fr, d) in distances.items():
            ax.plot(fr, d, ".-", ms=2, lw=0.8, label=label)
        ax.set_xlabel("frame", fontsize=8)
        ax.set_ylabel("distance ahead (m)", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.legend(fontsize=7)
        ax.set_title("distances of tracked cars", fontsize=8)
    fig.tight_layout()
    return fig
