"""Tests of vehicle_detection.metrics.detection: matching, annotation loading and scores.

Expected values are worked out by hand in the comments beside them.
"""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from strategies import box_sets

from vehicle_detection.detections import Detections
from vehicle_detection.errors import InputError
from vehicle_detection.geometry import box_iou
from vehicle_detection.metrics.detection import (
    Annotations,
    average_precision,
    camera_name,
    evaluation_report,
    find_failures,
    FrameLabels,
    frame_failures,
    pool_by_camera,
    pool_reports,
    Scores,
    evaluate_detections,
    load_annotations,
    match_frame,
)

REPO = Path(__file__).resolve().parents[1]


def _data_dir() -> Path:
    env = os.environ.get("VEHICLE_DETECTION_DATA")
    return Path(env) if env else REPO.parent / "shared" / "data"


CLIP_A = _data_dir() / "annotations" / "project_video_clip_A.json"
needs_clip_a = pytest.mark.skipif(
    not CLIP_A.is_file(),
    reason=f"shared data not found at {CLIP_A} (set VEHICLE_DETECTION_DATA to the shared data folder)",
)


# --------------------------------------------------------------------------------------------
# match_frame
# --------------------------------------------------------------------------------------------
CAR = [100, 100, 200, 200]  # 100 x 100


def _labels(cars=(), ignore=()):
    return FrameLabels(cars=list(cars), ignore=list(ignore))


