"""Lane finding, radius and offset on synthetic bird's-eye roads; distances; the CSV columns; the real frames."""

from __future__ import annotations

import csv

import cv2
import media
import numpy as np
import pytest

from conftest import REPO, shared_data_dir
from vehicle_detection.detections import Detections
from vehicle_detection.road.distance import DistanceTracker
from vehicle_detection.road.lanes import (
    BirdsEye,
    Lane,
    LaneTracker,
    birds_eye_from_straight,
    draw_lane,
    fit_lanes,
    fit_parallel_lanes,
    lane_measures,
    lane_sane,
    vertical_paint,
)
from vehicle_detection.io.tables import BOXES_CSV_HEADER, read_boxes_csv, write_boxes_csv, write_lanes_csv

W, H = 640, 360
XM = 3.7 / 320  # lines 320 px apart
YM = 0.1


def identity_view() -> BirdsEye:
    """A 'camera' that already looks straight down: the warp is the identity."""
    pts = [[160, H], [160, 0], [480, 0], [480, H]]
    return BirdsEye(pts, pts, (W, H), (W, H), XM, YM)


def synthetic_road(radius_m: float, shift_px: float, *, dashed: bool = True, width_px: float = 320) -> np.ndarray:
    """A warped binary image of a lane curving with ``radius_m`` (at the bottom), shifted ``shift_px`` right."""
    img = np.zeros((H, W), np.uint8)
    y = np.arange(H)
    y_m = (H - 1 - y) * YM
    bend = (radius_m - np.sqrt(np.maximum(radius_m**2 - y_m**2, 0))) / XM  # a circle through the bottom
    for base in (160 + shift_px, 160 + width_px + shift_px):
        x = base + bend
        for yy in range(H):
            if dashed and base > 300 and (yy // 30) % 3 == 2:
                continue  # gaps in the right line
            cv2.line(img, (int(round(x[yy])) - 4, yy), (int(round(x[yy])) + 4, yy), 1)
    return img


@pytest.mark.parametrize("radius", [400.0, 1000.0, 3000.0])
@pytest.mark.parametrize("shift", [-30.0, 0.0, 25.0])
def test_radius_and_offset_on_a_synthetic_road(radius, shift):
    view = identity_view()
    lane = LaneTracker(view).update(synthetic_road(radius, shift))
    assert lane is not None and lane.fresh
    assert lane.radius_m == pytest.approx(radius, rel=0.1)
    # the camera is at x = 320; the lane centre at 320 + shift: the car is left of centre for shift > 0
    assert lane.offset_m == pytest.approx(-shift * XM, abs=0.05)


def test_straight_road_is_very_flat():
    r, off = lane_measures(np.array([0, 0, 160.0]), np.array([0, 0, 480.0]), identity_view())
    assert r == float("inf") and off == pytest.approx(0.0)


def test_implausible_width_is_not_a_lane():
    view = identity_view()
    assert LaneTracker(view).update(synthetic_road(1000, 0, width_px=120)) is None  # 1.4 m: not a lane


def test_bad_frames_keep_the_last_fit_then_nothing():
    view = identity_view()
    tracker = LaneTracker(view, max_misses=3)
    good = tracker.update(synthetic_road(800, 0))
    assert good is not None and good.fresh
    empty = np.zeros((H, W), np.uint8)
    for _ in range(3):
        kept = tracker.update(empty)
        assert kept is not None and not kept.fresh
        np.testing.assert_allclose(kept.left_fit, good.left_fit)
    assert tracker.update(empty) is None  # after max_misses: no lane
    frame = np.zeros((H, W, 3), np.uint8)
    drawn = draw_lane(frame, None, view)
    assert drawn[100:, :].max() == 0  # no polygon, only the "not found" text at the top
    back = tracker.update(synthetic_road(800, 0))
    assert back is not None and back.fresh


def test_smoothing_averages_good_fits():
    view = identity_view()
    tracker = LaneTracker(view, smooth=2)
    tracker.update(synthetic_road(1000, 0))
    lane = tracker.update(synthetic_road(1000, 20))
    assert lane.offset_m == pytest.approx(-10 * XM, abs=0.05)  # the mean of 0 and 20 px


def short_dashes_with_glare() -> np.ndarray:
    """One short dash of each line, a bonnet's edge and a windscreen's slanted reflections (the
    854x480 highway dashcam's warped view, drawn on the synthetic road's geometry)."""
    img = np.zeros((H, W), np.uint8)
    cv2.rectangle(img, (156, 200), (164, 250), 1, -1)  # one dash of the left line, 5 m
    cv2.rectangle(img, (476, 215), (484, 250), 1, -1)  # one of the right line, 3.5 m
    for k in range(4):  # reflections: streaks slanting across the right line's windows
        cv2.line(img, (400 + 40 * k, 345), (640, 250 + 25 * k), 1, 1)
    cv2.line(img, (0, 345), (W, 340), 1, 2)  # the bonnet's edge
    return img


def test_short_dashes_among_reflections_make_a_lane():
    # The sliding windows used to take the streaks and the bonnet's edge for paint: no lane.
    lane = LaneTracker(identity_view()).update(short_dashes_with_glare())
    assert lane is not None and lane.fresh
    assert np.polyval(lane.left_fit, [0, H - 1]) == pytest.approx([160, 160], abs=2)
    assert np.polyval(lane.right_fit, [0, H - 1]) == pytest.approx([480, 480], abs=2)
    assert lane.offset_m == pytest.approx(0.0, abs=0.05)


def test_vertical_paint_keeps_lines_and_drops_slanted_and_flat_marks():
    img = short_dashes_with_glare()
    kept = vertical_paint(img, 5)
    ys, xs = kept.nonzero()
    assert set(np.unique(xs)) == set(range(156, 165)) | set(range(476, 485))
    assert vertical_paint(img, 1) is img


def one_dash_beside_a_curving_line(seed: int = 0):
    """A solid left line curving with a 500 m radius and one noisy 3 m dash of the right line."""
    rng = np.random.default_rng(seed)
    y = np.arange(H, dtype=float)
    bend = (500 - np.sqrt(500**2 - ((H - 1 - y) * YM) ** 2)) / XM
    lx, ly = np.repeat(160 + bend, 5) + np.tile(np.arange(-2, 3), H), np.repeat(y, 5)
    dy = np.arange(300, 330, dtype=float)
    ry = np.repeat(dy, 7)
    rx = np.repeat(480 + bend[300:330], 7) + np.tile(np.arange(-3, 4), 30) + rng.normal(0, 1.5, len(ry))
    return lx, ly, rx, ry, bend


def test_one_noisy_dash_borrows_the_other_lines_shape():
    view = identity_view()
    lx, ly, rx, ry, bend = one_dash_beside_a_curving_line()
    # on its own, the dash's parabola swings away: the lane is not sane
    assert not lane_sane(*fit_lanes(lx, ly, rx, ry), view)
    left, right = fit_parallel_lanes(lx, ly, rx, ry, H)
    assert lane_sane(left, right, view)
    y = np.array([0.0, H / 2, H - 1])
    np.testing.assert_allclose(np.polyval(right, y) - np.polyval(left, y), 320, atol=3)
    np.testing.assert_allclose(np.polyval(left, y), 160 + bend[y.astype(int)], atol=3)


def test_parallel_fit_needs_a_line_on_each_side():
    lx, ly, rx, ry, _ = one_dash_beside_a_curving_line()
    assert fit_parallel_lanes(lx, ly, rx[:10], ry[:10], H) == (None, None)  # too few pixels
    flat = ry * 0 + 315.0
    assert fit_parallel_lanes(lx, ly, rx, flat, H) == (None, None)  # no span along the road: a speck
    rng = np.random.default_rng(1)
    patch_x, patch_y = rng.uniform(420, 560, 400), rng.uniform(200, 330, 400)
    assert fit_parallel_lanes(lx, ly, patch_x, patch_y, H) == (None, None)  # a patch, not a line


def test_distance_from_the_box_bottom():
    view = identity_view()
    boxes = Detections([[300, 100, 340, H - 100], [300, 100, 340, H]], track_id=[0, 1])
    out = DistanceTracker(view, fps=25).update(boxes)
    np.testing.assert_allclose(out.data["distance_m"], [100 * YM, 0.0], atol=1e-6)
    assert np.isnan(out.data["relative_speed_mps"]).all()  # one frame: no speed yet


def test_relative_speed_from_successive_distances():
    view = identity_view()
    tracker = DistanceTracker(view, fps=25, min_points=3)
    speeds = []
    for f in range(10):
        bottom = H - 100 - f  # 1 px = 0.1 m farther each frame: 2.5 m/s pulling away
        out = tracker.update(Detections([[300, 50, 340, bottom]], track_id=[7], frame=f))
        speeds.append(out.data["relative_speed_mps"][0])
    assert np.isnan(speeds[:2]).all()
    np.testing.assert_allclose(speeds[2:], 2.5, rtol=1e-6)


def test_distance_above_the_horizon_is_nan():
    src = [[200, 700], [600, 450], [680, 450], [1100, 700]]
    dst = [[160, 360], [160, 0], [480, 0], [480, 360]]
    view = BirdsEye(src, dst, (1280, 720), (640, 360), XM, YM)
    d = view.ground_distance([[640, 700], [640, 500], [640, 300]])
    assert 0 <= d[0] < d[1] and np.isnan(d[2])


# --- the CSVs ----------------------------------------------------------------------------------


def test_boxes_csv_with_distance_columns_round_trip(tmp_path):
    d = Detections(
        [[1, 2, 30, 40], [5, 6, 70, 80]],
        score=[1.5, 2.25],
        track_id=[0, 1],
        frame=[3, 3],
        data={"distance_m": [12.345, np.nan], "relative_speed_mps": [np.nan, -1.5]},
    )
    path = write_boxes_csv(tmp_path / "b.csv", d)
    lines = path.read_text().splitlines()
    assert lines[0] == BOXES_CSV_HEADER + ",distance_m,relative_speed_mps"
    assert lines[1] == "3,1,2,30,40,0,1.5000,12.35," and lines[2] == "3,5,6,70,80,1,2.2500,,-1.50"
    back = read_boxes_csv(path)
    np.testing.assert_array_equal(back.xyxy, d.xyxy)
    np.testing.assert_allclose(back.data["distance_m"], [12.35, np.nan])
    np.testing.assert_allclose(back.data["relative_speed_mps"], [np.nan, -1.5])


def test_boxes_csv_without_distances_is_unchanged(tmp_path):
    d = Detections([[1, 2, 30, 40]], score=[1.5], track_id=[4], frame=[2], data={"scale_index": [1]})
    path = write_boxes_csv(tmp_path / "b.csv", d)
    assert path.read_text() == "frame,x1,y1,x2,y2,track_id,score\n2,1,2,30,40,4,1.5000\n"
    assert read_boxes_csv(path).data == {}


def test_boxes_csv_bad_distance_field(tmp_path):
    from vehicle_detection.errors import InputError

    p = tmp_path / "b.csv"
    p.write_text(BOXES_CSV_HEADER + ",distance_m,relative_speed_mps\n0,1,2,30,40,0,1.0,far,\n")
    with pytest.raises(InputError, match="line 2: distance_m 'far'"):
        read_boxes_csv(p)
    p.write_text(BOXES_CSV_HEADER + ",distance_m,relative_speed_mps\n0,1,2,30,40,0,1.0\n")
    with pytest.raises(InputError, match="expected 9 fields"):
        read_boxes_csv(p)


def test_lanes_csv(tmp_path):
    p = write_lanes_csv(tmp_path / "l.csv", [(0, 812.34, -0.3012), (1, None, None), (2, float("nan"), 0.1)])
    assert p.read_text() == "frame,curvature_m,offset_m\n0,812.3,-0.301\n1,,\n2,,0.100\n"


# --- the real frames ---------------------------------------------------------------------------

DATA = shared_data_dir()
needs_data = pytest.mark.skipif(
    not (DATA / "camera_cal").is_dir() or not (DATA / "lanes").is_dir(),
    reason=f"no chessboard photos or straight-road frames under {DATA}",
)


@pytest.fixture(scope="module")
def real_camera(calibrated_camera):
    from vehicle_detection.io.images import read_image

    cam = calibrated_camera
    frames = [read_image(DATA / "lanes" / f"straight_lines{i}.jpg") for i in (1, 2)]
    return cam.replace(birds_eye=birds_eye_from_straight(frames, cam)), frames


@needs_data
def test_birds_eye_from_the_straight_frames(real_camera):
    cam, frames = real_camera
    view = cam.birds_eye
    assert view.xm_per_px == pytest.approx(3.7 / 320)
    assert 0.06 < view.ym_per_px < 0.13  # 22 to 47 m of road in the 360 warped rows
    for f in frames:
        lane = LaneTracker(view).step(cam.undistort(f))
        assert lane is not None and lane.radius_m > 1500 and abs(lane.offset_m) < 0.5


@needs_data
def test_detect_with_lanes_on_the_test_video(real_camera, tmp_path, capsys):
    from vehicle_detection.cli import main

    cam, _ = real_camera
    cam_path = cam.save(tmp_path / "camera.json")
    clip = media.copy_packets(REPO / "test_video.mp4", tmp_path / "clip.mp4", max_frames=6)  # lanes and cars in each frame
    lanes_csv, boxes = tmp_path / "L.csv", tmp_path / "B.csv"
    code = main([
        "detect", str(clip), "--camera", str(cam_path), "--lanes-csv", str(lanes_csv),
        "--boxes", str(boxes), "--out", str(tmp_path / "o.mp4"), "--no-progress",
    ])
    assert code == 0
    # the camera file's road plane, not one estimated from these frames (which would succeed too)
    assert "from the footage" not in capsys.readouterr().out
    rows = list(csv.DictReader(lanes_csv.open()))
    assert len(rows) == 6
    radius = np.array([float(r["curvature_m"]) if r["curvature_m"] else np.nan for r in rows])
    offset = np.array([float(r["offset_m"]) if r["offset_m"] else np.nan for r in rows])
    assert np.mean((radius > 200) & (radius < 10_000)) > 0.8
    assert np.nanmax(np.abs(offset)) < 1.0
    table = read_boxes_csv(boxes)
    dist = table.data["distance_m"]
    assert len(table) and np.all((dist[np.isfinite(dist)] > 3) & (dist[np.isfinite(dist)] < 100))


def test_no_lane_is_carried_across_a_cut_between_shots():
    """A painted road, then a cut to a frame of grey blocks: with cuts found, the lane of the last
    shot is not kept (no stale fit is drawn over the new shot); taken as one shot, it coasts on."""
    from vehicle_detection.road.survey import Road
    from vehicle_detection.footage.shots import ShotCuts

    painted = np.where(synthetic_road(1000, 0)[..., None] > 0, 230, 70).astype(np.uint8).repeat(3, axis=2)
    blocks = np.random.default_rng(1).integers(0, 150, (H // 40, W // 40, 1)).astype(np.uint8).repeat(40, 0).repeat(40, 1).repeat(3, 2)
    frames = [painted] * 4 + [blocks] * 3
    found = Road(lanes=True, birds_eye=identity_view()).survey(25, shot_cuts=ShotCuts())
    lanes = [found.find_lane(f) for f in frames]
    assert all(lane is not None and lane.fresh for lane in lanes[:4]) and lanes[4:] == [None] * 3
    one_shot = Road(lanes=True, birds_eye=identity_view()).survey(25)
    kept = [one_shot.find_lane(f) for f in frames][4:]
    assert all(lane is not None and not lane.fresh for lane in kept)


# --- the lane and its caption drawn on other cameras' frames ----------------------------------------

BAR = 80  # pillarbox bars of a 640x360 frame holding a 480x360 picture


def frame_of(kind: str) -> np.ndarray:
    """A bright, a dark, a dusk (bright sky over a dark road) or a pillarboxed (black bars around a bright picture) frame."""
    frame = np.full((H, W, 3), {"bright": 255, "dark": 0, "dusk": 40, "pillarboxed": 235}[kind], np.uint8)
    if kind == "dusk":
        frame[: H // 2] = (235, 225, 210)
    if kind == "pillarboxed":
        frame[:, :BAR] = frame[:, W - BAR :] = 0
    return frame


def wide_lane() -> Lane:
    """A lane from x = 20 to x = 620 over the whole identity view: into any pillarbox bars."""
    return Lane(np.array([0.0, 0.0, 20.0]), np.array([0.0, 0.0, 620.0]), 850.0, -0.21, True)


def luminance(rgb) -> np.ndarray:
    """WCAG relative luminance of sRGB uint8 values (..., 3)."""
    c = np.asarray(rgb, np.float64) / 255
    c = np.where(c <= 0.03928, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)
    return c @ [0.2126, 0.7152, 0.0722]


@pytest.mark.parametrize("kind", ["bright", "dark", "dusk", "pillarboxed"])
@pytest.mark.parametrize("found", [True, False])
def test_lane_caption_reads_on_any_frame(kind, found):
    # White text straight on the frame could not be read over a bright sky (a 640x360 dusk clip).
    frame = frame_of(kind)
    drawn = draw_lane(frame, wide_lane() if found else None, identity_view(), alpha=0.0)  # the caption only
    changed = np.argwhere((drawn != frame).any(axis=2))
    assert len(changed), "no caption drawn (or drawn in the frame's own colours)"
    (y0, x0), (y1, x1) = changed.min(axis=0), changed.max(axis=0) + 1
    box = luminance(drawn[y0:y1, x0:x1])
    text, ground = box.max(), np.median(box)
    assert (text + 0.05) / (ground + 0.05) >= 4.5  # WCAG AA: the text against what lies around it
    assert y1 <= H // 2 and x0 >= (BAR if kind == "pillarboxed" else 0)  # in the top half, inside the picture


@pytest.mark.parametrize("kind", ["pillarboxed", "bright"])
def test_lane_is_drawn_inside_the_picture_only(kind):
    frame = frame_of(kind)
    drawn = draw_lane(frame, wide_lane(), identity_view())
    assert (drawn[:, :BAR] == frame[:, :BAR]).all() == (kind == "pillarboxed")  # the bars stay black
    assert (drawn[:, W - BAR :] == frame[:, W - BAR :]).all() == (kind == "pillarboxed")
    assert (drawn[H - 1, BAR : W - BAR] != frame[H - 1, BAR : W - BAR]).any(axis=1).all()  # the picture has its lane
    # the picture given (a video's bars, measured on its first frames) is the one kept to
    inside = draw_lane(frame_of("bright"), wide_lane(), identity_view(), area=(BAR, 0, W - BAR, H))
    assert (inside[:, :BAR] == 255).all() and (inside[:, W - BAR :] == 255).all()
