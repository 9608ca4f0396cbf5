"""Tests of vehicle_detection.tracker: heat integration, track life cycle, ids and chunking.

Scenarios are synthetic windows on a 720 x 1280 frame; expected frame numbers are worked out
from the default parameters in the comments beside them.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from vehicle_detection.detections import Detections
from vehicle_detection.geometry import box_iou
from vehicle_detection.tracker import Track, Tracker, TrackerState
from vehicle_detection.tracker import TrackerConfig as _TrackerConfig

# The scenarios below were worked out with whole windows as heat, threshold 6 and smoothing 0.3;
# the defaults tuned since then (inset windows, threshold 5, smoothing 0.5) are tested apart.
WORKED = dict(threshold=6.0, smoothing=0.3, window_inset=(0.0, 0.0, 0.0, 0.0))


def TrackerConfig(**kw) -> _TrackerConfig:  # noqa: N802  (stands in for the class)
    return _TrackerConfig(**{**WORKED, **kw})

SHAPE = (720, 1280, 3)


def car_windows(box, offsets=((0, 0), (16, 0), (-16, 0), (0, 8))) -> np.ndarray:
    """Detection windows around a car box: the box and shifted copies."""
    box = np.asarray(box)
    return np.array([box + [dx, dy, dx, dy] for dx, dy in offsets], dtype=np.int64)


def update(tr: Tracker, boxes, scores, shape=SHAPE) -> list[Track]:
    """One frame of windows through :meth:`Tracker.update`; the confirmed live tracks it leaves.

    ``scores`` None means margin 0 for every window (heat 1 each). Checks on the way that the
    returned Detections are those tracks, rounded to whole pixels.
    """
    boxes = np.asarray(boxes, dtype=np.int64).reshape(-1, 4) if np.size(boxes) else np.zeros((0, 4), np.int64)
    found = tr.update(Detections(boxes, score=np.zeros(len(boxes)) if scores is None else scores), shape)
    tracks = tr.tracks
    assert found.track_id.tolist() == [t.track_id for t in tracks]
    assert found.xyxy.tolist() == [t.int_box().tolist() for t in tracks]
    assert np.all(found.frame == tr.state.frame_index - 1)
    return tracks


def snapshot(tracks: list[Track]) -> list[tuple]:
    return [(t.track_id, tuple(t.box.tolist()), t.hits, t.misses, t.age, t.confirmed, t.score) for t in tracks]


def scenario(n_frames: int = 40, seed: int = 3) -> list[tuple[np.ndarray, np.ndarray]]:
    """Two cars (one leaving at frame 25, one entering at 10), a one-frame burst, random noise."""
    rng = np.random.default_rng(seed)
    frames = []
    for f in range(n_frames):
        parts = []
        if f < 25:
            parts.append(car_windows([300 + 2 * f, 420, 428 + 2 * f, 516]))
        if f >= 10:
            parts.append(car_windows([900 - 3 * f, 400, 996 - 3 * f, 472], offsets=((0, 0), (8, 0), (0, 8))))
        if f == 5:
            parts.append(car_windows([100, 600, 164, 664]))
        if f % 4 == 1:  # a lone random window now and then
            x, y = rng.integers(0, 1100), rng.integers(380, 600)
            parts.append(np.array([[x, y, x + 96, y + 96]]))
        boxes = np.concatenate(parts) if parts else np.zeros((0, 4), np.int64)
        frames.append((boxes, rng.uniform(-0.5, 2.0, size=len(boxes))))
    return frames


# --------------------------------------------------------------------------------------------
# Configuration
# --------------------------------------------------------------------------------------------
def test_config_defaults():
    cfg = _TrackerConfig()
    assert (cfg.decay, cfg.threshold, cfg.cell, cfg.min_hits, cfg.max_misses) == (0.6, 3.0, 8, 3, 5)
    assert cfg.peak_fraction == 0.3 and cfg.cluster_iou == 0.0
    assert (cfg.smoothing, cfg.match_iou, cfg.score_gain) == (0.5, 0.2, 1.0)
    assert cfg.window_inset == (-0.05, 0.05, -0.05, 0.15)
    assert cfg.min_size == (32.0, 32.0) and cfg.aspect_range == (0.3, 4.0)
    with pytest.raises(dataclasses.FrozenInstanceError):
        cfg.decay = 0.5  # type: ignore[misc]


@pytest.mark.parametrize(
    "field, value",
    [
        ("decay", 1.0),
        ("decay", -0.1),
        ("decay", float("nan")),
        ("decay", "0.5"),
        ("threshold", -1.0),
        ("threshold", float("inf")),
        ("cell", 0),
        ("cell", 8.0),
        ("cell", True),
        ("min_hits", 0),
        ("max_misses", -1),
        ("smoothing", 0.0),
        ("smoothing", 1.5),
        ("match_iou", 0.0),
        ("match_iou", 1.01),
        ("min_size", (-1, 32)),
        ("min_size", (32,)),
        ("aspect_range", (0.0, 4.0)),
        ("aspect_range", (4.0, 0.3)),
        ("score_gain", -1.0),
        ("motion", -0.1),
        ("motion", 1.5),
        ("motion", float("nan")),
    ],
)
def test_config_rejects_bad_values(field, value):
    with pytest.raises(ValueError, match=field):
        TrackerConfig(**{field: value})


def test_config_accepts_edge_values():
    cfg = TrackerConfig(decay=0, smoothing=1, match_iou=1, min_hits=1, max_misses=0, threshold=0, score_gain=0)
    assert isinstance(cfg.decay, float) and cfg.decay == 0.0


# --------------------------------------------------------------------------------------------
# Exact arithmetic on tiny cases
# --------------------------------------------------------------------------------------------
def test_match_moves_box_by_moving_average_and_confirms():
    # decay 0: the integrated heat is this frame's; windows aligned to the 8-px cells, so the
    # blob box is the window itself.
    cfg = TrackerConfig(decay=0.0, threshold=0.5, min_hits=2, smoothing=0.5)
    tr = Tracker(cfg)
    assert update(tr, [[64, 64, 192, 160]], [1.5], SHAPE) == []  # opened, not confirmed
    assert len(tr.state.tracks) == 1 and tr.state.tracks[0].hits == 1
    # IoU([64,64,192,160], [80,64,208,160]) = 112/144 >= 0.2 -> matched;
    # box = 0.5 * old + 0.5 * new = [72, 64, 200, 160]; heat 1 + max(-3, 0) = 1 -> score 1.
    (t,) = update(tr, [[80, 64, 208, 160]], [-3.0], SHAPE)
    assert t.track_id == 0 and t.confirmed and t.hits == 2 and t.misses == 0 and t.age == 2
    np.testing.assert_array_equal(t.box, [72, 64, 200, 160])
    assert t.score == 1.0
    np.testing.assert_array_equal(t.int_box(), [72, 64, 200, 160])
    assert t.int_box().dtype == np.int64


def test_measured_blob_boxes_are_matched_and_averaged_into_the_tracks():
    """``measure`` sees each frame's blob boxes ((n, 4)) before association; the tracks
    average what it returns, and their back-fill holds it too."""
    cfg = TrackerConfig(decay=0.0, threshold=0.5, min_hits=2, smoothing=0.5)
    seen = []

    def measure(boxes):
        seen.append(boxes.copy())
        return boxes + [-8, 0, 8, 0]  # one cell wider each side

    tr = Tracker(cfg)
    tr.update(Detections(np.array([[64, 64, 192, 160]]), score=[1.5]), SHAPE, measure)
    found = tr.update(Detections(np.array([[80, 64, 208, 160]]), score=[1.5]), SHAPE, measure)
    assert [b.tolist() for b in seen] == [[[64, 64, 192, 160]], [[80, 64, 208, 160]]]
    assert found.xyxy.tolist() == [[64, 64, 208, 160]]  # 0.5 * [56, 64, 200, 160] + 0.5 * [72, 64, 216, 160]
    assert tr.backfill.xyxy.tolist() == [[56, 64, 200, 160]] and tr.backfill.frame.tolist() == [0]
    tr.update(Detections.empty(), SHAPE, measure)  # no blob: measure is not called
    assert len(seen) == 2


def test_score_weights_heat_and_score_gain():
    one = [[64, 64, 192, 160]]
    (t,) = update(Tracker(TrackerConfig(decay=0, threshold=0, min_hits=1)), one, [2.0], SHAPE)
    assert t.score == 3.0  # 1 + max(2, 0)
    (t,) = update(Tracker(TrackerConfig(decay=0, threshold=0, min_hits=1, score_gain=0.5)), one, [2.0], SHAPE)
    assert t.score == 2.0
    (t,) = update(Tracker(TrackerConfig(decay=0, threshold=0, min_hits=1)), one, None, SHAPE)
    assert t.score == 1.0


def test_integration_accumulates_weak_evidence():
    # One window of heat 1 per frame: integrated 1, 1.7, 2.19, 2.533 -> above 2.5 on frame 3,
    # which opens the track; confirmed after 3 hits, on frame 5.
    tr = Tracker(TrackerConfig(decay=0.7, threshold=2.5, peak_fraction=0.0))
    window = [[640, 400, 736, 496]]
    reported = [len(update(tr, window, [0.0], SHAPE)) for _ in range(7)]
    assert reported == [0, 0, 0, 0, 0, 1, 1]
    assert tr.state.tracks[0].hits == 4
    np.testing.assert_allclose(tr.state.integrated.max(), sum(0.7**k for k in range(7)), rtol=1e-6)


def test_int_box_rounds_halves_up():
    t = Track(track_id=0, box=np.array([0.5, 1.5, 2.5, 3.49]))
    np.testing.assert_array_equal(t.int_box(), [1, 2, 3, 3])


# --------------------------------------------------------------------------------------------
# Life cycle
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("n_windows, score", [(1, 0.0), (3, 1.0), (12, 4.0)])
def test_one_frame_false_positive_is_never_reported(n_windows, score):
    tr = Tracker(TrackerConfig())
    burst = car_windows([200, 500, 296, 596], offsets=[(8 * (k % 4), 8 * (k // 4)) for k in range(n_windows)])
    assert update(tr, burst, np.full(n_windows, score), SHAPE) == []
    for _ in range(15):
        # Its afterglow in the integrated heat stays above the threshold for frames, but holds no
        # heat of the current frame, so it is never matched again.
        assert update(tr, [], [], SHAPE) == []
    assert tr.state.tracks == []


def test_strong_burst_afterglow_stays_above_threshold():
    # The case the freshness rule exists for: 12 windows of heat 5 give 60; 60 * 0.7^k > 2.5 for
    # k <= 8, so blobs of pure afterglow are there, yet no track gets a second hit.
    tr = Tracker(TrackerConfig())
    burst = car_windows([200, 500, 296, 596], offsets=[(8 * (k % 4), 8 * (k // 4)) for k in range(12)])
    update(tr, burst, np.full(12, 4.0), SHAPE)
    for _ in range(3):
        update(tr, [], [], SHAPE)
        assert tr.state.integrated.max() > 2.5
        assert all(t.hits == 1 for t in tr.state.tracks)


@pytest.mark.parametrize("origin", [(600, 400), (603, 405), (1000, 430)])
def test_steady_jittering_car_is_confirmed_once_and_smoothed(origin):
    rng = np.random.default_rng(sum(origin))
    tr = Tracker(TrackerConfig())
    x0, y0 = origin
    raw, reported, ids = [], [], set()
    for f in range(20):
        jx, jy = rng.integers(-2, 3, size=2)
        car = np.array([x0 + jx, y0 + jy, x0 + 128 + jx, y0 + 96 + jy])
        out = update(tr, car_windows(car), rng.uniform(0.2, 1.5, size=4), SHAPE)
        raw.append(car)
        if f < 2:
            assert out == []  # min_hits = 3: frames 0 and 1 are not enough
            continue
        assert len(out) == 1, f"frame {f}: {snapshot(out)}"
        ids.add(out[0].track_id)
        reported.append(out[0].box)
        assert box_iou(out[0].box[None], car[None])[0, 0] > 0.6
    assert ids == {0}
    assert len(tr.state.tracks) == 1
    raw_move = np.abs(np.diff(np.array(raw, float)[2:], axis=0)).mean()
    rep_move = np.abs(np.diff(np.array(reported), axis=0)).mean()
    assert rep_move < raw_move, (rep_move, raw_move)


def test_car_that_disappears_coasts_then_is_retired():
    tr = Tracker(TrackerConfig())  # max_misses = 5
    car = np.array([500, 420, 628, 516])
    for _ in range(10):
        out = update(tr, car_windows(car), np.ones(4), SHAPE)
    (last,) = out
    for k in range(1, 6):
        # Reported for max_misses frames on its last box, misses counting up.
        (t,) = update(tr, [], [], SHAPE)
        assert (t.track_id, t.misses, t.hits) == (last.track_id, k, last.hits)
        np.testing.assert_array_equal(t.box, last.box)
    assert update(tr, [], [], SHAPE) == []  # miss 6 > max_misses: retired
    assert tr.state.tracks == []
    # A car reappearing there later is a new track.
    for _ in range(3):
        out = update(tr, car_windows(car), np.ones(4), SHAPE)
    assert [t.track_id for t in out] == [1]


def test_track_survives_short_detection_gap_with_same_id():
    tr = Tracker(TrackerConfig())
    car = np.array([500, 420, 628, 516])
    ids = []
    for f in range(20):
        windows = car_windows(car) if f not in (8, 9, 10) else np.zeros((0, 4))
        ids += [t.track_id for t in update(tr, windows, np.ones(len(windows)), SHAPE)]
    assert set(ids) == {0} and len(ids) == 18  # reported every frame from frame 2 on


def test_two_cars_get_two_ids():
    tr = Tracker(TrackerConfig())
    ids: dict[str, set[int]] = {"a": set(), "b": set()}
    for f in range(12):
        cars = {
            "a": np.array([200 + 3 * f, 420, 328 + 3 * f, 516]),
            "b": np.array([800 - 2 * f, 400, 912 - 2 * f, 480]),
        }
        windows = np.concatenate([car_windows(c) for c in cars.values()])
        out = update(tr, windows, np.ones(len(windows)), SHAPE)
        if f < 2:
            assert out == []
            continue
        assert len(out) == 2
        for name, car in cars.items():
            iou = box_iou(np.stack([t.box for t in out]), car[None])[:, 0]
            assert iou.max() > 0.5
            ids[name].add(out[int(iou.argmax())].track_id)
    assert len(ids["a"]) == len(ids["b"]) == 1
    assert ids["a"] | ids["b"] == {0, 1}


def test_association_is_one_to_one_by_iou():
    # Two tracks; one blob overlapping both goes to the closer one, the other track misses.
    cfg = TrackerConfig(decay=0.0, threshold=0.5, min_hits=1, max_misses=3, smoothing=1.0)
    tr = Tracker(cfg)
    update(tr, [[0, 400, 128, 496], [136, 400, 264, 496]], None, SHAPE)  # two blobs (8 px gap)
    out = update(tr, [[120, 400, 248, 496]], None, SHAPE)
    by_id = {t.track_id: t for t in out}
    assert set(by_id) == {0, 1}
    assert by_id[1].misses == 0 and by_id[0].misses == 1
    np.testing.assert_array_equal(by_id[1].box, [120, 400, 248, 496])
    np.testing.assert_array_equal(by_id[0].box, [0, 400, 128, 496])


def test_implausible_blobs_are_not_tracked():
    cfg = TrackerConfig(decay=0.0, threshold=0.5, min_hits=1)
    tr = Tracker(cfg)
    assert update(tr, [[0, 400, 24, 496]], None, SHAPE) == []  # 24 px wide < 32
    assert update(tr, [[0, 400, 400, 440]], None, SHAPE) == []  # aspect 10 > 4
    assert tr.state.tracks == []


# --------------------------------------------------------------------------------------------
# State, chunking, validation
# --------------------------------------------------------------------------------------------
def test_returned_tracks_are_copies():
    tr = Tracker(TrackerConfig(min_hits=1))
    (t,) = update(tr, car_windows([500, 420, 628, 516]), np.ones(4), SHAPE)
    t.box[:] = 0
    t.hits = 99
    assert tr.state.tracks[0].hits == 1 and tr.state.tracks[0].box.any()


@pytest.mark.parametrize("split", [1, 6, 12, 26, 39])
def test_chunked_processing_equals_one_pass(split):
    frames = scenario()
    whole = Tracker(TrackerConfig())
    expected = [snapshot(update(whole, b, s, SHAPE)) for b, s in frames]
    assert any(len(e) == 2 for e in expected)  # the scenario does exercise two tracks

    first = Tracker(TrackerConfig())
    got = [snapshot(update(first, b, s, SHAPE)) for b, s in frames[:split]]
    second = Tracker(TrackerConfig(), state=first.state)
    # The old tracker can go on independently without disturbing the new one.
    update(first, car_windows([10, 400, 138, 496]), np.ones(4), SHAPE)
    got += [snapshot(update(second, b, s, SHAPE)) for b, s in frames[split:]]
    assert got == expected
    np.testing.assert_array_equal(second.state.integrated, whole.state.integrated)
    assert (second.state.next_id, second.state.frame_index) == (whole.state.next_id, len(frames))


def test_state_copy_is_deep():
    tr = Tracker(TrackerConfig())
    for b, s in scenario(12):
        update(tr, b, s, SHAPE)
    snap = tr.state.copy()
    before = (snap.integrated.copy(), snapshot(snap.tracks), snap.next_id, snap.frame_index)
    for b, s in scenario(12, seed=9):
        update(tr, b, s, SHAPE)
    np.testing.assert_array_equal(snap.integrated, before[0])
    assert (snapshot(snap.tracks), snap.next_id, snap.frame_index) == before[1:]


def test_cut_forgets_tracks_and_heat_and_ids_go_on():
    tr = Tracker(TrackerConfig())
    car = np.array([500, 420, 628, 516])
    for _ in range(6):
        out = update(tr, car_windows(car), np.ones(4), SHAPE)
    (before,) = out
    index, next_id = tr.state.frame_index, tr.state.next_id
    tr.cut()
    assert tr.state.tracks == [] and not tr.state.integrated.any()
    assert (tr.state.frame_index, tr.state.next_id) == (index, next_id)
    assert update(tr, [], [], SHAPE) == []  # nothing coasts across the cut
    for _ in range(3):  # the same place after the cut: another vehicle, another id
        out = update(tr, car_windows(car), np.ones(4), SHAPE)
    assert [t.track_id for t in out] == [before.track_id + 1]


def test_shot_start_is_the_last_cut_else_where_the_tracker_started():
    car = np.array([500, 420, 628, 516])
    tr = Tracker(TrackerConfig(), TrackerState(frame_index=100))  # a range of a video from frame 100
    assert tr.shot_start == 100
    for _ in range(4):
        update(tr, car_windows(car), np.ones(4), SHAPE)
    assert tr.shot_start == 100
    tr.cut()
    assert tr.shot_start == 104
    assert Tracker(TrackerConfig(), tr.state).shot_start == 104  # a chunk continued after the cut
    tr.reset()
    assert tr.shot_start == 0
    later = Tracker(TrackerConfig(), TrackerState(frame_index=100))
    update(later, car_windows(car), np.ones(4), SHAPE)
    assert Tracker(TrackerConfig(), later.state).shot_start == 100  # the next chunk knows where the run began
    with pytest.raises(ValueError, match="shot_start"):
        Tracker(TrackerConfig(), TrackerState(frame_index=5, shot_start=6))


def test_state_copy_keeps_the_shot_check_apart():
    state = TrackerState(shot_thumbnail=np.ones((27, 48, 3), np.float32), shot_changes=(1.0, 2.0))
    snap = state.copy()
    state.shot_thumbnail[:] = 5
    assert snap.shot_thumbnail.max() == 1 and snap.shot_changes == (1.0, 2.0)


def test_frame_shape_change_raises_and_keeps_state():
    tr = Tracker(TrackerConfig())
    update(tr, car_windows([500, 420, 628, 516]), np.ones(4), (720, 1280))  # (H, W) == (H, W, 3)
    update(tr, car_windows([500, 420, 628, 516]), np.ones(4), SHAPE)
    before = tr.state.copy()
    with pytest.raises(ValueError, match="frame_shape"):
        update(tr, [], [], (721, 1280, 3))  # same heat-map size at cell 8, still refused
    assert tr.state.frame_index == before.frame_index == 2
    np.testing.assert_array_equal(tr.state.integrated, before.integrated)


@pytest.mark.parametrize(
    "boxes, scores, shape, match",
    [
        ([[0, 0, 10, 10]], [1.0, 2.0], SHAPE, "one value per box"),
        ([[0, 0, 10, 10]], [np.nan], SHAPE, "finite"),
        ([[0, 0, 10]], [1.0], SHAPE, "shape"),
        ([], [], (720,), "frame_shape"),
        ([], [], (0, 1280), "frame_shape"),
        ([], [], (720.0, 1280), "frame_shape"),
    ],
)
def test_update_rejects_bad_input(boxes, scores, shape, match):
    tr = Tracker(TrackerConfig())
    with pytest.raises(ValueError, match=match):
        update(tr, boxes, scores, shape)
    assert tr.state.frame_index == 0


def test_update_takes_detections_only():
    tr = Tracker(TrackerConfig())
    with pytest.raises(ValueError, match="Detections"):
        tr.update([[0, 0, 10, 10]], SHAPE)
    assert tr.state.frame_index == 0


def test_state_must_fit_config():
    tr = Tracker(TrackerConfig())
    update(tr, [], [], SHAPE)
    with pytest.raises(ValueError, match="cell"):
        Tracker(TrackerConfig(cell=4), state=tr.state)
    with pytest.raises(ValueError, match="TrackerState"):
        Tracker(state={"tracks": []})  # type: ignore[arg-type]
    bad = tr.state.copy()
    bad.tracks = [Track(track_id=5, box=np.zeros(4))]
    with pytest.raises(ValueError, match="next_id"):
        Tracker(state=bad)


def test_reset_forgets_everything():
    tr = Tracker(TrackerConfig())
    for b, s in scenario(15):
        update(tr, b, s, SHAPE)
    assert tr.state.next_id > 0
    tr.reset()
    assert tr.state == TrackerState()
    out = [update(tr, car_windows([300, 300, 428, 396]), np.ones(4), (480, 640)) for _ in range(3)]
    assert [t.track_id for t in out[-1]] == [0]  # ids restart; a new frame size is fine after reset


def test_confirmation_backfills_the_frames_before_it():
    """The frame a track is confirmed, it carries its boxes on the earlier frames (min_hits - 1)."""
    cfg = TrackerConfig(decay=0.6, threshold=2.0, min_hits=3, peak_fraction=0.0)
    tr = Tracker(cfg)
    car = car_windows([600, 420, 696, 516], offsets=[(0, 0), (8, 0), (0, 8), (8, 8)])
    out = [update(tr, car, np.full(len(car), 1.0), SHAPE) for _ in range(5)]
    first = next(i for i, r in enumerate(out) if r)
    assert first == cfg.min_hits - 1  # born after min_hits matched frames, never before
    (t,) = out[first]
    assert [i for i, _ in t.backfill] == list(range(first))
    for _, box in t.backfill:
        assert box.shape == (4,) and np.all(np.isfinite(box))
    assert out[first + 1][0].backfill == []  # only on the confirmation frame


def test_backfill_detections_name_the_earlier_frames():
    cfg = TrackerConfig(decay=0.6, threshold=2.0, min_hits=3, peak_fraction=0.0)
    tr = Tracker(cfg)
    car = car_windows([600, 420, 696, 516], offsets=[(0, 0), (8, 0), (0, 8), (8, 8)])
    fills = []
    for _ in range(4):
        found = tr.update(Detections(car, score=np.ones(len(car))), SHAPE)
        fills.append(tr.backfill)
    assert [len(f) for f in fills] == [0, 0, 2, 0]  # only on the confirmation frame
    assert fills[2].frame.tolist() == [0, 1]
    assert fills[2].track_id.tolist() == [found.track_id[0]] * 2


def test_window_inset_moves_the_heat_inside_each_window():
    """Heat goes to the inset part of each window: a car framed by windows that reach below it
    gets a box that stops where the insets say."""
    window = [[400, 400, 496, 496]]
    plain = Tracker(TrackerConfig(decay=0, threshold=0, min_hits=1, peak_fraction=0.0))
    inset = Tracker(TrackerConfig(decay=0, threshold=0, min_hits=1, peak_fraction=0.0, window_inset=(0.0, 0.0, 0.0, 1 / 3)))
    (a,) = update(plain, window, None)
    (b,) = update(inset, window, None)
    np.testing.assert_array_equal(a.box, [400, 400, 496, 496])
    np.testing.assert_array_equal(b.box, [400, 400, 496, 464])  # 96 - 32 rows
    with pytest.raises(ValueError, match="window_inset"):
        _TrackerConfig(window_inset=(0.0, 0.5, 0.0, 0.0))
    with pytest.raises(ValueError, match="window_inset"):
        _TrackerConfig(window_inset=(0.0, 0.1))


# --------------------------------------------------------------------------------------------
# Motion model (TrackerConfig.motion)
# --------------------------------------------------------------------------------------------
def moving_car(f: int, speed: int = 8) -> np.ndarray:
    """A car box moving ``speed`` px a frame to the right (8: it stays on the 8-px heat cells)."""
    return np.array([200 + speed * f, 400, 328 + speed * f, 496])


def follow(motion: float, frames: int = 40) -> tuple[Tracker, Track]:
    """One window on the moving car a frame; decay 0, so each blob is that frame's window."""
    tr = Tracker(TrackerConfig(decay=0.0, threshold=0.5, smoothing=0.5, motion=motion))
    for f in range(frames):
        out = update(tr, [moving_car(f)], [1.0])
    (t,) = out
    return tr, t


