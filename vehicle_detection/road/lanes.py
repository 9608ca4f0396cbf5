"""Lane finding on the road plane.

The steps, all pure functions except the small stateful :class:`LaneTracker`:

1. :func:`birds_eye_from_straight`: the perspective transform to a bird's-eye view, derived from
   (undistorted) frames of a straight road. In each frame the two lane lines are found as
   straight lines ``x = a*y + b`` (thresholded lane pixels in a trapezoid in front of the car,
   Hough segments split by slope, a least-squares line through each side); the lines of all
   frames are averaged. The source quadrilateral is where the two lines cross the rows
   ``top_row`` (62.5 % of the height) and the bottom row; it is mapped onto a rectangle, so the
   lines come out vertical and parallel. Metres per pixel: across, 3.7 m (a US lane) over the
   distance between the two warped lines; along, 12 m (a US lane dash, 3 m, plus its gap, 9 m)
   over the dash-to-dash period measured in the warped straight frames (autocorrelation of the
   dashed line's profile; the dashes' own blurred ends would make them look longer).
2. :func:`lane_binary`: colour (HLS saturation, bright white) OR gradient (Sobel x of lightness)
   thresholds, computed on the warped image (lines are vertical there, and it is smaller).
3. :func:`vertical_paint` keeps the pixels that run along the road for at least half a metre
   (lines are near-vertical in the warped view; a bonnet's edge and a windscreen's reflections
   are not). :func:`find_lane_pixels` (sliding windows from the histogram peaks) or
   :func:`search_around` (a band around the previous fit), then :func:`fit_lanes`: second-order
   polynomials ``x = A*y^2 + B*y + C`` in warped pixels, and :func:`lane_sane` (roughly parallel,
   plausible width). On the paint along the road only, when the two separate fits are not sane
   (a line seen as one or two short dashes, whose own parabola swings away),
   :func:`fit_parallel_lanes` fits both lines at once as one shape at two offsets (a straight
   line when the paint spans less than half the view). :class:`LaneTracker` keeps the fits of
   all the paint where the two searches agree, else those of the paint along the road.
4. :class:`LaneTracker`: averages the last good fits; a frame whose fit fails keeps the last good
   fit for ``max_misses`` frames, after which no lane is reported (and none drawn) until a new
   good fit.
5. :func:`lane_measures`: radius of curvature and the vehicle's offset from the lane centre in
   metres (positive: the car is right of centre).
6. :meth:`BirdsEye.ground_distance`: a ground point's distance ahead through the ground-plane
   homography (:class:`~vehicle_detection.road.distance.DistanceTracker` measures the boxes
   with it).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property

import cv2
import numpy as np

from ..errors import InputError
from ..footage.overlays import active_area
from ..io.images import as_rgb_uint8
from ..viz.drawing import draw_caption

__all__ = [
    "BirdsEye",
    "birds_eye_from_straight",
    "lane_binary",
    "find_lane_pixels",
    "search_around",
    "vertical_paint",
    "fit_lanes",
    "fit_parallel_lanes",
    "lane_sane",
    "lane_measures",
    "Lane",
    "LaneTracker",
    "draw_lane",
    "lane_row",
    "LANE_WIDTH_M",
    "DASH_LENGTH_M",
]

LANE_WIDTH_M = 3.7
DASH_LENGTH_M = 3.0
#: A US lane dash (3 m, 10 ft) and the gap to the next (9 m, 30 ft).
DASH_PERIOD_M = 12.0
#: Smallest side of a bird's-eye view, pixels.
MIN_WARPED_SIDE = 16
#: Plausible extent of a bird's-eye view across and along the road, metres.
VIEW_SPAN_M = (1.0, 1000.0)
#: Smallest area of the lane quadrilateral, as a share of its frame.
MIN_QUAD_AREA = 0.01


def _quad_problem(name: str, quad: np.ndarray, w: float, h: float, slack_x: float) -> str:
    """Why ``quad`` (bottom-left, top-left, top-right, bottom-right) is no lane region of a ``w x h`` frame."""
    q = np.asarray(quad, dtype=np.float64)
    if q[:, 0].min() < -slack_x or q[:, 0].max() > w + slack_x or q[:, 1].min() < 0 or q[:, 1].max() > h:
        where = f"inside the {w:g}x{h:g} frame" + (f" (or at most {slack_x:g} px beyond its sides)" if slack_x else "")
        return f"{name} = {q.tolist()} must lie {where}"
    (blx, bly), (tlx, tly), (trx, try_), (brx, bry) = q
    if not (bly > tly and bry > try_ and brx > blx and trx > tlx):
        return f"{name} = {q.tolist()} must be bottom-left, top-left, top-right, bottom-right (image y grows downward)"
    edges = np.roll(q, -1, axis=0) - q
    cross = edges[:, 0] * np.roll(edges, -1, axis=0)[:, 1] - edges[:, 1] * np.roll(edges, -1, axis=0)[:, 0]
    area = 0.5 * abs(float(np.sum(q[:, 0] * np.roll(q[:, 1], -1) - np.roll(q[:, 0], -1) * q[:, 1])))
    if not (np.all(cross > 0) or np.all(cross < 0)) or area < MIN_QUAD_AREA * w * h:
        return f"{name} = {q.tolist()} must be a convex quadrilateral covering at least {MIN_QUAD_AREA:.0%} of the frame"
    return ""


@dataclass(frozen=True, eq=False)
class BirdsEye:
    """A perspective transform from camera pixels to a bird's-eye view of the road plane.

    Attributes
    ----------
    src, dst : ndarray, shape (4, 2)
        Corresponding points (camera image, warped image): bottom-left, top-left, top-right,
        bottom-right.
    image_size, warped_size : (int, int)
        ``(width, height)`` of the camera images and of the warped view.
    xm_per_px, ym_per_px : float
        Metres per warped pixel across and along the road.

    Raises
    ------
    ValueError
        Unless the transform is plausible; the message starts with the field at fault:

        - ``src`` is a convex quadrilateral in that corner order covering at least
          :data:`MIN_QUAD_AREA` of the camera frame and lying inside it (the bottom corners may
          lie up to half a frame width beyond its sides), no wider at its top than at its bottom;
          ``dst`` likewise inside the warped view;
        - the transform is invertible, and ``src`` and the bottom centre of the frame lie on the
          ground side of its horizon (so the lane region maps onto ``dst``, inside the view);
        - ``warped_size`` is at least :data:`MIN_WARPED_SIDE` pixels and at most 4 times the
          camera image each way, and the view spans :data:`VIEW_SPAN_M` metres across and along.
    """

    src: np.ndarray
    dst: np.ndarray
    image_size: tuple[int, int]
    warped_size: tuple[int, int]
    xm_per_px: float
    ym_per_px: float

    def __post_init__(self) -> None:
        set_ = object.__setattr__
        for name in ("src", "dst"):
            a = np.array(getattr(self, name), dtype=np.float64)
            if a.shape != (4, 2) or not np.all(np.isfinite(a)):
                raise ValueError(f"{name} must be 4 points (x, y) of finite numbers")
            a = a.astype(np.float32)
            a.setflags(write=False)
            set_(self, name, a)
        set_(self, "image_size", tuple(int(v) for v in self.image_size))
        set_(self, "warped_size", tuple(int(v) for v in self.warped_size))
        set_(self, "xm_per_px", float(self.xm_per_px))
        set_(self, "ym_per_px", float(self.ym_per_px))
        problem = self._implausible()
        if problem:
            raise ValueError(problem)

    def _implausible(self) -> str:
        """Why this cannot be a camera's view of the road ("" if it can); starts with the field at fault."""
        import cv2

        if len(self.image_size) != 2 or min(self.image_size) < 1:
            return f"image_size must be (width, height) of at least 1 pixel; got {self.image_size}"
        if len(self.warped_size) != 2:
            return f"warped_size must be (width, height); got {self.warped_size}"
        (w, h), (ww, wh) = self.image_size, self.warped_size
        if not (MIN_WARPED_SIDE <= ww <= 4 * w and MIN_WARPED_SIDE <= wh <= 4 * h):
            return (
                f"warped_size {'x'.join(map(str, self.warped_size))} must be at least {MIN_WARPED_SIDE} pixels and at most "
                f"4 times the camera image ({4 * w}x{4 * h}) each way"
            )
        for name, per_px, n in (("xm_per_px", self.xm_per_px, ww), ("ym_per_px", self.ym_per_px, wh)):
            lo, hi = VIEW_SPAN_M
            if not (math.isfinite(per_px) and per_px > 0 and lo <= per_px * n <= hi):
                return f"{name} = {per_px:.6g} m makes the warped view {per_px * n:.6g} m {'across' if name[0] == 'x' else 'long'} ({lo:g} to {hi:g} m expected)"
        # The lane region: a convex quadrilateral, in the documented corner order, inside the frame
        # (the bottom corners may lie beyond the sides: lane lines can leave the picture there) ...
        problem = _quad_problem("src", self.src, w, h, w / 2) or _quad_problem("dst", self.dst, ww, wh, 0.0)
        if problem:
            return problem
        (blx, _), (tlx, _), (trx, _), (brx, _) = self.src.astype(np.float64)
        if trx - tlx > brx - blx:
            return f"src = {self.src.tolist()}: the lane must narrow towards its top (its lines meet at the horizon above it)"
        # ... mapped by an invertible transform onto its place in the warped view, on the ground
        # side of the horizon, as is the bottom centre of the frame (the camera's own position).
        try:
            M, Minv = self.M, self.Minv  # cached for the object's use
        except cv2.error:
            return "src: the transform from src to dst is not invertible"
        if not (np.all(np.isfinite(M)) and np.all(np.isfinite(Minv)) and np.linalg.cond(M) < 1e12):
            return "src: the transform from src to dst is not invertible"
        ground = self.to_warped(np.r_[self.src, [[w / 2, h]]])
        if not np.all(np.isfinite(ground)) or np.abs(ground[:4] - self.dst).max() > 0.5:
            return "src: the lane region and the bottom of the frame are not all on the ground side of the transform's horizon"
        return ""

    @cached_property
    def M(self) -> np.ndarray:
        return cv2.getPerspectiveTransform(self.src, self.dst)

    @cached_property
    def Minv(self) -> np.ndarray:
        return cv2.getPerspectiveTransform(self.dst, self.src)

    def warp(self, image: np.ndarray) -> np.ndarray:
        return cv2.warpPerspective(image, self.M, self.warped_size, flags=cv2.INTER_LINEAR)

    def to_warped(self, points) -> np.ndarray:
        """Camera pixels ``(n, 2)`` -> warped pixels ``(n, 2)`` (NaN beyond the horizon)."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        h = np.c_[p, np.ones(len(p))] @ self.M.T
        with np.errstate(divide="ignore", invalid="ignore"):
            out = h[:, :2] / h[:, 2:3]
        w, ht = self.image_size
        sign = np.sign((self.M @ [w / 2, ht, 1.0])[2])  # the sign of w for a ground point
        out[h[:, 2] * sign <= 1e-12] = np.nan  # at or above the horizon: not on the ground
        return out

    @property
    def vehicle_x(self) -> float:
        """Warped x of the camera's centre line (the bottom-centre of the camera image)."""
        w, h = self.image_size
        return float(self.to_warped([[w / 2, h]])[0, 0])

    def ground_distance(self, points) -> np.ndarray:
        """Distance ahead in metres of ground points (camera pixels), from the bottom edge of the frame.

        Points at or above the horizon give NaN.
        """
        y = self.to_warped(points)[:, 1]
        return (self.warped_size[1] - y) * self.ym_per_px

    def to_dict(self) -> dict:
        return {
            "src": self.src.tolist(),
            "dst": self.dst.tolist(),
            "image_size": list(self.image_size),
            "warped_size": list(self.warped_size),
            "xm_per_px": float(self.xm_per_px),
            "ym_per_px": float(self.ym_per_px),
        }

    def replace(self, **changes) -> BirdsEye:
        """A copy with some fields changed."""
        from dataclasses import replace

        return replace(self, **changes)

    @classmethod
    def from_dict(cls, d: dict) -> BirdsEye:
        return cls(d["src"], d["dst"], tuple(d["image_size"]), tuple(d["warped_size"]), float(d["xm_per_px"]), float(d["ym_per_px"]))


