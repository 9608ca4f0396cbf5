"""Box geometry: box arrays, areas, intersection over union, one-to-one matching.

A box is ``[x1, y1, x2, y2]`` in pixels with ``x2`` and ``y2`` exclusive, so it covers
``(x2 - x1) * (y2 - y1)`` pixels. A set of boxes is an ``(n, 4)`` array. Everything that compares
boxes (the tracker's association, the evaluation's matching, the heat map) uses these functions.
"""

from __future__ import annotations

import functools
import itertools
import math

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["MAX_COORD", "as_boxes", "box_area", "box_intersection", "box_iou", "inset_boxes", "match_boxes", "mirror_boxes", "mirror_image"]

#: Coordinates beyond this are certainly errors (and would not fit 32-bit drawing code).
MAX_COORD = 2**31 - 1


def as_boxes(boxes: ArrayLike, name: str = "boxes", *, integer: bool = False) -> np.ndarray:
    """Validate ``boxes`` as an ``(n, 4)`` array of ``[x1, y1, x2, y2]``.

    Parameters
    ----------
    boxes : array_like, shape (n, 4)
        Empty inputs (``[]``, shape ``(0,)``) are read as shape ``(0, 4)``.
    name : str
        Named in error messages.
    integer : bool
        Return ``int64`` and refuse non-integral values; otherwise ``float64``.

    Returns
    -------
    ndarray of float64 or int64, shape (n, 4)
        The input itself where it already has that dtype (no copy).

    Raises
    ------
    ValueError
        If the shape is wrong, a value is not a finite number, or a box has ``x2 < x1`` or
        ``y2 < y1`` (zero-area boxes are allowed).

    Examples
    --------
    >>> as_boxes([])
    array([], shape=(0, 4), dtype=float64)
    >>> as_boxes([[0, 0, 2.0, 3]], integer=True)
    array([[0, 0, 2, 3]])
    """
    arr = np.asarray(boxes)
    if arr.size == 0:
        arr = arr.reshape(0, 4)
    if arr.ndim != 2 or arr.shape[1] != 4:
        raise ValueError(f"{name} must have shape (n, 4) as [x1, y1, x2, y2]; got shape {arr.shape}")
    if arr.dtype == bool or not (np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)):
        raise ValueError(f"{name} must hold numbers; got dtype {arr.dtype}")
    if np.issubdtype(arr.dtype, np.floating):
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{name} holds NaN or infinite coordinates")
        if integer:
            if np.any(arr != np.round(arr)):
                raise ValueError(f"{name} must hold whole pixel coordinates; round them first (np.rint)")
            if np.any(np.abs(arr) > MAX_COORD):
                raise ValueError(f"{name} holds coordinates beyond {MAX_COORD}")
    arr = arr.astype(np.int64 if integer else np.float64, copy=False)
    bad = np.flatnonzero((arr[:, 2] < arr[:, 0]) | (arr[:, 3] < arr[:, 1]))
    if bad.size:
        i = int(bad[0])
        raise ValueError(f"{name}[{i}] = {arr[i].tolist()} has x2 < x1 or y2 < y1")
    return arr


def inset_boxes(boxes: np.ndarray, inset: tuple[float, float, float, float]) -> np.ndarray:
    """Boxes shrunk by fractions of their size (negative fractions grow them), whole pixels.

    Parameters
    ----------
    boxes : ndarray, shape (n, 4)
    inset : (left, top, right, bottom)
        Fractions of each box's width (left, right) and height (top, bottom) to cut off; the
        two of an axis add up to less than 1, so that no box vanishes.

    Returns
    -------
    ndarray of int64, shape (n, 4)

    Examples
    --------
    >>> inset_boxes(np.array([[0, 0, 100, 50]]), (0.0, 0.1, 0.0, 0.2))
    array([[  0,   5, 100,  40]])
    """
    left, top, right, bottom = (float(v) for v in inset)
    if not (left + right < 1 and top + bottom < 1):
        raise ValueError(f"insets of an axis must add up to less than 1; got {inset}")
    b = np.asarray(boxes, dtype=np.float64).reshape(-1, 4)
    w = b[:, 2] - b[:, 0]
    h = b[:, 3] - b[:, 1]
    out = np.rint(np.stack([b[:, 0] + left * w, b[:, 1] + top * h, b[:, 2] - right * w, b[:, 3] - bottom * h], axis=1)).astype(np.int64)
    out[:, 2] = np.maximum(out[:, 2], out[:, 0] + 1)  # at least one pixel
    out[:, 3] = np.maximum(out[:, 3], out[:, 1] + 1)
    return out


def mirror_boxes(boxes: ArrayLike, width: int) -> np.ndarray:
    """Boxes flipped left to right in a frame ``width`` pixels wide.

    Parameters
    ----------
    boxes : array_like, shape (n, 4) or (4,)
        ``[x1, y1, x2, y2]``, x2 exclusive.
    width : int
        The frame's width in pixels.

    Returns
    -------
    ndarray, shape (n, 4)
        ``[width - x2, y1, width - x1, y2]``, in the boxes' dtype: the pixels a box covers in the
        frame, flipped, are those its mirror covers. The function is its own inverse.

    Examples
    --------
    >>> mirror_boxes([[0, 5, 10, 20]], 100).tolist()
    [[90, 5, 100, 20]]
    """
    b = np.asarray(boxes).reshape(-1, 4)
    out = b.copy()
    out[:, 0], out[:, 2] = width - b[:, 2], width - b[:, 0]
    return out


def mirror_image(image: np.ndarray) -> np.ndarray:
    """``image`` (H, W, ...) flipped left to right, as a C-contiguous copy (the compiled kernels'
    layout): the picture :func:`mirror_boxes` maps boxes into."""
    return np.ascontiguousarray(image[:, ::-1])


