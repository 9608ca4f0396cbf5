"""The vehicle / non-vehicle classifier: standardisation plus a linear SVM, saved as plain data.

Training uses scikit-learn (``StandardScaler`` + ``LinearSVC`` in a ``Pipeline``); the fitted
model is kept as four arrays (scaler mean and scale, SVM weights and bias) and a JSON header with
its :class:`~vehicle_detection.features.FeatureConfig`, library version and metrics. That is all
a linear model is, and all the sliding-window search needs: it folds the scaler into the weights
(:meth:`VehicleClassifier.folded`) and scores every window with dot products.

Model files are ``.npz`` archives read with ``allow_pickle=False``: nothing in them is executed.
Loading checks the schema, shapes, a SHA-256 of the arrays and header, the library version and the feature
configuration, and refuses anything else with a :class:`~vehicle_detection.errors.ModelError`.
"""

from __future__ import annotations

import dataclasses
import hashlib
import itertools
import json
import os
import time
import zipfile
from dataclasses import dataclass
from importlib import resources
from pathlib import Path

import numpy as np

from . import __version__
from ._files import atomic_output
from .data import Dataset
from .errors import ModelError
from .features import FEATURE_FORMAT, FeatureConfig, extract_features

__all__ = [
    "MODEL_FORMAT",
    "DEFAULT_C",
    "VehicleClassifier",
    "default_model_path",
    "load_default_model",
    "split_indices",
    "train",
    "sweep",
    "sweep_configs",
]

MODEL_FORMAT = "vehicle-detection-model"
#: SVM regularisation used by default (chosen with the sweep on the grouped split).
DEFAULT_C = 3e-4
MODEL_FORMAT_VERSION = 1
_ARRAYS = ("scaler_mean", "scaler_scale", "coef", "intercept")


def _version_tuple(v: str) -> tuple[int, ...]:
    out = []
    for part in str(v).split(".")[:2]:
        digits = "".join(itertools.takewhile(str.isdigit, part))
        out.append(int(digits) if digits else 0)
    return tuple(out)


def _digest(arrays: dict[str, np.ndarray], header: dict) -> str:
    """SHA-256 over the arrays and the header (minus the digest itself), canonically encoded."""
    h = hashlib.sha256()
    h.update(json.dumps({k: v for k, v in header.items() if k != "sha256"}, sort_keys=True).encode("utf-8"))
    for name in _ARRAYS:
        a = np.ascontiguousarray(arrays[name], dtype="<f8")
        h.update(name.encode())
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


