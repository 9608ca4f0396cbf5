"""Hostile inputs and environments, one fault each: the exact exit code and what is left on disk.

Special files as outputs, absurd image shapes, failed ``--overwrite`` runs, SIGTERM / SIGHUP,
full disks, training images as the model path, feature configurations the search cannot use,
tiny data sets, unwritable image formats, a closed stdout pipe, EXIF orientation.

Most cases run ``main([...])`` in this process (exact return code and stderr, fast); the signal
and pipe cases run ``python -m vehicle_detection.cli`` in a subprocess, as a shell would.
"""

from __future__ import annotations

import errno
import hashlib
import io
import os
import shutil
import signal
import stat
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
from PIL import Image, ImageFile, ImageOps

import media
from vehicle_detection.io._files import PARTIAL_SUFFIX, atomic_output, check_output_path
from vehicle_detection.cli import main
from vehicle_detection.errors import InputError, OutputError
from vehicle_detection.features import FeatureConfig
from vehicle_detection.io.images import decode_image, read_image

REPO = Path(__file__).resolve().parents[1]
TEST_VIDEO = REPO / "test_video.mp4"
TEST_IMAGES = REPO / "test_images"
ERROR = "vehicle-detection: error: "

posix_only = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals, FIFOs and pipes")
needs_media = pytest.mark.skipif(
    not (TEST_VIDEO.is_file() and (TEST_IMAGES / "test1.jpg").is_file()), reason="test_video.mp4 or test_images/ not in the checkout"
)


# ----------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------


def sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def snapshot(folder: Path) -> dict[str, tuple]:
    """Every entry below ``folder``: kind and content hash (files), link target (symlinks)."""
    out = {}
    for p in sorted(folder.rglob("*")):
        mode = os.lstat(p).st_mode
        rel = p.relative_to(folder).as_posix()
        if stat.S_ISLNK(mode):
            out[rel] = ("symlink", os.readlink(p))
        elif stat.S_ISREG(mode):
            out[rel] = ("file", sha256(p))
        elif stat.S_ISFIFO(mode):
            out[rel] = ("fifo",)
        else:
            out[rel] = ("dir",) if stat.S_ISDIR(mode) else ("other",)
    return out


def picture(h: int = 72, w: int = 128, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w]
    img = np.stack([x * 255 // max(1, w - 1), y * 255 // max(1, h - 1), np.full_like(x, 90)], axis=-1)
    return np.clip(img + rng.integers(0, 8, (h, w, 3)), 0, 255).astype(np.uint8)


def save(path: Path, arr: np.ndarray, **kwargs) -> Path:
    Image.fromarray(arr).save(path, **kwargs)
    return path


def run_main(capsys, *argv) -> tuple[int, list[str], list[str]]:
    code = main([str(a) for a in argv])
    captured = capsys.readouterr()
    return code, captured.out.splitlines(), captured.err.splitlines()


def run_cli(*args, **kwargs) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "vehicle_detection.cli", *map(str, args)], capture_output=True, text=True, timeout=300,
        cwd=REPO, **kwargs,
    )  # fmt: skip


def partials(folder: Path) -> list[Path]:
    return [p for p in folder.rglob(f"*{PARTIAL_SUFFIX}")]


def enospc(*args, **kwargs):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def _png(seed: int) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(picture(64, 64, seed)).save(buf, format="PNG")
    return buf.getvalue()


def make_data(root: Path, per_class: int, *, groups: int = 1, zipped: bool = False) -> Path:
    """``per_class`` 64x64 PNGs per class, spread over ``groups`` blocks of 100 file numbers."""
    root.mkdir(parents=True, exist_ok=True)
    for cls in ("vehicles", "non-vehicles"):
        names = {f"{cls}/set/image{(i % groups) * 100 + i // groups}.png": _png(i + 1000 * (cls == "vehicles")) for i in range(per_class)}
        if zipped:
            with zipfile.ZipFile(root / f"{cls}.zip", "w") as zf:
                for name, data in names.items():
                    zf.writestr(name, data)
        else:
            for name, data in names.items():
                (root / name).parent.mkdir(parents=True, exist_ok=True)
                (root / name).write_bytes(data)
    return root


# ----------------------------------------------------------------------------------------------
# a. Outputs that are not regular files are never replaced
# ----------------------------------------------------------------------------------------------


