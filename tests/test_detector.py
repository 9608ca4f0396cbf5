"""The detector: single images on real frames, and the fixed-lag tracking over frames."""

from __future__ import annotations

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
        res = det.detect_image(frame)
        assert isinstance(res, Detections) and res.track_id is None
        assert np.all(res.xyxy[:, [0, 2]] <= frame.shape[1]) and np.all(res.xyxy[:, [1, 3]] <= frame.shape[0])
        assert det.heat(frame.shape, det.windows(frame)).shape == (frame.shape[0] // 8, frame.shape[1] // 8)
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
