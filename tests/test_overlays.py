"""Black bars and static overlays: what is found, what is not, and the detector leaving them alone."""

from __future__ import annotations

import functools
from itertools import islice

import cv2
import numpy as np
import pytest

from conftest import REPO, shared_data_dir
from vehicle_detection.footage.overlays import (
    BarParams,
    MaskParams,
    Overlays,
    active_area,
    find_overlays,
    mask_integral,
    mask_share,
    static_mask,
)

CLIP_A = REPO / "dev_set" / "project_video_clip_A.mp4"
HIGHWAY = shared_data_dir() / "videos" / "highway_dashcam_854x480.mp4"
requires_highway = pytest.mark.skipif(
    not HIGHWAY.is_file(), reason=f"{HIGHWAY} not found (set VEHICLE_DETECTION_DATA to the folder holding videos/)"
)
MOUNT = (760, 290, 850, 345)  # inside the windscreen mount at the right of the highway clip


def frames_of(path, start=0, n=12):
    from vehicle_detection.io.video import read_frames

    frames = read_frames(path)
    try:
        return list(islice(frames, start, start + n))
    finally:
        frames.close()


@pytest.fixture(scope="module")
def clip_a():
    return frames_of(CLIP_A)


def pad(frame, top, bottom, left, right, value=0):
    return cv2.copyMakeBorder(np.ascontiguousarray(frame), top, bottom, left, right, cv2.BORDER_CONSTANT, value=(value,) * 3)


def share(mask, box):
    x1, y1, x2, y2 = box
    return float(mask[y1:y2, x1:x2].mean())


# --- black bars ------------------------------------------------------------------------------


@pytest.mark.parametrize("bars", [(0, 0, 160, 160), (90, 90, 0, 0), (45, 47, 101, 99), (3, 3, 0, 0)])
@pytest.mark.parametrize("black", [0, 16])
def test_bars_around_frames_are_found(clip_a, bars, black):
    top, bottom, left, right = bars
    h, w = clip_a[0].shape[:2]
    padded = [pad(f, *bars, value=black) for f in clip_a]
    small = min(top, bottom), min(left, right)  # uneven bars: both cut by the smaller
    want = (small[1], small[0], w + left + right - small[1], h + top + bottom - small[0])
    assert active_area(padded) == want
    assert active_area(padded[0]) == want  # one image will do
    assert active_area(np.stack(padded)) == want


def test_bars_of_a_compressed_image_are_found_within_a_pixel(test_frames):
    ok, jpeg = cv2.imencode(".jpg", pad(test_frames[0], 60, 60, 120, 120), [cv2.IMWRITE_JPEG_QUALITY, 60])
    assert ok
    x1, y1, x2, y2 = active_area(cv2.imdecode(jpeg, cv2.IMREAD_COLOR))
    assert abs(x1 - 120) <= 1 and abs(y1 - 60) <= 1 and abs(x2 - 1400) <= 1 and abs(y2 - 780) <= 1


def test_frames_without_bars_are_whole(test_frames, clip_a):
    for frame in [*test_frames, clip_a[0]]:
        assert active_area(frame) == (0, 0, 1280, 720)
    assert active_area(clip_a) == (0, 0, 1280, 720)


def night(image, gain, noise, seed=0):
    """A daytime frame as a night camera might see it: dark, noisy."""
    return np.clip(image * gain + noise * _standard_normal(image.shape, seed), 0, 255).astype(np.uint8)


@functools.lru_cache(maxsize=2)
def _standard_normal(shape, seed):
    """``default_rng(seed).normal(0, s, shape)`` is ``s`` times this, drawn once for every image and ``s``."""
    out = np.random.default_rng(seed).standard_normal(shape)
    out.flags.writeable = False
    return out


def night_road(size=(1280, 720)):
    """Black sky, a faintly lit road, two headlights: dark at the top and the bottom edges."""
    w, h = size
    img = np.full((h, w, 3), 4, np.uint8)
    road = np.array([[0.42 * w, 0.55 * h], [0.58 * w, 0.55 * h], [w, 0.85 * h], [w, h], [0, h], [0, 0.85 * h]], np.int32)
    cv2.fillPoly(img, [road], (28, 26, 24))
    for x in (0.45 * w, 0.52 * w):
        cv2.circle(img, (int(x), int(0.56 * h)), 6, (255, 250, 230), -1)
    return img