@posix_only
@pytest.mark.parametrize("kind", ["fifo", "symlink_to_file", "dangling_symlink", "symlink_to_device"])
@pytest.mark.parametrize("which", ["--out", "--boxes"])
def test_overwrite_refuses_special_files(tmp_path, capsys, kind, which):
    img = save(tmp_path / "street.png", picture())
    target = tmp_path / "target.png"
    special = tmp_path / ("special.png" if which == "--out" else "special.csv")
    if kind == "fifo":
        os.mkfifo(special)
    elif kind == "symlink_to_file":
        target.write_bytes(b"somebody else's file")
        special.symlink_to(target)
    elif kind == "dangling_symlink":
        special.symlink_to(tmp_path / "nowhere" / "file.png")
    else:
        special.symlink_to("/dev/null")  # the link is what would be replaced; /dev/null is never opened
    before = snapshot(tmp_path)
    code, _, err = run_main(capsys, "detect", img, which, special, "--overwrite")
    assert code == 5
    what = {"fifo": "a FIFO (named pipe)"}.get(kind, "a symlink")
    assert err == [f"{ERROR}{special}: output exists and is {what}, not a regular file; refusing to replace it"]
    assert snapshot(tmp_path) == before  # the special file is intact, and nothing was written


@posix_only
def test_special_file_is_refused_also_when_it_appears_during_the_run(tmp_path):
    dest = tmp_path / "out.csv"
    with pytest.raises(OutputError, match="output exists and is a FIFO"):
        with atomic_output(dest, overwrite=True) as tmp:
            tmp.write_text("data\n")
            os.mkfifo(dest)
    assert snapshot(tmp_path) == {"out.csv": ("fifo",)}
    assert check_output_path(tmp_path / "regular.csv", overwrite=True) == tmp_path / "regular.csv"


# ----------------------------------------------------------------------------------------------
# b. Absurd aspect ratios are refused before decoding
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("w", "h", "problem", "suffix"),
    [(20000, 50, "too wide (more than 8:1)", ".png"), (100000, 1, "too wide (more than 8:1)", ".png"),
     (401, 50, "too wide (more than 8:1)", ".png"), (50, 201, "too tall (more than 1:4)", ".png"),
     (1, 5000, "too tall (more than 1:4)", ".png"), (20000, 50, "too wide (more than 8:1)", ".jpg"),
     (50, 201, "too tall (more than 1:4)", ".jpg"), (50, 201, "too tall (more than 1:4)", ".webp")],
)  # fmt: skip
def test_extreme_aspect_ratio_refused_before_decoding(tmp_path, monkeypatch, w, h, problem, suffix):
    path = tmp_path / f"strip{suffix}"
    Image.new("L", (w, h), 128).save(path)  # a few KB on disk
    assert path.stat().st_size < 20_000
    # The shape is checked before the pixels are decoded, except for a PNG between 4:1 and 8:1
    # tall, whose EXIF orientation (possibly stored after the pixels) decides if it is refused.
    if not (suffix == ".png" and 4 * w < h <= 8 * w):

        def no_decoding(self):
            raise AssertionError("pixels decoded before the shape was checked")

        monkeypatch.setattr(Image.Image, "load", no_decoding)
        monkeypatch.setattr(ImageFile.ImageFile, "load", no_decoding)
    with pytest.raises(InputError) as info:
        read_image(path)
    assert str(info.value) == f"{path}: image of {w}x{h} pixels is {problem}; crop it first"


@pytest.mark.parametrize(("w", "h"), [(400, 50), (50, 200), (8, 1), (1, 4), (1280, 720), (720, 1280)])
def test_aspect_ratio_limits_are_inclusive(tmp_path, w, h):
    from vehicle_detection.io.images import check_frame_shape

    path = tmp_path / "ok.png"
    Image.new("RGB", (w, h), (10, 20, 30)).save(path)
    assert read_image(path).shape == (h, w, 3)
    check_frame_shape(h, w, "frame")