class TestMatchFrame:
    def test_more_detections_than_cars(self):
        cars = [[0, 0, 10, 10], [50, 0, 60, 10]]
        dets = [
            [300, 300, 310, 310],  # nowhere near a car: FP
            [50, 0, 60, 10],  # exactly car 1
            [0, 0, 10, 9],  # car 0, IoU 90/100
            [0, 0, 3, 10],  # overlaps car 0, IoU 30/100 < 0.5: FP
        ]
        m = match_frame(dets, _labels(cars))
        assert (m.tp, m.fp, m.fn, m.ignored) == (2, 2, 0, 0)
        np.testing.assert_array_equal(m.matches, [[1, 1], [2, 0]])
        np.testing.assert_allclose(m.match_iou, [1.0, 0.9])
        np.testing.assert_array_equal(m.false_positives, [0, 3])

    @pytest.mark.parametrize("order", [(0, 1), (1, 0)])
    def test_duplicates_around_one_car(self, order):
        exact = CAR
        shifted = [110, 100, 210, 200]  # inter 90*100=9000, union 20000-9000 -> IoU 9/11
        dets = [[exact, shifted][i] for i in order]
        m = match_frame(dets, _labels([CAR]))
        assert (m.tp, m.fp, m.fn) == (1, 1, 0)
        # The better box (IoU 1) is the match, wherever it is in the list.
        assert m.matches.tolist() == [[order.index(0), 0]]
        assert m.match_iou.tolist() == [1.0]

    def test_unmatched_cars_are_false_negatives(self):
        m = match_frame([[100, 100, 200, 200]], _labels([CAR, [400, 100, 500, 200], [600, 0, 650, 50]]))
        assert (m.tp, m.fp, m.fn) == (1, 0, 2)
        np.testing.assert_array_equal(m.missed, [1, 2])

    def test_iou_threshold(self):
        det = [[150, 100, 250, 200]]  # inter 50*100, union 15000 -> IoU 1/3
        at_05 = match_frame(det, _labels([CAR]), iou_threshold=0.5)
        at_03 = match_frame(det, _labels([CAR]), iou_threshold=0.3)
        assert (at_05.tp, at_05.fp, at_05.fn) == (0, 1, 1)
        assert (at_03.tp, at_03.fp, at_03.fn) == (1, 0, 0)

    def test_threshold_is_inclusive(self):
        det = [[100, 100, 150, 200]]  # the left half of CAR: IoU exactly 5000/10000 = 0.5
        assert match_frame(det, _labels([CAR]), iou_threshold=0.5).tp == 1
        assert match_frame(det, _labels([CAR]), iou_threshold=0.51).tp == 0

    def test_prefers_more_matches_over_one_tighter_match(self):
        # c1 = [0,0,10,10], c2 = [5,0,15,10]
        # A = [0,0,10,9]:  IoU(A,c1) = 90/100 = 0.9;  IoU(A,c2) = 45/(90+100-45) = 45/145 ~ 0.310
        # B = [-5,0,5,10]: IoU(B,c1) = 50/150 ~ 0.333; IoU(B,c2) = 0
        # At threshold 0.3 the single pair A-c1 has the larger IoU sum (0.9 > 0.644), but
        # A-c2 + B-c1 finds both cars: two true positives, no false positive.
        cars = [[0, 0, 10, 10], [5, 0, 15, 10]]
        dets = [[0, 0, 10, 9], [-5, 0, 5, 10]]
        m = match_frame(dets, _labels(cars), iou_threshold=0.3)
        assert (m.tp, m.fp, m.fn) == (2, 0, 0)
        np.testing.assert_array_equal(m.matches, [[0, 1], [1, 0]])
        np.testing.assert_allclose(m.match_iou, [45 / 145, 50 / 150])

    def test_maximises_total_iou_among_equal_counts(self):
        # Both detections overlap both cars; the crossed assignment has the smaller IoU sum.
        cars = [[0, 0, 10, 10], [2, 0, 12, 10]]
        dets = [[2, 0, 12, 10], [0, 0, 10, 10]]  # det 0 = car 1, det 1 = car 0
        # IoU(car0, car1) = 80/120 = 2/3 >= 0.5, so det 0 - car 0 would also be allowed.
        m = match_frame(dets, _labels(cars))
        np.testing.assert_array_equal(m.matches, [[0, 1], [1, 0]])
        np.testing.assert_allclose(m.match_iou, [1.0, 1.0])

    def test_detection_inside_ignore_region_is_ignored(self):
        ignore = [[0, 0, 100, 50]]
        dets = [
            [10, 10, 30, 30],  # wholly inside: ignored
            [80, 0, 120, 10],  # 20 of its 40 columns inside: exactly 0.5 -> ignored (>=)
            [90, 0, 115, 10],  # 10 of 25 columns inside: 0.4 -> FP
            [300, 300, 310, 310],  # outside: FP
        ]
        m = match_frame(dets, _labels([], ignore))
        assert (m.tp, m.fp, m.fn, m.ignored) == (0, 2, 0, 2)
        np.testing.assert_array_equal(m.ignored_detections, [0, 1])
        np.testing.assert_array_equal(m.false_positives, [2, 3])
        # A lower ignore_overlap lets the 40 % one through too.
        assert match_frame(dets, _labels([], ignore), ignore_overlap=0.4).ignored == 3

    def test_overlap_must_be_inside_one_ignore_box(self):
        # The detection [0,0,100,10] is 40 % in each of two ignore boxes (80 % in total).
        ignore = [[0, 0, 40, 10], [60, 0, 100, 10]]
        m = match_frame([[0, 0, 100, 10]], _labels([], ignore))
        assert (m.fp, m.ignored) == (1, 0)

    def test_cars_take_precedence_over_ignore(self):
        m = match_frame([CAR], _labels([CAR], [[0, 0, 1000, 1000]]))
        assert (m.tp, m.fp, m.ignored) == (1, 0, 0)

    def test_matched_detection_never_ignored_but_duplicate_is(self):
        # Two boxes on a car inside an ignore region: one TP, the duplicate is ignored, not FP.
        m = match_frame([CAR, [105, 100, 205, 200]], _labels([CAR], [[0, 0, 1000, 1000]]))
        assert (m.tp, m.fp, m.ignored) == (1, 0, 1)

    @pytest.mark.parametrize(
        "dets, cars, counts",
        [
            ([], [], (0, 0, 0)),
            ([], [CAR, [300, 300, 310, 310]], (0, 0, 2)),
            ([CAR, [300, 300, 310, 310]], [], (0, 2, 0)),
            (np.zeros((0, 4)), np.zeros((0, 4), dtype=int), (0, 0, 0)),
        ],
    )
    def test_empty_frames(self, dets, cars, counts):
        m = match_frame(dets, _labels(cars))
        assert (m.tp, m.fp, m.fn) == counts
        assert m.matches.shape == (0, 2) and m.match_iou.shape == (0,)

    def test_plain_array_labels_are_cars(self):
        m = match_frame([CAR], np.array([CAR]))
        assert (m.tp, m.fp, m.fn) == (1, 0, 0)

    @pytest.mark.parametrize("kwargs", [{"iou_threshold": 0.0}, {"iou_threshold": 1.5}, {"ignore_overlap": 0}])
    def test_rejects_bad_fractions(self, kwargs):
        with pytest.raises(ValueError):
            match_frame([CAR], _labels([CAR]), **kwargs)


# --------------------------------------------------------------------------------------------
# FrameLabels and load_annotations
# --------------------------------------------------------------------------------------------
def test_frame_labels_are_read_only_int_arrays():
    labels = FrameLabels(cars=[[1, 2, 3, 4]])
    assert labels.cars.dtype == np.int64 and labels.cars.shape == (1, 4)
    assert labels.ignore.shape == (0, 4)
    with pytest.raises(ValueError):
        labels.cars[0, 0] = 7
    with pytest.raises(ValueError, match="zero area"):
        FrameLabels(cars=[[1, 2, 1, 4]])


