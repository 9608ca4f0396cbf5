"""Camera calibration: synthetic chessboards (always), the real photos (when the shared data are present)."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from conftest import shared_data_dir
from vehicle_detection.road.camera import Camera, calibrate
from vehicle_detection.cli import main
from vehicle_detection.errors import InputError
from vehicle_detection.io.images import write_image

SIZE = (640, 480)
K_TRUE = np.array([[600.0, 0, 320], [0, 600.0, 240], [0, 0, 1]])
SQUARE_PX = 40  # of the flat board image


def _board_image(pattern=(9, 6)) -> np.ndarray:
    cols, rows = pattern[0] + 1, pattern[1] + 1
    margin = SQUARE_PX
    img = np.full((rows * SQUARE_PX + 2 * margin, cols * SQUARE_PX + 2 * margin), 255, np.uint8)
    for r in range(rows):
        for c in range(cols):
            if (r + c) % 2 == 0:
                y, x = margin + r * SQUARE_PX, margin + c * SQUARE_PX
                img[y : y + SQUARE_PX, x : x + SQUARE_PX] = 0
    return img


def render_chessboards(n=8, seed=0, size=SIZE, pattern=(9, 6)) -> list[np.ndarray]:
    """Photos of a flat chessboard in different poses, through a pinhole camera K_TRUE."""
    rng = np.random.default_rng(seed)
    board = _board_image(pattern)
    bh, bw = board.shape
    # board pixels -> board plane in units of squares, centred
    to_plane = np.array([[1 / SQUARE_PX, 0, -bw / 2 / SQUARE_PX], [0, 1 / SQUARE_PX, -bh / 2 / SQUARE_PX], [0, 0, 1]])
    out = []
    for _ in range(n):
        rvec = rng.uniform(-0.45, 0.45, 3) * np.array([1, 1, 0.3])
        R, _ = cv2.Rodrigues(rvec)
        t = np.array([rng.uniform(-1, 1), rng.uniform(-0.7, 0.7), rng.uniform(17, 21)])
        H = K_TRUE @ np.c_[R[:, 0], R[:, 1], t] @ to_plane
        gray = cv2.warpPerspective(board, H, size, flags=cv2.INTER_AREA, borderValue=128)
        out.append(np.repeat(gray[..., None], 3, axis=2))
    return out


@pytest.fixture(scope="module")
def synthetic_camera() -> Camera:
    """``calibrate(render_chessboards())``: the camera of 8 synthetic photos, shared by the tests that need one of 640x480."""
    return calibrate(render_chessboards())


def test_synthetic_calibration_recovers_the_camera(synthetic_camera):
    cam = synthetic_camera
    assert len(cam.images_used) == 8 and cam.image_size == SIZE
    assert cam.rms < 0.5
    np.testing.assert_allclose(cam.matrix[[0, 1, 0, 1], [0, 1, 2, 2]], [600, 600, 320, 240], rtol=0.03, atol=6)
    assert abs(cam.distortion[0]) < 0.05  # no lens distortion rendered (k2 is poorly constrained by these poses)


def test_photos_without_board_are_skipped_and_odd_sizes_cropped():
    photos = render_chessboards(6)
    blank = np.full((SIZE[1], SIZE[0], 3), 200, np.uint8)
    bigger = np.pad(photos[0], ((0, 1), (0, 1), (0, 0)), mode="edge")  # 641x481: cropped
    much_bigger = np.pad(photos[1], ((0, 40), (0, 40), (0, 0)), mode="edge")  # skipped
    names = [f"p{i}" for i in range(6)] + ["blank", "bigger", "much_bigger"]
    cam = calibrate([*photos, blank, bigger, much_bigger], names=names)
    assert cam.images_skipped["blank"].startswith("no full 9x6 chessboard")
    assert "majority 640x480" in cam.images_skipped["much_bigger"]
    assert cam.images_cropped == ("bigger",) and "bigger" in cam.images_used
    assert len(cam.images_used) == 7


def test_board_cut_by_the_edge_is_skipped():
    photos = render_chessboards(4)
    # Shift a photo so that its board's outermost inner corners come within a few pixels of the
    # left edge: the corners are still found, but from a truncated neighbourhood.
    gray = photos[0][..., 0]
    found, corners = cv2.findChessboardCornersSB(gray, (9, 6), cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY)
    assert found
    shift = int(corners[..., 0].min()) - 6
    cut = np.ascontiguousarray(np.pad(photos[0][:, shift:], ((0, 0), (0, shift), (0, 0)), constant_values=128))
    cam = calibrate([*photos, cut], names=["p0", "p1", "p2", "p3", "cut"])
    assert cam.images_skipped == {"cut": "the 9x6 chessboard is cut by the image edge"}
    assert len(cam.images_used) == 4


def test_no_chessboard_is_refused():
    blank = np.full((SIZE[1], SIZE[0], 3), 200, np.uint8)
    with pytest.raises(InputError, match="no chessboard to calibrate on"):
        calibrate([blank, blank, blank])


def test_json_round_trip_and_undistort(synthetic_camera, tmp_path):
    cam = synthetic_camera.replace(distortion=[-0.2, 0.05, 0.0, 0.0, 0.0])
    path = cam.save(tmp_path / "camera.json")
    text = path.read_text()
    assert json.loads(text)["format"].startswith("vehicle-detection camera")
    back = Camera.load(path)
    np.testing.assert_array_equal(back.matrix, cam.matrix)
    np.testing.assert_array_equal(back.distortion, cam.distortion)
    assert back.rms == cam.rms and back.images_used == cam.images_used and back.image_size == cam.image_size
    image = render_chessboards(1, seed=3)[0]
    expected = cv2.undistort(image, cam.matrix, cam.distortion)
    got = back.undistort(image)
    assert np.mean(np.abs(got.astype(int) - expected.astype(int))) < 1.0  # the remap is cv2.undistort
    assert np.mean(np.abs(got.astype(int) - image.astype(int))) > 1.0  # and it changes the image


def test_wrong_image_size_is_refused(synthetic_camera):
    with pytest.raises(InputError, match="calibrated for 640x480"):
        synthetic_camera.undistort(np.zeros((720, 1280, 3), np.uint8))


def test_bad_camera_file(tmp_path):
    p = tmp_path / "c.json"
    p.write_text('{"format": "something else"}')
    with pytest.raises(InputError, match="not a camera file"):
        Camera.load(p)
    p.write_text("{")
    with pytest.raises(InputError, match="invalid JSON"):
        Camera.load(p)


def test_cli_calibrate_synthetic(tmp_path, capsys):
    folder = tmp_path / "cal"
    for i, im in enumerate(render_chessboards(5)):
        write_image(folder / f"c{i}.png", im)
    out = tmp_path / "camera.json"
    assert main(["calibrate", str(folder), "--out", str(out), "--json"]) == 0
    captured = capsys.readouterr()
    report = json.loads(captured.out)  # stdout: the JSON object alone
    assert report["images_used"] == 5 and report["rms"] < 0.5 and report["out"] == str(out)
    assert "RMS reprojection error" in captured.err and f"camera saved to {out}" in captured.err
    assert Camera.load(out).image_size == SIZE


def test_cli_calibrate_writes_camera_json_by_default(tmp_path, capsys, monkeypatch):
    folder = tmp_path / "cal"
    for i, im in enumerate(render_chessboards(5)):
        write_image(folder / f"c{i}.png", im)
    monkeypatch.chdir(tmp_path)
    assert main(["calibrate", str(folder)]) == 0
    assert Camera.load(tmp_path / "camera.json").image_size == SIZE
    assert "camera saved to camera.json" in capsys.readouterr().out
    assert main(["calibrate", str(folder)]) == 5  # never replaced without --overwrite


def test_cli_calibrate_without_chessboard(tmp_path, capsys):
    folder = tmp_path / "cal"
    for i in range(3):
        write_image(folder / f"c{i}.png", np.full((SIZE[1], SIZE[0], 3), 90 + i, np.uint8))
    assert main(["calibrate", str(folder)]) == 3
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no chessboard to calibrate on" in err[0]


def test_cli_detect_refuses_camera_of_another_size(synthetic_camera, tmp_path, capsys):
    path = synthetic_camera.save(tmp_path / "camera.json")
    img = tmp_path / "road.png"
    write_image(img, np.zeros((720, 1280, 3), np.uint8))
    assert main(["detect", str(img), "--camera", str(path), "--out", str(tmp_path / "o.png")]) == 3
    assert "calibrated for 640x480" in capsys.readouterr().err


REAL = shared_data_dir() / "camera_cal"


@pytest.mark.skipif(not REAL.is_dir(), reason=f"no chessboard photos at {REAL}")
def test_real_photos(calibrated_camera):
    cam = calibrated_camera  # calibrate(REAL), once for the session
    assert cam.image_size == (1280, 720)
    assert len(cam.images_used) >= 17
    assert set(cam.images_cropped) == {"calibration7.jpg", "calibration15.jpg"}
    assert all("chessboard" in why for why in cam.images_skipped.values())
    assert cam.images_skipped["calibration4.jpg"] == "the 9x6 chessboard is cut by the image edge"
    assert cam.rms < 1.0  # 0.83 px
    assert 1000 < cam.matrix[0, 0] < 1300 and cam.distortion[0] < -0.1  # barrel distortion


def test_boxes_back_to_the_original_frame(synthetic_camera):
    cam = synthetic_camera.replace(distortion=[-0.25, 0.0, 0.0, 0.0, 0.0])
    # the corners of the box (40, 30, 200, 140) in the original (distorted) frame, near a corner
    corners = np.array([[40, 30], [200, 30], [40, 140], [200, 140]], float)
    und = cam.undistort_points(corners)
    und_box = [und[:, 0].min(), und[:, 1].min(), und[:, 0].max(), und[:, 1].max()]
    assert abs(und_box[0] - 40) > 3  # distortion moves it
    np.testing.assert_allclose(cam.distort_points(und), corners, atol=0.05)  # the inverse of undistort_points
    back = cam.boxes_to_original([und_box])[0]
    # the box around the bent edges of the undistorted box: encloses the original, not much larger
    assert back[0] <= 40 and back[1] <= 30 and back[2] >= 200 and back[3] >= 140
    area = (back[2] - back[0]) * (back[3] - back[1])
    assert area < 1.4 * 160 * 110


def test_cli_lanes_without_a_birds_eye_camera_look_at_the_image(synthetic_camera, tmp_path, capsys):
    """Lanes without a bird's-eye transform estimate one from the image; a black image has no lane lines: no lanes, exit 0."""
    path = synthetic_camera.save(tmp_path / "camera.json")
    img = tmp_path / "road.png"
    write_image(img, np.zeros((SIZE[1], SIZE[0], 3), np.uint8))
    for camera in ([], ["--camera", str(path)]):
        assert main(["detect", str(img), "--lanes", "--overwrite", *camera]) == 0
        captured = capsys.readouterr()
        assert captured.err == "" and len([line for line in captured.out.splitlines() if line.startswith("no lanes: no lane lines seen")]) == 1
        assert "distance_m" not in (tmp_path / "road_boxes.csv").read_text()
