"""The ``vehicle-detection`` command: help, exit codes, one-line errors, outputs, JSON reports.

Error paths run through ``main([...])`` in this process, stderr captured, one case after another:
the exit code ``main`` returns (or argparse's ``SystemExit``) and the one line it prints. One case
of each exit code and the installed console script also run as real subprocesses (``python -m
vehicle_detection.cli``; the console script's run is the missing input's), so that the exit status
and the exact stderr are what a shell sees, and both ways must agree. (``--debug`` changes what
``main`` prints, not how a process exits: it runs through ``main``.) Successful runs go through ``main([...])`` too.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import pickle
import re
import shutil
import subprocess
import sys
import zipfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np
import pytest

from conftest import small_archives
from PIL import Image

import media
from vehicle_detection.io.tables import BOXES_CSV_HEADER, read_boxes_csv
from vehicle_detection.cli import main
from vehicle_detection.classifier import default_model_path
from vehicle_detection.refine import REFINE_ALPHA
from vehicle_detection.io.images import read_image
from vehicle_detection.io.video import probe_video, read_frames

REPO = Path(__file__).resolve().parents[1]
TEST_VIDEO = REPO / "test_video.mp4"
TEST_IMAGES = REPO / "test_images"
SHARED = Path(os.environ.get("VEHICLE_DETECTION_DATA") or REPO.parent / "shared" / "data")
ERROR_PREFIX = "vehicle-detection: error: "

needs_media = pytest.mark.skipif(
    not (TEST_VIDEO.is_file() and (TEST_IMAGES / "test1.jpg").is_file()),
    reason="test_video.mp4 or test_images/ not in the checkout",
)
needs_archives = pytest.mark.skipif(
    not ((SHARED / "vehicles.zip").is_file() and (SHARED / "non-vehicles.zip").is_file()),
    reason=f"training archives not found in {SHARED} (set VEHICLE_DETECTION_DATA)",
)


def sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def cut_video(src: Path, dest: Path, frames: int) -> Path:
    return media.copy_packets(src, dest, max_frames=frames)


def run_cli(*args: str, cwd: Path | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "vehicle_detection.cli", *args], capture_output=True, text=True, cwd=cwd, timeout=300
    )


def last_json(stdout: str) -> dict:
    """With ``--json``, stdout is one JSON object and nothing else (the human lines go to stderr)."""
    doc = json.loads(stdout)
    assert isinstance(doc, dict)
    return doc


def csv_rows(path: Path) -> list[str]:
    lines = path.read_text().splitlines()
    assert lines[0] == BOXES_CSV_HEADER == "frame,x1,y1,x2,y2,track_id,score"
    return lines[1:]


# ----------------------------------------------------------------------------------------------
# --help
# ----------------------------------------------------------------------------------------------

OPTIONS = {
    None: ["--version", "download", "train", "refine", "sweep", "detect", "evaluate", "mine-negatives", "Exit codes", "2 usage", "3 bad input",
           "4 bad model", "5 output refused"],
    "download": ["--data-dir", "--no-progress", "--debug"],
    "train": ["--data-dir", "--model", "--C", "--drop-duplicates", "--extra-negatives", "--seed", "--traffic", "--json", "--overwrite", "--color-space",
              "--hog-channels", "--orientations", "--pixels-per-cell", "--cells-per-block", "--spatial-size",
              "--hist-bins", "--debug"],
    "refine": ["--labels", "--out", "--model", "--alpha", "--mirror", "--traffic", "--json", "--overwrite", "--debug"],
    "sweep": ["--data-dir", "--color-spaces", "--hog-channels", "--orientations", "--pixels-per-cell",
              "--cells-per-block", "--color-features", "--subsample", "--jobs", "--json", "--debug"],
    "detect": ["input", "--out", "--boxes", "--model", "--traffic", "--overwrite", "--no-progress", "--debug"],
    "evaluate": ["--video", "--labels", "--model", "--traffic", "--json", "--report", "--overwrite", "--no-progress", "--debug"],
    "mine-negatives": ["INPUT", "--labels", "--out", "--name", "--model", "--traffic", "--frames", "--every", "--threshold",
                       "--negative-region", "--max-gap", "--max-iou", "--max-car-cover", "--dedupe-iou", "--dedupe-frames",
                       "--overwrite", "--json", "--no-progress", "--debug"],
}  # fmt: skip


@pytest.mark.parametrize("command", list(OPTIONS), ids=lambda c: c or "top-level")
def test_help_exits_0_and_lists_the_options(command, capsys):
    argv = [command, "--help"] if command else ["--help"]
    with pytest.raises(SystemExit) as info:
        main(argv)
    assert info.value.code == 0
    out = " ".join(capsys.readouterr().out.split())  # argparse wraps lines
    assert out.startswith(f"usage: vehicle-detection{' ' + command if command else ''} ")
    for option in OPTIONS[command]:
        assert option in out, (option, out)


# ----------------------------------------------------------------------------------------------
# Error paths: exact exit code, exactly one line on stderr, no traceback (in subprocesses)
# ----------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    """Inputs for the error cases (the media ones only when the checkout has them)."""
    d = tmp_path_factory.mktemp("cli_inputs")
    f = {"dir": d}
    (d / "fake.png").write_text("not a picture\n")
    (d / "notes.txt").write_text("hello\n")
    (d / "empty.mp4").write_bytes(b"")
    (d / "bad.json").write_text('{"frames": {"0": {"cars": [[1, 2, 3]]')
    (d / "empty_labels.json").write_text('{"frames": {}}')
    (d / "far.json").write_text('{"frames": {"0": {"cars": []}, "20": {"cars": [[0, 0, 10, 10]]}}}')
    (d / "no_cars.json").write_text(json.dumps({"video": str(TEST_VIDEO), "frames": {"0": {"cars": [], "ignore": []}}}))
    (d / "a_file").write_text("I am a file, not a folder\n")
    model = default_model_path().read_bytes()
    (d / "model.npz").write_bytes(model)
    tampered = bytearray(model)
    tampered[len(tampered) // 2] ^= 0xFF  # one flipped byte inside the weights
    (d / "tampered.npz").write_bytes(bytes(tampered))
    (d / "evil.npz").write_bytes(pickle.dumps(_Payload()))  # would create EXECUTED if unpickled
    data = d / "data"
    data.mkdir()
    for cls in ("vehicles", "non-vehicles"):
        with zipfile.ZipFile(data / f"{cls}.zip", "w") as zf:
            zf.writestr(f"{cls}/readme.txt", "placeholder archive")
    if TEST_VIDEO.is_file() and (TEST_IMAGES / "test1.jpg").is_file():
        shutil.copy(TEST_IMAGES / "test1.jpg", d / "street.jpg")
        shutil.copy(TEST_IMAGES / "test1.jpg", d / "existing.png")
        cut_video(TEST_VIDEO, d / "clip.mp4", 4)
        cut_video(TEST_VIDEO, d / "clip8.mp4", 8)
        video = TEST_VIDEO.read_bytes()
        (d / "cut.mp4").write_bytes(video[: len(video) // 4])
        (d / "mixed").mkdir()
        shutil.copy(TEST_IMAGES / "test1.jpg", d / "mixed" / "a.jpg")
        (d / "mixed" / "b.png").write_text("not a picture either\n")
    return f | {p.name: p for p in d.iterdir()}


class _Payload:
    def __reduce__(self):
        return (os.system, ("touch EXECUTED",))


# name: (argv (paths relative to the inputs folder), exit code, fragments of the message, files that
# must stay byte-identical, needs the media files)
CASES = {
    # 2: usage
    "no-command": ([], 2, ["the following arguments are required: COMMAND"], [], False),
    "unknown-option": (["detect", "street.jpg", "--bogus"], 2, ["unrecognized arguments: --bogus"], [], False),
    "missing-argument": (["detect"], 2, ["the following arguments are required: INPUT", "vehicle-detection detect --help"], [], False),
    "bad-number": (["train", "--C", "-1"], 2, ["argument --C: expected a finite number > 0, got '-1'"], [], False),
    "bad-jobs": (["sweep", "--jobs", "0"], 2, ["argument --jobs: expected a whole number >= 1, got '0'"], [], False),
    "bad-augment": (["train", "--augment", "-1"], 2, ["argument --augment: expected a whole number from 0 to 8, got '-1'"], [], False),
    "augment-not-a-number": (["train", "--augment", "two"], 2, ["argument --augment: expected a whole number from 0 to 8, got 'two'"], [], False),
    "bad-horizon": (["detect", "street.jpg", "--horizon", "sky"], 2,
                    ["argument --horizon: expected a fraction in [0, 1), 'auto' or 'plan', got 'sky'"], [], False),
    # 3: bad input
    "missing-input": (["detect", "nothere.png"], 3, ["nothere.png: no such file or folder"], [], False),
    "unknown-type": (["detect", "notes.txt"], 3, ["notes.txt: unknown file type '.txt'"], ["notes.txt"], False),
    "text-as-png": (["detect", "fake.png"], 3, ["fake.png: not an image"], ["fake.png"], False),
    "corrupt-image-in-folder": (["detect", "mixed"], 3, ["mixed/b.png: not an image"], ["mixed/a.jpg"], True),
    "empty-video": (["detect", "empty.mp4"], 3, ["empty.mp4: file is empty"], [], False),
    "truncated-video": (["detect", "cut.mp4"], 3, ["cut.mp4: video is damaged or truncated"], ["cut.mp4"], True),
    "bad-labels": (["evaluate", "--video", "clip8.mp4", "--labels", "bad.json"], 3, ["bad.json: invalid JSON"], [], True),
    "no-labels": (["evaluate", "--video", "clip8.mp4", "--labels", "empty_labels.json"], 3,
                  ["empty_labels.json: no labelled frames"], [], True),
    "labels-beyond-video": (["evaluate", "--video", "clip8.mp4", "--labels", "far.json"], 3,
                            ["far.json: labels frame(s) 20, but clip8.mp4 has only 8 decoded frames"], [], True),
    "missing-data": (["train", "--data-dir", "nowhere"], 3, ["nowhere: data folder not found"], [], False),
    "refine-no-cars": (["refine", "--labels", "no_cars.json", "--out", "refined.npz"], 3,
                       ["no_cars.json: no labelled cars to fit the box refinement on"], [], False),
    # 4: bad model
    "missing-model": (["detect", "street.jpg", "--model", "gone.npz"], 4, ["gone.npz: model file not found"], [], True),
    "tampered-model": (["detect", "street.jpg", "--model", "tampered.npz"], 4, ["tampered.npz: unreadable model file"], ["street.jpg"], True),
    "pickled-model": (["detect", "street.jpg", "--model", "evil.npz"], 4, ["evil.npz: unreadable model file"], [], True),
    "refine-tampered-base": (["refine", "--labels", "no_cars.json", "--model", "tampered.npz", "--out", "refined.npz"], 4,
                             ["tampered.npz: unreadable model file"], ["tampered.npz"], False),
    # 5: output refused
    "out-is-input-overwrite": (["detect", "street.jpg", "--out", "sub/../street.jpg", "--overwrite"], 5,
                               ["output would overwrite the input"], ["street.jpg"], True),
    "video-out-is-input": (["detect", "clip.mp4", "--out", "clip.mp4", "--overwrite"], 5,
                           ["clip.mp4: output would overwrite the input"], ["clip.mp4"], True),
    "boxes-is-input": (["detect", "clip.mp4", "--out", "v.mp4", "--boxes", "clip.mp4", "--overwrite"], 5,
                       ["clip.mp4: output would overwrite the input"], ["clip.mp4"], True),
    "boxes-is-model": (["detect", "street.jpg", "--out", "m.png", "--model", "model.npz", "--boxes", "model.npz",
                        "--overwrite"], 5, ["model.npz: output would overwrite the input"], ["model.npz"], True),
    "refine-over-base": (["refine", "--labels", "no_cars.json", "--model", "model.npz", "--out", "model.npz", "--overwrite"], 5,
                         ["model.npz: output would overwrite the input"], ["model.npz"], False),
    "refine-over-labels": (["refine", "--labels", "no_cars.json", "--out", "no_cars.json", "--overwrite"], 5,
                           ["no_cars.json: output would overwrite the input"], ["no_cars.json"], False),
    "model-over-archive": (["train", "--data-dir", "data", "--model", "data/vehicles.zip", "--overwrite"], 5,
                           ["vehicles.zip: output would overwrite the input"], ["data/vehicles.zip"], False),
    "out-exists": (["detect", "street.jpg", "--out", "existing.png"], 5, ["existing.png: output exists; pass --overwrite"],
                   ["existing.png"], True),
    "out-is-boxes": (["detect", "street.jpg", "--out", "same.png", "--boxes", "same.png"], 5,
                     ["same.png: the annotated output and the boxes CSV cannot be the same file"], [], True),
    "unknown-out-extension": (["detect", "street.jpg", "--out", "x.xyz"], 5, ["x.xyz: unknown image extension '.xyz'"],
                              [], True),
    "out-below-a-file": (["detect", "street.jpg", "--out", "a_file/x.png"], 5, ["a_file/x.png: cannot write output here: a_file is a file, not a folder"],
                         ["a_file"], True),
}  # fmt: skip


#: The cases that also run as real subprocesses: one of each exit code.
SUBPROCESS_CASES = ("unknown-option", "missing-input", "tampered-model", "out-exists")


def run_in_process(argv: list[str], cwd: Path) -> subprocess.CompletedProcess:
    """``main(argv)`` in this process, from ``cwd``: its exit code and what it printed."""
    out, err = io.StringIO(), io.StringIO()
    previous = Path.cwd()
    os.chdir(cwd)
    try:
        with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
            try:
                code = main(argv)
            except SystemExit as exc:  # argparse's usage errors
                code = exc.code
    finally:
        os.chdir(previous)
    return subprocess.CompletedProcess(["main", *argv], code, out.getvalue(), err.getvalue())


@pytest.fixture(scope="module")
def error_runs(files):
    """Run every case through ``main`` (and a few as subprocesses too, 4 at a time); record the
    outcome and the protected hashes."""
    d = files["dir"]
    runnable = {n: c for n, c in CASES.items() if not c[4] or (d / "street.jpg").exists()}
    before = {n: {p: sha256(d / p) for p in c[3]} for n, c in runnable.items()}
    listing = sorted(p.name for p in d.iterdir())
    results = {n: run_in_process(c[0], d) for n, c in runnable.items()}
    results["--debug"] = run_in_process(["detect", "nothere.png", "--debug"], d)
    exe = shutil.which("vehicle-detection")
    with ThreadPoolExecutor(max_workers=4) as pool:
        futures = {}
        if exe:  # its run is missing-input's real process too (the same argv): one process less
            assert CASES["missing-input"][0] == ["detect", "nothere.png"]
            futures["console-script"] = futures["subprocess:missing-input"] = pool.submit(
                subprocess.run, [exe, "detect", "nothere.png"], capture_output=True, text=True, cwd=d, timeout=300
            )
        for n in SUBPROCESS_CASES:
            if n in runnable and f"subprocess:{n}" not in futures:
                futures[f"subprocess:{n}"] = pool.submit(run_cli, *runnable[n][0], cwd=d)
        results |= {n: f.result() for n, f in futures.items()}
    after = {n: {p: sha256(d / p) for p in c[3]} for n, c in runnable.items()}
    return results, before, after, listing, sorted(p.name for p in d.iterdir())


@pytest.mark.xdist_group("cli-error-runs")  # one worker makes every case's run, once
@pytest.mark.parametrize("name", list(CASES))
def test_error_path(name, error_runs, files):
    results, before, after, _, _ = error_runs
    if name not in results:
        pytest.skip("test_video.mp4 or test_images/ not in the checkout")
    argv, code, fragments, _, _ = CASES[name]
    proc = results[name]
    lines = proc.stderr.splitlines()
    assert len(lines) == 1, proc.stderr  # exactly one line, no traceback
    assert lines[0].startswith(ERROR_PREFIX), lines[0]
    for fragment in fragments:
        assert fragment in lines[0], (fragment, lines[0])
    assert proc.returncode == code, (proc.returncode, lines[0])
    assert before[name] == after[name]  # inputs and refused outputs are byte-identical


@pytest.mark.xdist_group("cli-error-runs")
@pytest.mark.parametrize("name", SUBPROCESS_CASES)
def test_a_real_process_exits_as_main_returns(name, error_runs):
    results = error_runs[0]
    if name not in results:
        pytest.skip("test_video.mp4 or test_images/ not in the checkout")
    proc, in_process = results[f"subprocess:{name}"], results[name]
    assert proc.stderr.splitlines() == in_process.stderr.splitlines() and len(proc.stderr.splitlines()) == 1, proc.stderr
    assert proc.returncode == in_process.returncode == CASES[name][1]


@pytest.mark.xdist_group("cli-error-runs")  # the same worker as the cases: the runs are made once
def test_errors_leave_no_outputs(error_runs):
    *_, listing_before, listing_after = error_runs
    assert listing_after == listing_before  # nothing created: no output, no .partial, no EXECUTED


@pytest.mark.xdist_group("cli-error-runs")
def test_debug_shows_the_traceback_and_keeps_the_exit_code(error_runs):
    proc = error_runs[0]["--debug"]
    assert proc.stderr.startswith("Traceback (most recent call last):")
    assert "InputError" in proc.stderr
    assert proc.stderr.splitlines()[-1] == f"{ERROR_PREFIX}nothere.png: no such file or folder"
    assert proc.returncode == 3


@pytest.mark.xdist_group("cli-error-runs")
def test_installed_console_script(error_runs):
    if "console-script" not in error_runs[0]:
        pytest.skip("the vehicle-detection script is not on PATH")
    proc = error_runs[0]["console-script"]
    assert proc.stderr.splitlines() == [f"{ERROR_PREFIX}nothere.png: no such file or folder"]
    assert proc.returncode == 3


def test_interrupted_message_is_one_line(monkeypatch, capsys):
    import vehicle_detection.cli.detect as detect

    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setattr(detect, "run", interrupted)
    assert main(["detect", "x.png"]) == 130
    assert capsys.readouterr().err.splitlines() == ["vehicle-detection: interrupted"]


# ----------------------------------------------------------------------------------------------
# detect: image, folder, video
# ----------------------------------------------------------------------------------------------


def _api_detect(path: Path):
    from vehicle_detection.detector import Detector

    det = Detector().detect_image(read_image(path))
    return [(b.tolist(), round(float(s), 4)) for b, s in zip(det.xyxy, det.score)]


def _table_rows(table, frame):
    keep = table.frame == frame
    return [(b.tolist(), round(float(s), 4)) for b, s in zip(table.xyxy[keep], table.score[keep])]


def test_detect_traffic_left_boxes_a_flipped_picture_where_right_boxes_the_picture(tmp_path):
    import cv2

    from vehicle_detection.geometry import mirror_boxes

    picture = read_image(TEST_IMAGES / "test1.jpg")
    as_is, flipped = tmp_path / "as_is.png", tmp_path / "flipped.png"  # lossless: the same pixels, flipped
    cv2.imwrite(str(as_is), np.ascontiguousarray(picture[:, :, ::-1]))
    cv2.imwrite(str(flipped), np.ascontiguousarray(picture[:, ::-1, ::-1]))
    assert main(["detect", str(as_is), "--boxes", str(tmp_path / "a.csv"), "--no-video"]) == 0
    assert main(["detect", str(flipped), "--traffic", "left", "--boxes", str(tmp_path / "b.csv"), "--no-video"]) == 0
    a, b = read_boxes_csv(tmp_path / "a.csv"), read_boxes_csv(tmp_path / "b.csv")
    assert len(a) == 2
    assert sorted(a.xyxy.tolist()) == sorted(mirror_boxes(b.xyxy, picture.shape[1]).tolist())


@needs_media
def test_detect_image_writes_next_to_the_input(tmp_path, capsys):
    img = tmp_path / "street.jpg"
    shutil.copy(TEST_IMAGES / "test1.jpg", img)
    before = sha256(img)
    assert main(["detect", str(img)]) == 0
    out, boxes = tmp_path / "street_detected.jpg", tmp_path / "street_boxes.csv"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([img.name, out.name, boxes.name])
    assert sha256(img) == before
    assert read_image(out).shape == read_image(img).shape
    table = read_boxes_csv(boxes)
    assert len(csv_rows(boxes)) == len(table)
    assert set(table.frame.tolist()) <= {0} and table.track_id is None
    assert _table_rows(table, 0) == _api_detect(img)
    n = len(table)
    assert capsys.readouterr().out.splitlines()[0].startswith(f"{img}: 1 image, {n} {'box' if n == 1 else 'boxes'}, ")
    drawn = read_image(out).astype(int)
    for x1, y1, x2, _ in table.xyxy:  # the top edge of each box is drawn green
        r, g, b = drawn[y1 + 1, (x1 + x2) // 2]
        assert g > 180 and r < 100 and b < 100


@needs_media
def test_detect_folder_frames_are_sorted_positions(tmp_path):
    folder = tmp_path / "shots"
    folder.mkdir()
    shutil.copy(TEST_IMAGES / "test1.jpg", folder / "b_street.jpg")
    Image.fromarray(np.full((720, 1280), 90, np.uint8)).save(folder / "a_grey.png")  # grayscale
    shutil.copy(TEST_IMAGES / "test4.jpg", folder / "c_street.JPG")
    (folder / "notes.txt").write_text("not an image: skipped")
    before = {p.name: sha256(p) for p in folder.iterdir()}
    assert main(["detect", str(folder)]) == 0
    out = tmp_path / "shots_detected"
    assert sorted(p.name for p in out.iterdir()) == ["a_grey.png", "b_street.jpg", "boxes.csv", "c_street.JPG"]
    assert {p.name: sha256(p) for p in folder.iterdir()} == before
    table = read_boxes_csv(out / "boxes.csv")
    assert set(table.frame.tolist()) <= {0, 1, 2}
    for i, name in enumerate(["a_grey.png", "b_street.jpg", "c_street.JPG"]):
        assert _table_rows(table, i) == _api_detect(folder / name), name


@needs_media
def test_detect_out_in_a_missing_folder_creates_it(tmp_path):
    img = tmp_path / "street.jpg"
    shutil.copy(TEST_IMAGES / "test1.jpg", img)
    out, boxes = tmp_path / "new" / "deeper" / "x.png", tmp_path / "other" / "b.csv"
    assert main(["detect", str(img), "--out", str(out), "--boxes", str(boxes)]) == 0
    assert read_image(out).shape == (720, 1280, 3)
    csv_rows(boxes)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["new", "other", "street.jpg"]


def test_detect_current_folder(tmp_path, monkeypatch):
    # "." has no name of its own: the outputs are named after the real folder, beside it.
    shots = tmp_path / "shots"
    shots.mkdir()
    Image.fromarray(np.full((72, 128, 3), 90, np.uint8)).save(shots / "grey.png")
    monkeypatch.chdir(shots)
    assert main(["detect", "."]) == 0
    assert sorted(p.name for p in (tmp_path / "shots_detected").iterdir()) == ["boxes.csv", "grey.png"]
    assert sorted(p.name for p in shots.iterdir()) == ["grey.png"]


@pytest.fixture(scope="module")
def detected_clip(tmp_path_factory):
    """``detect clip4.mp4`` (4 frames, both cars boxed in each) with default outputs, run once in this process."""
    if not TEST_VIDEO.is_file():
        pytest.skip("test_video.mp4 not in the checkout")
    d = tmp_path_factory.mktemp("clip")
    clip = cut_video(TEST_VIDEO, d / "clip4.mp4", 4)
    before = sha256(clip)
    assert main(["detect", str(clip), "--no-progress", "--out-dir", str(d)]) == 0
    return clip, before


def test_detect_video_outputs(detected_clip):
    clip, before = detected_clip
    out, boxes = clip.with_name("clip4_detected.mp4"), clip.with_name("clip4_boxes.csv")
    assert sorted(p.name for p in clip.parent.iterdir()) == sorted([clip.name, out.name, boxes.name])
    assert sha256(clip) == before
    n_decoded = sum(1 for _ in read_frames(clip))
    info = probe_video(out)
    assert info.size == probe_video(clip).size
    assert sum(1 for _ in read_frames(out)) == n_decoded == 4
    rows = csv_rows(boxes)
    table = read_boxes_csv(boxes)
    assert len(rows) == len(table) > 0
    assert all(0 <= f < n_decoded for f in table.frame.tolist())
    assert np.all(table.track_id >= 0)


def test_detect_video_second_run_needs_overwrite(detected_clip):
    clip, before = detected_clip
    out, boxes = clip.with_name("clip4_detected.mp4"), clip.with_name("clip4_boxes.csv")
    outputs = {p: (sha256(p), p.stat().st_ino) for p in (out, boxes)}
    # in this process (a real process's exit 5 is test_a_real_process_exits_as_main_returns's)
    proc = run_in_process(["detect", str(clip), "--no-progress", "--out-dir", str(clip.parent)], clip.parent)
    assert proc.returncode == 5
    assert proc.stderr.splitlines() == [f"{ERROR_PREFIX}{out}: output exists; pass --overwrite to replace it"]
    assert {p: (sha256(p), p.stat().st_ino) for p in (out, boxes)} == outputs
    assert main(["detect", str(clip), "--no-progress", "--overwrite", "--out-dir", str(clip.parent)]) == 0
    for p, (_, inode) in outputs.items():
        assert p.stat().st_ino != inode  # replaced by a new, complete file
    assert sha256(clip) == before
    assert not list(clip.parent.glob(".*.partial"))
    # An --out in a folder that does not exist yet: created.
    out2, boxes2 = clip.parent / "new" / "deeper" / "v.mp4", clip.parent / "other" / "v.csv"
    assert main(["detect", str(clip), "--no-progress", "--out", str(out2), "--boxes", str(boxes2)]) == 0
    assert probe_video(out2).n_frames == 4
    assert read_boxes_csv(boxes2).frame.tolist() == read_boxes_csv(boxes).frame.tolist()


@pytest.mark.parametrize("suffix", [".m2ts", ".ts"])
def test_detect_mpeg_ts_video(tmp_path, capsys, suffix):
    # MPEG-2 in MPEG-TS (as camcorders and broadcast recordings write it) is a video input too.
    n = 3  # each frame is searched at 1280x720: a few are enough
    clip = media.encode(tmp_path / f"cam{suffix}", media.moving_square_frames(n, 320, 180), codec="mpeg2video",
                        format="mpegts", container_options={"mpegts_m2ts_mode": "1"} if suffix == ".m2ts" else {})  # fmt: skip
    assert main(["detect", str(clip), "--no-progress"]) == 0
    out, boxes = Path("cam_detected.mp4"), Path("cam_boxes.csv")  # in the current folder, tmp_path
    assert capsys.readouterr().out.splitlines()[0].endswith(f"; wrote {out}, {boxes}")
    assert probe_video(out).size == (320, 180)
    assert sum(1 for _ in read_frames(out)) == n
    assert all(0 <= f < n for f in read_boxes_csv(boxes).frame.tolist())


def test_readme_documents_the_exit_codes():
    from vehicle_detection.errors import DownloadError, InputError, ModelError, OutputError

    readme = REPO / "README.md"
    assert readme.is_file(), "README.md is missing (pyproject.toml names it as the project's readme)"
    text = " ".join(readme.read_text().split())
    found = re.search(r"exit codes\W+(.{0,1200})", text, re.IGNORECASE)
    assert found, "README.md has no 'Exit codes' paragraph"
    paragraph = found.group(1).lower()
    documented = {2: "usage|command line", InputError.exit_code: "input", ModelError.exit_code: "model",
                  OutputError.exit_code: "output", DownloadError.exit_code: "download", 130: "interrupt"}  # fmt: skip
    assert sorted(documented) == [2, 3, 4, 5, 6, 130]
    for code, meaning in documented.items():
        assert re.search(rf"\b{code}\b[^;]*?({meaning})", paragraph), (code, paragraph)


# ----------------------------------------------------------------------------------------------
# train --json and evaluate --json
# ----------------------------------------------------------------------------------------------


def still_labels(folder: Path, frames: tuple[str, ...]) -> Path:
    """Those frames of ``dev_set/test_images.json`` (six labelled stills, nine cars) in a labels file of ``folder``."""
    doc = json.loads((REPO / "dev_set" / "test_images.json").read_text())
    doc["video"], doc["frames"] = str((REPO / "dev_set" / doc["video"]).resolve()), {k: doc["frames"][k] for k in frames}
    path = folder / f"stills_{'_'.join(frames)}.json"
    path.write_text(json.dumps(doc))
    return path


@pytest.fixture(scope="module")
def small_data(tmp_path_factory) -> Path:
    """60 patches of each class from the shared archives (read only by the runs: one folder for every train test)."""
    return small_archives(tmp_path_factory.mktemp("data"), 60)


@needs_archives
def test_train_json_on_a_small_data_folder(small_data, tmp_path, capsys):
    data = small_data
    model = tmp_path / "m.npz"
    assert main(["train", "--data-dir", str(data), "--json", "--model", str(model)]) == 0
    report = last_json(capsys.readouterr().out)
    keys = {"random_split_accuracy", "grouped_split_accuracy", "n_train", "n_test", "feature_seconds", "fit_seconds"}
    assert keys <= set(report)
    assert 0.5 < report["random_split_accuracy"] <= 1 and 0.5 < report["grouped_split_accuracy"] <= 1
    assert report["n_train"] + report["n_test"] == report["n_images"] == 120
    assert report["feature_seconds"] >= 0 and report["fit_seconds"] >= 0
    # The saved model is usable by detect.
    img = tmp_path / "street.jpg"
    shutil.copy(TEST_IMAGES / "test1.jpg", img)
    assert main(["detect", str(img), "--model", str(model)]) == 0
    csv_rows(tmp_path / "street_boxes.csv")


@needs_archives
def test_train_with_labelled_frames_adds_their_cars_and_the_box_refinement(small_data, tmp_path, capsys):
    from vehicle_detection.classifier import VehicleClassifier

    data = small_data
    labels = still_labels(tmp_path, ("0", "1"))  # test1.jpg, two cars, and test2.jpg, none (one picture searched, not five)
    model = tmp_path / "m.npz"
    assert main(["train", "--data-dir", str(data), "--labels", str(labels), "--json", "--model", str(model)]) == 0
    assert last_json(capsys.readouterr().out)["n_images"] == 120 + 12 * 2  # 2 labelled cars, 12 patches each
    loaded = VehicleClassifier.load(model)
    assert loaded.box_regressor is not None and loaded.metrics["box_refinement"]["labels"] == [str(labels)]
    assert loaded.metrics["box_refinement"]["alpha"] == REFINE_ALPHA
    tracker = loaded.detector_config.tracker
    assert tracker.window_inset == (0.0, 0.0, 0.0, 0.0) and tracker.cluster_iou > 0 and tracker.box_vote > 0


def test_refine_fits_the_box_refinement_and_keeps_the_classifier(tmp_path, capsys):
    from vehicle_detection.classifier import VehicleClassifier, load_default_model

    # The first 16 of clip A's 26 labelled frames (every 10th of its first 151): on the first 9,
    # the refit's F1 at IoU 0.7 falls below the embedded model's (0.944 against 1.0).
    clip = json.loads((REPO / "dev_set" / "clip_A.json").read_text())
    clip["video"] = str((REPO / "dev_set" / clip["video"]).resolve())
    clip["frames"] = {k: v for k, v in clip["frames"].items() if int(k) <= 150}
    labels = tmp_path / "clip_A_start.json"
    labels.write_text(json.dumps(clip))
    n_cars = sum(len(f["cars"]) for f in clip["frames"].values())
    out = tmp_path / "refined.npz"
    assert main(["refine", "--labels", str(labels), "--out", str(out), "--json"]) == 0
    summary = last_json(capsys.readouterr().out)
    base, refined = load_default_model(), VehicleClassifier.load(out)
    # The penalty is the base model's (the embedded model's refinement was fitted with the default).
    assert base.metrics["box_refinement"]["alpha"] == REFINE_ALPHA
    assert summary == {"n_frames": 16, "n_cars": n_cars, "alpha": REFINE_ALPHA, "mirror": False, "seconds": summary["seconds"], "model": str(out)}
    # The classifier, the search and the tracker settings are the base model's; the refinement is new.
    assert np.array_equal(refined.weights, base.weights) and refined.bias == base.bias
    assert refined.detector_config == base.detector_config
    assert not np.allclose(refined.box_regressor.coef, base.box_regressor.coef)
    assert refined.metrics["box_refinement"]["labels"] == [str(labels)]
    # Fitted to these frames' cars only, its boxes fit them better than the base model's (fitted
    # to two cameras' frames): F1 at IoU 0.7 as high, and a higher mean IoU of the matched boxes.
    # Scored on the first 2 of those frames, 4 cars (11 decoded frames, not 151): 0.900 against 0.876.
    clip["frames"] = {k: v for k, v in clip["frames"].items() if int(k) <= 10}
    few = tmp_path / "clip_A_first_2.json"
    few.write_text(json.dumps(clip))
    scores = []
    for model in (out, None):
        assert main(["evaluate", "--labels", str(few), "--json", "--no-progress"] + (["--model", str(model)] if model else [])) == 0
        at = last_json(capsys.readouterr().out)["all"]
        assert at["n_cars"] == 4
        scores.append((at["at_iou_0.7"]["f1"], at["at_iou_0.5"]["mean_iou"]))
    assert scores[0][0] >= scores[1][0] and scores[0][1] > scores[1][1]
    # A second run does not replace the model unless told to; the fit is deterministic. (Checked
    # on those 2 frames: a refit on all 16 would double the test's time.)
    small = tmp_path / "refined_on_2.npz"
    assert main(["refine", "--labels", str(few), "--out", str(small)]) == 0
    first = VehicleClassifier.load(small).box_regressor.coef
    assert not np.allclose(first, base.box_regressor.coef) and not np.allclose(first, refined.box_regressor.coef)
    before = small.read_bytes()
    assert main(["refine", "--labels", str(few), "--out", str(small)]) == 5
    assert small.read_bytes() == before
    assert main(["refine", "--labels", str(few), "--out", str(small), "--overwrite"]) == 0
    assert np.array_equal(VehicleClassifier.load(small).box_regressor.coef, first)


def test_refine_mirror_learns_from_the_frames_flipped_and_later_refits_keep_it(tmp_path, capsys):
    from vehicle_detection.classifier import VehicleClassifier

    labels = still_labels(tmp_path, ("0",))  # test1.jpg, two cars: the flag's effect and its inheritance show on one still as on six
    plain, mirrored, again = tmp_path / "plain.npz", tmp_path / "mirrored.npz", tmp_path / "again.npz"
    assert main(["refine", "--labels", str(labels), "--out", str(plain)]) == 0
    capsys.readouterr()
    assert main(["refine", "--labels", str(labels), "--out", str(mirrored), "--mirror", "--json"]) == 0
    assert last_json(capsys.readouterr().out)["mirror"] is True
    a, b = VehicleClassifier.load(plain), VehicleClassifier.load(mirrored)
    assert a.metrics["box_refinement"]["mirror"] is False and b.metrics["box_refinement"]["mirror"] is True
    assert not np.allclose(a.box_regressor.coef, b.box_regressor.coef)
    # refitted from a mirrored model without the flag: mirrored, as its base was; --no-mirror undoes it
    assert main(["refine", "--labels", str(labels), "--model", str(mirrored), "--out", str(again)]) == 0
    assert np.array_equal(VehicleClassifier.load(again).box_regressor.coef, b.box_regressor.coef)
    assert main(["refine", "--labels", str(labels), "--model", str(mirrored), "--out", str(again), "--no-mirror", "--overwrite"]) == 0
    assert np.array_equal(VehicleClassifier.load(again).box_regressor.coef, a.box_regressor.coef)


@needs_archives
def test_train_augment_adds_copies_and_the_model_says_how_it_was_trained(small_data, tmp_path, capsys):
    from vehicle_detection.classifier import VehicleClassifier

    model = tmp_path / "m.npz"
    assert main(["train", "--data-dir", str(small_data), "--augment", "2", "--json", "--model", str(model)]) == 0
    report = last_json(capsys.readouterr().out)
    assert report["n_images"] == 120 and report["n_augmented"] == 240 and report["n_test"] > 0
    assert report["n_train"] == 3 * (120 - report["n_test"])  # the training side's patches and their copies, not the test side's
    augment = VehicleClassifier.load(model).metrics["augment"]
    assert augment["copies"] == 2 and augment["n_copies"] == 240 and {"gamma", "blur", "jpeg", "scale"} <= set(augment)


def test_mine_negatives_horizon_takes_a_fraction(tmp_path):
    labels = str(Path(__file__).resolve().parents[1] / "dev_set" / "test_images.json")
    out = run_in_process(["mine-negatives", "--labels", labels, "--horizon", "auto", "--out", str(tmp_path / "n")], tmp_path)
    assert out.returncode == 2 and "fraction" in out.stderr


def test_evaluate_json_on_labels_from_detect(detected_clip, tmp_path, capsys):
    clip, _ = detected_clip
    table = read_boxes_csv(clip.with_name("clip4_boxes.csv"))
    assert len(table.at_frame(0)) == len(table.at_frame(3)) == 2  # both cars of the clip, in its first frame and its last
    cars = {f: table.at_frame(f).xyxy.tolist() for f in (0, 3)}
    cars[0].append([0, 0, 40, 40])  # a car nobody can find: one miss
    labels = tmp_path / "labels.json"
    labels.write_text(json.dumps({"video": clip.name, "frames": {str(f): {"cars": c} for f, c in cars.items()}}))
    assert main(["evaluate", "--video", str(clip), "--labels", str(labels), "--json", "--no-progress"]) == 0
    doc = last_json(capsys.readouterr().out)
    assert set(doc) == {"files", "cameras", "all"}
    scores = doc["all"]["at_iou_0.5"]
    assert {"precision", "recall", "f1", "fp_per_frame"} <= set(scores)
    assert doc["files"][str(labels)]["at_iou_0.5"] == scores  # one file: the same figures, the same keys
    assert set(doc["all"]) >= {"n_frames", "n_cars", "at_iou_0.5", "at_iou_0.7"}
    n_found = len(cars[0]) - 1 + len(cars[3])
    # The same decoded frames give the same boxes: every detection matches, one car is missed.
    assert (scores["tp"], scores["fp"], scores["fn"], scores["n_frames"]) == (n_found, 0, 1, 2)
    assert scores["precision"] == 1.0 and scores["fp_per_frame"] == 0.0
    assert scores["recall"] == pytest.approx(n_found / (n_found + 1))
    p, r = scores["precision"], scores["recall"]
    assert scores["f1"] == pytest.approx(2 * p * r / (p + r))


# ----------------------------------------------------------------------------------------------
# evaluate: cameras and --report
# ----------------------------------------------------------------------------------------------


@pytest.fixture
def scored_case(tmp_path):
    """Two labelled images of camera "dash" and a boxes CSV with one miss and two false positives."""
    imgs = tmp_path / "imgs"
    imgs.mkdir()
    for name in ("test1.jpg", "test4.jpg"):
        shutil.copy(TEST_IMAGES / name, imgs / name)
    labels = tmp_path / "labels.json"
    labels.write_text(json.dumps({"video": "imgs", "camera": "dash", "frames": {
        "0": {"cars": [[810, 410, 950, 500]], "ignore": [[0, 380, 640, 480]], "file": "test1.jpg"},
        "1": {"cars": [[1040, 400, 1260, 520]], "ignore": [], "file": "test4.jpg"},
    }}))  # fmt: skip
    boxes = tmp_path / "b.csv"
    boxes.write_text(
        BOXES_CSV_HEADER + "\n"
        "0,810,410,950,500,-1,1.0\n"  # the car of image 0: a match (IoU 1)
        "0,300,100,400,200,-1,1.0\n"  # the sky: a false positive
        "0,100,400,200,460,-1,1.0\n"  # inside the ignore region: not a failure
        "1,200,450,300,550,-1,1.0\n"  # the road of image 1: a false positive; its car is missed
    )
    return labels, boxes


def _report_args(labels, boxes, report, *more):
    return ["evaluate", "--labels", str(labels), "--boxes", str(boxes), "--report", str(report), "--no-progress", *more]


@needs_media
def test_evaluate_report_writes_the_sheet_and_the_tables(scored_case, tmp_path, capsys):
    labels, boxes = scored_case
    report = tmp_path / "rep"
    assert main(_report_args(labels, boxes, report, "--json")) == 0
    captured = capsys.readouterr()
    out = captured.out
    assert f"report: {report / 'failures_dash.png'} (3 tiles, 0 left out)" in captured.err
    assert sorted(p.name for p in report.iterdir()) == ["cameras.csv", "cameras.md", "failures_dash.png"]
    sheet = np.array(Image.open(report / "failures_dash.png").convert("RGB"))
    # 3 tiles of 256 x (192 + 38) px in one row, 4 px apart, under a 62 px header.
    assert sheet.shape == (62 + 4 + 230 + 4, 4 + 3 * 260, 3)
    from vehicle_detection.viz.drawing import KIND_COLORS, LABEL_COLOR, REPORTED_COLOR

    def has(color):
        return bool((sheet == color).all(axis=-1).any())

    assert has(KIND_COLORS["miss"]) and has(KIND_COLORS["false positive"]) and not has(KIND_COLORS["loose"])
    assert has(LABEL_COLOR) and has(REPORTED_COLOR)
    rows = (report / "cameras.csv").read_text().splitlines()
    assert len(rows) == 2 and rows[0].startswith("camera,files,frames,cars,tp_50,fp_50,fn_50,precision_50,")
    row = dict(zip(rows[0].split(","), rows[1].split(",")))
    assert (row["camera"], row["files"], row["frames"], row["cars"]) == ("dash", "1", "2", "2")
    assert (row["tp_50"], row["fp_50"], row["fn_50"], row["precision_50"], row["recall_50"]) == ("1", "2", "1", "0.3333", "0.5000")
    assert row["mean_iou_50"] == "1.0000" and row["fp_per_frame"] == "1.0000"
    assert "| dash | 1 | 2 | 2 | 1 | 2 | 1 | 0.3333 | 0.5000 |" in (report / "cameras.md").read_text()
    doc = last_json(out)
    assert list(doc["cameras"]) == ["dash"]
    cam = doc["cameras"]["dash"]
    at50 = cam["at_iou_0.5"]
    assert (at50["tp"], at50["fp"], at50["fn"], cam["n_cars"], cam["labels"]) == (1, 2, 1, 2, [str(labels)])
    assert cam["at_iou_0.7"]["tp"] == 1 and at50["mean_iou"] == 1.0
    assert {k: v for k, v in cam.items() if k != "labels"} == doc["all"]
    assert doc["files"][str(labels)]["camera"] == "dash"


@needs_media
def test_evaluate_report_prints_the_same_figures(scored_case, tmp_path, capsys):
    labels, boxes = scored_case
    assert main(["evaluate", "--labels", str(labels), "--boxes", str(boxes), "--json"]) == 0
    plain = capsys.readouterr().err.splitlines()
    assert main(_report_args(labels, boxes, tmp_path / "rep", "--json")) == 0
    with_report = capsys.readouterr().err.splitlines()

    def figures(lines):
        return [line for line in lines if not line.startswith(("scored in", "report: "))]

    assert figures(with_report) == figures(plain)


@needs_media
def test_evaluate_report_refuses_a_folder_with_files(scored_case, tmp_path, capsys):
    labels, boxes = scored_case
    report = tmp_path / "rep"
    report.mkdir()
    (report / "notes.txt").write_text("mine\n")
    assert main(_report_args(labels, boxes, report)) == 5
    err = capsys.readouterr().err.splitlines()
    assert err == [f"{ERROR_PREFIX}{report}: report folder exists and is not empty; pass --overwrite to replace its files"]
    assert [p.name for p in report.iterdir()] == ["notes.txt"]
    # A file where the folder should be: refused too, with or without --overwrite.
    assert main(_report_args(labels, boxes, report / "notes.txt", "--overwrite")) == 5
    assert (report / "notes.txt").read_text() == "mine\n"
    # --overwrite writes beside the other files; again, it replaces its own.
    assert main(_report_args(labels, boxes, report, "--overwrite")) == 0
    first = (report / "failures_dash.png").stat().st_ino
    assert main(_report_args(labels, boxes, report)) == 5
    assert main(_report_args(labels, boxes, report, "--overwrite")) == 0
    assert (report / "failures_dash.png").stat().st_ino != first
    assert sorted(p.name for p in report.iterdir()) == ["cameras.csv", "cameras.md", "failures_dash.png", "notes.txt"]


@needs_media
def test_evaluate_pools_files_of_one_camera(tmp_path, capsys):
    """Two labels files of one camera and one of another (the detector runs: one image each)."""
    imgs = tmp_path / "imgs"
    imgs.mkdir()
    shutil.copy(TEST_IMAGES / "test1.jpg", imgs / "test1.jpg")
    paths = []
    for name, camera in (("a.json", "front"), ("b.json", "front"), ("c.json", None)):
        doc = {"video": "imgs", "frames": {"0": {"cars": [[810, 410, 950, 500]], "ignore": []}}}
        paths.append(tmp_path / name)
        paths[-1].write_text(json.dumps(doc | ({"camera": camera} if camera else {})))
    assert main(["evaluate", "--labels", *map(str, paths), "--json", "--no-progress"]) == 0
    captured = capsys.readouterr()
    doc, out = last_json(captured.out), captured.err
    assert list(doc["cameras"]) == ["front", "1280x720"]  # c.json: named by its image size
    front, other = doc["cameras"]["front"], doc["cameras"]["1280x720"]
    assert front["labels"] == [str(paths[0]), str(paths[1])] and other["labels"] == [str(paths[2])]
    assert front["n_frames"] == 2 and other["n_frames"] == 1
    assert front["at_iou_0.5"]["tp"] == 2 * other["at_iou_0.5"]["tp"]  # the same image twice
    assert front["at_iou_0.5"]["fp"] == 2 * other["at_iou_0.5"]["fp"]
    assert "camera front: 2 frames, 2 cars" in out and "camera 1280x720: 1 frames, 1 cars" in out
    assert out.index("camera front:") < out.index("all: 3 frames, 3 cars")


@pytest.mark.parametrize("given", [None, "2"])
def test_the_command_line_starts_blas_with_one_thread_unless_told(given):
    """Its own threads do the work; BLAS threads would compete with them (and spin at load).
    A user's own setting stands: the same threads as NumPy alone gets with it."""
    env = {k: v for k, v in os.environ.items() if k not in ("OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "OMP_NUM_THREADS")}
    if given is not None:
        env["OPENBLAS_NUM_THREADS"] = given

    def blas_threads(first: str) -> list:
        code = (f"import {first}, numpy, json, threadpoolctl\n"  # the command line imports NumPy when it runs a command
                "print(json.dumps([p['num_threads'] for p in threadpoolctl.threadpool_info() if p['user_api'] == 'blas']))")
        proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stderr[-2000:]
        return json.loads(proc.stdout)

    threads = blas_threads("vehicle_detection.cli")
    assert threads
    assert set(threads) == ({1} if given is None else set(blas_threads("numpy")))


def test_the_command_line_imports_nothing_heavy_before_it_runs_a_command():
    """The helper compiling half the kernels on a fresh install starts before numba's import."""
    code = ("import sys, vehicle_detection.cli\n"
            "print(sorted(m for m in ('numba', 'numpy', 'cv2', 'av') if m in sys.modules))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert proc.stdout.strip() == "[]"


@pytest.mark.parametrize("argv, starts", [
    (["detect", "v.mp4"], True), (["evaluate", "--labels", "l.json"], True), (["detect", "--help"], False),
    (["detect", "v.mp4", "--he"], False), (["detect", "v.mp4", "--horizon", "0.5"], True),
    (["detect", "a.mp4", "b.mp4", "--jobs", "2"], False), (["detect", "a.mp4", "--jobs=1"], True),
    (["detect", "a.mp4", "--scheduler", "tcp://h:8786"], False), (["detect", "a.mp4", "--boxes", "b.csv"], True),
    (["evaluate", "--labels", "l.json", "--boxes", "b.csv"], False),
    (["train", "--data", "d"], False), (["--version"], False), ([], False),
])
def test_the_helper_starts_early_for_the_searching_commands_only(argv, starts, monkeypatch):
    import importlib

    from vehicle_detection import warmup

    cli_main = importlib.import_module("vehicle_detection.cli.main")  # the module (the package's main is the function)
    calls = []
    monkeypatch.setattr(warmup, "start_helper", lambda: calls.append("start"))
    monkeypatch.setattr(warmup, "stop_helper", lambda: calls.append("stop"))
    monkeypatch.setattr(cli_main, "_run", lambda args: 0)
    try:
        cli_main.main(argv)
    except SystemExit:  # --help, --version, a missing command: parsed, then exits
        pass
    assert calls == (["start", "stop"] if starts else ["stop"])


def test_a_signal_while_the_command_line_starts_ends_the_run_and_its_helper(monkeypatch, capsys):
    """SIGTERM (or Ctrl-C) before the command runs, while its modules are imported: exit 130 with
    the one line, and the helper process started for it ended."""
    import importlib
    import signal

    from vehicle_detection import warmup

    cli_main = importlib.import_module("vehicle_detection.cli.main")
    calls = []
    monkeypatch.setattr(warmup, "start_helper", lambda: (calls.append("start"), os.kill(os.getpid(), signal.SIGTERM)))
    monkeypatch.setattr(warmup, "stop_helper", lambda: calls.append("stop"))

    def unhandled(signum, frame):
        raise RuntimeError("SIGTERM reached the handler from before the run")  # not pytest's death

    previous = signal.signal(signal.SIGTERM, unhandled)
    try:
        assert cli_main.main(["detect", "v.mp4"]) == 130
    finally:
        signal.signal(signal.SIGTERM, previous)
    assert calls == ["start", "stop"]
    assert capsys.readouterr().err.strip() == "vehicle-detection: interrupted"
