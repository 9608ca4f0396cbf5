"""Tests of vehicle_detection.detections: the Detections type."""

from __future__ import annotations

import numpy as np
import pytest

from vehicle_detection.detections import Detections

BOXES = [[10, 20, 74, 84], [0, 0, 64, 64], [100, 20, 164, 84]]


def test_columns_are_typed_and_read_only():
    d = Detections(BOXES, score=[0.5, 1, 2], track_id=[3, 4, 5], frame=[7, 2, 7], data={"scale_index": [0, 1, 1]})
    assert d.xyxy.dtype == np.int64 and d.score.dtype == np.float64
    assert d.track_id.dtype == np.int64 and d.frame.dtype == np.int64
    for arr in (d.xyxy, d.score, d.track_id, d.frame, d.data["scale_index"]):
        with pytest.raises(ValueError, match="read-only"):
            arr[0] = 1
    with pytest.raises(TypeError):
        d.data["new"] = np.zeros(3)


def test_inputs_are_copied_not_shared():
    boxes = np.array(BOXES)
    d = Detections(boxes)
    boxes[0, 0] = 999
    assert d.xyxy[0, 0] == 10


def test_defaults_scalar_frame_and_untracked():
    d = Detections(BOXES, frame=4)
    assert d.frame.tolist() == [4, 4, 4]
    assert d.score.tolist() == [1.0, 1.0, 1.0]
    assert d.track_id is None


@pytest.mark.parametrize(
    "kwargs, fragment",
    [
        ({"xyxy": [[5, 0, 5, 10]]}, "x2 > x1"),
        ({"xyxy": [[0, 9, 5, 9]]}, "y2 > y1"),
        ({"xyxy": [[0, 0, 5.5, 9]]}, "whole pixel"),
        ({"xyxy": [[0, 0, 5, 9]], "score": [np.nan]}, "finite"),
        ({"xyxy": [[0, 0, 5, 9]], "score": [1, 2]}, "one value per box"),
        ({"xyxy": [[0, 0, 5, 9]], "frame": [-1]}, "frame must be >= 0"),
        ({"xyxy": [[0, 0, 5, 9]], "track_id": [-2]}, "track_id"),
        ({"xyxy": [[0, 0, 5, 9]], "track_id": [1.5]}, "whole numbers"),
        ({"xyxy": [[0, 0, 5, 9]], "data": {"k": [1, 2]}}, "data['k']"),
        ({"xyxy": [[0, 0, 5]]}, "shape (n, 4)"),
    ],
)
def test_rejects_bad_columns(kwargs, fragment):
    with pytest.raises(ValueError) as info:
        Detections(**kwargs)
    assert fragment in str(info.value)


def test_indexing_masks_slices_and_ints():
    d = Detections(BOXES, score=[0.5, 1, 2], track_id=[3, 4, 5], data={"s": [0, 1, 2]})
    assert d[1].xyxy.tolist() == [BOXES[1]] and len(d[1]) == 1
    assert d[d.score > 0.7].track_id.tolist() == [4, 5]
    assert d[::2].data["s"].tolist() == [0, 2]
    assert d[np.array([2, 0])].xyxy.tolist() == [BOXES[2], BOXES[0]]
    with pytest.raises(IndexError):
        d[np.array([True, False])]


def test_concatenate_fills_untracked_ids_and_keeps_common_data():
    a = Detections(BOXES[:1], track_id=[7], data={"s": [1], "t": [2]})
    b = Detections(BOXES[1:], frame=3, data={"s": [5, 6]})
    c = Detections.concatenate([a, Detections.empty(), b])
    assert c.track_id.tolist() == [7, -1, -1]
    assert c.frame.tolist() == [0, 3, 3]
    assert list(c.data) == ["s"] and c.data["s"].tolist() == [1, 5, 6]
    assert Detections.concatenate([]) == Detections.empty()
    none = Detections.empty().replace(data={"s": np.zeros(0, np.int64)})
    assert list(Detections.concatenate([none, none]).data) == ["s"]  # empty parts keep their columns
    assert Detections.concatenate([Detections.empty(tracked=True)]).track_id.tolist() == []


def test_by_frame_and_rows_round_trip():
    d = Detections(BOXES, score=[0.5, 1, 2], track_id=[3, -1, 4], frame=[7, 2, 7])
    parts = d.by_frame()
    assert list(parts) == [2, 7]
    assert parts[7].track_id.tolist() == [3, 4]
    assert d.at_frame(2).xyxy.tolist() == [BOXES[1]]
    assert d.frames().tolist() == [2, 7]
    assert Detections.from_rows(d.rows()) == d
    assert Detections.from_rows(d.replace(track_id=None).rows()).track_id is None


def test_equality_is_by_value():
    a = Detections(BOXES, score=[1, 2, 3])
    assert a == Detections(np.array(BOXES), score=np.array([1.0, 2.0, 3.0]))
    assert a != a.replace(score=[1, 2, 4])
    assert a != a.replace(track_id=[0, 1, 2])
    assert a != a.replace(frame=1)


def test_repr_is_short_and_informative():
    d = Detections(BOXES[:2], score=[0.5, 1.25], frame=3)
    assert repr(d) == "Detections(n=2, frames=[3], xyxy=[[10, 20, 74, 84], [0, 0, 64, 64]], score=[0.5, 1.25], track_id=None)"
    many = Detections.concatenate([d.replace(frame=i) for i in range(10)])
    assert repr(many).startswith("Detections(n=20, frames=[0, 1, 2, '...', 8, 9]")


def test_area():
    assert Detections(BOXES).area.tolist() == [64 * 64] * 3
