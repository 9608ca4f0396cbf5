"""The plain search path, the reference the fast search is tested against (the oracle tests use it).

Kept with the tests, not in the package: nothing of the library calls it. :func:`slide_window`
lists windows and :func:`classify_windows` crops, resizes and classifies each one;
:func:`search_plain` does the same over a :class:`~vehicle_detection.search.SearchPlan`, one
window at a time, through the search's own band geometry (so both give the same windows in the
same order).
"""

from __future__ import annotations

import cv2
import numpy as np

from vehicle_detection.classifier import VehicleClassifier
from vehicle_detection.detections import Detections
from vehicle_detection.features import extract_features
from vehicle_detection.io.images import as_rgb_uint8
from vehicle_detection.search import SearchPlan, _band, _band_boxes, _windows, _working_frame

__all__ = ["slide_window", "classify_windows", "search_plain"]


def slide_window(image_shape, x_start_stop=(None, None), y_start_stop=(None, None), xy_window=(64, 64), xy_overlap=(0.5, 0.5)):
    """List the windows of one size over a region (the classic teaching version).

    Parameters
    ----------
    image_shape : tuple
        ``(H, W, ...)`` of the frame.
    x_start_stop, y_start_stop : pair of int or None
        Region; None means the frame edge.
    xy_window : (int, int)
        Window width and height in pixels.
    xy_overlap : (float, float)
        Fraction of overlap between neighbours, in [0, 1).

    Returns
    -------
    ndarray of int64, shape (n, 4)
        ``[x1, y1, x2, y2]`` boxes, row by row.
    """
    h, w = image_shape[:2]
    x0, x1 = (x_start_stop[0] or 0), (x_start_stop[1] if x_start_stop[1] is not None else w)
    y0, y1 = (y_start_stop[0] or 0), (y_start_stop[1] if y_start_stop[1] is not None else h)
    ww, wh = xy_window
    if not (0 <= xy_overlap[0] < 1 and 0 <= xy_overlap[1] < 1):
        raise ValueError("overlap must be in [0, 1)")
    sx = max(1, int(ww * (1 - xy_overlap[0])))
    sy = max(1, int(wh * (1 - xy_overlap[1])))
    xs = np.arange(x0, x1 - ww + 1, sx)
    ys = np.arange(y0, y1 - wh + 1, sy)
    yy, xx = np.meshgrid(ys, xs, indexing="ij")
    return np.stack([xx.ravel(), yy.ravel(), xx.ravel() + ww, yy.ravel() + wh], axis=1).astype(np.int64)


def classify_windows(image: np.ndarray, windows: np.ndarray, model: VehicleClassifier) -> np.ndarray:
    """Margins of windows cropped from an RGB frame and resized to the model's patch size.

    Parameters
    ----------
    image : ndarray of uint8, shape (H, W, 3)
    windows : ndarray of int, shape (n, 4)
    model : VehicleClassifier

    Returns
    -------
    ndarray of float64, shape (n,)
    """
    image = as_rgb_uint8(image)
    side = model.config.window
    patches = np.empty((len(windows), side, side, 3), np.uint8)
    for i, (x1, y1, x2, y2) in enumerate(np.asarray(windows)):
        crop = image[y1:y2, x1:x2]
        patches[i] = crop if crop.shape[:2] == (side, side) else cv2.resize(crop, (side, side), interpolation=cv2.INTER_AREA)
    return model.decision_images(patches) if len(patches) else np.zeros(0)


def search_plain(frame: np.ndarray, model: VehicleClassifier, plan: SearchPlan | None = None) -> Detections:
    """Score every window of the plan one at a time: crop, extract features, classify.

    The reference the fast :func:`search` is tested against; about 100 times slower.

    Returns
    -------
    Detections
        All windows (not thresholded), in the order of :func:`search`, with their margins as
        ``score`` and ``data["scale_index"]``.
    """
    frame = as_rgb_uint8(frame, name="frame")
    plan = model.detector_config.plan if plan is None else plan
    work, f = _working_frame(frame, plan)
    cfg = model.config
    side, ppc = cfg.window, cfg.pixels_per_cell
    parts = []
    for k, s in enumerate(plan.scales):
        band = _band(work, s, cfg, plan.overhang_of(s), plan.y_shift)
        if band is None:
            continue
        patches = np.stack(
            [band.image[r * ppc : r * ppc + side, c * ppc : c * ppc + side] for r in band.rows for c in band.cols]
        )
        scores = model.decision_function(extract_features(patches, cfg))
        parts.append(_windows(_band_boxes(band, cfg, f, frame.shape), scores, k))
    return Detections.concatenate(parts) if parts else _windows(np.zeros((0, 4), np.int64), np.zeros(0), 0)
