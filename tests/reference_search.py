"""The plain search path, the reference the fast search is tested against (the oracle tests use it).

For plans with ``window_border="frame"``, each window's HOG is cut from the gradients of its
whole band (:func:`frame_hog_plain`), in NumPy, instead of from its crop.

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
from vehicle_detection.features import _orientation_lut, convert_color, extract_features, hog_input
from vehicle_detection.io.images import as_rgb_uint8
from vehicle_detection.search import SearchPlan, _band, _band_boxes, _working_frame

__all__ = ["slide_window", "classify_windows", "search_plain"]


def _windows(boxes: np.ndarray, scores: np.ndarray, scale_index: int) -> Detections:
    """One scale's windows as the search reports them (``scale_index`` in ``data``)."""
    return Detections(boxes, score=scores, data={"scale_index": np.full(len(scores), scale_index, np.int64)})


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
        corners = [(r * ppc, c * ppc) for r in band.rows for c in band.cols]
        patches = np.stack([band.image[y : y + side, x : x + side] for y, x in corners])
        feats = extract_features(patches, cfg)
        if plan.window_border == "frame":
            feats[:, cfg.layout()["hog"]] = frame_hog_plain(band.image, corners, cfg)
        scores = model.decision_function(feats)
        parts.append(_windows(_band_boxes(band, cfg, f, frame.shape), scores, k))
    return Detections.concatenate(parts) if parts else _windows(np.zeros((0, 4), np.int64), np.zeros(0), 0)


def frame_hog_plain(image: np.ndarray, corners, cfg) -> np.ndarray:
    """HOG of windows that see the band's gradient across their border, one window at a time.

    The gradient of the whole band (central differences, zero on the band's border), binned as
    the patch path bins it; each window's cells are its 64 x 64 gradients' histograms, and each
    block is L2-Hys normalised (scikit-image's order: block row, block column, cell row, cell
    column, bin; channels one after the other).

    Parameters
    ----------
    image : ndarray of uint8, shape (H, W, 3)
        The band, RGB.
    corners : list of (int, int)
        Each window's top-left pixel ``(y, x)`` in the band.

    Returns
    -------
    ndarray of float64, shape (len(corners), n_hog)
    """
    pixels = hog_input(convert_color(image, cfg.color_space), cfg).astype(np.int64)
    ppc, nb, side = cfg.pixels_per_cell, cfg.orientations, cfg.window
    lut = _orientation_lut(nb, cfg.signed)
    n = side // ppc
    cell_of = (np.arange(side)[:, None] // ppc) * n + np.arange(side)[None, :] // ppc  # (side, side)
    out = []
    for ch in cfg.hog_channels:
        p = pixels[:, :, ch]
        gx, gy = np.zeros_like(p), np.zeros_like(p)
        gx[:, 1:-1] = p[:, 2:] - p[:, :-2]
        gy[1:-1, :] = p[2:, :] - p[:-2, :]
        mag, bins = np.hypot(gx, gy), lut[gy + 255, gx + 255].astype(np.int64)
        per_channel = []
        for y, x in corners:
            votes = np.bincount((cell_of * (nb + 1) + bins[y : y + side, x : x + side]).ravel(),
                                weights=mag[y : y + side, x : x + side].ravel(), minlength=n * n * (nb + 1))
            cells = votes.reshape(n, n, nb + 1)[:, :, :nb]  # bin nb: votes counted in no bin
            m = n - cfg.cells_per_block + 1
            blocks = np.stack([cells[a : a + m, b : b + m] for a in range(cfg.cells_per_block) for b in range(cfg.cells_per_block)],
                              axis=2).reshape(m, m, -1)
            blocks = blocks / np.sqrt((blocks**2).sum(axis=-1, keepdims=True) + 1e-10)
            blocks = np.minimum(blocks, 0.2)
            blocks = blocks / np.sqrt((blocks**2).sum(axis=-1, keepdims=True) + 1e-10)
            per_channel.append(blocks.ravel())
        out.append(np.stack(per_channel))
    return np.concatenate(out, axis=1)
