"""Many inputs: ``detect INPUT...`` batches, --jobs, --skip-existing, dask, table formats, moviepy.

The batch runs go through ``main([...])`` in this process (the --jobs workers are real spawned
processes); the dask tests use an in-process ``LocalCluster``. They run on the first 8 frames of
test_video.mp4 (two cars in each, tracked from the first frame on): what they compare is the same
for 8 frames as for 38, at a fifth of the cost.
"""

from __future__ import annotations

import itertools
import json
import shutil
from pathlib import Path

import media
import numpy as np
import pytest

from vehicle_detection.cli import main
from vehicle_detection.cli.detect import SOME_FAILED
from vehicle_detection.io.tables import (
    BOXES_CSV_HEADER,
    FILES_CSV_HEADER,
    read_boxes_csv,
)

REPO = Path(__file__).resolve().parents[1]
TEST_VIDEO = REPO / "test_video.mp4"
TEST_IMAGES = REPO / "test_images"

pytestmark = pytest.mark.skipif(
    not (TEST_VIDEO.is_file() and (TEST_IMAGES / "test1.jpg").is_file()), reason="test_video.mp4 or test_images/ not in the checkout"
)


#: Frames of the clip the batch tests run on (cut from test_video.mp4, no re-encoding).
CLIP_FRAMES = 8


def snapshot(folder: Path) -> dict[str, tuple[int, int, bytes]]:
    return {p.name: (p.stat().st_ino, p.stat().st_mtime_ns, p.read_bytes()) for p in sorted(folder.iterdir())}


@pytest.fixture(scope="module")
def clip(tmp_path_factory) -> Path:
    """The first CLIP_FRAMES frames of test_video.mp4 (packets copied: the same decoded frames)."""
    return media.copy_packets(TEST_VIDEO, tmp_path_factory.mktemp("clip") / "clip.mp4", max_frames=CLIP_FRAMES)


@pytest.fixture(scope="module")
def videos(tmp_path_factory, clip) -> Path:
    """Three copies of the clip in one folder."""
    d = tmp_path_factory.mktemp("videos")
    for name in ("a.mp4", "b.mp4", "c.mp4"):
        shutil.copyfile(clip, d / name)
    return d


