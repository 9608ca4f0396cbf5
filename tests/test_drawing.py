"""Tests of vehicle_detection.viz.drawing."""

from __future__ import annotations

import numpy as np
import pytest

from vehicle_detection.detections import Detections
from vehicle_detection.viz.drawing import draw_boxes, draw_detections, place_labels


def _image(h=60, w=80, value=50):
    return np.full((h, w, 3), value, dtype=np.uint8)


def test_draw_leaves_input_unchanged():
    image = _image()
    image.setflags(write=False)  # any write to the input would raise
    out = draw_boxes(image, [[10, 10, 30, 30]], labels=["7"])
    assert np.all(image == 50)
    assert out is not image and not np.shares_memory(out, image)
    assert out.dtype == np.uint8 and out.shape == image.shape and out.flags.c_contiguous
    assert not np.array_equal(out, image)


@pytest.mark.parametrize("thickness", [1, 2, 3, 5])
def test_draw_edges_inside_the_box(thickness):
    # Box [10, 12, 40, 45): columns 10..39, rows 12..44.
    out = draw_boxes(_image(value=0), [[10, 12, 40, 45]], color=(0, 255, 0), thickness=thickness)
    drawn = out[..., 1] == 255
    assert np.all(out[..., 0] == 0) and np.all(out[..., 2] == 0)  # only the green channel
    ys, xs = np.nonzero(drawn)
    assert (xs.min(), xs.max(), ys.min(), ys.max()) == (10, 39, 12, 44)
    # A row through the middle crosses the left and right edges, each `thickness` pixels wide.
    np.testing.assert_array_equal(np.flatnonzero(drawn[28]),
                                  list(range(10, 10 + thickness)) + list(range(40 - thickness, 40)))
    np.testing.assert_array_equal(np.flatnonzero(drawn[:, 25]),
                                  list(range(12, 12 + thickness)) + list(range(45 - thickness, 45)))


def test_draw_labels_add_pixels_above_box():
    plain = draw_boxes(_image(value=0), [[10, 30, 40, 50]], thickness=1)
    labelled = draw_boxes(_image(value=0), [[10, 30, 40, 50]], thickness=1, labels=[12])
    assert np.array_equal(plain[30:], labelled[30:])  # box unchanged
    assert labelled[:30].any() and not plain[:30].any()  # tag above the box


def test_draw_clips_boxes_outside_image_and_accepts_views():
    image = np.zeros((40, 60, 3), dtype=np.uint8)
    view = image[:, ::2]  # not contiguous
    out = draw_boxes(view, [[-100, -100, 1000, 1000], [5.4, 5.6, 20.2, 20.0]], thickness=1)
    assert out.shape == (40, 30, 3)
    assert not out[0].any()  # the huge box's edges are all outside
    # Float box rounds to [5, 6, 20, 20): top edge row 6, columns 5..19.
    np.testing.assert_array_equal(np.flatnonzero(out[6, :, 1]), np.arange(5, 20))


def test_draw_no_boxes_is_a_copy():
    image = _image()
    out = draw_boxes(image, np.zeros((0, 4)), labels=[])
    assert np.array_equal(out, image) and out is not image


@pytest.mark.parametrize(
    "image, kwargs",
    [
        (np.zeros((10, 10, 3), dtype=np.float32), {}),
        (np.zeros((10, 10), dtype=np.uint8), {}),
        (np.zeros((10, 10, 4), dtype=np.uint8), {}),
        (np.zeros((10, 10, 3), dtype=np.uint8), {"labels": ["a", "b"]}),
        (np.zeros((10, 10, 3), dtype=np.uint8), {"thickness": 0}),
        (np.zeros((10, 10, 3), dtype=np.uint8), {"color": (0, 300, 0)}),
        (np.zeros((10, 10, 3), dtype=np.uint8), {"color": (0, 255)}),
    ],
)
def test_draw_rejects_bad_arguments(image, kwargs):
    with pytest.raises(ValueError):
        draw_boxes(image, [[1, 1, 5, 5]], **kwargs)


def test_draw_detections_labels_tracked_boxes_only():
    image = _image(value=0)
    box = [[10, 30, 40, 50]]
    untracked = draw_detections(image, Detections(box))
    tracked = draw_detections(image, Detections(box, track_id=[7]))
    assert np.array_equal(untracked, draw_boxes(image, box, thickness=4))
    assert np.array_equal(tracked, draw_boxes(image, box, thickness=4, labels=["car 7"]))
    assert not np.array_equal(tracked, untracked)


def test_context_region_stays_in_the_frame_at_the_aspect_ratio():
    from vehicle_detection.viz.drawing import context_region

    r = context_region([[600, 300, 700, 380]], (720, 1280, 3))
    assert r[0] < 600 and r[1] < 300 and r[2] > 700 and r[3] > 380
    assert (r[2] - r[0]) / (r[3] - r[1]) == pytest.approx(4 / 3, abs=0.02)
    r = context_region([[1250, 690, 1280, 720]], (720, 1280, 3))  # a corner: shifted inside
    assert r[2] == 1280 and r[3] == 720 and r[0] >= 0 and r[1] >= 0 and r[3] - r[1] >= 96
    r = context_region([[0, 0, 1280, 720]], (720, 1280, 3))  # bigger than the frame: the frame
    assert r.tolist() == [0, 0, 1280, 720]


