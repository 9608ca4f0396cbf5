"""The HTML report of a run and the one-line summary of an input."""

from __future__ import annotations

import base64
import functools
import importlib.util
import io
import json
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import media
import numpy as np
import pytest
from PIL import Image

from vehicle_detection.detections import Detections
from vehicle_detection.errors import InputError, MissingDependencyError, OutputError
from vehicle_detection.viz.report import CROP_HEIGHT, RunSummary, render_html_report, summarize, track_spans, write_html_report
from vehicle_detection.io.tables import read_lanes_csv, write_boxes_csv, write_lanes_csv

needs_matplotlib = pytest.mark.skipif(
    importlib.util.find_spec("matplotlib") is None, reason='matplotlib not installed (pip install -e ".[test]")'
)

N_FRAMES = 30


def grey_level(i: int) -> int:
    return 20 + 7 * i


@pytest.fixture(scope="module")
def grey_video(tmp_path_factory) -> Path:
    """Frame ``i`` is flat grey of level ``grey_level(i)``: a crop's mean tells its frame."""
    frames = [np.full((96, 160, 3), grey_level(i), np.uint8) for i in range(N_FRAMES)]
    return media.encode(tmp_path_factory.mktemp("grey") / "grey.mp4", frames)


def two_tracks() -> Detections:
    """Track 4 in frames 2..9 (a gap at 5), track 1 in frames 12..20; no box after frame 20."""
    frames_a = [2, 3, 4, 6, 7, 8, 9]
    frames_b = list(range(12, 21))
    xyxy = [[10, 10, 50, 40]] * len(frames_a) + [[60, 20, 120, 60]] * len(frames_b)
    return Detections(xyxy, score=np.linspace(5, 50, len(xyxy)), track_id=[4] * len(frames_a) + [1] * len(frames_b), frame=frames_a + frames_b)


def data_uris(page: str) -> list[tuple[str, bytes]]:
    return [(m.group(1), base64.b64decode(m.group(2))) for m in re.finditer(r'src="data:image/(png|jpeg);base64,([A-Za-z0-9+/=]+)"', page)]


# --- the summary line ----------------------------------------------------------------------------


def test_summary_counts_every_frame_and_says_one_vehicle():
    one = Detections([[0, 0, 64, 64], [2, 0, 66, 64]], track_id=[7, 7], frame=[3, 4])
    s = summarize("clip.mp4", one, frames=25, seconds=5.0, outputs=["o/clip.mp4", "o/clip.csv"])
    assert s.line() == "clip.mp4: 25 frames, 1 vehicle, 2 boxes, 5.0 fps (5.0 s); wrote o/clip.mp4, o/clip.csv"
    d = s.to_dict()
    assert json.loads(json.dumps(d)) == d
    assert d == {"input": "clip.mp4", "unit": "frame", "frames": 25, "tracks": 1, "boxes": 2, "seconds": 5.0, "fps": 5.0,
                 "outputs": ["o/clip.mp4", "o/clip.csv"]}
    many = summarize("clip.mp4", two_tracks(), frames=N_FRAMES)
    assert many.tracks == 2 and "2 vehicles, 16 boxes" in many.line() and many.fps is None


def test_summary_of_images_and_of_a_box():
    untracked = Detections([[0, 0, 64, 64]])
    line = summarize("shot.jpg", untracked, frames=1, seconds=2.0, unit="image").line()
    assert line == "shot.jpg: 1 image, 1 box, 0.5 images/s (2.0 s); nothing written"
    assert summarize("shots", Detections.empty(), frames=3, unit="image").to_dict()["tracks"] is None


def test_summary_refuses_boxes_beyond_the_frames():
    with pytest.raises(ValueError, match="frame 20"):
        summarize("clip.mp4", two_tracks(), frames=20)
    # a run from frame `first` (detect --start): its boxes lie in first .. first + frames - 1
    lo, last = int(two_tracks().frame.min()), int(two_tracks().frame.max())
    assert summarize("clip.mp4", two_tracks(), frames=last - lo + 1, first=lo).frames == last - lo + 1
    with pytest.raises(ValueError, match=f"frame {last}, but only frames {lo} to {last - 1}"):
        summarize("clip.mp4", two_tracks(), frames=last - lo, first=lo)
    first = int(two_tracks().frame.min())
    with pytest.raises(ValueError, match=f"frame {first}, but only frames {first + 1} to"):
        summarize("clip.mp4", two_tracks(), frames=100, first=first + 1)
    with pytest.raises(ValueError, match="unit"):
        RunSummary("x", 1, 0, unit="frames")