@needs_clip_a
def test_load_real_clip_a():
    ann = load_annotations(CLIP_A)
    assert isinstance(ann, Annotations)
    assert ann.video == "videos/project_video_clip_A.mp4"
    assert list(ann.frames) == [0, 50, 100, 150, 200, 250]
    assert ann.n_cars == 12
    for labels in ann.frames.values():
        assert labels.cars.shape == (2, 4) and labels.cars.dtype == np.int64
        assert np.all(labels.cars[:, 2:] > labels.cars[:, :2])
        assert np.all(labels.cars[:, 2] <= 1280) and np.all(labels.cars[:, 3] <= 720)
        assert np.all(labels.ignore[:, 2:] > labels.ignore[:, :2])
    # The first car of frame 0 as written in the file.
    assert ann.frames[0].cars[0].tolist() == [820, 406, 971, 501]


@needs_clip_a
def test_evaluate_real_labels_as_detections_is_perfect():
    ann = load_annotations(CLIP_A)
    scores = evaluate_detections({f: lab.cars for f, lab in ann.frames.items()}, ann)
    for s in scores.values():
        assert (s.tp, s.fp, s.fn, s.ignored, s.n_frames) == (12, 0, 0, 0, 6)
        assert s.precision == s.recall == s.f1 == 1.0


@needs_clip_a
def test_real_ignore_regions_absorb_detections_on_them():
    # Detecting exactly the ignore regions: no car is matched (each ignore box overlaps the cars
    # far below IoU 0.5), and every detection lies wholly inside its own ignore box.
    ann = load_annotations(CLIP_A)
    scores = evaluate_detections({f: lab.ignore for f, lab in ann.frames.items()}, ann, [0.5])[0.5]
    n_ignore = sum(len(lab.ignore) for lab in ann.frames.values())
    assert (scores.tp, scores.fp, scores.fn, scores.ignored) == (0, 0, 12, n_ignore)


def _write(tmp_path: Path, text: str, name: str = "labels.json") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def _doc(frames) -> str:
    return json.dumps({"video": "v.mp4", "frames": frames})


GOOD_FRAME = {"cars": [[0, 0, 10, 10]], "ignore": []}


@pytest.mark.parametrize(
    "text, fragments",
    [
        ('{"frames": {"0": ', ["invalid JSON", "line 1"]),
        ("[1, 2]", ["JSON object"]),
        ('{"video": "v.mp4"}', ["'frames'"]),
        ('{"frames": [1]}', ["'frames' must be an object"]),
        ('{"video": 3, "frames": {}}', ["'video'"]),
        (_doc({"-1": GOOD_FRAME}), ['frame key "-1"']),
        (_doc({"1.5": GOOD_FRAME}), ['frame key "1.5"']),
        (_doc({"a": GOOD_FRAME}), ['frame key "a"']),
        (_doc({" 3": GOOD_FRAME}), ['frame key " 3"']),
        (_doc({"03": GOOD_FRAME}), ['frame key "03"']),
        (_doc({"7": [[0, 0, 1, 1]]}), ['frames["7"]', "object"]),
        (_doc({"7": {"ignore": []}}), ['frames["7"]', "'cars'"]),
        (_doc({"7": {"cars": [], "ignroe": []}}), ['frames["7"]', "ignroe"]),
        (_doc({"7": {"cars": {"a": 1}}}), ['frames["7"].cars', "list"]),
        (_doc({"0": GOOD_FRAME, "7": {"cars": [[0, 0, 10, 10], [1, 2, 3]]}}), ['frames["7"].cars[1]', "4 numbers"]),
        (_doc({"7": {"cars": [[0, 0, "10", 10]]}}), ['frames["7"].cars[0]', "x2 is not a number"]),
        (_doc({"7": {"cars": [[0, 0, True, 10]]}}), ['frames["7"].cars[0]', "x2 is not a number"]),
        (_doc({"7": {"cars": [[0, 0, 10.5, 10]]}}), ['frames["7"].cars[0]', "whole pixel"]),
        (_doc({"7": {"cars": [[-1, 0, 10, 10]]}}), ['frames["7"].cars[0]', "x1 = -1"]),
        (_doc({"7": {"cars": [[0, 0, 10, 10]], "ignore": [[0, 0, 5, 5], [5, 0, 5, 9]]}}),
         ['frames["7"].ignore[1]', "x2 (5) <= x1 (5)"]),
        (_doc({"7": {"cars": [[0, 9, 10, 3]]}}), ['frames["7"].cars[0]', "y2 (3) <= y1 (9)"]),
        ('{"frames": {"0": {"cars": [[0, 0, NaN, 1]]}}}', ["NaN"]),
        ('{"frames": {"0": {"cars": []}, "0": {"cars": []}}}', ["duplicate key '0'"]),
    ],
)
def test_load_annotations_rejects_broken_files(tmp_path, text, fragments):
    path = _write(tmp_path, text, name="broken_labels.json")
    with pytest.raises(InputError) as info:
        load_annotations(path)
    message = str(info.value)
    assert str(path) in message
    for fragment in fragments:
        assert fragment in message