def test_a_moving_average_lags_a_moving_car_and_the_motion_model_does_not():
    # A moving average with weight s lags a car moving v px a frame by v (1 - s) / s: 8 px here.
    _, t = follow(motion=0.0)
    np.testing.assert_allclose(t.box - moving_car(39), [-8, 0, -8, 0], atol=1e-6)
    np.testing.assert_array_equal(t.velocity, 0)
    # With the motion model the velocity is learned and the lag dies out.
    _, t = follow(motion=0.3)
    np.testing.assert_allclose(t.box - moving_car(39), 0, atol=0.05)
    np.testing.assert_allclose(t.velocity, [8, 0, 8, 0], atol=0.05)


def test_a_lost_car_coasts_along_its_velocity_then_is_retired():
    tr, last = follow(motion=0.3)
    for k in range(1, 6):
        (t,) = update(tr, [], [])
        assert (t.track_id, t.misses) == (last.track_id, k)
        np.testing.assert_allclose(t.box - last.box, [8 * k, 0, 8 * k, 0], atol=0.5)
    assert update(tr, [], []) == []


def test_the_prediction_keeps_a_fast_car_matched_to_its_track():
    # 40 px a frame on a 128 px car, match_iou 0.5: the blob soon overlaps the lagging moving
    # average too little and opens new tracks, none confirmed; the predicted box stays on it.
    def run(motion):
        tr = Tracker(TrackerConfig(decay=0.0, threshold=0.5, smoothing=0.5, motion=motion, match_iou=0.5))
        reported = set()
        for f in range(20):
            reported |= {t.track_id for t in update(tr, [moving_car(f, speed=40)], [1.0])}
        return tr.state.next_id, reported

    opened, reported = run(0.0)
    assert opened > 5 and not reported
    assert run(0.5) == (1, {0})


