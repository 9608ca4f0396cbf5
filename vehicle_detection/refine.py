"""Box refinement: from a hot window's features, where the vehicle's four edges are.

A window the classifier accepts rarely frames its vehicle: the windows are square, sit on a
coarse grid, and come in a few sizes, while vehicles are wider than tall and of every size. As
in the bounding-box regression of deformable part models (Felzenszwalb et al., PAMI 2010) and
R-CNN, a linear model predicts, from the same feature vector the classifier scored, the offsets
of the vehicle's edges from the window's edges in units of the window's size:

    d = [(x1* - x1) / w, (y1* - y1) / h, (x2* - x2) / w, (y2* - y2) / h]

:func:`fit_box_regressor` learns it (ridge regression) from windows jittered around labelled
vehicles in real frames; :meth:`BoxRegressor.refine` applies it. Refined boxes are clipped to
the frame, so refinement never moves a box outside it.

Boxes are ``(n, 4)`` arrays ``[x1, y1, x2, y2]`` in frame pixels, x2 and y2 exclusive.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import cv2
import numpy as np

from ._jit import njit
from .features import FeatureConfig, extract_features
from .geometry import as_boxes

__all__ = ["BoxRegressor", "edge_offsets", "apply_offsets", "jittered_windows", "crop_windows", "working_frame", "fit_box_regressor"]

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


def jittered_windows(box: np.ndarray, rng: np.random.Generator, n: int, *, size_range=(0.75, 1.5), shift: float = 0.2) -> np.ndarray:
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
    samples: Iterable[tuple[np.ndarray, np.ndarray]],
    config: FeatureConfig,
    *,
    per_box: int = 24,
    alpha: float = 1.0,
    reference_height: int = 720,
    random_state: int = 0,
) -> BoxRegressor:
    """Learn edge offsets from windows jittered around labelled vehicles.

    Parameters
    ----------
    samples : iterable of (frame, boxes)
        RGB ``uint8`` frames ``(H, W, 3)`` and their labelled vehicle boxes ``(k, 4)``.
    config : FeatureConfig
        The features of the classifier whose hot windows will be refined.
    per_box : int
        Windows drawn per labelled box (:func:`jittered_windows`).
    alpha : float
        Ridge penalty on standardised features.
    reference_height : int
        Frames are resized to this height first, as the search does.

    Returns
    -------
    BoxRegressor
    """
    from sklearn.linear_model import Ridge
    from sklearn.preprocessing import StandardScaler

    rng = np.random.default_rng(random_state)
    feats, targets = [], []
    for frame, boxes in samples:
        boxes = as_boxes(boxes, "boxes").astype(np.float64)
        if not len(boxes):
            continue
        work, f = working_frame(frame, reference_height)
        boxes = boxes * f
        wins = np.concatenate([jittered_windows(b, rng, per_box) for b in boxes])
        feats.append(extract_features(crop_windows(work, wins, config.window), config))
        targets.append(edge_offsets(np.rint(wins), np.repeat(boxes, per_box, axis=0)))
    if not feats:
        raise ValueError("no labelled vehicles to learn box refinement from")
    x, y = np.concatenate(feats), np.concatenate(targets)
    scaler = StandardScaler().fit(x)
    scale = np.where(scaler.scale_ > 0, scaler.scale_, 1.0)
    ridge = Ridge(alpha=alpha).fit((x - scaler.mean_) / scale, y)
    coef = ridge.coef_ / scale
    return BoxRegressor(coef, ridge.intercept_ - coef @ scaler.mean_)
