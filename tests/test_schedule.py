"""Search schedule: full search every N frames, in between only the edges, the horizon and the tracks."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from vehicle_detection.detections import Detections
from vehicle_detection.detector import Detector
from vehicle_detection.search import SearchPlan, SearchScale, search

# Scales 1 and 2 with aspect 1: window corners fall on whole pixels (exact claims below).
PLAN = SearchPlan(
    scales=(SearchScale(1.0, 400, 496, step=2), SearchScale(2.0, 400, 592, step=1)),
    overhang=0.5, full_search_every=3, edge_width=160, horizon_height=96, track_margin=0.5,
)


def _key(d: Detections):
    return [tuple(b) + (k,) for b, k in zip(d.xyxy.tolist(), d.data["scale_index"].tolist())]


def _claimed(windows: Detections, plan: SearchPlan, width: int, around: np.ndarray) -> np.ndarray:
    """The windows the docs of SearchPlan promise for a between-frames search, from the boxes alone."""
    x1, y1, x2, y2 = windows.xyxy.T
    edge = (x2 <= plan.edge_width) | (x1 >= width - plan.edge_width)
    top = min(plan.scales, key=lambda s: (s.scale, s.y_start)).y_start  # the smallest windows' band
    horizon = (y1 >= top) & (y2 <= top + plan.horizon_height)
    near = np.zeros(len(windows), bool)
    for bx1, by1, bx2, by2 in around:
        w, h, m = bx2 - bx1, by2 - by1, plan.track_margin
        near |= (x1 < bx2 + m * w) & (x2 > bx1 - m * w) & (y1 < by2 + m * h) & (y2 > by1 - m * h)
    return edge | horizon | near


@pytest.mark.parametrize("border", ["frame", "crop"])
def test_between_frames_search_is_the_claimed_windows_with_the_same_margins(default_model, test_frames, border):
    frame = test_frames[0]
    plan = dataclasses.replace(PLAN, window_border=border)
    full = search(frame, default_model, plan, all_windows=True)
    around = np.array([[700.0, 420.0, 860.0, 520.0]])
    part = search(frame, default_model, plan, all_windows=True, around=around)
    claimed = _claimed(full, plan, frame.shape[1], around)
    assert 0 < claimed.sum() < len(full)
    assert _key(part) == _key(full[claimed])
    # bit for bit: windows see only their pixels and, across their border, the pixel around them
    np.testing.assert_array_equal(part.score, full.score[claimed])
    # thresholded: the hits of the full search among the claimed windows
    hits = search(frame, default_model, plan, around=around)
    assert _key(hits) == _key(full[claimed & (full.score > plan.threshold)])


def test_between_frames_search_of_the_default_plan_gives_the_full_search_margins(default_model, test_frames):
    """Every scale of the embedded plan (the fractional one, those that overhang the frame edges):
    the windows at the edges and around tracks get the margins the full search gives them."""
    plan = dataclasses.replace(default_model.detector_config.plan, full_search_every=2)
    frame = test_frames[2]
    full = search(frame, default_model, plan, all_windows=True)
    margins = dict(zip(_key(full), full.score.tolist()))
    around = np.array([[10.0, 400.0, 250.0, 560.0], [620.0, 410.0, 700.0, 460.0], [1000.0, 380.0, 1275.0, 700.0]])
    part = search(frame, default_model, plan, all_windows=True, around=around)
    assert 0 < len(part) < len(full)
    assert set(part.data["scale_index"].tolist()) == set(range(len(plan.scales)))
    assert part.score.tolist() == [margins[k] for k in _key(part)]
    # far cars: the smallest windows near the horizon are searched across the frame, not only at its edges
    alone = search(frame, default_model, plan, all_windows=True, around=np.zeros((0, 4)))
    small = alone[alone.data["scale_index"] == 0]
    assert ((small.xyxy[:, 0] > 400) & (small.xyxy[:, 2] < 880)).any()


def test_between_frames_search_without_tracks_or_regions(default_model, test_frames):
    frame = test_frames[0]
    none = dataclasses.replace(PLAN, edge_width=0, horizon_height=0)
    assert len(search(frame, default_model, none, all_windows=True, around=np.zeros((0, 4)))) == 0
    full = search(frame, default_model, PLAN, all_windows=True)
    edges = search(frame, default_model, dataclasses.replace(PLAN, horizon_height=0), all_windows=True, around=np.zeros((0, 4)))
    x1, x2 = full.xyxy[:, 0], full.xyxy[:, 2]
    assert 0 < len(edges) < len(full)
    assert _key(edges) == _key(full[(x2 <= 160) | (x1 >= frame.shape[1] - 160)])


class _Spy(Detector):
    """Records what each frame's search is asked for, without searching."""

    def __init__(self, plan):
        super().__init__()
        self.config = self.config.replace(plan=plan, car_horizon=None)  # only the frames' own searches asked
        self.asked = []

    def windows(self, frame, around=None):
        self.asked.append(None if around is None else np.array(around))
        if frame[0, 0, 0] == 1:  # a "car" in this frame
            return Detections(np.array([[600, 400, 700, 480]] * 4), score=np.full(4, 2.0))
        return Detections.empty()