def test_load_annotations_unreadable_files(tmp_path):
    missing = tmp_path / "nope.json"
    with pytest.raises(InputError, match="nope.json.*not found"):
        load_annotations(missing)
    with pytest.raises(InputError, match="folder"):
        load_annotations(tmp_path)
    binary = tmp_path / "binary.json"
    binary.write_bytes(b"\xff\xfe\x00garbage")
    with pytest.raises(InputError, match="binary.json.*UTF-8"):
        load_annotations(binary)


def test_load_annotations_minimal_file(tmp_path):
    # No video, no ignore lists, frames out of order, float pixels that are whole, extra keys.
    text = '{"format": "x", "frames": {"10": {"cars": [[0, 0, 4.0, 4]]}, "2": {"cars": []}}}'
    ann = load_annotations(_write(tmp_path, text))
    assert ann.video is None
    assert list(ann.frames) == [2, 10]
    assert ann.frames[10].cars.tolist() == [[0, 0, 4, 4]]
    assert ann.frames[2].cars.shape == (0, 4) and ann.frames[10].ignore.shape == (0, 4)


# --------------------------------------------------------------------------------------------
# Scores and evaluate_detections
# --------------------------------------------------------------------------------------------
class TestScores:
    def test_rates(self):
        s = Scores(tp=3, fp=1, fn=2, ignored=5, n_frames=4)
        assert s.precision == pytest.approx(3 / 4)
        assert s.recall == pytest.approx(3 / 5)
        assert s.f1 == pytest.approx(2 * 0.75 * 0.6 / (0.75 + 0.6))  # = 2/3
        assert s.fp_per_frame == pytest.approx(1 / 4)

    @pytest.mark.parametrize(
        "counts, p, r, f1",
        [
            ((0, 0, 0), 1.0, 1.0, 1.0),  # nothing to find, nothing found
            ((0, 0, 2), 1.0, 0.0, 0.0),  # no detections: precision 1 by convention
            ((0, 3, 0), 0.0, 1.0, 0.0),  # no cars: recall 1 by convention
        ],
    )
    def test_conventions(self, counts, p, r, f1):
        tp, fp, fn = counts
        s = Scores(tp=tp, fp=fp, fn=fn, ignored=0, n_frames=0)
        assert (s.precision, s.recall, s.f1, s.fp_per_frame) == (p, r, f1, 0.0)

    def test_as_dict_is_json_ready(self):
        s = Scores(tp=np.int64(3), fp=1, fn=2, ignored=0, n_frames=4, iou_sum=2.4)
        d = json.loads(json.dumps(s.as_dict()))
        assert d == {
            "tp": 3, "fp": 1, "fn": 2, "ignored": 0, "n_frames": 4,
            "precision": 0.75, "recall": 0.6, "f1": pytest.approx(2 / 3), "fp_per_frame": 0.25,
            "mean_iou": pytest.approx(0.8),
        }

    def test_rejects_negative_counts(self):
        with pytest.raises(ValueError):
            Scores(tp=-1, fp=0, fn=0, ignored=0, n_frames=1)


def _annotations(frames: dict) -> Annotations:
    return Annotations(video=None, frames={f: FrameLabels(**lab) for f, lab in frames.items()})


class TestEvaluateDetections:
    ANN = {
        0: {"cars": [CAR], "ignore": [[0, 0, 50, 50]]},
        5: {"cars": [CAR, [300, 100, 400, 200]]},
        9: {"cars": []},
    }

    def test_perfect_detections(self):
        ann = _annotations(self.ANN)
        scores = evaluate_detections({f: lab.cars for f, lab in ann.frames.items()}, ann)
        assert list(scores) == [0.5, 0.7]
        for s in scores.values():
            assert (s.tp, s.fp, s.fn, s.n_frames) == (3, 0, 0, 3)
            assert s.precision == s.recall == s.f1 == 1.0

    def test_counts_across_frames_and_thresholds(self):
        ann = _annotations(self.ANN)
        dets = {
            0: [[150, 100, 250, 200], [10, 10, 20, 20]],  # IoU 1/3 with CAR; one in ignore
            # frame 5 missing: no detections, two misses
            9: [[0, 0, 5, 5]],  # no cars: FP
            42: [[0, 0, 5, 5]] * 3,  # not annotated: not scored
        }
        scores = evaluate_detections(dets, ann, iou_thresholds=[0.5, 0.3])
        s5, s3 = scores[0.5], scores[0.3]
        # At 0.5 the shifted box misses CAR: FP; CAR, and both frame-5 cars, are missed.
        assert (s5.tp, s5.fp, s5.fn, s5.ignored, s5.n_frames) == (0, 2, 3, 1, 3)
        # At 0.3 it matches.
        assert (s3.tp, s3.fp, s3.fn, s3.ignored, s3.n_frames) == (1, 1, 2, 1, 3)
        assert s3.precision == pytest.approx(1 / 2) and s3.recall == pytest.approx(1 / 3)
        assert s3.fp_per_frame == pytest.approx(1 / 3)

    def test_no_frames(self):
        s = evaluate_detections({0: [CAR]}, Annotations(video=None, frames={}), [0.5])[0.5]
        assert (s.tp, s.fp, s.fn, s.n_frames, s.fp_per_frame) == (0, 0, 0, 0, 0.0)

    @pytest.mark.parametrize("thresholds", [[], [0.0], [1.2]])
    def test_rejects_bad_thresholds(self, thresholds):
        with pytest.raises(ValueError):
            evaluate_detections({}, _annotations(self.ANN), thresholds)

    def test_rejects_malformed_detections_naming_the_frame(self):
        with pytest.raises(ValueError, match="frame 5"):
            evaluate_detections({5: [[0, 0, 1]]}, _annotations(self.ANN))