def test_check_frame_shape_bounds_the_scaled_size():
    from vehicle_detection.io.images import check_frame_shape

    check_frame_shape(720, 5760, "v.mp4")  # 8:1 at 720 px: the largest working frame
    with pytest.raises(InputError, match=r"^v\.mp4: image of 5761x720 pixels is too wide"):
        check_frame_shape(720, 5761, "v.mp4")
    # A taller search height makes the same shape larger once scaled: bounded too.
    with pytest.raises(InputError, match=r"^v\.mp4: image of 5760x720 pixels would be 11520x1440 once scaled"):
        check_frame_shape(720, 5760, "v.mp4", reference_height=1440)
    with pytest.raises(InputError, match=r"^v\.mp4: empty image of 0x720 pixels"):
        check_frame_shape(720, 0, "v.mp4")


def test_cli_refuses_a_wide_image_with_exit_3_and_no_output(tmp_path, capsys):
    path = tmp_path / "strip.png"
    Image.new("RGB", (20000, 50)).save(path)
    code, out, err = run_main(capsys, "detect", path)
    assert code == 3
    assert err == [f"{ERROR}{path}: image of 20000x50 pixels is too wide (more than 8:1); crop it first"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["strip.png"]


# ----------------------------------------------------------------------------------------------
# c. A failed --overwrite run keeps the previous outputs
# ----------------------------------------------------------------------------------------------


def test_failed_overwrite_of_an_image_keeps_both_previous_outputs(tmp_path, capsys, monkeypatch):
    import vehicle_detection.io.tables as boxes_module

    img = save(tmp_path / "street.png", picture())
    assert run_main(capsys, "detect", img)[0] == 0
    before = snapshot(tmp_path)
    assert sorted(before) == ["street.png", "street_boxes.csv", "street_detected.png"]
    # The CSV is written after the annotated image: make it fail.
    monkeypatch.setattr(boxes_module.Path, "write_text", enospc)
    code, _, err = run_main(capsys, "detect", img, "--overwrite")
    assert code == 5
    assert err == [f"{ERROR}{tmp_path / 'street_boxes.csv'}: cannot write output: No space left on device"]
    assert snapshot(tmp_path) == before  # old image and old CSV intact, no .partial


def test_failed_overwrite_of_a_folder_keeps_every_previous_output(tmp_path, capsys):
    shots = tmp_path / "shots"
    shots.mkdir()
    for i in range(2):
        save(shots / f"a{i}.png", picture(seed=i))
    assert run_main(capsys, "detect", shots)[0] == 0
    before = snapshot(tmp_path / "shots_detected")
    assert sorted(before) == ["a0.png", "a1.png", "boxes.csv"]
    (shots / "z_broken.png").write_bytes(b"not a picture")  # the last in sorted order
    code, _, err = run_main(capsys, "detect", shots, "--overwrite")
    assert code == 3
    assert err == [f"{ERROR}{shots / 'z_broken.png'}: not an image (or a format Pillow cannot read)"]
    assert snapshot(tmp_path / "shots_detected") == before


def test_folder_outputs_appear_together_or_not_at_all(tmp_path, capsys):
    shots = tmp_path / "shots"
    shots.mkdir()
    save(shots / "a.png", picture())
    (shots / "b.png").write_bytes(b"")
    code, _, err = run_main(capsys, "detect", shots)
    assert code == 3 and err == [f"{ERROR}{shots / 'b.png'}: empty file, not an image"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["shots"]  # no output folder, no .partial


@needs_media
def test_failed_overwrite_of_a_video_keeps_both_previous_outputs(tmp_path, capsys, monkeypatch):
    from vehicle_detection.io import video as video_module

    clip = tmp_path / "clip.mp4"
    media.copy_packets(TEST_VIDEO, clip, max_frames=3)
    assert run_main(capsys, "detect", clip, "--no-progress")[0] == 0
    before = snapshot(tmp_path)
    assert sorted(before) == ["clip.mp4", "clip_boxes.csv", "clip_detected.mp4"]

    def broken_finish(self):
        raise OutputError(f"{self.path}: the encoder failed to finish the video: No space left on device")

    monkeypatch.setattr(video_module.VideoWriter, "_finish", broken_finish)
    code, _, err = run_main(capsys, "detect", clip, "--no-progress", "--overwrite")
    assert code == 5
    assert err == [f"{ERROR}{tmp_path / 'clip_detected.mp4'}: the encoder failed to finish the video: No space left on device"]
    assert snapshot(tmp_path) == before


def test_output_batch_commits_all_or_nothing(tmp_path):
    from vehicle_detection.io._files import output_batch

    old = tmp_path / "old.txt"
    old.write_text("previous\n")
    with pytest.raises(KeyboardInterrupt):
        with output_batch():
            with atomic_output(old, overwrite=True) as tmp:
                tmp.write_text("new\n")
            with atomic_output(tmp_path / "new" / "deeper" / "b.txt") as tmp:
                tmp.write_text("b\n")
            assert old.read_text() == "previous\n"  # finished, but not yet in place
            raise KeyboardInterrupt
    assert snapshot(tmp_path) == {"old.txt": ("file", hashlib.sha256(b"previous\n").hexdigest())}
    with output_batch():
        with atomic_output(old, overwrite=True) as tmp:
            tmp.write_text("new\n")
        with atomic_output(tmp_path / "b.txt") as tmp:
            tmp.write_text("b\n")
    assert old.read_text() == "new\n" and (tmp_path / "b.txt").read_text() == "b\n"
    assert partials(tmp_path) == []


# ----------------------------------------------------------------------------------------------
# d. SIGTERM and SIGHUP stop a run like Ctrl-C
# ----------------------------------------------------------------------------------------------


def _stop_when(proc: subprocess.Popen, ready, sig: int) -> tuple[str, str]:
    try:
        deadline = time.monotonic() + 120
        while not ready():
            assert proc.poll() is None, f"the run ended before it could be stopped: {proc.communicate()}"
            assert time.monotonic() < deadline, "the run never got going"
            time.sleep(0.01)
        proc.send_signal(sig)
        return proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()


@posix_only
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGHUP], ids=["SIGTERM", "SIGHUP"])
def test_signal_midway_through_a_video_keeps_previous_outputs(tmp_path, long_video, sig):
    video = tmp_path / "drive.mp4"
    shutil.copy(long_video, video)
    out, csv = tmp_path / "drive_detected.mp4", tmp_path / "drive_boxes.csv"
    out.write_bytes(b"previous video")
    csv.write_text("previous boxes\n")
    before = snapshot(tmp_path)

    def encoding():
        return any(p.stat().st_size > 100_000 for p in tmp_path.glob(f".{out.name}.*{PARTIAL_SUFFIX}") if p.exists())

    proc = subprocess.Popen(
        [sys.executable, "-m", "vehicle_detection.cli", "detect", str(video), "--no-progress", "--overwrite"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO,
    )  # fmt: skip
    _, err = _stop_when(proc, encoding, sig)
    assert proc.returncode == 130
    assert err.splitlines() == ["vehicle-detection: interrupted"]
    assert snapshot(tmp_path) == before  # no .partial, previous outputs untouched


@posix_only
@needs_media
def test_sigterm_midway_through_a_folder_keeps_previous_outputs(tmp_path):
    shots = tmp_path / "shots"
    shots.mkdir()
    for i in range(40):
        shutil.copy(TEST_IMAGES / f"test{i % 6 + 1}.jpg", shots / f"img{i:02d}.jpg")
    done = tmp_path / "shots_detected"
    done.mkdir()
    (done / "img00.jpg").write_bytes(b"previous annotated image")
    (done / "boxes.csv").write_text("previous boxes\n")
    before = snapshot(tmp_path)
    old_inodes = {p.name: p.stat().st_ino for p in done.iterdir()}

    def started():  # a new file in the output folder, or an old one replaced
        try:
            now = {p.name: p.stat().st_ino for p in done.iterdir()}
        except FileNotFoundError:
            return False
        return any(old_inodes.get(name) != inode for name, inode in now.items())

    proc = subprocess.Popen(
        [sys.executable, "-m", "vehicle_detection.cli", "detect", str(shots), "--overwrite"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO,
    )  # fmt: skip
    _, err = _stop_when(proc, started, signal.SIGTERM)
    assert proc.returncode == 130
    assert err.splitlines() == ["vehicle-detection: interrupted"]
    assert snapshot(tmp_path) == before  # no half set of images, no .partial, old outputs intact


def test_signal_handlers_are_restored(capsys):
    handlers = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)}
    assert main(["detect", "/nonexistent/x.png"]) == 3
    assert {s: signal.getsignal(s) for s in handlers} == handlers


