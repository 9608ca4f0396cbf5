"""The bird's-eye transform from the footage: a synthetic road seen by a known camera, refusals, camera files, real videos."""

from __future__ import annotations

import functools
import json
import math

import cv2
import numpy as np
import pytest

from conftest import REPO, shared_data_dir
from vehicle_detection.errors import OutputError
from vehicle_detection.road.autocamera import (
    camera_from_estimate,
    estimate_birds_eye,
    estimate_birds_eye_from_video,
    road_figure,
    road_transform,
    sample_frames,
    save_estimate,
)
from vehicle_detection.road.camera import Camera

# The synthetic camera: a pinhole 1.3 m above a flat road, pitched 2 degrees down, no roll.
W, H = 960, 540
F = 800.0
CX, CY = W / 2, H / 2
HEIGHT_M = 1.3
PITCH_DEG = 2.0
VANISHING_ROW = CY - F * math.tan(math.radians(PITCH_DEG))  # 242.1
LANE_M = 3.7
DASH_M, GAP_M = 3.0, 9.0  # the library's 12 m period


def project(x_m, z_m, *, pitch_deg=PITCH_DEG, height_m=HEIGHT_M):
    """Ground points (metres right of the camera, metres ahead of it) -> camera pixels ``(n, 2)``."""
    t = math.radians(pitch_deg)
    x, y, z = np.asarray(x_m, float), np.full(np.shape(x_m), height_m), np.asarray(z_m, float)
    yc = y * math.cos(t) - z * math.sin(t)
    zc = y * math.sin(t) + z * math.cos(t)
    return np.c_[CX + F * x / zc, CY + F * yc / zc]


@functools.lru_cache(maxsize=4)
def _road_geometry(pitch_deg: float, height_m: float, lines: tuple) -> tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray]]]:
    """What :func:`road_frame` draws that does not move: the 2x supersampled frame with the road,
    the sky and the solid lines, and for each line, the flat indices of its pixels and their
    distances ahead (where dashes are cut). Computed once for a camera and a set of lines."""
    s = 2
    u, v = np.meshgrid((np.arange(W * s) + 0.5) / s, (np.arange(H * s) + 0.5) / s)
    t = math.radians(pitch_deg)
    dx, dy, dz = (u - CX) / F, (v - CY) / F, np.ones_like(u)
    wy = dy * math.cos(t) + dz * math.sin(t)  # the ray in road coordinates (y down)
    wz = -dy * math.sin(t) + dz * math.cos(t)
    ground = wy > 1e-6
    with np.errstate(divide="ignore", invalid="ignore"):
        k = np.where(ground, height_m / wy, np.nan)
    gx, gz = k * dx, k * wz
    img = np.where(ground, 95.0, 175.0)
    painted = []
    for x0 in lines:
        on = np.flatnonzero(ground & (np.abs(gx - x0) < 0.075))
        painted.append((on, gz.ravel()[on]))
    for arr in (img, *(a for pair in painted for a in pair)):
        arr.flags.writeable = False
    return img, painted


def road_frame(phase_m: float, *, lines=(-1.5 * LANE_M, -LANE_M / 2, LANE_M / 2, 1.5 * LANE_M), dashed=(True, False, True, True),
               pitch_deg=PITCH_DEG, height_m=HEIGHT_M, seed=0) -> np.ndarray:
    """An RGB frame of a straight road rendered through the camera (2x supersampled), the car centred in its lane.

    ``lines``: lateral positions of the painted lines (metres); ``dashed``: 3 m dashes every 12 m,
    moved ``phase_m`` towards the car; otherwise solid.
    """
    base, painted = _road_geometry(pitch_deg, height_m, tuple(lines))
    img = base.copy()
    flat = img.reshape(-1)
    for (on, gz), dash in zip(painted, dashed):
        if dash:
            on = on[np.mod(gz + phase_m, DASH_M + GAP_M) < DASH_M]
        flat[on] = 225.0
    img = cv2.resize(img.astype(np.float32), (W, H), interpolation=cv2.INTER_AREA)
    img += np.random.default_rng(seed).normal(0, 3, img.shape)
    grey = np.clip(img, 0, 255).astype(np.uint8)
    return np.repeat(grey[..., None], 3, axis=2)


@pytest.fixture(scope="module")
def synthetic_frames():
    return [road_frame(2.3 * i, seed=i) for i in range(12)]  # 2.3 m of travel between frames


@pytest.fixture(scope="module")
def synthetic_estimate(synthetic_frames):
    return estimate_birds_eye(synthetic_frames)


