"""The detector: single images on real frames, and the fixed-lag tracking over frames."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vehicle_detection.config import DetectorConfig
from vehicle_detection.detections import Detections
from vehicle_detection.detector import Detector
from vehicle_detection.tracker import TrackerConfig


class _Scripted(Detector):
    """A detector whose windows come from a script instead of a classifier."""

    def __init__(self, script, tracker=TrackerConfig()):
        super().__init__(config=DetectorConfig(tracker=tracker))  # the model is never used
        self.script = script

    def windows(self, frame):
        boxes = np.asarray(self.script(int(frame[0, 0, 0])), dtype=np.int64).reshape(-1, 4)
        return Detections(boxes, score=np.full(len(boxes), 2.0))


def _frames(n):
    # Frame i carries its index in pixel (0, 0) so the scripted search knows which frame it is.
    out = []
    for i in range(n):
        f = np.zeros((720, 1280, 3), np.uint8)
        f[0, 0, 0] = i
        out.append(f)
    return out


def _car(i):
    return [[600 + dx, 420 + dy, 696 + dx, 516 + dy] for dx in (0, 8, 16) for dy in (0, 8)]


@pytest.mark.parametrize("workers", [1, 2])
def test_vehicle_reported_from_its_first_frame(workers):
    det = _Scripted(lambda i: _car(i) if i >= 2 else [], tracker=TrackerConfig(threshold=2.0, min_hits=3))
    out = list(det.track(_frames(10), workers=workers))
    reported = [len(d) for d in out]
    assert reported == [0, 0] + [1] * 8  # back-filled from frame 2, where the car appeared
    assert [int(d.frame[0]) for d in out[2:]] == list(range(2, 10))
    assert len({int(d.track_id[0]) for d in out[2:]}) == 1


@pytest.mark.parametrize("workers", [1, 2])
def test_one_frame_false_positive_never_reported(workers):
    det = _Scripted(lambda i: _car(i) if i == 3 else [], tracker=TrackerConfig(threshold=2.0, min_hits=3))
    assert all(len(d) == 0 for d in det.track(_frames(12), workers=workers))


def test_track_frames_yields_the_frames_in_order():
    frames = _frames(7)
    det = _Scripted(lambda i: [])
    got = [f for f, _ in det.track_frames(frames)]
    assert all(a is b for a, b in zip(got, frames)) and len(got) == 7


def test_detect_image_on_test_frames(test_frames):
    det = Detector()
    for frame in test_frames:
        windows = det.windows(frame)
        res = det.detect_image(frame, windows)  # searched once; the search of its own is used below
        assert isinstance(res, Detections) and res.track_id is None
        assert np.all(res.xyxy[:, [0, 2]] <= frame.shape[1]) and np.all(res.xyxy[:, [1, 3]] <= frame.shape[0])
        assert det.heat(frame.shape, windows).shape == (frame.shape[0] // 8, frame.shape[1] // 8)
    # test1.jpg has two cars side by side on the right: both found.
    assert len(det.detect_image(test_frames[0])) == 2


def test_detector_runs_with_the_settings_saved_in_the_model(default_model, test_frames):
    det = Detector(default_model)
    assert det.config == default_model.detector_config
    # A model whose image threshold is out of reach finds nothing; the same arrays with the
    # saved settings find the two cars.
    strict = default_model.replace(detector_config=default_model.detector_config.replace(image_threshold=1e9))
    assert len(Detector(strict).detect_image(test_frames[0])) == 0
    assert len(Detector(strict, config=default_model.detector_config).detect_image(test_frames[0])) == 2


def test_detector_refuses_wrong_types():
    with pytest.raises(ValueError, match="VehicleClassifier"):
        Detector(model=object())
    with pytest.raises(ValueError, match="DetectorConfig"):
        Detector(config=TrackerConfig())


def test_no_box_on_the_empty_road(test_frames):
    """test2.jpg shows an empty road (and the barrier at the left edge): no box."""
    assert len(Detector().detect_image(test_frames[1])) == 0


# --- black bars and static overlays (see also test_overlays.py) ------------------------------


def _pad(frame, top, bottom, left, right):
    import cv2

    return cv2.copyMakeBorder(np.ascontiguousarray(frame), top, bottom, left, right, cv2.BORDER_CONSTANT, value=(0, 0, 0))


def _same_boxes(a, b, tol):
    """Two box sets equal within ``tol`` pixels, rows in any order."""
    if len(a) != len(b):
        return False
    return not len(a) or np.abs(np.sort(a, axis=0) - np.sort(b, axis=0)).max() <= tol


_UNPADDED: dict = {}


def _unpadded_boxes(det, tol, i, frame):
    """The boxes of test frame ``i`` itself, found once for each of the two settings compared below
    (``tol`` 0: the saved ones; else without the side fit)."""
    if (tol > 0, i) not in _UNPADDED:
        _UNPADDED[tol > 0, i] = det.detect_image(frame).xyxy
    return _UNPADDED[tol > 0, i]


@pytest.mark.parametrize("bars, tol", [((0, 0, 160, 160), 0), ((96, 96, 0, 0), 0), ((45, 45, 101, 101), 8)])
def test_no_box_on_black_bars_of_images(test_frames, bars, tol):
    """Padded images give the boxes of the picture, shifted: exactly when the bars are whole heat
    cells (the sides fitted to the picture, whose edges count as the frame's); else the heat's
    boxes within one cell (8 px), which the side fit may then move to different edges."""
    top, bottom, left, right = bars
    det = Detector()
    compared = det if tol == 0 else Detector(config=det.config.replace(side_fit=None))
    first = None
    for i, frame in enumerate(test_frames):
        padded = _pad(frame, *bars)
        windows = det.windows(padded)  # the side fit changes the boxes, not the windows
        first = windows if first is None else first
        found = det.detect_image(padded, windows)
        xy = found.xyxy - [left, top, left, top]
        assert (xy >= 0).all() and (xy[:, [0, 2]] <= 1280).all() and (xy[:, [1, 3]] <= 720).all()
        xy = (found if compared is det else compared.detect_image(padded, windows)).xyxy - [left, top, left, top]
        assert _same_boxes(xy, _unpadded_boxes(compared, tol, i, frame), tol)
    # The search sees the picture at its own height: without the cut, letterboxed cars are smaller.
    off = Detector(config=det.config.replace(auto_overlays=False))
    if top:
        assert not _same_boxes(off.windows(_pad(test_frames[0], *bars)).xyxy, first.xyxy, tol)


@pytest.fixture(scope="module")
def clip_a_frames():
    from itertools import islice

    from conftest import REPO
    from vehicle_detection.io.video import read_frames

    frames = read_frames(REPO / "dev_set" / "project_video_clip_A.mp4")
    try:
        return list(islice(frames, 14))  # the first 12 measure the footage (HORIZON_FRAMES), 2 more are tracked after
    finally:
        frames.close()


@pytest.fixture(scope="module")
def clip_a_tracked(clip_a_frames):
    """Clip A's frames tracked without bars, by the saved settings (False) and without the side fit
    (True): each made once, for the cases that compare with it."""
    cache = {}

    def tracked(no_side_fit):
        if no_side_fit not in cache:
            det = Detector()
            if no_side_fit:
                det = Detector(config=det.config.replace(side_fit=None))
            cache[no_side_fit] = Detections.concatenate(det.track(clip_a_frames))
        return cache[no_side_fit]

    return tracked


@pytest.fixture(scope="module")
def padded_tracked(clip_a_frames):
    """Clip A's frames inside ``bars`` tracked by the saved settings or without the side fit:
    ``(boxes, tracker state)``, each made once (the pillarbox run serves two tests)."""
    cache = {}

    def tracked(bars, no_side_fit):
        if (bars, no_side_fit) not in cache:
            det = Detector()
            if no_side_fit:
                det = Detector(config=det.config.replace(side_fit=None))
            tracker = det.new_tracker()
            found = Detections.concatenate(det.track([_pad(f, *bars) for f in clip_a_frames], tracker))
            cache[bars, no_side_fit] = found, tracker.state
        return cache[bars, no_side_fit]

    return tracked


@pytest.mark.parametrize("bars, tol", [((0, 0, 160, 160), 0), ((48, 48, 104, 104), 0), ((45, 45, 101, 101), 12)])
def test_no_box_on_black_bars_of_a_video(clip_a_frames, clip_a_tracked, padded_tracked, bars, tol):
    top, bottom, left, right = bars
    # tol: the heat's boxes within a cell and a half (without the side fit, which may move them to different edges)
    reference = clip_a_tracked(bool(tol))
    found, state = padded_tracked(bars, bool(tol))
    h, w = clip_a_frames[0].shape[:2]
    assert state.overlays.area == (left, top, left + w, top + h)
    assert state.overlays.mask is None
    xy = found.xyxy - [left, top, left, top]
    assert len(reference) >= 2 * len(clip_a_frames) and (xy >= 0).all()  # two cars a frame and (xy[:, [0, 2]] <= w).all() and (xy[:, [1, 3]] <= h).all()
    for i in range(len(clip_a_frames)):
        assert _same_boxes(xy[found.frame == i], reference.xyxy[reference.frame == i], tol), i


def test_overlays_are_kept_in_the_tracker_state_across_chunks(padded_tracked):
    from vehicle_detection.tracker import Tracker

    det = Detector()
    _, state = padded_tracked((0, 0, 160, 160), False)  # a first chunk of 14 pillarboxed frames, measured on 12
    assert state.overlays_searched and state.overlays.area == (160, 0, 1440, 720)
    later = Tracker(det.config.tracker, state)
    assert later.state.overlays is state.overlays  # immutable: shared by copies
    moved, rest = det.for_footage(iter([np.full((720, 1600, 3), 128, np.uint8)] * 3), later)
    assert moved._overlays is state.overlays and sum(1 for _ in rest) == 3  # not measured again


def test_each_shot_is_measured_again(clip_a_frames, test_frames):
    """Clip A inside pillarbox bars, then a cut to another road filling the frame: the second shot
    is searched as a video of its own would be (its whole width), not inside the first's bars."""
    import cv2

    det = Detector()
    first = [_pad(f, 0, 0, 160, 160) for f in clip_a_frames[:12]]  # the bars measured on all 12
    second = [cv2.resize(test_frames[0], (1600, 720), interpolation=cv2.INTER_AREA)] * 6
    tracker = det.new_tracker()
    found = Detections.concatenate(det.track(first + second, tracker))
    assert tracker.state.cuts == (12,) and tracker.state.overlays.area == (0, 0, 1600, 720)
    alone = Detections.concatenate(det.track(second))
    assert len(alone) >= 6 and (alone.xyxy[:, 2] > 1440).any()  # a car beyond the first shot's picture
    for i in range(len(second)):
        assert _same_boxes(found.xyxy[found.frame == 12 + i], alone.xyxy[alone.frame == i], 0), i
    assert (found.xyxy[found.frame < 12][:, [0, 2]] >= 160).all()  # the first shot inside its bars


def test_windows_on_the_static_mask_are_dropped(test_frames):
    from vehicle_detection.detector import MASKED_SHARE
    from vehicle_detection.footage.overlays import Overlays

    det = Detector()
    frame = test_frames[0]  # a black car at x 816..952, a white one from x 1048 to the right edge
    windows = det.windows(frame)
    mask = np.zeros((720, 1280), bool)
    mask[:, 1000:] = True  # as if the white car were glued to the camera
    on_mask = np.clip(windows.xyxy[:, 2] - 1000, 0, None) / (windows.xyxy[:, 2] - windows.xyxy[:, 0]) > MASKED_SHARE
    assert on_mask.sum() >= 5 and (~on_mask).sum() >= 5
    masked = det.with_overlays(Overlays((720, 1280), (0, 0, 1280, 720), mask))
    assert masked.windows(frame) == windows[~on_mask]
    kept = masked.detect_image(frame).xyxy
    assert len(kept) == 1 and kept[0, 0] > 800 and kept[0, 2] < 1000  # the black car only
    assert len(det.detect_image(frame)) == 2
    assert det.with_overlays(None) is det


def test_overlays_can_be_turned_off(clip_a_frames):
    det = Detector(config=DetectorConfig().replace(auto_overlays=False))
    tracker = det.new_tracker()
    moved, _ = det.for_footage(iter([_pad(f, 0, 0, 160, 160) for f in clip_a_frames[:12]]), tracker)
    assert tracker.state.overlays is None and not tracker.state.overlays_searched and moved._overlays is None


def test_config_overlay_setting_round_trips():
    cfg = DetectorConfig()
    assert cfg.auto_overlays and DetectorConfig.from_dict(cfg.to_dict()) == cfg
    off = cfg.replace(auto_overlays=False)
    assert DetectorConfig.from_dict(off.to_dict()) == off and off.to_dict()["auto_overlays"] is False
    old = cfg.to_dict()
    del old["auto_overlays"]  # files saved before it get it: it changes nothing on the project camera
    assert DetectorConfig.from_dict(old).auto_overlays is True
    assert DetectorConfig.library_0_1().auto_overlays is False
    with pytest.raises(ValueError, match="auto_overlays"):
        DetectorConfig(auto_overlays=1)


def test_cli_reports_the_bars(tmp_path, capsys, clip_a_frames):
    from vehicle_detection.cli import main
    from vehicle_detection.io.video import VideoWriter

    video = tmp_path / "pillarbox.mp4"
    with VideoWriter(video, 25, (1600, 720), preset="ultrafast") as writer:
        for frame in clip_a_frames[:12]:
            writer.write(_pad(frame, 0, 0, 160, 160))
    assert main(["detect", str(video), "--no-progress", "--no-video"]) == 0  # the facts are told without a video written
    out = capsys.readouterr().out.splitlines()
    assert "picture: 1280x720 inside black bars" in out
    assert not any(line.startswith(("static overlay:", "horizon:")) for line in out)


def test_cli_reports_the_cuts_between_shots(tmp_path, capsys, clip_a_frames, test_frames):
    """Twelve frames of clip A, then another road (a test image, held for five): one cut, and no track on both sides of it."""
    from vehicle_detection.cli import main
    from vehicle_detection.io.tables import read_boxes_csv
    from vehicle_detection.io.video import VideoWriter

    video = tmp_path / "two_shots.mp4"
    with VideoWriter(video, 25, (1280, 720), preset="ultrafast") as writer:
        for frame in clip_a_frames[:12] + [test_frames[0]] * 5:
            writer.write(frame)
    assert main(["detect", str(video), "--no-progress", "--boxes", str(tmp_path / "b.csv"), "--no-video"]) == 0
    out = capsys.readouterr().out.splitlines()
    assert "1 cut between shots (frame 12): tracks started afresh and the footage measured again there" in out
    found = read_boxes_csv(tmp_path / "b.csv")
    before, after = set(found.track_id[found.frame < 12].tolist()), set(found.track_id[found.frame >= 12].tolist())
    assert before and after and not before & after


# --- one box per car, of any size ------------------------------------------------------------


def _labelled_cars(name):
    import json

    frames = json.loads((Path(__file__).resolve().parents[1] / "dev_set" / "test_images.json").read_text())["frames"]
    return next(np.array(sorted(f["cars"]), np.float64) for f in frames.values() if f.get("file") == name)


@pytest.mark.parametrize("name", ["test4.jpg", "test5.jpg", "test6.jpg"])
def test_two_cars_side_by_side_stay_two_boxes(name):
    """The black car copied 6 px to its own left: two cars whose heat touches, two boxes."""
    from vehicle_detection.geometry import box_iou
    from vehicle_detection.io.images import read_image

    frame = read_image(Path(__file__).resolve().parents[1] / "test_images" / name).copy()
    x1, y1, x2, y2 = _labelled_cars(name)[0].astype(int)
    nx = x1 - 6 - (x2 - x1)
    frame[y1:y2, nx : nx + x2 - x1] = frame[y1:y2, x1:x2]
    pair = np.array([[nx, y1, nx + x2 - x1, y2], [x1, y1, x2, y2]])
    found = Detector().detect_image(frame)
    near = found.xyxy[box_iou(found.xyxy, pair).max(axis=1) > 0]
    assert len(near) == 2
    assert (box_iou(pair, near).max(axis=1) >= 0.5).all()


@pytest.mark.parametrize("name, zoom", [("test1.jpg", 2.2), ("test5.jpg", 2.6), ("test6.jpg", 2.2),
                                        ("test1.jpg", 3.2), ("test5.jpg", 3.2), ("test6.jpg", 3.2)])
def test_a_car_larger_than_192_px_gets_a_fitting_box(name, zoom):
    """The nearer car zoomed about the horizon row to 270-330 px wide, and to about 400 px (a car
    close to the camera, for the 320-pixel windows): one box, IoU >= 0.7."""
    import cv2

    from vehicle_detection.geometry import box_iou
    from vehicle_detection.io.images import read_image

    frame = read_image(Path(__file__).resolve().parents[1] / "test_images" / name)
    c = np.array([880.0, 420.0])
    warp = np.array([[zoom, 0, c[0] * (1 - zoom)], [0, zoom, c[1] * (1 - zoom)]])
    big = cv2.warpAffine(frame, warp, (1280, 720), flags=cv2.INTER_LINEAR)
    car = _labelled_cars(name)[0]
    truth = np.r_[car[:2] * zoom + c * (1 - zoom), car[2:] * zoom + c * (1 - zoom)][None]
    assert truth[0, 2] - truth[0, 0] > 192
    found = Detector().detect_image(big)
    overlapping = found.xyxy[box_iou(found.xyxy, truth)[:, 0] > 0]
    assert len(overlapping) == 1 and box_iou(overlapping, truth)[0, 0] >= 0.7


# --- sides fitted to the frame -----------------------------------------------------------------


def _with_side_fit(model, fit):
    return Detector(model.replace(detector_config=model.detector_config.replace(side_fit=fit)))


def test_reported_boxes_have_their_sides_fitted_to_the_frame(default_model, test_frames):
    from vehicle_detection.refine import SideFit, fit_sides

    plain, fitted = _with_side_fit(default_model, None), _with_side_fit(default_model, SideFit())
    moved = 0
    for frame in test_frames:
        windows = plain.windows(frame)  # the side fit changes the boxes, not the windows
        before, after = plain.detect_image(frame, windows), fitted.detect_image(frame, windows)
        assert after.xyxy.tolist() == fit_sides(frame, before.xyxy, SideFit()).tolist()
        assert after.score.tolist() == before.score.tolist()
        moved += int((after.xyxy != before.xyxy).any(axis=1).sum())
    assert moved >= 3


def test_tracked_boxes_have_their_sides_fitted_before_smoothing():
    """A dark car 200 px wide whose windows all reach 12 to 20 px past its left side and stop 20
    to 28 px short of its right one: with the side fit the track's box, back-filled frames included,
    sits on the car's sides; without, it keeps the windows' error."""
    from vehicle_detection.refine import SideFit

    rng = np.random.default_rng(1)
    car = (500, 300, 700, 420)

    def frames(n):
        out = []
        for i in range(n):
            f = rng.integers(110, 130, (720, 1280, 3)).astype(np.uint8)
            f[car[1] : car[3], car[0] : car[2]] = 40
            f[0, 0, 0] = i
            out.append(f)
        return out

    def windows(i):
        return [[car[0] - 16 + dx, car[1] - 20 + dy, car[2] - 24 + dx, car[3] + dy] for dx in (-4, 0, 4) for dy in (0, 8)]

    tracker = TrackerConfig(threshold=2.0, min_hits=3, window_inset=(0.0, 0.0, 0.0, 0.0))
    fitted, plain = _Scripted(windows, tracker=tracker), _Scripted(windows, tracker=tracker)
    fitted.config = fitted.config.replace(side_fit=SideFit())
    plain.config = plain.config.replace(side_fit=None)
    video = frames(8)
    got = Detections.concatenate(fitted.track(video))
    ref = Detections.concatenate(plain.track(video))
    assert len(got) == len(ref) == 8 and got.frame.tolist() == list(range(8))  # back-filled from frame 0
    assert (np.abs(got.xyxy[:, 0] - car[0]) <= 2).all() and (np.abs(got.xyxy[:, 2] - car[2]) <= 2).all()
    assert (np.abs(ref.xyxy[:, 0] - car[0]) >= 8).all() and (np.abs(ref.xyxy[:, 2] - car[2]) >= 8).all()
    assert got.xyxy[:, [1, 3]].tolist() == ref.xyxy[:, [1, 3]].tolist()  # top and bottom as the heat gives them


@pytest.mark.parametrize("name, kind, bad", [("side_fit", "refine.SideFit", (0.1, 0.07)),
                                             ("shot_cuts", "shots.ShotCuts", {"threshold": 30.0}),
                                             ("car_horizon", "horizon.CarHorizon", {"ratio": 0.57})])
def test_optional_settings_round_trip_and_older_files_load_without_them(name, kind, bad):
    """Files saved before ``side_fit`` report their boxes as they did; before ``shot_cuts``,
    they track a video as one shot."""
    import importlib

    module, cls = kind.split(".")
    default = getattr(importlib.import_module(f"vehicle_detection.{module}"), cls)()
    cfg = DetectorConfig()
    assert getattr(cfg, name) == default and DetectorConfig.from_dict(cfg.to_dict()) == cfg
    off = cfg.replace(**{name: None})
    assert DetectorConfig.from_dict(off.to_dict()) == off and off.to_dict()[name] is None
    old = cfg.to_dict()
    del old[name]
    assert getattr(DetectorConfig.from_dict(old), name) is None
    assert getattr(DetectorConfig.library_0_1(), name) is None
    with pytest.raises(ValueError, match=name):
        DetectorConfig(**{name: bad})


def _two_shots():
    """Ten frames of one shot with a car on the left, then ten of another (other blocks of grey)
    with a car on the right."""
    out = []
    scenes = [np.random.default_rng(seed).integers(60, 200, (9, 16, 1)).astype(np.uint8).repeat(80, 0).repeat(80, 1).repeat(3, 2)
              for seed in (1, 2)]
    for i in range(20):
        f = scenes[i >= 10].copy()
        f[0, 0, 0] = i
        out.append(f)

    def windows(i):
        x = 200 if i < 10 else 900
        return [[x + dx, 420 + dy, x + 96 + dx, 516 + dy] for dx in (0, 8, 16) for dy in (0, 8)]

    return out, windows


@pytest.mark.parametrize("workers", [1, 2])
def test_no_track_is_carried_across_a_cut_between_shots(workers):
    from vehicle_detection.footage.shots import ShotCuts

    frames, windows = _two_shots()
    tracker = TrackerConfig(threshold=2.0, min_hits=3)
    det, plain = _Scripted(windows, tracker=tracker), _Scripted(windows, tracker=tracker)
    assert det.config.shot_cuts == ShotCuts()
    plain.config = plain.config.replace(shot_cuts=None)
    got = Detections.concatenate(det.track(frames, workers=workers))
    first, second = got.frame < 10, got.frame >= 10
    assert set(got.frame.tolist()) == set(range(20))  # both cars reported from their first frame
    assert not set(got.track_id[first].tolist()) & set(got.track_id[second].tolist())
    assert (got.xyxy[second, 0] > 600).all()  # only the second shot's car after the cut
    ref = Detections.concatenate(plain.track(frames, workers=workers))
    carried = ref.frame >= 10
    assert (ref.xyxy[carried, 0] < 600).any()  # as one shot, the first car's track coasts on past the cut


def test_a_cut_at_a_chunk_border_is_found_from_the_state():
    """Live steps, the tracker handed over (as between chunks) just before the cut."""
    from vehicle_detection.tracker import Tracker

    frames, windows = _two_shots()
    det = _Scripted(windows, tracker=TrackerConfig(threshold=2.0, min_hits=3))
    tracker = det.new_tracker()
    for f in frames[:10]:
        before = det.step(f, tracker)
    assert len(before) == 1
    tracker = Tracker(tracker.config, tracker.state)
    after = det.step(frames[10], tracker)
    assert len(after) == 0 and tracker.state.tracks and all(t.track_id > before.track_id[0] for t in tracker.state.tracks)


def test_config_traffic_setting_round_trips_and_is_checked():
    cfg = DetectorConfig()
    assert cfg.traffic == "right" and DetectorConfig.from_dict(cfg.to_dict()) == cfg
    left = cfg.replace(traffic="left")
    assert DetectorConfig.from_dict(left.to_dict()) == left and left.to_dict()["traffic"] == "left"
    old = cfg.to_dict()
    del old["traffic"]  # files saved before it: right-hand traffic, as every labelled frame was
    assert DetectorConfig.from_dict(old).traffic == "right"
    for bad in ("LEFT", "both", None, 1):
        with pytest.raises(ValueError, match="traffic"):
            DetectorConfig(traffic=bad)


def test_left_hand_traffic_finds_in_a_flipped_frame_the_flipped_windows_and_boxes(test_frames):
    # In left-hand traffic the picture is searched flipped: a frame flipped left to right, as a
    # camera in left-hand traffic would see the road, gives exactly the flipped windows (margins,
    # refined boxes) and boxes of the frame in right-hand traffic.
    from vehicle_detection.geometry import mirror_boxes

    right, left = Detector.load(), Detector.load(traffic="left")
    assert left.config.traffic == "left" and right.config.traffic == "right"
    found = 0
    for frame in test_frames:
        flipped, width = np.ascontiguousarray(frame[:, ::-1]), frame.shape[1]
        a, b = right.windows(frame), left.windows(flipped)
        mirrored = mirror_boxes(b.xyxy, width)
        order_a, order_b = np.lexsort(a.xyxy.T[::-1]), np.lexsort(mirrored.T[::-1])
        assert np.array_equal(a.xyxy[order_a], mirrored[order_b])
        assert np.array_equal(a.score[order_a], b.score[order_b])
        assert np.array_equal(a.data["box"][order_a], mirror_boxes(b.data["box"], width)[order_b])
        boxes = right.detect_image(frame, a).xyxy  # the windows found above, searched once
        assert sorted(boxes.tolist()) == sorted(mirror_boxes(left.detect_image(flipped, b).xyxy, width).tolist())
        found += len(boxes)
    assert found >= 6
    # and right-hand traffic's search of the flipped frame is not that: the model is not symmetric
    flipped = np.ascontiguousarray(test_frames[0][:, ::-1])
    a, b = right.windows(flipped), left.windows(flipped)
    assert len(a) != len(b) or not np.array_equal(np.sort(a.score), np.sort(b.score))


def test_patches_are_what_the_classifier_scored_in_either_traffic(test_frames):
    # Left-hand traffic's windows lie on the flipped picture's grid: its patches are cut there, so
    # a flipped frame gives exactly the patches of the frame in right-hand traffic.
    right, left = Detector.load(), Detector.load(traffic="left")
    frame = test_frames[0]
    flipped = np.ascontiguousarray(frame[:, ::-1])
    a, b = right.windows(frame), left.windows(flipped)
    pa, pb = right.patches(frame, a), left.patches(flipped, b)
    order_a, order_b = np.argsort(a.score, kind="stable"), np.argsort(b.score, kind="stable")
    assert len(a) > 10 and np.array_equal(pa[order_a], pb[order_b])
    # inside black bars too: the windows are cut from the picture the search saw
    barred = np.zeros((720, 1480, 3), np.uint8)
    barred[:, 100:1380] = flipped
    wins = left.windows(barred)
    scores = left.model.decision_images(left.patches(barred, wins))
    assert len(wins) == len(b) and np.corrcoef(scores, wins.score)[0, 1] > 0.9


def test_a_model_saved_for_left_hand_traffic_loads_for_it(tmp_path, default_model):
    path = tmp_path / "left.npz"
    default_model.replace(detector_config=default_model.detector_config.replace(traffic="left")).save(path)
    assert Detector.load(path).config.traffic == "left"
    assert Detector.load(path, traffic="right").config.traffic == "right"


def test_left_hand_traffic_flips_the_scheduled_search_around_the_tracks(test_frames):
    # Between full searches only the frame's edges, the horizon band and the tracks' surroundings
    # are searched: in left-hand traffic the tracks' boxes are flipped with the picture.
    import dataclasses

    from vehicle_detection.geometry import mirror_boxes

    right = Detector.load()
    plan = dataclasses.replace(right.config.plan, full_search_every=3)
    right = Detector(right.model, right.config.replace(plan=plan))
    left = Detector(right.model, right.config.replace(traffic="left"))
    frame = test_frames[0]
    flipped, width = np.ascontiguousarray(frame[:, ::-1]), frame.shape[1]
    around = np.array([[1040, 400, 1260, 510]], np.float64)  # a tracked car on the right
    a = right.windows(frame, around)
    b = left.windows(flipped, mirror_boxes(around, width))
    assert 0 < len(a) < len(right.windows(frame))
    assert sorted(a.xyxy.tolist()) == sorted(mirror_boxes(b.xyxy, width).tolist())
