"""What a new user hit, following the README (issue 21, section 4): each a run as the user made it."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import media
import pytest

REPO = Path(__file__).resolve().parents[1]
TEST_VIDEO = REPO / "test_video.mp4"
TEST_IMAGES = REPO / "test_images"

pytestmark = pytest.mark.skipif(
    not (TEST_VIDEO.is_file() and (TEST_IMAGES / "test1.jpg").is_file()), reason="test_video.mp4 or test_images/ not in the checkout"
)


#: Frames of the clip the video runs use (cut from test_video.mp4): two cars in each.
CLIP_FRAMES = 4


@pytest.fixture(scope="module")
def clip(tmp_path_factory) -> Path:
    """The first CLIP_FRAMES frames of test_video.mp4 (packets copied, no re-encoding): what the
    runs below check is the same for 4 frames as for 38 (both cars boxed from the first frame on),
    at a tenth of the cost."""
    return media.copy_packets(TEST_VIDEO, tmp_path_factory.mktemp("clip") / "clip.mp4", max_frames=CLIP_FRAMES)


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), *filter(None, [env.get("PYTHONPATH")])])
    return env


def test_detect_many_with_jobs_in_a_plain_script_without_a_main_guard(tmp_path):
    # A script as a user writes it: no ``if __name__ == "__main__":``. Worker processes must not
    # re-run it (each input came back "worker failed: BrokenProcessPool" with multiprocessing's spawn).
    for name in ("test1.jpg", "test3.jpg"):
        shutil.copy(TEST_IMAGES / name, tmp_path / name)
    script = tmp_path / "plain.py"
    script.write_text(textwrap.dedent("""
        import vehicle_detection as vd
        print("script started")
        results = vd.detect_many(["test1.jpg", "test3.jpg"], "out", vd.InputOptions(video=False), jobs=2)
        for r in results:
            print(r.path, r.n_boxes, r.error)
    """))
    proc = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=_env(), capture_output=True, text=True, timeout=600, check=False)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines.count("script started") == 1  # the workers did not run the script again
    rows = [line.split() for line in lines[1:]]
    assert [r[0] for r in rows] == ["test1.jpg", "test3.jpg"]
    assert all(r[2] == "None" and int(r[1]) >= 1 for r in rows), lines  # no error, cars found in both
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["test1_boxes.csv", "test3_boxes.csv"]


def test_out_puts_every_output_of_the_run_beside_it(clip, tmp_path, capsys):
    from vehicle_detection.cli import main
    from vehicle_detection.io.tables import read_boxes_csv

    video = tmp_path / "in" / "clip.mp4"
    video.parent.mkdir()
    shutil.copy(clip, video)
    out = tmp_path / "o" / "t.mp4"
    assert main(["detect", str(video), "--out", str(out), "--format", "csv,mot", "--no-progress"]) == 0
    assert sorted(p.name for p in video.parent.iterdir()) == ["clip.mp4"]  # nothing beside the input
    assert sorted(p.name for p in out.parent.iterdir()) == ["t.mp4", "t_boxes.csv", "t_mot.txt"]  # named after --out
    assert len(read_boxes_csv(out.parent / "t_boxes.csv")) > 0
    # A folder of images: the annotated folder, its boxes.csv inside, the other tables beside it.
    shots = tmp_path / "shots"
    shots.mkdir()
    for name in ("test1.jpg", "test2.jpg"):
        shutil.copy(TEST_IMAGES / name, shots / name)
    drawn = tmp_path / "o2" / "drawn"
    assert main(["detect", str(shots), "--out", str(drawn), "--format", "csv,coco"]) == 0
    assert sorted(p.name for p in shots.iterdir()) == ["test1.jpg", "test2.jpg"]
    assert sorted(p.name for p in drawn.parent.iterdir()) == ["drawn", "drawn_coco.json"]
    assert sorted(p.name for p in drawn.iterdir()) == ["boxes.csv", "test1.jpg", "test2.jpg"]


def test_the_runner_counts_every_frame_and_image_not_only_those_with_boxes(clip, tmp_path):
    import vehicle_detection as vd
    from vehicle_detection.pipeline.inputs import InputOptions, run_input

    frames = sum(1 for _ in vd.read_frames(clip))
    r = run_input(clip, InputOptions(video=False), out_dir=tmp_path / "v")
    table = vd.read_boxes_csv(r.outputs[0])
    assert r.n_frames == frames == CLIP_FRAMES and r.n_boxes == len(table) > 0
    shots = tmp_path / "shots"
    shots.mkdir()
    for name in ("test1.jpg", "test2.jpg", "test3.jpg"):  # test2: an empty road
        shutil.copy(TEST_IMAGES / name, shots / name)
    r = run_input(shots, InputOptions(video=False), out_dir=tmp_path / "f")
    counts = [len(vd.Detector().detect_image(vd.read_image(shots / n))) for n in ("test1.jpg", "test2.jpg", "test3.jpg")]
    assert r.n_frames == 3 and r.n_boxes == sum(counts) and 0 in counts and 1 in counts
    for name, n in zip(("test1.jpg", "test2.jpg", "test3.jpg"), counts):
        assert f"{shots / name}: {n} vehicle{'' if n == 1 else 's'}" in r.notes
    assert any(note.endswith(": 1 vehicle") for note in r.notes)


SHARED = REPO.parent / "shared" / "data"
CLIP_A = Path(os.environ.get("VEHICLE_DETECTION_DATA", SHARED)) / "videos" / "project_video_clip_A.mp4"


@pytest.mark.skipif(not CLIP_A.is_file(), reason=f"{CLIP_A} not found (clip A of the shared data)")
def test_horizon_auto_on_a_still_image_estimates_it_from_the_image(tmp_path, capsys):
    import vehicle_detection as vd
    from vehicle_detection.cli import main
    from vehicle_detection.io.images import write_image

    frame = next(iter(vd.read_frames(CLIP_A)))
    # The frame as another camera would frame it: 120 rows less sky, the horizon higher up.
    tilted = frame[120:]
    estimate = vd.estimate_horizon([tilted])
    plan = vd.Detector().config.plan.reference_horizon
    assert estimate is not None and estimate < plan - 0.05
    write_image(tmp_path / "tilted.png", tilted)
    write_image(tmp_path / "frame.png", frame)
    write_image(tmp_path / "flat.png", vd.read_image(tmp_path / "tilted.png") * 0 + 128)  # no lines at all

    assert main(["detect", str(tmp_path / "tilted.png"), "--horizon", "auto", "--no-video", "--boxes", str(tmp_path / "t.csv")]) == 0
    out = capsys.readouterr().out
    assert f"horizon: {estimate:.3f} of the height, estimated from the image's road lines" in out and "bands moved" in out
    expected = vd.Detector().with_horizon(estimate).detect_image(tilted)
    found = vd.read_boxes_csv(tmp_path / "t.csv")
    assert found.xyxy.tolist() == expected.xyxy.tolist() and len(found) > 0
    assert found.xyxy.tolist() != vd.Detector().detect_image(tilted).xyxy.tolist()  # the plan's bands give other boxes

    assert main(["detect", str(tmp_path / "frame.png"), "--horizon", "auto", "--no-video", "--boxes", str(tmp_path / "f.csv")]) == 0
    out = capsys.readouterr().out
    assert "estimated from the image's road lines" in out and "bands unchanged" in out  # the project camera's own horizon
    assert vd.read_boxes_csv(tmp_path / "f.csv").xyxy.tolist() == vd.Detector().detect_image(frame).xyxy.tolist()

    assert main(["detect", str(tmp_path / "flat.png"), "--horizon", "auto", "--no-video", "--boxes", str(tmp_path / "n.csv")]) == 0
    assert "horizon: no road lines or cars to estimate it from in this image" in capsys.readouterr().out
    # Without --horizon auto an image is searched where the plan says, as documented, and nothing is said.
    assert main(["detect", str(tmp_path / "tilted.png"), "--no-video", "--boxes", str(tmp_path / "p.csv")]) == 0
    assert "horizon:" not in capsys.readouterr().out


def test_coco_in_a_mixed_batch_is_written_for_the_images_and_a_glob_of_images_is_one_dataset(clip, tmp_path, capsys):
    import json

    import vehicle_detection as vd
    from vehicle_detection.cli import main

    mixed = tmp_path / "mixed"
    mixed.mkdir()
    shutil.copy(clip, mixed / "clip.mp4")
    for name in ("test1.jpg", "test3.jpg"):
        shutil.copy(TEST_IMAGES / name, mixed / name)
    out = tmp_path / "out"
    argv = ["detect", str(mixed), "--format", "csv,mot,coco", "--no-video", "--out-dir", str(out), "--no-progress"]
    assert main(argv) == 0  # the video no longer fails for want of COCO
    err = capsys.readouterr().err
    assert err.count("COCO JSON is written for images only") == 1
    assert sorted(p.name for p in out.iterdir()) == ["clip_boxes.csv", "clip_mot.txt", "mixed_coco.json", "mixed_detected",
                                                     "mixed_mot.txt"]
    assert len(json.loads((out / "mixed_coco.json").read_text())["images"]) == 2

    # A glob of images (a batch of single images): one COCO dataset, not one file each (two images, one without cars).
    shots = tmp_path / "shots"
    shots.mkdir()
    for name in ("test1.jpg", "test2.jpg"):
        shutil.copy(TEST_IMAGES / name, shots / name)
    out2 = tmp_path / "out2"
    assert main(["detect", str(shots / "test*.jpg"), "--format", "coco", "--no-video", "--out-dir", str(out2)]) == 0
    assert sorted(p.name for p in out2.iterdir()) == ["images_coco.json"]
    doc = json.loads((out2 / "images_coco.json").read_text())
    assert [im["file_name"] for im in doc["images"]] == [f"../shots/test{i}.jpg" for i in (1, 2)]
    assert [im["id"] for im in doc["images"]] == [1, 2] and {(im["width"], im["height"]) for im in doc["images"]} == {(1280, 720)}
    detector = vd.Detector()
    for im in doc["images"]:
        expected = detector.detect_image(shots / Path(im["file_name"]).name)
        got = [a["bbox"] for a in doc["annotations"] if a["image_id"] == im["id"]]
        assert got == [[x1, y1, x2 - x1, y2 - y1] for x1, y1, x2, y2 in expected.xyxy.tolist()]
    assert len(doc["annotations"]) > 0
    # Again with --skip-existing: the dataset is complete, nothing is rewritten.
    before = (out2 / "images_coco.json").stat().st_mtime_ns
    assert main(["detect", str(shots / "test*.jpg"), "--format", "coco", "--no-video", "--out-dir", str(out2), "--skip-existing"]) == 0
    assert (out2 / "images_coco.json").stat().st_mtime_ns == before