# ----------------------------------------------------------------------------------------------
# f. A full disk (or quota, read-only file system, permission) is exit 5 naming the file
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("code", [errno.ENOSPC, errno.EDQUOT, errno.EROFS, errno.EACCES, errno.EIO], ids=errno.errorcode.get)
def test_disk_full_writing_an_image(tmp_path, capsys, monkeypatch, code):
    img = save(tmp_path / "street.png", picture())
    real_save = Image.Image.save

    def failing_save(self, fp, *args, **kwargs):
        if isinstance(fp, (str, os.PathLike)):  # a file, not the up-front check in memory
            raise OSError(code, os.strerror(code))
        return real_save(self, fp, *args, **kwargs)

    monkeypatch.setattr(Image.Image, "save", failing_save)
    rc, _, err = run_main(capsys, "detect", img)
    assert rc == 5
    assert err == [f"{ERROR}{tmp_path / 'street_detected.png'}: cannot write output: {os.strerror(code)}"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["street.png"]


def test_disk_full_writing_the_csv(tmp_path, capsys, monkeypatch):
    import vehicle_detection.io.tables as boxes_module

    img = save(tmp_path / "street.png", picture())
    monkeypatch.setattr(boxes_module.Path, "write_text", enospc)
    rc, _, err = run_main(capsys, "detect", img, "--boxes", tmp_path / "sub" / "b.csv")
    assert rc == 5
    assert err == [f"{ERROR}{tmp_path / 'sub' / 'b.csv'}: cannot write output: No space left on device"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["street.png"]  # nor the folder made for it


def test_disk_full_writing_a_model(tmp_path, monkeypatch):
    from vehicle_detection.classifier import VehicleClassifier

    cfg = FeatureConfig(spatial_size=0, hist_bins=0, hog_channels=(0,), orientations=4, pixels_per_cell=16, cells_per_block=2)
    rng = np.random.default_rng(0)
    model = VehicleClassifier.fit(rng.normal(size=(20, cfg.n_features)), np.repeat([0, 1], 10), cfg)
    monkeypatch.setattr(np, "savez", enospc)
    dest = tmp_path / "model.npz"
    with pytest.raises(OutputError) as info:
        model.save(dest)
    assert str(info.value) == f"{dest}: cannot write output: No space left on device"
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------------------------
# g. The model path may not be a training image
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("spelling", ["plain", "dotted", "symlinked_folder"])
def test_train_refuses_a_model_path_inside_the_extracted_images(tmp_path, capsys, spelling):
    data = make_data(tmp_path / "data", 12, groups=6)
    image = data / "vehicles" / "set" / "image0.png"
    if spelling == "plain":
        model = image
    elif spelling == "dotted":
        model = data / "non-vehicles" / ".." / "vehicles" / "set" / "image0.png"
    else:
        (tmp_path / "alias").symlink_to(data / "vehicles")
        model = tmp_path / "alias" / "set" / "new_model.npz"
    before = snapshot(tmp_path)
    code, out, err = run_main(capsys, "train", "--data-dir", data, "--model", model, "--overwrite")
    assert code == 5
    assert err == [f"{ERROR}{model}: model path is inside the training images folder {data / 'vehicles'}; save the model elsewhere"]
    assert out == []  # refused before any work
    assert snapshot(tmp_path) == before


# ----------------------------------------------------------------------------------------------
# h. Feature configurations the sliding-window search cannot use are refused when built
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("ppc", "cpb", "ok"), [(8, 6, True), (8, 7, False), (16, 2, True), (16, 3, False), (4, 14, True), (4, 15, False)]
)
def test_feature_config_needs_three_blocks_per_window(ppc, cpb, ok):
    kwargs = dict(pixels_per_cell=ppc, cells_per_block=cpb, orientations=4, spatial_size=0, hist_bins=0, hog_channels=(0,))
    if not ok:
        with pytest.raises(ValueError, match=rf"cells_per_block must be at most {64 // ppc - 2} with {64 // ppc} cells per window \(got {cpb}"):
            FeatureConfig(**kwargs)
        return
    cfg = FeatureConfig(**kwargs)
    assert cfg.blocks_per_window == 3
    # The boundary really is the search's: a model of this config scores every window.
    from vehicle_detection.classifier import VehicleClassifier
    from reference_search import search_plain
    from vehicle_detection.search import SearchPlan, SearchScale, search

    rng = np.random.default_rng(1)
    model = VehicleClassifier.fit(rng.normal(size=(20, cfg.n_features)), np.repeat([0, 1], 10), cfg)
    frame = rng.integers(0, 256, (720, 256, 3), dtype=np.uint8)
    plan = SearchPlan(scales=(SearchScale(1.0, 400, 496),))
    fast = search(frame, model, plan, all_windows=True)
    assert len(fast) > 0
    np.testing.assert_allclose(fast.score, search_plain(frame, model, plan).score, atol=1e-4)


@pytest.mark.parametrize(
    ("argv", "fragment"),
    [(["train", "--cells-per-block", "7"], "cells_per_block must be at most 6 with 8 cells per window (got 7"),
     (["train", "--pixels-per-cell", "16", "--cells-per-block", "3"], "cells_per_block must be at most 2 with 4 cells per window (got 3"),
     (["train", "--pixels-per-cell", "32"], "pixels_per_cell 32 leaves 2 cells per window"),
     (["sweep", "--cells-per-block", "2,7"], "cells_per_block must be at most 6 with 8 cells per window (got 7"),
     (["sweep", "--orientations", "9,x"], "--orientations: expected comma-separated integers, got '9,x'")],
)  # fmt: skip
def test_cli_bad_feature_options_are_usage_errors(tmp_path, capsys, argv, fragment):
    code, out, err = run_main(capsys, *argv, "--data-dir", tmp_path / "nowhere")
    assert code == 2
    assert len(err) == 1 and err[0].startswith(ERROR) and fragment in err[0], err
    assert out == [] and list(tmp_path.iterdir()) == []


def test_model_file_with_a_two_block_config_is_refused_not_a_crash(tmp_path, capsys):
    """A model saved before the check (--cells-per-block 7) is a bad model file (exit 4), not an IndexError."""
    import json

    from vehicle_detection.classifier import _digest, default_model_path

    with np.load(default_model_path(), allow_pickle=False) as npz:
        meta = json.loads(npz["meta"].tobytes())
    # A consistent, correctly signed model of the old, unchecked config (2 blocks per window).
    config = {**meta["feature_config"], "cells_per_block": 7}
    n = sum(v for v in (3 * config["spatial_size"] ** 2, 3 * config["hist_bins"],
                        len(config["hog_channels"]) * 2 * 2 * 7 * 7 * config["orientations"]))  # fmt: skip
    rng = np.random.default_rng(0)
    arrays = {"scaler_mean": rng.normal(size=n), "scaler_scale": rng.uniform(0.5, 2, n), "coef": rng.normal(size=n) * 1e-3,
              "intercept": np.array([0.0])}  # fmt: skip
    meta["feature_config"] = config
    meta["sha256"] = _digest(arrays, meta)
    model = tmp_path / "two_blocks.npz"
    np.savez(model, meta=np.frombuffer(json.dumps(meta).encode(), np.uint8), **arrays)
    img = save(tmp_path / "street.png", picture())
    before = snapshot(tmp_path)
    code, _, err = run_main(capsys, "detect", img, "--model", model)
    assert code == 4
    assert len(err) == 1 and err[0].startswith(f"{ERROR}{model}: feature config does not match this code: invalid FeatureConfig: cells_per_block must be at most 6"), err
    assert snapshot(tmp_path) == before


def test_cli_boundary_feature_options_are_accepted(tmp_path, capsys):
    # Accepted: the run goes on to look for the data (exit 3), instead of refusing the options.
    code, _, err = run_main(capsys, "train", "--cells-per-block", "6", "--data-dir", tmp_path / "nowhere")
    assert code == 3 and err == [f"{ERROR}{tmp_path / 'nowhere'}: data folder not found; run `vehicle-detection download` or pass --data-dir (or set $VEHICLE_DETECTION_DATA)"]


# ----------------------------------------------------------------------------------------------
# i. Too small a data set: a clear message before any work
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("per_class", "groups", "counts", "need"),
    [(3, 3, "vehicles 3 images in 3 groups, non-vehicles 3 images in 3 groups", "at least 5 images and at least 3 groups (the grouped split leaves 2 of the 6 groups"),
     (10, 1, "vehicles 10 images in 1 groups, non-vehicles 10 images in 1 groups", "at least 5 images and at least 2 groups (the grouped split leaves 1 of the 2 groups")],
    ids=["few_images", "few_groups"],
)  # fmt: skip
@pytest.mark.parametrize("command", ["train", "sweep"])
def test_too_small_a_dataset_is_a_clear_input_error(tmp_path, capsys, command, per_class, groups, counts, need):
    data = make_data(tmp_path / "data", per_class, groups=groups, zipped=True)
    before = snapshot(tmp_path)
    extra = ["--model", tmp_path / "m.npz"] if command == "train" else ["--jobs", "1"]
    code, out, err = run_main(capsys, command, "--data-dir", data, *extra)
    assert code == 3
    assert len(err) == 1, err
    assert err[0].startswith(f"{ERROR}{data}: too few training images for the random and grouped train/test splits ({counts}); each class needs {need}")
    assert out == []  # nothing computed, nothing reported
    assert snapshot(tmp_path) == before


