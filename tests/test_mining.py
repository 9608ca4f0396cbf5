"""Tests of vehicle_detection.training.mining (hard-negative mining), search.window_patches, extra
negatives in load_dataset, and the ``mine-negatives`` / ``train --extra-negatives`` commands."""

from __future__ import annotations

import io
import json
import os
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest

from conftest import small_archives
from PIL import Image

from vehicle_detection.classifier import VehicleClassifier
from vehicle_detection.cli import main
from vehicle_detection.config import DetectorConfig
from vehicle_detection.training.data import load_dataset
from vehicle_detection.detections import Detections
from vehicle_detection.detector import Detector
from vehicle_detection.errors import InputError, OutputError
from vehicle_detection.metrics.detection import Annotations, FrameLabels
from vehicle_detection.io.images import read_image, write_image
from vehicle_detection.training.mining import (
    MinedNegatives,
    MiningOptions,
    MiningSource,
    labels_at,
    mine_negatives,
    negative_mask,
    write_negatives,
)
from vehicle_detection.search import SearchPlan, SearchScale, search, window_patches

REPO = Path(__file__).resolve().parents[1]
TEST_IMAGES = REPO / "test_images"
SHARED = Path(os.environ.get("VEHICLE_DETECTION_DATA") or REPO.parent / "shared" / "data")
needs_images = pytest.mark.skipif(not (TEST_IMAGES / "test1.jpg").is_file(), reason="test_images/ not in the checkout")
needs_archives = pytest.mark.skipif(
    not ((SHARED / "vehicles.zip").is_file() and (SHARED / "non-vehicles.zip").is_file()),
    reason=f"training archives not found in {SHARED} (set VEHICLE_DETECTION_DATA)",
)


def _ann(frames: dict[int, dict]) -> Annotations:
    return Annotations(video=None, frames={k: FrameLabels(**v) for k, v in sorted(frames.items())})


# --------------------------------------------------------------------------------------------
# Labels between labelled frames
# --------------------------------------------------------------------------------------------
def test_labels_at_interpolates_between_labelled_frames():
    ann = _ann({
        0: {"cars": [[100, 100, 200, 180], [500, 100, 600, 160]], "ignore": [[0, 0, 50, 50]]},
        10: {"cars": [[120, 110, 220, 190]], "ignore": [[0, 0, 60, 60]]},
        40: {"cars": [], "ignore": []},
    })  # fmt: skip
    assert labels_at(ann, 0) is ann.frames[0]
    mid = labels_at(ann, 5)
    # The first car moves half-way; the second has no partner at frame 10 and keeps its box.
    assert mid.cars.tolist() == [[110, 105, 210, 185], [500, 100, 600, 160]]
    assert mid.ignore.tolist() == [[0, 0, 50, 50], [0, 0, 60, 60]]
    assert labels_at(ann, 20, max_gap=10).cars.tolist() == [[120, 110, 220, 190]]
    assert labels_at(ann, 25, max_gap=10) is None  # 15 frames from both labelled frames
    assert labels_at(ann, 41) is None  # after the last labelled frame
    assert labels_at(_ann({3: {"cars": []}}), 2) is None  # before the first


def test_labels_at_pairs_cars_by_track_id():
    ann = _ann({
        0: {"cars": [[0, 0, 10, 10], [100, 0, 110, 10]], "ids": [1, 2]},
        2: {"cars": [[104, 0, 114, 10], [2, 0, 12, 10]], "ids": [2, 1]},
    })  # fmt: skip
    assert labels_at(ann, 1).cars.tolist() == [[1, 0, 11, 10], [102, 0, 112, 10]]