# --------------------------------------------------------------------------------------------
# Properties
# --------------------------------------------------------------------------------------------
def _best_matching(iou: np.ndarray, threshold: float) -> tuple[int, float]:
    """(most pairs, largest IoU sum among those) over all one-to-one matchings, by brute force."""
    n_det, n_car = iou.shape
    best = (0, 0.0)

    def walk(d, used, count, total):
        nonlocal best
        if d == n_det:
            if count > best[0] or (count == best[0] and total > best[1]):
                best = (count, total)
            return
        walk(d + 1, used, count, total)
        for c in range(n_car):
            if c not in used and iou[d, c] >= threshold:
                walk(d + 1, used | {c}, count + 1, total + iou[d, c])

    walk(0, frozenset(), 0, 0.0)
    return best


@settings(deadline=None, max_examples=150)
@given(
    box_sets(max_boxes=4, max_coord=20, max_size=20),
    box_sets(max_boxes=4, max_coord=20, max_size=20),
    st.sampled_from([0.1, 0.3, 0.5, 0.7]),
)
def test_matching_is_optimal(dets, cars, threshold):
    m = match_frame(dets, FrameLabels(cars=cars), iou_threshold=threshold)
    iou = box_iou(dets, cars)
    count, total = _best_matching(iou, threshold)
    assert m.tp == count
    assert m.match_iou.sum() == pytest.approx(total)
    # One to one, above threshold, and IoUs reported correctly.
    assert len(set(m.matches[:, 0])) == len(set(m.matches[:, 1])) == m.tp
    assert np.all(m.match_iou >= threshold)
    np.testing.assert_allclose(m.match_iou, iou[m.matches[:, 0], m.matches[:, 1]])


@settings(deadline=None, max_examples=80)
@given(
    st.lists(st.tuples(box_sets(), box_sets(), box_sets(max_boxes=2)), min_size=1, max_size=5),
    st.lists(st.floats(0.05, 1.0), min_size=1, max_size=3),
    st.floats(0.05, 1.0),
)
def test_evaluation_counts_are_consistent(frames, thresholds, ignore_overlap):
    ann = Annotations(
        video=None, frames={i: FrameLabels(cars=c, ignore=ig) for i, (_, c, ig) in enumerate(frames)}
    )
    dets = {i: d for i, (d, _, _) in enumerate(frames)}
    n_cars = sum(len(c) for _, c, _ in frames)
    n_dets = sum(len(d) for d, _, _ in frames)
    scores = evaluate_detections(dets, ann, thresholds, ignore_overlap=ignore_overlap)
    assert set(scores) == set(thresholds)
    for s in scores.values():
        assert s.tp + s.fn == n_cars
        assert s.tp + s.fp + s.ignored == n_dets
        assert s.n_frames == len(frames)
        for rate in (s.precision, s.recall, s.f1):
            assert 0.0 <= rate <= 1.0


# --------------------------------------------------------------------------------------------
# Mean IoU, average precision, tracking frames and the report
# --------------------------------------------------------------------------------------------
def test_mean_iou_of_matched_pairs():
    ann = Annotations(video=None, frames={0: FrameLabels(cars=[CAR, [300, 100, 400, 200]])})
    # CAR matched exactly (IoU 1); the second car by a box covering 80 of its 100 columns (0.8).
    s = evaluate_detections(Detections([CAR, [300, 100, 380, 200]]), ann, [0.5])[0.5]
    assert s.tp == 2 and s.mean_iou == pytest.approx(0.9)


