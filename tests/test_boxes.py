"""Tests of vehicle_detection.boxes: the detection-box CSV format and draw_boxes."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vehicle_detection.boxes import (
    BOXES_CSV_HEADER,
    BoxTable,
    draw_boxes,
    read_boxes_csv,
    read_boxes_table,
    write_boxes_csv,
)
from vehicle_detection.errors import InputError, OutputError
from vehicle_detection.evaluate import Annotations, FrameLabels, evaluate_detections

ROWS = [
    (7, [10, 20, 74, 84], 3, 0.5),
    (2, [0, 0, 64, 64], -1, 1.23456),  # 1.23456 -> "1.2346"
    (7, np.array([100, 20, 164, 84]), 4, -0.75),
    (2, (500, 400, 596, 496), -1, -0.00001),  # rounds to -0.0000, written as 0.0000
]


# --------------------------------------------------------------------------------------------
# Writing and reading
# --------------------------------------------------------------------------------------------
def test_written_text(tmp_path):
    path = write_boxes_csv(tmp_path / "boxes.csv", ROWS)
    assert path == tmp_path / "boxes.csv"
    assert path.read_bytes().decode() == (
        "frame,x1,y1,x2,y2,track_id,score\n"
        "7,10,20,74,84,3,0.5000\n"
        "2,0,0,64,64,-1,1.2346\n"
        "7,100,20,164,84,4,-0.7500\n"
        "2,500,400,596,496,-1,0.0000\n"
    )


def test_round_trip(tmp_path):
    path = write_boxes_csv(tmp_path / "out" / "boxes.csv", ROWS)  # creates the folder
    by_frame = read_boxes_csv(path)
    assert list(by_frame) == [2, 7]
    assert by_frame[2].dtype == np.int64
    np.testing.assert_array_equal(by_frame[2], [[0, 0, 64, 64], [500, 400, 596, 496]])
    np.testing.assert_array_equal(by_frame[7], [[10, 20, 74, 84], [100, 20, 164, 84]])

    table = read_boxes_table(path)
    assert len(table) == 4
    np.testing.assert_array_equal(table.frame, [7, 2, 7, 2])  # file order kept
    np.testing.assert_array_equal(table.track_id, [3, -1, 4, -1])
    np.testing.assert_allclose(table.score, [0.5, 1.2346, -0.75, 0.0])
    per_frame = table.split_by_frame()
    np.testing.assert_array_equal(per_frame[7].track_id, [3, 4])

    # A table writes back to the same bytes.
    again = write_boxes_csv(tmp_path / "again.csv", table)
    assert again.read_bytes() == path.read_bytes()


def test_empty_rows_give_header_only(tmp_path):
    path = write_boxes_csv(tmp_path / "empty.csv", [])
    assert path.read_text() == BOXES_CSV_HEADER + "\n"
    assert read_boxes_csv(path) == {}
    assert len(read_boxes_table(path)) == 0


def test_refuses_to_overwrite_unless_asked(tmp_path):
    path = write_boxes_csv(tmp_path / "boxes.csv", ROWS[:1])
    before = path.read_bytes()
    with pytest.raises(OutputError, match="boxes.csv"):
        write_boxes_csv(path, ROWS)
    assert path.read_bytes() == before
    write_boxes_csv(path, ROWS[1:2], overwrite=True)
    assert read_boxes_csv(path).keys() == {2}
    assert [p.name for p in tmp_path.iterdir()] == ["boxes.csv"]  # no .partial left behind


def test_refuses_to_write_over_an_input(tmp_path):
    video = tmp_path / "clip.mp4"
    video.write_bytes(b"not really a video")
    with pytest.raises(OutputError, match="input"):
        write_boxes_csv(video, ROWS, overwrite=True, inputs=[video])
    # Also through another spelling of the same path.
    with pytest.raises(OutputError, match="input"):
        write_boxes_csv(tmp_path / "sub" / ".." / "clip.mp4", ROWS, overwrite=True, inputs=[str(video)])
    assert video.read_bytes() == b"not really a video"


@pytest.mark.parametrize(
    "rows, fragment",
    [
        ([(0, [0, 0, 10], -1, 0.5)], "4 coordinates"),
        ([(0, [0, 0, 10, 10], -1)], "expected (frame, box, track_id, score)"),
        ([(0, [0, 0, 10, 10], -1, 0.5), (-1, [0, 0, 10, 10], -1, 0.5)], "row 1"),
        ([(0, [5, 0, 5, 10], -1, 0.5)], "x2 > x1"),
        ([(0, [0, 0, 10.5, 10], -1, 0.5)], "whole pixel"),
        ([(0, [0, 0, 10, 10], -2, 0.5)], "track_id"),
        ([(0, [0, 0, 10, 10], 1.0, 0.5)], "track_id must be an integer"),
        ([(0, [0, 0, 10, 10], 1, float("nan"))], "finite"),
        ([(0, [0, 0, 10, 10], 1, "0.5")], "score must be a number"),
    ],
)
def test_write_rejects_bad_rows_before_writing(tmp_path, rows, fragment):
    with pytest.raises(ValueError) as info:
        write_boxes_csv(tmp_path / "boxes.csv", rows)
    assert fragment in str(info.value)
    assert list(tmp_path.iterdir()) == []


def _csv(tmp_path: Path, text: str, name: str = "dets.csv") -> Path:
    path = tmp_path / name
    path.write_bytes(text.encode())
    return path


GOOD = "0,10,20,74,84,-1,0.5000\n"


@pytest.mark.parametrize(
    "text, fragment",
    [
        ("", "line 1: empty file"),
        ("frame,x1,y1,x2,y2,track,score\n" + GOOD, "line 1: header"),
        ("frame, x1, y1, x2, y2, track_id, score\n" + GOOD, "line 1: header"),
        ("x1,y1,x2,y2\n", "line 1: header"),
        (BOXES_CSV_HEADER + "\n" + GOOD + "1,10,20,74,84,-1\n", "line 3: expected 7 fields"),
        (BOXES_CSV_HEADER + "\n" + GOOD + "1,10,20,74,84,-1,0.5,9\n", "line 3: expected 7 fields"),
        (BOXES_CSV_HEADER + "\n1,10.5,20,74,84,-1,0.5\n", "line 2: x1 '10.5' is not an integer"),
        (BOXES_CSV_HEADER + "\n1,10,20,74,84,-1,abc\n", "line 2: score 'abc'"),
        (BOXES_CSV_HEADER + "\n1,10,20,74,84,-1,nan\n", "line 2: score 'nan'"),
        (BOXES_CSV_HEADER + "\n1,10,20,74,84,-1,1e999\n", "line 2: score '1e999'"),
        (BOXES_CSV_HEADER + "\n1, 10,20,74,84,-1,0.5\n", "line 2: x1 ' 10'"),
        (BOXES_CSV_HEADER + "\n" + GOOD * 3 + "-1,10,20,74,84,-1,0.5\n", "line 5: frame -1 is negative"),
        (BOXES_CSV_HEADER + "\n2,74,20,74,84,-1,0.5\n", "line 2: x2 (74) <= x1 (74)"),
        (BOXES_CSV_HEADER + "\n2,10,90,74,84,-1,0.5\n", "line 2: y2 (84) <= y1 (90)"),
        (BOXES_CSV_HEADER + "\n2,10,20,74,84,-2,0.5\n", "line 2: track_id -2"),
        (BOXES_CSV_HEADER + "\n2,10,20,74,84,99999999999,0.5\n", "line 2: track_id 99999999999 is out of range"),
        (BOXES_CSV_HEADER + "\n" + GOOD + "\n" + GOOD, "line 3: blank line"),
    ],
)
def test_read_rejects_broken_files(tmp_path, text, fragment):
    path = _csv(tmp_path, text, name="broken_dets.csv")
    with pytest.raises(InputError) as info:
        read_boxes_csv(path)
    message = str(info.value)
    assert message.startswith(f"{path}: ")
    assert fragment in message


def test_read_unreadable_files(tmp_path):
    with pytest.raises(InputError, match="missing.csv.*not found"):
        read_boxes_csv(tmp_path / "missing.csv")
    with pytest.raises(InputError, match="folder"):
        read_boxes_csv(tmp_path)
    binary = tmp_path / "bin.csv"
    binary.write_bytes(b"\x89PNG\r\n\x1a\n\xff\xff")
    with pytest.raises(InputError, match="bin.csv.*UTF-8"):
        read_boxes_csv(binary)


def test_read_accepts_crlf_bom_and_trailing_blank_lines(tmp_path):
    text = "\ufeff" + BOXES_CSV_HEADER + "\r\n" + GOOD.replace("\n", "\r\n") + "\r\n\n"
    by_frame = read_boxes_csv(_csv(tmp_path, text))
    np.testing.assert_array_equal(by_frame[0], [[10, 20, 74, 84]])


def test_csv_feeds_evaluation(tmp_path):
    # Labels written as detections and read back score perfectly; a frame without rows is a miss.
    cars = {0: [[10, 20, 74, 84], [200, 20, 300, 90]], 3: [[5, 5, 50, 50]], 4: [[0, 0, 9, 9]]}
    ann = Annotations(video=None, frames={f: FrameLabels(cars=c) for f, c in cars.items()})
    rows = [(f, box, i, 1.0) for f, boxes in cars.items() if f != 4 for i, box in enumerate(boxes)]
    dets = read_boxes_csv(write_boxes_csv(tmp_path / "dets.csv", rows))
    s = evaluate_detections(dets, ann, [0.5])[0.5]
    assert (s.tp, s.fp, s.fn) == (3, 0, 1)


@settings(deadline=None, max_examples=50)
@given(
    st.lists(
        st.tuples(
            st.integers(0, 10_000),
            st.tuples(st.integers(-50, 2000), st.integers(-50, 2000), st.integers(1, 300), st.integers(1, 300)),
            st.integers(-1, 1000),
            st.floats(-1e6, 1e6, allow_nan=False),
        ),
        max_size=30,
    )
)
def test_round_trip_property(rows):
    rows = [(f, [x, y, x + w, y + h], t, s) for f, (x, y, w, h), t, s in rows]
    with tempfile.TemporaryDirectory() as tmp:
        table = read_boxes_table(write_boxes_csv(Path(tmp) / "b.csv", rows))
    assert len(table) == len(rows)
    for (f, box, t, s), (f2, box2, t2, s2) in zip(rows, table.rows()):
        assert (f, box, t) == (f2, box2.tolist(), t2)
        assert abs(s - s2) <= 0.00005 * (1 + 1e-9) + abs(s) * 1e-15  # 4 decimals


def test_box_table_columns_are_read_only():
    table = BoxTable.from_rows(ROWS)
    assert table.boxes.dtype == np.int64 and table.score.dtype == np.float64
    with pytest.raises(ValueError):
        table.boxes[0, 0] = 1
    with pytest.raises(ValueError, match="differ in length"):
        BoxTable(frame=[0, 1], boxes=[[0, 0, 1, 1]], track_id=[0], score=[0.0])


# --------------------------------------------------------------------------------------------
# draw_boxes
# --------------------------------------------------------------------------------------------
def _image(h=60, w=80, value=50):
    return np.full((h, w, 3), value, dtype=np.uint8)


def test_draw_leaves_input_unchanged():
    image = _image()
    image.setflags(write=False)  # any write to the input would raise
    out = draw_boxes(image, [[10, 10, 30, 30]], labels=["7"])
    assert np.all(image == 50)
    assert out is not image and not np.shares_memory(out, image)
    assert out.dtype == np.uint8 and out.shape == image.shape and out.flags.c_contiguous
    assert not np.array_equal(out, image)


@pytest.mark.parametrize("thickness", [1, 2, 3, 5])
def test_draw_edges_inside_the_box(thickness):
    # Box [10, 12, 40, 45): columns 10..39, rows 12..44.
    out = draw_boxes(_image(value=0), [[10, 12, 40, 45]], color=(0, 255, 0), thickness=thickness)
    drawn = out[..., 1] == 255
    assert np.all(out[..., 0] == 0) and np.all(out[..., 2] == 0)  # only the green channel
    ys, xs = np.nonzero(drawn)
    assert (xs.min(), xs.max(), ys.min(), ys.max()) == (10, 39, 12, 44)
    # A row through the middle crosses the left and right edges, each `thickness` pixels wide.
    np.testing.assert_array_equal(np.flatnonzero(drawn[28]),
                                  list(range(10, 10 + thickness)) + list(range(40 - thickness, 40)))
    np.testing.assert_array_equal(np.flatnonzero(drawn[:, 25]),
                                  list(range(12, 12 + thickness)) + list(range(45 - thickness, 45)))


def test_draw_labels_add_pixels_above_box():
    plain = draw_boxes(_image(value=0), [[10, 30, 40, 50]], thickness=1)
    labelled = draw_boxes(_image(value=0), [[10, 30, 40, 50]], thickness=1, labels=[12])
    assert np.array_equal(plain[30:], labelled[30:])  # box unchanged
    assert labelled[:30].any() and not plain[:30].any()  # tag above the box


def test_draw_clips_boxes_outside_image_and_accepts_views():
    image = np.zeros((40, 60, 3), dtype=np.uint8)
    view = image[:, ::2]  # not contiguous
    out = draw_boxes(view, [[-100, -100, 1000, 1000], [5.4, 5.6, 20.2, 20.0]], thickness=1)
    assert out.shape == (40, 30, 3)
    assert not out[0].any()  # the huge box's edges are all outside
    # Float box rounds to [5, 6, 20, 20): top edge row 6, columns 5..19.
    np.testing.assert_array_equal(np.flatnonzero(out[6, :, 1]), np.arange(5, 20))


def test_draw_no_boxes_is_a_copy():
    image = _image()
    out = draw_boxes(image, np.zeros((0, 4)), labels=[])
    assert np.array_equal(out, image) and out is not image


@pytest.mark.parametrize(
    "image, kwargs",
    [
        (np.zeros((10, 10, 3), dtype=np.float32), {}),
        (np.zeros((10, 10), dtype=np.uint8), {}),
        (np.zeros((10, 10, 4), dtype=np.uint8), {}),
        (np.zeros((10, 10, 3), dtype=np.uint8), {"labels": ["a", "b"]}),
        (np.zeros((10, 10, 3), dtype=np.uint8), {"thickness": 0}),
        (np.zeros((10, 10, 3), dtype=np.uint8), {"color": (0, 300, 0)}),
        (np.zeros((10, 10, 3), dtype=np.uint8), {"color": (0, 255)}),
    ],
)
def test_draw_rejects_bad_arguments(image, kwargs):
    with pytest.raises(ValueError):
        draw_boxes(image, [[1, 1, 5, 5]], **kwargs)