def test_negative_mask_rules():
    labels = FrameLabels(cars=[[100, 100, 200, 200]], ignore=[[0, 0, 100, 50]])
    boxes = np.array([
        [300, 300, 364, 364],   # far from everything: negative
        [150, 150, 214, 214],   # IoU with the car 0.1+: not
        [0, 100, 64, 164],      # touches nothing: negative
        [190, 100, 254, 164],   # IoU < 0.1, but 10/64 of it inside the car: not (max_car_cover 0.1)
        [0, 0, 64, 64],         # 50/64 inside an ignore box: not
        [0, 30, 64, 94],        # 20/64 inside an ignore box: negative
    ])  # fmt: skip
    assert negative_mask(boxes, labels).tolist() == [True, False, True, False, False, True]
    assert negative_mask(boxes, labels, max_car_cover=0.5).tolist() == [True, False, True, True, False, True]
    regions = np.array([[0, 0, 400, 250]])  # must lie wholly inside
    assert negative_mask(boxes, None, regions).tolist() == [False, True, True, True, True, True]
    assert negative_mask(boxes, labels, regions).tolist() == [False, False, True, False, False, True]
    with pytest.raises(ValueError, match="needs labels or negative regions"):
        negative_mask(boxes)


# --------------------------------------------------------------------------------------------
# Mining a tiny synthetic case: a 64x256 frame, four 64x64 windows, hot windows controlled
# --------------------------------------------------------------------------------------------
TINY_PLAN = SearchPlan(scales=(SearchScale(1.0, 0, 64, step=8),), threshold=0.0, reference_height=64, overhang=0.0)
TINY_WINDOWS = np.array([[x, 0, x + 64, 64] for x in (0, 64, 128, 192)])


@pytest.fixture()
def tiny(tmp_path, monkeypatch, default_model):
    """Three 64x256 random frames as an image folder, and a detector whose hot windows are all
    four windows of every frame (scores 1, 2, 3, 4)."""
    folder = tmp_path / "frames"
    rng = np.random.default_rng(0)
    frames = [rng.integers(0, 256, (64, 256, 3), dtype=np.uint8) for _ in range(3)]
    for i, f in enumerate(frames):
        write_image(folder / f"f{i}.png", f)

    def windows(self, frame):
        assert frame.shape == (64, 256, 3)
        return Detections(TINY_WINDOWS, score=[1.0, 2.0, 3.0, 4.0], data={"scale_index": np.zeros(4, np.int64)})

    monkeypatch.setattr(Detector, "windows", windows)
    detector = Detector(default_model.replace(detector_config=DetectorConfig(plan=TINY_PLAN)))
    # A car on window 1 in frames 0 and 2 (frame 1 interpolated), an ignore box on window 3.
    ann = _ann({k: {"cars": [[64, 0, 128, 64]], "ignore": [[192, 0, 256, 64]]} for k in (0, 2)})
    return folder, frames, detector, ann


def test_window_patches_are_the_crops_in_the_tiny_plan(tiny, default_model):
    _, frames, detector, _ = tiny
    wins = Detections(TINY_WINDOWS[[2, 0]], data={"scale_index": np.zeros(2, np.int64)})
    patches = window_patches(frames[0], wins, detector.model)
    np.testing.assert_array_equal(patches, np.stack([frames[0][:, 128:192], frames[0][:, 0:64]]))
    with pytest.raises(ValueError, match="not a window of scale 0"):
        window_patches(frames[0], Detections([[1, 0, 65, 64]], data={"scale_index": [0]}), detector.model)


def test_mining_gives_exactly_the_expected_crops(tiny):
    folder, frames, detector, ann = tiny
    no_dedupe = mine_negatives([MiningSource(folder, ann)], detector, MiningOptions(dedupe_iou=1.01))
    # Windows 0 and 2 of each frame, hardest (highest score) first.
    assert no_dedupe.windows.frame.tolist() == [0, 0, 1, 1, 2, 2]
    assert no_dedupe.windows.xyxy.tolist() == [TINY_WINDOWS[k].tolist() for k in (2, 0) * 3]
    assert no_dedupe.windows.score.tolist() == [3.0, 1.0] * 3
    want = np.stack([frames[i][:, x : x + 64] for i in range(3) for x in (128, 0)])
    np.testing.assert_array_equal(no_dedupe.patches, want)
    assert no_dedupe.stats == {"frames": {"frames": 3, "skipped_frames": 0, "hot": 12, "far": 6, "duplicates": 0, "kept": 6}}
    assert no_dedupe.file_names()[:2] == ["frames__f000000__s0_128_0_192_64.png", "frames__f000000__s0_0_0_64_64.png"]

    # The same boxes in the next frames are near duplicates: only frame 0's are kept ...
    deduped = mine_negatives([MiningSource(folder, ann)], detector)
    assert deduped.windows.frame.tolist() == [0, 0] and deduped.stats["frames"]["duplicates"] == 4
    # ... unless the frames are farther apart than dedupe_frames.
    apart = mine_negatives([MiningSource(folder, ann)], detector, MiningOptions(dedupe_frames=1, every=2))
    assert apart.windows.frame.tolist() == [0, 0, 2, 2]
    # Frames left out are never searched.
    only = mine_negatives([MiningSource(folder, ann)], detector, MiningOptions(frames=[1], dedupe_iou=1.01))
    assert only.windows.frame.tolist() == [1, 1] and only.stats["frames"]["frames"] == 1
    np.testing.assert_array_equal(only.patches, want[2:4])