def test_dark_frames_without_bars_are_not_cut(test_frames):
    for image in test_frames:
        for gain, noise in [(0.1, 1.5), (0.1, 0.0), (0.05, 1.0)]:
            assert active_area(night(image, gain, noise)) == (0, 0, 1280, 720)
    assert active_area(night_road()) == (0, 0, 1280, 720)
    assert active_area([night_road(), night_road()]) == (0, 0, 1280, 720)
    assert active_area(np.zeros((720, 1280, 3), np.uint8)) == (0, 0, 1280, 720)  # a black frame is not all bars


def test_a_dark_edge_on_one_side_is_not_a_bar(test_frames):
    image = test_frames[0].copy()
    image[:120] = 0  # black sky above, nothing below
    assert active_area(image) == (0, 0, 1280, 720)
    image[-10:] = 0  # a thin black strip below: the pair is far from symmetric
    assert active_area(image) == (0, 0, 1280, 720)


def test_bars_must_be_black_in_every_frame(clip_a):
    padded = [pad(f, 0, 0, 160, 160) for f in clip_a]
    assert active_area(padded) == (160, 0, 1440, 720)
    lit = padded[5].copy()
    lit[:, :160] = 90  # one frame's left bar is not black: not a bar
    assert active_area([*padded[:5], lit, *padded[6:]]) == (0, 0, 1600, 720)


def test_bar_params_are_used(clip_a):
    padded = pad(clip_a[0], 0, 0, 160, 160, value=40)
    assert active_area(padded) == (0, 0, 1600, 720)  # grey bars are above the black level
    assert active_area(padded, BarParams(black_level=48)) == (160, 0, 1440, 720)


# --- static overlays -------------------------------------------------------------------------