@pytest.fixture(scope="module")
def single_csv(tmp_path_factory, clip) -> bytes:
    """The boxes CSV of a single run of the clip with --no-video."""
    out = tmp_path_factory.mktemp("single")
    assert main(["detect", str(clip), "--no-video", "--out-dir", str(out), "--no-progress"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["clip_boxes.csv"]
    data = (out / "clip_boxes.csv").read_bytes()
    assert len(data.splitlines()) == 1 + 2 * CLIP_FRAMES  # boxes to compare: the two cars in every frame
    return data


@pytest.fixture(scope="module")
def cluster():
    distributed = pytest.importorskip("distributed", reason="dask.distributed not installed (pip install -e '.[distributed]')")
    with (
        distributed.LocalCluster(processes=False, n_workers=1, threads_per_worker=2, dashboard_address=None) as c,
        distributed.Client(c) as client,
    ):
        yield c, client


def test_jobs_2_gives_the_single_run_csv_and_skip_existing_rewrites_nothing(videos, single_csv, tmp_path, capsys):
    out = tmp_path / "out"
    assert main(["detect", str(videos), "--out-dir", str(out), "--jobs", "2", "--no-video", "--no-progress"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["a_boxes.csv", "b_boxes.csv", "c_boxes.csv"]
    for name in ("a", "b", "c"):
        assert (out / f"{name}_boxes.csv").read_bytes() == single_csv
    assert "3 done, 0 skipped, 0 failed" in capsys.readouterr().out
    before = snapshot(out)
    assert main(["detect", str(videos), "--out-dir", str(out), "--jobs", "2", "--no-video", "--skip-existing"]) == 0
    assert snapshot(out) == before  # same inodes, same mtimes, same bytes
    assert "0 done, 3 skipped, 0 failed" in capsys.readouterr().out
    # Without --skip-existing the outputs are refused (exit 7: every input failed, each named).
    assert main(["detect", str(videos), "--out-dir", str(out), "--no-video"]) == SOME_FAILED
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 3 and all("output exists" in line for line in err)
    assert snapshot(out) == before


def test_single_run_with_video_gives_the_same_boxes(clip, single_csv, tmp_path):
    shutil.copyfile(clip, tmp_path / "clip.mp4")
    assert main(["detect", str(tmp_path / "clip.mp4"), "--no-progress"]) == 0  # the single-input path, with video
    assert (tmp_path / "clip_boxes.csv").read_bytes() == single_csv


def test_a_bad_input_is_named_and_the_others_go_on(videos, tmp_path, capsys):
    bad = tmp_path / "broken.mp4"
    bad.write_bytes(b"not a video")
    out = tmp_path / "out"
    code = main(["detect", str(videos / "a.mp4"), str(bad), str(tmp_path / "missing.mp4"), "--out-dir", str(out), "--no-video"])
    assert code == SOME_FAILED
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 2
    assert err[0].startswith(f"vehicle-detection: error: {bad}: ") or err[1].startswith(f"vehicle-detection: error: {bad}: ")
    assert any(str(tmp_path / "missing.mp4") in line for line in err)
    assert sorted(p.name for p in out.iterdir()) == ["a_boxes.csv"]
    # One input: its own exit code.
    assert main(["detect", str(bad), "--out-dir", str(out), "--no-video"]) == 3


def test_frame_range_keeps_decoded_indexes(clip, tmp_path):
    import vehicle_detection as vd

    # Frames 2-5 of 8: the range ends before the clip does.
    assert main(["detect", str(clip), "--frames", "2-5", "--no-video", "--out-dir", str(tmp_path)]) == 0
    table = read_boxes_csv(tmp_path / "clip_boxes.csv")
    assert table.frame.min() >= 2 and table.frame.max() <= 5 and 2 in table.frame and 5 in table.frame
    ref = vd.process_video(clip, None, progress=False, frames=(2, 6))
    assert table == ref.replace(score=np.round(ref.score, 4))  # the CSV keeps 4 decimals
    assert main(["detect", str(clip), "--start", "2", "--end", "6", "--no-video", "--out-dir", str(tmp_path / "b")]) == 0
    assert (tmp_path / "b" / "clip_boxes.csv").read_bytes() == (tmp_path / "clip_boxes.csv").read_bytes()


def test_detect_many_python(videos, single_csv, tmp_path):
    import vehicle_detection as vd

    results = vd.detect_many([videos / "b.mp4", str(videos / "a.*")], tmp_path, vd.InputOptions(video=False))
    assert [r.path.name for r in results] == ["b.mp4", "a.mp4"]
    assert all(r.ok and r.n_boxes == 2 * CLIP_FRAMES and r.n_frames == CLIP_FRAMES and not r.skipped for r in results)
    assert results[0].outputs == (tmp_path / "b_boxes.csv",)
    assert (tmp_path / "b_boxes.csv").read_bytes() == single_csv
    again = vd.detect_many(videos / "b.mp4", tmp_path, vd.InputOptions(video=False), skip_existing=True)
    assert again[0].skipped and again[0].error is None


def test_image_folder_csv_names_each_file(tmp_path):
    shots = tmp_path / "shots"
    shots.mkdir()
    for name in ("test1.jpg", "test3.jpg"):
        shutil.copyfile(TEST_IMAGES / name, shots / name)
    out = tmp_path / "out"
    assert main(["detect", str(shots), "--out-dir", str(out), "--format", "csv,coco"]) == 0
    assert sorted(p.name for p in (out / "shots_detected").iterdir()) == ["boxes.csv", "test1.jpg", "test3.jpg"]
    lines = (out / "shots_detected" / "boxes.csv").read_text().splitlines()
    assert lines[0] == FILES_CSV_HEADER == BOXES_CSV_HEADER + ",file"
    table = read_boxes_csv(out / "shots_detected" / "boxes.csv")
    assert [n for n in table.data["file"]] == [["test1.jpg", "test3.jpg"][f] for f in table.frame]
    # COCO detection JSON, read back with json and checked against the schema.
    doc = json.loads((out / "shots_coco.json").read_text())
    assert [i["file_name"] for i in doc["images"]] == ["test1.jpg", "test3.jpg"]
    assert all(i["width"] == 1280 and i["height"] == 720 for i in doc["images"])
    assert doc["categories"] == [{"id": 1, "name": "car", "supercategory": "vehicle"}]
    anns = doc["annotations"]
    assert len(anns) == len(table) > 0 and len({a["id"] for a in anns}) == len(anns)
    for a, (frame, x1, y1, x2, y2, _, score) in zip(anns, table.rows()):
        assert set(a) >= {"id", "image_id", "category_id", "bbox", "area", "score", "iscrowd"}
        assert a["image_id"] == frame + 1 and a["bbox"] == [x1, y1, x2 - x1, y2 - y1] and a["area"] == (x2 - x1) * (y2 - y1)
        assert a["score"] == pytest.approx(score, abs=1e-4)
    # Read back by the COCO reference API, as a ground-truth file and as detection results.
    coco_mod = pytest.importorskip("pycocotools.coco")
    coco = coco_mod.COCO(str(out / "shots_coco.json"))
    assert sorted(coco.getImgIds()) == [1, 2] and coco.getCatIds(catNms=["car"]) == [1]
    for frame in range(2):
        boxes = [a["bbox"] for a in coco.loadAnns(coco.getAnnIds(imgIds=[frame + 1]))]
        assert boxes == [[x1, y1, x2 - x1, y2 - y1] for f, x1, y1, x2, y2, _, _ in table.rows() if f == frame]
    results = coco.loadRes(anns)
    assert len(results.getAnnIds()) == len(table)


def test_mot_export_reads_back_with_motmetrics(clip, tmp_path):
    mmio = pytest.importorskip("motmetrics.io")
    assert main(["detect", str(clip), "--no-video", "--out-dir", str(tmp_path), "--format", "csv,mot"]) == 0
    table = read_boxes_csv(tmp_path / "clip_boxes.csv")
    df = mmio.loadtxt(str(tmp_path / "clip_mot.txt"), fmt="mot15-2D", min_confidence=-1)
    assert len(df) == len(table) > 0
    got = sorted((int(f), int(i), float(r.X), float(r.Y), float(r.Width), float(r.Height)) for (f, i), r in df.iterrows())
    want = sorted((f + 1, t, x1, y1, x2 - x1, y2 - y1) for f, x1, y1, x2, y2, t, _ in table.rows())
    assert got == want


def test_parquet_per_input_and_one_table_for_the_batch(videos, single_csv, tmp_path):
    pytest.importorskip("pyarrow")
    from vehicle_detection.io.formats import read_parquet

    out = tmp_path / "out"
    both = str(tmp_path / "all.parquet")
    args = ["detect", str(videos / "a.mp4"), str(videos / "b.mp4"), "--no-video", "--out-dir", str(out), "--format", "parquet", "--table", both]
    assert main(args) == 0
    assert sorted(p.name for p in out.iterdir()) == ["a_boxes.parquet", "b_boxes.parquet"]
    ref = read_boxes_csv_bytes(single_csv, tmp_path)
    tables = read_parquet(both)
    assert list(tables) == ["a.mp4", "b.mp4"]
    assert all(t.replace(score=np.round(t.score, 4)) == ref for t in tables.values())  # full precision in Parquet
    assert read_parquet(out / "a_boxes.parquet")["a.mp4"] == tables["a.mp4"]


def read_boxes_csv_bytes(data: bytes, tmp_path: Path):
    p = tmp_path / "ref.csv"
    p.write_bytes(data)
    return read_boxes_csv(p)


def test_supervision_round_trip():
    sv = pytest.importorskip("supervision")
    from vehicle_detection.detections import Detections

    d = Detections([[10, 20, 74, 84], [100, 20, 164, 84]], score=[0.5, 2.0], track_id=[3, 7], frame=[4, 5])
    s = d.to_supervision()
    assert isinstance(s, sv.Detections) and len(s) == 2
    assert s.xyxy.tolist() == d.xyxy.tolist() and s.tracker_id.tolist() == [3, 7]
    assert s.confidence.tolist() == pytest.approx([2 / 3, 5 / 6]) and s.data["score"].tolist() == [0.5, 2.0]
    assert Detections.from_supervision(s) == d
    untracked = Detections([[1, 2, 30, 40]])
    assert Detections.from_supervision(untracked.to_supervision()) == untracked


# --- dask -----------------------------------------------------------------------------------------


@pytest.mark.xdist_group("batch-dask")  # the dask tests on one worker: one LocalCluster
def test_scheduler_gives_identical_csvs(cluster, videos, single_csv, tmp_path):
    c, _ = cluster
    out = tmp_path / "out"
    assert main(["detect", str(videos), "--out-dir", str(out), "--no-video", "--scheduler", c.scheduler_address]) == 0
    for name in ("a", "b", "c"):
        assert (out / f"{name}_boxes.csv").read_bytes() == single_csv
    # Chunks of a video (3, 3 and 2 frames), the tracker state passed from chunk to chunk: the same CSV.
    out2 = tmp_path / "chunks"
    assert main(["detect", str(videos / "a.mp4"), "--out-dir", str(out2), "--no-video", "--scheduler", c.scheduler_address,
                 "--chunk-frames", "3"]) == 0
    assert (out2 / "a_boxes.csv").read_bytes() == single_csv


@pytest.mark.xdist_group("batch-dask")
def test_chunks_continue_the_tracker_and_its_back_fill(cluster, clip):
    import vehicle_detection as vd
    from vehicle_detection.pipeline.batch import (
        detect_chunked,
        join_chunks,
        track_chunk,
    )

    _, client = cluster
    n = CLIP_FRAMES
    ref = vd.process_video(clip, None, progress=False)
    assert len(ref) > 0 and len(set(ref.track_id.tolist())) >= 1
    lag = vd.Detector().config.tracker.min_hits - 1
    assert lag >= 1
    whole, _ = track_chunk(clip, 0, None)
    assert join_chunks(whole, lag) == ref
    # Put a chunk border between a track's confirmation and the earlier frames it back-fills,
    # so that the test means something: the back-fill lands in the chunk before.
    fills = [i for i, (_, _, fill) in enumerate(whole) if len(fill) and fill.frame.min() < i]
    assert fills
    border = fills[0]
    bounds = sorted({0, border, *range(border + 4, n, 4)}) + [n]
    assert len(bounds) >= 4  # at least three chunks: a state passed on twice
    steps, state = [], None
    for a, b in itertools.pairwise(bounds):
        part, state = track_chunk(clip, a, b, state)
        steps += part
    assert state.frame_index == n
    assert [s[0] for s in steps] == list(range(n))
    assert join_chunks(steps, lag) == ref
    assert detect_chunked(clip, 3, client=client) == ref  # chunks of 3, 3 and 2
    # A range (chunks of 2 from frame 1 to 7), ending before the clip does.
    assert detect_chunked(clip, 2, client=client, start=1, end=7) == vd.process_video(clip, None, progress=False, frames=(1, 7))
    with pytest.raises(ValueError, match="continues at frame"):
        track_chunk(clip, 3, 5, state)


@pytest.mark.xdist_group("batch-dask")
def test_detect_many_with_a_client(cluster, videos, single_csv, tmp_path):
    import vehicle_detection as vd

    _, client = cluster
    results = vd.detect_many(videos, tmp_path, vd.InputOptions(video=False), client=client)
    assert [r.path.name for r in results] == ["a.mp4", "b.mp4", "c.mp4"] and all(r.ok for r in results)
    assert all((tmp_path / f"{n}_boxes.csv").read_bytes() == single_csv for n in "abc")


# --- moviepy ----------------------------------------------------------------------------------------


class FakeClip:
    """What MoviepyAdapter needs of a moviepy 2 clip: ``image_transform`` (which, like moviepy's,
    reads frame 0 once to learn the size) and ``iter_frames``."""

    def __init__(self, frames, func=None):
        self.frames, self.func = frames, func
        if func is not None:
            self.size = self.get_frame(0).shape[1::-1]  # moviepy's extra call on frame 0

    def get_frame(self, t):
        frame = self.frames[int(t)]
        return frame if self.func is None else self.func(frame)

    def image_transform(self, func):
        return FakeClip(self.frames, func)

    def iter_frames(self):
        for t in range(len(self.frames)):
            yield self.get_frame(t)


@pytest.fixture(scope="module")
def clip_frames():
    from itertools import islice

    from vehicle_detection.io.video import read_frames

    frames = read_frames(TEST_VIDEO)
    try:
        return list(islice(frames, 6))  # tracks confirmed from the third frame on
    finally:
        frames.close()


def test_moviepy_adapter_with_a_fake_clip(clip_frames):
    import vehicle_detection as vd
    from vehicle_detection.viz.drawing import draw_detections

    detector = vd.Detector()
    adapter = vd.MoviepyAdapter(detector)
    out = list(FakeClip(clip_frames).image_transform(adapter).iter_frames())
    assert adapter.frames_processed == len(clip_frames)  # frame 0 asked twice, processed once
    tracker = detector.new_tracker()
    live = [detector.step(f, tracker) for f in clip_frames]
    assert adapter.detections == vd.Detections.concatenate(live)
    assert all(np.array_equal(o, draw_detections(f, d)) for o, f, d in zip(out, clip_frames, live))
    assert len(adapter.detections) > 0
    with pytest.raises(ValueError, match="frames must come in order"):
        list(FakeClip(clip_frames).image_transform(adapter).iter_frames())  # a second pass
    adapter.reset()  # clip.transform(adapter.transform): times checked instead of contents

    def get(t):
        return clip_frames[round(t * 25)]

    first = adapter.transform(get, 0.0)
    assert adapter.transform(get, 0.0) is first and adapter.frames_processed == 1
    adapter.transform(get, 0.04)
    assert adapter.frames_processed == 2
    with pytest.raises(ValueError, match="frames must come in order"):
        adapter.transform(get, 0.0)


def test_moviepy_adapter_with_moviepy(tmp_path):
    # moviepy 2.2 pins Pillow < 12, so it is not in the test extra; .ci/run runs this test in a
    # separate environment with the [moviepy] extra.
    moviepy = pytest.importorskip("moviepy", reason="moviepy 2 not installed (pip install -e '.[moviepy]')")
    import vehicle_detection as vd
    from vehicle_detection.io.video import read_frames

    clip = moviepy.VideoFileClip(str(TEST_VIDEO)).subclipped(0, 0.6)
    raw = list(clip.iter_frames())
    detector = vd.Detector()
    adapter = vd.MoviepyAdapter(detector)
    out = tmp_path / "out.mp4"
    clip.image_transform(adapter).write_videofile(str(out), codec="libx264", audio=False, logger=None)
    clip.close()
    # moviepy's extra call on frame 0 did not advance the tracker: one step per frame, in order,
    # the same boxes as stepping the detector live over the frames moviepy decodes.
    assert adapter.frames_processed == len(raw) == 15
    tracker = detector.new_tracker()
    assert adapter.detections == vd.Detections.concatenate([detector.step(f, tracker) for f in raw])
    assert len(adapter.detections) > 0
    written = read_frames(out)
    try:
        assert sum(1 for _ in written) == len(raw)
    finally:
        written.close()
    with pytest.raises(ValueError, match="frames must come in order"):
        adapter(raw[0])  # a second pass from the start


def test_sigterm_with_jobs_leaves_no_partial_files(tmp_path):
    import os
    import signal
    import subprocess
    import sys
    import time

    # The whole 38-frame video, three times: a run that lasts well past the first .partial file,
    # whatever the machine's load (what it costs is the start-up, up to that file, not the length).
    videos = tmp_path / "videos"
    videos.mkdir()
    for name in ("a.mp4", "b.mp4", "c.mp4"):
        shutil.copyfile(TEST_VIDEO, videos / name)
    out = tmp_path / "out"
    proc = subprocess.Popen(
        [sys.executable, "-m", "vehicle_detection.cli", "detect", str(videos), "--out-dir", str(out), "--jobs", "2", "--no-progress"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO,
    )
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not (out.is_dir() and any(p.name.endswith(".partial") for p in out.iterdir())):
        time.sleep(0.05)
    assert proc.poll() is None, proc.communicate()
    os.kill(proc.pid, signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130, err
    assert err.strip().splitlines()[-1] == "vehicle-detection: interrupted"
    left = sorted(p.name for p in out.iterdir()) if out.exists() else []
    assert not [n for n in left if n.endswith(".partial")], left
    # An input is committed whole or not at all: its video and its CSV together.
    stems = {n.split("_")[0] for n in left}
    assert sorted(left) == sorted(n for s in stems for n in (f"{s}_boxes.csv", f"{s}_detected.mp4"))