def test_average_precision_by_hand():
    cars = [[0, 0, 10, 10], [20, 0, 30, 10], [40, 0, 50, 10]]
    ann = Annotations(video=None, frames={0: FrameLabels(cars=cars[:2], ignore=[[100, 100, 200, 200]]), 1: FrameLabels(cars=cars[2:])})
    dets = Detections(
        [cars[0], [60, 0, 70, 10], [120, 120, 140, 140], cars[1], cars[0], cars[2]],
        score=[0.9, 0.8, 0.75, 0.7, 0.6, 0.5],
        frame=[0, 0, 0, 0, 0, 1],
    )
    # Ranked: TP (0.9), FP (0.8), ignored (0.75, dropped), TP (0.7), FP duplicate (0.6), TP (0.5).
    # Precision 1, 1/2, 2/3, 2/4, 3/5 at recall 1/3, 1/3, 2/3, 2/3, 1. Made monotone: 1, 2/3, 2/3, 3/5, 3/5.
    # AP = 1/3 * 1 + 1/3 * 2/3 + 1/3 * 3/5
    assert average_precision(dets, ann) == pytest.approx((1 + 2 / 3 + 3 / 5) / 3)
    assert average_precision(Detections.empty(), ann) == 0.0
    perfect = Detections(cars, frame=[0, 0, 1])
    assert average_precision(perfect, ann) == pytest.approx(1.0)


def test_report_adds_tracking_scores_for_identified_labels():
    frames = {f: FrameLabels(cars=[CAR], ids=[4], ignore=[[500, 500, 600, 600]]) for f in range(3)}
    ann = Annotations(video=None, frames=frames)
    tracked = Detections([CAR, CAR, CAR, [510, 510, 560, 560]], track_id=[1, 1, 1, 9], frame=[0, 1, 2, 2])
    report = evaluation_report(tracked, ann, fps=25.0)
    assert report["at_iou_0.5"]["f1"] == 1.0 and report["ap50"] == pytest.approx(1.0)
    assert report["fp_per_minute"] == 0.0
    # The box in the ignore region is neither a false positive nor a tracker box.
    assert report["tracking"]["mota"] == 1.0 and report["tracking"]["n_tracker"] == 3
    assert "tracking" not in evaluation_report(tracked.replace(track_id=None), ann)


def test_labels_with_ids_and_files(tmp_path):
    path = tmp_path / "labels.json"
    path.write_text(json.dumps({"video": "../imgs", "frames": {"0": {"cars": [CAR], "ids": [3], "ignore": [], "file": "a.jpg"}}}))
    ann = load_annotations(path)
    assert ann.tracked and ann.frames[0].ids.tolist() == [3] and ann.frames[0].file == "a.jpg"
    assert ann.source == tmp_path / ".." / "imgs"
    for frame, fragment in (({"cars": [CAR], "ids": [3, 4]}, "one distinct id"), ({"cars": [CAR], "ids": ["a"]}, "whole numbers"),
                            ({"cars": [CAR], "file": "x/a.jpg"}, "file name")):
        path.write_text(json.dumps({"frames": {"0": frame}}))
        with pytest.raises(InputError, match=fragment):
            load_annotations(path)


# --------------------------------------------------------------------------------------------
# Cameras: the "camera" key and per-camera pooling
# --------------------------------------------------------------------------------------------
def test_labels_camera_key(tmp_path):
    path = _write(tmp_path, json.dumps({"camera": "highway_dashcam", "frames": {"0": GOOD_FRAME}}))
    assert load_annotations(path).camera == "highway_dashcam"
    assert load_annotations(_write(tmp_path, _doc({"0": GOOD_FRAME}))).camera is None
    for bad in ("", "a/b", "../x", ".hidden", "x" * 65, 3, ["a"]):
        path = _write(tmp_path, json.dumps({"camera": bad, "frames": {"0": GOOD_FRAME}}))
        with pytest.raises(InputError, match="'camera' must be a short name"):
            load_annotations(path)


def test_camera_name_falls_back_to_the_frame_size():
    assert camera_name(Annotations(None, {}, camera="project"), (640, 480)) == "project"
    assert camera_name(Annotations(None, {}), (1280, 720)) == "1280x720"
    assert camera_name(Annotations(None, {}), None) == "unknown"


SQUARE = [0, 0, 100, 100]  # 100 x 100 = 10,000 px


def _camera_files():
    """Three labels files, two of camera "a" and one of "b", with outcomes worked out by hand."""
    a1 = Annotations(None, {0: FrameLabels(cars=[SQUARE]), 1: FrameLabels(cars=[SQUARE])})
    a1_dets = Detections([SQUARE,  # frame 0: IoU 1
                          [0, 0, 100, 60],  # frame 1: 6,000 / 10,000 = IoU 0.6
                          [500, 500, 550, 550]],  # frame 1: nowhere near a car
                         frame=[0, 1, 1])
    a2 = Annotations(None, {7: FrameLabels(cars=[SQUARE])})  # nothing reported: a miss
    b = Annotations(None, {0: FrameLabels(cars=[SQUARE])})
    b_dets = Detections([[0, 0, 100, 80]], frame=[0])  # IoU 0.8
    return {"a1.json": evaluation_report(a1_dets, a1), "a2.json": evaluation_report(Detections.empty(), a2),
            "b.json": evaluation_report(b_dets, b)}