def test_sweep_subsample_too_small_is_a_usage_error(tmp_path, capsys):
    code, _, err = run_main(capsys, "sweep", "--subsample", "3", "--data-dir", tmp_path)
    assert code == 2
    assert err == [f"{ERROR}--subsample 3: too few images; at least 10 (5 per class) are needed"]


def test_split_size_rule_is_sufficient():
    """Data sets the check accepts never make scikit-learn raise, whatever the seed."""
    from vehicle_detection.training.fit import train
    from vehicle_detection.training.data import Dataset, check_split_sizes

    cfg = FeatureConfig(spatial_size=0, hist_bins=0, hog_channels=(0,), orientations=4)
    # Imbalanced groups: 4 vehicle groups among 12; the grouped split leaves 3 out of training.
    labels = np.array([1] * 8 + [0] * 8, np.int8)
    groups = np.array([0, 0, 1, 1, 2, 2, 3, 3, 4, 5, 6, 7, 8, 9, 10, 11])
    check_split_sizes(labels, groups)
    with pytest.raises(InputError, match=r"vehicles 8 images in 3 groups.*at least 4 groups"):
        check_split_sizes(labels, np.where(groups == 3, 2, groups))
    with pytest.raises(InputError, match=r"non-vehicles 4 images"):
        check_split_sizes(labels[:12], groups[:12])
    images = np.stack([picture(64, 64, i) for i in range(len(labels))])
    n = len(labels)
    ds = Dataset(images, labels, np.array(["s"] * n), np.array([f"{i}.png" for i in range(n)]), groups, np.array([str(i) for i in range(n)]))
    for seed in range(15):
        model = train(ds, cfg, random_state=seed, n_jobs=1)
        assert model.metrics["grouped_split"]["n_train"] > 0