def test_failure_tile_and_sheet_shapes():
    from vehicle_detection.viz.drawing import IGNORE_COLOR, LABEL_COLOR, REPORTED_COLOR, failure_sheet, failure_tile
    from vehicle_detection.metrics.detection import Failure

    frame = _image(h=720, w=1280, value=90)
    miss = Failure(0, "miss", np.array([600.0, 300, 700, 380]), 0.2, np.array([640.0, 300, 740, 380]))
    tile = failure_tile(frame, miss, [[600, 300, 700, 380]], [[0, 280, 640, 480]], [[640, 300, 740, 380]], "f.json frame 0")
    assert tile.shape == (192 + 38, 256, 3) and tile.dtype == np.uint8
    for color in (LABEL_COLOR, REPORTED_COLOR, IGNORE_COLOR):
        assert (tile == color).all(axis=-1).any(), color
    sheet = failure_sheet([tile] * 7, "title", "note", ncols=3)
    assert sheet.shape == (62 + 4 + 3 * (230 + 4), max(640, 4 + 3 * 260), 3)
    with pytest.raises(ValueError, match="one shape"):
        failure_sheet([tile, tile[:-1]], "t")


def test_draw_into_out():
    image = _image()
    boxes, labels = [[10, 10, 30, 30], [40, 5, 70, 50]], ["car 1", "car 2"]
    expected = draw_boxes(image, boxes, labels=labels)
    same = image.copy()
    assert draw_boxes(same, boxes, labels=labels, out=same) is same  # in place
    np.testing.assert_array_equal(same, expected)
    other = np.zeros_like(image)
    assert draw_boxes(image, boxes, labels=labels, out=other) is other
    np.testing.assert_array_equal(other, expected)
    assert np.all(image == 50)
    found = Detections(np.array(boxes, float), track_id=np.array([1, 2]))
    frame = image.copy()
    assert draw_detections(frame, found, out=frame) is frame
    np.testing.assert_array_equal(frame, draw_detections(image, found))
    nothing = image.copy()
    assert draw_detections(nothing, Detections(np.zeros((0, 4))), out=nothing) is nothing
    assert np.all(nothing == 50)


@pytest.mark.parametrize("make", [
    lambda im: np.zeros((60, 81, 3), np.uint8),  # another shape
    lambda im: np.zeros(im.shape, np.float32),
    lambda im: np.zeros((60, 160, 3), np.uint8)[:, ::2],  # not contiguous
    lambda im: np.frombuffer(bytes(im.size), np.uint8).reshape(im.shape),  # read-only
    lambda im: im.tolist(),
])
def test_draw_refuses_a_bad_out(make):
    image = _image()
    with pytest.raises(ValueError, match="out must be"):
        draw_boxes(image, [[1, 1, 5, 5]], out=make(image))


# --- labels of neighbouring cars --------------------------------------------------------------------

#: Neighbouring cars of a 640x360 frame: two side by side with their tops level, one just below
#: them, one against the right edge, one against the top edge.
CROWD = [[100, 120, 160, 170], [126, 120, 186, 170], [110, 150, 170, 200], [600, 60, 640, 100], [300, 0, 360, 40]]
CROWD_LABELS = ["car 1 21 m", "car 17 25 m", "car 3 12 m", "car 22 40 m", "car 5 60 m"]


def _disjoint(rects) -> bool:
    r = np.asarray(rects)
    apart = ((r[:, None, 2] <= r[None, :, 0]) | (r[None, :, 2] <= r[:, None, 0])
             | (r[:, None, 3] <= r[None, :, 1]) | (r[None, :, 3] <= r[:, None, 1]))
    np.fill_diagonal(apart, True)
    return bool(apart.all())


def test_place_labels_keeps_tags_apart_inside_the_frame_and_near_their_boxes():
    sizes = [[90, 22]] * len(CROWD)
    rects, shown = place_labels(CROWD, sizes, (360, 640))
    assert shown.all()
    assert _disjoint(rects)
    assert (rects[:, :2] >= 0).all() and (rects[:, 2] <= 640).all() and (rects[:, 3] <= 360).all()
    assert (rects[:, 2:] - rects[:, :2] == sizes).all()  # no tag shrunk
    assert rects[2].tolist() == [110, 128, 200, 150]  # the nearest car's tag: its place of choice, above its box
    # a lone box gets its tag above its top-left corner; one at the top edge, inside its box
    assert place_labels([[10, 40, 60, 80]], [[40, 12]], (100, 100))[0].tolist() == [[10, 28, 50, 40]]
    assert place_labels([[10, 0, 60, 80]], [[40, 12]], (100, 100))[0].tolist() == [[10, 0, 50, 12]]


def test_place_labels_leaves_out_what_fits_nowhere():
    rects, shown = place_labels([[0, 0, 10, 10]] * 4, [[30, 10], [30, 10], [30, 10], [200, 10]], (21, 40))
    assert shown.tolist() == [True, True, False, False]  # two rows of tags, 1 pixel apart, fill the frame; the last is wider than it
    assert _disjoint(rects[shown])
    with pytest.raises(ValueError):
        place_labels([[0, 0, 10, 10]], [[5, 5], [5, 5]], (20, 20))


def _ink(image: np.ndarray) -> int:
    """Pixels of label text: neither the white frame nor the green of the boxes and tags."""
    return int((np.abs(image.astype(int) - [0, 255, 0]).sum(axis=2) > 30).sum() - (image == 255).all(axis=2).sum())


def test_drawn_labels_of_neighbouring_cars_are_whole():
    # "car 1 21 m" used to be cut to "ar 1 21 m" under its neighbour's tag, and a tag at the right
    # edge ran out of the frame: every label's text must be drawn whole.
    frame = np.full((360, 640, 3), 255, np.uint8)
    drawn = draw_boxes(frame, CROWD, thickness=1, labels=CROWD_LABELS)
    alone = 0
    for label in CROWD_LABELS:  # each label on its own, in the middle of a large frame
        big = np.full((400, 800, 3), 255, np.uint8)
        alone += _ink(draw_boxes(big, [[350, 200, 450, 260]], thickness=1, labels=[label]))
    assert _ink(drawn) == alone
