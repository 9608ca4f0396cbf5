"""The command line's lanes without a camera file, its summary line, ``--json``, ``--report`` and ``report``.

``detect VIDEO --lanes`` without ``--camera`` estimates the road plane from the video itself
(:meth:`vehicle_detection.road.survey.Road.for_footage`), prints it, and saves it with
``--save-camera``; footage without lane lines runs without lanes and says so. Every input ends
with one summary line (:func:`vehicle_detection.viz.report.summarize`); ``--json`` makes standard
output one JSON object; ``--report`` and ``vehicle-detection report`` write the HTML page.
"""

from __future__ import annotations

import contextlib
import csv
import io
import json
import re
import shutil
from pathlib import Path

import numpy as np
import pytest

import vehicle_detection as vd
from vehicle_detection.cli import main
from vehicle_detection.io.tables import read_boxes_csv, read_lanes_csv
from vehicle_detection.io.video import probe_video, read_frames

from media import encode

REPO = Path(__file__).resolve().parents[1]
TEST_VIDEO = REPO / "test_video.mp4"
TEST_IMAGES = REPO / "test_images"

pytestmark = [
    pytest.mark.skipif(not (TEST_VIDEO.is_file() and (TEST_IMAGES / "test3.jpg").is_file()), reason="test_video.mp4 or test_images/ not in the checkout"),
    pytest.mark.xdist_group(name="test_cli_lanes"),  # one worker: the module's fixtures below are shared by several tests
]
try:
    import matplotlib  # noqa: F401

    HAS_MATPLOTLIB = True
except ImportError:
    HAS_MATPLOTLIB = False
needs_matplotlib = pytest.mark.skipif(not HAS_MATPLOTLIB, reason='matplotlib not installed (pip install "vehicle-detection[report]")')

SUMMARY = re.compile(r"^(?P<input>.+): (?P<frames>\d+) (frame|frames|image|images), (?:(?P<tracks>\d+) vehicles?, )?"
                     r"(?P<boxes>\d+) box(?:es)?, [\d.]+ (?:fps|images/s) \([\d.]+ s\); wrote (?P<wrote>.+)$")


def run(capsys, *argv) -> tuple[int, list[str], list[str]]:
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out.splitlines(), captured.err.splitlines()


def lane_rows(path: Path) -> list[list[str]]:
    with open(path, newline="") as f:
        return list(csv.reader(f))[1:]


N = 8  # frames of the clips: with 7, the estimate from the footage sees no dash move


@pytest.fixture(scope="module")
def plain_video(tmp_path_factory) -> Path:
    """A video of grey frames: no lane lines, no cars."""
    path = tmp_path_factory.mktemp("plain") / "plain.mp4"
    return encode(path, [np.full((360, 640, 3), 110, np.uint8) for _ in range(N)])


@pytest.fixture(scope="module")
def clips(tmp_path_factory) -> Path:
    """Two copies of the test video's first N frames (both lane lines and two cars in every one)."""
    d = tmp_path_factory.mktemp("lane_clips")
    with vd.VideoWriter(d / "v.mp4", probe_video(TEST_VIDEO).fps, (1280, 720), crf=18) as writer:
        for i, frame in enumerate(read_frames(TEST_VIDEO)):
            if i == N:
                break
            writer.write(frame)
    shutil.copyfile(d / "v.mp4", d / "w.mp4")
    return d


@pytest.fixture(scope="module")
def lanes_batch(clips, tmp_path_factory) -> tuple[int, list[str], list[str], Path]:
    """``detect v.mp4 w.mp4 --out-dir o --format csv,lanes --no-video``: exit code, stdout and stderr lines, o."""
    out_dir = tmp_path_factory.mktemp("lanes_batch") / "o"
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in ("detect", clips / "v.mp4", clips / "w.mp4", "--out-dir", out_dir, "--format", "csv,lanes",
                                      "--no-video", "--no-progress")])
    return code, out.getvalue().splitlines(), err.getvalue().splitlines(), out_dir


@pytest.fixture(scope="module")
def footage_road(clips):
    """``Road(lanes=True).for_footage(v.mp4)``: the road plane estimated from the clip, and the estimate."""
    from vehicle_detection.road.survey import Road

    return Road(lanes=True).for_footage(clips / "v.mp4")


# --- lanes without a camera file ---------------------------------------------------------------------