def test_synthetic_road_recovers_the_pitch(synthetic_estimate):
    view, est = synthetic_estimate
    assert view is not None and est.ok, est.reason
    assert len(est.frames_used) >= 10 and est.frames_with_dashes >= 8
    vx, vy = est.vanishing_point
    assert vy == pytest.approx(VANISHING_ROW, abs=3.0)  # 3 px: 0.2 degrees of pitch at f = 800 px
    assert vx == pytest.approx(CX, abs=6.0)
    pitch = math.degrees(math.atan2(CY - vy, F))
    assert pitch == pytest.approx(PITCH_DEG, abs=0.25)
    assert est.pitch_deg == pytest.approx(PITCH_DEG, abs=0.5)  # from the implied focal length
    assert est.camera_height_m == pytest.approx(HEIGHT_M, rel=0.05)
    assert est.focal_px == pytest.approx(F, rel=0.08)


def test_synthetic_road_recovers_the_scale(synthetic_estimate):
    view, est = synthetic_estimate
    # along the road: distances between ground points 8 to 40 m ahead, within 5 %
    z = np.array([8.0, 12.0, 20.0, 30.0, 40.0])
    d = view.ground_distance(project(np.zeros_like(z), z))
    np.testing.assert_allclose(np.diff(d), np.diff(z), rtol=0.05)
    # across: the lane's two lines 3.7 m apart at any distance, within 3 %
    for zz in (8.0, 20.0):
        xw = view.to_warped(project([-LANE_M / 2, LANE_M / 2], [zz, zz]))[:, 0]
        assert (xw[1] - xw[0]) * view.xm_per_px == pytest.approx(LANE_M, rel=0.03)
    # the car is centred in its lane: no offset
    assert view.vehicle_x == pytest.approx((view.dst[0, 0] + view.dst[3, 0]) / 2, abs=0.1 / view.xm_per_px)
    assert est.xm_per_px == view.xm_per_px and est.ym_per_px == view.ym_per_px
    lo, hi = est.interval["ym_per_px"]
    assert lo <= est.ym_per_px <= hi and est.spread["vanishing_y_px"] < 5


def test_another_pitch_and_height():
    frames = [road_frame(3.1 * i, pitch_deg=5.0, height_m=1.6, seed=i) for i in range(10)]
    view, est = estimate_birds_eye(frames)
    assert view is not None, est.reason
    assert est.vanishing_point[1] == pytest.approx(CY - F * math.tan(math.radians(5.0)), abs=3.0)
    assert est.camera_height_m == pytest.approx(1.6, rel=0.06)
    z = np.array([10.0, 25.0])
    d = view.ground_distance(project([0, 0], z, pitch_deg=5.0, height_m=1.6))
    assert d[1] - d[0] == pytest.approx(15.0, rel=0.05)


def test_no_lines_gives_none_with_a_reason():
    frames = [road_frame(0, lines=(), dashed=(), seed=i) for i in range(8)]
    view, est = estimate_birds_eye(frames)
    assert view is None and not est.ok
    assert "no lane lines" in est.reason
    assert est.frames_sampled == 8 and est.frames_used == ()
    assert est.summary()[0].startswith("no lanes:")


def test_one_line_is_not_a_lane():
    frames = [road_frame(2.0 * i, lines=(LANE_M / 2,), dashed=(True,), seed=i) for i in range(8)]
    view, est = estimate_birds_eye(frames)
    assert view is None and "no lane lines" in est.reason


def test_solid_lines_give_no_scale_along_the_road():
    frames = [road_frame(0, dashed=(False, False, False, False), seed=i) for i in range(8)]
    view, est = estimate_birds_eye(frames)
    assert view is None and "dashes" in est.reason
    assert len(est.frames_used) >= 5  # the lines were seen; only the scale is missing
    assert est.vanishing_point[1] == pytest.approx(VANISHING_ROW, abs=3.0)


def test_frames_of_other_sizes_are_refused(synthetic_frames):
    with pytest.raises(ValueError, match="one size"):
        estimate_birds_eye([synthetic_frames[0], synthetic_frames[1][:-2]])


def test_saved_estimate_is_a_camera_file(synthetic_estimate, tmp_path):
    view, est = synthetic_estimate
    path = save_estimate(tmp_path / "auto.json", view, est)
    cam = Camera.load(path)  # what --camera reads
    assert cam.birds_eye is not None
    np.testing.assert_allclose(cam.birds_eye.src, view.src)
    assert cam.birds_eye.ym_per_px == pytest.approx(view.ym_per_px)
    assert not np.any(cam.distortion)
    frame = road_frame(0)
    np.testing.assert_array_equal(cam.undistort(frame), frame)  # no lens distortion assumed
    saved = json.loads(path.read_text())["road_estimate"]
    assert saved["frames_used"] == list(est.frames_used) and saved["interval"]["vanishing_y_px"][0] <= saved["vanishing_point"][1]
    with pytest.raises(OutputError):
        save_estimate(path, view, est)  # no overwrite without overwrite=True
    assert save_estimate(path, view, est, overwrite=True) == path