class VehicleClassifier:
    """A trained linear vehicle classifier over :func:`~vehicle_detection.features.extract_features`.

    Parameters
    ----------
    config : FeatureConfig
        Features the model was trained on.
    scaler_mean, scaler_scale : ndarray of float64, shape (n_features,)
        Standardisation: ``z = (x - mean) / scale``.
    coef : ndarray of float64, shape (n_features,)
        SVM weights over standardised features.
    intercept : float
        SVM bias; the decision is ``z @ coef + intercept`` (> 0: vehicle).
    metrics : dict, optional
        Training report (accuracies, timings), saved with the model.
    library_version : str, optional
        Version of the library that trained the model.
    """

    def __init__(self, config, scaler_mean, scaler_scale, coef, intercept, metrics=None, library_version=__version__):
        self.config = config
        self.scaler_mean = np.asarray(scaler_mean, dtype=np.float64)
        self.scaler_scale = np.asarray(scaler_scale, dtype=np.float64)
        self.coef = np.asarray(coef, dtype=np.float64)
        self.intercept = float(intercept)
        self.metrics = dict(metrics or {})
        self.library_version = str(library_version)
        n = config.n_features
        for name in ("scaler_mean", "scaler_scale", "coef"):
            if getattr(self, name).shape != (n,):
                raise ValueError(f"{name} must have shape ({n},) for this feature config, got {getattr(self, name).shape}")

    def __repr__(self):
        return f"VehicleClassifier({self.config!r}, n_features={self.config.n_features})"

    # --- fitting -------------------------------------------------------------------------------
    @classmethod
    def fit(cls, features: np.ndarray, labels: np.ndarray, config: FeatureConfig, *, C: float = DEFAULT_C, max_iter: int = 5000):
        """Fit ``StandardScaler`` + ``LinearSVC`` on feature vectors.

        Parameters
        ----------
        features : ndarray of float32, shape (N, n_features)
        labels : ndarray of int, shape (N,)
            1 vehicle, 0 other.
        config : FeatureConfig
            The config that produced ``features``.
        C : float
            SVM regularisation (smaller: wider margin).
        """
        from sklearn.pipeline import make_pipeline
        from sklearn.preprocessing import StandardScaler
        from sklearn.svm import LinearSVC

        pipe = make_pipeline(StandardScaler(), LinearSVC(C=C, dual=True, max_iter=max_iter, random_state=0))
        pipe.fit(features, labels)
        scaler, svm = pipe[0], pipe[1]
        scale = np.where(scaler.scale_ > 0, scaler.scale_, 1.0)
        return cls(config, scaler.mean_, scale, svm.coef_[0], svm.intercept_[0])

    # --- prediction ----------------------------------------------------------------------------
    def decision_function(self, features: np.ndarray) -> np.ndarray:
        """Signed SVM margin of feature vectors, shape (N,) (or a float for one vector)."""
        w, b = self.folded()
        return np.asarray(features, dtype=np.float64) @ w + b

    def predict(self, features: np.ndarray) -> np.ndarray:
        """1 where the margin is positive (vehicle), else 0."""
        return (self.decision_function(features) > 0).astype(np.int8)

    def decision_images(self, images: np.ndarray) -> np.ndarray:
        """Margins of RGB ``uint8`` patches ``(N, window, window, 3)``."""
        return self.decision_function(extract_features(images, self.config))

    def folded(self) -> tuple[np.ndarray, float]:
        """Weights and bias over raw features, the scaler folded in: ``x @ w + b``."""
        w = self.coef / self.scaler_scale
        return w, float(self.intercept - np.dot(self.coef, self.scaler_mean / self.scaler_scale))

    # --- persistence ---------------------------------------------------------------------------
    def _arrays(self) -> dict[str, np.ndarray]:
        return {
            "scaler_mean": self.scaler_mean,
            "scaler_scale": self.scaler_scale,
            "coef": self.coef,
            "intercept": np.array([self.intercept]),
        }

    def save(self, path: str | os.PathLike, *, overwrite: bool = False) -> Path:
        """Write the model as an ``.npz`` of float arrays plus a JSON header, atomically."""
        arrays = self._arrays()
        meta = {
            "format": MODEL_FORMAT,
            "format_version": MODEL_FORMAT_VERSION,
            "library_version": self.library_version,
            "feature_format": FEATURE_FORMAT,
            "feature_config": self.config.to_dict(),
            "metrics": self.metrics,
        }
        meta["sha256"] = _digest(arrays, meta)
        meta_bytes = np.frombuffer(json.dumps(meta, sort_keys=True).encode("utf-8"), dtype=np.uint8)
        path = Path(path)
        with atomic_output(path, overwrite=overwrite) as tmp:
            with open(tmp, "wb") as f:
                np.savez(f, meta=meta_bytes, **arrays)
        return path

    @classmethod
    def load(cls, path: str | os.PathLike) -> VehicleClassifier:
        """Read and check a model file.

        Raises
        ------
        ModelError
            Missing, truncated or tampered file; unknown format; feature configuration or
            feature format that the running code does not produce; a model from a newer
            library; arrays whose shapes do not fit the configuration. The message names the
            file and the problem.
        """
        path = Path(path)
        if not path.is_file():
            raise ModelError(f"{path}: model file not found")
        try:
            npz = np.load(path, allow_pickle=False)
            if not isinstance(npz, np.lib.npyio.NpzFile):
                raise ModelError(f"{path}: not a {MODEL_FORMAT} file (a single .npy array, not an .npz archive)")
            with npz:
                keys = set(npz.files)
                expected = {"meta", *_ARRAYS}
                if keys != expected:
                    raise ModelError(f"{path}: not a {MODEL_FORMAT} file: arrays {sorted(keys)}, expected {sorted(expected)}")
                data = {k: npz[k] for k in expected}
        except ModelError:
            raise
        except (zipfile.BadZipFile, EOFError, OSError, ValueError, KeyError) as exc:
            raise ModelError(f"{path}: unreadable model file (truncated, corrupt or not an .npz): {exc}") from None
        meta_arr = data["meta"]
        if meta_arr.dtype != np.uint8 or meta_arr.ndim != 1:
            raise ModelError(f"{path}: model header has the wrong type")
        try:
            meta = json.loads(meta_arr.tobytes().decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ModelError(f"{path}: model header is not valid JSON: {exc}") from None
        if not isinstance(meta, dict) or meta.get("format") != MODEL_FORMAT:
            raise ModelError(f"{path}: not a {MODEL_FORMAT} file")
        if meta.get("format_version") != MODEL_FORMAT_VERSION:
            raise ModelError(f"{path}: model format version {meta.get('format_version')!r} is not supported (expected {MODEL_FORMAT_VERSION})")
        lib = str(meta.get("library_version", "?"))
        if _version_tuple(lib) > _version_tuple(__version__):
            raise ModelError(f"{path}: trained by vehicle-detection {lib}, newer than this {__version__}; upgrade the library")
        if meta.get("feature_format") != FEATURE_FORMAT:
            raise ModelError(
                f"{path}: features were computed by feature format {meta.get('feature_format')!r}, this code computes "
                f"format {FEATURE_FORMAT}; retrain the model (vehicle-detection train)"
            )
        try:
            config = FeatureConfig.from_dict(meta.get("feature_config"))
        except (TypeError, ValueError) as exc:
            raise ModelError(f"{path}: feature config does not match this code: {exc}") from None
        n = config.n_features
        arrays = {}
        for name in _ARRAYS:
            a = data[name]
            want = (1,) if name == "intercept" else (n,)
            if a.dtype != np.float64 or a.shape != want:
                raise ModelError(f"{path}: array {name} is {a.dtype} {a.shape}, expected float64 {want} for its feature config")
            if not np.all(np.isfinite(a)):
                raise ModelError(f"{path}: array {name} holds non-finite values")
            arrays[name] = a
        if np.any(arrays["scaler_scale"] <= 0):
            raise ModelError(f"{path}: scaler_scale must be positive")
        if meta.get("sha256") != _digest(arrays, meta):
            raise ModelError(f"{path}: contents do not match the checksum in the header (file altered or damaged)")
        metrics = meta.get("metrics") or {}
        if not isinstance(metrics, dict):
            raise ModelError(f"{path}: metrics must be a JSON object")
        return cls(
            config,
            arrays["scaler_mean"],
            arrays["scaler_scale"],
            arrays["coef"],
            arrays["intercept"][0],
            metrics=metrics,
            library_version=lib,
        )


def default_model_path() -> Path:
    """Path of the model shipped inside the package."""
    return Path(str(resources.files("vehicle_detection") / "models" / "default.npz"))


def load_default_model() -> VehicleClassifier:
    """The embedded default model (see the README for how it was trained and its metrics)."""
    return VehicleClassifier.load(default_model_path())


# --- training ----------------------------------------------------------------------------------


def split_indices(labels, groups=None, *, test_size: float = 0.2, random_state: int = 0):
    """Train/test indices of a randomised split; grouped when ``groups`` is given.

    With ``groups`` no group is on both sides (:class:`~sklearn.model_selection.GroupShuffleSplit`);
    without, the split is stratified by label.

    Returns
    -------
    train, test : ndarray of int
    """
    from sklearn.model_selection import GroupShuffleSplit, train_test_split

    idx = np.arange(len(labels))
    if groups is None:
        return train_test_split(idx, test_size=test_size, random_state=random_state, shuffle=True, stratify=labels)
    gss = GroupShuffleSplit(n_splits=1, test_size=test_size, random_state=random_state)
    return next(gss.split(idx, labels, groups))


def _scores(y_true, y_pred) -> dict:
    from sklearn.metrics import accuracy_score, confusion_matrix, precision_score, recall_score

    tn, fp, fn, tp = confusion_matrix(y_true, y_pred, labels=[0, 1]).ravel()
    return {
        "accuracy": float(accuracy_score(y_true, y_pred)),
        "precision": float(precision_score(y_true, y_pred, zero_division=0)),
        "recall": float(recall_score(y_true, y_pred, zero_division=0)),
        "confusion": {"tn": int(tn), "fp": int(fp), "fn": int(fn), "tp": int(tp)},
    }


def _evaluate_split(features, labels, config, train_idx, test_idx, C):
    t = time.perf_counter()
    model = VehicleClassifier.fit(features[train_idx], labels[train_idx], config, C=C)
    fit_s = time.perf_counter() - t
    pred = model.predict(features[test_idx])
    out = _scores(labels[test_idx], pred)
    out.update(n_train=int(len(train_idx)), n_test=int(len(test_idx)), fit_seconds=round(fit_s, 3))
    return out


def train(
    dataset: Dataset,
    config: FeatureConfig = FeatureConfig(),
    *,
    C: float = DEFAULT_C,
    test_size: float = 0.2,
    random_state: int = 0,
    evaluate: bool = True,
    n_jobs: int = 2,
) -> VehicleClassifier:
    """Extract features, report honest accuracies, and fit the final model on every patch.

    Two held-out evaluations are run (in parallel with ``n_jobs``): a randomised stratified
    80/20 split, and a grouped 80/20 split in which no group of
    :attr:`~vehicle_detection.data.Dataset.groups` (GTI time-series blocks, byte-identical
    files) is on both sides. The final model is then fitted on all patches.

    Returns
    -------
    VehicleClassifier
        With ``metrics``: ``random_split`` and ``grouped_split`` (accuracy, precision, recall,
        confusion, n_train, n_test, fit_seconds), ``feature_seconds`` and ``fit_seconds`` for
        all patches, ``n_images``, ``n_features``, ``C``.
    """
    from joblib import Parallel, delayed

    from .data import check_split_sizes
    from .errors import InputError

    labels = np.asarray(dataset.labels)
    splits = {}
    if evaluate:  # too small a data set is refused here, before any work, not by scikit-learn
        check_split_sizes(labels, dataset.groups, test_size=test_size)
        splits = {
            "random_split": split_indices(labels, test_size=test_size, random_state=random_state),
            "grouped_split": split_indices(labels, dataset.groups, test_size=test_size, random_state=random_state),
        }
    elif len(np.unique(labels)) < 2:
        raise InputError(f"dataset: training needs images of both classes, got only label(s) {np.unique(labels).tolist()}")
    extract_features(dataset.images[:2], config)  # compile the kernels outside the timing
    t = time.perf_counter()
    features = extract_features(dataset.images, config)
    feature_s = time.perf_counter() - t
    metrics = {}
    if evaluate:
        results = Parallel(n_jobs=n_jobs, backend="threading")(
            delayed(_evaluate_split)(features, labels, config, tr, te, C) for tr, te in splits.values()
        )
        metrics.update(zip(splits, results))
    t = time.perf_counter()
    model = VehicleClassifier.fit(features, labels, config, C=C)
    fit_s = time.perf_counter() - t
    metrics.update(
        feature_seconds=round(feature_s, 3),
        fit_seconds=round(fit_s, 3),
        n_images=int(len(labels)),
        n_features=int(config.n_features),
        C=C,
        test_size=test_size,
        random_state=random_state,
    )
    model.metrics = metrics
    return model


# --- parameter sweep ---------------------------------------------------------------------------


def sweep_configs(
    color_spaces=("YCrCb", "YUV", "HLS", "LUV"),
    hog_channels=((0, 1, 2),),
    orientations=(9, 16),
    pixels_per_cell=(8, 16),
    cells_per_block=(2,),
    color_features=((16, 32), (0, 0)),
    signed=(True,),
    hog_sqrt=(True,),
) -> list[FeatureConfig]:
    """The product of the given choices as :class:`FeatureConfig` objects.

    ``color_features`` lists ``(spatial_size, hist_bins)`` pairs; ``(0, 0)`` is HOG only.
    """
    return [
        FeatureConfig(
            color_space=cs, hog_channels=ch, orientations=o, pixels_per_cell=p, cells_per_block=b,
            signed=sg, hog_sqrt=sq, spatial_size=s, hist_bins=h,
        )
        for cs, ch, o, p, b, (s, h), sg, sq in itertools.product(
            color_spaces, hog_channels, orientations, pixels_per_cell, cells_per_block, color_features, signed, hog_sqrt
        )
    ]


def _sweep_one(images, labels, groups, config, C, test_size, random_state):
    t = time.perf_counter()
    feats = extract_features(images, config)
    feature_s = time.perf_counter() - t
    row = {k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(config).items()}
    row.update(n_features=config.n_features, feature_seconds=round(feature_s, 3))
    for name, g in (("random", None), ("grouped", groups)):
        tr, te = split_indices(labels, g, test_size=test_size, random_state=random_state)
        res = _evaluate_split(feats, labels, config, tr, te, C)
        row[f"{name}_accuracy"] = res["accuracy"]
        row[f"{name}_fit_seconds"] = res["fit_seconds"]
    return row


def sweep(
    dataset: Dataset,
    configs: list[FeatureConfig],
    *,
    C: float = DEFAULT_C,
    test_size: float = 0.2,
    random_state: int = 0,
    n_jobs: int = 2,
) -> list[dict]:
    """Score each feature configuration on the random and grouped splits, in parallel.

    Returns
    -------
    list of dict
        One row per config: its fields, ``n_features``, ``feature_seconds``,
        ``random_accuracy``, ``grouped_accuracy`` and the fit times; sorted by
        ``grouped_accuracy``, best first.
    """
    from joblib import Parallel, delayed

    from .data import check_split_sizes

    check_split_sizes(dataset.labels, dataset.groups, test_size=test_size)  # before any work
    rows = Parallel(n_jobs=n_jobs)(
        delayed(_sweep_one)(dataset.images, dataset.labels, dataset.groups, cfg, C, test_size, random_state) for cfg in configs
    )
    return sorted(rows, key=lambda r: -r["grouped_accuracy"])
