"""Tests of vehicle_detection.metrics.tracking: hand-worked sequences, and py-motmetrics as an
independent reference for MOTA and IDF1."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vehicle_detection.geometry import box_iou
from vehicle_detection.metrics.tracking import ALPHAS, tracking_scores

BOX = np.array([[0, 0, 10, 10]])
NONE = np.zeros((0, 4), np.int64)
NO_IDS = np.zeros(0, np.int64)


def test_perfect_tracking_scores_one():
    s = tracking_scores([(np.array([1]), BOX, np.array([7]), BOX)] * 5)
    assert (s.mota, s.idf1, s.hota, s.id_switches) == (1.0, 1.0, pytest.approx(1.0), 0)


def test_one_identity_switch_halfway():
    # One car over 10 frames, tracked as id 7 then id 8, boxes exact.
    frames = [(np.array([1]), BOX, np.array([7 if f < 5 else 8]), BOX) for f in range(10)]
    s = tracking_scores(frames)
    assert s.id_switches == 1
    assert s.mota == pytest.approx(1 - 1 / 10)  # one switch over 10 objects
    # IDF1: car 1 <-> id 7 holds for 5 frames: IDTP 5, IDFN 5, IDFP 5 -> 5 / (5 + 5) = 0.5
    assert s.idf1 == pytest.approx(0.5)
    # HOTA: every box detected exactly (DetA 1); association IoU of (1, 7) = 5 / (10 + 5 - 5) =
    # 0.5, likewise (1, 8): AssA = 0.5 -> HOTA = sqrt(0.5) at every threshold.
    assert s.deta == pytest.approx(1.0) and s.assa == pytest.approx(0.5)
    assert s.hota == pytest.approx(np.sqrt(0.5))


def test_localisation_enters_hota_not_mota():
    # The tracker's box covers 60 of the 100 pixels of the car: IoU 0.6.
    tr = np.array([[0, 0, 6, 10]])
    s = tracking_scores([(np.array([1]), BOX, np.array([3]), tr)] * 4)
    assert s.mota == 1.0 and s.idf1 == 1.0  # IoU >= 0.5 is a match
    # Matched at alpha <= 0.6 only: 12 of the 19 thresholds (0.05 .. 0.60); there DetA = AssA = 1.
    assert np.sum(ALPHAS <= 0.6 + 1e-9) == 12
    assert s.hota == pytest.approx(12 / 19)


def test_misses_and_false_positives():
    far = np.array([[50, 50, 60, 60]])
    frames = [
        (np.array([1]), BOX, NO_IDS, NONE),  # missed
        (np.array([1]), BOX, np.array([4, 5]), np.vstack([BOX, far])),  # one match, one FP
        (NO_IDS, NONE, np.array([5]), far),  # FP
    ]
    s = tracking_scores(frames)
    assert s.mota == pytest.approx(1 - (1 + 2 + 0) / 2)
    # IDTP 1 (car 1 <-> 4 in one frame), IDFN 1, IDFP 2 -> 1 / (1 + 1.5)
    assert s.idf1 == pytest.approx(1 / 2.5)
    assert (s.n_gt, s.n_tracker, s.n_frames) == (2, 3, 3)


def test_empty_sequences():
    s = tracking_scores([(NO_IDS, NONE, NO_IDS, NONE)] * 3)
    assert (s.mota, s.idf1, s.hota) == (0.0, 0.0, 0.0)


@st.composite
def sequences(draw):
    """Up to 3 cars moving a little, a tracker that sometimes misses, jitters, swaps ids, adds FPs."""
    n_frames = draw(st.integers(1, 8))
    starts = [np.array([x, 0, x + 20, 20]) for x in (0, 40, 80)][: draw(st.integers(1, 3))]
    frames = []
    for f in range(n_frames):
        gt_ids, gt_boxes, tr_ids, tr_boxes = [], [], [], []
        for k, b in enumerate(starts):
            box = b + [f, 0, f, 0]
            gt_ids.append(k)
            gt_boxes.append(box)
            if draw(st.booleans()) or draw(st.booleans()):
                jitter = draw(st.integers(-8, 8))
                tr_ids.append(draw(st.sampled_from([k + 10, k + 20])))
                tr_boxes.append(box + [jitter, 0, jitter, 0])
        if draw(st.booleans()) and draw(st.booleans()):
            tr_ids.append(99)
            tr_boxes.append(np.array([200, 200, 220, 220]))
        if len(set(tr_ids)) != len(tr_ids):  # one box per id and frame
            keep = {i: n for n, i in enumerate(tr_ids)}
            tr_ids, tr_boxes = list(keep), [tr_boxes[n] for n in keep.values()]
        frames.append((np.array(gt_ids), np.array(gt_boxes).reshape(-1, 4), np.array(tr_ids, np.int64), np.array(tr_boxes).reshape(-1, 4)))
    return frames


@settings(deadline=None, max_examples=80)
@given(sequences())
def test_mota_and_idf1_equal_py_motmetrics(frames):
    mm = pytest.importorskip("motmetrics", reason="py-motmetrics is the reference (pip install -e '.[test]')")
    acc = mm.MOTAccumulator(auto_id=True)
    for gt_ids, gt_boxes, tr_ids, tr_boxes in frames:
        iou = box_iou(gt_boxes, tr_boxes)
        acc.update(gt_ids.tolist(), tr_ids.tolist(), np.where(iou >= 0.5, 1 - iou, np.nan))
    ref = mm.metrics.create().compute(acc, metrics=["mota", "idf1", "num_switches"], name="seq")
    s = tracking_scores(frames)
    assert s.id_switches == int(ref["num_switches"].iloc[0])
    assert s.mota == pytest.approx(float(ref["mota"].iloc[0]))
    assert s.idf1 == pytest.approx(float(np.nan_to_num(ref["idf1"].iloc[0])))
    assert 0.0 <= s.hota <= 1.0 and 0.0 <= s.deta <= 1.0 and 0.0 <= s.assa <= 1.0