# ----------------------------------------------------------------------------------------------
# k. Image formats Pillow reads but cannot write: refused before any work
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize(("suffix", "why"), [(".xbm", "cannot write XBM images (cannot write mode RGB as XBM)"),
                                             (".h5", "cannot write HDF5 images (HDF5 save handler not installed)"),
                                             (".psd", "cannot write PSD images (Pillow can read this format but not write it)")])  # fmt: skip
def test_unwritable_image_format_refused_before_detection(tmp_path, capsys, monkeypatch, suffix, why):
    from vehicle_detection.detector import Detector

    def no_work(self, image):
        raise AssertionError("detection ran before the output format was checked")

    monkeypatch.setattr(Detector, "detect_image", no_work)
    img = save(tmp_path / "street.png", picture())
    out = tmp_path / f"annotated{suffix}"
    code, _, err = run_main(capsys, "detect", img, "--out", out)
    assert code == 5
    assert err == [f"{ERROR}{out}: {why}; use .png or .jpg"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["street.png"]


# ----------------------------------------------------------------------------------------------
# l. A closed stdout pipe: the outputs are written, the exit is quiet
# ----------------------------------------------------------------------------------------------


@posix_only
@pytest.mark.parametrize("buffering", ["unbuffered", "buffered"])
def test_closed_stdout_keeps_the_outputs_and_exits_quietly(tmp_path, buffering):
    shots = tmp_path / "shots"
    shots.mkdir()
    for i in range(2):
        save(shots / f"a{i}.png", picture(seed=i))
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader is gone before the first line is written (| head -0)
    env = dict(os.environ, PYTHONUNBUFFERED="1") if buffering == "unbuffered" else {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}
    try:
        proc = subprocess.run(
            [sys.executable, "-m", "vehicle_detection.cli", "detect", str(shots)],
            stdout=write_end, stderr=subprocess.PIPE, text=True, timeout=300, cwd=REPO, env=env,
        )  # fmt: skip
    finally:
        os.close(write_end)
    assert (proc.returncode, proc.stderr) == (0, "")
    done = tmp_path / "shots_detected"
    assert sorted(p.name for p in done.iterdir()) == ["a0.png", "a1.png", "boxes.csv"]
    assert read_image(done / "a0.png").shape == (72, 128, 3)


# ----------------------------------------------------------------------------------------------
# n. EXIF orientation is applied
# ----------------------------------------------------------------------------------------------

# What each EXIF orientation value does to the stored pixels to show them upright.
UPRIGHT = {
    1: lambda a: a,
    2: lambda a: a[:, ::-1],
    3: lambda a: a[::-1, ::-1],
    4: lambda a: a[::-1],
    5: lambda a: a.swapaxes(0, 1),
    6: lambda a: np.rot90(a, -1),  # stored rotated 90 degrees counter-clockwise: turn clockwise
    7: lambda a: np.rot90(a, 2).swapaxes(0, 1),
    8: lambda a: np.rot90(a, 1),
}


def _with_orientation(arr: np.ndarray, orientation: int, fmt: str) -> bytes:
    img = Image.fromarray(arr)
    exif = img.getexif()
    exif[0x0112] = orientation
    buf = io.BytesIO()
    img.save(buf, format=fmt, exif=exif.tobytes(), **({"quality": 95} if fmt == "JPEG" else {}))
    return buf.getvalue()


@pytest.mark.parametrize("orientation", range(1, 9))
def test_exif_orientation_applied(orientation):
    stored = picture(6, 10, seed=orientation)
    png = _with_orientation(stored, orientation, "PNG")
    got = decode_image(png, "x.png")
    np.testing.assert_array_equal(got, UPRIGHT[orientation](stored))
    np.testing.assert_array_equal(got, np.asarray(ImageOps.exif_transpose(Image.open(io.BytesIO(png))).convert("RGB")))
    jpeg = _with_orientation(picture(48, 80, seed=orientation), orientation, "JPEG")
    want = np.asarray(ImageOps.exif_transpose(Image.open(io.BytesIO(jpeg))).convert("RGB"))
    np.testing.assert_array_equal(decode_image(jpeg, "x.jpg"), want)


def test_exif_rotated_jpeg_is_detected_upright(tmp_path, capsys):
    stored = picture(72, 128)
    path = tmp_path / "phone.jpg"
    path.write_bytes(_with_orientation(stored, 6, "JPEG"))  # stored sideways: shown 72 wide, 128 high
    assert read_image(path).shape == (128, 72, 3)
    code, _, _ = run_main(capsys, "detect", path)
    assert code == 0
    assert read_image(tmp_path / "phone_detected.jpg").shape == (128, 72, 3)


def test_exif_orientation_counts_for_the_shape_check(tmp_path):
    path = tmp_path / "strip.jpg"
    path.write_bytes(_with_orientation(np.zeros((60, 400, 3), np.uint8), 8, "JPEG"))  # 400x60 stored, 60x400 shown
    with pytest.raises(InputError) as info:
        read_image(path)
    assert str(info.value) == f"{path}: image of 60x400 pixels is too tall (more than 1:4); crop it first"


def test_wide_video_refused_before_decoding(tmp_path, capsys):
    """b. for videos: a 4096x16 clip is refused from its size, with exit 3 and no output."""
    clip = media.encode(tmp_path / "strip.mp4", [np.zeros((16, 4096, 3), np.uint8)] * 3)
    code, _, err = run_main(capsys, "detect", clip, "--no-progress")
    assert code == 3
    assert err == [f"{ERROR}{clip}: image of 4096x16 pixels is too wide (more than 8:1); crop it first"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["strip.mp4"]


def test_search_refuses_absurd_arrays():
    from vehicle_detection.detector import Detector

    with pytest.raises(InputError, match="too wide"):
        Detector().detect_image(np.zeros((10, 20000, 3), np.uint8))
