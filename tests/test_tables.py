"""Tests of vehicle_detection.io.tables: the boxes CSV format."""

from __future__ import annotations

import tempfile
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vehicle_detection.detections import Detections
from vehicle_detection.errors import InputError, OutputError
from vehicle_detection.metrics.detection import Annotations, FrameLabels, evaluate_detections
from vehicle_detection.io.tables import BOXES_CSV_HEADER, read_boxes_csv, write_boxes_csv

DETS = Detections(
    [[10, 20, 74, 84], [0, 0, 64, 64], [100, 20, 164, 84], [500, 400, 596, 496]],
    score=[0.5, 1.23456, -0.75, -0.00001],  # 1.23456 -> "1.2346"; -0.00001 -> "-0.0000", written as 0.0000
    track_id=[3, -1, 4, -1],
    frame=[7, 2, 7, 2],
)


# --------------------------------------------------------------------------------------------
# Writing and reading
# --------------------------------------------------------------------------------------------
def test_written_text(tmp_path):
    path = write_boxes_csv(tmp_path / "boxes.csv", DETS)
    assert path == tmp_path / "boxes.csv"
    assert path.read_bytes().decode() == (
        "frame,x1,y1,x2,y2,track_id,score\n"
        "7,10,20,74,84,3,0.5000\n"
        "2,0,0,64,64,-1,1.2346\n"
        "7,100,20,164,84,4,-0.7500\n"
        "2,500,400,596,496,-1,0.0000\n"
    )


def test_round_trip(tmp_path):
    path = write_boxes_csv(tmp_path / "out" / "boxes.csv", DETS)  # creates the folder
    table = read_boxes_csv(path)
    by_frame = table.by_frame()
    assert list(by_frame) == [2, 7]
    assert table.xyxy.dtype == np.int64
    np.testing.assert_array_equal(by_frame[2].xyxy, [[0, 0, 64, 64], [500, 400, 596, 496]])
    np.testing.assert_array_equal(by_frame[7].xyxy, [[10, 20, 74, 84], [100, 20, 164, 84]])
    assert len(table) == 4
    np.testing.assert_array_equal(table.frame, [7, 2, 7, 2])  # file order kept
    np.testing.assert_array_equal(table.track_id, [3, -1, 4, -1])
    np.testing.assert_allclose(table.score, [0.5, 1.2346, -0.75, 0.0])
    np.testing.assert_array_equal(by_frame[7].track_id, [3, 4])

    # A table writes back to the same bytes.
    again = write_boxes_csv(tmp_path / "again.csv", table)
    assert again.read_bytes() == path.read_bytes()


def test_empty_rows_give_header_only(tmp_path):
    path = write_boxes_csv(tmp_path / "empty.csv", Detections.empty())
    assert path.read_text() == BOXES_CSV_HEADER + "\n"
    assert read_boxes_csv(path) == Detections.empty()


def test_untracked_rows_read_back_untracked(tmp_path):
    untracked = DETS.replace(track_id=None)
    path = write_boxes_csv(tmp_path / "boxes.csv", untracked)
    assert all(line.split(",")[5] == "-1" for line in path.read_text().splitlines()[1:])
    assert read_boxes_csv(path).track_id is None


def test_refuses_to_overwrite_unless_asked(tmp_path):
    path = write_boxes_csv(tmp_path / "boxes.csv", DETS[:1])
    before = path.read_bytes()
    with pytest.raises(OutputError, match="boxes.csv"):
        write_boxes_csv(path, DETS)
    assert path.read_bytes() == before
    write_boxes_csv(path, DETS[1:2], overwrite=True)
    assert read_boxes_csv(path).frames().tolist() == [2]
    assert [p.name for p in tmp_path.iterdir()] == ["boxes.csv"]  # no .partial left behind


def test_refuses_to_write_over_an_input(tmp_path):
    video = tmp_path / "clip.mp4"
    video.write_bytes(b"not really a video")
    with pytest.raises(OutputError, match="input"):
        write_boxes_csv(video, DETS, overwrite=True, inputs=[video])
    # Also through another spelling of the same path.
    with pytest.raises(OutputError, match="input"):
        write_boxes_csv(tmp_path / "sub" / ".." / "clip.mp4", DETS, overwrite=True, inputs=[str(video)])
    assert video.read_bytes() == b"not really a video"


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
    table = read_boxes_csv(_csv(tmp_path, text))
    np.testing.assert_array_equal(table.at_frame(0).xyxy, [[10, 20, 74, 84]])


