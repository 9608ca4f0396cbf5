"""What a new user hands the API: paths and Pillow images, Detections to draw, pandas, supervision."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from vehicle_detection.detections import Detections
from vehicle_detection.viz.drawing import draw_boxes
from vehicle_detection.errors import InputError
from vehicle_detection.io.images import as_image, decode_image, read_image

REPO = Path(__file__).resolve().parents[1]
TEST1 = REPO / "test_images" / "test1.jpg"


@pytest.fixture(scope="module")
def detector():
    from vehicle_detection.detector import Detector

    return Detector()


@pytest.fixture(scope="module")
def found(detector):
    return detector.detect_image(read_image(TEST1))


# --- detect_image: a path, a Pillow image ------------------------------------------------------


def test_detect_image_takes_a_path(detector, found):
    assert len(found) > 0  # the reference finds cars here
    assert detector.detect_image(str(TEST1)) == found
    assert detector.detect_image(TEST1) == found


def test_detect_image_takes_a_pillow_image(detector, found):
    with Image.open(TEST1) as img:
        assert detector.detect_image(img) == found
    grey = Image.open(TEST1).convert("L")
    as_array = np.repeat(np.asarray(grey)[:, :, None], 3, axis=2)
    assert detector.detect_image(grey) == detector.detect_image(as_array)


def test_detect_image_says_what_it_expects(detector):
    with pytest.raises(InputError, match="expected an RGB uint8 array of shape \\(H, W, 3\\), a PIL image or an image file path; got dict"):
        detector.detect_image({"image": 1})
    with pytest.raises(InputError, match="got bytes; pass a file path, a PIL image or an array"):
        detector.detect_image(TEST1.read_bytes())
    with pytest.raises(InputError, match="nothing.jpg: no such file"):
        detector.detect_image(REPO / "nothing.jpg")
    with pytest.raises(InputError, match="float"):
        detector.detect_image(np.zeros((720, 1280, 3), np.float32))


def test_as_image_applies_a_pillow_images_exif_orientation():
    img = Image.new("RGB", (80, 40), (10, 20, 30))
    img.paste((200, 0, 0), (0, 0, 10, 10))  # a red corner, top left as stored
    exif = img.getexif()
    exif[0x0112] = 6  # stored rotated: shown turned 90 degrees clockwise
    buf = io.BytesIO()
    img.save(buf, format="JPEG", exif=exif.tobytes(), quality=95)
    with Image.open(buf) as opened:
        arr = as_image(opened)
    assert arr.shape == (80, 40, 3)
    assert arr[:8, -8:, 0].mean() > 150  # the red corner is now top right
    np.testing.assert_array_equal(arr, decode_image(buf.getvalue()))  # as read from a file


# --- draw_boxes takes Detections -------------------------------------------------------------------


def test_draw_boxes_takes_detections():
    img = np.zeros((60, 80, 3), np.uint8)
    d = Detections([[5, 5, 30, 40], [40, 10, 75, 50]], track_id=[1, 2])
    drawn = draw_boxes(img, d, thickness=2)
    np.testing.assert_array_equal(drawn, draw_boxes(img, d.xyxy, thickness=2))
    assert drawn.any() and not img.any()


# --- pandas -------------------------------------------------------------------------------------


def test_to_pandas():
    pd = pytest.importorskip("pandas")
    d = Detections(
        [[10, 20, 74, 84], [100, 20, 164, 84]], score=[0.5, 2.0], track_id=[3, 7], frame=[4, 5],
        data={"distance_m": [12.5, np.nan], "box": [[1, 2, 3, 4], [5, 6, 7, 8]]},
    )
    df = d.to_pandas()
    assert isinstance(df, pd.DataFrame)
    assert list(df.columns) == ["frame", "x1", "y1", "x2", "y2", "track_id", "score", "distance_m", "box_0", "box_1", "box_2", "box_3"]
    assert df[["frame", "x1", "y1", "x2", "y2", "track_id"]].to_numpy().tolist() == [[4, 10, 20, 74, 84, 3], [5, 100, 20, 164, 84, 7]]
    assert df["score"].tolist() == [0.5, 2.0] and df["score"].dtype == np.float64
    assert df["box_2"].tolist() == [3, 7] and df["distance_m"].isna().tolist() == [False, True]
    untracked = Detections([[1, 2, 30, 40]]).to_pandas()
    assert untracked["track_id"].tolist() == [-1] and untracked["frame"].dtype == np.int64
    assert len(Detections.empty().to_pandas().columns) == 7
    with pytest.raises(ValueError, match="'score' has the name of a main column"):
        Detections([[1, 2, 30, 40]], data={"score": [1.0]}).to_pandas()


# --- supervision: confidence in 0..1 -----------------------------------------------------------


def test_supervision_confidence_is_in_0_1_in_the_order_of_the_scores():
    pytest.importorskip("supervision")
    scores = np.array([-2.0, 0.0, 0.31, 3.0, 48.6, 91.7, 179.2])
    d = Detections([[0, 0, 64, 64]] * len(scores), score=scores, track_id=range(len(scores)))
    s = d.to_supervision()
    assert np.all((s.confidence > 0) & (s.confidence < 1))
    assert np.all(np.diff(s.confidence) > 0)  # no two tracked boxes tied at 1.0
    assert s.data["score"].tolist() == scores.tolist()
    assert Detections.from_supervision(s) == d  # exactly, through data["score"]


def test_from_supervision_of_another_detector_takes_its_confidence():
    sv = pytest.importorskip("supervision")
    other = sv.Detections(xyxy=np.array([[0.0, 0.0, 10.0, 10.0]]), confidence=np.array([0.8]), class_id=np.array([2]))
    assert Detections.from_supervision(other).score.tolist() == [0.8]


# --- frames the detector takes, and those it refuses ---------------------------------------------


def test_grey_image_finds_what_its_rgb_stacked_copy_finds(detector):
    grey = read_image(TEST1)[..., 1].copy()
    rgb = np.repeat(grey[:, :, None], 3, axis=2)
    assert detector.detect_image(grey) == detector.detect_image(rgb) == detector.detect_image(grey[:, :, None])
    # A grey video, frame by frame and tracked: the same as its RGB copy (it crashed in OpenCV before).
    frames = [np.ascontiguousarray(f[::4, ::4, 1]) for f in read_frames_of_test_video(3)]
    tracked = [list(map(repr, detector.track(fs, workers=1))) for fs in (frames, [np.dstack([f] * 3) for f in frames])]
    assert tracked[0] == tracked[1] and len(tracked[0]) == 3
    tracker = detector.new_tracker()
    assert len(detector.step(frames[0], tracker)) == 0 and tracker.state.frame_index == 1


def read_frames_of_test_video(n: int) -> list[np.ndarray]:
    import itertools

    from vehicle_detection.io.video import read_frames

    video = REPO / "test_video.mp4"
    if not video.is_file():
        pytest.skip("test_video.mp4 not in the checkout")
    return list(itertools.islice(read_frames(video), n))


REFUSED_FRAMES = [
    ("float", np.zeros((480, 640)), "got float64 of shape (480, 640) (0-1 versus 0-255 is ambiguous"),
    ("batch", np.zeros((1, 72, 128, 3), np.uint8), "got uint8 of shape (1, 72, 128, 3)"),
    ("two_channels", np.zeros((72, 128, 2), np.uint8), "got uint8 of shape (72, 128, 2)"),
    ("int64", np.zeros((72, 128, 3), np.int64), "got int64 of shape (72, 128, 3)"),
    ("bool", np.zeros((72, 128, 3), bool), "got bool of shape (72, 128, 3)"),
]


@pytest.mark.parametrize(("case", "frame", "given"), REFUSED_FRAMES, ids=[c[0] for c in REFUSED_FRAMES])
def test_frames_the_library_cannot_use_are_refused_naming_shape_and_dtype(detector, case, frame, given):
    expected = "expected an RGB uint8 image of shape (H, W, 3), " + given
    calls = {
        "detect_image": lambda: detector.detect_image(frame),
        "windows": lambda: detector.windows(frame),
        "step": lambda: detector.step(frame, detector.new_tracker()),
        "track": lambda: list(detector.track([frame], workers=1)),
        "shot_cut": lambda: detector.shot_cut(frame, detector.new_tracker()),
    }
    for name, call in calls.items():
        with pytest.raises(ValueError) as info:  # an InputError: the CLI's exit code 3
            call()
        assert isinstance(info.value, InputError) and expected in str(info.value), (name, str(info.value))


def test_the_footage_and_lane_functions_take_grey_frames_and_refuse_the_rest():
    """``fit_sides``, ``vanishing_row`` and ``lane_binary`` convert a grey frame once at their
    edge, as the detector does (they raised NumPy's or OpenCV's errors), and refuse what they
    cannot use in one line naming the shape and dtype."""
    import vehicle_detection as vd

    rgb = read_image(Path(__file__).resolve().parents[1] / "test_images" / "test1.jpg")
    grey = rgb[..., 1].copy()
    stacked = np.repeat(grey[..., None], 3, axis=2)
    boxes = np.array([[800, 400, 950, 500], [1050, 400, 1250, 510]])
    fit = vd.SideFit()
    calls = {
        "fit_sides": lambda frame: vd.fit_sides(frame, boxes, fit),
        "vanishing_row": vd.vanishing_row,
        "lane_binary": vd.lane_binary,
    }
    for name, call in calls.items():
        want = call(stacked)
        for same in (grey, grey[..., None]):
            got = call(same)
            assert np.array_equal(np.asarray(got, dtype=float), np.asarray(want, dtype=float), equal_nan=True), name
        with pytest.raises(InputError, match=r"expected an RGB uint8 image of shape \(H, W, 3\), got float64 of shape \(720, 1280\)"):
            call(grey / 255.0)
