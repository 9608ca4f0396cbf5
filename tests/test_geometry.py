"""Tests of vehicle_detection.geometry: box arrays, IoU and one-to-one matching."""

from __future__ import annotations

from itertools import permutations, product

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from strategies import box_sets

from vehicle_detection.geometry import as_boxes, box_iou, match_boxes, mirror_boxes, mirror_image


# --------------------------------------------------------------------------------------------
# box_iou
# --------------------------------------------------------------------------------------------
class TestBoxIou:
    def test_known_values(self):
        a = [[0, 0, 10, 10]]
        b = [
            [0, 0, 10, 10],  # identical: 1
            [20, 20, 30, 30],  # disjoint: 0
            [10, 0, 20, 10],  # shares the edge x=10, but x2 is exclusive: no common pixel, 0
            [5, 0, 15, 10],  # half of each: inter 5*10=50, union 100+100-50=150 -> 1/3
            [0, 0, 5, 10],  # the left half of a: inter 50, union 100 -> 1/2
            [5, 5, 15, 15],  # a quarter of each: inter 25, union 175 -> 1/7
            [-10, -10, 20, 20],  # a inside a 30x30 box: 100/900 -> 1/9
        ]
        expected = [[1.0, 0.0, 0.0, 1 / 3, 1 / 2, 1 / 7, 1 / 9]]
        np.testing.assert_allclose(box_iou(a, b), expected, rtol=1e-12)

    def test_one_pixel_boxes(self):
        # [0,0,1,1] is the single pixel (0,0); [0,0,2,2] covers 4 pixels -> 1/4.
        np.testing.assert_allclose(box_iou([[0, 0, 1, 1]], [[0, 0, 2, 2], [1, 1, 2, 2]]), [[0.25, 0.0]])

    def test_shape_and_dtype(self):
        a = np.array([[0, 0, 4, 4], [2, 2, 6, 6]], dtype=np.int32)
        b = np.array([[0, 0, 4, 4], [2, 2, 6, 6], [100, 100, 101, 101]], dtype=np.float32)
        iou = box_iou(a, b)
        assert iou.shape == (2, 3) and iou.dtype == np.float64
        # a[0] vs a[1]: inter 2*2=4, union 16+16-4=28 -> 1/7
        np.testing.assert_allclose(iou, [[1, 1 / 7, 0], [1 / 7, 1, 0]], rtol=1e-12)

    def test_float_coordinates(self):
        # [0,0,1,1] vs [0.5,0,1.5,1]: inter 0.5, union 1.5 -> 1/3
        np.testing.assert_allclose(box_iou([[0.0, 0.0, 1.0, 1.0]], [[0.5, 0.0, 1.5, 1.0]]), [[1 / 3]])

    @pytest.mark.parametrize(
        "a, b, shape",
        [([], [[0, 0, 1, 1]], (0, 1)), (np.zeros((2, 4)) + [0, 0, 1, 1], [], (2, 0)), ([], [], (0, 0))],
    )
    def test_empty_inputs(self, a, b, shape):
        assert box_iou(a, b).shape == shape

    def test_zero_area_boxes_give_zero_not_nan(self):
        iou = box_iou([[3, 3, 3, 3]], [[3, 3, 3, 3], [0, 0, 10, 10]])
        np.testing.assert_array_equal(iou, [[0.0, 0.0]])

    @pytest.mark.parametrize(
        "bad",
        [
            [[0, 0, 1]],  # 3 coordinates
            [0, 0, 1, 1],  # 1-D
            [[0, 0, 1, np.nan]],
            [[5, 0, 4, 1]],  # x2 < x1
            [[0, 5, 1, 4]],  # y2 < y1
            [["a", "b", "c", "d"]],
        ],
    )
    def test_rejects_malformed_boxes(self, bad):
        with pytest.raises(ValueError):
            box_iou(bad, [[0, 0, 1, 1]])


@settings(deadline=None)
@given(box_sets(), box_sets())
def test_iou_symmetric_bounded_and_one_on_diagonal(a, b):
    ab, ba = box_iou(a, b), box_iou(b, a)
    np.testing.assert_allclose(ab, ba.T, rtol=1e-12, atol=0)
    assert np.all((ab >= 0) & (ab <= 1))
    np.testing.assert_allclose(np.diag(box_iou(a, a)), 1.0)


