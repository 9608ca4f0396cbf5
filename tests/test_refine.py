"""Box refinement: offsets, clipping, learning on synthetic frames, and the model file."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from vehicle_detection.classifier import VehicleClassifier, load_default_model
from vehicle_detection.errors import ModelError
from vehicle_detection.features import FeatureConfig
from vehicle_detection.geometry import box_iou
from vehicle_detection.refine import (
    MAX_OFFSET,
    BoxRegressor,
    SideFit,
    apply_offsets,
    crop_windows,
    edge_offsets,
    fit_box_regressor,
    fit_sides,
    beyond_jitter,
    hot_window_targets,
    jittered_windows,
)
from vehicle_detection.search import SearchPlan, SearchScale, search

SMALL = FeatureConfig(color_space="YCrCb", orientations=9, hog_channels=(0,), spatial_size=8, hist_bins=8)


def test_offsets_move_windows_onto_their_boxes():
    windows = np.array([[100, 200, 164, 264], [0, 0, 128, 128]])
    boxes = np.array([[90, 220, 180, 260], [10, 30, 120, 100]])
    d = edge_offsets(windows, boxes)
    assert d[0].tolist() == pytest.approx([-10 / 64, 20 / 64, 16 / 64, -4 / 64])
    assert apply_offsets(windows, d, (720, 1280)).tolist() == boxes.tolist()


@settings(max_examples=200, deadline=None)
@given(
    st.integers(-300, 1500), st.integers(-300, 800), st.integers(8, 600),
    st.lists(st.floats(-5, 5, allow_nan=False), min_size=4, max_size=4), st.integers(1, 3),
)
def test_refinement_never_leaves_the_frame(x, y, side, offsets, n_coef):
    h, w = 480, 854
    window = np.array([[x, y, x + side, y + side]], np.float64)
    reg = BoxRegressor(np.zeros((4, n_coef)), np.array(offsets))
    box = reg.refine(window, np.zeros((1, n_coef)), (h, w))[0]
    assert 0 <= box[0] < box[2] <= w and 0 <= box[1] < box[3] <= h
    inside = apply_offsets(window, np.clip(offsets, -MAX_OFFSET, MAX_OFFSET), (10**6, 10**6))[0]
    if 0 <= inside[0] < inside[2] <= w and 0 <= inside[1] < inside[3] <= h:  # no clipping needed: moved as predicted
        assert box.tolist() == inside.tolist()


def test_offsets_are_bounded():
    reg = BoxRegressor(np.zeros((4, 2)), np.array([3.0, -3.0, 0.1, -0.1]))
    assert reg.offsets(np.zeros((1, 2)))[0].tolist() == [MAX_OFFSET, -MAX_OFFSET, 0.1, -0.1]


def test_regressor_checks_its_arrays():
    with pytest.raises(ValueError):
        BoxRegressor(np.zeros((3, 5)), np.zeros(3))
    with pytest.raises(ValueError):
        BoxRegressor(np.full((4, 5), np.nan), np.zeros(4))


def test_crop_windows_mirrors_beyond_the_edges():
    frame = np.arange(20 * 30 * 3, dtype=np.uint8).reshape(20, 30, 3)
    inside = crop_windows(frame, [[5, 5, 13, 13]], 8)[0]
    assert np.array_equal(inside, frame[5:13, 5:13])
    edge = crop_windows(frame, [[-4, 0, 4, 8]], 8)[0]
    assert np.array_equal(edge[:, 4:], frame[0:8, 0:4]) and np.array_equal(edge[:, 3], frame[0:8, 1])


def _synthetic_road(rng, n_cars=2, h=240, w=400):
    """A grey textured road with dark, wheeled boxes: frames and the cars' boxes."""
    frame = rng.integers(90, 130, (h, w, 3)).astype(np.uint8)
    boxes = []
    for _ in range(n_cars):
        bw = int(rng.integers(50, 110))
        bh = int(bw * rng.uniform(0.6, 0.9))
        x, y = int(rng.integers(0, w - bw)), int(rng.integers(0, h - bh))
        frame[y : y + bh, x : x + bw] = rng.integers(10, 40, 3)
        frame[y + bh // 5 : y + bh // 2, x + bw // 8 : x + bw - bw // 8] = 200  # a window
        boxes.append([x, y, x + bw, y + bh])
    return frame, np.array(boxes)


def test_learned_refinement_tightens_windows_on_held_out_frames():
    rng = np.random.default_rng(0)
    # 20 training frames and 8 held-out ones (were 40 and 15): the mean IoU still gains 0.36
    train = [_synthetic_road(rng, 1) for _ in range(20)]
    reg = fit_box_regressor(train, SMALL, per_box=24, alpha=10.0, reference_height=240)
    from vehicle_detection.features import extract_features

    before, after = [], []
    for frame, boxes in (_synthetic_road(rng, 1) for _ in range(8)):
        wins = np.rint(jittered_windows(boxes[0], rng, 10))
        refined = reg.refine(wins, extract_features(crop_windows(frame, wins, SMALL.window), SMALL), frame.shape)
        before.append(box_iou(wins, boxes)[:, 0].mean())
        after.append(box_iou(refined, boxes)[:, 0].mean())
    assert np.mean(after) > np.mean(before) + 0.1


def test_hot_window_targets_pair_each_window_with_the_vehicle_it_overlaps_most():
    boxes = np.array([[100, 100, 200, 160], [300, 100, 380, 170]])
    windows = np.array([
        [100, 90, 180, 170],   # on the first car (IoU 0.63)
        [110, 100, 150, 140],  # a part of it (IoU 0.27): dropped at 0.5
        [290, 95, 370, 175],   # on the second (IoU 0.69)
        [0, 0, 64, 64],        # on neither
        [190, 100, 330, 170],  # between them, more on the second (IoU 0.04 and 0.16)
    ])
    assert box_iou(windows, boxes).round(2).tolist() == [[0.63, 0.0], [0.27, 0.0], [0.0, 0.69], [0.0, 0.0], [0.04, 0.16]]
    kept, theirs = hot_window_targets(windows, boxes, 0.5)
    assert kept.tolist() == windows[[0, 2]].tolist() and theirs.tolist() == boxes[[0, 1]].tolist()
    kept, theirs = hot_window_targets(windows, boxes, 0.25)
    assert theirs.tolist() == boxes[[0, 0, 1]].tolist()
    kept, theirs = hot_window_targets(windows, boxes, 0.12)
    assert kept.tolist() == windows[[0, 1, 2, 4]].tolist() and theirs.tolist() == boxes[[0, 0, 1, 1]].tolist()
    assert [a.shape for a in hot_window_targets(windows[:0], boxes, 0.5)] == [(0, 4), (0, 4)]
    assert [a.shape for a in hot_window_targets(windows, boxes[:0], 0.5)] == [(0, 4), (0, 4)]
    with pytest.raises(ValueError, match="min_iou"):
        hot_window_targets(windows, boxes, 0.0)


def test_beyond_jitter_finds_the_windows_jittering_never_draws():
    rng = np.random.default_rng(6)
    box = np.array([100.0, 100.0, 220.0, 180.0])  # larger side 120
    drawn = jittered_windows(box, rng, 500)
    assert not beyond_jitter(drawn, np.repeat(box[None], 500, axis=0)).any()
    windows = np.array([
        [100, 100, 180, 180],  # side 80 < 0.75 x 120
        [60, 60, 260, 260],    # side 200 > 1.5 x 120 = 180
        [130, 80, 230, 180],   # side 100, centre 20 px right = 0.2 sides: drawn
        [140, 80, 240, 180],   # centre 30 px right = 0.3 sides: not drawn
        [110, 90, 210, 190],   # side 100, centred: drawn
    ], np.float64)
    assert beyond_jitter(windows, np.repeat(box[None], 5, axis=0)).tolist() == [True, True, False, True, False]
    with pytest.raises(ValueError, match="hot_iou"):
        fit_box_regressor([], SMALL, hot_iou=0.0)


def test_accepted_windows_like_the_jittered_ones_change_nothing():
    rng = np.random.default_rng(7)
    train = [_long_car(rng) for _ in range(6)]
    like = [(f, b, jittered_windows(b[0], np.random.default_rng(i), 5)) for i, (f, b, _) in enumerate(train)]
    plain = fit_box_regressor([t[:2] for t in train], SMALL, per_box=8, alpha=10.0, reference_height=240)
    same = fit_box_regressor(like, SMALL, per_box=8, alpha=10.0, reference_height=240, hot_iou=0.1)
    other = fit_box_regressor(train, SMALL, per_box=8, alpha=10.0, reference_height=240, hot_iou=0.1)
    assert np.array_equal(plain.coef, same.coef) and np.array_equal(plain.intercept, same.intercept)
    assert not np.array_equal(plain.coef, other.coef)


def _long_car(rng):
    """A grey road with one dark car twice as wide as high (a car seen at an angle, its side
    beside its rear), its box, and a window on its rear: square, as tall as the car, at its
    left end; smaller than the car and off its centre, which jittering around it never draws."""
    frame = rng.integers(90, 130, (240, 400, 3)).astype(np.uint8)
    h = int(rng.integers(40, 70))
    x, y = int(rng.integers(0, 400 - 2 * h)), int(rng.integers(0, 240 - h))
    frame[y : y + h, x : x + 2 * h] = rng.integers(10, 40, 3)
    frame[y + h // 5 : y + h // 2, x + h // 8 : x + h - h // 8] = 200  # the rear window
    return frame, np.array([[x, y, x + 2 * h, y + h]]), np.array([[x, y, x + h, y + h]], np.float64)


@pytest.mark.parametrize("zoom", [1, 2])
def test_accepted_windows_teach_the_refinement_what_jittering_does_not(zoom):
    """Frames of ``zoom`` times the reference height: the windows, in frame pixels, are scaled
    to the frame the features are cut from."""
    import cv2

    rng = np.random.default_rng(5)
    # 20 training frames and 8 held-out ones (were 40 and 15): the accepted windows still gain 0.35 IoU
    train = [_long_car(rng) for _ in range(20)]
    train = [(cv2.resize(f, None, fx=zoom, fy=zoom, interpolation=cv2.INTER_NEAREST), b * zoom, w * zoom) for f, b, w in train]
    jitter_only = fit_box_regressor([t[:2] for t in train], SMALL, per_box=24, alpha=10.0, reference_height=240)
    with_hot = fit_box_regressor(train, SMALL, per_box=24, alpha=10.0, reference_height=240, hot_iou=0.3)
    from vehicle_detection.features import extract_features

    iou = {"jitter": [], "hot": []}
    for frame, boxes, rear in (_long_car(rng) for _ in range(8)):
        feats = extract_features(crop_windows(frame, rear, SMALL.window), SMALL)
        for name, reg in (("jitter", jitter_only), ("hot", with_hot)):
            iou[name].append(box_iou(reg.refine(rear, feats, frame.shape), boxes)[0, 0])
    assert np.mean(iou["hot"]) > np.mean(iou["jitter"]) + 0.1, iou


def _with_regressor(model: VehicleClassifier, seed: int = 0) -> VehicleClassifier:
    rng = np.random.default_rng(seed)
    n = model.config.n_features
    return model.replace(box_regressor=BoxRegressor(rng.normal(0, 1e-4, (4, n)), [-0.05, 0.1, 0.05, -0.1]))


def test_model_file_keeps_the_refinement(tmp_path):
    model = _with_regressor(load_default_model())
    loaded = VehicleClassifier.load(model.save(tmp_path / "m.npz"))
    assert np.array_equal(loaded.box_regressor.coef, model.box_regressor.coef)
    assert np.array_equal(loaded.box_regressor.intercept, model.box_regressor.intercept)
    assert load_default_model().replace(box_regressor=None).box_regressor is None


def _rewrite(path, out, drop=(), change=None):
    with np.load(path, allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files if k not in drop}
    if change:
        arrays.update(change)
    with open(out, "wb") as f:
        np.savez(f, **arrays)
    return out


def test_model_file_with_a_broken_refinement_is_refused(tmp_path):
    path = _with_regressor(load_default_model()).save(tmp_path / "m.npz")
    with pytest.raises(ModelError, match="arrays"):
        VehicleClassifier.load(_rewrite(path, tmp_path / "half.npz", drop=("box_intercept",)))
    with pytest.raises(ModelError, match="box refinement"):
        VehicleClassifier.load(_rewrite(path, tmp_path / "shape.npz", change={"box_coef": np.zeros((4, 3))}))
    with pytest.raises(ModelError, match="checksum"):
        VehicleClassifier.load(_rewrite(path, tmp_path / "edit.npz", change={"box_intercept": np.zeros(4)}))


def test_search_reports_refined_boxes_inside_the_frame(test_frames):
    model = _with_regressor(load_default_model(), seed=1)
    plan = SearchPlan(scales=(SearchScale(2.0, 380, 620, step=1),), overhang=0.5)
    n = 0
    for frame in test_frames[:3]:
        found = search(frame, model, plan)
        n += len(found)
        assert "box" in found.data and found.data["box"].shape == (len(found), 4)
        boxes = found.data["box"]
        h, w = frame.shape[:2]
        assert np.all(boxes[:, :2] >= 0) and np.all(boxes[:, 2] <= w) and np.all(boxes[:, 3] <= h)
        assert np.all(boxes[:, 2:] > boxes[:, :2])
        plain = search(frame, model.replace(box_regressor=None), plan)
        assert np.array_equal(plain.xyxy, found.xyxy) and np.array_equal(plain.score, found.score)
        assert "box" not in plain.data
    assert n > 0


def test_refined_boxes_follow_the_picture_inside_black_bars(test_frames):
    from vehicle_detection.detector import Detector

    detector = Detector(_with_regressor(load_default_model(), seed=2))
    frame = test_frames[0]
    padded = np.zeros((720, 1280 + 2 * 96, 3), np.uint8)
    padded[:, 96:-96] = frame
    plain, barred = detector.windows(frame), detector.windows(padded)
    assert len(plain) > 0 and np.array_equal(plain.xyxy + [96, 0, 96, 0], barred.xyxy)
    assert np.array_equal(plain.data["box"] + [96, 0, 96, 0], barred.data["box"])


def test_offsets_are_the_linear_map_of_the_features():
    rng = np.random.default_rng(4)
    coef, intercept = rng.normal(0, 0.01, (4, 300)), rng.normal(0, 0.1, 4)
    features = rng.random((7, 300)).astype(np.float32)
    want = np.clip(features.astype(np.float64) @ coef.T + intercept, -MAX_OFFSET, MAX_OFFSET)
    np.testing.assert_allclose(BoxRegressor(coef, intercept).offsets(features), want, atol=1e-5)


def test_labelled_frames_give_vehicle_patches_grouped_by_blocks(tmp_path):
    from vehicle_detection.training.data import Dataset
    from vehicle_detection.metrics.detection import load_annotations
    from vehicle_detection.training.mining import labelled_dataset

    repo = Path(__file__).resolve().parents[1]
    labels = load_annotations(repo / "dev_set" / "test_images.json")
    ds = labelled_dataset([labels], per_car=3)
    n_cars = sum(len(f.cars) for f in labels.frames.values())
    assert len(ds) == 3 * n_cars and set(ds.labels.tolist()) == {1} and ds.images.shape[1:] == (64, 64, 3)
    assert set(ds.sources.tolist()) == {"vehicles/labelled_test_images"}
    other = Dataset.from_patches([(ds.images[:2], ["x/a.png", "x/b.png"], "g")], label=0)
    joined = ds.concatenate(other)
    assert len(joined) == len(ds) + 2 and joined.labels[-2:].tolist() == [0, 0]
    assert not set(joined.groups[-2:].tolist()) & set(ds.groups.tolist())


@pytest.mark.parametrize(("index", "border"), [(0, "frame"), (3, "frame"), (0, "crop")])
def test_search_reads_the_refinement_off_the_features_it_scored_with(default_model, test_frames, index, border):
    """The fast path's edge products equal those of the hot windows' features: their patches'
    (``"crop"``), with the HOG cut from the band's gradients (``"frame"``)."""
    from reference_search import frame_hog_plain

    from vehicle_detection.features import extract_features
    from vehicle_detection.search import _band, _band_patches, _score_band, _working_frame

    for model in (default_model, _with_regressor(default_model, seed=5)):
        plan, cfg = model.detector_config.plan, model.config
        work, _ = _working_frame(test_frames[index], plan)
        n_hot = 0
        for s in plan.scales:
            band = _band(work, s, cfg, plan.overhang_of(s), plan.y_shift)
            margins, products = _score_band(band, model, reuse=False, refine_above=plan.threshold - 1.0,
                                            frame=border == "frame")
            hot = margins > plan.threshold - 1.0
            assert np.array_equal(~np.isnan(products[:, 0]), hot)
            n_hot += hot.sum()
            if not hot.any():
                continue
            features = extract_features(_band_patches(band, cfg, hot), cfg).astype(np.float64)
            if border == "frame":
                corners = [(band.rows[i // len(band.cols)] * cfg.pixels_per_cell, band.cols[i % len(band.cols)] * cfg.pixels_per_cell)
                           for i in np.flatnonzero(hot)]
                features[:, cfg.layout()["hog"]] = frame_hog_plain(band.image, corners, cfg)
            want = features @ model.box_regressor.coef.T
            np.testing.assert_allclose(products[hot], want, rtol=1e-4, atol=1e-5)
        assert n_hot > 5


# --- sides fitted to the image -------------------------------------------------------------------


def _dark_car(x1=500, x2=700, y1=300, y2=420, shape=(480, 854), seed=0):
    """A grey road with noise and a dark car ``[x1, x2) x [y1, y2)``, its rear window lighter."""
    rng = np.random.default_rng(seed)
    frame = rng.integers(110, 130, (*shape, 3)).astype(np.uint8)
    frame[y1:y2, x1:x2] = 40
    w, h = x2 - x1, y2 - y1
    frame[y1 + h // 8 : y1 + h // 3, x1 + w // 6 : x2 - w // 6] = 90  # rear window, above the rows that count
    return frame


@pytest.mark.parametrize("off", [(-12, 9), (10, -14), (-6, -6), (15, 15)])
def test_sides_move_onto_the_vehicle_edges(off):
    frame = _dark_car()
    box = np.array([[500 + off[0], 300, 700 + off[1], 420]])
    fitted = fit_sides(frame, box, SideFit())[0]
    assert abs(fitted[0] - 500) <= 1 and abs(fitted[2] - 700) <= 1  # within a pixel of the car's sides
    assert fitted[1:4:2].tolist() == [300, 420]  # top and bottom as they were


def test_a_side_further_than_the_reach_moves_at_most_the_reach():
    frame = _dark_car()
    box = np.array([[460, 300, 740, 420]])  # 40 px outside each side; reach 0.1 x 280 = 28 px
    fitted = fit_sides(frame, box, SideFit(reach=0.1))[0]
    assert abs(fitted[0] - 460) <= 28 and abs(fitted[2] - 740) <= 28
    wider = fit_sides(frame, box, SideFit(reach=0.2))[0]  # within reach now
    assert abs(wider[0] - 500) <= 1 and abs(wider[2] - 700) <= 1


def test_the_outline_wins_over_a_stronger_edge_inside():
    """A bright tail light 6 px inside the left side: its edges are stronger than the outline's;
    ``outer`` keeps the side on the outline, ``outer=1`` takes the strongest edge."""
    frame = _dark_car()
    frame[340:400, 506:520] = 255
    box = np.array([[503, 300, 700, 420]])
    assert abs(fit_sides(frame, box, SideFit(outer=0.5))[0, 0] - 500) <= 1
    assert fit_sides(frame, box, SideFit(outer=1.0))[0, 0] >= 505


def test_a_vehicle_cut_by_the_frame_keeps_the_frame_edge():
    frame = _dark_car(x1=700, x2=854)
    for x2 in (854, 845):  # at the edge, and short of it by 9 px (reach 0.1 x 150 = 15 px)
        fitted = fit_sides(frame, np.array([[702, 300, x2, 420]]), SideFit(reach=0.1))[0]
        assert fitted[2] == 854 and abs(fitted[0] - 700) <= 1


def test_the_picture_edge_inside_black_bars_counts_as_the_frame_edge():
    frame = _dark_car(x1=640, x2=760)
    frame[:, 760:] = 0  # a pillarbox bar: the picture is columns 0..759
    box = np.array([[642, 300, 752, 420]])  # short of the picture's edge by 8 px (reach 11 px)
    assert fit_sides(frame, box, SideFit(), area=(0, 0, 760, 480))[0, 2] == 760
    assert fit_sides(frame, np.array([[642, 300, 760, 420]]), SideFit(), area=(0, 0, 760, 480))[0, 2] == 760
    free = fit_sides(frame, box, SideFit())[0, 2]  # the frame's edge is far: the car's own edge at the bar
    assert abs(free - 760) <= 1


def test_flat_and_tiny_boxes_are_left_alone():
    flat = np.full((200, 300, 3), 128, np.uint8)
    boxes = np.array([[50, 50, 150, 120], [10, 10, 16, 40]])
    assert fit_sides(flat, boxes, SideFit()).tolist() == boxes.tolist()
    noisy = _dark_car(shape=(200, 300), x1=100, x2=200, y1=50, y2=120)
    assert fit_sides(noisy, boxes[1:], SideFit()).tolist() == boxes[1:].tolist()  # 6 px wide: too small to measure


@settings(max_examples=150, deadline=None)
@given(st.integers(0, 2**32 - 1), st.integers(-5, 300), st.integers(-5, 200), st.integers(1, 400), st.integers(1, 300))
def test_fitted_sides_stay_inside_the_frame(seed, x, y, w, h):
    rng = np.random.default_rng(seed)
    frame = rng.integers(0, 256, (200, 300, 3)).astype(np.uint8)
    box = np.array([[max(0, x), max(0, y), min(300, max(0, x) + w), min(200, max(0, y) + h)]])
    if box[0, 2] <= box[0, 0] or box[0, 3] <= box[0, 1]:
        return
    fit = SideFit()
    fitted = fit_sides(frame, box, fit)[0]
    assert 0 <= fitted[0] < fitted[2] <= 300 and fitted[1:4:2].tolist() == box[0, 1:4:2].tolist()
    bw = box[0, 2] - box[0, 0]
    assert abs(fitted[0] - box[0, 0]) <= fit.reach * bw + 1 and abs(fitted[2] - box[0, 2]) <= fit.reach * bw + 1


def test_side_fit_settings_are_checked_and_round_trip():
    fit = SideFit(reach=0.15, prior=0.05, outer=0.8, rows=(0.2, 0.9))
    assert SideFit.from_dict(fit.to_dict()) == fit
    for bad in (dict(reach=0.0), dict(reach=0.5), dict(prior=-1.0), dict(outer=0.0), dict(outer=1.5), dict(rows=(0.9, 0.2)), dict(reach=True)):
        with pytest.raises(ValueError, match=next(iter(bad))):
            SideFit(**bad)
    with pytest.raises(ValueError, match="keys"):
        SideFit.from_dict({"reach": 0.1})


def test_side_fit_tightens_the_boxes_of_the_labelled_test_images(default_model, test_frames):
    """The six test images against their labels (dev_set/test_images.json): the fitted boxes
    overlap their cars more than the same detector's boxes without the fit."""
    import json

    from vehicle_detection.detector import Detector

    labels = json.loads((Path(__file__).resolve().parents[1] / "dev_set" / "test_images.json").read_text())["frames"]
    fitted = Detector(default_model.replace(detector_config=default_model.detector_config.replace(side_fit=SideFit())))
    plain = Detector(default_model.replace(detector_config=default_model.detector_config.replace(side_fit=None)))
    gains = []
    for key, entry in labels.items():
        cars = np.array(entry["cars"], np.float64).reshape(-1, 4)
        if not len(cars):
            continue
        frame = test_frames[int(key)]
        before = plain.detect_image(frame).xyxy
        after = fitted.detect_image(frame).xyxy
        assert len(after) == len(before)
        gains.append(box_iou(cars, after).max(axis=1) - box_iou(cars, before).max(axis=1))
    gains = np.concatenate(gains)
    assert gains.mean() > 0.01 and (gains > 0).sum() > (gains < 0).sum()


def test_box_refinement_learns_from_the_windows_the_detector_accepts(monkeypatch):
    """``with_box_refinement`` hands the fit each labelled frame with the windows that the
    model's own detector accepts in it (``hot_iou=None``: the frames and cars only)."""
    from vehicle_detection.detector import Detector
    from vehicle_detection.metrics.detection import load_annotations
    from vehicle_detection.training import fit

    seen = {}

    def spy(samples, config, **kwargs):
        seen[kwargs.get("hot_iou")] = [tuple(np.array(a, copy=True) for a in s) for s in samples]
        return BoxRegressor(np.zeros((4, config.n_features)), np.zeros(4))

    monkeypatch.setattr(fit, "fit_box_regressor", spy)
    labels = load_annotations(Path(__file__).resolve().parents[1] / "dev_set" / "test_images.json")
    model = load_default_model()
    refined = fit.with_box_refinement(model, [labels])
    plain_model = fit.with_box_refinement(model, [labels], hot_iou=None)
    assert refined.metrics["box_refinement"]["hot_iou"] == 0.5 and plain_model.metrics["box_refinement"]["hot_iou"] is None
    with_windows, plain = seen[0.5], seen[None]
    assert len(with_windows) == len(plain) == len(labels.frames) and all(len(s) == 2 for s in plain)
    detector = Detector(model, model.detector_config)
    accepted = 0
    for (frame, cars, windows), (_, cars_plain), want in zip(with_windows, plain, labels.frames.values()):
        assert np.array_equal(cars, want.cars) and np.array_equal(cars_plain, want.cars)
        assert np.array_equal(windows, detector.windows(frame).xyxy)
        accepted += len(windows)
    assert accepted > 0


def test_a_refinement_fitted_with_mirrored_frames_moves_mirrored_windows_the_mirrored_way():
    # Cars seen at an angle, always with their rear at the left end: a plain refinement learns
    # to move a window on the rear to the right; fitted with the frames mirrored too, it moves
    # a mirrored window to the left just as far (a car in left-hand traffic).
    from vehicle_detection.features import extract_features
    from vehicle_detection.geometry import mirror_boxes

    rng = np.random.default_rng(3)
    train = [_long_car(rng) for _ in range(12)]
    fits = {m: fit_box_regressor(train, SMALL, per_box=16, alpha=10.0, reference_height=240, hot_iou=0.3, mirror=m) for m in (False, True)}
    gaps = {}
    for mirror, reg in fits.items():
        gap = []
        for frame, _, rear in (_long_car(rng) for _ in range(8)):
            flipped, width = np.ascontiguousarray(frame[:, ::-1]), frame.shape[1]
            move = reg.offsets(extract_features(crop_windows(frame, rear, SMALL.window), SMALL))
            back = reg.offsets(extract_features(crop_windows(flipped, mirror_boxes(rear, width), SMALL.window), SMALL))
            # the mirror of a move [left, top, right, bottom] is [-right, top, -left, bottom]
            gap.append(np.abs(back - move[:, [2, 1, 0, 3]] * [-1, 1, -1, 1]).max())
        gaps[mirror] = max(gap)
    # close, not equal: 9 signed orientation bins are not symmetric about the vertical, so a
    # mirrored patch's HOG is near, not exactly, a permutation of the patch's
    assert gaps[True] < 0.06
    assert gaps[False] > 0.3


def test_labelled_frames_of_left_hand_traffic_teach_the_refinement_as_the_search_sees_them(tmp_path, default_model):
    # The test images flipped, labelled where their cars are, and learned as left-hand traffic:
    # flipped back as the detector's search flips them, they teach exactly what the images do.
    import json

    import cv2

    from vehicle_detection.geometry import mirror_boxes
    from vehicle_detection.metrics.detection import load_annotations
    from vehicle_detection.training.fit import with_box_refinement

    repo = Path(__file__).resolve().parents[1]
    doc = json.loads((repo / "dev_set" / "test_images.json").read_text())
    folder = tmp_path / "flipped"
    folder.mkdir()
    for entry in doc["frames"].values():
        image = cv2.imread(str(repo / "test_images" / entry["file"]))
        cv2.imwrite(str(folder / Path(entry["file"]).with_suffix(".png")), np.ascontiguousarray(image[:, ::-1]))
        entry["file"] = str(Path(entry["file"]).with_suffix(".png"))
        for key in ("cars", "ignore"):
            entry[key] = mirror_boxes(np.array(entry[key], np.int64).reshape(-1, 4), image.shape[1]).tolist()
    doc["video"] = str(folder)
    (tmp_path / "flipped.json").write_text(json.dumps(doc))
    # the originals, losslessly, so that flipping back gives their pixels
    same = tmp_path / "same"
    same.mkdir()
    for entry in doc["frames"].values():
        cv2.imwrite(str(same / entry["file"]), cv2.imread(str(folder / entry["file"]))[:, ::-1])
    (tmp_path / "same.json").write_text(json.dumps({**doc, "frames": json.loads((repo / "dev_set" / "test_images.json").read_text())["frames"],
                                                     "video": str(same)}).replace(".jpg", ".png"))
    left = with_box_refinement(default_model, [load_annotations(tmp_path / "flipped.json")], traffic="left")
    right = with_box_refinement(default_model, [load_annotations(tmp_path / "same.json")])
    assert left.detector_config.traffic == "left" and right.detector_config.traffic == "right"
    assert np.array_equal(left.box_regressor.coef, right.box_regressor.coef)
    # learned as right-hand traffic, the flipped frames teach something else
    other = with_box_refinement(default_model, [load_annotations(tmp_path / "flipped.json")], traffic="right")
    assert not np.allclose(other.box_regressor.coef, right.box_regressor.coef)
