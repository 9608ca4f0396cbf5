"""Box refinement: from a hot window's features, where the vehicle's four edges are; and a box's sides fitted to the vehicle's edges.

A window the classifier accepts rarely frames its vehicle: the windows are square, sit on a
coarse grid, and come in a few sizes, while vehicles are wider than tall and of every size. As
in the bounding-box regression of deformable part models (Felzenszwalb et al., PAMI 2010) and
R-CNN, a linear model predicts, from the same feature vector the classifier scored, the offsets
of the vehicle's edges from the window's edges in units of the window's size:

    d = [(x1* - x1) / w, (y1* - y1) / h, (x2* - x2) / w, (y2* - y2) / h]

:func:`fit_box_regressor` learns it (ridge regression) from windows jittered around labelled
vehicles in real frames and, optionally, as R-CNN learns its regression from its own proposals,
from the windows the search accepts in those frames that the jitter never draws
(:func:`hot_window_targets`, :func:`beyond_jitter`);
:meth:`BoxRegressor.refine` applies it. Refined boxes are clipped to
the frame, so refinement never moves a box outside it.

The regression learns the shape of the vehicles it was fitted on, and a camera it never saw has
vehicles of other shapes in other places. :func:`fit_sides` then moves each box's left and right
sides (a single image's boxes; in a video, each blob's box before the tracker averages it into
its track) onto the vehicle's own vertical edges, read off the image: the strongest column of
horizontal gradient near each side, at the height of the vehicle's body, with a prior that the
side is about right. It learns nothing, so it transfers to any camera.

Boxes are ``(n, 4)`` arrays ``[x1, y1, x2, y2]`` in frame pixels, x2 and y2 exclusive.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import cv2
import numpy as np

from ._jit import njit
from ._settings import JsonSettings, number_in
from .features import FeatureConfig, extract_features
from .geometry import as_boxes, box_iou, mirror_boxes
from .io.images import as_rgb_uint8

__all__ = [
    "BoxRegressor", "SideFit", "fit_sides", "edge_offsets", "apply_offsets", "jittered_windows", "hot_window_targets", "beyond_jitter",
    "crop_windows", "working_frame", "fit_box_regressor", "REFINE_ALPHA",
]

#: Default ridge penalty of the box refinement fitted to labelled frames
#: (:func:`~vehicle_detection.training.with_box_refinement`, ``train --labels``, ``refine``), on
#: standardised features.
REFINE_ALPHA = 1e4
#: The ridge penalties :func:`fit_box_regressor` takes.
MIN_ALPHA, MAX_ALPHA = 1e-6, 1e12

#: Largest predicted edge offset, in window sizes: a window far off its vehicle is not trusted
#: to move further than this.
MAX_OFFSET = 0.5


@dataclass(frozen=True, eq=False)
class BoxRegressor:
    """A linear map from a window's raw feature vector to its vehicle's edge offsets.

    Parameters
    ----------
    coef : array_like of float, shape (4, n_features)
        Weights over raw (unscaled) features, one row per edge (left, top, right, bottom).
    intercept : array_like of float, shape (4,)

    Attributes are read-only float64 copies.
    """

    coef: np.ndarray
    intercept: np.ndarray
    _weights: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        coef = np.array(self.coef, dtype=np.float64, copy=True)
        intercept = np.array(self.intercept, dtype=np.float64, copy=True).reshape(-1)
        if coef.ndim != 2 or coef.shape[0] != 4 or intercept.shape != (4,):
            raise ValueError(f"a box regressor needs coef (4, n) and intercept (4,); got {coef.shape} and {intercept.shape}")
        if not (np.all(np.isfinite(coef)) and np.all(np.isfinite(intercept))):
            raise ValueError("box regressor weights must be finite")
        weights = np.ascontiguousarray(coef, dtype=np.float32)  # the features are float32
        for arr in (coef, intercept, weights):
            arr.setflags(write=False)
        object.__setattr__(self, "coef", coef)
        object.__setattr__(self, "intercept", intercept)
        object.__setattr__(self, "_weights", weights)

    @property
    def n_features(self) -> int:
        return self.coef.shape[1]

    def offsets(self, features: np.ndarray) -> np.ndarray:
        """Predicted edge offsets of feature vectors ``(n, n_features)``: float64 ``(n, 4)``,
        clipped to ``[-MAX_OFFSET, MAX_OFFSET]``."""
        return self._offsets(_products(np.ascontiguousarray(features, dtype=np.float32), self._weights))

    def _offsets(self, products: np.ndarray) -> np.ndarray:
        return np.clip(products + self.intercept, -MAX_OFFSET, MAX_OFFSET)

    def refine_products(self, windows: np.ndarray, products: np.ndarray, frame_shape: tuple[int, ...]) -> np.ndarray:
        """:meth:`refine` from the products ``features @ coef.T`` ``(n, 4)`` already computed
        (the search reads them off the features it scored the windows with)."""
        return apply_offsets(windows, self._offsets(np.asarray(products, np.float64).reshape(-1, 4)), frame_shape)

    def refine(self, windows: np.ndarray, features: np.ndarray, frame_shape: tuple[int, ...]) -> np.ndarray:
        """Refined boxes of ``windows`` whose feature vectors are ``features``.

        Parameters
        ----------
        windows : array_like, shape (n, 4)
            Window boxes in frame pixels.
        features : ndarray, shape (n, n_features)
        frame_shape : (H, W, ...)

        Returns
        -------
        ndarray of int64, shape (n, 4)
            Boxes inside the frame, each at least one pixel wide and high.
        """
        return apply_offsets(windows, self.offsets(features), frame_shape)


@njit(nogil=True, fastmath=True)
def _products(features, weights):
    """``features @ weights.T`` in float64 sums, on this thread: BLAS would start threads of its
    own beside the search's, which spin on the cores the search needs."""
    n, k = features.shape[0], weights.shape[0]
    out = np.zeros((n, k), np.float64)
    for i in range(n):
        for j in range(k):
            s = 0.0
            for f in range(features.shape[1]):
                s += features[i, f] * weights[j, f]
            out[i, j] = s
    return out


