"""Tests of vehicle_detection.training.augment and of augmentation in training (groups kept)."""

from __future__ import annotations

import json
import math

import cv2
import numpy as np
import pytest

from vehicle_detection.features import FeatureConfig
from vehicle_detection.training import fit
from vehicle_detection.training.augment import AugmentConfig, augment, blur, flip, jpeg, photometric, scale_jitter
from vehicle_detection.training.data import Dataset
from vehicle_detection.training.fit import split_indices, train, with_copies

TRANSFORMS = (flip, scale_jitter, blur, photometric, jpeg)


def _noise(n=6, seed=0):
    return np.random.default_rng(seed).integers(0, 256, (n, 64, 64, 3), dtype=np.uint8)


def _scene(n=6, seed=0):
    """Smooth patches with edges (a bright box on a gradient), more like a picture than noise."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:64, :64]
    out = np.empty((n, 64, 64, 3), np.uint8)
    for i in range(n):
        base = 40 + xx * rng.uniform(0.5, 1.5) + yy * rng.uniform(0.2, 1.0)
        base = np.where((abs(xx - 32) < 14) & (abs(yy - 36) < 10), 200.0, base)
        out[i] = np.clip(base[..., None] * np.array([1.0, 0.9, 0.8]), 0, 255).astype(np.uint8)
    return out


def _constant(values):
    return np.stack([np.full((64, 64, 3), v, np.uint8) for v in values])


# --------------------------------------------------------------------------------------------
# AugmentConfig
# --------------------------------------------------------------------------------------------
def test_config_defaults_make_no_copies_and_round_trip_through_json():
    cfg = AugmentConfig()
    assert cfg.copies == 0
    d = json.loads(json.dumps(AugmentConfig(copies=2, jpeg_quality=(40, 80)).to_dict()))
    assert AugmentConfig.from_dict(d) == AugmentConfig(copies=2, jpeg_quality=(40, 80))
    assert AugmentConfig.from_dict({"copies": 1}) == AugmentConfig(copies=1)
    assert cfg.replace(copies=3).copies == 3
    with pytest.raises(ValueError, match="unknown fields"):
        AugmentConfig.from_dict({"copies": 1, "hue": 0.1})


@pytest.mark.parametrize(
    "changes, field",
    [
        ({"copies": -1}, "copies"),
        ({"copies": 1.5}, "copies"),
        ({"copies": True}, "copies"),
        ({"flip": 1.5}, "flip"),
        ({"scale": -0.1}, "scale"),
        ({"blur": float("nan")}, "blur"),
        ({"gamma": "0.3"}, "gamma"),
        ({"contrast": 1.0}, "contrast"),
        ({"brightness": 2.0}, "brightness"),
        ({"jpeg": -1}, "jpeg"),
        ({"blur_sigma": (1.0, 0.5)}, "blur_sigma"),
        ({"blur_sigma": (0.0, 1.0)}, "blur_sigma"),
        ({"blur_sigma": 1.0}, "blur_sigma"),
        ({"jpeg_quality": (0, 90)}, "jpeg_quality"),
        ({"jpeg_quality": (90, 30)}, "jpeg_quality"),
        ({"jpeg_quality": (30.5, 90)}, "jpeg_quality"),
    ],
)
def test_config_refuses_bad_values_naming_the_field(changes, field):
    with pytest.raises(ValueError, match=rf"AugmentConfig\.{field} "):
        AugmentConfig(**changes)


# --------------------------------------------------------------------------------------------
# The transforms: shape, dtype, purity, determinism
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("transform", TRANSFORMS, ids=lambda f: f.__name__)
def test_transforms_keep_shape_and_dtype_and_leave_the_input_alone(transform):
    images = _scene(5)
    before = images.copy()
    out = transform(images, np.random.default_rng(0))
    assert out.shape == images.shape and out.dtype == np.uint8
    assert np.array_equal(images, before)
    empty = transform(np.zeros((0, 64, 64, 3), np.uint8), np.random.default_rng(0))
    assert empty.shape == (0, 64, 64, 3) and empty.dtype == np.uint8


@pytest.mark.parametrize("transform", TRANSFORMS, ids=lambda f: f.__name__)
def test_transforms_are_deterministic_given_the_generator(transform):
    images = _scene(8)
    a = transform(images, np.random.default_rng(7))
    b = transform(images, np.random.default_rng(7))
    c = transform(images, np.random.default_rng(8))
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


@pytest.mark.parametrize("bad", [np.zeros((2, 64, 64, 3), np.float32), np.zeros((64, 64, 3), np.uint8), np.zeros((2, 64, 32, 3), np.uint8)])
def test_transforms_refuse_what_is_not_a_batch_of_rgb_uint8_patches(bad):
    with pytest.raises(ValueError, match="RGB uint8"):
        flip(bad, np.random.default_rng(0))


# --------------------------------------------------------------------------------------------
# Each transform changes the patches, within its range
# --------------------------------------------------------------------------------------------
def test_flip_mirrors_left_right():
    images = _noise(50)
    out = flip(images, np.random.default_rng(1), p=0.5)
    mirrored = np.array([np.array_equal(o, im[:, ::-1]) for o, im in zip(out, images)])
    same = np.array([np.array_equal(o, im) for o, im in zip(out, images)])
    assert np.all(mirrored ^ same) and 10 < mirrored.sum() < 40
    assert np.array_equal(flip(images, np.random.default_rng(1), p=1.0), images[:, :, ::-1])
    assert np.array_equal(flip(images, np.random.default_rng(1), p=0.0), images)


def _box_width(patch):
    row = patch[32, :, 0] > 128
    return np.ptp(np.flatnonzero(row)) + 1


def test_scale_jitter_zooms_within_its_range_without_black_borders():
    box = np.zeros((64, 64, 3), np.uint8)
    box[16:48, 16:48] = 255  # a centred white square, 32 px
    images = np.repeat(box[None], 200, axis=0)
    out = scale_jitter(images, np.random.default_rng(2), scale=0.25)
    widths = np.array([_box_width(o) for o in out])
    assert widths.min() < 30 and widths.max() > 34  # both ways
    assert widths.min() >= math.floor(32 / 1.25) - 1 and widths.max() <= math.ceil(32 * 1.25) + 1
    # Zooming out pads by reflection: a uniform patch stays uniform (no black border).
    grey = _constant([90] * 50)
    assert np.array_equal(scale_jitter(grey, np.random.default_rng(3), scale=0.3), grey)
    assert np.array_equal(scale_jitter(images, np.random.default_rng(2), scale=0.0), images)


def _gradient_energy(images):
    g = images.astype(np.float64)
    return (np.diff(g, axis=1) ** 2).mean(axis=(1, 2, 3)) + (np.diff(g, axis=2) ** 2).mean(axis=(1, 2, 3))


def test_blur_softens_within_its_sigma_range():
    images = _noise(30)
    out = blur(images, np.random.default_rng(4), p=1.0, sigma=(0.6, 1.0))
    energy = _gradient_energy(out)
    softest = _gradient_energy(np.stack([cv2.GaussianBlur(im, (7, 7), 1.0) for im in images]))
    sharpest = _gradient_energy(np.stack([cv2.GaussianBlur(im, (5, 5), 0.6) for im in images]))
    assert np.all(energy < _gradient_energy(images))
    assert np.all(softest * 0.97 <= energy) and np.all(energy <= sharpest * 1.03)
    assert np.allclose(out.mean(axis=(1, 2, 3)), images.mean(axis=(1, 2, 3)), atol=1.0)  # no change of brightness
    assert np.array_equal(blur(images, np.random.default_rng(4), p=0.0), images)
    some = blur(images, np.random.default_rng(4), p=0.5)
    changed = np.array([not np.array_equal(o, im) for o, im in zip(some, images)])
    assert 5 < changed.sum() < 25


def test_brightness_shifts_within_its_range():
    images = _constant([128] * 100)
    out = photometric(images, np.random.default_rng(5), gamma=0.0, contrast=0.0, brightness=0.1)
    shift = out.reshape(100, -1).astype(int) - 128
    assert np.all(shift == shift[:, :1])  # one offset per patch
    assert np.abs(shift).max() <= round(0.1 * 255) and shift.min() < -15 and shift.max() > 15


def test_contrast_scales_about_the_mean_within_its_range():
    half = np.zeros((64, 64, 3), np.uint8)
    half[:, :32], half[:, 32:] = 100, 160
    images = np.repeat(half[None], 100, axis=0)
    out = photometric(images, np.random.default_rng(6), gamma=0.0, contrast=0.3, brightness=0.0).astype(float)
    factor = (out[:, 0, 40, 0] - out[:, 0, 0, 0]) / 60.0
    assert np.all(factor >= 0.7 - 0.02) and np.all(factor <= 1.3 + 0.02)
    assert factor.min() < 0.8 and factor.max() > 1.2
    assert np.allclose(out.mean(axis=(1, 2, 3)), 130, atol=1.0)  # about the mean


def test_gamma_bends_the_tone_curve_within_its_range():
    images = _constant([64] * 100)
    out = photometric(images, np.random.default_rng(7), gamma=0.4, contrast=0.0, brightness=0.0)[:, 0, 0, 0].astype(float)
    darkest, brightest = 255 * (64 / 255) ** math.exp(0.4), 255 * (64 / 255) ** math.exp(-0.4)
    assert np.all(out >= math.floor(darkest)) and np.all(out <= math.ceil(brightest))
    assert out.min() < 55 and out.max() > 75
    # Grey stays grey: the same curve for the three channels.
    colour = photometric(_scene(4), np.random.default_rng(7), gamma=0.4, contrast=0.0, brightness=0.0)
    assert np.array_equal(colour[:, 10, 10, 0] >= colour[:, 10, 10, 2], _scene(4)[:, 10, 10, 0] >= _scene(4)[:, 10, 10, 2])


def test_photometric_with_no_range_is_the_identity():
    images = _scene(6)
    assert np.array_equal(photometric(images, np.random.default_rng(0), gamma=0.0, contrast=0.0, brightness=0.0), images)


def test_jpeg_recompresses_at_a_quality_within_its_range():
    images = _scene(6)

    def recompressed(im, q):
        ok, data = cv2.imencode(".jpg", im[:, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, q])
        return cv2.imdecode(data, cv2.IMREAD_COLOR)[:, :, ::-1]

    out = jpeg(images, np.random.default_rng(8), p=1.0, quality=(30, 60))
    for o, im in zip(out, images):
        assert not np.array_equal(o, im)
        assert any(np.array_equal(o, recompressed(im, q)) for q in range(30, 61))
    fixed = jpeg(images, np.random.default_rng(8), p=1.0, quality=(45, 45))
    assert all(np.array_equal(o, recompressed(im, 45)) for o, im in zip(fixed, images))
    assert np.array_equal(jpeg(images, np.random.default_rng(8), p=0.0), images)


# --------------------------------------------------------------------------------------------
# augment: copies and where they come from
# --------------------------------------------------------------------------------------------
def test_augment_makes_copies_of_each_patch_in_order():
    values = [20, 80, 140, 200]
    images = _constant(values)
    cfg = AugmentConfig(copies=3, brightness=0.05, gamma=0.1, contrast=0.1)
    out, origin = augment(images, cfg, np.random.default_rng(9))
    assert out.shape == (12, 64, 64, 3) and out.dtype == np.uint8
    assert origin.tolist() == [0, 0, 0, 1, 1, 1, 2, 2, 2, 3, 3, 3]
    means = out.mean(axis=(1, 2, 3))
    assert np.all(np.abs(means - np.repeat(values, 3)) < 30)  # each copy looks like its source
    again, _ = augment(images, cfg, np.random.default_rng(9))
    assert np.array_equal(out, again)
    none, origin0 = augment(images, AugmentConfig(copies=0), np.random.default_rng(9))
    assert none.shape == (0, 64, 64, 3) and origin0.shape == (0,)


def test_with_copies_adds_only_the_copies_of_the_training_side():
    origin = np.repeat(np.arange(5), 2)  # 5 patches, 2 copies each: rows 5..14
    rows = with_copies(np.array([1, 3]), origin, 5)
    assert rows.tolist() == [1, 3, 5 + 2, 5 + 3, 5 + 6, 5 + 7]
    assert with_copies(np.array([0, 2]), np.zeros(0, np.int64), 5).tolist() == [0, 2]


def _toy_dataset(n_per_class=60, seed=0):
    """Two separable classes of scene-like patches, 12 groups per class."""
    rng = np.random.default_rng(seed)
    images = np.concatenate([_scene(n_per_class, seed), _noise(n_per_class, seed) // 4 + 40])
    labels = np.repeat(np.array([1, 0], np.int8), n_per_class)
    groups = np.concatenate([np.arange(n_per_class) // 5, 100 + np.arange(n_per_class) // 5]).astype(np.int64)
    names = np.array([f"c{lab}/{i}.png" for i, lab in enumerate(labels)])
    sources = np.array([f"c{lab}" for lab in labels])
    digests = np.array([f"{rng.random()}" for _ in labels])
    return Dataset(images, labels, sources, names, groups, digests)


def test_train_keeps_augmented_copies_on_their_sources_side_of_every_split(monkeypatch):
    ds = _toy_dataset()
    n, copies = len(ds), 2
    seen = []
    evaluate = fit._evaluate_split

    def spy(features, labels, config, train_idx, test_idx, C):
        seen.append((np.asarray(train_idx), np.asarray(test_idx), labels))
        return evaluate(features, labels, config, train_idx, test_idx, C)

    monkeypatch.setattr(fit, "_evaluate_split", spy)
    cfg = FeatureConfig(pixels_per_cell=16, spatial_size=0, hist_bins=0)
    model = train(ds, cfg, augment=AugmentConfig(copies=copies), n_jobs=1)
    assert len(seen) == 2
    grouped_train, grouped_test = split_indices(ds.labels, ds.groups)
    for train_idx, test_idx, labels in seen:
        assert test_idx.max() < n  # only original patches are tested
        originals, augmented = train_idx[train_idx < n], train_idx[train_idx >= n]
        sources = (augmented - n) // copies  # augment's order: the copies of patch i follow each other
        assert set(sources.tolist()) == set(originals.tolist())  # every training patch's copies, no other
        assert not set(sources.tolist()) & set(test_idx.tolist())
        assert np.array_equal(labels[augmented], ds.labels[sources])
        assert len(augmented) == copies * len(originals)
    # The grouped split: no group on both sides, copies included.
    train_idx, test_idx, _ = seen[1]
    assert np.array_equal(np.sort(test_idx), np.sort(grouped_test))
    train_groups = set(ds.groups[train_idx[train_idx < n]]) | set(ds.groups[(train_idx[train_idx >= n] - n) // copies])
    assert not train_groups & set(ds.groups[test_idx])
    m = model.metrics
    assert m["n_images"] == n
    assert m["augment"]["copies"] == copies and m["augment"]["n_copies"] == copies * n
    assert m["grouped_split"]["n_train"] == (1 + copies) * len(grouped_train)
    assert m["grouped_split"]["n_augmented"] == copies * len(grouped_train)
    assert m["grouped_split"]["n_test"] == len(grouped_test)
    assert AugmentConfig.from_dict({k: v for k, v in m["augment"].items() if k not in ("n_copies", "seconds")}) == AugmentConfig(copies=copies)
    json.dumps(m)


def test_train_without_augmentation_records_none():
    m = train(_toy_dataset(), FeatureConfig(pixels_per_cell=16, spatial_size=0, hist_bins=0), n_jobs=1).metrics
    assert "augment" not in m and m["random_split"]["n_augmented"] == 0
