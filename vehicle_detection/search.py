"""Sliding-window search: where to look in a frame, and how to score every window at once.

Two paths give the same answer:

* the **plain path**, for teaching and figures: :func:`slide_window` lists windows and
  :func:`classify_windows` crops, resizes and classifies each one; :func:`search_plain` does the
  same over a :class:`SearchPlan`, one window at a time;
* the **fast path**, used everywhere else (:func:`search`): per scale, the search region is
  resized and colour-converted once, the HOG cells of the whole region are computed once, the
  scaler is folded into the SVM weights, and every window is scored in compiled passes: with
  :attr:`SearchPlan.window_border` ``"frame"`` (the default), every HOG block of the region is
  normalised once and each window is the dot product of its blocks with the weights; with
  ``"crop"``, each block is normalised once per border class (a window's crop has no gradient
  across its border) and dotted with the weights of every window that holds it. Spatial bins
  are block means shared by all windows; colour histograms become a per-pixel weight map summed
  over cells. No Python loop over windows.
  With :attr:`SearchPlan.coarse_margin` (the default plan's), the windows are scored in two
  stages: every other window in both directions, then only the neighbours of those within that
  margin of the threshold; a hit's neighbours score close to it, so the hits are the full
  search's (a test checks this on the shipped frames) at about a third of the block products.
  The box refinement of the hot windows is read off the same cells, spatial bins and pixels.

With ``"crop"``, the fast path reproduces the features a cropped window would give, including
scikit-image's zero gradient on the window border (see :mod:`vehicle_detection.features`), so
both paths agree on every window's margin to rounding error; with ``"frame"``, the plain path
cuts each window's HOG from its band's gradients (``tests/reference_search.py``); tests check
both on real frames.

Coordinates: the plan is written for a frame ``reference_height`` pixels high (720, the project
video); other frames are resized to that height first and the boxes mapped back.
"""

from __future__ import annotations

import threading
import weakref
from collections import OrderedDict
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import cv2
import numba
import numpy as np

from ._jit import njit
from .detections import Detections
from .features import (
    FeatureConfig,
    _block_map,
    _cell_squares,
    _cell_work,
    _clipped_block,
    _flat_lut,
    _gather_block,
    _planes,
    _region_cells,
    convert_color,
    hog_input,
    region_hog,
)
from .io.images import as_rgb_uint8, check_frame_shape
from .refine import BoxRegressor, apply_offsets, working_frame

if TYPE_CHECKING:
    from .convnet import ConvNet

__all__ = [
    "SearchScale",
    "SearchPlan",
    "plan_windows",
    "plan_bands",
    "search",
    "window_patches",
    "WindowScorer",
]


@dataclass(frozen=True)
class SearchScale:
    """One band of the frame searched with one window size.

    Parameters
    ----------
    scale : float
        Window side in frame pixels divided by the model's window (64): 1.5 means 96-pixel
        windows.
    y_start, y_stop : int
        Rows searched (frame pixels at the reference height).
    x_start : int
        First column searched.
    x_stop : int or None
        End column (None: the frame's right edge).
    step : int
        Window step in HOG cells (of the scaled image): with 8-pixel cells and scale 1.5,
        ``step=2`` moves windows by 24 frame pixels (horizontally ``aspect`` times that).
    aspect : float
        Window width over height: 1.5 searches windows ``96 x 64`` at scale 1, squeezed to the
        model's square patch. Vehicles seen on the road are wider than tall, while the training
        patches frame each vehicle edge to edge; wide windows fit them.
    """

    scale: float
    y_start: int
    y_stop: int
    x_start: int = 0
    x_stop: int | None = None
    step: int = 2
    aspect: float = 1.0

    def __post_init__(self):
        if not 0.25 <= self.scale <= 32:
            raise ValueError(f"scale must be within 0.25..32 (windows of 16 to 2048 pixels), got {self.scale}")
        if not 0.25 <= self.aspect <= 4:
            raise ValueError(f"aspect must be within 0.25..4, got {self.aspect}")
        if self.y_stop <= self.y_start or self.y_start < 0 or self.x_start < 0:
            raise ValueError(f"empty or negative search band y {self.y_start}..{self.y_stop}")
        if self.x_stop is not None and self.x_stop <= self.x_start:
            raise ValueError(f"empty search band x {self.x_start}..{self.x_stop}")
        if self.step < 1:
            raise ValueError("step must be at least one cell")


def _default_scales():
    # Each integer scale's band is a whole number of its scaled rows (303 = 101 x 3, 380 = 76 x 5):
    # OpenCV's INTER_AREA then resizes it by plain block means, its fast path.
    return (
        SearchScale(1.0, 384, 496, step=1),
        SearchScale(1.5, 384, 544, step=1),
        SearchScale(2.0, 384, 592, step=1),
        SearchScale(3.0, 384, 687, step=1),
        SearchScale(4.0, 336, 720, step=1),
        SearchScale(5.0, 336, 716, step=1),  # 320-pixel windows, for cars close to the camera
    )


#: The most scales a search plan may have (the shipped plans have up to 14): a model file
#: declaring thousands would make every frame's search take minutes and gigabytes.
MAX_SCALES = 64