# --- thresholds --------------------------------------------------------------------------------


def lane_binary(rgb: np.ndarray, *, s_thresh=(170, 255), sx_thresh=(20, 100), white=200) -> np.ndarray:
    """Lane-line pixels: ``uint8`` 0/1, same height and width.

    HLS saturation in ``s_thresh`` (yellow and white paint), or lightness > ``white`` in all
    three RGB channels, or the scaled Sobel x of the lightness in ``sx_thresh``.
    """
    rgb = np.ascontiguousarray(as_rgb_uint8(rgb))  # grey converted, anything else refused in one line
    hls = cv2.cvtColor(rgb, cv2.COLOR_RGB2HLS)
    lum = np.ascontiguousarray(hls[..., 1])
    dx = cv2.Sobel(lum, cv2.CV_16S, 1, 0, ksize=3)
    top = max(float(-dx.min()), float(dx.max()), 1.0)
    sobel = cv2.convertScaleAbs(dx, alpha=255.0 / top)  # |d/dx| scaled to the frame's strongest edge
    out = cv2.inRange(hls, (0, 61, s_thresh[0]), (255, 255, s_thresh[1]))  # saturated paint, not dark
    out |= cv2.inRange(sobel, sx_thresh[0], sx_thresh[1])
    out |= cv2.inRange(rgb, (white + 1,) * 3, (255, 255, 255))
    return (out > 0).view(np.uint8)