def test_a_prediction_that_leaves_no_box_stops_the_track():
    tr, t = follow(motion=0.3, frames=6)
    track = tr.state.tracks[0]
    track.velocity = np.array([0.0, 0.0, -500.0, 0.0])  # would shrink the box to nothing
    (t,) = update(tr, [], [])
    np.testing.assert_array_equal(t.box, track.box)
    assert t.box[2] > t.box[0] and not t.velocity.any()


def test_the_motion_model_continues_across_chunks():
    cfg = TrackerConfig(motion=0.3)
    frames = scenario()
    whole = Tracker(cfg)
    expected = [snapshot(update(whole, b, s, SHAPE)) for b, s in frames]
    first = Tracker(cfg)
    got = [snapshot(update(first, b, s, SHAPE)) for b, s in frames[:12]]
    assert any(t.velocity.any() for t in first.state.tracks)
    second = Tracker(cfg, state=first.state)
    update(first, car_windows([10, 400, 138, 496]), np.ones(4), SHAPE)  # no effect on second
    got += [snapshot(update(second, b, s, SHAPE)) for b, s in frames[12:]]
    assert got == expected


def test_settings_saved_before_the_motion_model_load_without_it():
    d = _TrackerConfig().to_dict()
    del d["motion"]
    assert _TrackerConfig.from_dict(d).motion == 0.0
