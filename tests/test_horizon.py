"""The camera's horizon from the road's lines, and the detector searching there."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from conftest import REPO
from vehicle_detection.config import DetectorConfig
from vehicle_detection.detector import Detector
from vehicle_detection.footage.horizon import (
    TOLERANCE,
    CarHorizon,
    estimate_horizon,
    horizon_from_cars,
    implied_horizon,
    vanishing_row,
)
from vehicle_detection.io.images import read_image
from vehicle_detection.search import SearchPlan


def road(vp_row: float, size=(1280, 720), vp_x: float = 0.5) -> np.ndarray:
    """A grey road with two white lane lines and a road edge meeting at (vp_x, vp_row)."""
    w, h = size
    img = np.full((h, w, 3), 70, np.uint8)
    img[: int(vp_row * h)] = (150, 180, 210)  # sky
    vp = (vp_x * w, vp_row * h)
    for bottom_x in (0.15 * w, 0.8 * w, 1.05 * w):
        # From the bottom edge towards the vanishing point, stopping short of it.
        t = 0.85
        end = (bottom_x + t * (vp[0] - bottom_x), h + t * (vp[1] - h))
        cv2.line(img, (int(bottom_x), h - 1), (int(end[0]), int(end[1])), (235, 235, 235), max(2, h // 120))
    return img


@pytest.mark.parametrize("vp_row", [0.45, 0.52, 0.583, 0.66])
@pytest.mark.parametrize("size", [(1280, 720), (960, 540), (640, 480)])
def test_vanishing_row_of_a_drawn_road(vp_row, size):
    assert vanishing_row(road(vp_row, size)) == pytest.approx(vp_row, abs=0.01)


def test_no_lines_no_row():
    assert vanishing_row(np.full((720, 1280, 3), 90, np.uint8)) is None
    assert vanishing_row(np.zeros((8, 8, 3), np.uint8)) is None
    assert estimate_horizon([]) is None


def test_estimate_needs_agreement():
    same = [road(0.5), road(0.505), road(0.495)]
    assert estimate_horizon(same) == pytest.approx(0.5, abs=0.01)
    split = [road(0.45), road(0.45), road(0.6), road(0.6)]  # no group holds 60 % of the frames
    assert estimate_horizon(split) is None
    assert estimate_horizon(split, min_share=0.5) == pytest.approx(0.45, abs=0.01)
    assert estimate_horizon(same[:2], min_frames=3) is None


def test_estimate_on_several_workers_is_the_same():
    frames = [road(0.5), road(0.505), road(0.62), road(0.495), np.full((720, 1280, 3), 90, np.uint8)]
    assert estimate_horizon(frames, workers=3) == estimate_horizon(frames) == pytest.approx(0.5, abs=0.01)
    assert estimate_horizon(iter(frames[2:3]), workers=2) == estimate_horizon(frames[2:3])
    assert estimate_horizon([], workers=2) is None


def _read_first_frames(path, n):
    from itertools import islice

    from vehicle_detection.io.video import read_frames

    frames = read_frames(path)
    try:
        return list(islice(frames, n))
    finally:
        frames.close()


_TEST_VIDEO_FRAMES: list = []


@pytest.fixture(scope="module", autouse=True)
def _test_video_frames_decoded_once():
    """The test video's first 25 frames, which most tests here read, decoded once for the module
    (read-only: a test that wrote into them would fail rather than change the others' input)."""
    yield
    _TEST_VIDEO_FRAMES.clear()


def _first_frames(path, n=25):
    if path != REPO / "test_video.mp4" or n > 25:
        return _read_first_frames(path, n)
    if not _TEST_VIDEO_FRAMES:
        for frame in _read_first_frames(path, 25):
            frame.flags.writeable = False
            _TEST_VIDEO_FRAMES.append(frame)
    return _TEST_VIDEO_FRAMES[:n]


def test_project_camera_sits_at_the_reference_horizon(test_frames):
    reference = SearchPlan().reference_horizon
    rows = [r for r in map(vanishing_row, test_frames) if r is not None]
    assert len(rows) >= 4 and max(abs(r - reference) for r in rows) <= TOLERANCE
    assert estimate_horizon(_first_frames(REPO / "test_video.mp4")[::2]) == pytest.approx(reference, abs=0.003)


def shifted(image: np.ndarray, rows: int) -> np.ndarray:
    """The scene moved up by ``rows`` (a camera tilted down): the top cut, the bottom repeated."""
    return np.ascontiguousarray(np.concatenate([image[rows:], np.repeat(image[-1:], rows, axis=0)]))


def test_detector_follows_a_camera_with_a_higher_horizon(test_frames):
    detector = Detector()
    assert detector.estimates_horizon
    # horizon 0.1 of the height higher; the first HORIZON_FRAMES (12) frames are all it measures
    video = [shifted(f, 72) for f in _first_frames(REPO / "test_video.mp4", 12)]
    tracker = detector.new_tracker()
    moved, rest = detector.for_footage(iter(video), tracker)
    assert moved.config.plan.horizon == pytest.approx(SearchPlan().reference_horizon - 0.1, abs=0.01)
    assert tracker.state.horizon_searched and tracker.state.horizon == moved.config.plan.horizon
    assert sum(1 for _ in rest) == len(video)  # no frame consumed
    # Searching there finds test1's two cars, 72 rows higher; the plan as written does not.
    image = test_frames[0]
    reference = detector.detect_image(image)
    found = moved.detect_image(shifted(image, 72))
    assert len(reference) == 2 and len(found) == 2
    from vehicle_detection.geometry import box_iou

    iou = box_iou(found.xyxy, reference.xyxy - [0, 72, 0, 72])
    assert (iou.max(axis=1) >= 0.4).all() and sorted(iou.argmax(axis=1)) == [0, 1]  # both cars, one box each
    assert len(detector.detect_image(shifted(image, 72))) < 2  # images: the plan as written


def test_video_horizon_is_kept_in_the_tracker_state_across_chunks():
    detector = Detector()
    video = [shifted(f, 72) for f in _first_frames(REPO / "test_video.mp4", 12)]
    tracker = detector.new_tracker()
    list(detector.track(video[:4], tracker))  # a first chunk of 4 frames, measured on all 4
    state = tracker.state
    assert state.horizon_searched and state.horizon is not None
    # A later chunk does not look again: it keeps the first chunk's horizon, whatever it sees.
    from vehicle_detection.tracker import Tracker

    later = Tracker(detector.config.tracker, state)
    det, _ = detector.for_footage(iter([np.zeros((720, 1280, 3), np.uint8)] * 3), later)
    assert det.config.plan.horizon == state.horizon
    # The project camera's own footage leaves the plan as written.
    tracker3 = detector.new_tracker()
    det, _ = detector.for_footage(iter(_first_frames(REPO / "test_video.mp4", 12)), tracker3)
    assert det.config is detector.config and tracker3.state.horizon is None and tracker3.state.horizon_searched


def test_config_horizon_settings_round_trip():
    cfg = DetectorConfig()
    assert cfg.auto_horizon and cfg.plan.horizon is None
    assert cfg.at_horizon(0.5).plan.horizon == 0.5
    assert not cfg.at_horizon("plan").auto_horizon and cfg.at_horizon("plan").plan.horizon is None
    assert cfg.at_horizon(0.5).at_horizon("auto") == cfg
    assert cfg.at_horizon(None) is cfg
    with pytest.raises(ValueError, match="'auto' or 'plan'"):
        cfg.at_horizon("sky")
    assert DetectorConfig.from_dict(cfg.to_dict()) == cfg
    old = cfg.to_dict()
    del old["auto_horizon"]  # files saved before it searched where the plan says
    assert DetectorConfig.from_dict(old).auto_horizon is False
    assert DetectorConfig.library_0_1().auto_horizon is False
    with pytest.raises(ValueError, match="auto_horizon"):
        DetectorConfig(auto_horizon="yes")


@pytest.mark.parametrize("value, auto, horizon", [("auto", True, None), ("plan", False, None), ("0.5", True, 0.5)])
def test_cli_horizon_values(value, auto, horizon):
    from vehicle_detection.cli import build_parser
    from vehicle_detection.cli.options import load_detector

    args = build_parser().parse_args(["detect", "x.mp4", "--horizon", value])
    config = load_detector(None, args.horizon).config
    assert config.auto_horizon is auto and config.plan.horizon == horizon
    assert Detector(config=config).estimates_horizon is (auto and horizon is None)


@pytest.fixture(scope="module")
def tilted_video(tmp_path_factory):
    """The test video's first 12 frames (all the horizon is measured on) as a camera tilted down
    by 0.1 sees them, written to a file; and its first 12 frames as they are (stream-copied)."""
    import media

    from vehicle_detection.io.video import VideoWriter

    folder = tmp_path_factory.mktemp("tilted")
    video = folder / "tilted.mp4"
    with VideoWriter(video, 25, (1280, 720), preset="ultrafast") as writer:
        for frame in _first_frames(REPO / "test_video.mp4", 12):
            writer.write(shifted(frame, 72))
    return video, media.copy_packets(REPO / "test_video.mp4", folder / "level.mp4", max_frames=12)


def test_cli_reports_the_estimated_horizon(tmp_path, capsys, tilted_video):
    from vehicle_detection.cli import main

    video, level = tilted_video
    assert main(["detect", str(video), "--no-progress", "--no-video", "--boxes", str(tmp_path / "t.csv")]) == 0
    out = capsys.readouterr().out
    line = [l for l in out.splitlines() if l.startswith("horizon: ")]
    assert len(line) == 1 and float(line[0].split()[1]) == pytest.approx(SearchPlan().reference_horizon - 0.1, abs=0.01)
    assert main(["detect", str(level), "--out", str(tmp_path / "o.mp4"), "--boxes", str(tmp_path / "o.csv"),
                 "--no-progress"]) == 0
    assert "horizon: " not in capsys.readouterr().out  # the project camera: the plan as written


def test_process_video_continues_a_given_tracker_only_at_its_frame(tmp_path):
    from vehicle_detection.pipeline import process_video

    detector = Detector()
    tracker = detector.new_tracker()
    table = process_video(REPO / "test_video.mp4", None, detector=detector, progress=False, frames=(0, 6), tracker=tracker)
    assert tracker.state.frame_index == 6 and tracker.state.horizon_searched and set(table.frame) <= set(range(6))
    with pytest.raises(ValueError, match="continues at frame 6, not at start=0"):
        process_video(REPO / "test_video.mp4", None, detector=detector, progress=False, frames=(0, 6), tracker=tracker)


def test_detector_load(tmp_path):
    default = Detector()
    assert Detector.load().config == default.config and np.array_equal(Detector.load().model.weights, default.model.weights)
    assert not Detector.load(horizon="plan").estimates_horizon
    path = default.model.replace(detector_config=default.config.at_horizon(0.5)).save(tmp_path / "m.npz")
    assert Detector.load(path).config.plan.horizon == 0.5
    assert Detector.load(path, horizon="auto").estimates_horizon


# --- the horizon from the cars ---------------------------------------------------------------


def cars_on_a_road(horizon: float, height: int = 720, ratio: float = 0.57, widths=(60, 90, 140, 220)) -> np.ndarray:
    """Boxes of cars on a flat road whose horizon is at ``horizon`` of ``height``: each car's
    bottom lies ``ratio`` times its width below it."""
    out = []
    for i, w in enumerate(widths):
        bottom = horizon * height + ratio * w
        x1 = 100 + 250 * i
        out.append([x1, bottom - 0.8 * w, x1 + w, bottom])
    return np.array(out, np.float64)


def test_implied_horizon_is_the_ground_plane_of_each_box():
    boxes = cars_on_a_road(0.52, 540)
    assert np.allclose(implied_horizon(boxes, 540, 0.57), 0.52)
    assert implied_horizon([[0, 0, 100, 300]], 600, 1.0)[0] == pytest.approx(200 / 600)
    assert implied_horizon(np.zeros((0, 4)), 600, 0.5).shape == (0,)


def test_horizon_from_cars_found_where_the_bands_were_right():
    rule = CarHorizon()
    cars = cars_on_a_road(0.47)
    margins = np.full(len(cars), 1.5)
    # Found at the candidates near 0.47 (0.43 and 0.51): they say 0.47.
    found = [(0.43, cars[:3], margins[:3]), (0.51, cars[1:], margins[1:])]
    assert horizon_from_cars(found, 720, rule) == pytest.approx(0.47, abs=1e-9)
    # Windows hot at a candidate far from what their boxes imply (scenery, far clusters) do not count...
    wrong = cars_on_a_road(0.30)
    assert horizon_from_cars(found + [(0.67, wrong, np.full(4, 3.0))], 720, rule) == pytest.approx(0.47, abs=1e-9)
    # ...nor weak windows, nor too few.
    assert horizon_from_cars([(0.43, cars, np.full(4, 0.9)), (0.51, cars, np.full(4, 0.9))], 720, rule) is None
    assert horizon_from_cars([(0.51, cars, margins)], 720, rule) is None  # 4 < min_hits
    assert horizon_from_cars([(0.51, cars, margins)], 720, CarHorizon(min_hits=4)) == pytest.approx(0.47, abs=1e-9)
    assert horizon_from_cars([], 720, rule) is None


def test_horizon_from_cars_that_disagree_is_none():
    rule = CarHorizon(agree=0.2)
    a, b = cars_on_a_road(0.40), cars_on_a_road(0.55)
    found = [(0.43, a, np.full(4, 2.0)), (0.51, b, np.full(4, 2.0))]  # two halves, 0.15 apart
    assert horizon_from_cars(found, 720, rule) is None
    heavier = [(0.43, a, np.full(4, 2.0)), (0.51, b, np.full(4, 6.0))]  # most of the weight agrees
    assert horizon_from_cars(heavier, 720, rule) == pytest.approx(0.55, abs=1e-9)


@pytest.mark.parametrize("bad", [{"ratio": 0.0}, {"ratio": 2.5}, {"agree": 0.5}, {"candidates": ()},
                                 {"candidates": (0.5, 1.0)}, {"candidates": "0.5"}, {"min_hits": 0}, {"frames": 2.0},
                                 {"min_margin": float("nan")}])
def test_car_horizon_settings_are_checked(bad):
    with pytest.raises(ValueError, match="CarHorizon." + next(iter(bad))):
        CarHorizon(**bad)


def test_car_horizon_settings_round_trip():
    rule = CarHorizon(candidates=(0.4, 0.6), min_hits=3)
    assert CarHorizon.from_dict(rule.to_dict()) == rule and rule.to_dict()["candidates"] == [0.4, 0.6]


def _without_lines(monkeypatch):
    """Footage whose road lines give no horizon (no markings, dusk, a car hiding them)."""
    import vehicle_detection.detector as detector_module

    monkeypatch.setattr(detector_module, "estimate_horizon", lambda *a, **k: None)


def test_a_video_without_road_lines_takes_its_horizon_from_the_cars(monkeypatch):
    _without_lines(monkeypatch)
    video = [shifted(f, 72) for f in _first_frames(REPO / "test_video.mp4", 12)]  # horizon 0.1 higher
    detector = Detector()
    tracker = detector.new_tracker()
    moved, _ = detector.for_footage(iter(video), tracker)
    assert tracker.state.horizon_source == "cars"
    assert moved.config.plan.horizon == pytest.approx(SearchPlan().reference_horizon - 0.1, abs=0.02)
    # Without the rule, lines or nothing: the plan as written.
    off = Detector(config=detector.config.replace(car_horizon=None))
    tracker = off.new_tracker()
    same, _ = off.for_footage(iter(video), tracker)
    assert same.config.plan.horizon is None and tracker.state.horizon is None and tracker.state.horizon_source is None


def test_the_cars_of_a_longer_lens_give_its_horizon():
    """Clip A zoomed twice about the right half of the road (``tools/other_cameras.py``'s
    ``zoomed_2x`` view): the road's lines give no horizon, the cars give one within 0.03 of the
    true 0.556 (the project camera's 0.583 moved by the crop)."""
    import cv2

    frames = [cv2.resize(np.ascontiguousarray(f[220:580, 640:1280]), (1280, 720), interpolation=cv2.INTER_AREA)
              for f in _first_frames(REPO / "dev_set" / "project_video_clip_A.mp4", 12)]
    assert estimate_horizon(frames, min_frames=3) is None
    detector = Detector()
    tracker = detector.new_tracker()
    moved, _ = detector.for_footage(iter(frames), tracker)
    assert tracker.state.horizon_source == "cars"
    assert moved.config.plan.horizon == pytest.approx((0.583 * 720 - 220) / 360, abs=0.03)


def test_the_cars_of_the_project_camera_agree_with_its_lines():
    """Where both can be read, the cars and the lines agree within twice the tolerance."""
    frames = _first_frames(REPO / "test_video.mp4", 12)
    detector = Detector()
    state = detector.new_tracker().state
    state.overlays, state.overlays_searched, state.gain = None, True, 1.0
    from_cars = detector._horizon_from_cars(frames, state, workers=2)
    assert from_cars == pytest.approx(estimate_horizon(frames, min_frames=3), abs=2 * TOLERANCE)


def test_cli_says_where_the_horizon_came_from(tmp_path, capsys, monkeypatch, tilted_video):
    from vehicle_detection.cli import main

    _without_lines(monkeypatch)
    video, _ = tilted_video
    assert main(["detect", str(video), "--no-progress", "--no-video", "--boxes", str(tmp_path / "t.csv")]) == 0
    line = [l for l in capsys.readouterr().out.splitlines() if l.startswith("horizon: ")]
    assert len(line) == 1 and "estimated from the cars found in the video" in line[0]


def _quick_looks(frames: int) -> Detector:
    """The embedded detector without shot cuts, its cars read off ``frames`` of the 12 frames of
    each look at the horizon (4 by default): the tests of when the shot is looked at again need
    no more (the cars' horizon itself is tested on the default's 4 above)."""
    import dataclasses

    config = Detector().config
    return Detector(config=config.replace(shot_cuts=None, car_horizon=dataclasses.replace(config.car_horizon, frames=frames)))


def test_a_shot_without_lines_or_cars_is_measured_again_at_twice_its_age(monkeypatch):
    _without_lines(monkeypatch)
    detector = _quick_looks(1)  # no car on a grey picture: one frame a look will do
    grey = np.full((720, 1280, 3), 90, np.uint8)
    tracker = detector.new_tracker()
    list(detector.track([grey] * 50, tracker))
    # measured on frames 0-11, again before frame 24 (on 12-23) and 48 (on 36-47): next before 96
    assert tracker.state.horizon is None and tracker.state.horizon_retry == (0, 96)
    off = Detector(config=detector.config.replace(car_horizon=None))
    tracker = off.new_tracker()
    list(off.track([grey] * 25, tracker))
    assert tracker.state.horizon_retry is None  # with the lines only, no second look (due before frame 24)


CARS = 16  # frames of the test video after the empty road: the bands move before frame 48, its cars are confirmed by 50


def _road_then_cars():
    """36 frames of an empty road without lines, then the test video's first :data:`CARS` frames,
    shifted as a camera tilted down by 0.1 sees them. The shot is measured on frames 0-11, again
    before frame 24 (on 12-23: the road) and before frame 48 (on 36-47: the cars)."""
    cars = [shifted(f, 72) for f in _first_frames(REPO / "test_video.mp4", CARS)]
    road = cars[0].copy()
    road[300:] = road[-1:].mean(axis=(0, 1)).astype(np.uint8)  # no car, no line
    return [road] * 36 + cars


@pytest.fixture(scope="module")
def road_then_cars_run(tmp_path_factory):
    """:func:`_road_then_cars` written to a video, and the video through ``process_video`` with a
    detector without shot cuts whose lines give no horizon, reading the cars off one frame of each
    look, once for the tests below: ``(path, decoded frames, detector, boxes, tracker state)``."""
    from vehicle_detection.io.video import VideoWriter, read_frames
    from vehicle_detection.pipeline import process_video

    path = tmp_path_factory.mktemp("road_then_cars") / "road_then_cars.mp4"
    with VideoWriter(path, 25, (1280, 720), preset="ultrafast") as writer:
        for frame in _road_then_cars():
            writer.write(frame)
    with pytest.MonkeyPatch.context() as mp:
        _without_lines(mp)
        detector = _quick_looks(1)
        tracker = detector.new_tracker()
        whole = process_video(path, None, detector=detector, progress=False, tracker=tracker)
    return path, list(read_frames(path)), detector, whole, tracker.state


@pytest.mark.xdist_group(name="horizon_road_then_cars")
def test_cars_that_come_later_give_the_horizon(monkeypatch, road_then_cars_run):
    """An empty road first, then cars: the horizon is read off them when the shot is measured
    again, and the bands move there (lines give none; the camera tilted down by 0.1)."""
    _without_lines(monkeypatch)
    _, video, detector, found, state = road_then_cars_run
    assert state.horizon_source == "cars" and state.horizon_retry is None
    assert state.horizon == pytest.approx(SearchPlan().reference_horizon - 0.1, abs=0.02)
    # measured again before frame 48 on frames 36-47: the frames after it are searched there, and
    # the test video's two cars are found in each (the plan as written finds neither)
    assert len(video) == 36 + CARS and all((found.frame == i).sum() == 2 for i in range(50, len(video)))
    off = Detector(config=detector.config.replace(car_horizon=None))
    assert sum(len(f) for f in off.track(video[36:])) == 0  # the cars, at the plan's bands


@pytest.mark.xdist_group(name="horizon_road_then_cars")
def test_a_second_look_reads_frames_as_decoded_not_as_drawn_on(monkeypatch, road_then_cars_run):
    """The caller draws on the frames it gets back (``process_video`` does); the frames of a
    second look at the horizon are the decoded ones all the same."""
    from vehicle_detection.detections import Detections

    _without_lines(monkeypatch)
    _, video, detector, clean, _ = road_then_cars_run  # process_video's run, which draws nothing without a video
    drawn = []
    for frame, found in detector.track_frames([f.copy() for f in video]):
        frame[...] = 255  # drawn over, entirely
        drawn.append(found)
    assert len(clean) > 0 and len(drawn) == len(video) and Detections.concatenate(drawn) == clean


@pytest.mark.xdist_group(name="horizon_road_then_cars")
def test_chunks_measure_again_as_a_whole_run_does(monkeypatch, road_then_cars_run):
    from vehicle_detection.pipeline.batch import detect_chunked

    _without_lines(monkeypatch)
    video, _, detector, whole, state = road_then_cars_run  # the whole run: process_video's
    assert state.horizon_source == "cars" and len(whole)  # found at the second look, before frame 48
    # Chunks of 10 frames start with a look pending and fewer than 12 frames before them (at 10),
    # with 12 (at 20 and 40, looks due at 24 and 48 inside them) and after the last look (at 50,
    # as the cars' tracks are confirmed): every case chunks of 20 met, and more.
    assert detect_chunked(video, 10, detector=detector) == whole


@pytest.mark.parametrize("name", ["test1.jpg", "test4.jpg", "test6.jpg"])
def test_an_image_without_lines_takes_its_horizon_from_its_cars(monkeypatch, name):
    """``detect --horizon auto`` on an image: its lines, else its cars (a camera tilted down by 0.1)."""
    image = shifted(read_image(REPO / "test_images" / name), 72)
    detector = Detector()
    _without_lines(monkeypatch)
    estimate, source = detector.image_horizon(image)
    assert source == "cars" and estimate == pytest.approx(SearchPlan().reference_horizon - 0.1, abs=0.02)
    assert Detector(config=detector.config.replace(car_horizon=None)).image_horizon(image) == (None, None)


def test_an_image_without_lines_or_cars_has_no_horizon(monkeypatch):
    """An empty grey picture: no line, no car (once, not for each image above)."""
    _without_lines(monkeypatch)
    assert Detector().image_horizon(np.full((720, 1280, 3), 90, np.uint8)) == (None, None)


def test_an_image_in_black_bars_reads_the_horizon_of_its_picture(monkeypatch):
    """Letterboxed and pillarboxed, an image gives the horizon of its picture (a fraction of the
    picture's height, where the search places its bands), from its cars and from its lines."""
    def boxed(picture):
        out = np.zeros((1120, 1600, 3), np.uint8)  # bars of 200 rows and 160 columns
        out[200:920, 160:1440] = picture
        return out

    detector = Detector()
    lines = read_image(REPO / "test_images" / "test3.jpg")  # its lines give 0.589: 0.557 of the boxed frame
    (inside, source), (plain, plain_source) = detector.image_horizon(boxed(lines)), detector.image_horizon(lines)
    assert source == plain_source == "lines" and inside == pytest.approx(plain, abs=0.01)
    _without_lines(monkeypatch)
    cars = read_image(REPO / "test_images" / "test1.jpg")  # its cars give 0.587
    (inside, source), (plain, plain_source) = detector.image_horizon(boxed(cars)), detector.image_horizon(cars)
    assert source == plain_source == "cars" and inside == pytest.approx(plain, abs=0.01)