# --- tracks and the lanes table --------------------------------------------------------------------


def test_track_spans_group_rows_by_track_in_frame_order():
    d = two_tracks()[::-1]  # rows in any order
    spans = track_spans(d)
    assert list(spans) == [4, 1]  # by first frame
    assert d.frame[spans[4]].tolist() == [2, 3, 4, 6, 7, 8, 9]
    assert d.frame[spans[1]].tolist() == list(range(12, 21))
    assert track_spans(Detections([[0, 0, 9, 9]])) == {}


def test_lanes_csv_round_trip_and_errors(tmp_path):
    rows = [(0, 812.4, -0.25), (1, None, None), (2, 15000.0, 0.3)]
    path = write_lanes_csv(tmp_path / "l.csv", rows)
    got = read_lanes_csv(path)
    assert got["frame"].tolist() == [0, 1, 2]
    np.testing.assert_allclose(got["curvature_m"], [812.4, np.nan, 15000.0])
    np.testing.assert_allclose(got["offset_m"], [-0.25, np.nan, 0.3])
    bad = tmp_path / "bad.csv"
    bad.write_text("frame,curvature_m,offset_m\n0,1.0,0.1\n0,2.0,0.2\n")
    with pytest.raises(InputError, match=r"bad\.csv: line 3: frame 0 does not follow"):
        read_lanes_csv(bad)
    bad.write_text("frame,radius,offset\n")
    with pytest.raises(InputError, match="line 1: header"):
        read_lanes_csv(bad)


# --- the page ------------------------------------------------------------------------------------


@needs_matplotlib
def test_report_has_every_section_and_crops_from_the_right_frames(grey_video, tmp_path):
    d = two_tracks()
    boxes = write_boxes_csv(tmp_path / "b.csv", d)
    lanes = write_lanes_csv(tmp_path / "l.csv", [(i, 500.0 + i, 0.01 * i) for i in range(N_FRAMES)])
    out = write_html_report(tmp_path / "r" / "report.html", boxes, video=grey_video, lanes=lanes)
    page = out.read_text(encoding="utf-8")
    for heading in ("Track timeline", "Contact sheet", "Boxes per frame", "Lanes"):
        assert f"<h2>{heading}" in page
    assert "Distances" not in page  # no distance column
    assert "<script" not in page.lower() and "http://" not in page and "https://" not in page
    assert re.findall(r'<img src="(?!data:)', page) == []
    # every frame counted, also those after the last box (one lanes row per frame)
    assert f"{N_FRAMES} (one lanes row per frame)" in page
    assert f"frames without any: {N_FRAMES - 16}" in page
    images = data_uris(page)
    assert [kind for kind, _ in images] == ["png"] + ["jpeg"] * 6 + ["png", "png"]
    for _, raw in images:
        Image.open(io.BytesIO(raw)).load()
    # crops: first, middle and last box of each track, in the timeline's order (track 4 first)
    crops = [np.asarray(Image.open(io.BytesIO(raw))) for kind, raw in images if kind == "jpeg"]
    expected = [2, 6, 9, 12, 16, 20]
    for crop, frame in zip(crops, expected):
        assert crop.shape[0] == CROP_HEIGHT
        assert abs(crop.mean() - grey_level(frame)) < 3, frame
    captions = re.findall(r"<figcaption>frame (\d+),", page)
    assert [int(c) for c in captions] == expected


@needs_matplotlib
def test_report_without_video_lists_the_boxes_and_counts_frames_up_to_the_last(tmp_path):
    page = render_html_report(two_tracks())
    assert "No video given" in page and "21 (at least: up to the last frame with a box)" in page
    assert [k for k, _ in data_uris(page)] == ["png", "png"]
    assert "<h2>Lanes" not in page
    untracked = render_html_report(Detections([[0, 0, 9, 9]], frame=4), n_frames=9)
    assert "the boxes are not tracked" in untracked and "frames without any: 8" in untracked


@needs_matplotlib
def test_report_with_distances_and_lane_rows(tmp_path):
    d = two_tracks()
    d = d.replace(data={"distance_m": np.linspace(30, 10, len(d)), "relative_speed_mps": np.zeros(len(d))})
    page = render_html_report(d, lanes=[(0, 900.0, 0.1), (1, None, None)], n_frames=N_FRAMES)
    assert "<h2>Distances" in page and "<h2>Lanes" in page and "no lane in 1 of 2 frames" in page


