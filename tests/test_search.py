"""Sliding-window search: plan validation, the plain path, and fast == plain on real frames."""

from __future__ import annotations

import numpy as np
import pytest

from vehicle_detection.search import (
    SearchPlan,
    SearchScale,
    Windows,
    classify_windows,
    plan_windows,
    search,
    search_plain,
    slide_window,
)


def test_slide_window_counts_and_geometry():
    wins = slide_window((720, 1280, 3), x_start_stop=(0, 256), y_start_stop=(400, 528), xy_window=(64, 64), xy_overlap=(0.5, 0.5))
    # 32-pixel steps: x in 0..192 (7 positions), y in 400..464 (3 positions)
    assert wins.shape == (21, 4)
    assert set(wins[:, 0]) == set(range(0, 193, 32))
    assert set(wins[:, 1]) == {400, 432, 464}
    assert np.all(wins[:, 2] - wins[:, 0] == 64) and np.all(wins[:, 3] - wins[:, 1] == 64)
    assert wins[:, 2].max() <= 256 and wins[:, 3].max() <= 528


def test_slide_window_rejects_full_overlap():
    with pytest.raises(ValueError):
        slide_window((100, 100), xy_overlap=(1.0, 0.5))


@pytest.mark.parametrize(
    "kwargs",
    [dict(scale=0, y_start=0, y_stop=10), dict(scale=1, y_start=10, y_stop=10), dict(scale=1, y_start=0, y_stop=10, step=0),
     dict(scale=1, y_start=0, y_stop=10, x_start=50, x_stop=40)],
)
def test_search_scale_validation(kwargs):
    with pytest.raises(ValueError):
        SearchScale(**kwargs)


def test_plan_round_trip():
    plan = SearchPlan()
    assert SearchPlan.from_dict(plan.to_dict()) == plan
    with pytest.raises(ValueError):
        SearchPlan(scales=())


def test_plan_windows_match_search_boxes(small_model):
    frame = np.zeros((720, 1280, 3), np.uint8)
    per_scale = plan_windows(frame.shape, SearchPlan(), small_model.config)
    wins = search(frame, small_model, all_windows=True)
    assert np.array_equal(np.concatenate(per_scale), wins.boxes)
    for k, s in enumerate(SearchPlan().scales):
        b = per_scale[k]
        assert len(b) > 0
        side = round(64 * s.scale)
        assert np.all(np.abs((b[:, 2] - b[:, 0]) - side) <= 1)
        assert b[:, 1].min() >= s.y_start and b[:, 3].max() <= s.y_stop
        assert b[:, 0].min() >= 0 and b[:, 2].max() <= 1280


@pytest.mark.parametrize("index", [0, 3, 5])
def test_fast_and_plain_paths_agree_on_real_frames(small_model, test_frames, index):
    frame = test_frames[index]
    fast = search(frame, small_model, all_windows=True)
    plain = search_plain(frame, small_model)
    assert len(fast) == len(plain) > 1000
    assert np.array_equal(fast.boxes, plain.boxes)
    assert np.array_equal(fast.scale_index, plain.scale_index)
    # Same margins to rounding error, hence the same decision on every window not on the fence.
    np.testing.assert_allclose(fast.scores, plain.scores, rtol=0, atol=1e-6)
    clear = np.abs(plain.scores) > 1e-6
    assert np.array_equal(fast.scores[clear] > 0, plain.scores[clear] > 0)
    assert (plain.scores > 0).any() and (plain.scores < 0).any()


def test_search_threshold_filters(small_model, test_frames):
    frame = test_frames[0]
    all_w = search(frame, small_model, all_windows=True)
    hot = search(frame, small_model, SearchPlan(threshold=0.5))
    assert np.array_equal(np.sort(hot.scores), np.sort(all_w.scores[all_w.scores > 0.5]))


def test_classify_windows_resizes_to_patch(small_model, test_frames):
    frame = test_frames[0]
    wins = np.array([[800, 400, 960, 560], [0, 0, 64, 64]])
    scores = classify_windows(frame, wins, small_model)
    import cv2

    patch = cv2.resize(frame[400:560, 800:960], (64, 64), interpolation=cv2.INTER_AREA)
    assert scores.shape == (2,)
    assert scores[0] == pytest.approx(small_model.decision_images(patch[None])[0])
    assert scores[1] == pytest.approx(small_model.decision_images(frame[None, 0:64, 0:64])[0])


def test_other_frame_sizes_map_back(small_model, test_frames):
    """A half-size frame is searched at the reference height; boxes come back in its pixels."""
    import cv2

    frame = test_frames[0]
    small = cv2.resize(frame, (640, 360), interpolation=cv2.INTER_AREA)
    wins = search(small, small_model, all_windows=True)
    assert wins.boxes[:, 2].max() <= 640 and wins.boxes[:, 3].max() <= 360
    big = search(frame, small_model, all_windows=True)
    assert len(wins) == len(big)
    np.testing.assert_allclose(wins.boxes * 2, big.boxes, atol=2)


def test_band_outside_frame_is_skipped(small_model):
    plan = SearchPlan(scales=(SearchScale(1.0, 400, 496), SearchScale(1.0, 2000, 2100)))
    wins = search(np.zeros((720, 1280, 3), np.uint8), small_model, plan, all_windows=True)
    assert len(wins) > 0 and np.all(wins.scale_index == 0)


def test_search_refuses_float_frames(small_model):
    from vehicle_detection.errors import InputError

    with pytest.raises(InputError, match="0-1 versus 0-255"):
        search(np.zeros((720, 1280, 3), np.float32), small_model)


def test_windows_concatenate_empty():
    w = Windows.concatenate([])
    assert len(w) == 0 and w.boxes.shape == (0, 4)
