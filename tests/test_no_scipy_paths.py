"""The scipy-free blob labelling and small matching give exactly what scipy gives."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage
from scipy.optimize import linear_sum_assignment

from vehicle_detection.geometry import match_boxes
from vehicle_detection.heatmap import _find_objects, _label


@pytest.mark.parametrize("connectivity", [4, 8])
def test_label_and_find_objects_match_scipy(connectivity):
    rng = np.random.default_rng(0)
    structure = ndimage.generate_binary_structure(2, 1 if connectivity == 4 else 2)
    for shape in [(1, 1), (1, 7), (7, 1), (9, 16), (90, 160)]:
        for density in (0.0, 0.2, 0.45, 0.6, 1.0):
            mask = rng.random(shape) < density
            got, n = _label(mask, connectivity)
            want, wn = ndimage.label(mask, structure=structure)
            assert n == wn and got.dtype == want.dtype
            np.testing.assert_array_equal(got, want)
            assert _find_objects(got, n) == ndimage.find_objects(want, max_label=n)


def _scipy_match(iou, threshold):
    iou = np.asarray(iou, float)
    valid = iou >= threshold
    if not valid.any():
        return [], []
    bonus = float(min(iou.shape) + 1)
    r, c = linear_sum_assignment(np.where(valid, bonus + iou, 0.0), maximize=True)
    keep = valid[r, c]
    return r[keep].tolist(), c[keep].tolist()


def test_small_matching_matches_scipy():
    rng = np.random.default_rng(1)
    for _ in range(3000):
        shape = tuple(rng.integers(1, 7, size=2))
        iou = rng.random(shape) * (rng.random(shape) < 0.6)
        if rng.random() < 0.2:  # ties
            iou = np.round(iou, 1)
        r, c = match_boxes(iou, 0.2)
        assert (r.tolist(), c.tolist()) == _scipy_match(iou, 0.2)
    big = rng.random((9, 9))
    r, c = match_boxes(big, 0.2)
    assert (r.tolist(), c.tolist()) == _scipy_match(big, 0.2)