@needs_matplotlib
def test_report_refuses_a_video_shorter_than_the_boxes(grey_video, tmp_path):
    d = Detections([[0, 0, 9, 9]], track_id=[0], frame=N_FRAMES + 5)
    out = tmp_path / "r.html"
    with pytest.raises(InputError, match=rf"grey\.mp4: has {N_FRAMES} frames, but the boxes name frame {N_FRAMES + 5}"):
        write_html_report(out, d, video=grey_video)
    assert list(tmp_path.iterdir()) == []  # nothing half-written


@needs_matplotlib
def test_report_never_overwrites_without_asking(tmp_path):
    out = tmp_path / "r.html"
    out.write_text("keep")
    with pytest.raises(OutputError):
        write_html_report(out, two_tracks())
    assert out.read_text() == "keep"
    write_html_report(out, two_tracks(), overwrite=True)
    assert out.read_text().startswith("<!DOCTYPE html>")
    csv = write_boxes_csv(tmp_path / "b.csv", two_tracks())
    with pytest.raises(OutputError):
        write_html_report(csv, csv, overwrite=True)  # the input itself


def test_report_without_matplotlib_names_the_extra():
    code = (
        "import sys; sys.modules['matplotlib'] = None\n"
        "from vehicle_detection.detections import Detections\n"
        "from vehicle_detection.viz.report import render_html_report\n"
        "from vehicle_detection.errors import MissingDependencyError\n"
        "try:\n"
        "    render_html_report(Detections([[0, 0, 9, 9]]))\n"
        "except MissingDependencyError as e:\n"
        "    print(e)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    assert out.stdout.strip() == 'the HTML report needs matplotlib, which is not installed: pip install "vehicle-detection[report]"'
    assert issubclass(MissingDependencyError, ImportError) and MissingDependencyError.exit_code == 2


# --- readable on any run: many tracks, cuts, ids, coasted boxes ----------------------------------------


def many_tracks(n: int = 14, every: int = 6) -> Detections:
    """``n`` tracks of 3 to 8 boxes each, a track every ``every`` frames, with distances; ids with gaps (0, 1, 3, 4, 6, ...)."""
    ids = [k + k // 2 for k in range(n)]
    rows = [(k * every + j, tid, 40.0 - j - k % 7) for k, tid in enumerate(ids) for j in range(3 + k % 6)]
    frames, tids, dist = (list(c) for c in zip(*rows))
    return Detections([[10, 10, 50, 40]] * len(rows), score=np.arange(len(rows), dtype=float), track_id=tids, frame=frames,
                      data={"distance_m": dist, "relative_speed_mps": np.zeros(len(rows))})


@functools.lru_cache(maxsize=1)
def many_tracks_page() -> str:
    """``render_html_report(many_tracks(), n_frames=200)``, rendered once for the tests below."""
    return render_html_report(many_tracks(), n_frames=200)


@needs_matplotlib
def test_report_labels_every_distance_line_and_marks_the_cuts():
    from vehicle_detection.viz import report

    d = many_tracks()  # 14 tracks: more lines than the 12 a legend would name
    assert len(track_spans(d)) > 12
    spans = track_spans(d)
    page = render_html_report(d, n_frames=200, cuts=[63, 150])
    assert "<tr><td>cuts between shots</td><td>2: frames 63, 150 (dashed lines on the charts)</td></tr>" in page
    assert "each line is labelled with its track id at its end (car 0, car 1, car 3, " in page
    fig = report._distances(d, spans, 200, [63, 150])
    ax = fig.axes[0]
    assert sorted(t.get_gid() for t in ax.texts) == sorted(f"track-{t}" for t in spans)  # every line, not 12 at most
    assert [t.get_text() for t in ax.texts] == [str(t) for t in spans]
    for figure in (fig, report._timeline(d, spans, 200, [63, 150]), report._boxes_per_frame(d, 200, [63, 150])):
        cuts = [line for line in figure.axes[0].lines if (line.get_gid() or "").startswith("cut-")]
        assert [line.get_xdata()[0] for line in cuts] == [62.5, 149.5]
    assert "cuts between shots" not in many_tracks_page()  # no video, none given: nothing said


@needs_matplotlib
def test_report_says_which_ids_it_counts():
    page = many_tracks_page()
    # 14 tracks with ids 0 to 19: the count agrees with the ids shown, and says why some are missing
    assert "<td>vehicles tracked</td><td>14 (ids 0 to 19: the tracker numbers every candidate, and 6 candidates were never " \
           "confirmed as vehicles)</td>" in page
    assert len(set(re.findall(r"<td>car (\d+)</td>", page))) == 14
    assert "<td>vehicles tracked</td><td>2 (ids 1 to 2)</td>" in render_html_report(two_tracks().replace(
        track_id=np.where(two_tracks().track_id == 4, 2, 1)))


@needs_matplotlib
def test_contact_sheet_shows_matched_boxes_not_coasted_ones(grey_video):
    # Track 3: frames 2 and 3 back-filled at its confirmation in frame 4 (the same score), matched
    # to frame 10, then coasting on its predicted box (the score of frame 10) to frame 14.
    frames = list(range(2, 15))
    score = [7.0, 7.0, 7.0] + [8.0 + f for f in range(5, 11)] + [18.0] * 4
    d = Detections([[10, 10, 50, 40]] * len(frames), score=score, track_id=3, frame=frames)
    page = render_html_report(d, video=grey_video)
    assert [int(c) for c in re.findall(r"<figcaption>frame (\d+),", page)] == [2, 6, 10]
    crops = [np.asarray(Image.open(io.BytesIO(raw))) for kind, raw in data_uris(page) if kind == "jpeg"]
    assert abs(crops[-1].mean() - grey_level(10)) < 3  # the last tile: frame 10's box


@needs_matplotlib
def test_report_finds_the_cuts_in_the_video(tmp_path):
    frames = []
    for i in range(N_FRAMES):  # one shot bright on the left, the next bright on the right
        frame = np.full((96, 160, 3), 30, np.uint8)
        (frame[:, :80] if i < 17 else frame[:, 80:])[:] = 200
        frames.append(frame)
    video = media.encode(tmp_path / "cut.mp4", frames)
    page = render_html_report(Detections([[0, 0, 9, 9]], track_id=[1], frame=[3]), video=video)
    assert "<td>cuts between shots</td><td>1: frame 17, found in the video (dashed lines on the charts)</td>" in page
    assert "<td>cuts between shots</td><td>none</td>" in render_html_report(Detections.empty(tracked=True), video=video, cuts=[])


# --- in a real browser ----------------------------------------------------------------------------

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser") or shutil.which("google-chrome")
_CHECK = """<script>
window.addEventListener("load", function () {
  var imgs = document.images, ok = 0;
  for (var i = 0; i < imgs.length; i++) {
    var good = imgs[i].complete && imgs[i].naturalWidth > 0;
    imgs[i].setAttribute("data-decoded", good ? "yes" : "no");
    ok += good;
  }
  var p = document.createElement("p");
  p.id = "vd-check";
  p.textContent = "decoded " + ok + " of " + imgs.length;
  document.body.appendChild(p);
});
</script>"""


def browser_check(page: str, folder: Path) -> tuple[int, int]:
    """``(decoded, total)`` images of ``page`` as headless Chromium sees them after the load event.

    The checking script is added to a copy: the report itself has none.
    """
    path = folder / "check.html"
    path.write_text(page.replace("</body>", _CHECK + "</body>"), encoding="utf-8")
    with tempfile.TemporaryDirectory() as profile:
        out = subprocess.run(
            [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
             "--disable-background-networking", "--disable-component-update", "--disable-sync",
             f"--user-data-dir={profile}", "--virtual-time-budget=10000", "--dump-dom", path.as_uri()],
            capture_output=True, text=True, timeout=120,
        )
    found = re.search(r'<p id="vd-check">decoded (\d+) of (\d+)</p>', out.stdout)
    assert found, f"chromium did not run the check (exit {out.returncode}): {out.stderr[-500:]}"
    return int(found.group(1)), int(found.group(2))


@needs_matplotlib
@pytest.mark.skipif(CHROMIUM is None, reason="no chromium on PATH (Debian: apt-get install chromium)")
def test_report_loads_in_chromium_and_every_image_decodes(grey_video, tmp_path):
    d = two_tracks().replace(data={"distance_m": np.linspace(30, 10, 16), "relative_speed_mps": np.zeros(16)})
    page = render_html_report(d, video=grey_video, lanes=[(i, 600.0, 0.0) for i in range(N_FRAMES)])
    decoded, total = browser_check(page, tmp_path)
    assert total == len(data_uris(page)) == 10  # 4 figures, 6 crops
    assert decoded == total
    # the check can fail: a damaged image is seen as one
    broken = page.replace("data:image/jpeg;base64,/9j/", "data:image/jpeg;base64,AAAA", 1)
    assert browser_check(broken, tmp_path) == (total - 1, total)