# --- the bird's-eye transform -----------------------------------------------------------------


def _straight_lines(rgb: np.ndarray, top_row: int) -> tuple[np.ndarray, np.ndarray]:
    """``(a, b)`` of ``x = a*y + b`` for the left and right lane lines of a straight-road frame."""
    h, w = rgb.shape[:2]
    binary = lane_binary(rgb, sx_thresh=(40, 255))
    mask = np.zeros((h, w), np.uint8)
    roi = np.array([[0.10 * w, h], [0.45 * w, top_row], [0.55 * w, top_row], [0.95 * w, h]], np.int32)
    cv2.fillPoly(mask, [roi], 1)
    binary &= mask
    segments = cv2.HoughLinesP(binary * 255, 2, np.pi / 180, 40, minLineLength=30, maxLineGap=20)
    if segments is None:
        raise InputError("no lane lines found in a straight-road frame")
    fits = []
    for side in (-1, 1):
        ys, xs, ws = [], [], []
        for x1, y1, x2, y2 in segments.reshape(-1, 4):
            if y1 == y2:
                continue
            slope = (x2 - x1) / (y2 - y1)  # dx/dy: negative on the left line, positive on the right
            if np.sign(slope) != side or not 0.3 < abs(slope) < 3:
                continue
            length = np.hypot(x2 - x1, y2 - y1)
            ys += [y1, y2]
            xs += [x1, x2]
            ws += [length, length]
        if len(ys) < 4:
            raise InputError("a lane line was not found in a straight-road frame")
        fits.append(np.polyfit(ys, xs, 1, w=np.sqrt(ws)))
    return fits[0], fits[1]