def test_lanes_from_the_footage_and_the_saved_camera_give_the_same_lanes(clips, tmp_path, capsys):
    lanes, boxes, cam = tmp_path / "L.csv", tmp_path / "b.csv", tmp_path / "C.json"
    code, out, err = run(capsys, "detect", clips / "v.mp4", "--lanes", "--lanes-csv", lanes, "--boxes", boxes, "--save-camera", cam,
                         "--no-video", "--no-progress")
    assert code == 0, err
    assert SUMMARY.match(out[0]), out[0]
    assert out[1].startswith("bird's-eye view from the footage: both lane lines in ")
    assert any("vanishing point" in line and "90 % interval" in line for line in out)
    rows = lane_rows(lanes)
    assert [int(r[0]) for r in rows] == list(range(N))  # one row per frame
    radius = np.array([float(r[1]) for r in rows if r[1]])
    offset = np.array([float(r[2]) for r in rows if r[2]])
    assert len(radius) >= N - 1 and 200 < np.median(radius) < 5000  # the test video's bend: about 730 m calibrated
    assert np.all(np.abs(offset) < 1.0)  # the car stays in its lane
    table = read_boxes_csv(boxes)
    dist = np.asarray(table.data["distance_m"])
    assert len(table) and np.isfinite(dist).mean() > 0.9 and 3 < np.nanmedian(dist) < 40
    # the camera file: a second run with it reuses the plane, and gives the same lanes and distances
    saved = json.loads(cam.read_text())
    assert saved["birds_eye"] is not None and saved["road_estimate"]["source"] == "footage"
    assert saved["road_estimate"]["frames_sampled"] == N
    lanes2, boxes2 = tmp_path / "L2.csv", tmp_path / "b2.csv"
    code, out, err = run(capsys, "detect", clips / "v.mp4", "--camera", cam, "--lanes-csv", lanes2, "--boxes", boxes2, "--no-video",
                         "--no-progress")
    assert code == 0, err
    assert not any("from the footage" in line for line in out)  # the camera file wins: nothing estimated
    assert lanes2.read_bytes() == lanes.read_bytes()
    assert boxes2.read_bytes() == boxes.read_bytes()


def test_footage_without_lane_lines_runs_without_lanes_and_says_so(plain_video, tmp_path, capsys):
    lanes, boxes, cam = tmp_path / "L.csv", tmp_path / "b.csv", tmp_path / "C.json"
    code, out, err = run(capsys, "detect", plain_video, "--lanes", "--lanes-csv", lanes, "--boxes", boxes, "--save-camera", cam,
                         "--out", tmp_path / "o.mp4", "--no-progress")
    assert code == 0, err
    no_lanes = [line for line in out if line.startswith("no lanes: ")]
    assert len(no_lanes) == 1 and "no lane lines seen" in no_lanes[0]
    assert f"{cam}: not written (no road plane estimated from the footage)" in out
    assert not cam.exists()
    assert lane_rows(lanes) == [[str(i), "", ""] for i in range(N)]  # no lane in any frame, none guessed
    assert list(read_boxes_csv(boxes).data) == []  # no distance columns without a road plane
    # nothing is drawn: the frames are the plain grey they were (no lane, no "lane: not found")
    frame = next(read_frames(tmp_path / "o.mp4")).astype(int)
    assert np.abs(frame - 110).max() < 12
    assert SUMMARY.match(out[0]) and str(cam) not in out[0]


def test_a_camera_file_with_a_plane_wins_and_save_camera_is_refused_with_it(tmp_path, capsys):
    cam = tmp_path / "C.json"
    assert main(["detect", str(TEST_IMAGES / "test3.jpg"), "--save-camera", str(cam), "--no-video", "--boxes",
                 str(tmp_path / "b.csv")]) == 0
    capsys.readouterr()
    code, out, err = run(capsys, "detect", TEST_IMAGES / "test3.jpg", "--camera", cam, "--save-camera", tmp_path / "D.json",
                         "--no-video")
    assert code == 2 and len(err) == 1 and "has one (it wins): there is nothing to estimate" in err[0]
    assert not (tmp_path / "D.json").exists()


def test_a_still_image_estimates_from_itself_or_says_why_not(tmp_path, capsys):
    code, out, err = run(capsys, "detect", TEST_IMAGES / "test3.jpg", "--lanes", "--boxes", tmp_path / "b3.csv",
                         "--out", tmp_path / "o3.jpg")
    assert code == 0, err
    assert out[1].startswith("bird's-eye view from the footage: both lane lines in 1 of 1 sampled frames")
    table = read_boxes_csv(tmp_path / "b3.csv")
    assert len(table) and np.isfinite(table.data["distance_m"]).all()
    code, out, err = run(capsys, "detect", TEST_IMAGES / "test1.jpg", "--lanes", "--boxes", tmp_path / "b1.csv", "--no-video")
    assert code == 0, err
    assert len([line for line in out if line.startswith("no lanes: no lane lines seen")]) == 1
    assert "distance_m" not in read_boxes_csv(tmp_path / "b1.csv").data