def box_area(boxes: np.ndarray) -> np.ndarray:
    """Areas of valid boxes ``(n, 4)``, shape ``(n,)``, in the boxes' dtype."""
    return (boxes[:, 2] - boxes[:, 0]) * (boxes[:, 3] - boxes[:, 1])


def box_intersection(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Pairwise intersection areas of valid boxes, shape ``(len(a), len(b))``."""
    w = np.minimum(a[:, None, 2], b[None, :, 2]) - np.maximum(a[:, None, 0], b[None, :, 0])
    h = np.minimum(a[:, None, 3], b[None, :, 3]) - np.maximum(a[:, None, 1], b[None, :, 1])
    return np.clip(w, 0, None) * np.clip(h, 0, None)


def box_iou(a: ArrayLike, b: ArrayLike) -> np.ndarray:
    """Pairwise intersection over union of two sets of boxes.

    Parameters
    ----------
    a : array_like, shape (n, 4)
        Boxes ``[x1, y1, x2, y2]`` (x2, y2 exclusive), any integer or float dtype.
    b : array_like, shape (m, 4)

    Returns
    -------
    ndarray of float64, shape (n, m)
        ``iou[i, j]`` is the IoU of ``a[i]`` and ``b[j]``, in ``[0, 1]``; 0 where the union has
        zero area (both boxes degenerate).

    Raises
    ------
    ValueError
        As for :func:`as_boxes`.

    Examples
    --------
    >>> box_iou([[0, 0, 10, 10]], [[0, 0, 10, 10], [5, 0, 15, 10], [20, 20, 30, 30]])
    array([[1.        , 0.33333333, 0.        ]])
    """
    a = as_boxes(a, "a")
    b = as_boxes(b, "b")
    inter = box_intersection(a, b)
    union = box_area(a)[:, None] + box_area(b)[None, :] - inter
    iou = np.zeros_like(inter)
    np.divide(inter, union, out=iou, where=union > 0)
    return np.clip(iou, 0.0, 1.0, out=iou)


def match_boxes(iou: ArrayLike, threshold: float) -> tuple[np.ndarray, np.ndarray]:
    """One-to-one matching of rows to columns of an IoU matrix.

    Among the pairs with IoU >= ``threshold``, the matching has the largest possible number of
    pairs and, among matchings of that size, the largest total IoU: an assignment problem
    (:func:`scipy.optimize.linear_sum_assignment`) in which each valid pair is worth more than
    any sum of IoUs. Maximising the total IoU alone could trade two valid matches for one
    tighter one at low thresholds.

    Parameters
    ----------
    iou : array_like of float, shape (n, m)
    threshold : float
        Smallest IoU of a matched pair.

    Returns
    -------
    rows, cols : ndarray of intp, shape (k,)
        Matched pairs ``(rows[i], cols[i])``, sorted by row.

    Examples
    --------
    >>> match_boxes([[0.9, 0.6], [0.55, 0.0]], 0.5)
    (array([0, 1]), array([1, 0]))
    """
    iou = np.asarray(iou, dtype=np.float64)
    empty = np.zeros(0, np.intp)
    if iou.size == 0:
        return empty, empty
    if iou.ndim != 2:
        raise ValueError(f"iou must be a 2-D matrix; got shape {iou.shape}")
    valid = iou >= threshold
    if not valid.any():
        return empty, empty
    bonus = float(min(iou.shape) + 1)
    weights = np.where(valid, bonus + iou, 0.0)
    small = _match_small(weights, valid)
    if small is not None:
        return small
    from scipy.optimize import linear_sum_assignment  # imported on first use: 0.3 s at start-up

    rows, cols = linear_sum_assignment(weights, maximize=True)
    keep = valid[rows, cols]
    return rows[keep].astype(np.intp), cols[keep].astype(np.intp)


_SMALL_ASSIGNMENTS = 5040  # 7 x 7


@functools.lru_cache(maxsize=64)
def _permutations(m: int, n: int) -> np.ndarray:
    """Every ordered choice of ``n`` of ``m`` columns, ``(m! / (m - n)!, n)`` intp, read-only (made once per shape)."""
    perms = np.array(list(itertools.permutations(range(m), n)), np.intp).reshape(-1, n)
    perms.setflags(write=False)
    return perms


def _match_small(weights: np.ndarray, valid: np.ndarray):
    """The maximum-weight matching of a small matrix by trying every assignment, or None.

    None (use scipy's solver) when there are too many assignments, or when the best total is
    tied, within rounding, by an assignment with other valid pairs: then the choice is the
    solver's, and the result is always the one ``linear_sum_assignment`` gives. A tracker's
    matrices are a few tracks by a few blobs, so scipy is rarely imported (a quarter of a
    second at start-up).
    """
    transpose = weights.shape[0] > weights.shape[1]
    w, v = (weights.T, valid.T) if transpose else (weights, valid)
    n, m = w.shape
    if math.perm(m, n) > _SMALL_ASSIGNMENTS:
        return None
    perms = _permutations(m, n)
    rows = np.arange(n)
    totals = w[rows, perms].sum(axis=1)
    best = totals.max()
    near = np.flatnonzero(totals >= best - 1e-9 * max(1.0, abs(best)))
    chosen = perms[near[0]]
    keep = v[rows, chosen]
    for k in near[1:]:
        other = perms[k]
        other_keep = v[rows, other]
        if not (np.array_equal(keep, other_keep) and np.array_equal(chosen[keep], other[other_keep])):
            return None
    r, c = rows[keep], chosen[keep]
    if transpose:
        order = np.argsort(c, kind="stable")
        r, c = c[order], r[order]
    return r.astype(np.intp), c.astype(np.intp)