@pytest.mark.parametrize("every", [1, 3])
def test_detector_searches_whole_frames_every_n(every):
    det = _Spy(dataclasses.replace(PLAN, full_search_every=every))
    frames = [np.full((720, 1280, 3), 1 if i >= 2 else 0, np.uint8) for i in range(9)]
    list(det.track(frames))
    whole = [i for i, a in enumerate(det.asked) if a is None]
    # the first min_hits (3) frames are searched whole too: a car seen from the start is confirmed there
    assert whole == (list(range(9)) if every == 1 else [0, 1, 2, 3, 6])
    if every == 3:
        # between full searches: the live tracks' boxes when the frame was submitted (the tracker
        # stands behind the search: at frame 4 it has seen frames 0 and 1, without the car)
        assert len(det.asked[4]) == 0
        assert all(len(a) == 1 for i, a in enumerate(det.asked) if a is not None and i >= 7)


def test_a_range_of_a_video_starts_with_whole_frames():
    """A run from frame 100 (``--start 100``): its first min_hits frames are searched whole."""
    from vehicle_detection.tracker import Tracker, TrackerState

    frames = [np.full((720, 1280, 3), 1, np.uint8) for _ in range(9)]  # frames 100..108
    for chunks in ([9], [1, 8], [2, 1, 6]):  # whole, or in chunks that carry the tracker's state on
        det = _Spy(dataclasses.replace(PLAN, full_search_every=3))
        state, at = TrackerState(frame_index=100), 0
        for n in chunks:
            tracker = Tracker(det.config.tracker, state)
            list(det.track(frames[at : at + n], tracker))
            state, at = tracker.state, at + n
        whole = [100 + i for i, a in enumerate(det.asked) if a is None]
        assert whole == [100, 101, 102, 105, 108], chunks


def test_a_new_shot_starts_with_whole_frames():
    """After a cut, the shot's first min_hits frames are searched whole, wherever the schedule stands."""
    det = _Spy(dataclasses.replace(PLAN, full_search_every=3))
    first, second = np.zeros((2, 720, 1280, 3), np.uint8)
    first[:, :640], second[360:] = 200, 200  # left half bright, then the bottom half: another picture
    frames = [first] * 7 + [second] * 8  # a cut at frame 7
    list(det.track(frames))
    whole = [i for i, a in enumerate(det.asked) if a is None]
    assert whole == [0, 1, 2, 3, 6, 7, 8, 9, 12]
    live = _Spy(dataclasses.replace(PLAN, full_search_every=3))  # live use: a frame at a time
    tracker = live.new_tracker()
    for frame in frames:
        live.step(frame, tracker)
    assert [i for i, a in enumerate(live.asked) if a is None] == whole


def test_default_schedule_is_every_frame_and_old_plans_load():
    assert SearchPlan().full_search_every == 1
    d = PLAN.to_dict()
    assert SearchPlan.from_dict(d) == PLAN
    old = {k: d[k] for k in ("scales", "threshold", "reference_height", "overhang", "horizon")}
    assert SearchPlan.from_dict(old) == dataclasses.replace(
        PLAN, full_search_every=1, edge_width=160, horizon_height=96, track_margin=0.5, overhang_min_scale=0.0, coarse_margin=None,
        window_border="crop")
    assert SearchPlan().overhang_min_scale == 2.0  # plans saved before it overhang at every scale, as they did
    for bad in (dict(full_search_every=0), dict(edge_width=-1), dict(track_margin=-0.1), dict(full_search_every=True)):
        with pytest.raises(ValueError):
            dataclasses.replace(PLAN, **bad)
    with pytest.raises(ValueError):
        SearchPlan.from_dict({**d, "unknown": 1})


def test_cli_full_search_every(tmp_path):
    """``detect --full-search-every N`` runs the schedule; 0 is refused as a bad command line."""
    from pathlib import Path

    import media
    from vehicle_detection.cli import main
    from vehicle_detection.io.tables import read_boxes_csv

    frames = media.copy_packets(Path(__file__).resolve().parents[1] / "test_video.mp4", tmp_path / "clip.mp4", max_frames=12)
    assert main(["detect", str(frames), "--out", str(tmp_path / "o.mp4"), "--boxes", str(tmp_path / "o.csv"),
                 "--full-search-every", "4", "--no-progress"]) == 0
    assert len(read_boxes_csv(tmp_path / "o.csv")) > 0
    with pytest.raises(SystemExit) as exc:
        main(["detect", str(frames), "--full-search-every", "0"])
    assert exc.value.code == 2