def test_a_folder_of_images_of_two_sizes_is_refused_for_an_estimate(tmp_path, capsys):
    folder = tmp_path / "shots"
    folder.mkdir()
    shutil.copy(TEST_IMAGES / "test3.jpg", folder / "a.jpg")
    vd.write_image(folder / "b.jpg", vd.read_image(TEST_IMAGES / "test1.jpg")[:360, :640])
    code, out, err = run(capsys, "detect", folder, "--lanes", "--no-video")
    assert code == 3 and len(err) == 1 and f"{folder}: its images are not of one size" in err[0]


def test_a_batch_estimates_each_input_and_refuses_save_camera(clips, lanes_batch, tmp_path, capsys):
    code, out, err, out_dir = lanes_batch
    assert code == 0, err
    assert sorted(p.name for p in out_dir.iterdir()) == ["v_boxes.csv", "v_lanes.csv", "w_boxes.csv", "w_lanes.csv"]
    assert sum(line.startswith("bird's-eye view from the footage") for line in out) == 2
    assert (out_dir / "v_lanes.csv").read_bytes() == (out_dir / "w_lanes.csv").read_bytes()
    assert len(read_lanes_csv(out_dir / "v_lanes.csv")["frame"]) == N
    assert "distance_m" in read_boxes_csv(out_dir / "v_boxes.csv").data
    code, out, err = run(capsys, "detect", clips / "v.mp4", clips / "w.mp4", "--out-dir", tmp_path / "p", "--lanes",
                         "--save-camera", tmp_path / "C.json")
    assert code == 2 and len(err) == 1 and "--save-camera name the outputs of one input" in err[0]
    assert not (tmp_path / "p").exists()


# --- the summary line and --json ---------------------------------------------------------------------


def test_one_summary_line_counts_every_frame(clips, tmp_path, capsys):
    boxes = tmp_path / "b.csv"
    code, out, err = run(capsys, "detect", clips / "v.mp4", "--frames", "2-6", "--boxes", boxes, "--no-video", "--no-progress")
    assert code == 0, err
    m = SUMMARY.match(out[0])
    assert m and m["input"] == str(clips / "v.mp4") and m["frames"] == "5" and m["wrote"] == str(boxes)
    table = read_boxes_csv(boxes)
    assert m["boxes"] == str(len(table)) and m["tracks"] == str(len(set(table.track_id.tolist()) - {-1}))
    assert len([line for line in out if SUMMARY.match(line)]) == 1


def test_json_is_one_object_on_stdout_with_the_human_lines_on_stderr(clips, tmp_path, capsys):
    code, out, err = run(capsys, "detect", clips / "v.mp4", "--lanes", "--boxes", tmp_path / "b.csv", "--no-video",
                         "--no-progress", "--json")
    assert code == 0
    doc = json.loads("\n".join(out))
    (one,) = doc["inputs"]
    table = read_boxes_csv(tmp_path / "b.csv")
    assert one["input"] == str(clips / "v.mp4") and one["frames"] == N and one["boxes"] == len(table)
    assert one["outputs"] == [str(tmp_path / "b.csv")]
    assert one["road_estimate"]["source"] == "footage" and one["road_estimate"]["reason"] is None
    assert SUMMARY.match(err[0]) and err[1:] == one["notes"]
    # a batch: one object, each input's summary or error, and the totals
    code, out, err = run(capsys, "detect", clips / "v.mp4", clips / "missing.mp4", "--out-dir", tmp_path / "o", "--no-video",
                         "--no-progress", "--json")
    assert code == 7
    doc = json.loads("\n".join(out))
    assert [d["input"] for d in doc["inputs"]] == [str(clips / "v.mp4"), str(clips / "missing.mp4")]
    assert doc["inputs"][0]["boxes"] == len(table) and doc["inputs"][1]["exit_code"] == 3
    assert (doc["done"], doc["failed"], doc["frames"]) == (1, 1, N)
    assert any("missing.mp4: no such file" in line for line in err)


# --- the HTML report -----------------------------------------------------------------------------------


