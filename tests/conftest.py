"""Shared fixtures: where the real data is, and a small model trained on it once per session."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]


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


@pytest.fixture(scope="session")
def data_dir() -> Path:
    if not has_training_data():
        pytest.skip(f"training archives not found in {shared_data_dir()} (set VEHICLE_DETECTION_DATA)")
    return shared_data_dir()


@pytest.fixture(scope="session")
def dataset(data_dir):
    from vehicle_detection.data import load_dataset

    return load_dataset(data_dir)


@pytest.fixture(scope="session")
def small_model(dataset):
    """A model with the default feature config trained on 3,000 random patches (seconds)."""
    from vehicle_detection.classifier import VehicleClassifier
    from vehicle_detection.features import FeatureConfig, extract_features

    idx = np.random.default_rng(0).choice(len(dataset), 3000, replace=False)
    cfg = FeatureConfig()
    return VehicleClassifier.fit(extract_features(dataset.images[idx], cfg), dataset.labels[idx], cfg)


@pytest.fixture(scope="session")
def test_frames():
    """The six committed 1280x720 test images, RGB uint8."""
    from vehicle_detection.images import read_image

    return [read_image(p) for p in sorted((REPO / "test_images").glob("test*.jpg"))]