def scrolling(n=12, size=(640, 360), seed=1):
    """A scene going by: smooth random texture scrolled down 6 pixels a frame."""
    w, h = size
    rng = np.random.default_rng(seed)
    tall = cv2.resize(rng.integers(0, 256, ((h + 6 * n) // 8, w // 8, 3), dtype=np.uint8), (w, h + 6 * n),
                      interpolation=cv2.INTER_CUBIC)
    return [np.ascontiguousarray(tall[6 * (n - i) : 6 * (n - i) + h]) for i in range(n)]


MOUNT_SYNTH = np.array([[640, 150], [560, 200], [540, 250], [640, 260]], np.int32)  # at the right edge
ROAD_SYNTH = np.array([[250, 200], [390, 200], [560, 360], [80, 360]], np.int32)  # an empty road ahead


def glued(frames, blob=None, road=None, road_grey=100):
    out = []
    for f in frames:
        f = f.copy()
        if road is not None:
            cv2.fillPoly(f, [road], (road_grey,) * 3)
        if blob is not None:
            cv2.fillPoly(f, [blob], (22, 20, 18))
            cv2.line(f, tuple(blob[1]), tuple(blob[2]), (60, 60, 60), 2)  # an edge of the mount
        out.append(f)
    return out


def polygon_mask(points, shape):
    m = np.zeros(shape, np.uint8)
    cv2.fillPoly(m, [points], 1)
    return m.astype(bool)


def test_a_dark_blob_glued_to_the_edge_over_a_moving_scene_is_masked():
    frames = glued(scrolling(), MOUNT_SYNTH)
    mask = static_mask(frames)
    blob = polygon_mask(MOUNT_SYNTH, mask.shape)
    assert mask[blob].mean() >= 0.9
    assert mask[~blob].mean() <= 0.005
    assert not static_mask(scrolling()).any()  # the scene alone: nothing


def test_an_empty_road_that_stays_the_same_is_not_masked():
    """The road ahead barely changes while the scene around goes by: it must stay searchable."""
    for grey in (100, 70):
        frames = glued(scrolling(), MOUNT_SYNTH, ROAD_SYNTH, grey)
        mask = static_mask(frames)
        assert not mask[polygon_mask(ROAD_SYNTH, mask.shape)].any()
        assert mask[polygon_mask(MOUNT_SYNTH, mask.shape)].mean() >= 0.9  # masking did happen


def test_nothing_is_masked_while_the_scene_stands_still():
    frames = glued([scrolling(1)[0]] * 12, MOUNT_SYNTH)
    assert not static_mask(frames).any()
    assert not static_mask(glued(scrolling(), MOUNT_SYNTH)[:1]).any()  # one frame cannot tell


def test_a_dark_blob_inside_the_picture_is_not_masked():
    """A dark car keeping its distance ahead stays where it is in the frame, but does not touch its border."""
    car = np.array([[280, 200], [360, 200], [360, 260], [280, 260]], np.int32)
    mask = static_mask(glued(scrolling(), car))
    assert not mask[polygon_mask(car, mask.shape)].any()


def test_burnt_in_text_is_masked_only_near_the_top_or_bottom():
    frames = scrolling()
    for f in frames:
        for org in ((12, 30), (12, 190)):
            cv2.putText(f, "2024-05-01 12:00", org, cv2.FONT_HERSHEY_SIMPLEX, 0.8, (0, 0, 0), 5)
            cv2.putText(f, "2024-05-01 12:00", org, cv2.FONT_HERSHEY_SIMPLEX, 0.8, (255, 255, 255), 2)
    mask = static_mask(frames)
    assert share(mask, (12, 12, 230, 34)) >= 0.5
    assert not mask[100:300].any()  # the same text in the middle of the picture: not an overlay band
    assert not static_mask(frames, MaskParams(overlay_band=0.0)).any()


def test_static_mask_of_the_project_camera_spares_the_road_and_the_cars(clip_a):
    from vehicle_detection.metrics.detection import load_annotations

    labels = load_annotations(REPO / "dev_set" / "clip_A.json")
    horizon, bottom = int(0.583 * 720), int(0.92 * 720)  # below: the bonnet
    later = frames_of(CLIP_A, 100, 112)  # frames 100-111 and 200-211, decoded in one pass
    for start in (0, 100, 200):
        frames = {0: clip_a, 100: later[:12], 200: later[100:]}[start]
        assert len(frames) == 12
        mask = static_mask(frames)
        assert not mask[horizon:bottom].any(), start
        for index, frame_labels in labels.frames.items():
            for box in frame_labels.cars:
                assert not mask[box[1] : box[3], box[0] : box[2]].any(), (start, index)
    assert find_overlays(clip_a).describe() == []


def test_static_mask_of_the_test_video_is_empty():
    frames = frames_of(REPO / "test_video.mp4")
    overlays = find_overlays(frames)
    assert overlays.mask is None and not overlays.cropped


@requires_highway
def test_the_windscreen_mount_of_the_highway_clip_is_masked():
    overlays = find_overlays(frames_of(HIGHWAY))
    assert not overlays.cropped
    mask = overlays.mask
    assert share(mask, MOUNT) >= 0.95
    assert share(mask, (0, 200, 650, 400)) <= 0.005  # the road and the cars on it
    assert share(mask, (0, 0, 854, 200)) == 0.0  # sky, signs and buildings
    assert 0.02 <= overlays.masked_share <= 0.1
    assert overlays.describe() == [f"static overlay: {100 * overlays.masked_share:.0f} % of the picture masked"]


def mount_detector(frames):
    """A detector whose classifier takes the windscreen mount for a car: a linear SVM fitted on the
    embedded model's features, with squares around the mount as positives and squares of sizes in
    the same range elsewhere in the same frames as negatives. It fires there whatever the embedded
    model learned, so the test below tests the mask, not one model's margins on the mount."""
    from vehicle_detection.classifier import VehicleClassifier
    from vehicle_detection.detector import Detector
    from vehicle_detection.features import extract_features
    from vehicle_detection.geometry import box_intersection
    from vehicle_detection.refine import crop_windows

    embedded = Detector().model
    rng = np.random.default_rng(0)
    x1, y1, x2, y2 = MOUNT
    near_mount = np.array([[x1 - 20, y1 - 20, x2 + 20, y2 + 20]])
    patches, labels = [], []
    for frame in frames:
        h, w = frame.shape[:2]
        side = rng.integers(40, 90, 8)
        centre = np.array([(x1 + x2) // 2, (y1 + y2) // 2]) + rng.integers(-8, 9, (8, 2))
        corner = np.clip(centre - side[:, None] // 2, 0, np.stack([w - side, h - side], axis=1))
        on = np.column_stack([corner, corner + side[:, None]])
        side = rng.integers(40, 90, 200)
        corner = np.column_stack([rng.integers(0, w - side), rng.integers(h // 3, h - side)])
        off = np.column_stack([corner, corner + side[:, None]])
        off = off[box_intersection(off, near_mount)[:, 0] == 0][:24]
        patches += [crop_windows(frame, on, embedded.config.window), crop_windows(frame, off, embedded.config.window)]
        labels += [np.ones(len(on), int), np.zeros(len(off), int)]
    features = extract_features(np.concatenate(patches), embedded.config)
    model = VehicleClassifier.fit(features, np.concatenate(labels), embedded.config, detector_config=embedded.detector_config)
    return Detector(model)


@requires_highway
def test_no_track_lives_on_the_windscreen_mount():
    from vehicle_detection.detections import Detections
    from vehicle_detection.detector import Detector

    # The detector learns the mount on every third of the first 60 frames; the first 20 are
    # tracked: 29 boxes with the mask, 20 on the mount without it (2026-11-29; 49 and 30 in 30 frames).
    frames = frames_of(HIGHWAY, 0, 60)
    # Heat goes to the windows themselves (the mount detector has no box refinement): the mask is
    # what is tested.
    detector = mount_detector(frames[::3])
    frames = frames[:20]
    tracker = detector.new_tracker()
    found = Detections.concatenate(detector.track(frames, tracker))
    integral = mask_integral(tracker.state.overlays.mask)
    assert len(found) >= 26 and (mask_share(found.xyxy, integral) <= 0.5).all()
    # Without the mask, the same detector's tracks sit on the mount.
    unmasked = Detector(detector.model, detector.config.replace(auto_overlays=False))
    before = Detections.concatenate(unmasked.track(frames))
    assert (mask_share(before.xyxy, integral) > 0.5).sum() >= 13


# --- helpers ----------------------------------------------------------------------------------


def test_mask_share_counts_the_masked_pixels_of_each_box():
    rng = np.random.default_rng(3)
    mask = rng.random((50, 80)) < 0.3
    boxes = np.array([[0, 0, 80, 50], [10, 5, 11, 6], [30, 20, 60, 45], [70, 40, 90, 60], [5, 5, 5, 9], [-5, -5, 4, 4]])
    got = mask_share(boxes, mask_integral(mask))
    for box, value in zip(boxes, got):
        x1, y1, x2, y2 = np.clip(box, 0, [80, 50, 80, 50])
        want = mask[y1:y2, x1:x2].mean() if x2 > x1 and y2 > y1 else 0.0
        assert value == pytest.approx(want)


def test_overlays_check_their_arguments():
    Overlays((720, 1280), (0, 0, 1280, 720))
    with pytest.raises(ValueError, match="not a box inside"):
        Overlays((720, 1280), (0, 0, 1300, 720))
    with pytest.raises(ValueError, match="bool of shape"):
        Overlays((720, 1280), (0, 0, 1280, 720), np.zeros((72, 128), bool))
    with pytest.raises(ValueError, match="RGB uint8"):
        active_area(np.zeros((72, 128), np.uint8))
    with pytest.raises(ValueError, match="no frames"):
        static_mask([])
    overlays = Overlays((720, 1600), (160, 0, 1440, 720), np.zeros((720, 1600), bool))
    assert overlays.describe()[0] == "picture: 1280x720 inside black bars"
    assert overlays.crop(np.zeros((720, 1600, 3), np.uint8)).shape == (720, 1280, 3)
    with pytest.raises(ValueError, match="these overlays are of 1600x720"):
        overlays.crop(np.zeros((720, 1280, 3), np.uint8))
    with pytest.raises(ValueError):
        overlays.mask[0, 0] = True  # read-only
