"""Tests of vehicle_detection.heatmap: adding heat, thresholds, blob labels and blob boxes.

Expected arrays are worked out by hand in the comments beside them.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vehicle_detection.heatmap import add_heat, apply_threshold, blob_boxes, heat_to_boxes, label_heat


def _reference_heat(shape, boxes, weights, cell):
    """Slow oracle: one slice per box, cell ranges [floor(a / cell), ceil(b / cell))."""
    out = np.zeros(shape, dtype=np.float64)
    for (x1, y1, x2, y2), w in zip(boxes, weights):
        if x2 <= x1 or y2 <= y1:
            continue
        c1, c2 = max(int(np.floor(x1 / cell)), 0), max(int(np.ceil(x2 / cell)), 0)
        r1, r2 = max(int(np.floor(y1 / cell)), 0), max(int(np.ceil(y2 / cell)), 0)
        out[r1:r2, c1:c2] += w
    return out


# --------------------------------------------------------------------------------------------
# add_heat
# --------------------------------------------------------------------------------------------
def test_add_heat_exact_sums_cell_1():
    # A covers x 1..3, y 1..2; B covers x 2..5, y 2..4 (x2, y2 exclusive).
    heat = add_heat(np.zeros((6, 8)), [[1, 1, 4, 3], [2, 2, 6, 5]])
    expected = [
        [0, 0, 0, 0, 0, 0, 0, 0],
        [0, 1, 1, 1, 0, 0, 0, 0],
        [0, 1, 2, 2, 1, 1, 0, 0],
        [0, 0, 1, 1, 1, 1, 0, 0],
        [0, 0, 1, 1, 1, 1, 0, 0],
        [0, 0, 0, 0, 0, 0, 0, 0],
    ]
    assert heat.dtype == np.float32
    np.testing.assert_array_equal(heat, expected)


def test_add_heat_cell_coverage_touches_every_cell_the_box_overlaps():
    # Frame 32 x 48 at cell 8 -> map 4 x 6.
    # [4, 9, 17, 16]: cols floor(4/8)=0 .. ceil(17/8)=3 -> 0, 1, 2; rows floor(9/8)=1 .. ceil(16/8)=2 -> 1.
    # [8, 8, 16, 24]: cols 1 .. 2 -> 1; rows 1 .. 3 -> 1, 2 (aligned edges cover no extra cell).
    heat = add_heat(np.zeros((4, 6), np.float32), [[4, 9, 17, 16], [8, 8, 16, 24]], cell=8)
    expected = [
        [0, 0, 0, 0, 0, 0],
        [1, 2, 1, 0, 0, 0],
        [0, 1, 0, 0, 0, 0],
        [0, 0, 0, 0, 0, 0],
    ]
    np.testing.assert_array_equal(heat, expected)


def test_add_heat_clips_at_the_borders():
    # Frame 37 x 50 at cell 8 -> map 4 x 6; the last 5 rows and 2 columns have no cell.
    boxes = [
        [-10, -10, 12, 12],  # cols 0..1, rows 0..1
        [40, 28, 100, 100],  # col 5 only (ceil(100/8) = 13 clipped to 6), row 3 only
        [60, 0, 70, 10],  # wholly right of the map: nothing
        [45, 30, 50, 37],  # col 5 (floor 45/8 = 5), row 3: pixels in the partial cells are dropped
        [0, -20, 8, -1],  # wholly above: nothing
    ]
    heat = add_heat(np.zeros((4, 6)), boxes, cell=8)
    expected = [
        [1, 1, 0, 0, 0, 0],
        [1, 1, 0, 0, 0, 0],
        [0, 0, 0, 0, 0, 0],
        [0, 0, 0, 0, 0, 2],
    ]
    np.testing.assert_array_equal(heat, expected)


def test_add_heat_weights_and_existing_heat():
    base = np.full((3, 4), 0.25, dtype=np.float32)
    # Box 0 (weight 2.5) covers cols 0..2 of rows 0..1; box 1 (weight -1) covers cols 2..3 of
    # rows 1..2; they overlap at (1, 2): 0.25 + 2.5 - 1 = 1.75.
    heat = add_heat(base, [[0, 0, 3, 2], [2, 1, 4, 3]], [2.5, -1.0])
    expected = [
        [2.75, 2.75, 2.75, 0.25],
        [2.75, 2.75, 1.75, -0.75],
        [0.25, 0.25, -0.75, -0.75],
    ]
    np.testing.assert_allclose(heat, expected, rtol=0, atol=1e-6)


def test_add_heat_returns_new_array_and_leaves_input_unchanged():
    base = np.arange(12, dtype=np.float32).reshape(3, 4)
    before = base.copy()
    heat = add_heat(base, [[0, 0, 2, 2]])
    assert heat is not base
    np.testing.assert_array_equal(base, before)
    assert heat[0, 0] == 1.0 and heat[2, 3] == 11.0
    # No boxes: still a new float32 array.
    empty = add_heat(base, [])
    assert empty is not base and empty.dtype == np.float32
    np.testing.assert_array_equal(empty, before)
    # Integer heat is accepted and the result is float32.
    assert add_heat(np.zeros((2, 2), np.int32), [[0, 0, 1, 1]], [0.5]).dtype == np.float32


def test_add_heat_zero_area_boxes_add_nothing():
    # [3, 3, 3, 10] has zero width; at cell 8 it would otherwise touch cell column 0.
    heat = add_heat(np.zeros((2, 2)), [[3, 3, 3, 10], [0, 5, 9, 5]], cell=8)
    assert not heat.any()


def test_add_heat_cells_outside_every_box_are_exactly_zero():
    # Awkward weights make the cumulative sums round; uncovered cells must still be exactly 0.
    rng = np.random.default_rng(7)
    xy = rng.integers(0, 60, size=(40, 2))
    size = rng.integers(1, 30, size=(40, 2))
    boxes = np.hstack([xy, xy + size])
    weights = rng.uniform(0.01, 10.0, size=40) / 3.0
    heat = add_heat(np.zeros((50, 70), np.float32), boxes, weights)
    ref = _reference_heat((50, 70), boxes, weights, 1)
    assert np.all(heat[ref == 0] == 0)
    np.testing.assert_allclose(heat, ref, rtol=1e-6, atol=1e-5)


def test_add_heat_zero_weight_box_never_goes_negative():
    # Found by search: without clipping, the cumulative sums leave -1.1e-16 in a cell that only
    # the zero-weight box covers.
    boxes = [[0, 7, 2, 13], [1, 7, 5, 10], [10, 2, 11, 3], [9, 0, 14, 3], [6, 8, 12, 15]]
    heat = add_heat(np.zeros((20, 20), np.float32), boxes, [2.9, 0.001, 2.9, 0.7, 0.0])
    assert heat.min() == 0.0
    np.testing.assert_allclose(heat, _reference_heat((20, 20), boxes, [2.9, 0.001, 2.9, 0.7, 0.0], 1), atol=1e-6)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"heat": np.zeros(5)}, "2-D"),
        ({"heat": np.zeros((2, 2), bool)}, "real numbers"),
        ({"boxes": [[0, 0, 1]]}, "shape"),
        ({"boxes": [[2, 0, 1, 1]]}, "x2 < x1"),
        ({"weights": [1.0, 2.0]}, "one per box"),
        ({"weights": [np.nan]}, "finite"),
        ({"cell": 0}, "cell"),
        ({"cell": 2.0}, "cell"),
    ],
)
def test_add_heat_rejects_bad_arguments(kwargs, match):
    args = {"heat": np.zeros((4, 4)), "boxes": [[0, 0, 2, 2]], "weights": None, "cell": 1} | kwargs
    with pytest.raises(ValueError, match=match):
        add_heat(args["heat"], args["boxes"], args["weights"], cell=args["cell"])


@st.composite
def _maps_and_boxes(draw, inside: bool):
    cell = draw(st.integers(1, 9))
    rows, cols = draw(st.integers(1, 12)), draw(st.integers(1, 12))
    height, width = rows * cell, cols * cell
    n = draw(st.integers(0, 12))
    boxes = []
    for _ in range(n):
        if inside:
            x1 = draw(st.integers(0, width - 1))
            y1 = draw(st.integers(0, height - 1))
            x2 = draw(st.integers(x1 + 1, width))
            y2 = draw(st.integers(y1 + 1, height))
        else:
            x1 = draw(st.integers(-2 * width, 2 * width))
            y1 = draw(st.integers(-2 * height, 2 * height))
            x2 = x1 + draw(st.integers(0, 2 * width))
            y2 = y1 + draw(st.integers(0, 2 * height))
        boxes.append([x1, y1, x2, y2])
    weights = draw(st.lists(st.floats(0.0, 100.0, allow_subnormal=False), min_size=n, max_size=n))
    return cell, (rows, cols), np.array(boxes, dtype=np.int64).reshape(-1, 4), np.array(weights)


@settings(deadline=None, max_examples=150)
@given(_maps_and_boxes(inside=True))
def test_add_heat_total_equals_weight_times_covered_cells(case):
    cell, shape, boxes, weights = case
    heat = add_heat(np.zeros(shape, np.float32), boxes, weights, cell=cell)
    cols = np.ceil(boxes[:, 2] / cell) - np.floor(boxes[:, 0] / cell)
    rows = np.ceil(boxes[:, 3] / cell) - np.floor(boxes[:, 1] / cell)
    expected = float(np.sum(weights * cols * rows))
    assert heat.sum(dtype=np.float64) == pytest.approx(expected, rel=1e-5, abs=1e-4)
    np.testing.assert_allclose(heat, _reference_heat(shape, boxes, weights, cell), rtol=1e-6, atol=1e-4)


@settings(deadline=None, max_examples=150)
@given(_maps_and_boxes(inside=False))
def test_add_heat_never_negative_and_matches_oracle_anywhere(case):
    cell, shape, boxes, weights = case
    heat = add_heat(np.zeros(shape, np.float32), boxes, weights, cell=cell)
    assert heat.shape == shape and heat.dtype == np.float32
    assert np.all(heat >= 0)
    ref = _reference_heat(shape, boxes, weights, cell)
    assert np.all(heat[ref == 0] == 0)
    np.testing.assert_allclose(heat, ref, rtol=1e-6, atol=1e-4)


# --------------------------------------------------------------------------------------------
# apply_threshold and label_heat
# --------------------------------------------------------------------------------------------
def test_apply_threshold_zeroes_values_not_above():
    heat = np.array([[0.0, 1.0, 2.0], [3.0, 2.5, -1.0]], dtype=np.float32)
    out = apply_threshold(heat, 2.0)
    np.testing.assert_array_equal(out, [[0, 0, 0], [3.0, 2.5, 0]])  # 2.0 itself is not above
    assert out.dtype == np.float32
    np.testing.assert_array_equal(heat, [[0.0, 1.0, 2.0], [3.0, 2.5, -1.0]])
    with pytest.raises(ValueError, match="finite"):
        apply_threshold(heat, np.nan)


def test_label_two_separate_blobs():
    heat = np.array(
        [
            [3, 3, 0, 0, 0],
            [3, 3, 0, 0, 0],
            [0, 0, 0, 5, 5],
            [0, 0, 0, 5, 0],
        ],
        dtype=np.float32,
    )
    labels, n = label_heat(heat, 1.0)
    assert n == 2
    np.testing.assert_array_equal(
        labels, [[1, 1, 0, 0, 0], [1, 1, 0, 0, 0], [0, 0, 0, 2, 2], [0, 0, 0, 2, 0]]
    )


def test_label_touching_blobs_merge_and_threshold_is_strict():
    heat = np.array([[2, 2, 4, 4], [2, 2, 4, 4], [1, 1, 1, 1]], dtype=np.float32)
    labels, n = label_heat(heat, 1.0)  # the row of 1s is not above the threshold
    assert n == 1
    np.testing.assert_array_equal(labels, [[1, 1, 1, 1], [1, 1, 1, 1], [0, 0, 0, 0]])
    _, n_high = label_heat(heat, 2.0)  # only the 4s remain
    assert n_high == 1
    _, n_none = label_heat(heat, 4.0)
    assert n_none == 0


def test_label_corner_contact_depends_on_connectivity():
    heat = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 0]], dtype=np.float32)
    assert label_heat(heat)[1] == 1  # default: 8-connectivity
    labels, n = label_heat(heat, connectivity=4)
    assert n == 2
    np.testing.assert_array_equal(labels, [[1, 0, 0], [0, 2, 0], [0, 0, 0]])
    with pytest.raises(ValueError, match="connectivity"):
        label_heat(heat, connectivity=6)


# --------------------------------------------------------------------------------------------
# blob_boxes and heat_to_boxes
# --------------------------------------------------------------------------------------------
def test_blob_boxes_scales_by_cell_and_reports_peaks():
    labels = np.zeros((10, 12), dtype=np.int32)
    labels[1:5, 2:7] = 1  # rows 1..4, cols 2..6
    labels[6:10, 8:12] = 2
    heat = np.where(labels > 0, 1.0, 0.0)
    heat[3, 4] = 7.0
    heat[9, 11] = 3.0
    heat[0, 0] = 99.0  # outside every blob: not a peak
    boxes, peaks = blob_boxes(labels, 2, cell=8, min_size=(0, 0), heat=heat)
    np.testing.assert_array_equal(boxes, [[16, 8, 56, 40], [64, 48, 96, 80]])
    assert boxes.dtype == np.int64
    np.testing.assert_array_equal(peaks, [7.0, 3.0])
    # Without heat the peaks are zeros.
    _, zeros = blob_boxes(labels, 2, cell=8, min_size=(0, 0))
    np.testing.assert_array_equal(zeros, [0.0, 0.0])


def test_blob_boxes_peak_uses_blob_cells_not_its_whole_box():
    # An L-shaped blob whose bounding box also holds a hotter cell of another blob.
    labels = np.array([[1, 2], [1, 1]], dtype=np.int32)
    heat = np.array([[1.0, 9.0], [2.0, 3.0]])
    _, peaks = blob_boxes(labels, 2, min_size=(0, 0), aspect_range=(0.1, 10), heat=heat)
    np.testing.assert_array_equal(peaks, [3.0, 9.0])


def test_blob_boxes_size_filter_is_width_then_height():
    labels = np.zeros((20, 20), dtype=np.int32)
    labels[0:2, 0:6] = 1  # 48 wide x 16 high at cell 8 (aspect 3)
    labels[5:11, 10:12] = 2  # 16 wide x 48 high (aspect 1/3)
    boxes, _ = blob_boxes(labels, 2, cell=8, min_size=(40, 10))
    np.testing.assert_array_equal(boxes, [[0, 0, 48, 16]])
    boxes, _ = blob_boxes(labels, 2, cell=8, min_size=(10, 40))
    np.testing.assert_array_equal(boxes, [[80, 40, 96, 88]])
    boxes, _ = blob_boxes(labels, 2, cell=8, min_size=(48, 48))
    assert boxes.shape == (0, 4)


def test_blob_boxes_aspect_filter_is_inclusive():
    labels = np.zeros((12, 40), dtype=np.int32)
    labels[0:1, 0:4] = 1  # 4 x 1: aspect exactly 4.0 -> kept
    labels[2:3, 5:10] = 2  # 5 x 1: aspect 5 -> dropped
    labels[0:10, 12:15] = 3  # 3 x 10: aspect exactly 0.3 -> kept
    labels[0:11, 16:19] = 4  # 3 x 11: aspect 0.27 -> dropped
    labels[0:2, 20:22] = 5  # square -> kept
    boxes, _ = blob_boxes(labels, 5, min_size=(0, 0), aspect_range=(0.3, 4.0))
    np.testing.assert_array_equal(boxes, [[0, 0, 4, 1], [12, 0, 15, 10], [20, 0, 22, 2]])


def test_blob_boxes_skips_missing_labels_and_labels_above_n():
    labels = np.zeros((4, 4), dtype=np.int32)
    labels[0:2, 0:2] = 3
    labels[2:4, 2:4] = 5
    boxes, _ = blob_boxes(labels, 4, min_size=(0, 0))  # labels 1, 2, 4 empty; 5 > n ignored
    np.testing.assert_array_equal(boxes, [[0, 0, 2, 2]])
    boxes, peaks = blob_boxes(np.zeros((3, 3), np.int32), 0)
    assert boxes.shape == (0, 4) and peaks.shape == (0,)


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"labels": np.zeros((2, 2))}, "integer"),
        ({"n": -1}, "n must"),
        ({"cell": 0}, "cell"),
        ({"min_size": (-1, 3)}, "min_size"),
        ({"min_size": 5}, "min_size"),
        ({"aspect_range": (0, 2)}, "aspect_range"),
        ({"aspect_range": (3, 2)}, "aspect_range"),
        ({"heat": np.zeros((3, 3))}, "shape"),
    ],
)
def test_blob_boxes_rejects_bad_arguments(kwargs, match):
    args = {"labels": np.zeros((2, 2), np.int32), "n": 0} | kwargs
    labels, n = args.pop("labels"), args.pop("n")
    with pytest.raises(ValueError, match=match):
        blob_boxes(labels, n, **args)


def test_heat_to_boxes_end_to_end():
    # Two cars of windows on a 64 x 96 frame at cell 8 (map 8 x 12), and one lone window.
    windows = [
        [0, 0, 32, 32], [8, 0, 40, 32], [0, 8, 32, 40],  # car 1: cells >= 2 hot in x 8..32, y 8..32
        [56, 24, 88, 56], [64, 24, 96, 56],  # car 2: overlap x 64..88, y 24..56
        [40, 56, 56, 64],  # lone window: heat 1
    ]
    heat = add_heat(np.zeros((8, 12), np.float32), windows, cell=8)
    boxes, peaks = heat_to_boxes(heat, 1.5, cell=8, min_size=(16, 16))
    # Car 1: cells with >= 2 windows: cols 1..3, rows 0..3 (rows 0 with cols 1..3 by windows 0+1,
    # col 0 rows 1..3 by windows 0+2) -> union box x 0..32, y 0..32, peak 3 at cols 1..3, rows 1..3.
    np.testing.assert_array_equal(boxes, [[0, 0, 32, 32], [64, 24, 88, 56]])
    np.testing.assert_array_equal(peaks, [3.0, 2.0])


@st.composite
def _heat_maps(draw):
    rows, cols = draw(st.integers(1, 16)), draw(st.integers(1, 16))
    levels = draw(st.lists(st.sampled_from([0.0, 0.5, 1.0, 2.0, 3.0]), min_size=rows * cols, max_size=rows * cols))
    heat = np.array(levels, dtype=np.float32).reshape(rows, cols)
    cell = draw(st.integers(1, 8))
    min_w, min_h = draw(st.integers(0, 40)), draw(st.integers(0, 40))
    lo = draw(st.sampled_from([0.25, 0.3, 0.5, 1.0]))
    hi = draw(st.sampled_from([1.0, 2.0, 4.0, np.inf]))
    threshold = draw(st.sampled_from([0.0, 0.5, 1.0, 2.5]))
    return heat, cell, (min_w, min_h), (lo, hi), threshold


@settings(deadline=None, max_examples=150)
@given(_heat_maps())
def test_heat_to_boxes_boxes_are_inside_and_plausible(case):
    heat, cell, min_size, aspect_range, threshold = case
    boxes, peaks = heat_to_boxes(heat, threshold, cell=cell, min_size=min_size, aspect_range=aspect_range)
    height, width = heat.shape[0] * cell, heat.shape[1] * cell
    assert boxes.dtype == np.int64 and boxes.shape == (len(peaks), 4)
    x1, y1, x2, y2 = boxes.T
    assert np.all((0 <= x1) & (x1 < x2) & (x2 <= width))
    assert np.all((0 <= y1) & (y1 < y2) & (y2 <= height))
    assert np.all(boxes % cell == 0)
    w, h = x2 - x1, y2 - y1
    assert np.all((w >= min_size[0]) & (h >= min_size[1]))
    assert np.all((w / h >= aspect_range[0]) & (w / h <= aspect_range[1]))
    assert np.all(peaks > threshold)
    # Every box's peak is the largest heat of some blob inside it.
    for (bx1, by1, bx2, by2), peak in zip(boxes // cell, peaks):
        assert heat[by1:by2, bx1:bx2].max() >= peak
    assert len(boxes) <= label_heat(heat, threshold)[1]


def _two_core_heat(gap_cols: int, core_w: int) -> np.ndarray:
    """One blob (a weak bridge of heat) holding two hot cores ``core_w`` cells wide."""
    heat = np.zeros((30, 60), np.float32)
    heat[5:15, 5 : 5 + 2 * core_w + gap_cols] = 3.0  # the bridge: above threshold, below the cores' fraction
    heat[5:15, 5 : 5 + core_w] = 20.0
    heat[5:15, 5 + core_w + gap_cols : 5 + 2 * core_w + gap_cols] = 12.0
    return heat


def test_two_large_cores_in_one_blob_give_two_boxes():
    heat = _two_core_heat(gap_cols=3, core_w=10)  # cores 80 px wide at cell 8
    boxes, peaks = heat_to_boxes(heat, 1.0, cell=8, peak_fraction=0.3, split_size=(64, 64), min_size=(32, 32))
    assert boxes.tolist() == [[40, 40, 120, 120], [144, 40, 224, 120]]
    assert peaks.tolist() == [20.0, 12.0]
    # Without the core cut, the same heat is one blob and one box.
    whole, _ = heat_to_boxes(heat, 1.0, cell=8, min_size=(32, 32))
    assert whole.tolist() == [[40, 40, 224, 120]]


def test_small_cores_of_one_car_stay_one_box():
    heat = _two_core_heat(gap_cols=3, core_w=5)  # cores 40 px wide: front and back of one car
    boxes, peaks = heat_to_boxes(heat, 1.0, cell=8, peak_fraction=0.3, split_size=(64, 64), min_size=(32, 32))
    assert boxes.tolist() == [[40, 40, 144, 120]]
    assert peaks.tolist() == [20.0]


# --- clusters of refined boxes ----------------------------------------------------------------


def test_cluster_boxes_votes_the_weighted_mean():
    from vehicle_detection.heatmap import cluster_boxes

    boxes = np.array([[0, 0, 100, 60], [4, 2, 104, 62], [300, 0, 380, 60]], float)
    centres, support = cluster_boxes(boxes, np.array([3.0, 1.0, 2.0]), 0.5)
    np.testing.assert_allclose(centres, [[1, 0.5, 101, 60.5], [300, 0, 380, 60]])
    np.testing.assert_allclose(support, [4.0, 2.0])


def test_split_blobs_splits_neighbours_and_keeps_one_car_whole():
    from vehicle_detection.heatmap import split_blobs

    left, right = np.array([100, 50, 200, 120]), np.array([206, 50, 306, 120])
    rng = np.random.default_rng(0)
    votes = np.concatenate([b + rng.integers(-3, 4, (6, 4)) for b in (left, right)])
    blob = np.array([[96, 46, 312, 124]])
    boxes, peaks = split_blobs(blob, np.array([9.0]), votes, np.ones(12), iou=0.3)
    assert sorted(boxes.tolist()) == sorted(np.clip(np.rint([votes[:6].mean(0), votes[6:].mean(0)]), [96, 46, 96, 46], [312, 124, 312, 124]).astype(int).tolist())
    assert peaks.tolist() == [9.0, 9.0]
    # one car, plus a few votes for its rear window (inside it): not split
    one = np.concatenate([left + rng.integers(-3, 4, (6, 4)), np.tile([130, 60, 170, 90], (3, 1))])
    same, _ = split_blobs(np.array([[96, 46, 204, 124]]), np.array([5.0]), one, np.ones(9), iou=0.3)
    assert same.tolist() == [[96, 46, 204, 124]]
    # a cluster with too little weight is no car
    weak = np.concatenate([left + rng.integers(-3, 4, (6, 4)), right[None]])
    kept, _ = split_blobs(blob, np.array([5.0]), weak, np.ones(7), iou=0.3)
    assert kept.tolist() == blob.tolist()


def test_vote_boxes_moves_a_loose_blob_towards_its_windows_boxes():
    from vehicle_detection.heatmap import vote_boxes

    car = np.array([100, 50, 200, 120])
    rng = np.random.default_rng(1)
    votes = car + rng.integers(-3, 4, (8, 4))
    mean = votes.mean(0)
    blob = np.array([[80, 40, 220, 150]])  # heat spread beyond the car, most below it
    for fraction in (0.0, 0.5, 1.0):
        moved = vote_boxes(blob, votes, np.ones(8), iou=0.3, fraction=fraction)
        assert moved.tolist() == [np.rint(blob[0] + fraction * (mean - blob[0])).astype(int).tolist()]
    # windows of another blob do not vote here; a blob without windows keeps its box
    far = np.array([[500, 50, 600, 120]])
    both = vote_boxes(np.concatenate([blob, far]), votes, np.ones(8), iou=0.3, fraction=1.0)
    assert both[1].tolist() == far[0].tolist() and both[0].tolist() == np.rint(mean).astype(int).tolist()
    # the heaviest cluster votes, not a stray box that also lies inside the blob
    stray = np.concatenate([votes, [[82, 42, 120, 80]]])
    assert vote_boxes(blob, stray, np.r_[np.ones(8), 0.5], iou=0.3, fraction=1.0).tolist() == [np.rint(mean).astype(int).tolist()]


def test_tracker_settings_saved_before_clustering_and_voting_load_with_them_off():
    from vehicle_detection.tracker import TrackerConfig

    for name in ("cluster_iou", "box_vote"):
        d = TrackerConfig(cluster_iou=0.3, box_vote=0.5).to_dict()
        del d[name]
        assert getattr(TrackerConfig.from_dict(d), name) == 0.0
        with pytest.raises(ValueError, match=name):
            TrackerConfig(**{name: 1.5})


def test_add_heat_cells_of_zero_weight_boxes_stay_exactly_zero():
    """A case like the one hypothesis found: a cell covered only by a box of weight 0, next to
    boxes whose weights do not cancel exactly in floating point ((3.3 + 6) - 6 - 3.3 = 8.9e-16),
    kept that rounding residue instead of 0."""
    boxes = np.array([[0, 0, 2, 1], [0, 0, 3, 1], [0, 0, 1, 1]])
    heat = add_heat(np.zeros((1, 3), np.float32), boxes, [3.3, 0.0, 6.0], cell=1)
    assert heat.tolist() == [[np.float32(9.3), np.float32(3.3), 0.0]]
