"""Heat maps: accumulate detection windows, threshold them, and turn the hot blobs into boxes.

A heat map counts, per cell, how much detection evidence covers it. It may be coarser than the
frame: with ``cell = c`` a frame of ``(H, W)`` pixels has a heat map of ``(H // c, W // c)``
cells, heat cell ``(i, j)`` standing for the pixels ``[i*c, (i+1)*c) x [j*c, (j+1)*c)``. The
last ``H % c`` rows and ``W % c`` columns of the frame have no cell; boxes reaching into them
are clipped to the map. ``cell = 8`` (the detector's default) makes every step here about 64
times cheaper than a per-pixel map while staying far finer than the smallest window (64 px).

Boxes are ``(n, 4)`` arrays ``[x1, y1, x2, y2]`` in frame pixels, x2/y2 exclusive.

Typical use::

    heat = add_heat(np.zeros((720 // 8, 1280 // 8), np.float32), windows, scores + 1, cell=8)
    boxes, peaks = heat_to_boxes(heat, threshold=2.0, cell=8)
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np
from numpy.typing import ArrayLike

from .detections import Detections
from .geometry import as_boxes, box_area, box_intersection, box_iou

__all__ = [
    "add_heat",
    "cluster_boxes",
    "split_blobs",
    "vote_boxes",
    "apply_threshold",
    "label_heat",
    "blob_boxes",
    "heat_to_boxes",
]

_DEFAULT_MIN_SIZE = (32, 32)
_DEFAULT_ASPECT_RANGE = (0.3, 4.0)
_CONNECTIVITIES = (4, 8)


def _label(mask: np.ndarray, connectivity: int) -> tuple[np.ndarray, int]:
    """``scipy.ndimage.label`` of a 2-D bool mask with the 4- or 8-neighbour structure.

    The same labels (int32, numbered in the raster order of each blob's first cell) from
    OpenCV's connected components, which is already imported: scipy.ndimage and
    scipy.optimize would add a quarter of a second to every start.
    """
    m = np.ascontiguousarray(mask, dtype=np.uint8)
    if m.size == 0:
        return np.zeros(mask.shape, np.int32), 0
    n, labels = cv2.connectedComponents(m, connectivity=connectivity, ltype=cv2.CV_32S)
    n -= 1
    if n > 1:
        flat = labels.ravel()
        found, first = np.unique(flat, return_index=True)
        order = np.argsort(first[1:], kind="stable")  # labels by their first cell in raster order
        remap = np.zeros(n + 1, np.int32)
        remap[found[1:][order]] = np.arange(1, n + 1, dtype=np.int32)
        labels = remap[labels]
    return labels, int(n)


def _find_objects(labels: np.ndarray, n: int) -> list[tuple[slice, slice] | None]:
    """``scipy.ndimage.find_objects(labels, max_label=n)`` for 2-D int labels."""
    if n <= 0:
        return []
    ys, xs = np.nonzero(labels)
    lab = labels[ys, xs]
    keep = lab <= n
    ys, xs, lab = ys[keep], xs[keep], lab[keep]
    big = np.iinfo(np.int64).max
    y0, x0 = np.full(n + 1, big), np.full(n + 1, big)
    y1, x1 = np.full(n + 1, -1), np.full(n + 1, -1)
    np.minimum.at(y0, lab, ys)
    np.minimum.at(x0, lab, xs)
    np.maximum.at(y1, lab, ys)
    np.maximum.at(x1, lab, xs)
    return [
        None if y1[i] < 0 else (slice(int(y0[i]), int(y1[i]) + 1), slice(int(x0[i]), int(x1[i]) + 1))
        for i in range(1, n + 1)
    ]


# --------------------------------------------------------------------------------------------
# Argument checks
# --------------------------------------------------------------------------------------------
def _check_heat(heat: ArrayLike, name: str = "heat") -> np.ndarray:
    arr = np.asarray(heat)
    if arr.ndim != 2:
        raise ValueError(f"{name} must be a 2-D array (rows, cols); got shape {arr.shape}")
    if arr.dtype == bool or not (np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)):
        raise ValueError(f"{name} must hold real numbers; got dtype {arr.dtype}")
    return arr


def _check_cell(cell: int) -> int:
    if isinstance(cell, (bool, np.bool_)) or not isinstance(cell, (int, np.integer)) or cell < 1:
        raise ValueError(f"cell must be an integer >= 1 (heat-map cell side in pixels); got {cell!r}")
    return int(cell)


def _check_real(value: float, name: str) -> float:
    if isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name} must be a number; got {value!r}")
    try:
        out = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a number; got {value!r}") from None
    if not np.isfinite(out):
        raise ValueError(f"{name} must be finite; got {value!r}")
    return out


def _check_pair(value: Sequence[float], name: str) -> tuple[float, float]:
    try:
        a, b = value
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a pair of numbers; got {value!r}") from None
    if isinstance(a, (bool, np.bool_)) or isinstance(b, (bool, np.bool_)):
        raise ValueError(f"{name} must be a pair of numbers; got {value!r}")
    try:
        return float(a), float(b)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a pair of numbers; got {value!r}") from None


def _check_min_size(min_size: Sequence[float]) -> tuple[float, float]:
    w, h = _check_pair(min_size, "min_size")
    if not (np.isfinite(w) and np.isfinite(h) and w >= 0 and h >= 0):
        raise ValueError(f"min_size must be (min_width, min_height) with finite values >= 0; got {min_size!r}")
    return w, h


def _check_aspect_range(aspect_range: Sequence[float]) -> tuple[float, float]:
    lo, hi = _check_pair(aspect_range, "aspect_range")
    if not (lo > 0 and hi >= lo):  # also rejects NaN; hi may be inf
        raise ValueError(
            f"aspect_range must be (low, high) width/height ratios with 0 < low <= high; got {aspect_range!r}"
        )
    return lo, hi


def _check_connectivity(connectivity: int) -> int:
    if isinstance(connectivity, (bool, np.bool_)) or connectivity not in _CONNECTIVITIES:
        raise ValueError(f"connectivity must be 4 or 8; got {connectivity!r}")
    return int(connectivity)


# --------------------------------------------------------------------------------------------
# Heat
# --------------------------------------------------------------------------------------------
def add_heat(heat: ArrayLike, boxes: ArrayLike | Detections, weights: ArrayLike | None = None, *, cell: int = 1) -> np.ndarray:
    """Add the weight of every box to the heat cells it covers.

    Parameters
    ----------
    heat : array_like, shape (h, w)
        Heat map of a frame of ``(H, W)`` pixels, ``h = H // cell`` and ``w = W // cell``; any
        real dtype. It is not modified.
    boxes : array_like, shape (n, 4)
        ``[x1, y1, x2, y2]`` in frame pixels (x2, y2 exclusive), integer or float; ``[]`` means
        none. A box covers the heat cells ``floor(y1 / cell) <= i < ceil(y2 / cell)`` and
        ``floor(x1 / cell) <= j < ceil(x2 / cell)`` (every cell it touches), clipped to the
        map. Boxes of zero area, or wholly outside the map, add nothing.
    weights : array_like of float, shape (n,), optional
        Heat added by each box, finite; default 1 per box.
    cell : int, default 1
        Heat-map cell side in frame pixels.

    Returns
    -------
    ndarray of float32, shape (h, w)
        A new array, ``heat`` plus the weights of the boxes covering each cell.

    Raises
    ------
    ValueError
        If ``heat`` is not 2-D real, ``boxes`` is not ``(n, 4)`` with ``x2 >= x1`` and
        ``y2 >= y1``, ``weights`` does not hold ``n`` finite numbers, or ``cell < 1``.

    Notes
    -----
    Vectorised over boxes: each box adds ``+w`` and ``-w`` at the corners of its cell range in a
    difference array spanning the boxes' bounding rectangle (one ``np.bincount``), and its
    integral image (``cv2.integral``) is the summed heat, in float64. Cells that no box of
    non-zero weight covers are set to exactly 0 (rounding in the cumulative sums could otherwise leave ``1e-17``-sized
    residues there, which a ``> 0`` threshold would pick up), and with non-negative weights the
    added heat is clipped at 0 for the same reason, so the result is never below ``heat``.

    Examples
    --------
    >>> add_heat(np.zeros((2, 3)), [[0, 0, 16, 8], [9, 1, 10, 15]], [1.0, 0.5], cell=8)
    array([[1. , 1.5, 0. ],
           [0. , 0.5, 0. ]], dtype=float32)
    """
    base = _check_heat(heat)
    cell = _check_cell(cell)
    box_arr = as_boxes(boxes.xyxy if isinstance(boxes, Detections) else boxes, "boxes")
    n = len(box_arr)
    if weights is None:
        w = np.ones(n, dtype=np.float64)
    else:
        w = np.asarray(weights, dtype=np.float64)
        if w.size == 0:
            w = w.reshape(0)
        if w.shape != (n,):
            raise ValueError(f"weights must have shape ({n},), one per box; got shape {w.shape}")
        if not np.all(np.isfinite(w)):
            raise ValueError("weights must be finite")

    out = base.astype(np.float32, copy=True)
    rows, cols = out.shape
    if n == 0 or rows == 0 or cols == 0:
        return out

    # Cell ranges [cx1, cx2) x [cy1, cy2) covered by each box, clipped to the map.
    rng = np.concatenate([np.floor(box_arr[:, :2] / cell), np.ceil(box_arr[:, 2:] / cell)], axis=1)
    np.clip(rng, 0, np.array([cols, rows, cols, rows], dtype=np.float64), out=rng)
    r = rng.astype(np.intp)
    # Boxes of weight 0 add nothing and must not count as covering a cell (its rounding residue would stay).
    keep = (r[:, 2] > r[:, 0]) & (r[:, 3] > r[:, 1]) & (box_arr[:, 2] > box_arr[:, 0]) & (box_arr[:, 3] > box_arr[:, 1]) & (w != 0)
    if not keep.all():
        r, w = r[keep], w[keep]
        if len(w) == 0:
            return out

    # Work on the bounding rectangle of all boxes only (typically the road band of the frame).
    x0, y0 = int(r[:, 0].min()), int(r[:, 1].min())
    r = r - np.array([x0, y0, x0, y0])
    sub_cols, sub_rows = int(r[:, 2].max()), int(r[:, 3].max())
    # Corners (y1, x1) +w, (y1, x2) -w, (y2, x1) -w, (y2, x2) +w of a difference array.
    stride = sub_cols + 1
    size = (sub_rows + 1) * stride
    corners = (r[:, [1, 1, 3, 3]] * stride + r[:, [0, 2, 0, 2]]).ravel()
    signs = np.tile(np.array([1.0, -1.0, -1.0, 1.0]), len(w))
    diff = np.bincount(corners, weights=signs * np.repeat(w, 4), minlength=size).reshape(sub_rows + 1, stride)
    # cv2.integral(d)[i + 1, j + 1] == d[:i + 1, :j + 1].sum(): both cumulative sums at once,
    # several times faster than numpy's sequential cumsum.
    added = cv2.integral(diff, sdepth=cv2.CV_64F)[1 : sub_rows + 1, 1 : sub_cols + 1]
    # Integer coverage counts are exact in float64: use them to zero the uncovered cells.
    count = np.bincount(corners, weights=signs, minlength=size).reshape(sub_rows + 1, stride)
    added *= cv2.integral(count, sdepth=cv2.CV_64F)[1 : sub_rows + 1, 1 : sub_cols + 1] > 0.5
    if w.min() >= 0:
        np.maximum(added, 0.0, out=added)
    view = out[y0 : y0 + sub_rows, x0 : x0 + sub_cols]
    np.add(view, added, out=view)  # summed in float64, rounded once to float32
    return out


def apply_threshold(heat: ArrayLike, threshold: float) -> np.ndarray:
    """Zero the cells of a heat map that are not above a threshold.

    Parameters
    ----------
    heat : array_like, shape (h, w)
        Heat map, any real dtype; not modified.
    threshold : float
        Finite; cells with ``heat <= threshold`` become 0.

    Returns
    -------
    ndarray, shape (h, w)
        A new array of the same dtype as ``heat``.

    Raises
    ------
    ValueError
        If ``heat`` is not 2-D real or ``threshold`` is not a finite number.

    Examples
    --------
    >>> apply_threshold(np.array([[0.5, 1.0, 1.5]]), 1.0)
    array([[0. , 0. , 1.5]])
    """
    out = np.array(_check_heat(heat), copy=True)
    out[out <= _check_real(threshold, "threshold")] = 0
    return out


def label_heat(heat: ArrayLike, threshold: float = 0.0, *, connectivity: int = 8) -> tuple[np.ndarray, int]:
    """Label the connected blobs of cells hotter than a threshold.

    Parameters
    ----------
    heat : array_like, shape (h, w)
        Heat map, any real dtype.
    threshold : float, default 0.0
        Cells with ``heat > threshold`` belong to blobs (NaN cells never do).
    connectivity : {8, 4}, default 8
        Cells touching by an edge (4) or also by a corner (8) belong to the same blob. 8 is the
        default: on a coarse map the thresholded overlap of a car's windows often narrows to a
        corner-to-corner contact, and splitting there would leave parts too small to pass the
        size filter of :func:`blob_boxes`. Two cars whose blobs touch only at a corner are
        merged, but cars that close nearly always share an edge of heat anyway.

    Returns
    -------
    labels : ndarray of int32, shape (h, w)
        0 for background, ``1..n`` for the blobs in raster order of their first cell.
    n : int
        Number of blobs.

    Raises
    ------
    ValueError
        If ``heat`` is not 2-D real, ``threshold`` is not finite, or ``connectivity`` is not 4
        or 8.

    Examples
    --------
    >>> labels, n = label_heat(np.array([[1, 0, 0], [0, 1, 0], [0, 0, 0], [2, 2, 0]]))
    >>> n, labels.tolist()
    (2, [[1, 0, 0], [0, 1, 0], [0, 0, 0], [2, 2, 0]])
    """
    arr = _check_heat(heat)
    conn = _check_connectivity(connectivity)
    mask = arr > _check_real(threshold, "threshold")
    labels, n = _label(mask, conn)
    return labels, int(n)


def _blob_boxes(
    labels: np.ndarray,
    n: int,
    cell: int,
    min_size: tuple[float, float],
    aspect_range: tuple[float, float],
) -> tuple[np.ndarray, list[tuple[int, tuple[slice, slice]]]]:
    """Boxes (frame pixels, int64 (k, 4)) of the plausible blobs, and their (label, slices)."""
    slices = _find_objects(labels, n) if n else []
    blobs = [(i, s) for i, s in enumerate(slices, start=1) if s is not None]
    if not blobs:
        return np.zeros((0, 4), dtype=np.int64), []
    boxes = np.array([(s[1].start, s[0].start, s[1].stop, s[0].stop) for _, s in blobs], dtype=np.int64)
    boxes *= cell
    width = boxes[:, 2] - boxes[:, 0]
    height = boxes[:, 3] - boxes[:, 1]  # >= cell >= 1: every listed blob has a cell
    aspect = width / height
    keep = (
        (width >= min_size[0])
        & (height >= min_size[1])
        & (aspect >= aspect_range[0])
        & (aspect <= aspect_range[1])
    )
    return boxes[keep], [b for b, k in zip(blobs, keep.tolist()) if k]


def _peaks(heat: np.ndarray, labels: np.ndarray, blobs: list[tuple[int, tuple[slice, slice]]]) -> np.ndarray:
    """Largest ``heat`` value over the cells of each blob, float64 (k,).

    A loop over the (few) blobs, each reading only its bounding box: much faster than
    ``ndimage.maximum``, which visits the whole map.
    """
    return np.array([heat[s][labels[s] == i].max() for i, s in blobs], dtype=np.float64).reshape(len(blobs))


def _core_boxes(
    heat: np.ndarray,
    labels: np.ndarray,
    blobs: list[tuple[int, tuple[slice, slice]]],
    cell: int,
    fraction: float,
    min_size: tuple[float, float] = (0.0, 0.0),
) -> tuple[np.ndarray, np.ndarray]:
    """Cut each blob to its cores: connected cells holding at least ``fraction`` of its peak.

    Windows overlapping a car only partly (below it, on its shadow) add less heat than the
    windows centred on it, so cutting a blob at a fraction of its own peak keeps the car. Two
    cars side by side make one blob with two hot cores: when at least two cores are each as
    large as ``min_size`` (frame pixels; the smallest search window, as no car's core can be
    smaller), each becomes its own box; otherwise the blob keeps one box around all its cores
    (one car can show two small cores, its front and its back).

    Returns
    -------
    boxes : ndarray of int64, shape (k, 4)
        Frame pixels; ``k >= len(blobs)``.
    peaks : ndarray of float64, shape (k,)
        Peak heat of each core.
    source : ndarray of int64, shape (k,)
        Index into ``blobs`` of the blob each box came from.
    """
    boxes, peaks, source = [], [], []
    for k, (i, s) in enumerate(blobs):
        h = np.where(labels[s] == i, heat[s], 0.0)
        top = h.max()
        core = h >= fraction * top
        sub, n = _label(core, 8)
        kept = []
        for j, sl in enumerate(_find_objects(sub, n), start=1):
            w = (sl[1].stop - sl[1].start) * cell
            ht = (sl[0].stop - sl[0].start) * cell
            if w >= min_size[0] and ht >= min_size[1]:
                kept.append((sl, float(h[sl][sub[sl] == j].max())))
        if len(kept) < 2:  # one car: one box around all its cores
            rows, cols = np.nonzero(core)
            kept = [((slice(rows.min(), rows.max() + 1), slice(cols.min(), cols.max() + 1)), float(top))]
        for sl, pk in kept:
            boxes.append((s[1].start + sl[1].start, s[0].start + sl[0].start, s[1].start + sl[1].stop, s[0].start + sl[0].stop))
            peaks.append(pk)
            source.append(k)
    return (np.array(boxes, dtype=np.int64).reshape(-1, 4) * cell, np.array(peaks, dtype=np.float64), np.array(source, dtype=np.int64))


def blob_boxes(
    labels: ArrayLike,
    n: int,
    *,
    cell: int = 1,
    min_size: Sequence[float] = _DEFAULT_MIN_SIZE,
    aspect_range: Sequence[float] = _DEFAULT_ASPECT_RANGE,
    heat: ArrayLike | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Bounding boxes, in frame pixels, of labelled blobs of plausible vehicle size and shape.

    Parameters
    ----------
    labels : array_like of int, shape (h, w)
        Blob labels as from :func:`label_heat` (0 is background).
    n : int
        Number of labels; blobs labelled above ``n`` are ignored, labels without cells skipped.
    cell : int, default 1
        Heat-map cell side in frame pixels: label cell ``(i, j)`` is the frame pixels
        ``[i*cell, (i+1)*cell) x [j*cell, (j+1)*cell)``.
    min_size : (float, float), default (32, 32)
        Smallest ``(width, height)`` in frame pixels; smaller boxes are dropped.
    aspect_range : (float, float), default (0.3, 4.0)
        Inclusive range of ``width / height``; boxes outside it are dropped.
    heat : array_like, shape (h, w), optional
        The heat map the labels came from, for the peaks.

    Returns
    -------
    boxes : ndarray of int64, shape (k, 4)
        ``[x1, y1, x2, y2]`` (exclusive ends) of each kept blob, in label order; all
        coordinates are multiples of ``cell`` and lie in ``[0, w*cell] x [0, h*cell]``.
    peaks : ndarray of float64, shape (k,)
        Largest heat inside each kept blob (its cells only, not its whole box); zeros if
        ``heat`` is None.

    Raises
    ------
    ValueError
        If ``labels`` is not a 2-D integer array, ``n < 0``, ``heat`` differs in shape, or
        ``cell``, ``min_size`` or ``aspect_range`` are invalid.

    Examples
    --------
    >>> labels = np.array([[1, 1, 0], [1, 1, 0], [0, 0, 2]])
    >>> blob_boxes(labels, 2, cell=16, min_size=(32, 32))
    (array([[ 0,  0, 32, 32]]), array([0.]))
    """
    lab = np.asarray(labels)
    if lab.ndim != 2 or lab.dtype == bool or not np.issubdtype(lab.dtype, np.integer):
        raise ValueError(f"labels must be a 2-D integer array; got {lab.dtype} of shape {lab.shape}")
    if isinstance(n, (bool, np.bool_)) or not isinstance(n, (int, np.integer)) or n < 0:
        raise ValueError(f"n must be an integer >= 0; got {n!r}")
    cell = _check_cell(cell)
    size = _check_min_size(min_size)
    aspect = _check_aspect_range(aspect_range)
    heat_arr = None
    if heat is not None:
        heat_arr = _check_heat(heat)
        if heat_arr.shape != lab.shape:
            raise ValueError(f"heat has shape {heat_arr.shape} but labels have shape {lab.shape}")
    boxes, blobs = _blob_boxes(lab, int(n), cell, size, aspect)
    peaks = np.zeros(len(blobs), dtype=np.float64) if heat_arr is None else _peaks(heat_arr, lab, blobs)
    return boxes, peaks


def heat_to_boxes(
    heat: ArrayLike,
    threshold: float,
    *,
    cell: int = 1,
    min_size: Sequence[float] = _DEFAULT_MIN_SIZE,
    aspect_range: Sequence[float] = _DEFAULT_ASPECT_RANGE,
    connectivity: int = 8,
    peak_fraction: float = 0.0,
    split_size: Sequence[float] = (64, 64),
) -> tuple[np.ndarray, np.ndarray]:
    """Boxes around the blobs of a heat map above a threshold: label, then :func:`blob_boxes`.

    Parameters
    ----------
    heat : array_like, shape (h, w)
        Heat map of a frame of at least ``(h*cell, w*cell)`` pixels.
    threshold : float
        Cells with ``heat > threshold`` form blobs.
    cell, min_size, aspect_range
        As for :func:`blob_boxes`.
    connectivity : {8, 4}, default 8
        As for :func:`label_heat`.
    peak_fraction : float, default 0.0
        If positive, each kept blob's box is shrunk to its cells holding at least this fraction
        of the blob's peak heat (the size and shape filters apply to the whole blob); a blob
        with two or more such cores of at least ``split_size`` (width, height in frame pixels)
        gives one box per core (two cars side by side).
    split_size : (float, float), default (64, 64)
        Smallest core that counts as a car of its own (the smallest search window).

    Returns
    -------
    boxes : ndarray of int64, shape (k, 4)
        One box per plausible blob, in frame pixels, in raster order of the blobs.
    peaks : ndarray of float64, shape (k,)
        Largest heat in each blob (``> threshold``).

    Raises
    ------
    ValueError
        As for :func:`label_heat` and :func:`blob_boxes`.
    """
    arr = _check_heat(heat)
    cell = _check_cell(cell)
    size = _check_min_size(min_size)
    aspect = _check_aspect_range(aspect_range)
    if not 0.0 <= peak_fraction < 1.0:
        raise ValueError(f"peak_fraction must be in [0, 1); got {peak_fraction!r}")
    labels, n = label_heat(arr, threshold, connectivity=connectivity)
    boxes, blobs = _blob_boxes(labels, n, cell, size, aspect)
    if peak_fraction > 0 and blobs:
        boxes, peaks, _ = _core_boxes(arr, labels, blobs, cell, peak_fraction, split_size)
        return boxes, peaks
    return boxes, _peaks(arr, labels, blobs)


def cluster_boxes(boxes: np.ndarray, weights: np.ndarray, iou: float) -> tuple[np.ndarray, np.ndarray]:
    """Greedy clustering of boxes that predict the same vehicle (box voting).

    The heaviest box not yet taken opens a cluster of every untaken box overlapping it at
    ``iou`` or more; the cluster's box is their weighted mean.

    Parameters
    ----------
    boxes : ndarray, shape (n, 4)
    weights : ndarray, shape (n,)
        Positive weights (a window's heat).
    iou : float
        In (0, 1].

    Returns
    -------
    centres : ndarray of float64, shape (k, 4)
        One box per cluster, heaviest cluster first.
    support : ndarray of float64, shape (k,)
        Summed weight of each cluster.
    """
    boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
    weights = np.asarray(weights, np.float64).reshape(-1)
    order = np.argsort(-weights, kind="stable")
    overlap = box_iou(boxes, boxes) >= iou if len(boxes) else np.zeros((0, 0), bool)
    free = np.ones(len(boxes), bool)
    centres, support = [], []
    for i in order.tolist():
        if not free[i]:
            continue
        members = free & overlap[i]
        free &= ~members
        w = weights[members]
        centres.append(w @ boxes[members] / w.sum())
        support.append(w.sum())
    return np.array(centres, np.float64).reshape(-1, 4), np.array(support, np.float64)


def _apart(boxes: np.ndarray, iou: float) -> bool:
    """Whether boxes are separate vehicles: no pair overlaps at ``iou`` and none lies mostly
    inside another (a car's rear window is not a second car)."""
    inter = box_intersection(boxes, boxes)
    smaller = np.minimum.outer(box_area(boxes), box_area(boxes))
    np.fill_diagonal(inter, 0.0)
    return bool((box_iou(boxes, boxes) - np.eye(len(boxes))).max() < iou and (inter / smaller).max() < 0.5)


def split_blobs(
    blobs: np.ndarray, peaks: np.ndarray, boxes: np.ndarray, weights: np.ndarray, *, iou: float, min_share: float = 0.25
) -> tuple[np.ndarray, np.ndarray]:
    """One box per vehicle where a heat blob holds several: neighbours whose heat touches.

    Heat merges two cars side by side into one blob. The boxes the windows stand for (refined
    to their vehicles, :mod:`~vehicle_detection.refine`) still fall into one cluster per car
    (:func:`cluster_boxes`). A blob whose boxes (those with most of their area inside it) form
    two or more clusters, each holding at least ``min_share`` of their weight, overlapping
    each other by less than ``iou`` and none mostly inside another, is replaced by those clusters' boxes, clipped to the blob.

    Parameters
    ----------
    blobs : ndarray, shape (k, 4)
        Blob boxes in frame pixels.
    peaks : ndarray, shape (k,)
        Their peak heat (kept by each box a blob splits into).
    boxes, weights : ndarray, shapes (n, 4) and (n,)
        The frame's window boxes and heat weights.
    iou : float
        Clustering overlap, in (0, 1].
    min_share : float
        Smallest share of the blob's weight a cluster needs to count as a vehicle.

    Returns
    -------
    boxes : ndarray of int64, shape (m, 4), m >= k
    peaks : ndarray of float64, shape (m,)
    """
    blobs = np.asarray(blobs, np.int64).reshape(-1, 4)
    boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
    if not len(blobs) or not len(boxes):
        return blobs, np.asarray(peaks, np.float64)
    inside = box_intersection(boxes, blobs.astype(np.float64)) / np.maximum(box_area(boxes), 1.0)[:, None]
    out, out_peaks = [], []
    for j, blob in enumerate(blobs):
        mine = inside[:, j] >= 0.7
        centres, support = cluster_boxes(boxes[mine], np.asarray(weights)[mine], iou)
        keep = support >= min_share * support.sum() if len(support) else support.astype(bool)
        centres = centres[keep]
        if len(centres) >= 2 and _apart(centres, iou):
            parts = np.clip(np.rint(centres), [blob[0], blob[1], blob[0], blob[1]], [blob[2], blob[3], blob[2], blob[3]]).astype(np.int64)
            parts = parts[(parts[:, 2] > parts[:, 0]) & (parts[:, 3] > parts[:, 1])]
            if len(parts) >= 2:
                out.extend(parts)
                out_peaks.extend([peaks[j]] * len(parts))
                continue
        out.append(blob)
        out_peaks.append(peaks[j])
    return np.array(out, np.int64).reshape(-1, 4), np.array(out_peaks, np.float64)


def vote_boxes(
    blobs: np.ndarray, boxes: np.ndarray, weights: np.ndarray, *, iou: float, fraction: float, inside: float = 0.7
) -> np.ndarray:
    """Move each blob's box towards the boxes its windows vote for (box voting).

    A blob's extent is where heat is high, which a vehicle's windows spread beyond its edges;
    the boxes the windows stand for (refined to their vehicles, :mod:`~vehicle_detection.refine`)
    say where the edges are. Each blob box moves ``fraction`` of the way to the weighted mean
    of the heaviest cluster (:func:`cluster_boxes`) of the window boxes lying mostly inside it.

    Parameters
    ----------
    blobs : ndarray, shape (k, 4)
        Blob boxes in frame pixels (after :func:`split_blobs`).
    boxes, weights : ndarray, shapes (n, 4) and (n,)
        The frame's window boxes and heat weights.
    iou : float
        Clustering overlap, in (0, 1].
    fraction : float
        In [0, 1]: 0 keeps the blob boxes, 1 takes the voted boxes.
    inside : float
        Smallest share of a window box's area inside a blob for it to vote there.

    Returns
    -------
    ndarray of int64, shape (k, 4)
        The blob boxes moved; a blob no window box lies in keeps its box.
    """
    blobs = np.asarray(blobs, np.int64).reshape(-1, 4)
    boxes = np.asarray(boxes, np.float64).reshape(-1, 4)
    if fraction <= 0 or not len(blobs) or not len(boxes):
        return blobs
    weights = np.asarray(weights, np.float64).reshape(-1)
    share = box_intersection(boxes, blobs.astype(np.float64)) / np.maximum(box_area(boxes), 1.0)[:, None]
    out = blobs.astype(np.float64)
    for j in range(len(blobs)):
        mine = share[:, j] >= inside
        if mine.any():
            centres, _ = cluster_boxes(boxes[mine], weights[mine], iou)
            out[j] += fraction * (centres[0] - out[j])
    return np.rint(out).astype(np.int64)