def test_csv_feeds_evaluation(tmp_path):
    # Labels written as detections and read back score perfectly; a frame without rows is a miss.
    cars = {0: [[10, 20, 74, 84], [200, 20, 300, 90]], 3: [[5, 5, 50, 50]], 4: [[0, 0, 9, 9]]}
    ann = Annotations(video=None, frames={f: FrameLabels(cars=c) for f, c in cars.items()})
    rows = [(f, *box, i, 1.0) for f, boxes in cars.items() if f != 4 for i, box in enumerate(boxes)]
    dets = read_boxes_csv(write_boxes_csv(tmp_path / "dets.csv", Detections.from_rows(rows)))
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
    rows = [(f, x, y, x + w, y + h, t, s) for f, (x, y, w, h), t, s in rows]
    with tempfile.TemporaryDirectory() as tmp:
        table = read_boxes_csv(write_boxes_csv(Path(tmp) / "b.csv", Detections.from_rows(rows)))
    assert len(table) == len(rows)
    for row, row2 in zip(rows, table.rows()):
        assert row[:6] == row2[:6]
        s, s2 = row[6], row2[6]
        assert abs(s - s2) <= 0.00005 * (1 + 1e-9) + abs(s) * 1e-15  # 4 decimals


def test_distances_and_file_columns_together(tmp_path):
    dets = DETS.replace(
        data={
            "distance_m": np.array([12.345, np.nan, 30.0, 7.5]),
            "relative_speed_mps": np.array([np.nan, -1.5, 0.25, 2.0]),
        }
    )
    names = ["a.jpg", "b,c.jpg", 'd"e.png', "f.png"]
    path = write_boxes_csv(tmp_path / "boxes.csv", dets, files=names)
    lines = path.read_text().splitlines()
    assert lines[0] == BOXES_CSV_HEADER + ",distance_m,relative_speed_mps,file"
    assert lines[1] == "7,10,20,74,84,3,0.5000,12.35,,a.jpg"
    assert lines[2] == '2,0,0,64,64,-1,1.2346,,-1.50,"b,c.jpg"'
    assert lines[3] == '7,100,20,164,84,4,-0.7500,30.00,0.25,"d""e.png"'
    back = read_boxes_csv(path)
    assert list(back.data["file"]) == names
    np.testing.assert_allclose(back.data["distance_m"], [12.35, np.nan, 30.0, 7.5])
    np.testing.assert_allclose(back.data["relative_speed_mps"], [np.nan, -1.5, 0.25, 2.0])
    assert write_boxes_csv(tmp_path / "again.csv", back, files=back.data["file"]).read_bytes() == path.read_bytes()


@pytest.mark.parametrize(
    "header, row, fragment",
    [
        (",distance_m,relative_speed_mps,file", "0,1,2,30,40,0,1.0,5.0,a.png", "expected 10 fields"),
        (",file,distance_m,relative_speed_mps", "0,1,2,30,40,0,1.0,a.png,5.0,1.0", "header is"),
        (",distance_m,relative_speed_mps,file", "0,1,2,30,40,0,1.0,near,,a.png", "distance_m 'near' is not a number"),
    ],
)
def test_read_rejects_broken_extended_files(tmp_path, header, row, fragment):
    p = tmp_path / "boxes.csv"
    p.write_text(BOXES_CSV_HEADER + header + "\n" + row + "\n")
    with pytest.raises(InputError, match=fragment):
        read_boxes_csv(p)


def test_file_names_with_line_breaks_round_trip_and_lines_are_counted(tmp_path):
    dets = DETS[:2]
    names = ["two\nlines.png", 'a "b", c.png']
    path = write_boxes_csv(tmp_path / "boxes.csv", dets, files=names)
    assert list(read_boxes_csv(path).data["file"]) == names
    # A bad record after the two-line one is reported at its own line of the file (line 4).
    broken = tmp_path / "broken.csv"
    broken.write_text(path.read_text().replace("2,0,0,64,64", "2,0,0,-64,64"))
    with pytest.raises(InputError, match=r"line 4: x2 \(-64\) <= x1"):
        read_boxes_csv(broken)
