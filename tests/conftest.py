"""Shared fixtures: where the real data is, and a small model trained on it once per session."""

from __future__ import annotations

import os
import sys
from pathlib import Path


def _write_bytecode() -> None:
    """Where the environment writes no bytecode (``PYTHONDONTWRITEBYTECODE``, as on the project's
    machines), every process the tests start (the command line, the notebooks' kernels, the tools:
    hundreds) would compile the package from source, and each xdist worker would rewrite the test
    modules' asserts afresh. The test run writes the bytecode of the checkout's modules as Python
    does by default (``__pycache__/`` beside them, ignored by git), and the processes it starts,
    the workers included, inherit that. Installed packages keep the bytecode their install wrote."""
    if sys.dont_write_bytecode:
        os.environ.pop("PYTHONDONTWRITEBYTECODE", None)
        sys.dont_write_bytecode = False


_write_bytecode()

import numpy as np  # noqa: E402  (after the bytecode's folder is set)
import pytest

REPO = Path(__file__).resolve().parents[1]


def pytest_configure(config) -> None:
    """One thread for the libraries' own pools in each xdist worker.

    The suite runs one worker per core (``-n auto``); OpenCV's, numba's and BLAS's thread pools
    start a thread per core in every worker, so two workers on two cores run four compute threads
    that wait on each other. With one each, ``tests/test_inputs.py`` took 13 % to 14 % less CPU
    time (2 pairs of runs, ``/usr/bin/time``). Only the test process is set: the processes the tests
    start keep their defaults, and a run without workers (``-n 0``) keeps every core.
    """
    if os.environ.get("PYTEST_XDIST_WORKER"):
        import cv2
        import numba
        from threadpoolctl import threadpool_limits

        cv2.setNumThreads(1)
        numba.set_num_threads(1)
        threadpool_limits(1)


def shared_data_dir() -> Path:
    """``$VEHICLE_DETECTION_DATA`` if set, else ``<repo>/../shared/data``."""
    env = os.environ.get("VEHICLE_DETECTION_DATA")
    return Path(env) if env else REPO.parent / "shared" / "data"


def has_training_data() -> bool:
    d = shared_data_dir()
    return (d / "vehicles.zip").is_file() and (d / "non-vehicles.zip").is_file()


requires_data = pytest.mark.skipif(
    not has_training_data(),
    reason=f"training archives not found in {shared_data_dir()} (set VEHICLE_DETECTION_DATA to the folder holding vehicles.zip and non-vehicles.zip)",
)


@pytest.fixture(scope="session", autouse=True)
def _in_session_tmp_path(tmp_path_factory):
    """The session's fixtures too (module-scoped runs of the command line) write nowhere in the checkout."""
    before = os.getcwd()
    os.chdir(tmp_path_factory.mktemp("cwd"))
    yield
    os.chdir(before)


@pytest.fixture(autouse=True)
def _in_tmp_path(tmp_path, monkeypatch):
    """Each test runs in its own temporary folder: the command line writes its default outputs
    into the current folder, never into the checkout."""
    monkeypatch.chdir(tmp_path)


@pytest.fixture(scope="session")
def data_dir() -> Path:
    if not has_training_data():
        pytest.skip(f"training archives not found in {shared_data_dir()} (set VEHICLE_DETECTION_DATA)")
    return shared_data_dir()


@pytest.fixture(scope="session")
def dataset(data_dir):
    from vehicle_detection.training.data import load_dataset

    return load_dataset(data_dir)


@pytest.fixture(scope="session")
def small_model(dataset):
    """A model with the default feature config trained on 1,000 random patches of the archives
    (a second): it classifies real patches 99.5 % right, all its tests ask of it."""
    from vehicle_detection.classifier import VehicleClassifier
    from vehicle_detection.features import FeatureConfig, extract_features

    idx = np.random.default_rng(0).choice(len(dataset), 1000, replace=False)
    cfg = FeatureConfig()
    return VehicleClassifier.fit(extract_features(dataset.images[idx], cfg), dataset.labels[idx], cfg)


def small_archives(folder: Path, per_class: int) -> Path:
    """``vehicles.zip`` and ``non-vehicles.zip`` in ``folder`` with ``per_class`` images of each
    class, spread evenly over the shared archives (every source folder, many file-number blocks)."""
    import zipfile

    folder.mkdir(parents=True, exist_ok=True)
    for cls in ("vehicles", "non-vehicles"):
        with zipfile.ZipFile(shared_data_dir() / f"{cls}.zip") as src, zipfile.ZipFile(folder / f"{cls}.zip", "w") as dst:
            names = sorted(n for n in src.namelist() if n.endswith(".png"))
            for name in names[:: len(names) // per_class][:per_class]:
                dst.writestr(name, src.read(name))
    return folder


@pytest.fixture(scope="module")
def long_video(tmp_path_factory):
    """``test_video.mp4`` looped 6 times (228 frames, no re-encoding): longer than a run lasts
    before a test stops it."""
    import media

    video = REPO / "test_video.mp4"
    if not video.is_file():
        pytest.skip("test_video.mp4 not in the checkout")
    path = tmp_path_factory.mktemp("long") / "long.mp4"
    media.copy_packets(video, path, loops=6)
    return path


@pytest.fixture(scope="session")
def test_frames():
    """The six committed 1280x720 test images, RGB uint8."""
    from vehicle_detection.io.images import read_image

    return [read_image(p) for p in sorted((REPO / "test_images").glob("test*.jpg"))]


@pytest.fixture(scope="session")
def default_model():
    """The embedded model the package ships (no training data needed)."""
    from vehicle_detection.classifier import load_default_model

    return load_default_model()


@pytest.fixture(scope="session")
def shipped_patches(test_frames):
    """60 RGB 64x64 patches cut from the shipped test images at random places and sizes: cars,
    road, trees and sky, as the search sees them (resized with INTER_AREA)."""
    import cv2

    rng = np.random.default_rng(7)
    out = []
    for k in range(60):
        frame = test_frames[k % len(test_frames)]
        side = int(rng.integers(48, 200))
        y = int(rng.integers(0, frame.shape[0] - side))
        x = int(rng.integers(0, frame.shape[1] - side))
        out.append(cv2.resize(frame[y : y + side, x : x + side], (64, 64), interpolation=cv2.INTER_AREA))
    return np.stack(out)


@pytest.fixture(scope="session")
def calibrated_camera():
    """The project camera calibrated on the twenty shared chessboard photos (seconds; once a worker)."""
    from vehicle_detection.road.camera import calibrate

    folder = shared_data_dir() / "camera_cal"
    if not folder.is_dir():
        pytest.skip(f"no chessboard photos at {folder}")
    return calibrate(folder)