def _dash_period(warped_binary: np.ndarray, x: float, half_width: int = 12) -> float | None:
    """Dash-to-dash period (pixels) along column ``x`` of a warped binary image, or None (a solid line).

    The first clear peak of the autocorrelation of the column's on/off profile: the start of
    one dash to the start of the next (one dash plus one gap), which the blurred far ends of the
    dashes do not bias, unlike a dash's own length.
    """
    lo, hi = int(max(0, x - half_width)), int(min(warped_binary.shape[1], x + half_width))
    on = (warped_binary[:, lo:hi].sum(axis=1) >= 3).astype(np.float64)
    if on.mean() > 0.8 or on.mean() < 0.1:
        return None  # solid line, or nothing
    prof = on - on.mean()
    ac = np.correlate(prof, prof, "full")[len(prof) - 1 :]
    ac /= ac[0]
    lags = np.arange(len(ac))
    ok = (lags >= 20) & (lags <= len(prof) * 0.6)
    peaks = [i for i in lags[ok] if ac[i] > 0.2 and ac[i] >= ac[i - 1] and ac[i] >= ac[min(i + 1, len(ac) - 1)]]
    return float(peaks[0]) if peaks else None


def birds_eye_from_straight(
    frames, camera=None, *, top_row: float = 0.625, warped_size: tuple[int, int] | None = None, margin: float = 0.25
) -> BirdsEye:
    """Derive the bird's-eye transform from frames of a straight road (see the module docstring).

    Parameters
    ----------
    frames : iterable of RGB ndarray
        Frames with both lane lines straight ahead (the project's ``straight_lines*.jpg``).
    camera : Camera, optional
        Undistort the frames first (do: the transform applies to undistorted frames).
    top_row : float
        Top of the source quadrilateral as a fraction of the height (below the horizon).
    warped_size : (int, int), optional
        Default: half the camera image's width and height.
    margin : float
        The warped lines sit at ``margin`` and ``1 - margin`` of the warped width.
    """
    frames = [camera.undistort(f) if camera is not None else f for f in frames]
    if not frames:
        raise InputError("no straight-road frames")
    h, w = frames[0].shape[:2]
    ww, wh = warped_size or (w // 2, h // 2)
    top = int(round(top_row * h))
    lefts, rights = zip(*(_straight_lines(f, top) for f in frames))
    left, right = np.mean(lefts, axis=0), np.mean(rights, axis=0)
    provisional = _straight_view(lambda: _view_from_lines(left, right, (w, h), top, (ww, wh), margin))
    xl, xr = provisional.dst[0, 0], provisional.dst[3, 0]
    periods = []
    for f in frames:
        binary = lane_binary(provisional.warp(f))
        for x in (xl, xr):
            d = _dash_period(binary, x)
            if d is not None:
                periods.append(d)
    if not periods:
        raise InputError("no lane dashes found in the straight-road frames; cannot derive metres per pixel along the road")
    return _straight_view(lambda: provisional.replace(ym_per_px=DASH_PERIOD_M / float(np.median(periods))))


def _view_from_lines(left, right, image_size, top: float, warped_size, margin: float, lane_width_m: float = LANE_WIDTH_M) -> BirdsEye:
    """The view that maps the quadrilateral between two lane lines and two rows onto a rectangle.

    ``left`` and ``right`` are ``(a, b)`` of ``x = a*y + b`` in camera pixels; the source corners
    are where they cross the rows ``top`` and the bottom row; the lines land at ``margin`` and
    ``1 - margin`` of the warped width, ``lane_width_m`` apart. Metres per pixel along the road
    are left at 1.0 (for the caller to measure).
    """
    w, h = image_size
    ww, wh = warped_size
    ys = np.array([h, top, top, h], float)
    src = np.c_[[np.polyval(left, h), np.polyval(left, top), np.polyval(right, top), np.polyval(right, h)], ys]
    xl, xr = margin * ww, (1 - margin) * ww
    dst = np.array([[xl, wh], [xl, 0], [xr, 0], [xr, wh]], float)
    return BirdsEye(src, dst, (w, h), (ww, wh), lane_width_m / (xr - xl), 1.0)


def _straight_view(make) -> BirdsEye:
    """``make()``, a view from straight-road frames: an implausible one is the frames' fault."""
    try:
        return make()
    except ValueError as exc:
        raise InputError(f"the straight-road frames give an implausible bird's-eye view: {exc}") from None


# --- lane pixels and fits ----------------------------------------------------------------------


def find_lane_pixels(
    binary: np.ndarray, *, n_windows: int = 9, margin: int | None = None, min_pix: int = 30, expected=(0.25, 0.75), band: float = 0.15
):
    """Sliding-window search: ``(left_x, left_y, right_x, right_y)`` pixel coordinates.

    The windows start at the column-histogram peaks of the lower half, searched within
    ``band`` (fraction of the width) of the ``expected`` line positions (fractions of the width;
    where :func:`birds_eye_from_straight` puts the lines), so a barrier or the next lane's line
    is not taken for the lane's own.
    """
    h, w = binary.shape
    margin = margin or max(8, w // 12)
    hist = binary[h // 2 :].sum(axis=0)
    bases = []
    for e in expected:
        lo, hi = int(max(0, (e - band) * w)), int(min(w, (e + band) * w))
        bases.append(lo + int(np.argmax(hist[lo:hi])))
    ys, xs = binary.nonzero()
    win_h = h // n_windows
    picked = [[], []]
    for side in (0, 1):
        x = bases[side]
        for i in range(n_windows):
            y_lo, y_hi = h - (i + 1) * win_h, h - i * win_h
            inside = np.flatnonzero((ys >= y_lo) & (ys < y_hi) & (xs >= x - margin) & (xs < x + margin))
            picked[side].append(inside)
            if len(inside) > min_pix:
                x = int(np.mean(xs[inside]))
    li, ri = np.concatenate(picked[0]), np.concatenate(picked[1])
    return xs[li], ys[li], xs[ri], ys[ri]


def search_around(binary: np.ndarray, left_fit, right_fit, *, margin: int | None = None):
    """Pixels within ``margin`` of the previous fits: ``(left_x, left_y, right_x, right_y)``."""
    margin = margin or max(8, binary.shape[1] // 16)
    ys, xs = binary.nonzero()
    lsel = np.abs(xs - np.polyval(left_fit, ys)) < margin
    rsel = np.abs(xs - np.polyval(right_fit, ys)) < margin
    return xs[lsel], ys[lsel], xs[rsel], ys[rsel]


def fit_lanes(lx, ly, rx, ry, *, min_pixels: int = 50):
    """Second-order fits ``x = A*y^2 + B*y + C`` of both lines, or None where too few pixels."""
    left = np.polyfit(ly, lx, 2) if len(lx) >= min_pixels and np.ptp(ly) > 10 else None
    right = np.polyfit(ry, rx, 2) if len(rx) >= min_pixels and np.ptp(ry) > 10 else None
    return left, right


def vertical_paint(binary: np.ndarray, min_rows: int) -> np.ndarray:
    """The pixels of a warped binary image that lie on vertical runs of at least ``min_rows`` rows.

    A morphological opening with a ``1 x min_rows`` column: lane paint, which runs along the
    road (near-vertical in the bird's-eye view), keeps its shape; a bonnet's edge, the rows of a
    car's shadow and the slanted streaks of a windscreen's reflections, a few rows high wherever
    they are crossed, are removed.

    Parameters
    ----------
    binary : ndarray of uint8, shape (H, W)
        0 or 1 (:func:`lane_binary` of a warped frame).
    min_rows : int
        Shortest vertical run kept; 1 or less keeps everything.

    Returns
    -------
    ndarray of uint8, shape (H, W)
        0 or 1.
    """
    if min_rows <= 1:
        return binary
    kernel = cv2.getStructuringElement(cv2.MORPH_RECT, (1, int(min_rows)))
    return cv2.morphologyEx(np.ascontiguousarray(binary, dtype=np.uint8), cv2.MORPH_OPEN, kernel)


def fit_parallel_lanes(lx, ly, rx, ry, height: int, *, min_pixels: int = 20, min_span_px: float = 20.0, quadratic_span: float = 0.5,
                       max_rms_px: float = 9.0, min_share: float = 0.5, rounds: int = 2):
    """Both lane lines fitted at once as one shape at two offsets, or ``(None, None)``.

    ``x = A*y^2 + B*y + C_left`` and ``x = A*y^2 + B*y + C_right`` (warped pixels), each line's
    pixels weighted as much in total as the other's, so a line seen as one short dash borrows
    its direction and curvature from the other instead of swinging away on its own. ``A`` is 0
    (straight lines) unless the paint spans at least ``quadratic_span`` of the view's height.
    Pixels farther from the fit than 2.5 robust standard deviations (at least 3 pixels) are
    dropped and the fit repeated, ``rounds`` times; each line must keep ``min_share`` of its
    pixels (a line's pixels lie mostly along it, a blotch's do not).

    Parameters
    ----------
    lx, ly, rx, ry : array_like
        Pixel coordinates of the left and the right line (:func:`find_lane_pixels`,
        :func:`search_around`).
    height : int
        Rows of the warped view.
    min_pixels : int
        Fewest pixels of each line, before and after the outliers are dropped.
    min_span_px : float
        Each line's pixels must span this many rows (a dash, not a speck).
    quadratic_span : float
        Share of the rows the paint must span for a curved fit.
    max_rms_px : float
        Largest root-mean-square distance of each line's kept pixels from its fitted line: the
        pixels must form a line, not a patch.
    min_share : float
        Share of each line's pixels that must be kept (not outliers).
    rounds : int
        Refits without the outliers.

    Returns
    -------
    left_fit, right_fit : ndarray of shape (3,), or None
        Coefficients as :func:`fit_lanes` gives them (the same ``A`` and ``B``), or both None
        when either line has too few pixels, too short a span or too loose a fit.
    """
    lx, ly, rx, ry = (np.asarray(v, dtype=np.float64).ravel() for v in (lx, ly, rx, ry))
    if len(lx) < min_pixels or len(rx) < min_pixels:
        return None, None
    x, y = np.r_[lx, rx], np.r_[ly, ry]
    right = np.r_[np.zeros(len(lx), bool), np.ones(len(rx), bool)]
    keep = np.ones(len(x), bool)
    for round_ in range(rounds + 1):
        n_left, n_right = int(np.sum(keep & ~right)), int(np.sum(keep & right))
        if min(n_left, n_right) < min_pixels:
            return None, None
        quadratic = np.ptp(y[keep]) >= quadratic_span * height
        design = np.stack(([y**2] if quadratic else []) + [y, (~right).astype(float), right.astype(float)], axis=1)
        sw = np.sqrt(np.where(right, 1.0 / n_right, 1.0 / n_left) * keep)
        coef = np.linalg.lstsq(design * sw[:, None], x * sw, rcond=None)[0]
        residual = x - design @ coef
        if round_ < rounds:
            keep = np.abs(residual) <= max(3.0, 2.5 * 1.4826 * float(np.median(np.abs(residual[keep]))))
    for side in (~right, right):
        sel = keep & side
        if np.sum(sel) < min_share * np.sum(side) or np.ptp(y[sel]) < min_span_px or np.sqrt(np.mean(residual[sel] ** 2)) > max_rms_px:
            return None, None
    a, b = (coef[0], coef[1]) if quadratic else (0.0, coef[0])
    return np.array([a, b, coef[-2]]), np.array([a, b, coef[-1]])


def lane_sane(left_fit, right_fit, birds_eye: BirdsEye, *, width_m=(2.8, 5.0), max_width_change_m: float = 1.0) -> bool:
    """Both fits present, of a plausible lane width, and roughly parallel (width nearly constant)."""
    if left_fit is None or right_fit is None:
        return False
    h = birds_eye.warped_size[1]
    y = np.linspace(0, h - 1, 8)
    widths = (np.polyval(right_fit, y) - np.polyval(left_fit, y)) * birds_eye.xm_per_px
    return bool(widths.min() >= width_m[0] and widths.max() <= width_m[1] and np.ptp(widths) <= max_width_change_m)


def _radius_m(fit, y_px: float, xm: float, ym: float) -> float:
    a, b = fit[0] * xm / ym**2, fit[1] * xm / ym
    y = y_px * ym
    if a == 0:
        return float("inf")
    return float((1 + (2 * a * y + b) ** 2) ** 1.5 / abs(2 * a))


def lane_measures(left_fit, right_fit, birds_eye: BirdsEye) -> tuple[float, float]:
    """``(radius of curvature m, offset m)`` at the bottom of the view.

    The radius is that of the lane's centre line; the offset is the camera centre's distance
    from the lane centre, positive when the car is right of centre.
    """
    h = birds_eye.warped_size[1]
    centre = (np.asarray(left_fit) + np.asarray(right_fit)) / 2
    radius = _radius_m(centre, h - 1, birds_eye.xm_per_px, birds_eye.ym_per_px)
    offset = (birds_eye.vehicle_x - np.polyval(centre, h - 1)) * birds_eye.xm_per_px
    return radius, float(offset)


@dataclass(frozen=True)
class Lane:
    """The lane of one frame: fits in warped pixels, radius and offset in metres."""

    left_fit: np.ndarray
    right_fit: np.ndarray
    radius_m: float
    offset_m: float
    fresh: bool  # fitted on this frame (False: the last good fit, kept)


@dataclass
class LaneTracker:
    """Lane fits over video frames, with smoothing and a bounded fallback.

    ``update(warped_binary)`` searches around the last fit (sliding windows when there is none,
    or after a miss), fits each line (:func:`fit_lanes`) and checks the fit with
    :func:`lane_sane`; then again on the paint that runs along the road only
    (:func:`vertical_paint`, runs of at least ``min_run_m`` metres: no bonnet edge, no slanted
    glare), this time fitting both lines at once (:func:`fit_parallel_lanes`) where their own
    fits are not sane. The first fit is kept when the two agree within ``agree_m`` metres at the
    bottom row and halfway up (clean footage: the fits of all its paint, as before), the second
    when they do not or the first is missing (``min_run_m = 0``: the first only). It returns the
    average of the last ``smooth`` good fits. A frame whose fit fails gets the last good lane
    (``fresh=False``) for ``max_misses`` frames; after that, None: no lane is drawn until a good
    fit comes back.
    """

    birds_eye: BirdsEye
    smooth: int = 5
    max_misses: int = 5
    min_run_m: float = 0.5
    agree_m: float = 0.2
    _fits: deque = field(default_factory=deque, repr=False)
    _misses: int = 0

    def reset(self) -> None:
        self._fits.clear()
        self._misses = 0

    def _search(self, binary: np.ndarray, fallback: bool) -> tuple:
        """Fits of the two lines in ``binary``: around the last fit, else from sliding windows;
        with ``fallback``, both lines at once (:func:`fit_parallel_lanes`) where their own fits are not sane."""
        view = self.birds_eye
        searches = [lambda: search_around(binary, *self._mean_fit())] if self._fits and self._misses == 0 else []
        for pixels in (*searches, lambda: find_lane_pixels(binary)):
            pixels = pixels()
            left, right = fit_lanes(*pixels)
            if not lane_sane(left, right, view) and fallback:  # a dash of 2 m at least; pixels within 0.15 m of their line (rms)
                left, right = fit_parallel_lanes(*pixels, view.warped_size[1], min_span_px=2.0 / view.ym_per_px, max_rms_px=0.15 / view.xm_per_px)
            if lane_sane(left, right, view):
                return left, right
        return None, None

    def _mean_fit(self) -> tuple[np.ndarray, np.ndarray]:
        return np.mean([f[0] for f in self._fits], axis=0), np.mean([f[1] for f in self._fits], axis=0)

    def _choose(self, warped_binary: np.ndarray) -> tuple:
        """The fits of all the paint, or of the paint that runs along the road where the two differ."""
        view = self.birds_eye
        fits = self._search(warped_binary, fallback=False)
        if self.min_run_m <= 0:
            return fits
        along = self._search(vertical_paint(warped_binary, int(round(self.min_run_m / view.ym_per_px))), fallback=True)
        if fits[0] is None or along[0] is None:
            return along if fits[0] is None else fits
        h = view.warped_size[1]
        y = np.array([h - 1, (h - 1) / 2])  # the bottom row and halfway up
        apart = max(float(np.abs(np.polyval(fits[k], y) - np.polyval(along[k], y)).max()) for k in (0, 1)) * view.xm_per_px
        return fits if apart <= self.agree_m else along

    def update(self, warped_binary: np.ndarray) -> Lane | None:
        left, right = self._choose(warped_binary)
        if lane_sane(left, right, self.birds_eye):
            self._fits.append((left, right))
            while len(self._fits) > self.smooth:
                self._fits.popleft()
            self._misses = 0
            fresh = True
        else:
            self._misses += 1
            fresh = False
            if not self._fits or self._misses > self.max_misses:
                self._fits.clear()
                return None
        lf, rf = np.mean([f[0] for f in self._fits], axis=0), np.mean([f[1] for f in self._fits], axis=0)
        radius, offset = lane_measures(lf, rf, self.birds_eye)
        return Lane(lf, rf, radius, offset, fresh)

    def step(self, frame: np.ndarray) -> Lane | None:
        """Warp and threshold an (undistorted) RGB frame, then :meth:`update`."""
        return self.update(lane_binary(self.birds_eye.warp(frame)))


def lane_row(frame: int, lane: Lane | None) -> tuple[int, float | None, float | None]:
    """The row of frame ``frame`` in the lanes CSV (:func:`~vehicle_detection.io.write_lanes_csv`):
    ``(frame, radius_m, offset_m)``, with None for both when no lane was found."""
    return (frame, lane.radius_m, lane.offset_m) if lane is not None else (frame, None, None)


def draw_lane(
    image: np.ndarray,
    lane: Lane | None,
    birds_eye: BirdsEye,
    *,
    color=(0, 200, 255),
    alpha: float = 0.3,
    area: Sequence[int] | None = None,
) -> np.ndarray:
    """The lane area filled on a copy of the (undistorted) frame, with radius and offset written.

    Parameters
    ----------
    image : ndarray of uint8, shape (H, W, 3)
        RGB frame; it is not modified.
    lane : Lane or None
        None writes ``lane: not found``.
    birds_eye : BirdsEye
        The view the lane was fitted in.
    color : sequence of 3 int, default (0, 200, 255)
        RGB fill of the lane.
    alpha : float, default 0.3
        The fill's opacity.
    area : sequence of 4 int, optional
        ``(x1, y1, x2, y2)`` of the picture inside black bars: the lane and the caption are drawn
        inside it only. Default: the picture of ``image`` itself
        (:func:`~vehicle_detection.footage.overlays.active_area`).

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
        The caption on a dark panel (:func:`~vehicle_detection.viz.drawing.draw_caption`).
    """
    out = np.array(image, copy=True)
    h, w = out.shape[:2]
    ax1, ay1, ax2, ay2 = active_area(out) if area is None else (int(v) for v in area)
    ax1, ay1, ax2, ay2 = max(ax1, 0), max(ay1, 0), min(ax2, w), min(ay2, h)
    if lane is None:
        return draw_caption(out, ["lane: not found"], area=(ax1, ay1, ax2, ay2), out=out)
    ww, wh = birds_eye.warped_size
    y = np.linspace(0, wh - 1, 24)
    pts = np.r_[np.c_[np.polyval(lane.left_fit, y), y], np.c_[np.polyval(lane.right_fit, y), y][::-1]]
    cam = cv2.perspectiveTransform(pts.reshape(-1, 1, 2).astype(np.float64), birds_eye.Minv).reshape(-1, 2)
    poly = np.round(cam).astype(np.int32)
    x0, y0 = np.maximum(poly.min(axis=0), [ax1, ay1])
    x1, y1 = np.minimum(poly.max(axis=0) + 1, [ax2, ay2])
    if x1 > x0 and y1 > y0:  # blend only the polygon's bounding box inside the picture
        roi = out[y0:y1, x0:x1]
        overlay = roi.copy()
        cv2.fillPoly(overlay, [poly - [x0, y0]], color)
        out[y0:y1, x0:x1] = cv2.addWeighted(overlay, alpha, roi, 1 - alpha, 0)
    radius = "straight" if lane.radius_m > 10_000 else f"{lane.radius_m:,.0f} m"
    side = "right" if lane.offset_m > 0 else "left"
    lines = [f"radius of curvature: {radius}", f"{abs(lane.offset_m):.2f} m {side} of lane centre"]
    return draw_caption(out, lines, area=(ax1, ay1, ax2, ay2), out=out)
