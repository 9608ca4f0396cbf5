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

import imageio_ffmpeg
import numpy as np
import pytest
from PIL import Image, ImageFile, ImageOps

from vehicle_detection._files import PARTIAL_SUFFIX, atomic_output, check_output_path
from vehicle_detection.cli import main
from vehicle_detection.errors import InputError, OutputError
from vehicle_detection.features import FeatureConfig
from vehicle_detection.images import decode_image, read_image

REPO = Path(__file__).resolve().parents[1]
TEST_VIDEO = REPO / "test_video.mp4"
TEST_IMAGES = REPO / "test_images"
FFMPEG = imageio_ffmpeg.get_ffmpeg_exe()
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
    from vehicle_detection.search import SearchPlan, SearchScale, search, search_plain

    rng = np.random.default_rng(1)
    model = VehicleClassifier.fit(rng.normal(size=(20, cfg.n_features)), np.repeat([0, 1], 10), cfg)
    frame = rng.integers(0, 256, (720, 160, 3), dtype=np.uint8)
    plan = SearchPlan(scales=(SearchScale(1.0, 400, 496),))
    fast = search(frame, model, plan, all_windows=True)
    assert len(fast) > 0
    np.testing.assert_allclose(fast.scores, search_plain(frame, model, plan).scores, atol=1e-4)


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


def test_cli_boundary_feature_options_are_accepted(tmp_path, capsys):
    # Accepted: the run goes on to look for the data (exit 3), instead of refusing the options.
    code, _, err = run_main(capsys, "train", "--cells-per-block", "6", "--data-dir", tmp_path / "nowhere")
    assert code == 3 and err == [f"{ERROR}{tmp_path / 'nowhere'}: data folder not found; run `vehicle-detection download` or pass --data-dir (or set $VEHICLE_DETECTION_DATA)"]