@dataclass(frozen=True)
class SearchPlan:
    """Where and at what sizes to search, and the margin above which a window is a hit.

    Parameters
    ----------
    scales : tuple of SearchScale
    threshold : float
        Minimum SVM margin of a window reported as a detection. The default goes with the
        default ``window_border``: windows seen across their border score a little higher than
        their crops (plans that search crops used 0.3).
    reference_height : int
        Frame height the bands are written for; other frames are resized to it.
    overhang : float
        Fraction of a window's width that may lie beyond the left or right frame edge, in
        ``[0, 1)``: the frame is mirrored there, and boxes are clipped to the frame.
    overhang_min_scale : float
        Windows of smaller scales (``scale * aspect``) do not overhang: a vehicle
        cut by the frame edge is a close, large one, while half a small window mirrored at the
        edge makes a symmetric pattern that looks like a car's rear.
    horizon : float or None
        Where the camera's horizon is (the row where the road vanishes), as a fraction of the
        frame height from the top: the bands move up or down together by its distance from
        ``reference_horizon``. None keeps them where they are written;
        :class:`~vehicle_detection.detector.Detector` then estimates it from the footage
        (:mod:`~vehicle_detection.footage.horizon`) unless its config says not to.
    reference_horizon : float
        The horizon of the camera the bands are written for (the project camera's, measured by
        :func:`~vehicle_detection.footage.horizon.vanishing_row`).
    full_search_every : int
        Search schedule over video frames (:class:`~vehicle_detection.detector.Detector`): every
        ``full_search_every``-th frame (counted from the video's frame 0) is searched whole, and so are the first ``min_hits``
        frames of a run and of each shot (:class:`~vehicle_detection.tracker.TrackerConfig`,
        :attr:`~vehicle_detection.tracker.Tracker.shot_start`); the frames in between only where a
        vehicle can appear or be: windows lying within the ``edge_width`` columns at the left
        or right frame edge (part of them may overhang it), windows lying inside the ``horizon_height`` rows below the top
        of the band of the smallest windows (near the horizon, where distant vehicles are small), and windows overlapping a
        live track's box grown by ``track_margin`` times its width and height on each side.
        1 (the default) searches every frame whole. Single images are always searched whole.
    edge_width, horizon_height : int
        In pixels at the reference height.
    track_margin : float
        Fraction of a track box's size added on each side.
    coarse_margin : float or None
        A two-stage search. None scores every window. A number first scores every other window
        of each band in both directions (a quarter of them), then only the windows next to a
        first-stage window whose margin exceeds ``threshold - coarse_margin``. Every window
        scored gets its exact margin, so hits are found as the full search finds them unless
        a hit's four coarse neighbours all score more than ``coarse_margin`` below the
        threshold. Windows not scored are reported with a margin of ``-inf`` by
        ``search(all_windows=True)``, which scores every window whatever this says.
    window_border : {"frame", "crop"}
        What a window's HOG sees across its border. ``"frame"`` (the default): the frame's own
        gradient there, as detectors that compute the HOG of a whole image do; each band's
        blocks are then normalised once for all its windows
        (:func:`~vehicle_detection.features.region_blocks`). ``"crop"``: no gradient across the
        border, exactly as the window's cropped patch gives it (the training patches have no
        pixels around them); about twice the work. Only the cells along a window's border
        differ between the two. Plans saved before this setting existed load with ``"crop"``.
    reach_bottom : bool
        With a horizon above the reference one, the bands move up; True keeps the bands that
        reach the bottom of the reference frame reaching the frame's bottom (a camera that
        sees the road ahead from higher up sees close cars there). False moves them up whole.
    """

    scales: tuple[SearchScale, ...] = field(default_factory=_default_scales)
    threshold: float = 0.43
    reference_height: int = 720
    overhang: float = 0.5
    overhang_min_scale: float = 2.0
    horizon: float | None = None
    reference_horizon: float = 0.583
    full_search_every: int = 1
    edge_width: int = 160
    horizon_height: int = 96
    track_margin: float = 0.5
    coarse_margin: float | None = 1.5
    window_border: str = "frame"
    reach_bottom: bool = False

    def __post_init__(self):
        object.__setattr__(self, "scales", tuple(self.scales))
        for name in ("full_search_every", "edge_width", "horizon_height"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < (1 if name == "full_search_every" else 0):
                raise ValueError(f"{name} must be an integer >= {1 if name == 'full_search_every' else 0}, got {v!r}")
            object.__setattr__(self, name, int(v))
        if self.coarse_margin is not None:
            c = self.coarse_margin
            if isinstance(c, bool) or not isinstance(c, (int, float, np.floating)) or not 0.0 <= c <= 100.0:
                raise ValueError(f"coarse_margin must be None or a number in [0, 100], got {c!r}")
            object.__setattr__(self, "coarse_margin", float(c))
        if not 0.0 <= self.track_margin <= 10.0:
            raise ValueError(f"track_margin must be in [0, 10], got {self.track_margin}")
        if not isinstance(self.reach_bottom, bool):
            raise ValueError(f"reach_bottom must be True or False, got {self.reach_bottom!r}")
        if self.window_border not in ("frame", "crop"):
            raise ValueError(f"window_border must be 'frame' or 'crop', got {self.window_border!r}")
        if not self.scales:
            raise ValueError("a search plan needs at least one scale")
        if len(self.scales) > MAX_SCALES:
            raise ValueError(f"a search plan has at most {MAX_SCALES} scales, got {len(self.scales)}")
        if not 64 <= self.reference_height <= 1440:
            raise ValueError(f"reference_height must be 64 to 1440 pixels, got {self.reference_height}")
        if not np.isfinite(self.threshold):
            raise ValueError(f"threshold must be a finite number, got {self.threshold}")
        if not 0.0 <= self.overhang < 1.0:
            raise ValueError(f"overhang must be in [0, 1), got {self.overhang}")
        for name in ("horizon", "reference_horizon"):
            v = getattr(self, name)
            if v is not None and not 0.0 <= v < 1.0:
                raise ValueError(f"{name} must be a fraction of the frame height in [0, 1), got {v}")

    def overhang_of(self, s: SearchScale) -> float:
        """The overhang of scale ``s``'s windows (0 below ``overhang_min_scale``)."""
        return self.overhang if s.scale * s.aspect >= self.overhang_min_scale else 0.0

    @property
    def y_shift(self) -> int:
        """Rows (at the reference height) the bands move down: the horizon's distance below the reference."""
        if self.horizon is None:
            return 0
        return round((self.horizon - self.reference_horizon) * self.reference_height)

    def to_dict(self) -> dict:
        return {
            "scales": [dict(vars(s)) for s in self.scales],
            "threshold": self.threshold,
            "reference_height": self.reference_height,
            "overhang": self.overhang,
            "overhang_min_scale": self.overhang_min_scale,
            "horizon": self.horizon,
            "reference_horizon": self.reference_horizon,
            "full_search_every": self.full_search_every,
            "edge_width": self.edge_width,
            "horizon_height": self.horizon_height,
            "track_margin": self.track_margin,
            "coarse_margin": self.coarse_margin,
            "window_border": self.window_border,
            "reach_bottom": self.reach_bottom,
        }

    @classmethod
    def from_dict(cls, d: dict) -> SearchPlan:
        """The inverse of :meth:`to_dict`; a malformed plan raises ``ValueError``.

        Plans saved before the search schedule existed (without its four fields) load with the
        defaults: every frame searched whole; plans without ``reference_horizon``, with the
        project camera's; plans without ``coarse_margin`` score every window, as they did; plans
        without ``window_border``, with ``"crop"`` (the only search there was).
        """
        try:
            required = {"scales", "threshold", "reference_height", "overhang", "horizon"}
            optional = {"full_search_every", "edge_width", "horizon_height", "track_margin", "reference_horizon",
                        "overhang_min_scale", "coarse_margin", "window_border", "reach_bottom"}
            if not required <= set(d) <= required | optional:
                raise ValueError(f"fields {sorted(d)}")
            schedule = {"overhang_min_scale": 0.0, "coarse_margin": None, "window_border": "crop",
                        **{k: d[k] for k in optional & set(d)}}
            for name in ("track_margin", "reference_horizon", "overhang_min_scale"):
                if name in schedule:
                    schedule[name] = float(schedule[name])
            return cls(
                **schedule,
                scales=tuple(SearchScale(**s) for s in d["scales"]),
                threshold=float(d["threshold"]),
                reference_height=int(d["reference_height"]),
                overhang=float(d["overhang"]),
                horizon=None if d["horizon"] is None else float(d["horizon"]),
            )
        except (TypeError, KeyError, ValueError) as exc:
            raise ValueError(f"malformed search plan: {exc}") from None


# --- shared geometry ---------------------------------------------------------------------------


@dataclass(frozen=True)
class _Band:
    """A scale's region, resized: the pixels both paths score."""

    image: np.ndarray  # RGB uint8 of the scaled region
    x0: int  # region origin in working-frame pixels
    y0: int
    sx: float  # working-frame pixels per scaled pixel
    sy: float
    rows: np.ndarray  # window top rows, in cells of the scaled region
    cols: np.ndarray


def _working_frame(frame: np.ndarray, plan: SearchPlan) -> tuple[np.ndarray, float]:
    h, w = frame.shape[:2]
    check_frame_shape(h, w, "frame", reference_height=plan.reference_height)
    return working_frame(frame, plan.reference_height)


def _band(frame: np.ndarray, s: SearchScale, config: FeatureConfig, overhang: float = 0.0, y_shift: int = 0,
          reach_bottom: bool = False) -> _Band | None:
    h, w = frame.shape[:2]
    x0, x1 = min(s.x_start, w), min(s.x_stop if s.x_stop is not None else w, w)
    y0, y1 = min(max(s.y_start + y_shift, 0), h), min(max(s.y_stop + y_shift, 0), h)
    if reach_bottom and s.y_stop >= h:
        y1 = h
    side = config.window
    if (x1 - x0) < side * s.scale * s.aspect or (y1 - y0) < side * s.scale:
        return None
    region = frame[y0:y1, x0:x1]
    # Windows may overhang the left and right frame edges (mirrored pixels beyond them), so a
    # vehicle cut by the edge still has windows that frame it.
    pad = round(overhang * side * s.scale * s.aspect)
    left, right = (pad if x0 == 0 else 0), (pad if x1 == w else 0)
    ratio = s.scale * s.aspect
    if (left or right) and ratio == int(ratio):
        # A padded width of whole scaled pixels: OpenCV's INTER_AREA then takes its fast path
        # for integer ratios (plain block means) instead of fractional weights.
        extra = (x1 - x0 + left + right) % int(ratio)
        if right >= extra:
            right -= extra
        elif left >= extra:
            left -= extra
    if left or right:
        region = cv2.copyMakeBorder(region, 0, 0, left, right, cv2.BORDER_REFLECT_101)
        x0, x1 = x0 - left, x1 + right
    nw, nh = round((x1 - x0) / (s.scale * s.aspect)), round((y1 - y0) / s.scale)
    scaled = region if (nw, nh) == (x1 - x0, y1 - y0) else cv2.resize(region, (nw, nh), interpolation=cv2.INTER_AREA)
    ppc, cpw = config.pixels_per_cell, config.cells_per_window
    n_cr, n_cc = nh // ppc, nw // ppc
    rows = np.arange(0, n_cr - cpw + 1, s.step)
    cols = np.arange(0, n_cc - cpw + 1, s.step)
    if not len(rows) or not len(cols):
        return None
    return _Band(np.ascontiguousarray(scaled), x0, y0, (x1 - x0) / nw, (y1 - y0) / nh, rows, cols)


def _band_windows(band: _Band, config: FeatureConfig, f: float, keep: slice | np.ndarray = slice(None)) -> np.ndarray:
    """The band's windows in the input frame's pixels, float64 (n, 4), not clipped.

    ``keep`` selects windows in the band's row-major order (a boolean mask or indices): only
    those are computed (a frame keeps a few dozen of its thousands).
    """
    ppc, side = config.pixels_per_cell, config.window
    index = np.arange(len(band.rows) * len(band.cols))[keep]
    xx = band.cols[index % len(band.cols)] * ppc
    yy = band.rows[index // len(band.cols)] * ppc
    x1 = band.x0 + xx * band.sx
    y1 = band.y0 + yy * band.sy
    return np.stack([x1, y1, x1 + side * band.sx, y1 + side * band.sy], axis=1) / f


def _band_boxes(band: _Band, config: FeatureConfig, f: float, frame_shape: tuple[int, ...],
                keep: slice | np.ndarray = slice(None)) -> np.ndarray:
    """The band's windows in the input frame's pixels, clipped to the frame (``keep``: as
    :func:`_band_windows`)."""
    return _clipped_boxes(_band_windows(band, config, f, keep), frame_shape)


def _clipped_boxes(windows: np.ndarray, frame_shape: tuple[int, ...]) -> np.ndarray:
    """Windows (float64, :func:`_band_windows`) as whole-pixel boxes clipped to the frame."""
    h, w = frame_shape[:2]
    return np.clip(np.rint(windows).astype(np.int64), 0, [w, h, w, h])


def _band_patches(band: _Band, config: FeatureConfig, keep: np.ndarray) -> np.ndarray:
    """The 64x64 patches of the band's windows selected by ``keep``, as the classifier scored them."""
    ppc, side = config.pixels_per_cell, config.window
    index = np.flatnonzero(keep)
    n_cols = len(band.cols)
    patches = np.empty((len(index), side, side, 3), np.uint8)
    for j, i in enumerate(index.tolist()):
        r, c = band.rows[i // n_cols] * ppc, band.cols[i % n_cols] * ppc
        patches[j] = band.image[r : r + side, c : c + side]
    return patches


def plan_windows(frame_shape, plan: SearchPlan, config: FeatureConfig) -> list[np.ndarray]:
    """The windows each scale of ``plan`` searches, as boxes in frame pixels (for figures).

    Returns
    -------
    list of ndarray of int64, shape (n_i, 4)
        One array per scale (empty where the band does not fit the frame).
    """
    h, w = frame_shape[:2]
    f = plan.reference_height / h
    dummy = np.zeros((plan.reference_height, max(1, round(w * f)), 3), np.uint8)
    out = []
    for s in plan.scales:
        band = _band(dummy, s, config, plan.overhang_of(s), plan.y_shift, plan.reach_bottom)
        out.append(np.zeros((0, 4), np.int64) if band is None else _band_boxes(band, config, f, frame_shape))
    return out


def plan_bands(frame: np.ndarray, plan: SearchPlan, config: FeatureConfig):
    """Each scale's band of a frame as the search cuts it, with its windows (for training).

    Parameters
    ----------
    frame : ndarray of uint8, shape (H, W, 3)
        A frame at the plan's reference height.
    plan : SearchPlan
    config : FeatureConfig
        The model's (its window and cell sizes).

    Yields
    ------
    (int, ndarray, ndarray, ndarray)
        The scale's index in the plan; the band resized to the scale (RGB ``uint8``); the rows
        and columns of its windows, in cells of the band (every ``step``); and the windows in
        the frame's pixels, float64 ``(rows * cols, 4)`` in row-major order, not clipped (they
        may overhang the frame's sides).
    """
    for k, s in enumerate(plan.scales):
        band = _band(frame, s, config, plan.overhang_of(s), plan.y_shift, plan.reach_bottom)
        if band is not None:
            yield k, band.image, band.rows, band.cols, _band_windows(band, config, 1.0)


class _Planned(Protocol):
    """A model's detector settings, as far as the search reads them (a :class:`~vehicle_detection.config.DetectorConfig`)."""

    @property
    def plan(self) -> SearchPlan: ...


class WindowScorer(Protocol):
    """What the search reads of a model: the features it scores, its folded weights, its box
    refinement or network, and the plan searched when none is given.

    :class:`~vehicle_detection.classifier.VehicleClassifier` is one. The search names only what it
    reads, so it needs nothing of the classifier module (whose model file carries a
    :class:`~vehicle_detection.config.DetectorConfig`, and so a :class:`SearchPlan` of this one).
    """

    @property
    def config(self) -> FeatureConfig: ...

    @property
    def weights(self) -> np.ndarray: ...

    @property
    def bias(self) -> float: ...

    @property
    def box_regressor(self) -> BoxRegressor | None: ...

    @property
    def convnet(self) -> ConvNet | None: ...

    @property
    def detector_config(self) -> _Planned: ...

    def decision_images(self, images: np.ndarray) -> np.ndarray: ...


def window_patches(frame: np.ndarray, windows: Detections, model: WindowScorer, plan: SearchPlan | None = None) -> np.ndarray:
    """The 64x64 patches the classifier scored for windows that :func:`search` returned.

    Each patch is cut from the scale's resized band exactly as the search saw it (INTER_AREA
    resize, windows that overhang the frame edge filled with mirrored pixels, wide windows
    squeezed), so ``model.decision_images(patches)`` gives the windows' margins again with
    ``plan.window_border="crop"``, and close to them with ``"frame"`` (where the search also
    saw the gradient across the window's border, which a patch cannot hold).

    Parameters
    ----------
    frame : ndarray of uint8, shape (H, W, 3)
        The frame that was searched.
    windows : Detections
        Windows of ``search(frame, model, plan)`` (any subset), with ``data["scale_index"]``.
    model : WindowScorer
    plan : SearchPlan, optional
        The plan of the search; the model's own by default.

    Returns
    -------
    ndarray of uint8, shape (len(windows), window, window, 3)

    Raises
    ------
    ValueError
        If a window is not one the plan searches in this frame.
    """
    frame = as_rgb_uint8(frame, name="frame")
    plan = model.detector_config.plan if plan is None else plan
    cfg = model.config
    side, ppc = cfg.window, cfg.pixels_per_cell
    out = np.empty((len(windows), side, side, 3), np.uint8)
    if not len(windows):
        return out
    if "scale_index" not in windows.data:
        raise ValueError("windows need data['scale_index'] (as search returns them)")
    work, f = _working_frame(frame, plan)
    scale_index = np.asarray(windows.data["scale_index"])
    for k in np.unique(scale_index):
        if not 0 <= k < len(plan.scales):
            raise ValueError(f"scale_index {k} is not a scale of the plan ({len(plan.scales)} scales)")
        band = _band(work, plan.scales[k], cfg, plan.overhang_of(plan.scales[k]), plan.y_shift, plan.reach_bottom)
        if band is None:
            raise ValueError(f"scale {k} of the plan searches no window in a {frame.shape[1]}x{frame.shape[0]} frame")
        boxes = _band_boxes(band, cfg, f, frame.shape)
        where = {tuple(b): i for i, b in enumerate(boxes.tolist())}
        n_cols = len(band.cols)
        for j in np.flatnonzero(scale_index == k):
            i = where.get(tuple(windows.xyxy[j].tolist()))
            if i is None:
                raise ValueError(f"window {windows.xyxy[j].tolist()} is not a window of scale {k} of the plan")
            r, c = band.rows[i // n_cols] * ppc, band.cols[i % n_cols] * ppc
            out[j] = band.image[r : r + side, c : c + side]
    return out


# --- the fast path -----------------------------------------------------------------------------


@njit(nogil=True, inline="always")
def _border_class(i, nbw):
    """Where block ``i`` (0..nbw-1) of a window lies along one axis: 1 first, 2 last, 0 inside."""
    return 1 if i == 0 else (2 if i == nbw - 1 else 0)


@njit(nogil=True)
def _windows_per_block(starts, nbw, lo, hi, seen):
    """Which windows hold each block along one axis, for :func:`_score_hog`.

    starts: the windows' first blocks, increasing. For each block ``k`` (``lo``, ``hi``, ``seen``
    all of length n_blocks): windows ``lo[k]..hi[k]-1`` hold it, and ``seen[k, b]`` says whether
    one of them has it in border class ``b`` (:func:`_border_class`).
    """
    n = starts.shape[0]
    first = 0
    for k in range(lo.shape[0]):
        while first < n and starts[first] + nbw <= k:
            first += 1
        last = first
        seen[k, :] = False
        while last < n and starts[last] <= k:
            seen[k, _border_class(k - starts[last], nbw)] = True
            last += 1
        lo[k], hi[k] = first, last


@njit(nogil=True, fastmath=True)
def _score_hog(variants, cpb, weights, rows, cols, ss, out):
    """Add the HOG part of every window's margin to ``out`` (len(rows), len(cols)).

    variants (C, 3, 3, n_cr, n_cc, nb) from :func:`~vehicle_detection.features.region_hog`;
    weights (C, nbw, nbw, bs) float32; rows, cols: the windows' top-left cells, increasing;
    ss (C, 3, 3, n_cr, n_cc) float64: the cells' sums of squares
    (:func:`~vehicle_detection.features._cell_squares` of each channel's variants).

    Block by block: each block position is normalised once for each border class some window
    sees it in (inside, or on a window's top, bottom, left or right border, or a corner), and
    at once dotted with the weights of every window it belongs to. No block map is stored.
    """
    n_ch, nbw, bs = weights.shape[0], weights.shape[1], weights.shape[3]
    n_br, n_bc = variants.shape[3] - cpb + 1, variants.shape[4] - cpb + 1
    row_lo, row_hi = np.empty(n_br, np.int64), np.empty(n_br, np.int64)
    col_lo, col_hi = np.empty(n_bc, np.int64), np.empty(n_bc, np.int64)
    row_seen, col_seen = np.empty((n_br, 3), np.bool_), np.empty((n_bc, 3), np.bool_)
    _windows_per_block(rows, nbw, row_lo, row_hi, row_seen)
    _windows_per_block(cols, nbw, col_lo, col_hi, col_seen)
    block = np.empty(bs, np.float32)
    for ch in range(n_ch):
        var = variants[ch]
        sq = ss[ch]
        for r in range(n_br):
            if row_hi[r] == row_lo[r]:
                continue
            for c in range(n_bc):
                if col_hi[c] == col_lo[c]:
                    continue
                for vclass in range(3):
                    if not row_seen[r, vclass]:
                        continue
                    for hclass in range(3):
                        if not col_seen[c, hclass]:
                            continue
                        scale = _clipped_block(var, sq, r, c, cpb, vclass, hclass, block)
                        for wr in range(row_lo[r], row_hi[r]):
                            i = r - rows[wr]
                            if _border_class(i, nbw) != vclass:
                                continue
                            for wc in range(col_lo[c], col_hi[c]):
                                j = c - cols[wc]
                                if _border_class(j, nbw) != hclass:
                                    continue
                                w = weights[ch, i, j]
                                t = np.float32(0.0)
                                for k in range(bs):
                                    t += block[k] * w[k]
                                out[wr, wc] += t * scale


@njit(nogil=True, fastmath=True)
def _score_blocks(blocks, weights, rows, cols, out):
    """Add the HOG part of every window's margin to ``out`` (len(rows), len(cols)), from a block map.

    blocks (C, n_br, n_bc, bs) float32 from :func:`~vehicle_detection.features.region_blocks`
    (normalised once, whatever window holds them); weights (C, nbw, nbw, bs) float32; rows,
    cols: the windows' top-left cells. Each window is the dot product of its ``nbw x nbw``
    blocks with the weights.
    """
    n_ch, nbw, bs = weights.shape[0], weights.shape[1], weights.shape[3]
    for wr in range(rows.shape[0]):
        r0 = rows[wr]
        for wc in range(cols.shape[0]):
            c0 = cols[wc]
            t = np.float32(0.0)
            for k in range(n_ch):
                for a in range(nbw):
                    for b in range(nbw):
                        block = blocks[k, r0 + a, c0 + b]
                        w = weights[k, a, b]
                        for j in range(bs):
                            t += block[j] * w[j]
            out[wr, wc] += t


@njit(nogil=True)
def _colour_sums(conv, f, ppc, hist_lut, bin_means, cell_scores):
    """One pass over the region for the colour features.

    bin_means (h // f, w // f, 3) float32: mean of each channel over each ``f x f`` block (the
    spatial bins of any window aligned to the ``f`` grid, as :func:`bin_spatial` computes
    them), each block summed in registers; cell_scores (h // ppc, w // ppc): sum over each
    cell's pixels of ``hist_lut[ch, value]``, the histogram weight of the pixel's bin (a
    window's histogram score is the sum over its cells). Outputs last, as in every kernel here.
    """
    nby, nbx = bin_means.shape[0], bin_means.shape[1]
    inv = 1.0 / (f * f)
    for by in range(nby):
        for bx in range(nbx):
            s0 = s1 = s2 = np.int64(0)  # not a Python 0: plain Python (no JIT) would add in uint8
            for y in range(by * f, (by + 1) * f):
                row = conv[y]
                for x in range(bx * f, (bx + 1) * f):
                    s0 += row[x, 0]
                    s1 += row[x, 1]
                    s2 += row[x, 2]
            bin_means[by, bx, 0] = np.float32(s0 * inv)
            bin_means[by, bx, 1] = np.float32(s1 * inv)
            bin_means[by, bx, 2] = np.float32(s2 * inv)
    for cy in range(cell_scores.shape[0]):
        for cx in range(cell_scores.shape[1]):
            s = 0.0
            for y in range(cy * ppc, (cy + 1) * ppc):
                for x in range(cx * ppc, (cx + 1) * ppc):
                    s += hist_lut[0, conv[y, x, 0]] + hist_lut[1, conv[y, x, 1]] + hist_lut[2, conv[y, x, 2]]
            cell_scores[cy, cx] = s


@njit(nogil=True, fastmath=True)
def _score_colour(means, weights, f, cell_scores, cpw, ppc, rows, cols, with_hist, out):
    """Add the spatial-bin and histogram parts of every window's margin to ``out``.

    means (h // f, w // f * 3) float32: the bin means, a row of bins' channels in a row;
    weights (size, size * 3): the spatial weights the same way (no rows: no spatial part). A
    window's row of spatial bins is contiguous in both.
    """
    size, run = weights.shape[0], weights.shape[1]
    for wr in range(rows.shape[0]):
        r0 = rows[wr]
        for wc in range(cols.shape[0]):
            c0 = cols[wc]
            s = 0.0
            if size:
                by0 = r0 * ppc // f
                x0 = (c0 * ppc // f) * 3
                for by in range(size):
                    m = means[by0 + by]
                    w = weights[by]
                    for k in range(run):
                        s += m[x0 + k] * w[k]
            if with_hist:
                for cy in range(r0, r0 + cpw):
                    for cx in range(c0, c0 + cpw):
                        s += cell_scores[cy, cx]
            out[wr, wc] += s


@njit(nogil=True, fastmath=True, inline="always")
def _add_products(block, hog_w, ch, a, b, out):
    """``out[k] += block . hog_w[k, ch, a, b]`` for each of the K maps (one block of one window)."""
    for k in range(hog_w.shape[0]):
        w = hog_w[k, ch, a, b]
        t = 0.0
        for j in range(w.shape[0]):
            t += block[j] * w[j]
        out[k] += t


@njit(nogil=True, fastmath=True)
def _hog_products_crop(variants, cpb, hog_w, rows, cols, out):
    """The HOG part of :func:`_colour_products`'s maps, for windows seen as their crops.

    Blocks are gathered from the cell variants with each window's border classes and normalised
    (:func:`~vehicle_detection.features.region_hog`); ``out[i, k]`` (n, K) gets their dot
    products with ``hog_w[k]`` (K, C, nbw, nbw, bs).
    """
    n_ch, nbw, bs = hog_w.shape[1], hog_w.shape[2], hog_w.shape[4]
    block = np.empty(bs, np.float64)
    for i in range(rows.shape[0]):
        r0, c0 = rows[i], cols[i]
        for ch in range(n_ch):
            var = variants[ch]
            for a in range(nbw):
                for b in range(nbw):
                    _gather_block(var, r0 + a, c0 + b, cpb, _border_class(a, nbw), _border_class(b, nbw), block)
                    _add_products(block, hog_w, ch, a, b, out[i])


@njit(nogil=True, fastmath=True)
def _hog_products_frame(blocks, hog_w, rows, cols, out):
    """:func:`_hog_products_crop` for windows that see the frame across their border: the blocks
    are read off the band's block map (C, n_br, n_bc, bs) as they are."""
    n_ch, nbw = hog_w.shape[1], hog_w.shape[2]
    for i in range(rows.shape[0]):
        r0, c0 = rows[i], cols[i]
        for ch in range(n_ch):
            for a in range(nbw):
                for b in range(nbw):
                    _add_products(blocks[ch, r0 + a, c0 + b], hog_w, ch, a, b, out[i])


@njit(nogil=True, fastmath=True)
def _colour_products(means, spatial_w, f, conv, hist_lut, ppc, cpw, rows, cols, cell_maps, done, out):
    """Linear maps of the colour part of chosen windows' feature vectors, read off the band's features.

    The window whose top-left cell is ``(rows[i], cols[i])`` has the spatial bins ``means``
    (the bin means as :func:`_score_colour` reads them) and the histograms counted on ``conv``, as
    :func:`~vehicle_detection.features.extract_features` gives them for its patch. ``out[i, k]``
    (n, K) gets their dot products with ``spatial_w[k]`` (K, size, size * 3) and the histogram
    weights ``hist_lut[k]`` (K, 3, 256: the weight of each 8-bit value's bin). The histogram
    part is summed over the window's cells: ``cell_maps`` (n_cr, n_cc, K) holds each cell's
    share once ``done`` (n_cr, n_cc) says so (computed here when first needed).
    """
    n_maps = out.shape[1]
    size = spatial_w.shape[1]
    run = size * 3
    with_hist = hist_lut.shape[0] == n_maps
    for i in range(rows.shape[0]):
        r0, c0 = rows[i], cols[i]
        if size:
            by0, x0 = r0 * ppc // f, (c0 * ppc // f) * 3
            for k in range(n_maps):
                t = 0.0
                for by in range(size):
                    for j in range(run):
                        t += means[by0 + by, x0 + j] * spatial_w[k, by, j]
                out[i, k] += t
        if with_hist:
            for cy in range(r0, r0 + cpw):
                for cx in range(c0, c0 + cpw):
                    if not done[cy, cx]:
                        for k in range(n_maps):
                            t = 0.0
                            for y in range(cy * ppc, (cy + 1) * ppc):
                                for x in range(cx * ppc, (cx + 1) * ppc):
                                    t += hist_lut[k, 0, conv[y, x, 0]] + hist_lut[k, 1, conv[y, x, 1]] + hist_lut[k, 2, conv[y, x, 2]]
                            cell_maps[cy, cx, k] = t
                        done[cy, cx] = True
                    for k in range(n_maps):
                        out[i, k] += cell_maps[cy, cx, k]


_BUFFERS = threading.local()


_MAX_BUFFERS = 32


def _buffer(name: str, shape: tuple, dtype=np.float64) -> np.ndarray:
    """A work array reused across frames (per thread): no page faults per frame.

    Only whole bands use it (their shapes come back every frame; the crops of a scheduled
    search change shape with the tracks and are not kept). At most ``_MAX_BUFFERS`` are kept,
    the most recently used, so memory stays bounded whatever plans are searched.
    """
    cache = getattr(_BUFFERS, "arrays", None)
    if cache is None:
        cache = _BUFFERS.arrays = OrderedDict()
    key = (name, shape, np.dtype(dtype).str)  # one per band shape: scales alternate every frame
    arr = cache.get(key)
    if arr is None:
        arr = cache[key] = np.empty(shape, dtype)
        while len(cache) > _MAX_BUFFERS:
            cache.popitem(last=False)
    else:
        cache.move_to_end(key)
    return arr


def _hist_lut(weights: np.ndarray) -> np.ndarray:
    """Histogram weights ``(..., bins)`` as the weight of each 8-bit value's bin ``(..., 256)``."""
    bins = weights.shape[-1]
    return np.ascontiguousarray(weights[..., (np.arange(256) * bins) // 256])


class _KernelWeights:
    """A model's folded weights split by feature part, in the layouts the kernels read."""

    def __init__(self, model: WindowScorer):
        cfg = model.config
        w, lay = model.weights, cfg.layout()
        self.bias = model.bias
        size = cfg.spatial_size
        self.spatial = w[lay["spatial"]].reshape(size, size * 3) if size else np.zeros((0, 0))
        # Weight of each 8-bit value's histogram bin, per channel: (3, 256).
        self.hist_lut = _hist_lut(w[lay["hist"]].reshape(3, cfg.hist_bins) if cfg.hist_bins else np.zeros((3, 1)))
        nbw = cfg.blocks_per_window
        # float32 like the blocks: half the memory traffic of float64
        self.hog = np.ascontiguousarray(w[lay["hog"]].reshape(len(cfg.hog_channels), nbw, nbw, cfg.block_size), np.float32)
        # The box refinement's four edge maps, in the same layouts (float64: few windows use them).
        reg = model.box_regressor
        self.refine = None
        if reg is not None:
            k, size, bins = reg.coef, cfg.spatial_size, cfg.hist_bins
            self.refine = (
                np.ascontiguousarray(k[:, lay["hog"]].reshape(4, len(cfg.hog_channels), nbw, nbw, cfg.block_size)),
                np.ascontiguousarray(k[:, lay["spatial"]].reshape(4, size, size * 3)),
                _hist_lut(k[:, lay["hist"]].reshape(4, 3, bins)) if bins else np.zeros((0, 3, 256)),
            )


# Models are immutable, so their kernel weights are computed once per model and dropped with it.
_KERNEL_WEIGHTS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()


def _kernel_weights(model: WindowScorer) -> _KernelWeights:
    kw = _KERNEL_WEIGHTS.get(model)
    if kw is None:
        kw = _KERNEL_WEIGHTS[model] = _KernelWeights(model)
    return kw


def _next_to(seeds: np.ndarray) -> np.ndarray:
    """Cells of a boolean grid next to (or on) a True one: a 3x3 dilation."""
    out = seeds.copy()
    out[1:] |= seeds[:-1]
    out[:-1] |= seeds[1:]
    rows = out.copy()
    out[:, 1:] |= rows[:, :-1]
    out[:, :-1] |= rows[:, 1:]
    return out


@dataclass
class _BandFeatures:
    """One band's features, shared by the kernels that score its windows."""

    conv: np.ndarray  # (h, w, 3) uint8, the model's colour space
    variants: np.ndarray | None  # (C, 3, 3, n_cr, n_cc, nb) float32 HOG cell variants (window_border "crop")
    squares: np.ndarray | None  # (C, 3, 3, n_cr, n_cc) float64 their sums of squares
    blocks: np.ndarray | None  # (C, n_br, n_bc, bs) float32 normalised blocks (window_border "frame")
    bin_means: np.ndarray  # (h // f, w // f, 3) float32 spatial-bin means
    cell_scores: np.ndarray | None  # (n_cr, n_cc) float64 histogram score of each cell
    f: int  # pixels per spatial bin

    @property
    def bin_rows(self) -> np.ndarray:
        """The bin means as the colour kernels read them: (h // f, w // f * 3), a view."""
        return self.bin_means.reshape(self.bin_means.shape[0], -1)


def _band_features(band: _Band, model: WindowScorer, buffer, hog_blocks: bool, frame: bool) -> _BandFeatures:
    cfg, folded = model.config, _kernel_weights(model)
    conv = convert_color(band.image, cfg.color_space)
    ppc, cpb, n_hc = cfg.pixels_per_cell, cfg.cells_per_block, len(cfg.hog_channels)
    n_cr, n_cc = conv.shape[0] // ppc, conv.shape[1] // ppc
    variants = squares = blocks = None
    if frame:
        cells = buffer("cells", (n_hc, n_cr, n_cc, cfg.orientations), np.float32)
        planes = _planes(hog_input(conv, cfg), cfg.hog_channels, buffer("planes", (n_hc,) + conv.shape[:2], np.uint8))
        _region_cells(planes, _flat_lut(cfg.orientations, cfg.signed), ppc, cfg.orientations,
                      *_cell_work(n_cc, ppc, cfg.orientations), cells)
        blocks = buffer("blocks", (n_hc, n_cr - cpb + 1, n_cc - cpb + 1, cfg.block_size), np.float32)
        if hog_blocks:
            _block_map(cells, cpb, blocks)
        else:
            blocks.fill(0.0)  # the warm-up's blank search, without the block kernel (scored: that kernel compiles)
    else:
        # Cells are summed in float64 and stored in float32: half the memory traffic; margins
        # stay within 1e-6 of the plain path's (float64 throughout).
        variants = buffer("variants", (n_hc, 3, 3, n_cr, n_cc, cfg.orientations), np.float32)
        region_hog(hog_input(conv, cfg), cfg, out=variants)
        if hog_blocks:
            squares = buffer("cell_squares", (n_hc, 3, 3, n_cr, n_cc))
            for ch in range(n_hc):
                _cell_squares(variants[ch], squares[ch])
    f = cfg.window // cfg.spatial_size if cfg.spatial_size else ppc
    bin_means = buffer("bin_means", (conv.shape[0] // f, conv.shape[1] // f, 3), np.float32)
    cell_scores = None
    if cfg.spatial_size or cfg.hist_bins:
        cell_scores = buffer("cell_scores", (n_cr, n_cc))
        _colour_sums(conv, f, ppc, folded.hist_lut, bin_means, cell_scores)
    return _BandFeatures(conv, variants, squares, blocks, bin_means, cell_scores, f)


def _margins(feats: _BandFeatures, model: WindowScorer, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Margins of the windows at ``rows`` x ``cols`` (top-left cells, increasing): ``(len(rows), len(cols))``."""
    cfg, folded = model.config, _kernel_weights(model)
    out = np.zeros((len(rows), len(cols)))
    if feats.blocks is not None:
        _score_blocks(feats.blocks, folded.hog, rows, cols, out)
    elif feats.squares is not None:
        _score_hog(feats.variants, cfg.cells_per_block, folded.hog, rows, cols, feats.squares, out)
    if feats.cell_scores is not None:
        _score_colour(feats.bin_rows, folded.spatial, feats.f, feats.cell_scores, cfg.cells_per_window, cfg.pixels_per_cell,
                      rows, cols, bool(cfg.hist_bins), out)
    return out + folded.bias


def _two_stage_margins(feats: _BandFeatures, model: WindowScorer, band: _Band, threshold: float, margin: float) -> np.ndarray:
    """The two-stage search of :attr:`SearchPlan.coarse_margin`: ``(rows, cols)``, -inf where not scored."""
    first = np.zeros((len(band.rows), len(band.cols)), bool)
    first[::2, ::2] = True
    margins = np.full(first.shape, -np.inf)
    # contiguous copies: a strided view would make numba compile the kernels once more for it
    margins[::2, ::2] = _margins(feats, model, np.ascontiguousarray(band.rows[::2]), np.ascontiguousarray(band.cols[::2]))
    # The second stage: the windows next to a first-stage window within the margin, scored by
    # the same kernels a band row at a time (the cell sums of squares are computed once).
    second = _next_to(margins > threshold - margin) & ~first
    for i in np.flatnonzero(second.any(axis=1)):
        at = np.flatnonzero(second[i])
        margins[i, at] = _margins(feats, model, band.rows[i : i + 1], band.cols[at])[0]
    return margins


def _refine_products(feats: _BandFeatures, model: WindowScorer, band: _Band, index: np.ndarray) -> np.ndarray:
    """The box refinement's four edge maps (before its intercept) of the windows at flat ``index``: ``(n, 4)``."""
    cfg, refine = model.config, _kernel_weights(model).refine
    ppc = cfg.pixels_per_cell
    n_cr, n_cc = feats.conv.shape[0] // ppc, feats.conv.shape[1] // ppc
    out = np.zeros((len(index), 4))
    if len(index):
        rows, cols = band.rows[index // len(band.cols)], band.cols[index % len(band.cols)]
        _refine_hog(feats, model, rows, cols, out)
        _colour_products(feats.bin_rows, refine[1], feats.f, feats.conv, refine[2], ppc, cfg.cells_per_window,
                         rows, cols, np.empty((n_cr, n_cc, 4)), np.zeros((n_cr, n_cc), np.bool_), out)
    return out


def _refine_hog(feats: _BandFeatures, model: WindowScorer, rows: np.ndarray, cols: np.ndarray, out: np.ndarray) -> None:
    """The HOG part of :func:`_refine_products` for the windows at ``rows``, ``cols``, added to ``out`` (n, 4)."""
    refine = _kernel_weights(model).refine
    if feats.blocks is not None:
        _hog_products_frame(feats.blocks, refine[0], rows, cols, out)
    else:
        _hog_products_crop(feats.variants, model.config.cells_per_block, refine[0], rows, cols, out)


def _score_band(band: _Band, model: WindowScorer, reuse: bool = True, hog_blocks: bool = True,
                refine_above: float | None = None,
                cascade: tuple[float, float] | None = None, frame: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    """Margins of the windows of ``band``, and the box refinement's products of the hot ones.

    Returns ``(margins, products)``: margins flat ``(n_windows,)``; with ``refine_above`` and a
    model that refines its boxes, ``products`` ``(n_windows, 4)`` holds the four edge maps
    (:class:`~vehicle_detection.refine.BoxRegressor`, before its intercept) of every window
    whose margin exceeds it, read off the band's features, and NaN elsewhere; else None.

    ``cascade=(threshold, coarse_margin)``: the two-stage search of
    :attr:`SearchPlan.coarse_margin` (windows not scored get ``-inf``); None scores every window.
    ``reuse``: work arrays kept for the next frame (whole bands). ``hog_blocks=False`` (the
    warm-up, whose helper process compiles the block kernel meanwhile) leaves the HOG blocks
    zero: with ``"frame"`` they are still scored, with ``"crop"`` their part of the margins is
    left out. ``frame``: the plan's ``window_border`` is ``"frame"``.
    """
    buffer = _buffer if reuse else (lambda name, shape, dtype=np.float64: np.empty(shape, dtype))
    feats = _band_features(band, model, buffer, hog_blocks, frame)
    if cascade is not None and hog_blocks:
        margins = _two_stage_margins(feats, model, band, *cascade).ravel()
    else:
        margins = _margins(feats, model, band.rows, band.cols).ravel()
    if refine_above is None or model.box_regressor is None:
        return margins, None
    products = np.full((len(margins), 4), np.nan)
    hot = np.flatnonzero(margins > refine_above)
    products[hot] = _refine_products(feats, model, band, hot)
    return margins, products


def _scheduled_mask(band: _Band, config: FeatureConfig, plan: SearchPlan, work_width: int, around: np.ndarray) -> np.ndarray:
    """Which windows of ``band`` a between-frames search scores (see :class:`SearchPlan`), ``(rows, cols)`` bool.

    ``around``: live track boxes in working-frame pixels, ``(n, 4)`` float.
    """
    ppc, side = config.pixels_per_cell, config.window
    x1 = band.x0 + band.cols * ppc * band.sx  # (n_cols,) unclipped, working-frame pixels
    x2 = x1 + side * band.sx
    y1 = band.y0 + band.rows * ppc * band.sy  # (n_rows,)
    y2 = y1 + side * band.sy
    edge = ((x2 <= plan.edge_width) | (x1 >= work_width - plan.edge_width)) & (plan.edge_width > 0)
    top = min(plan.scales, key=lambda s: (s.scale, s.y_start)).y_start + plan.y_shift  # the smallest windows' band
    horizon = (y1 >= top) & (y2 <= top + plan.horizon_height)
    mask = edge[None, :] | horizon[:, None]
    if len(around):
        a = around
        w, h = a[:, 2] - a[:, 0], a[:, 3] - a[:, 1]
        m = plan.track_margin
        gx1, gy1, gx2, gy2 = a[:, 0] - m * w, a[:, 1] - m * h, a[:, 2] + m * w, a[:, 3] + m * h
        cols_hit = (x1[None, :] < gx2[:, None]) & (x2[None, :] > gx1[:, None])  # (n, n_cols)
        rows_hit = (y1[None, :] < gy2[:, None]) & (y2[None, :] > gy1[:, None])  # (n, n_rows)
        mask |= (rows_hit[:, :, None] & cols_hit[:, None, :]).any(axis=0)
    return mask


def _score_band_where(band: _Band, model: WindowScorer, mask: np.ndarray, refine_above: float | None = None,
                      cascade: tuple[float, float] | None = None, frame: bool = True) -> tuple[np.ndarray, np.ndarray | None]:
    """:func:`_score_band` of the band's windows where ``mask`` holds, flat like it.

    The other margins are -inf, or their margins where a crop or the whole band scored them
    anyway: callers keep the windows of ``mask`` only.

    Windows see only their own pixels and, with ``frame``, one pixel around them (the
    gradient across their border), so each run of wanted columns is scored on a crop of the
    band holding just its windows and that pixel (a whole cell above and to the left, so that the
    cells stay where they are), with the same margins as the whole band gives.
    """
    cfg = model.config
    ppc, side = cfg.pixels_per_cell, cfg.window
    out = np.full(mask.shape, -np.inf)
    products = None if refine_above is None or model.box_regressor is None else np.full(mask.shape + (4,), np.nan)
    wanted = mask.any(axis=0)
    if not wanted.any():
        return out.ravel(), None if products is None else products.reshape(-1, 4)
    if wanted.all() and mask.any(axis=1).all():
        return _score_band(band, model, refine_above=refine_above, cascade=cascade, frame=frame)
    edges = np.flatnonzero(np.diff(np.r_[0, wanted.astype(np.int8), 0]))
    for a, b in zip(edges[::2], edges[1::2]):  # columns a..b-1
        rows_any = np.flatnonzero(mask[:, a:b].any(axis=1))
        r0, r1 = rows_any[0], rows_any[-1] + 1
        top, left = band.rows[r0] * ppc, band.cols[a] * ppc
        bottom, right = band.rows[r1 - 1] * ppc + side, band.cols[b - 1] * ppc + side
        up = min(ppc, top) if frame else 0  # the context around the windows, where the band has it
        back = min(ppc, left) if frame else 0
        bottom, right = (min(bottom + 1, band.image.shape[0]), min(right + 1, band.image.shape[1])) if frame else (bottom, right)
        image = band.image[top - up : bottom, left - back : right]
        sub = _Band(np.ascontiguousarray(image), 0, 0, band.sx, band.sy,
                    band.rows[r0:r1] - band.rows[r0] + up // ppc, band.cols[a:b] - band.cols[a] + back // ppc)
        margins, found = _score_band(sub, model, reuse=False, refine_above=refine_above, cascade=cascade,
                                     frame=frame)  # shapes vary
        out[r0:r1, a:b] = margins.reshape(r1 - r0, b - a)
        if products is not None:
            products[r0:r1, a:b] = found.reshape(r1 - r0, b - a, 4)
    return out.ravel(), None if products is None else products.reshape(-1, 4)


def search(
    frame: np.ndarray,
    model: WindowScorer,
    plan: SearchPlan | None = None,
    *,
    all_windows: bool = False,
    around: np.ndarray | None = None,
) -> Detections:
    """Find the windows the classifier calls vehicles, scoring every window of the plan at once.

    Parameters
    ----------
    frame : ndarray of uint8, shape (H, W, 3)
        RGB frame (any size; resized internally to ``plan.reference_height``).
    model : WindowScorer
    plan : SearchPlan, optional
        The model's own plan by default.
    all_windows : bool
        Return every window with its margin instead of only those above ``plan.threshold``.
    around : ndarray, shape (n, 4), optional
        None (the default) searches the whole plan. Otherwise the search between two full
        searches of :attr:`SearchPlan.full_search_every`: only the windows at the frame edges,
        near the horizon and overlapping these boxes (live tracks, in ``frame``'s pixels) grown
        by ``plan.track_margin``; each with the same margin the whole search gives it.

    Returns
    -------
    Detections
        Windows in ``frame``'s pixels with their margins as ``score`` and the index of the
        plan's scale that produced each as ``data["scale_index"]``.
    """
    frame = as_rgb_uint8(frame, name="frame")
    plan = model.detector_config.plan if plan is None else plan
    work, f = _working_frame(frame, plan)
    cfg = model.config
    if around is not None:
        around = np.asarray(around, np.float64).reshape(-1, 4) * f
    if model.convnet is not None:
        return _search_convnet(frame, work, f, model, plan, all_windows=all_windows, around=around)
    refine = model.box_regressor is not None and not all_windows
    above = plan.threshold if refine else None
    cascade = None if all_windows or plan.coarse_margin is None else (plan.threshold, plan.coarse_margin)
    border = plan.window_border == "frame"
    boxes, scores, scales, windows, products = [], [], [], [], []
    for k, s in enumerate(plan.scales):
        band = _band(work, s, cfg, plan.overhang_of(s), plan.y_shift, plan.reach_bottom)
        if band is None:
            continue
        if around is None:
            margins, found = _score_band(band, model, refine_above=above, cascade=cascade, frame=border)
            keep = slice(None) if all_windows else margins > plan.threshold
        else:
            mask = _scheduled_mask(band, cfg, plan, work.shape[1], around)
            margins, found = _score_band_where(band, model, mask, refine_above=above, cascade=cascade, frame=border)
            keep = mask.ravel() if all_windows else mask.ravel() & (margins > plan.threshold)
        kept = _band_windows(band, cfg, f, keep)  # once: the boxes, and the refinement's windows
        boxes.append(_clipped_boxes(kept, frame.shape))
        scores.append(margins[keep])
        scales.append(np.full(len(kept), k, np.int64))
        if refine:
            windows.append(kept)
            products.append(found[keep])
    if not boxes:  # no band fits the frame
        boxes, scores, scales = [np.zeros((0, 4), np.int64)], [np.zeros(0)], [np.zeros(0, np.int64)]
    data = {"scale_index": np.concatenate(scales)}
    if refine:
        refined = np.zeros((0, 4), np.int64)
        if len(data["scale_index"]):
            refined = model.box_regressor.refine_products(np.concatenate(windows), np.concatenate(products), frame.shape)
        data["box"] = refined
    # one Detections for the frame (its checks once, not once per scale)
    return Detections(np.concatenate(boxes), score=np.concatenate(scores), data=data)


def _search_convnet(frame: np.ndarray, work: np.ndarray, f: float, model: WindowScorer, plan: SearchPlan, *,
                    all_windows: bool, around: np.ndarray | None) -> Detections:
    """:func:`search` with the model's network: each band scored whole in one pass
    (:meth:`~vehicle_detection.convnet.ConvNet.scores`), the hot windows' boxes moved by the
    network's edge offsets (``data["box"]``, as the box refinement gives them)."""
    cfg = model.config
    boxes, scores, scales, windows, offsets = [], [], [], [], []
    for k, s in enumerate(plan.scales):
        band = _band(work, s, cfg, plan.overhang_of(s), plan.y_shift, plan.reach_bottom)
        if band is None:
            continue
        out = model.convnet.scores(band.image)[np.ix_(band.rows, band.cols)].reshape(-1, 5)
        margins = out[:, 0].astype(np.float64)
        keep = np.ones(len(margins), bool) if all_windows else margins > plan.threshold
        if around is not None:
            keep &= _scheduled_mask(band, cfg, plan, work.shape[1], around).ravel()
        kept = _band_windows(band, cfg, f, keep)
        boxes.append(_clipped_boxes(kept, frame.shape))
        scores.append(margins[keep])
        scales.append(np.full(len(kept), k, np.int64))
        windows.append(kept)
        offsets.append(out[keep, 1:])
    if not boxes:
        boxes, scores, scales, windows, offsets = ([np.zeros((0, 4), np.int64)], [np.zeros(0)], [np.zeros(0, np.int64)],
                                                   [np.zeros((0, 4))], [np.zeros((0, 4), np.float32)])
    data = {"scale_index": np.concatenate(scales)}
    if not all_windows:
        wins = np.concatenate(windows)
        data["box"] = apply_offsets(wins, np.concatenate(offsets), frame.shape) if len(wins) else np.zeros((0, 4), np.int64)
    return Detections(np.concatenate(boxes), score=np.concatenate(scores), data=data)