def edge_offsets(windows: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """The offsets that move each window onto its box: float64 ``(n, 4)`` (see the module)."""
    w = as_boxes(windows, "windows").astype(np.float64)
    b = as_boxes(boxes, "boxes").astype(np.float64)
    size = np.tile(w[:, 2:] - w[:, :2], 2)
    return (b - w) / size


def apply_offsets(windows: np.ndarray, offsets: np.ndarray, frame_shape: tuple[int, ...]) -> np.ndarray:
    """Boxes from windows moved by edge offsets, rounded and clipped to the frame: int64 ``(n, 4)``."""
    w = as_boxes(windows, "windows").astype(np.float64)
    size = np.tile(w[:, 2:] - w[:, :2], 2)
    boxes = np.rint(w + np.asarray(offsets, np.float64).reshape(-1, 4) * size).astype(np.int64)
    h, wd = frame_shape[:2]
    np.clip(boxes, 0, [wd - 1, h - 1, wd, h], out=boxes)
    boxes[:, 2:] = np.maximum(boxes[:, 2:], boxes[:, :2] + 1)
    return boxes


#: The sides of :func:`jittered_windows`, as multiples of the box's larger dimension, and how far
#: their centres move, in sides.
JITTER_SIZES = (0.75, 1.5)
JITTER_SHIFT = 0.2


def jittered_windows(box: np.ndarray, rng: np.random.Generator, n: int, *, size_range=JITTER_SIZES, shift: float = JITTER_SHIFT) -> np.ndarray:
    """``n`` square windows around one vehicle box, like those a sliding-window search accepts.

    The side is the box's larger dimension times a factor drawn from ``size_range``; the centre
    moves by up to ``shift`` sides in each direction.

    Returns
    -------
    ndarray of float64, shape (n, 4)
    """
    x1, y1, x2, y2 = np.asarray(box, np.float64)
    side = max(x2 - x1, y2 - y1) * rng.uniform(*size_range, n)
    cx = (x1 + x2) / 2 + rng.uniform(-shift, shift, n) * side
    cy = (y1 + y2) / 2 + rng.uniform(-shift, shift, n) * side
    return np.stack([cx - side / 2, cy - side / 2, cx + side / 2, cy + side / 2], axis=1)


def hot_window_targets(windows: np.ndarray, boxes: np.ndarray, min_iou: float) -> tuple[np.ndarray, np.ndarray]:
    """The search's windows that overlap a labelled vehicle, each with the vehicle it overlaps most.

    Parameters
    ----------
    windows : array_like, shape (n, 4)
        Windows the search accepted in a labelled frame.
    boxes : array_like, shape (k, 4)
        The frame's labelled vehicles, in the same pixels.
    min_iou : float
        Smallest IoU of a window with its vehicle, in (0, 1]: a window mostly off every vehicle
        (on a neighbour, the road, a false positive) teaches nothing about edges.

    Returns
    -------
    (ndarray, ndarray), shapes (m, 4) and (m, 4), float64
        The windows kept and their vehicles' boxes, in the windows' order.
    """
    windows = as_boxes(windows, "windows").astype(np.float64)
    boxes = as_boxes(boxes, "boxes").astype(np.float64)
    if not 0 < min_iou <= 1:
        raise ValueError(f"min_iou must be in (0, 1]; got {min_iou!r}")
    if not len(windows) or not len(boxes):
        return np.zeros((0, 4)), np.zeros((0, 4))
    iou = box_iou(windows, boxes)
    best = iou.argmax(axis=1)
    keep = iou[np.arange(len(windows)), best] >= min_iou
    return windows[keep], boxes[best[keep]]


def beyond_jitter(windows: np.ndarray, boxes: np.ndarray, *, size_range=JITTER_SIZES, shift: float = JITTER_SHIFT) -> np.ndarray:
    """Which windows :func:`jittered_windows` never draws around their boxes.

    A window is beyond the jitter when its side (its width: the search's windows are square,
    up to their rounding to whole pixels) is outside ``size_range`` times its box's larger
    dimension, or its centre is more than ``shift`` sides from the box's in either direction.

    Parameters
    ----------
    windows, boxes : array_like, shape (n, 4)
        Windows and the boxes they are paired with, row by row, in the same pixels.
    size_range : (float, float)
    shift : float
        As :func:`jittered_windows` takes them.

    Returns
    -------
    ndarray of bool, shape (n,)
    """
    w = as_boxes(windows, "windows").astype(np.float64)
    b = as_boxes(boxes, "boxes").astype(np.float64)
    side = w[:, 2] - w[:, 0]
    larger = np.maximum(b[:, 2] - b[:, 0], b[:, 3] - b[:, 1])
    off = np.maximum(np.abs(w[:, 0] + w[:, 2] - b[:, 0] - b[:, 2]), np.abs(w[:, 1] + w[:, 3] - b[:, 1] - b[:, 3])) / 2
    return (side < size_range[0] * larger) | (side > size_range[1] * larger) | (off > shift * side)


def working_frame(frame: np.ndarray, height: int) -> tuple[np.ndarray, float]:
    """``frame`` resized to ``height`` rows as the search sees it, and the factor applied."""
    f = height / frame.shape[0]
    if f == 1:
        return frame, 1.0
    size = (max(1, round(frame.shape[1] * f)), height)
    return cv2.resize(frame, size, interpolation=cv2.INTER_AREA if f < 1 else cv2.INTER_LINEAR), f


def crop_windows(frame: np.ndarray, windows: np.ndarray, side: int) -> np.ndarray:
    """Windows cut from an RGB ``uint8`` frame (mirrored beyond its edges), resized to ``side``.

    Parameters
    ----------
    frame : ndarray of uint8, shape (H, W, 3)
    windows : array_like, shape (n, 4)
        Boxes in frame pixels (rounded to whole pixels); they may reach beyond the frame.
    side : int

    Returns
    -------
    ndarray of uint8, shape (n, side, side, 3)
    """
    windows = np.rint(np.asarray(windows, np.float64)).reshape(-1, 4)
    h, w = frame.shape[:2]
    pad = int(np.ceil(max(0.0, -windows.min(initial=0.0), (windows[:, 2] - w).max(initial=0.0), (windows[:, 3] - h).max(initial=0.0)))) + 1
    padded = cv2.copyMakeBorder(frame, pad, pad, pad, pad, cv2.BORDER_REFLECT_101) if pad > 1 else frame
    off = pad if pad > 1 else 0
    out = np.empty((len(windows), side, side, 3), np.uint8)
    for i, (a, b, c, d) in enumerate(np.rint(windows).astype(np.int64) + off):
        out[i] = cv2.resize(padded[b:d, a:c], (side, side), interpolation=cv2.INTER_AREA)
    return out


def fit_box_regressor(
    samples: Iterable[tuple],
    config: FeatureConfig,
    *,
    per_box: int = 24,
    alpha: float = REFINE_ALPHA,
    reference_height: int = 720,
    random_state: int = 0,
    hot_iou: float = 0.5,
    mirror: bool = False,
) -> BoxRegressor:
    """Learn edge offsets from windows around labelled vehicles.

    Two kinds of window teach it. Windows jittered around each vehicle (:func:`jittered_windows`)
    cover it at every position and size near its own. Of the windows the search accepted in the
    same frame (:func:`hot_window_targets`), those the jitter never draws (:func:`beyond_jitter`)
    are added: on a car seen at an angle they sit on its rear, smaller than the car and off its
    centre. The others are like jittered windows already, and would only weigh the cameras with
    many accepted windows a frame more.

    Parameters
    ----------
    samples : iterable of (frame, boxes) or (frame, boxes, windows)
        RGB ``uint8`` frames ``(H, W, 3)``, their labelled vehicle boxes ``(k, 4)`` and,
        optionally, the windows the search accepted in them ``(n, 4)``, all in frame pixels.
    config : FeatureConfig
        The features of the classifier whose hot windows will be refined.
    per_box : int
        Windows drawn per labelled box (:func:`jittered_windows`).
    alpha : float
        Ridge penalty on standardised features, :data:`MIN_ALPHA` to :data:`MAX_ALPHA`
        (:data:`REFINE_ALPHA` by default, as :func:`~vehicle_detection.training.with_box_refinement` has it).
    reference_height : int
        Frames are resized to this height first, as the search does.
    random_state : int
        Seed of the jitter.
    hot_iou : float
        Smallest IoU of an accepted window with a labelled vehicle for it to count.
    mirror : bool
        Learn from each frame flipped left to right too, with the same windows flipped: the
        refinement then moves a window on a mirrored scene as the mirror of its move on the
        scene (a vehicle seen from its right as one seen from its left), so it holds in
        left-hand and right-hand traffic alike, wherever the labelled vehicles drove.

    Returns
    -------
    BoxRegressor
    """
    from sklearn.linear_model import Ridge
    from sklearn.preprocessing import StandardScaler

    if not 0 < hot_iou <= 1:
        raise ValueError(f"hot_iou must be in (0, 1]; got {hot_iou!r}")
    if not MIN_ALPHA <= alpha <= MAX_ALPHA:
        raise ValueError(f"alpha must be from {MIN_ALPHA:g} to {MAX_ALPHA:g} (below, the fit's matrix is singular in "
                         f"floating point); got {alpha!r}")
    rng = np.random.default_rng(random_state)
    feats, targets = [], []
    for frame, boxes, *hot in samples:
        boxes = as_boxes(boxes, "boxes").astype(np.float64)
        if not len(boxes):
            continue
        work, f = working_frame(frame, reference_height)
        boxes = boxes * f
        wins = np.concatenate([jittered_windows(b, rng, per_box) for b in boxes])
        cars = np.repeat(boxes, per_box, axis=0)
        if hot and hot[0] is not None:
            found, theirs = hot_window_targets(np.asarray(hot[0], np.float64).reshape(-1, 4) * f, boxes, hot_iou)
            new = beyond_jitter(found, theirs)
            wins, cars = np.concatenate([wins, found[new]]), np.concatenate([cars, theirs[new]])
        wins = np.rint(wins)
        crops = crop_windows(work, wins, config.window)
        feats.append(extract_features(crops, config))
        targets.append(edge_offsets(wins, cars))
        if mirror:  # each window flipped, as it is in the frame flipped
            width = work.shape[1]
            feats.append(extract_features(np.ascontiguousarray(crops[:, :, ::-1]), config))
            targets.append(edge_offsets(mirror_boxes(wins, width), mirror_boxes(cars, width)))
    if not feats:
        raise ValueError("no labelled vehicles to learn box refinement from")
    x, y = np.concatenate(feats), np.concatenate(targets)
    scaler = StandardScaler().fit(x)
    scale = np.where(scaler.scale_ > 0, scaler.scale_, 1.0)
    ridge = Ridge(alpha=alpha).fit((x - scaler.mean_) / scale, y)
    coef = ridge.coef_ / scale
    return BoxRegressor(coef, ridge.intercept_ - coef @ scaler.mean_)


# --------------------------------------------------------------------------------------------
# Sides fitted to the image
# --------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class SideFit(JsonSettings):
    """How :func:`fit_sides` moves a box's left and right sides onto the vehicle's edges.

    Parameters
    ----------
    reach : float, default 0.1
        Each side may move up to this fraction of the box's width, inwards or outwards, in
        ``(0, 0.5)``.
    prior : float, default 0.07
        Standard deviation of the Gaussian prior on a side's move, as a fraction of the box's
        width, > 0: a column's edge strength is weighed by it, so a side moves far only to a
        much stronger edge.
    outer : float, default 0.9
        A side goes to the outermost column whose weighed strength is at least this share of
        the best, in ``(0, 1]``: a vehicle's outline lies outside its lights and number plate,
        whose edges can be as strong. 1 takes the best column.
    rows : (float, float), default (0.3, 0.95)
        The rows of the box whose edges count, as fractions of its height from its top,
        ``0 <= top < bottom <= 1``: the vehicle's body, below the roof (where the background
        shows beside it) and above the road.

    Raises
    ------
    ValueError
        If a value is out of range; the message names the field.
    """

    reach: float = 0.1
    prior: float = 0.07
    outer: float = 0.9
    rows: tuple[float, float] = (0.3, 0.95)

    def __post_init__(self) -> None:
        object.__setattr__(self, "reach", number_in(self, "reach", 0.0, 0.5))
        object.__setattr__(self, "prior", number_in(self, "prior", 0.0))
        object.__setattr__(self, "outer", number_in(self, "outer", 0.0, 1.0, high_in=True))
        rows = tuple(self.rows) if isinstance(self.rows, (tuple, list)) else ()
        if len(rows) != 2 or not all(isinstance(r, (int, float)) and not isinstance(r, bool) for r in rows) or not 0 <= rows[0] < rows[1] <= 1:
            raise ValueError(f"SideFit.rows must be two fractions 0 <= top < bottom <= 1; got {self.rows!r}")
        object.__setattr__(self, "rows", (float(rows[0]), float(rows[1])))


def _column_strength(image: np.ndarray, top: int, bottom: int, left: int, right: int, first: int, end: int) -> np.ndarray:
    """Mean absolute horizontal gradient (Sobel, the strongest of the three channels) of each
    column ``left..right-1`` over rows ``top..bottom-1``, smoothed over three columns: float64.
    Only the picture's columns ``first..end-1`` are read (black bars beyond are not)."""
    # two columns of context each side, so the gradient and the smoothing see real pixels
    c0, c1 = max(first, left - 2), min(end, right + 2)
    crop = image[top:bottom, c0:c1].astype(np.float32)
    gx = np.abs(cv2.Sobel(crop, cv2.CV_32F, 1, 0, ksize=3)).max(axis=2)
    profile = np.convolve(gx.mean(axis=0, dtype=np.float64), np.ones(3) / 3.0, mode="same")
    return profile[left - c0 : right - c0]


def _side(profile: np.ndarray, start: int, at: float, sigma: float, outer: float, outwards: int, frame_edge: bool) -> int:
    """The column of one side: ``profile[i]`` is column ``start + i``'s strength; the side is now
    at column ``at``; ``outwards`` is -1 for a left side, +1 for a right one."""
    peak = profile.max()
    if not peak > 0:  # a flat patch: nothing to go by
        return int(round(at))
    strength = profile / peak
    if frame_edge:  # a vehicle cut by the frame ends at the frame's edge
        strength[0 if outwards < 0 else -1] = 1.0
    cols = start + np.arange(len(profile))
    weighed = strength * np.exp(-0.5 * ((cols - at) / sigma) ** 2)
    good = np.flatnonzero(weighed >= outer * weighed.max())
    return int(cols[good[0] if outwards < 0 else good[-1]])


def fit_sides(image: np.ndarray, boxes: np.ndarray, fit: SideFit, *, area: tuple[int, int, int, int] | None = None) -> np.ndarray:
    """Boxes whose left and right sides are moved onto the vehicle's vertical edges.

    For each side, the columns within ``fit.reach`` of the box's width either side of it are
    weighed by their edge strength (the mean absolute horizontal gradient over the rows
    ``fit.rows`` of the box, the strongest colour channel) times a Gaussian prior centred on
    the side; the side goes to the outermost column within ``fit.outer`` of the best. A box
    that reaches the picture's edge may stay there: the edge counts as a vehicle edge of full
    strength. Top and bottom are left as they are.

    Parameters
    ----------
    image : ndarray of uint8, shape (H, W, 3)
        The frame the boxes were found in.
    boxes : array_like, shape (n, 4)
        ``[x1, y1, x2, y2]`` in frame pixels, x2 and y2 exclusive, inside the frame.
    fit : SideFit
    area : (int, int, int, int), optional
        The picture inside black bars, ``(x1, y1, x2, y2)`` (:func:`~vehicle_detection.footage.overlays.active_area`):
        sides move only within its columns, and its left and right edges count as the frame's.
        Default: the whole frame.

    Returns
    -------
    ndarray of int64, shape (n, 4)
        The boxes with their sides moved, inside the frame (and the picture); a box too small to measure (under
        8 pixels wide or high) is returned as it is.
    """
    out = np.rint(as_boxes(boxes, "boxes")).astype(np.int64)
    image = as_rgb_uint8(image)  # grey converted, anything else refused in one line
    h, w = image.shape[:2]
    a0, a1 = (0, w) if area is None else (max(0, int(area[0])), min(w, int(area[2])))
    for box in out:
        x1, y1, x2, y2 = (int(v) for v in box)
        bw, bh = x2 - x1, y2 - y1
        top, bottom = max(0, y1 + int(fit.rows[0] * bh)), min(h, y1 + int(round(fit.rows[1] * bh)))
        if bw < 8 or bh < 8 or bottom - top < 2 or x1 < a0 or x2 > a1:
            continue
        reach, sigma = fit.reach * bw, fit.prior * bw
        # left: the box's first column; right: its last (x2 exclusive)
        lo, hi = max(a0, int(x1 - reach)), min(a1, int(x1 + reach) + 1)
        left = _side(_column_strength(image, top, bottom, lo, hi, a0, a1), lo, x1, sigma, fit.outer, -1, lo == a0)
        lo, hi = max(a0, int(x2 - 1 - reach)), min(a1, int(x2 - 1 + reach) + 1)
        right = _side(_column_strength(image, top, bottom, lo, hi, a0, a1), lo, x2 - 1, sigma, fit.outer, +1, hi == a1) + 1
        if right - left >= 2:
            box[0], box[2] = left, right
    return out