def test_mining_without_labels_needs_a_negative_region(tiny):
    folder, frames, detector, _ = tiny
    with pytest.raises(InputError, match="no labels for this input"):
        mine_negatives([MiningSource(folder)], detector)
    mined = mine_negatives([MiningSource(folder)], detector, MiningOptions(negative_regions=[[100, 0, 256, 64]], dedupe_iou=1.01))
    assert mined.windows.xyxy.tolist() == [TINY_WINDOWS[k].tolist() for k in (3, 2) * 3]


def test_labelled_frames_far_from_labels_are_skipped(tiny):
    folder, _, detector, _ = tiny
    ann = _ann({0: {"cars": [[64, 0, 128, 64]]}})
    mined = mine_negatives([MiningSource(folder, ann)], detector, MiningOptions(dedupe_iou=1.01))
    assert mined.windows.frame.tolist() == [0, 0, 0]  # frames 1 and 2 lie after the last label
    assert mined.stats["frames"]["skipped_frames"] == 2


@needs_images
def test_mined_patches_reproduce_the_margins_of_the_real_search(default_model, test_frames):
    """Exactly with windows seen as their crops; with the frame's gradient across the window
    border (the default), the patches' margins differ only by their border cells."""
    from dataclasses import replace

    frame = test_frames[0]
    for border, tol in (("crop", 1e-6), ("frame", 0.5)):
        plan = replace(default_model.detector_config.plan, window_border=border)
        wins = search(frame, default_model, plan, all_windows=True)
        pick = wins[np.r_[0:5, len(wins) - 5 : len(wins)]]  # left and right edges: mirrored overhang
        patches = window_patches(frame, pick, default_model, plan)
        np.testing.assert_allclose(default_model.decision_images(patches), pick.score, atol=tol)


# --------------------------------------------------------------------------------------------
# Writing, and loading as extra negatives
# --------------------------------------------------------------------------------------------
def _mined(n: int, stem="clip", seed=0, frames=None) -> MinedNegatives:
    rng = np.random.default_rng(seed)
    frames = list(range(n)) if frames is None else frames
    wins = Detections(
        [[8 * i, 0, 8 * i + 64, 64] for i in range(n)], score=np.ones(n), frame=frames,
        data={"scale_index": np.zeros(n, np.int64)},
    )  # fmt: skip
    return MinedNegatives(rng.integers(0, 256, (n, 64, 64, 3), dtype=np.uint8), wins, np.array([stem] * n))


def test_write_negatives_is_atomic_and_refuses_to_overwrite(tmp_path):
    mined = _mined(3)
    out = write_negatives(mined, tmp_path / "neg", "Hard")
    assert out == tmp_path / "neg" / "non-vehicles" / "Hard"
    files = sorted(out.iterdir())
    assert [f.name for f in files] == sorted(mined.file_names())
    for name, patch in zip(mined.file_names(), mined.patches):
        np.testing.assert_array_equal(read_image(out / name), patch)  # lossless
    with pytest.raises(OutputError, match="output exists"):
        write_negatives(_mined(1, seed=1), tmp_path / "neg", "Hard")
    assert sorted(out.iterdir()) == files
    write_negatives(_mined(1, stem="other", seed=1), tmp_path / "neg", "Hard", overwrite=True)
    assert [f.name for f in out.iterdir()] == ["other__f000000__s0_0_0_64_64.png"]
    assert sorted(p.name for p in out.parent.iterdir()) == ["Hard"]  # no .partial left behind
    with pytest.raises(OutputError, match="folder name"):
        write_negatives(mined, tmp_path / "neg", "../up")
    with pytest.raises(OutputError, match="inside the input"):
        write_negatives(mined, tmp_path / "neg", "X", inputs=[tmp_path / "neg" / "non-vehicles" / "X" / "a.mp4"])