@settings(deadline=None, max_examples=60)
@given(box_sets(max_boxes=3, max_coord=12, max_size=8), box_sets(max_boxes=3, max_coord=12, max_size=8))
def test_iou_matches_pixel_count(a, b):
    # Rasterise each box as the pixels [x1, x2) x [y1, y2) and count.
    def mask(box):
        m = np.zeros((24, 24), dtype=bool)
        m[box[1] : box[3], box[0] : box[2]] = True
        return m

    iou = box_iou(a, b)
    for i, j in product(range(len(a)), range(len(b))):
        ma, mb = mask(a[i]), mask(b[j])
        assert iou[i, j] == pytest.approx((ma & mb).sum() / (ma | mb).sum())



def test_as_boxes_keeps_dtype_and_refuses_fractions_for_integers():
    arr = np.array([[0, 0, 2, 2]], np.int64)
    assert as_boxes(arr, integer=True) is arr
    with pytest.raises(ValueError, match="whole pixel"):
        as_boxes([[0, 0, 2.5, 2]], integer=True)


def test_match_prefers_more_pairs_over_larger_total():
    # Row 0 fits column 0 best (0.9), but then row 1 has nothing: two pairs (0-1, 1-0) win.
    rows, cols = match_boxes([[0.9, 0.6], [0.55, 0.0]], 0.5)
    assert list(zip(rows.tolist(), cols.tolist())) == [(0, 1), (1, 0)]


def test_match_nothing_below_threshold_or_empty():
    for iou in ([[0.2, 0.1]], np.zeros((0, 3)), np.zeros((2, 0))):
        rows, cols = match_boxes(iou, 0.5)
        assert rows.size == cols.size == 0


@settings(deadline=None, max_examples=150)
@given(st.integers(1, 4), st.integers(1, 4), st.data(), st.sampled_from([0.1, 0.3, 0.5, 0.7]))
def test_match_is_optimal_by_brute_force(n, m, data, threshold):
    iou = np.array(data.draw(st.lists(st.lists(st.floats(0, 1), min_size=m, max_size=m), min_size=n, max_size=n)))
    rows, cols = match_boxes(iou, threshold)
    assert len(set(rows.tolist())) == len(set(cols.tolist())) == len(rows)
    assert np.all(iou[rows, cols] >= threshold)
    best = (0, 0.0)
    for perm in permutations(range(max(n, m)), n):
        pairs = [(r, c) for r, c in enumerate(perm) if c < m and iou[r, c] >= threshold]
        best = max(best, (len(pairs), sum(iou[r, c] for r, c in pairs)))
    assert len(rows) == best[0]
    assert iou[rows, cols].sum() == pytest.approx(best[1])


def test_mirror_boxes_flips_left_to_right_keeps_the_dtype_and_is_its_own_inverse():
    boxes = np.array([[0, 5, 10, 20], [90, 0, 100, 7], [40, 40, 41, 41]], np.int64)
    out = mirror_boxes(boxes, 100)
    assert out.dtype == np.int64 and out.tolist() == [[90, 5, 100, 20], [0, 0, 10, 7], [59, 40, 60, 41]]
    assert np.array_equal(mirror_boxes(out, 100), boxes) and boxes[0, 0] == 0  # the input untouched
    # the pixels a box covers, flipped, are those its mirror covers
    frame = np.zeros((50, 100), bool)
    frame[5:20, 0:10] = True
    x1, y1, x2, y2 = out[0]
    assert np.array_equal(frame[:, ::-1], np.pad(np.ones((y2 - y1, x2 - x1), bool), ((y1, 50 - y2), (x1, 100 - x2))))
    assert mirror_boxes(np.zeros((0, 4)), 100).shape == (0, 4)


def test_mirror_image_holds_each_box_s_pixels_in_its_mirror_box():
    rng = np.random.default_rng(0)
    image = rng.integers(0, 256, (30, 50, 3), dtype=np.uint8)
    before = image.copy()
    flipped = mirror_image(image)
    assert flipped.flags.c_contiguous and np.array_equal(image, before)  # a copy; the input untouched
    x1, y1, x2, y2 = 3, 4, 20, 25
    m1, _, m2, _ = mirror_boxes([x1, y1, x2, y2], 50)[0]
    assert np.array_equal(flipped[y1:y2, m1:m2], image[y1:y2, x1:x2][:, ::-1])
    assert np.array_equal(mirror_image(flipped), image)
