"""Cuts between shots: the rule on made-up frames, and where it finds cuts in real footage."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from conftest import shared_data_dir

from vehicle_detection.footage.shots import THUMBNAIL, ShotCuts, frame_change, next_shot, thumbnail

HIGHWAY = shared_data_dir() / "videos" / "highway_dashcam_854x480.mp4"


def _cuts(frames, rule=ShotCuts()):
    previous, changes, cuts = None, (), []
    for i, frame in enumerate(frames):
        cut, previous, changes = next_shot(frame, previous, changes, rule)
        if cut:
            cuts.append(i)
    return cuts


def _scene(seed, shape=(360, 640, 3)):
    return np.random.default_rng(seed).integers(0, 256, (shape[0] // 40, shape[1] // 40, 3)).astype(np.uint8).repeat(40, 0).repeat(40, 1)


def test_settings_are_checked_and_round_trip():
    rule = ShotCuts(threshold=20, ratio=2, memory=4)
    assert ShotCuts.from_dict(rule.to_dict()) == rule and isinstance(rule.threshold, float)
    for bad in (dict(threshold=0), dict(threshold=float("nan")), dict(ratio=0.5), dict(memory=0), dict(memory=2.5), dict(ratio=True)):
        with pytest.raises(ValueError, match="ShotCuts"):
            ShotCuts(**bad)
    with pytest.raises(ValueError, match="keys"):
        ShotCuts.from_dict({"threshold": 30.0})


def test_thumbnail_does_not_depend_on_the_frame_size():
    big = _scene(1, (720, 1280, 3))
    small = cv2.resize(big, (640, 360), interpolation=cv2.INTER_AREA)
    a, b = thumbnail(big), thumbnail(small)
    assert a.shape == b.shape == (THUMBNAIL[1], THUMBNAIL[0], 3) and a.dtype == np.float32
    assert frame_change(a, b) < 1.0 and frame_change(a, a) == 0.0


def test_a_jump_to_another_scene_is_a_cut_and_nothing_else_is():
    shot_a = [np.clip(_scene(1).astype(int) + k, 0, 255).astype(np.uint8) for k in range(6)]  # slowly brightening
    shot_b = [_scene(2)] * 5
    assert _cuts(shot_a + shot_b) == [6]
    assert _cuts(shot_a) == [] and _cuts(shot_b) == []


def test_footage_changing_a_lot_every_frame_is_not_cut_at_every_frame():
    """A time lapse: every frame another scene. Only the second frame (nothing known before it) can
    be a cut; afterwards the usual change is as large as each new one."""
    frames = [_scene(seed) for seed in range(12)]
    changes = [frame_change(thumbnail(a), thumbnail(b)) for a, b in zip(frames, frames[1:])]
    assert min(changes) > ShotCuts().threshold  # each would be a cut by the threshold alone
    assert _cuts(frames) == [1]


def test_the_threshold_and_the_ratio_both_decide():
    a, b = _scene(1), _scene(2)
    jump = frame_change(thumbnail(a), thumbnail(b))
    assert jump > ShotCuts().threshold
    assert _cuts([a, a, b]) == [2] and _cuts([a, a, b], ShotCuts(threshold=jump + 1)) == []
    wobble = a.copy()
    wobble[: a.shape[0] // 4] = b[: a.shape[0] // 4]  # a quarter of the frame changes back and forth
    small = frame_change(thumbnail(a), thumbnail(wobble))
    assert small < ShotCuts().threshold < jump
    frames = [a, wobble, a, wobble, a, b]  # the jump after changes of `small`
    assert _cuts(frames, ShotCuts(ratio=0.9 * jump / small)) == [5]
    assert _cuts(frames, ShotCuts(ratio=1.1 * jump / small)) == []


def test_a_sudden_change_of_light_is_not_a_cut():
    """A bridge's shadow or the camera's exposure: the same scene at 0.45 of its light for a few
    frames. Compared as they are, the thumbnails would differ by far more than the threshold."""
    lit = _scene(1)
    dark = np.rint(lit * 0.45).astype(np.uint8)
    assert np.abs(thumbnail(lit) - thumbnail(dark)).mean() > 2 * ShotCuts().threshold
    assert frame_change(thumbnail(lit), thumbnail(dark)) < 1.0
    assert _cuts([lit] * 4 + [dark] * 4 + [lit] * 2) == []


@pytest.mark.parametrize("name", ["test_video.mp4", "dev_set/project_video_clip_A.mp4"])
def test_continuous_footage_has_no_cut(name):
    from pathlib import Path

    from vehicle_detection.io.video import read_frames

    assert _cuts(read_frames(Path(__file__).resolve().parents[1] / name)) == []


@pytest.mark.skipif(not HIGHWAY.is_file(), reason=f"{HIGHWAY} not found (the shared highway dashcam clip)")
def test_the_highway_clip_is_cut_where_its_replays_begin():
    """The dashcam clip cuts to a zoomed replay at frame 363 and to a replay of an earlier
    stretch at 434 (dev_set/README.md); it has no other cut."""
    from vehicle_detection.io.video import read_frames

    assert _cuts(read_frames(HIGHWAY)) == [363, 434]