def test_pool_by_camera_by_hand():
    reports = _camera_files()
    pooled = pool_by_camera(reports, {"a1.json": "a", "a2.json": "a", "b.json": "b"})
    assert list(pooled) == ["a", "b"]
    a, b = pooled["a"], pooled["b"]
    assert a["labels"] == ["a1.json", "a2.json"] and b["labels"] == ["b.json"]
    assert (a["n_frames"], a["n_cars"], b["n_frames"], b["n_cars"]) == (3, 3, 1, 1)
    # Camera a at IoU 0.5: frame 0 TP (IoU 1), frame 1 TP (IoU 0.6) + FP, file a2 one miss.
    s = a["at_iou_0.5"]
    assert (s["tp"], s["fp"], s["fn"], s["n_frames"]) == (2, 1, 1, 3)
    assert s["precision"] == pytest.approx(2 / 3) and s["recall"] == pytest.approx(2 / 3) and s["f1"] == pytest.approx(2 / 3)
    assert s["mean_iou"] == pytest.approx((1.0 + 0.6) / 2) and s["fp_per_frame"] == pytest.approx(1 / 3)
    # At IoU 0.7 the 0.6 box no longer matches: one more FP and one more miss.
    s = a["at_iou_0.7"]
    assert (s["tp"], s["fp"], s["fn"]) == (1, 2, 2)
    assert s["precision"] == pytest.approx(1 / 3) and s["recall"] == pytest.approx(1 / 3) and s["mean_iou"] == 1.0
    for key in ("at_iou_0.5", "at_iou_0.7"):  # camera b: one car, found at IoU 0.8
        s = b[key]
        assert (s["tp"], s["fp"], s["fn"], s["f1"]) == (1, 0, 0, 1.0) and s["mean_iou"] == pytest.approx(0.8)


def test_pool_reports_of_every_file_is_the_sum_of_the_cameras():
    reports = _camera_files()
    everything = pool_reports(reports.values())
    s = everything["at_iou_0.5"]
    assert (everything["n_frames"], everything["n_cars"]) == (4, 4)
    assert (s["tp"], s["fp"], s["fn"]) == (3, 1, 1) and s["mean_iou"] == pytest.approx((1.0 + 0.6 + 0.8) / 3)
    # One camera for every file: the same figures.
    one = pool_by_camera(reports, dict.fromkeys(reports, "c"))["c"]
    assert {k: v for k, v in one.items() if k != "labels"} == everything


# --------------------------------------------------------------------------------------------
# Failures
# --------------------------------------------------------------------------------------------
def test_frame_failures_by_hand():
    labels = FrameLabels(cars=[SQUARE, [200, 0, 300, 100], [400, 0, 500, 100]], ignore=[[0, 300, 600, 400]])
    dets = [
        [400, 0, 500, 100],  # car 2 exactly: a good match, not a failure
        [0, 0, 100, 60],  # car 0, IoU 0.6: loose
        [200, 0, 300, 40],  # car 1, IoU 0.4: no match, so car 1 is missed and this is a FP
        [100, 310, 200, 390],  # inside the ignore region: neither
        [700, 700, 720, 720],  # far from everything: FP, best IoU 0
    ]
    got = frame_failures(dets, labels, frame=5)
    assert [(f.frame, f.kind) for f in got] == [(5, "miss"), (5, "false positive"), (5, "false positive"), (5, "loose")]
    miss, fp_near, fp_far, loose = got
    assert miss.box.tolist() == [200, 0, 300, 100] and miss.iou == pytest.approx(0.4)
    assert miss.partner.tolist() == [200, 0, 300, 40]
    assert fp_near.box.tolist() == [200, 0, 300, 40] and fp_near.iou == pytest.approx(0.4)
    assert fp_far.iou == 0.0 and fp_far.partner is None
    assert loose.box.tolist() == SQUARE and loose.iou == pytest.approx(0.6) and loose.partner.tolist() == [0, 0, 100, 60]
    # With a lower loose threshold the 0.6 match is fine.
    assert [f.kind for f in frame_failures(dets, labels, loose_below=0.55)] == ["miss", "false positive", "false positive"]


def test_find_failures_over_frames():
    ann = Annotations(None, {0: FrameLabels(cars=[SQUARE]), 4: FrameLabels(cars=[SQUARE]), 9: FrameLabels(cars=[])})
    dets = Detections([SQUARE, [0, 0, 100, 65], [0, 0, 10, 10]], frame=[0, 4, 8])  # frame 8 is not labelled
    assert [(f.frame, f.kind) for f in find_failures(dets, ann)] == [(4, "loose")]
    assert [(f.frame, f.kind) for f in find_failures(Detections.empty(), ann)] == [(0, "miss"), (4, "miss")]