def test_camera_file_wins(synthetic_estimate, tmp_path):
    view, est = synthetic_estimate
    given = camera_from_estimate(view, est)
    be, report = road_transform(tmp_path / "never-read.mp4", given)
    assert be is given.birds_eye and report.source == "camera file"
    assert report.summary() == ["bird's-eye view: from the camera file"]


def test_road_figure(synthetic_frames, synthetic_estimate):
    from vehicle_detection.road.lanes import LaneTracker

    view, est = synthetic_estimate
    lanes = [LaneTracker(view).step(f) for f in synthetic_frames[:2]]
    assert all(lane is not None and abs(lane.offset_m) < 0.2 for lane in lanes)
    fig = road_figure(synthetic_frames[:2], view, est, lanes=lanes, distances={"track 1": (np.arange(5), np.linspace(30, 10, 5))})
    assert len(fig.axes) == 4
    assert "cm/px" in fig.axes[2].get_title()
    import matplotlib.pyplot as plt

    plt.close(fig)


# --- real videos --------------------------------------------------------------------------------

CLIP_A = shared_data_dir() / "videos" / "project_video_clip_A.mp4"
HIGHWAY = shared_data_dir() / "videos" / "highway_dashcam_854x480.mp4"


def test_sample_frames_spread_over_the_stretch():
    idx, frames = sample_frames(REPO / "test_video.mp4", seconds=1.0, max_frames=6)
    assert idx == [0, 5, 10, 14, 19, 24] and len(frames) == 6 and frames[0].shape == (720, 1280, 3)


@pytest.fixture(scope="module")
def test_video_estimate():
    video = REPO / "test_video.mp4"
    if not video.is_file():
        pytest.skip("test_video.mp4 not in the checkout")
    return estimate_birds_eye_from_video(video)


def test_test_video(test_video_estimate):
    view, est = test_video_estimate
    assert view is not None, est.reason
    assert len(est.frames_used) >= 30
    # the project camera's road vanishes at 0.583 of the height (its calibrated straight-road lines cross there)
    assert est.vanishing_point[1] / 720 == pytest.approx(0.583, abs=0.01)
    assert 1.0 < est.camera_height_m < 1.5


@pytest.mark.skipif(not (shared_data_dir() / "camera_cal").is_dir(), reason=f"no chessboard photos in {shared_data_dir()}")
def test_test_video_distances_against_the_calibrated_camera(test_video_estimate, calibrated_camera):
    from vehicle_detection.io.images import read_image
    from vehicle_detection.road.lanes import birds_eye_from_straight

    cam = calibrated_camera
    cal = birds_eye_from_straight([read_image(shared_data_dir() / "lanes" / f"straight_lines{i}.jpg") for i in (1, 2)], cam)
    view, _ = test_video_estimate
    # points on the road straight ahead, 4 to 30 m (calibrated) beyond the bottom row
    pts = np.c_[np.full(5, 650.0), [560, 520, 490, 470, 455]]
    dc = cal.ground_distance(cam.undistort_points(pts))
    da = view.ground_distance(pts)
    assert np.all((dc > 4) & (dc < 30))
    np.testing.assert_allclose(da, dc, rtol=0.1)


@pytest.mark.skipif(not CLIP_A.is_file(), reason=f"{CLIP_A} not found (the shared data)")
def test_clip_a():
    view, est = estimate_birds_eye_from_video(CLIP_A, max_frames=20)  # 20 of the default 60 frames, over the same 10 s
    assert view is not None, est.reason
    assert est.vanishing_point[1] / 720 == pytest.approx(0.583, abs=0.01)
    assert len(est.frames_used) >= 14


@pytest.mark.skipif(not HIGHWAY.is_file(), reason=f"{HIGHWAY} not found (the shared data; not redistributable, so not in the repository)")
def test_highway_dashcam():
    view, est = estimate_birds_eye_from_video(HIGHWAY)
    assert view is not None, est.reason
    # another camera: its road vanishes higher than the project camera's (0.583), near half the height
    assert 0.48 < est.vanishing_point[1] / 480 < 0.54
    assert 0.6 < _lane_width_share(est) < 0.9  # the lane spans most of the bottom row of this wide lens
    assert 1.0 < est.camera_height_m < 1.8


def _lane_width_share(est) -> float:
    w, h = est.image_size
    return float(np.polyval(est.right_line, h) - np.polyval(est.left_line, h)) / w