def _png(seed: int) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(np.random.default_rng(seed).integers(0, 256, (64, 64, 3), dtype=np.uint8)).save(buf, format="PNG")
    return buf.getvalue()


def _fake_archives(root: Path) -> Path:
    root.mkdir(parents=True)
    for cls, start in (("vehicles", 0), ("non-vehicles", 100)):
        with zipfile.ZipFile(root / f"{cls}.zip", "w") as zf:
            for k in range(12):
                zf.writestr(f"{cls}/A/image{k:04d}.png", _png(start + k))
    return root


def test_extra_negatives_load_with_their_own_groups(tmp_path):
    data = _fake_archives(tmp_path / "data")
    base = load_dataset(data, track_length=10)
    extra = tmp_path / "mined"
    # Mined from two inputs: frames 0..14 of "clip" (two blocks of 10 frames) and frame 3 of "other".
    write_negatives(_mined(15, "clip", seed=1000), extra, "Hard")
    write_negatives(_mined(1, "other", seed=1001, frames=[3]), extra, "Hard2")
    # A folder of plain PNGs, and a half-written folder that must be skipped.
    plain = tmp_path / "plain"
    plain.mkdir()
    for k in (1, 2, 15):
        (plain / f"x{k}.png").write_bytes(_png(200 + k))
    (extra / "non-vehicles" / ".Hard3.abcd.partial").mkdir()
    (extra / "non-vehicles" / ".Hard3.abcd.partial" / "clip__f000001__s0_0_0_64_64.png").write_bytes(_png(300))

    ds = load_dataset(data, track_length=10, extra_negatives=[extra, plain])
    n = len(base)
    assert len(ds) == n + 15 + 1 + 3
    np.testing.assert_array_equal(ds.groups[:n], base.groups)  # the archives' groups do not change
    np.testing.assert_array_equal(ds.images[:n], base.images)
    assert ds.labels[n:].tolist() == [0] * 19
    assert ds.counts()["non-vehicles/Hard"] == 15 and ds.counts()["non-vehicles/Hard2"] == 1
    assert ds.counts()["non-vehicles/plain"] == 3
    g = ds.groups[n:]
    assert not set(g.tolist()) & set(base.groups.tolist())
    # clip frames 0-9 | clip frames 10-14 | other | plain x1, x2 | plain x15
    expected = [0] * 10 + [1] * 5 + [2] + [3, 3, 4]
    for i in range(len(g)):
        for j in range(len(g)):
            assert (g[i] == g[j]) == (expected[i] == expected[j]), (ds.names[n + i], ds.names[n + j])
    assert ds.names[n] == "non-vehicles/Hard/clip__f000000__s0_0_0_64_64.png"


def test_extra_negatives_refusals(tmp_path):
    data = _fake_archives(tmp_path / "data")
    clash = tmp_path / "clash" / "non-vehicles" / "A"  # the archives' own folder name
    clash.mkdir(parents=True)
    (clash / "x.png").write_bytes(_png(1))
    with pytest.raises(InputError, match="name of a folder of the training archives"):
        load_dataset(data, extra_negatives=[tmp_path / "clash"])
    with pytest.raises(InputError, match="extra negatives folder not found"):
        load_dataset(data, extra_negatives=[tmp_path / "nowhere"])
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="no PNG images"):
        load_dataset(data, extra_negatives=[tmp_path / "empty"])
    cars = tmp_path / "cars" / "vehicles" / "B"
    cars.mkdir(parents=True)
    (cars / "x.png").write_bytes(_png(2))
    with pytest.raises(InputError, match="may not hold a vehicles/ folder"):
        load_dataset(data, extra_negatives=[tmp_path / "cars"])