@needs_matplotlib
def test_detect_report_with_the_default_outputs(clips, tmp_path, capsys):
    """In a batch: tests/test_inputs.py::test_a_batch_writes_each_input_s_report."""
    # --boxes names the boxes CSV alone: the report is a default output, in the current folder.
    named = tmp_path / "named"
    code, out, err = run(capsys, "detect", clips / "v.mp4", "--boxes", named / "b.csv", "--lanes", "--no-video", "--report",
                         "--no-progress")
    assert code == 0, err
    page = (tmp_path / "v_report.html").read_text()
    assert "<h2>Track timeline</h2>" in page and "<h2>Lanes</h2>" in page and "<h2>Distances</h2>" in page
    assert page.count("data:image/jpeg;base64,") >= 3  # crops cut from the video
    assert "<script" not in page and out[0].endswith(f"; wrote {named / 'b.csv'}, v_report.html")


@needs_matplotlib
def test_report_command_from_a_boxes_csv(clips, lanes_batch, tmp_path, capsys):
    for name in ("v_boxes.csv", "v_lanes.csv"):  # the tables of `detect v.mp4 --lanes --format csv,lanes`
        shutil.copy(lanes_batch[3] / name, tmp_path / name)
    code, out, err = run(capsys, "report", tmp_path / "v_boxes.csv", "--video", clips / "v.mp4", "--lanes", tmp_path / "v_lanes.csv")
    assert code == 0, err
    page = tmp_path / "v_report.html"
    assert out == [f"wrote {page}"]
    text = page.read_text()
    assert "<h2>Lanes</h2>" in text and text.count("data:image/jpeg;base64,") >= 3
    code, out, err = run(capsys, "report", tmp_path / "v_boxes.csv", "--out", tmp_path / "r.html", "--json")
    assert code == 0 and json.loads(out[0])["report"] == str(tmp_path / "r.html")
    assert "Contact sheet" in (tmp_path / "r.html").read_text()


@pytest.mark.parametrize("what", ["missing", "lanes-csv", "folder", "exists"])
def test_report_command_refusals(tmp_path, capsys, what):
    lanes = tmp_path / "L.csv"
    lanes.write_text("frame,curvature_m,offset_m\n0,500.0,0.1\n")
    boxes = tmp_path / "b.csv"
    boxes.write_text("frame,x1,y1,x2,y2,track_id,score\n0,1,2,30,40,0,1.5\n")
    (tmp_path / "b_report.html").write_text("earlier")
    argv, code_wanted, message = {
        "missing": (["report", tmp_path / "nope.csv"], 3, f"{tmp_path / 'nope.csv'}: boxes file not found"),
        "lanes-csv": (["report", lanes], 3, f"{lanes}: line 1: header is 'frame,curvature_m,offset_m'; expected 'frame,x1,"),
        "folder": (["report", tmp_path], 3, f"{tmp_path}: is a folder"),
        "exists": (["report", boxes], 5, f"{tmp_path / 'b_report.html'}: output exists"),
    }[what]
    code, out, err = run(capsys, *argv)
    assert code == code_wanted and out == []
    assert len(err) == 1 and err[0].startswith(f"vehicle-detection: error: {message}")
    assert (tmp_path / "b_report.html").read_text() == "earlier"
    assert not (tmp_path / "L_report.html").exists()


# --- the same through the Python API ---------------------------------------------------------------------


def test_run_input_estimates_the_road_plane_and_summarizes(clips, plain_video, footage_road, tmp_path):
    from vehicle_detection.pipeline.inputs import InputOptions, run_input
    from vehicle_detection.road.autocamera import road_transform
    from vehicle_detection.road.survey import Road

    options = InputOptions(road=Road(lanes=True), video=False, formats=("csv", "lanes"))
    result = run_input(clips / "v.mp4", options, out_dir=tmp_path)
    plane, estimate = road_transform(clips / "v.mp4")
    assert result.estimate == estimate and estimate.ok
    road, again = footage_road
    assert road.plane.to_dict() == plane.to_dict() and road.lanes and again == estimate
    assert result.summary.to_dict()["frames"] == N and result.summary.boxes == result.n_boxes
    assert result.summary.line() == f"{clips / 'v.mp4'}: " + result.summary.line().split(": ", 1)[1]
    lanes = read_lanes_csv(tmp_path / "v_lanes.csv")
    assert np.isfinite(lanes["curvature_m"]).sum() >= N - 1
    # no lane lines: no plane, no lanes, and the reason
    road, why = Road(lanes=True).for_footage(plain_video)
    assert road.plane is None and not road.lanes and why.reason.startswith("no lane lines seen")
    # nothing to estimate: lanes not asked for, or the plane known
    assert Road().for_footage(plain_video) == (Road(), None)
    known = Road(birds_eye=plane, lanes=True)
    same, nothing = known.for_footage(plain_video)
    assert same is known and nothing is None


