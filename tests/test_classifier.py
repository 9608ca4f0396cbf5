"""Tests of vehicle_detection.classifier: the model file, splits, training and the sweep."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from vehicle_detection import __version__
from vehicle_detection.classifier import _digest, VehicleClassifier, default_model_path, load_default_model
from vehicle_detection.training.fit import split_indices, sweep, sweep_configs, train
from vehicle_detection.errors import InputError, ModelError, OutputError
from vehicle_detection.features import FEATURE_FORMAT, FeatureConfig, extract_features

# the training archives are loaded once a worker (session fixtures): their tests share one
pytestmark = pytest.mark.xdist_group("archives")

ARRAYS = ("scaler_mean", "scaler_scale", "coef", "intercept")


def _stratified(labels, n_per_class, seed):
    rng = np.random.default_rng(seed)
    return np.sort(np.concatenate([rng.choice(np.flatnonzero(labels == c), n_per_class, replace=False) for c in (0, 1)]))


@pytest.fixture(scope="module")
def real_features(dataset, small_model):
    idx = _stratified(dataset.labels, 100, seed=11)
    return extract_features(dataset.images[idx], small_model.config), dataset.labels[idx], dataset.images[idx]


@pytest.fixture(scope="module")
def saved_model(small_model, tmp_path_factory):
    return small_model.save(tmp_path_factory.mktemp("model") / "model.npz")


# --------------------------------------------------------------------------------------------
# Decisions and the folded form
# --------------------------------------------------------------------------------------------
def test_small_model_separates_real_patches(small_model, real_features):
    feats, labels, _ = real_features
    assert small_model.config == FeatureConfig()
    acc = float((small_model.predict(feats) == labels).mean())
    assert acc > 0.9


def test_folded_equals_scaler_plus_coef(small_model, real_features):
    feats, _, _ = real_features
    x = feats.astype(np.float64)
    ref = ((x - small_model.scaler_mean) / small_model.scaler_scale) @ small_model.coef + small_model.intercept
    w, b = small_model.weights, small_model.bias
    assert w.shape == (small_model.config.n_features,) and isinstance(b, float)
    assert not w.flags.writeable
    np.testing.assert_allclose(x @ w + b, ref, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(small_model.decision_function(feats), ref, rtol=1e-9, atol=1e-9)
    np.testing.assert_array_equal(small_model.predict(feats), (ref > 0).astype(np.int8))


def test_decision_images_equals_features_path(small_model, real_features):
    feats, _, images = real_features
    np.testing.assert_allclose(small_model.decision_images(images[:20]), small_model.decision_function(feats[:20]), rtol=1e-12, atol=1e-12)


def test_fit_standardises_and_separates():
    cfg = FeatureConfig(spatial_size=0, hist_bins=0, hog_channels=(0,), orientations=5, pixels_per_cell=16, cells_per_block=1, window=48)
    nf = cfg.n_features
    assert nf == 1 * (3 * 3) * (1 * 1) * 5  # channels * blocks * cells per block * orientations
    rng = np.random.default_rng(0)
    n = 400
    y = np.repeat([0, 1], n // 2)
    scales = rng.uniform(0.1, 10, nf)
    x = rng.normal(0, 1, (n, nf)) * scales + rng.uniform(-50, 50, nf)
    x[:, 0] += 3 * scales[0] * y  # the informative feature
    x[:, 3] = 7.0  # constant
    x = x.astype(np.float32)
    model = VehicleClassifier.fit(x, y, cfg, C=1.0)
    x64 = x.astype(np.float64)
    np.testing.assert_allclose(model.scaler_mean, x64.mean(0), rtol=1e-5, atol=1e-4)
    std = x64.std(0)
    others = [i for i in range(nf) if i != 3]
    np.testing.assert_allclose(model.scaler_scale[others], std[others], rtol=1e-4)
    assert model.scaler_scale[3] == 1.0  # constant feature: scale 1, not 0
    assert np.argmax(np.abs(model.coef)) == 0 and model.coef[0] > 0
    assert (model.predict(x) == y).mean() > 0.9


def test_constructor_checks_shapes():
    cfg = FeatureConfig()
    n = cfg.n_features
    with pytest.raises(ValueError):
        VehicleClassifier(cfg, np.zeros(n), np.ones(n), np.zeros(n - 1), 0.0)
    with pytest.raises(ValueError):
        VehicleClassifier(cfg, np.zeros((1, n)), np.ones(n), np.zeros(n), 0.0)


# --------------------------------------------------------------------------------------------
# Save / load
# --------------------------------------------------------------------------------------------
def test_round_trip(small_model, saved_model, real_features):
    feats, _, _ = real_features
    loaded = VehicleClassifier.load(saved_model)
    assert loaded.config == small_model.config
    for name in ("scaler_mean", "scaler_scale", "coef"):
        np.testing.assert_array_equal(getattr(loaded, name), getattr(small_model, name))
    assert loaded.intercept == small_model.intercept
    assert loaded.library_version == __version__
    assert loaded.metrics == small_model.metrics
    np.testing.assert_allclose(loaded.decision_function(feats), small_model.decision_function(feats), rtol=0, atol=1e-12)


def test_round_trip_keeps_metrics_and_config(tmp_path):
    cfg = FeatureConfig(color_space="HLS", hog_channels=(0, 2), orientations=11, pixels_per_cell=16, spatial_size=8, hist_bins=32)
    n = cfg.n_features
    rng = np.random.default_rng(1)
    metrics = {"random_split": {"accuracy": 0.99, "confusion": {"tn": 1, "fp": 0, "fn": 0, "tp": 1}}, "C": 3e-4}
    m = VehicleClassifier(cfg, rng.normal(size=n), rng.uniform(0.5, 2, n), rng.normal(size=n), -0.25, metrics=metrics)
    loaded = VehicleClassifier.load(m.save(tmp_path / "m.npz"))
    assert loaded.config == cfg
    assert loaded.metrics == metrics
    assert loaded.intercept == -0.25
    np.testing.assert_array_equal(loaded.coef, m.coef)


def test_saved_file_is_plain_npz(saved_model, small_model):
    with np.load(saved_model, allow_pickle=False) as npz:
        assert set(npz.files) == {"meta", *ARRAYS}
        meta = json.loads(npz["meta"].tobytes().decode("utf-8"))
        for name in ARRAYS:
            assert npz[name].dtype == np.float64
        np.testing.assert_array_equal(npz["coef"], small_model.coef)
        assert npz["intercept"].shape == (1,)
    assert meta["feature_format"] == FEATURE_FORMAT
    assert meta["library_version"] == __version__
    assert FeatureConfig.from_dict(meta["feature_config"]) == small_model.config


def test_save_refuses_overwrite(small_model, tmp_path):
    path = small_model.save(tmp_path / "m.npz")
    before = path.read_bytes()
    with pytest.raises(OutputError) as info:
        small_model.save(path)
    assert str(path) in str(info.value)
    assert path.read_bytes() == before
    small_model.save(path, overwrite=True)
    VehicleClassifier.load(path)
    assert [p.name for p in tmp_path.iterdir()] == ["m.npz"]  # no .partial left behind


def _contents(path: Path):
    with np.load(path, allow_pickle=False) as npz:
        d = {k: npz[k] for k in npz.files}
    return d, json.loads(d["meta"].tobytes().decode("utf-8"))


def _write(path: Path, d: dict, meta: dict | None = None) -> Path:
    d = dict(d)
    if meta is not None:
        d["meta"] = np.frombuffer(json.dumps(meta).encode("utf-8"), dtype=np.uint8)
    with open(path, "wb") as f:
        np.savez(f, **d)
    return path


def _tamper(kind: str, src: Path, dst: Path) -> Path:
    d, meta = _contents(src)
    n = len(d["coef"])
    if kind == "feature_format":
        meta["feature_format"] = FEATURE_FORMAT + 1
    elif kind == "config_unknown_field":
        meta["feature_config"]["gamma"] = True
    elif kind == "config_renamed_field":
        meta["feature_config"]["orientation"] = meta["feature_config"].pop("orientations")
    elif kind == "config_missing_field":
        del meta["feature_config"]["window"]
    elif kind == "config_invalid_value":
        meta["feature_config"]["color_space"] = "BGR"
    elif kind == "config_other_size":  # a valid config with another feature count
        meta["feature_config"]["orientations"] = 11
    elif kind == "config_not_object":
        meta["feature_config"] = "YCrCb"
    elif kind == "newer_library":
        meta["library_version"] = "99.0.0"
    elif kind == "newer_minor":
        major, minor = (int(x) for x in __version__.split(".")[:2])
        meta["library_version"] = f"{major}.{minor + 1}.0"
    elif kind == "other_format":
        meta["format"] = "something-else"
    elif kind == "format_version":
        meta["format_version"] = 3
    elif kind == "header_not_json":
        d["meta"] = np.frombuffer(b"{not json", dtype=np.uint8)
        meta = None
    elif kind == "header_wrong_dtype":
        d["meta"] = np.zeros(3)
        meta = None
    elif kind == "coef_long":
        d["coef"] = np.concatenate([d["coef"], [0.0]])
    elif kind == "coef_2d":
        d["coef"] = d["coef"][None]
    elif kind == "intercept_shape":
        d["intercept"] = np.zeros(2)
    elif kind == "coef_float32":
        d["coef"] = d["coef"].astype(np.float32)
    elif kind == "flipped_coef":
        d["coef"] = d["coef"].copy()
        d["coef"][n // 2] = -d["coef"][n // 2] + 1e-3
    elif kind == "flipped_intercept":
        d["intercept"] = d["intercept"] + 1e-9
    elif kind == "nan_coef":
        d["coef"] = d["coef"].copy()
        d["coef"][0] = np.nan
    elif kind == "zero_scale":
        d["scaler_scale"] = d["scaler_scale"].copy()
        d["scaler_scale"][3] = 0.0
    elif kind == "missing_array":
        del d["scaler_mean"]
    elif kind == "extra_array":
        d["bonus"] = np.zeros(3)
    elif kind == "object_array":
        d["coef"] = np.array([{"evil": 1}] * n, dtype=object)
    else:
        raise AssertionError(kind)
    if kind == "object_array":
        d2 = dict(d)
        if meta is not None:
            d2["meta"] = np.frombuffer(json.dumps(meta).encode("utf-8"), dtype=np.uint8)
        with open(dst, "wb") as f:
            np.savez(f, **d2)  # object arrays are pickled inside the npz
        return dst
    return _write(dst, d, meta)


TAMPERS = {
    "feature_format": "feature format",
    "config_unknown_field": "gamma",
    "config_renamed_field": "orientation",
    "config_missing_field": "window",
    "config_invalid_value": "color_space",
    "config_other_size": "expected",
    "config_not_object": "feature config",
    "newer_library": "99.0.0",
    "newer_minor": "newer",
    "other_format": "not a",
    "format_version": "format version",
    "header_not_json": "JSON",
    "header_wrong_dtype": "header",
    "coef_long": "coef",
    "coef_2d": "coef",
    "intercept_shape": "intercept",
    "coef_float32": "coef",
    "flipped_coef": "checksum",
    "flipped_intercept": "checksum",
    "nan_coef": "non-finite",
    "zero_scale": "scaler_scale",
    "missing_array": "scaler_mean",
    "extra_array": "bonus",
    "object_array": "",
}


@pytest.mark.parametrize("kind", list(TAMPERS))
def test_tampered_files_raise_model_error(saved_model, tmp_path, kind):
    bad = _tamper(kind, saved_model, tmp_path / f"{kind}.npz")
    with pytest.raises(ModelError) as info:
        VehicleClassifier.load(bad)
    msg = str(info.value)
    assert str(bad) in msg
    assert TAMPERS[kind] in msg


def test_float_size_in_header_refused(saved_model, tmp_path):
    d, meta = _contents(saved_model)
    meta["feature_config"]["hist_bins"] = float(meta["feature_config"]["hist_bins"])
    bad = _write(tmp_path / "float.npz", d, meta)
    with pytest.raises(ModelError) as info:
        VehicleClassifier.load(bad)
    assert str(bad) in str(info.value)


def test_untampered_rewrite_still_loads(saved_model, tmp_path):
    # The rewriting helper itself does not break files: only the tampering does.
    d, meta = _contents(saved_model)
    VehicleClassifier.load(_write(tmp_path / "same.npz", d, meta))


@pytest.mark.parametrize("keep", [0.5, 0.9, 0.99, 30])
def test_truncated_file(saved_model, tmp_path, keep):
    data = saved_model.read_bytes()
    n = keep if isinstance(keep, int) else int(len(data) * keep)
    bad = tmp_path / "cut.npz"
    bad.write_bytes(data[:n])
    with pytest.raises(ModelError) as info:
        VehicleClassifier.load(bad)
    assert str(bad) in str(info.value)


@pytest.mark.parametrize("content", [b"", b"hello, I am a model\n", b"\x93NUMPY garbage", b"PK\x03\x04garbage"])
def test_non_npz_file(tmp_path, content):
    bad = tmp_path / "model.npz"
    bad.write_bytes(content)
    with pytest.raises(ModelError) as info:
        VehicleClassifier.load(bad)
    assert str(bad) in str(info.value)


def test_npy_file_instead_of_npz(tmp_path):
    bad = tmp_path / "model.npy"
    np.save(bad, np.arange(5.0))
    with pytest.raises(ModelError) as info:
        VehicleClassifier.load(bad)
    assert str(bad) in str(info.value)


def test_missing_file_and_folder(tmp_path):
    missing = tmp_path / "nope.npz"
    with pytest.raises(ModelError) as info:
        VehicleClassifier.load(missing)
    assert str(missing) in str(info.value)
    with pytest.raises(ModelError) as info:
        VehicleClassifier.load(tmp_path)
    assert str(tmp_path) in str(info.value)
    assert issubclass(ModelError, InputError)


def test_older_library_version_accepted(saved_model, tmp_path):
    d, meta = _contents(saved_model)
    meta["library_version"] = "0.0.1"
    meta["sha256"] = _digest({k: v for k, v in d.items() if k != "meta"}, meta)
    m = VehicleClassifier.load(_write(tmp_path / "old.npz", d, meta))
    assert m.library_version == "0.0.1"


# --------------------------------------------------------------------------------------------
# Splits
# --------------------------------------------------------------------------------------------
def test_grouped_split_on_real_groups(dataset):
    train_idx, test_idx = split_indices(dataset.labels, dataset.groups, test_size=0.2, random_state=0)
    n = len(dataset)
    assert len(np.intersect1d(train_idx, test_idx)) == 0
    assert np.array_equal(np.sort(np.concatenate([train_idx, test_idx])), np.arange(n))
    assert not set(dataset.groups[train_idx].tolist()) & set(dataset.groups[test_idx].tolist())
    frac = len(test_idx) / n
    assert 0.13 < frac < 0.27, frac
    # Both classes on both sides.
    assert set(dataset.labels[test_idx].tolist()) == {0, 1} == set(dataset.labels[train_idx].tolist())


def test_grouped_split_synthetic():
    groups = np.repeat(np.arange(100), 7)
    labels = (groups % 3 == 0).astype(int)
    for seed in range(3):
        tr, te = split_indices(labels, groups, test_size=0.2, random_state=seed)
        assert not set(groups[tr]) & set(groups[te])
        assert len(set(groups[te])) == 20  # 20% of the groups
        assert len(tr) + len(te) == len(groups)
    a = split_indices(labels, groups, random_state=5)
    b = split_indices(labels, groups, random_state=5)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))  # reproducible


def test_random_split_stratified():
    labels = np.array([1] * 300 + [0] * 700)
    tr, te = split_indices(labels, test_size=0.2, random_state=0)
    assert len(te) == 200 and len(tr) == 800
    assert int(labels[te].sum()) == 60  # 30% positives on each side
    assert int(labels[tr].sum()) == 240
    assert len(np.intersect1d(tr, te)) == 0


def test_random_split_stratified_real(dataset):
    tr, te = split_indices(dataset.labels, test_size=0.2, random_state=1)
    assert len(te) == math.ceil(0.2 * len(dataset))
    p_all = dataset.labels.mean()
    assert abs(dataset.labels[te].mean() - p_all) < 1e-3
    assert abs(dataset.labels[tr].mean() - p_all) < 1e-3


# --------------------------------------------------------------------------------------------
# Training and the sweep
# --------------------------------------------------------------------------------------------
def _check_split_metrics(m, n_total):
    assert 0.9 < m["accuracy"] <= 1.0
    c = m["confusion"]
    assert m["n_train"] + m["n_test"] == n_total
    assert c["tn"] + c["fp"] + c["fn"] + c["tp"] == m["n_test"]
    assert m["accuracy"] == pytest.approx((c["tn"] + c["tp"]) / m["n_test"])
    if c["tp"] + c["fp"]:
        assert m["precision"] == pytest.approx(c["tp"] / (c["tp"] + c["fp"]))
    assert m["recall"] == pytest.approx(c["tp"] / (c["tp"] + c["fn"]))
    assert m["fit_seconds"] >= 0


def test_train_on_subset(dataset):
    sub = dataset.subset(_stratified(dataset.labels, 300, seed=5))
    cfg = FeatureConfig()
    model = train(sub, cfg)
    m = model.metrics
    assert model.config == cfg
    for key in ("random_split", "grouped_split", "feature_seconds", "fit_seconds", "n_images", "n_features", "C"):
        assert key in m
    assert m["n_images"] == 600 and m["n_features"] == cfg.n_features
    assert m["feature_seconds"] >= 0 and m["fit_seconds"] >= 0
    _check_split_metrics(m["random_split"], 600)
    _check_split_metrics(m["grouped_split"], 600)
    assert m["random_split"]["n_test"] == 120
    # The final model was fitted on every patch: it classifies them nearly all correctly.
    assert (model.predict(extract_features(sub.images, cfg)) == sub.labels).mean() > 0.97
    json.dumps(m)  # metrics are JSON-serialisable (they go into the model header)


def test_train_without_evaluation(dataset):
    sub = dataset.subset(_stratified(dataset.labels, 150, seed=6))
    cfg = FeatureConfig(spatial_size=0, hist_bins=0, pixels_per_cell=16)
    model = train(sub, cfg, evaluate=False)
    assert "random_split" not in model.metrics and "grouped_split" not in model.metrics
    assert model.metrics["n_images"] == 300


def test_sweep(dataset):
    sub = dataset.subset(_stratified(dataset.labels, 250, seed=8))
    configs = [
        FeatureConfig(color_space="YCrCb", pixels_per_cell=16, spatial_size=0, hist_bins=0),
        FeatureConfig(color_space="HLS", hog_channels=(1,), orientations=6, pixels_per_cell=16, spatial_size=8, hist_bins=8),
    ]
    rows = sweep(sub, configs, n_jobs=2)
    assert len(rows) == 2
    expected = set(FeatureConfig().to_dict()) | {
        "n_features",
        "feature_seconds",
        "random_accuracy",
        "grouped_accuracy",
        "random_fit_seconds",
        "grouped_fit_seconds",
    }
    for row in rows:
        assert set(row) == expected
        assert 0.5 < row["random_accuracy"] <= 1 and 0.5 < row["grouped_accuracy"] <= 1
        json.dumps(row)
    assert rows[0]["grouped_accuracy"] >= rows[1]["grouped_accuracy"]
    # Each row describes one of the configs, with its feature count.
    got = {FeatureConfig.from_dict({k: row[k] for k in FeatureConfig().to_dict()}) for row in rows}
    assert got == set(configs)
    for row in rows:
        cfg = FeatureConfig.from_dict({k: row[k] for k in FeatureConfig().to_dict()})
        assert row["n_features"] == cfg.n_features


def test_sweep_configs_product():
    cfgs = sweep_configs(color_spaces=("YUV", "HLS"), orientations=(9, 11, 12), pixels_per_cell=(8,), color_features=((16, 16), (0, 0)))
    assert len(cfgs) == 2 * 3 * 2
    assert len(set(cfgs)) == len(cfgs)
    assert {c.color_space for c in cfgs} == {"YUV", "HLS"}
    assert {(c.spatial_size, c.hist_bins) for c in cfgs} == {(16, 16), (0, 0)}
    assert len(sweep_configs()) == 4 * 1 * 2 * 2 * 1 * 2


# --------------------------------------------------------------------------------------------
# The embedded default model
# --------------------------------------------------------------------------------------------
def test_load_default_model():
    path = default_model_path()
    assert path.name == "default.npz" and path.parent.name == "models"
    if not path.is_file():
        pytest.skip(f"{path} does not exist yet (train it with `vehicle-detection train`)")
    model = load_default_model()
    assert model.config == FeatureConfig()
    assert model.coef.shape == (FeatureConfig().n_features,)


def test_header_edit_is_refused_by_the_checksum(saved_model, tmp_path):
    """Changing the colour space in the header (a valid config) must not load silently."""
    d, meta = _contents(saved_model)
    meta["feature_config"]["color_space"] = "HLS" if meta["feature_config"]["color_space"] != "HLS" else "YUV"
    path = _write(tmp_path / "edited.npz", d, meta)
    with pytest.raises(ModelError, match="checksum") as err:
        VehicleClassifier.load(path)
    assert str(path) in str(err.value)


# --------------------------------------------------------------------------------------------
# The detector settings in the model file, old files, hostile files
# --------------------------------------------------------------------------------------------
def test_detector_config_round_trips_through_the_file(tmp_path):
    from vehicle_detection.config import DetectorConfig
    from vehicle_detection.search import SearchPlan, SearchScale
    from vehicle_detection.tracker import TrackerConfig

    model = load_default_model()
    custom = DetectorConfig(
        plan=SearchPlan(scales=(SearchScale(1.25, 380, 560, x_start=16, step=1),), threshold=0.7),
        tracker=TrackerConfig(decay=0.5, min_hits=2, min_size=(40, 30)),
        image_threshold=3.5,
    )
    path = model.replace(detector_config=custom).save(tmp_path / "m.npz")
    assert VehicleClassifier.load(path).detector_config == custom
    assert _contents(path)[1]["format_version"] == 2


def test_version_1_files_are_migrated_with_the_settings_of_library_0_1(tmp_path):
    from vehicle_detection.config import DetectorConfig

    src = load_default_model().save(tmp_path / "v2.npz")
    d, meta = _contents(src)
    del meta["detector_config"]
    meta.update(format_version=1, library_version="0.1.0")
    meta["sha256"] = _digest({k: v for k, v in d.items() if k != "meta"}, meta)
    old = VehicleClassifier.load(_write(tmp_path / "v1.npz", d, meta))
    # Library 0.1 ran every model with what were then the defaults; they are written out in
    # the migration, independent of today's defaults.
    cfg = old.detector_config
    assert isinstance(cfg, DetectorConfig)
    assert [(s.scale, s.y_start, s.y_stop, s.step) for s in cfg.plan.scales] == [
        (1.0, 400, 496, 2), (1.5, 400, 544, 1), (2.0, 400, 592, 1), (3.0, 400, 688, 1)]
    assert (cfg.plan.threshold, cfg.tracker.threshold, cfg.tracker.decay, cfg.image_threshold) == (0.3, 6.0, 0.6, 2.0)
    np.testing.assert_array_equal(old.coef, load_default_model().coef)


def test_files_saved_before_the_overlay_setting_load_with_it_on(tmp_path):
    """The embedded model and older format-2 files carry no ``auto_overlays``: they get it, as it
    changes nothing on footage without bars or static overlays."""
    src = load_default_model().save(tmp_path / "new.npz")
    d, meta = _contents(src)
    assert meta["detector_config"]["auto_overlays"] is True
    del meta["detector_config"]["auto_overlays"]
    meta["sha256"] = _digest({k: v for k, v in d.items() if k != "meta"}, meta)
    old = VehicleClassifier.load(_write(tmp_path / "old.npz", d, meta))
    assert old.detector_config == load_default_model().detector_config and old.detector_config.auto_overlays
    off = load_default_model().replace(
        detector_config=load_default_model().detector_config.replace(auto_overlays=False)
    ).save(tmp_path / "off.npz")
    assert VehicleClassifier.load(off).detector_config.auto_overlays is False


def test_oversized_members_are_refused_before_reading(tmp_path):
    import zipfile

    src = load_default_model().save(tmp_path / "m.npz")
    d, meta = _contents(src)
    meta["padding"] = " " * (2 << 20)  # a header of 2 MB, 1 MB allowed
    bomb = tmp_path / "bomb.npz"
    with zipfile.ZipFile(bomb, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name, arr in {**d, "meta": np.frombuffer(json.dumps(meta).encode(), np.uint8)}.items():
            with zf.open(f"{name}.npy", "w") as f:
                np.lib.format.write_array(f, arr)
    assert bomb.stat().st_size < 1_000_000  # small on disk, large unpacked
    with pytest.raises(ModelError, match="meta is .* bytes unpacked"):
        VehicleClassifier.load(bomb)


def test_deeply_nested_header_is_a_model_error(tmp_path):
    src = load_default_model().save(tmp_path / "m.npz")
    d, _ = _contents(src)
    d["meta"] = np.frombuffer(("[" * 100_000 + "]" * 100_000).encode(), np.uint8)
    with pytest.raises(ModelError, match="nested too deeply"):
        VehicleClassifier.load(_write(tmp_path / "deep.npz", d))


def test_models_are_immutable():
    model = load_default_model()
    for name in ("scaler_mean", "scaler_scale", "coef", "weights"):
        with pytest.raises(ValueError, match="read-only"):
            getattr(model, name)[0] = 0.0
    with pytest.raises(AttributeError):
        model.intercept = 1.0
