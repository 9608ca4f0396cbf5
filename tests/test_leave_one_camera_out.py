"""tools/leave_one_camera_out.py: a camera left out gives its model no frame, no label and no
archive patch of its own."""

from __future__ import annotations

import importlib.util
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def loco():
    spec = importlib.util.spec_from_file_location("leave_one_camera_out", ROOT / "tools" / "leave_one_camera_out.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _footage(path: Path) -> tuple[str, str]:
    """The camera a labels file names (or the project camera's frame size) and its video's file name."""
    d = json.loads(path.read_text())
    return d.get("camera", "project"), Path(d["video"]).name


def test_no_fold_trains_on_the_camera_it_scores(loco):
    cameras = list(loco.CAMERAS)
    assert len(cameras) == 5
    for cam, train_cams, scored, without_extras in loco.folds(cameras, cameras):
        assert cam not in train_cams and sorted(train_cams + [cam]) == sorted(cameras)
        scored_footage = {_footage(loco.DEV / f) for f in scored}
        trained = {_footage(f) for f in loco.training_labels(train_cams)}
        assert {c for c, _ in scored_footage} == {cam}
        assert not {c for c, _ in trained} & {cam}
        assert not {v for _, v in trained} & {v for _, v in scored_footage}
        # the archives' non-vehicles/Extras are frames of the project video
        assert without_extras == (cam == "project")


def test_every_camera_has_a_held_out_split_apart_from_its_training_frames(loco):
    for cam, (train, scored, heldout) in loco.CAMERAS.items():
        frames = {f: set(json.loads((loco.DEV / f).read_text())["frames"]) for f in {*train, *heldout}}
        for h in heldout:
            for t in train:
                assert not frames[h] & frames[t], (cam, h, t)