# --------------------------------------------------------------------------------------------
# The command line
# --------------------------------------------------------------------------------------------
@needs_images
def test_cli_mine_negatives_writes_and_refuses_to_overwrite(tmp_path, capsys):
    folder = tmp_path / "imgs"
    folder.mkdir()
    shutil.copy(TEST_IMAGES / "test1.jpg", folder / "test1.jpg")
    labels = tmp_path / "labels.json"
    labels.write_text(json.dumps({"video": "imgs", "frames": {"0": {"cars": [], "ignore": []}}}))
    out = tmp_path / "out"
    argv = ["mine-negatives", "--labels", str(labels), "--out", str(out), "--name", "HN", "--no-progress", "--json"]
    assert main(argv) == 0
    report = json.loads(capsys.readouterr().out)  # stdout: the JSON object alone
    folder_out = out / "non-vehicles" / "HN"
    files = sorted(folder_out.iterdir())
    assert report["mined"] == len(files) > 0 and report["folder"] == str(folder_out)
    assert all(f.name.startswith("imgs__f000000__s") for f in files)
    before = {f.name: f.read_bytes() for f in files}

    assert main(argv) == 5  # exists: refused before any work, nothing touched
    assert "output exists; pass --overwrite" in capsys.readouterr().err
    assert {f.name: f.read_bytes() for f in folder_out.iterdir()} == before
    # An unlabelled input needs a negative region; a region restricts the windows to it.
    assert main(["mine-negatives", str(folder), "--out", str(out), "--name", "R", "--no-progress"]) == 2
    assert "give --negative-region" in capsys.readouterr().err
    region = ["--negative-region", "640,0,1280,720"]
    assert main(["mine-negatives", str(folder), "--out", str(out), "--name", "R", *region, "--no-progress"]) == 0
    mined = list((out / "non-vehicles" / "R").iterdir())
    assert mined and all(int(f.stem.split("_")[-4]) >= 640 for f in mined)
    assert main(["mine-negatives", str(folder), "--out", str(folder), "--name", "X", *region]) == 5  # inside the input
    assert main(["mine-negatives", "--labels", str(labels), "--out", str(out), "--frames", "3-1"]) == 2


@needs_archives
def test_cli_train_with_extra_negatives(tmp_path, capsys):
    data = small_archives(tmp_path / "data", 100)
    extra = tmp_path / "mined"
    write_negatives(_mined(20), extra, "HardNegatives")
    model = tmp_path / "m.npz"
    argv = ["train", "--data-dir", str(data), "--extra-negatives", str(extra), "--model", str(model), "--json"]
    assert main(argv) == 0
    captured = capsys.readouterr()
    assert "images: 220 (" in captured.err and "non-vehicles/HardNegatives 20" in captured.err
    assert json.loads(captured.out)["n_images"] == 220
    assert VehicleClassifier.load(model).metrics["extra_negatives"] == {"non-vehicles/HardNegatives": 20}


def test_labels_of_an_image_folder_must_name_its_images(tiny):
    folder, _, detector, _ = tiny
    ann = _ann({0: {"cars": [], "file": "f0.png"}, 1: {"cars": [], "file": "f2.png"}})
    with pytest.raises(InputError, match="frame 1 is labelled as f2.png, but image 1 of .* is f1.png"):
        mine_negatives([MiningSource(folder, ann)], detector)


def test_the_earlier_keywords_of_mine_negatives_still_work(tmp_path):
    """``mine_negatives(..., every=2, dedupe_iou=...)`` gives what ``MiningOptions`` gives, with a warning."""
    folder = tmp_path / "shots"
    folder.mkdir()
    shutil.copyfile(TEST_IMAGES / "test1.jpg", folder / "a.jpg")
    regions = [[0, 0, 1280, 720]]
    new = mine_negatives([MiningSource(folder)], None, MiningOptions(negative_regions=regions, dedupe_iou=1.01))
    with pytest.warns(DeprecationWarning, match="mine_negatives"):
        old = mine_negatives([MiningSource(folder)], None, negative_regions=regions, dedupe_iou=1.01)
    assert old.stats == new.stats and np.array_equal(old.patches, new.patches)
    with pytest.raises(ValueError, match="every"):
        MiningOptions(every=0)