# --------------------------------------------------------------------------------------------
# The report folder (vehicle_detection.metrics.reporting)
# --------------------------------------------------------------------------------------------
def test_select_failures_puts_misses_and_false_positives_first():
    from vehicle_detection.metrics.detection import Failure
    from vehicle_detection.metrics.reporting import select_failures

    box = np.array(SQUARE, float)
    items = [(1, Failure(3, "loose", box, 0.6)), (0, Failure(9, "false positive", box, 0.0)),
             (1, Failure(2, "miss", box, 0.1)), (0, Failure(4, "miss", box, 0.0))]
    got = [(k, f.frame, f.kind) for k, f in select_failures(items, 3)]
    assert got == [(0, 4, "miss"), (1, 2, "miss"), (0, 9, "false positive")]
    assert select_failures(items, 0) == []
    # 100 misses and one false positive, at most 60: the false positive is kept, and the 59
    # misses are spread from the first frame to the last.
    many = [(0, Failure(f, "miss", box, 0.0)) for f in range(100)] + [(0, Failure(50, "false positive", box, 0.0))]
    got = select_failures(many, 60)
    frames = [f.frame for _, f in got if f.kind == "miss"]
    assert len(got) == 60 and [f.kind for _, f in got].count("false positive") == 1
    assert frames[0] == 0 and frames[-1] == 99 and len(set(frames)) == 59 and frames == sorted(frames)
    # Misses and false positives share the limit evenly; loose matches get what is left.
    mixed = [(0, Failure(f, k, box, 0.0)) for k in ("miss", "false positive", "loose") for f in range(10)]
    assert [f.kind for _, f in select_failures(mixed, 8)] == ["miss"] * 4 + ["false positive"] * 4
    assert [f.kind for _, f in select_failures(mixed, 25)].count("loose") == 5


def test_camera_sheet_caps_the_tiles(tmp_path):
    from vehicle_detection.io.images import write_image
    from vehicle_detection.metrics.reporting import ReportSource, camera_sheet

    folder = tmp_path / "imgs"
    for i in range(3):
        write_image(folder / f"f{i}.png", np.full((240, 320, 3), 60 * i, np.uint8))
    ann = Annotations("imgs", {i: FrameLabels(cars=[[10, 10, 60, 50]]) for i in range(3)}, path=tmp_path / "l.json")
    dets = Detections([[200, 100, 260, 160]], frame=[1])  # frame 1: a FP; every frame: a miss
    item = ReportSource(ann, dets, folder, "cam")
    sheet, counts = camera_sheet("cam", [item], limit=2)
    assert counts == {"miss": 3, "false positive": 1, "loose": 0, "shown": 2, "left_out": 2}
    assert sheet.dtype == np.uint8 and sheet.shape == (62 + 4 + 230 + 4, 640, 3)  # 2 tiles: the header's width
    sheet, counts = camera_sheet("cam", [item])
    assert counts["shown"] == 4 and counts["left_out"] == 0 and sheet.shape[1] == 4 + 4 * 260
    sheet, counts = camera_sheet("cam", [ReportSource(ann, Detections([[10, 10, 60, 50]] * 3, frame=[0, 1, 2]), folder, "cam")])
    assert counts["shown"] == 0 and sheet.shape[0] == 62 + 4  # no failures: the header alone


def test_scores_do_not_depend_on_the_order_of_the_boxes_to_the_last_bit():
    # Found by test_bad_input.test_evaluation_invariants: equal boxes tie, the matching pairs
    # them in either order, and summing the matched IoUs in that order moved the mean IoU's
    # last bit.
    import itertools

    from vehicle_detection.metrics.detection import Annotations, FrameLabels, evaluate_detections

    dets = np.array([[0, 0, 1, 1], [0, 0, 1, 1], [0, 0, 1, 1], [0, 0, 1, 1], [0, 0, 1, 4]])
    cars = np.array([[0, 0, 2, 2], [0, 0, 1, 1], [0, 0, 1, 2], [0, 0, 1, 1]])
    none = np.zeros((0, 4), np.int64)
    seen = set()
    for d, c in itertools.product(itertools.permutations(range(5)), [(0, 1, 2, 3), (3, 2, 1, 0)]):
        ann = Annotations(None, {0: FrameLabels(cars=cars[list(c)], ignore=none)})
        scores = evaluate_detections({0: dets[list(d)]}, ann, (0.3, 0.5))
        seen.add(tuple(tuple(sorted(s.as_dict().items())) for s in scores.values()))
    assert len(seen) == 1

