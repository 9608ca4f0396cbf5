"""Distances of tracked cars over time: the per-track filter on synthetic tracks whose box bottoms move a whole pixel at a time."""

from __future__ import annotations

import numpy as np
import pytest

from vehicle_detection.detections import Detections
from vehicle_detection.road.distance import DistanceFilter, DistanceTracker, smooth_distances
from vehicle_detection.road.lanes import BirdsEye

FPS = 30.0


def dashcam_view() -> BirdsEye:
    """The road plane the footage estimate gives the 854x480 highway dashcam (numbers only)."""
    return BirdsEye(
        [[196.64, 480.0], [415.17, 267.91], [478.14, 267.91], [826.34, 480.0]],
        [[106.75, 240.0], [106.75, 0.0], [320.25, 0.0], [320.25, 240.0]],
        (854, 480), (427, 240), 0.017330, 0.102128,
    )  # fmt: skip


def row_at(view: BirdsEye, distance_m: np.ndarray, x: float = 440.0) -> np.ndarray:
    """Camera rows (fractional) of the ground points ``distance_m`` ahead, in column ``x``."""
    rows = np.linspace(250.0, 480.0, 20001)
    d = view.ground_distance(np.c_[np.full_like(rows, x), rows])
    return np.interp(-np.asarray(distance_m), -d, rows)


def approaching_track(view: BirdsEye, start_m: float, speed_mps: float, end_m: float = 8.0, jitter_px: float = 0.0, seed: int = 0):
    """Boxes of one car closing in at constant speed, their bottoms on whole pixel rows."""
    t = np.arange(int((start_m - end_m) / speed_mps * FPS))
    truth = start_m - speed_mps * t / FPS
    rng = np.random.default_rng(seed)
    bottom = np.round(row_at(view, truth) + rng.normal(0.0, jitter_px, len(t)) if jitter_px else row_at(view, truth))
    boxes = np.c_[np.full(len(t), 400.0), bottom - 40, np.full(len(t), 480.0), bottom]
    return t, truth, boxes


def frame_by_frame(tracker: DistanceTracker, t, boxes, track: int = 7) -> np.ndarray:
    return np.concatenate([tracker.update(Detections(boxes[i : i + 1], track_id=[track], frame=int(f))).data["distance_m"] for i, f in enumerate(t)])


@pytest.mark.parametrize("start_m, speed_mps", [(25.0, 5.0), (25.0, 10.0), (35.0, 8.0)])
def test_a_car_closing_in_gets_distances_that_fall_every_frame(start_m, speed_mps):
    view = dashcam_view()
    t, truth, boxes = approaching_track(view, start_m, speed_mps)
    raw = frame_by_frame(DistanceTracker(view, FPS, smooth=False), t, boxes)
    assert np.mean(np.diff(raw) == 0) > 0.3  # the measured distance stays on a pixel row's value, then steps
    smoothed = frame_by_frame(DistanceTracker(view, FPS), t, boxes)
    steps = np.diff(smoothed)
    assert steps[0] <= 0 and np.all(steps[1:] < 0)  # two equal first measurements say nothing of a speed yet
    assert np.abs(smoothed - truth).max() < max(1.0, 0.05 * start_m)
    assert np.abs(smoothed - truth)[len(t) // 2 :].max() < 0.5


def test_jittering_box_bottoms_rise_rarely_and_little():
    view = dashcam_view()
    t, truth, boxes = approaching_track(view, 30.0, 6.0, jitter_px=0.5, seed=3)
    raw = frame_by_frame(DistanceTracker(view, FPS, smooth=False), t, boxes)
    smoothed = frame_by_frame(DistanceTracker(view, FPS), t, boxes)
    assert np.diff(raw).max() > 0.5  # the box bottom jumps back up now and then
    settled = np.diff(smoothed)[int(FPS) :]  # after a second, when the filter has its speed
    assert settled.max() < 0.1 and np.mean(settled < 0) > 0.9
    assert np.abs(smoothed - truth).mean() < np.abs(raw - truth).mean()


def test_a_whole_table_at_once_equals_its_frames_one_by_one():
    view = dashcam_view()
    t, _, boxes = approaching_track(view, 25.0, 5.0)
    t2, _, boxes2 = approaching_track(view, 30.0, 4.0)
    n = min(len(t), len(t2))
    table = Detections(np.r_[boxes[:n], boxes2[:n]], track_id=[1] * n + [2] * n, frame=np.r_[t[:n], t2[:n]])  # track by track
    whole = DistanceTracker(view, FPS).update(table)
    one = frame_by_frame(DistanceTracker(view, FPS), t[:n], boxes[:n], track=1)
    np.testing.assert_allclose(whole.data["distance_m"][:n], one)
    assert np.all(np.isfinite(whole.data["relative_speed_mps"][n // 2 : n]))


def test_untracked_boxes_and_unknown_distances_are_not_filtered():
    view = dashcam_view()
    boxes = Detections([[400, 300, 480, 340], [400, 200, 480, 240]], track_id=[-1, 3], frame=[0, 0])
    out = DistanceTracker(view, FPS).update(boxes).data["distance_m"]
    np.testing.assert_allclose(out[0], view.ground_distance([[440, 340]])[0])
    assert np.isnan(out[1])  # above the horizon


def test_smooth_distances_is_the_filter_in_frame_order():
    frames = np.array([3, 0, 1, 2, 5])
    d = np.array([17.0, 20.0, 19.0, np.nan, 16.0])
    out = smooth_distances(frames, d, 0.5, FPS)
    f = DistanceFilter(FPS)
    expected = [f.update(i, x, 0.5) for i, x in ((0, 20.0), (1, 19.0), (3, 17.0), (5, 16.0))]
    np.testing.assert_allclose(out[[1, 2, 0, 4]], expected)
    assert np.isnan(out[3])


def test_filter_follows_a_change_of_speed():
    f = DistanceFilter(FPS)
    est = [f.update(i, 20.0, 0.2) for i in range(30)]  # keeping its distance
    est += [f.update(30 + i, 20.0 - 8.0 * i / FPS, 0.2) for i in range(1, 60)]  # then closing in at 8 m/s
    assert est[29] == pytest.approx(20.0, abs=1e-6)
    assert est[-1] == pytest.approx(20.0 - 8.0 * 59 / FPS, abs=0.3)


def test_an_infinite_sigma_is_a_prediction():
    f = DistanceFilter(FPS)
    for i in range(10):
        f.update(i, 20.0 - 0.2 * i, 0.1)
    assert f.update(12, 0.0, float("inf")) == pytest.approx(20.0 - 0.2 * 12, abs=0.1)
    assert f.frame == 12