def test_the_dash_period_sets_the_scale_along_the_road_only(clips, footage_road, tmp_path, capsys):
    from vehicle_detection.road.survey import Road

    us, _ = footage_road
    ca, estimate = Road(lanes=True, dash_period_m=14.6).for_footage(clips / "v.mp4")
    assert estimate.dash_period_m == 14.6 and ca.dash_period_m == 14.6
    assert ca.plane.ym_per_px == pytest.approx(us.plane.ym_per_px * 14.6 / 12.0)
    assert ca.plane.xm_per_px == us.plane.xm_per_px  # across the road: the lane's width, 3.7 m, either way
    np.testing.assert_allclose(ca.plane.src, us.plane.src)
    # the command line: --dash-period, printed in the estimate; refused where nothing is estimated
    # (one frame's detection: the estimate samples the whole clip whatever --frames says)
    code, out, err = run(capsys, "detect", clips / "v.mp4", "--lanes", "--dash-period", "14.6", "--frames", "0-0", "--no-video",
                         "--boxes", tmp_path / "b.csv")
    assert code == 0, err
    assert any("(dash period 14.6 m;" in line for line in out)
    code, out, err = run(capsys, "detect", clips / "v.mp4", "--dash-period", "14.6", "--no-video", "--boxes", tmp_path / "c.csv")
    assert code == 2 and len(err) == 1 and "--dash-period sets the scale of a road plane estimated from the footage" in err[0]
    with pytest.raises(SystemExit) as info:
        main(["detect", str(clips / "v.mp4"), "--lanes", "--dash-period", "0.5", "--no-video"])
    assert info.value.code == 2 and "expected metres from one dash to the next, 2 to 50, got '0.5'" in capsys.readouterr().err


def test_the_estimate_refuses_a_video_of_another_size_than_the_camera(plain_video, tmp_path, capsys):
    camera = tmp_path / "cam.json"
    matrix = [[1000.0, 0.0, 640.0], [0.0, 1000.0, 360.0], [0.0, 0.0, 1.0]]
    vd.Camera(image_size=(1280, 720), matrix=matrix, distortion=[0.0] * 5).save(camera)
    code, out, err = run(capsys, "detect", plain_video, "--camera", camera, "--lanes", "--no-video", "--boxes", tmp_path / "b.csv")
    assert code == 3 and out == []
    assert err == [f"vehicle-detection: error: {plain_video}: the video is 640x360, but the camera file was calibrated for "
                   "1280x720 images; calibrate this camera at this size"]
    assert not (tmp_path / "b.csv").exists()


@pytest.mark.parametrize("existing", ["v_report.html", "C.json"])
def test_an_existing_report_or_camera_file_is_refused_before_any_work(clips, tmp_path, capsys, existing):
    (tmp_path / existing).write_text("earlier")
    before = sorted(p.name for p in tmp_path.iterdir())
    code, out, err = run(capsys, "detect", clips / "v.mp4", "--boxes", tmp_path / "b.csv", "--no-video", "--report", "--save-camera",
                         tmp_path / "C.json", "--no-progress")
    assert code == 5 and out == []
    shown = existing if existing == "v_report.html" else tmp_path / existing  # the report: in the current folder, tmp_path
    assert err == [f"vehicle-detection: error: {shown}: output exists; pass --overwrite to replace it"]
    assert sorted(p.name for p in tmp_path.iterdir()) == before and (tmp_path / existing).read_text() == "earlier"


def test_format_lanes_in_a_batch_without_a_camera_estimates_or_says_no_lane(tmp_path, capsys):
    """``--format lanes`` asks for lanes as ``--lanes`` does: without a camera file each input's road
    plane comes from its own frames, and where none is seen its lanes table says "no lane"."""
    shutil.copy(TEST_IMAGES / "test1.jpg", tmp_path / "a.jpg")  # no lane lines the estimate can use
    (tmp_path / "d").mkdir()
    shutil.copy(TEST_IMAGES / "test2.jpg", tmp_path / "d" / "b.jpg")
    assert main(["detect", str(tmp_path / "a.jpg"), str(tmp_path / "d"), "--format", "lanes", "--no-progress"]) == 0
    captured = capsys.readouterr()
    assert (captured.out + captured.err).count("no lanes: no lane lines seen") == 2
    for name in ("a_lanes.csv", "d_lanes.csv"):
        rows = list(csv.reader(open(tmp_path / name)))
        assert rows[0] == ["frame", "curvature_m", "offset_m"] and len(rows) == 2 and rows[1][1:] == ["", ""]
