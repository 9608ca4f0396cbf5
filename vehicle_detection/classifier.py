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
import math
import os
import zipfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any
from importlib import resources
from pathlib import Path

import numpy as np

from . import __version__, deprecation
from .config import DetectorConfig
from .convnet import ConvNet
from .errors import ModelError, shorten
from .features import FEATURE_FORMAT, FeatureConfig, extract_features
from .io import atomic_output, input_file
from .refine import BoxRegressor

__all__ = [
    "MODEL_FORMAT",
    "DEFAULT_C",
    "VehicleClassifier",
    "default_model_path",
    "load_model",
    "load_default_model",
    "SHIPPED_MODELS",
    "shipped_model_path",
]

MODEL_FORMAT = "vehicle-detection-model"
#: SVM regularisation used by default (chosen with the sweep on the grouped split).
DEFAULT_C = 3e-4
MODEL_FORMAT_VERSION = 2
# Caps on a model file's members, checked before anything is read: a header is a few KB, and the
# largest feature vector of any sensible FeatureConfig is well under a million floats.
_MAX_HEADER_BYTES = 1 << 20
_MAX_ARRAY_BYTES = 64 << 20
_ARRAYS = ("scaler_mean", "scaler_scale", "coef", "intercept")
#: Arrays of the optional box refinement (:mod:`~vehicle_detection.refine`).
_BOX_ARRAYS = ("box_coef", "box_intercept")


def _version_tuple(v: str) -> tuple[int, ...]:
    out = []
    for part in str(v).split(".")[:2]:
        digits = "".join(itertools.takewhile(str.isdigit, part))
        out.append(int(digits) if digits else 0)
    return tuple(out)


#: Largest magnitude of any number of a model's linear maps, and of its folded weights and bias
#: (trained ones stay far below: the embedded model's largest is 1,802, a feature mean); far
#: larger ones overflow the float32 scores.
MAX_MODEL_VALUE = 1e9
#: Smallest feature scale (standard deviation) of a model's scaler: a trained one's is far
#: larger; dividing by a subnormal one overflows.
MIN_SCALER_SCALE = 1e-12


def _implausible_weights(arrays: dict[str, np.ndarray]) -> str:
    """Why the arrays of a model file cannot be a trained model ("" if they can)."""
    for name, a in arrays.items():
        top = float(np.max(np.abs(a))) if a.size else 0.0
        if top > MAX_MODEL_VALUE:
            return f"array {name} holds {top:.3g}; a model's numbers are at most {MAX_MODEL_VALUE:g} in magnitude"
    if "coef" not in arrays:
        return ""
    low = float(np.min(np.abs(arrays["scaler_scale"]))) if arrays["scaler_scale"].size else 1.0
    if not low >= MIN_SCALER_SCALE:
        return f"array scaler_scale holds {low:.3g}; a feature's scale is at least {MIN_SCALER_SCALE:g}"
    weights = arrays["coef"] / arrays["scaler_scale"]
    bias = float(arrays["intercept"][0] - np.dot(weights, arrays["scaler_mean"]))
    if np.max(np.abs(weights)) > MAX_MODEL_VALUE or not abs(bias) <= MAX_MODEL_VALUE:
        return f"coef / scaler_scale reaches {np.max(np.abs(weights)):.3g} and the bias {bias:.3g}; at most {MAX_MODEL_VALUE:g} in magnitude"
    return ""


def _digest(arrays: dict[str, np.ndarray], header: dict) -> str:
    """SHA-256 over the arrays and the header (minus the digest itself), canonically encoded."""
    h = hashlib.sha256()
    h.update(json.dumps({k: v for k, v in header.items() if k != "sha256"}, sort_keys=True).encode("utf-8"))
    for name in (*_ARRAYS, *(b for b in (*_BOX_ARRAYS, *ConvNet.array_names()) if b in arrays)):
        a = np.ascontiguousarray(arrays[name], dtype="<f8")
        h.update(name.encode())
        h.update(str(a.shape).encode())
        h.update(a.tobytes())
    return h.hexdigest()


@dataclass(frozen=True, eq=False)
class VehicleClassifier:
    """A trained linear vehicle classifier and the detector settings tuned to it; immutable.

    Parameters
    ----------
    config : FeatureConfig
        Features the model was trained on.
    scaler_mean, scaler_scale : array_like of float, shape (n_features,)
        Standardisation: ``z = (x - mean) / scale``.
    coef : array_like of float, shape (n_features,)
        SVM weights over standardised features.
    intercept : float
        SVM bias; the decision is ``z @ coef + intercept`` (> 0: vehicle).
    metrics : dict, optional
        Training report (accuracies, timings), saved with the model; kept as a JSON copy.
    library_version : str, optional
        Version of the library that trained the model.
    detector_config : DetectorConfig, optional
        Search plan, heat, blob and tracker settings tuned to this model's margins.
    box_regressor : BoxRegressor, optional
        Predicts a vehicle's edges from a hot window's features (:mod:`~vehicle_detection.refine`);
        None: windows are not refined.
    convnet : ConvNet, optional
        A network that scores the search's windows and gives each its vehicle's edges
        (:mod:`~vehicle_detection.convnet`) in place of the linear SVM and the box refinement;
        the SVM is kept beside it (trained on the same patches). None: the SVM scores.

    Attributes
    ----------
    weights : ndarray of float64, shape (n_features,)
        The scaler folded into the SVM: the margin is ``x @ weights + bias`` on raw features.
    bias : float

    All arrays are read-only copies; use :meth:`replace` for a changed model.

    Examples
    --------
    >>> import numpy as np
    >>> model = load_default_model()
    >>> model.weights.flags.writeable
    False
    >>> bolder = model.replace(intercept=model.intercept + 1.0)
    >>> round(float(bolder.bias - model.bias), 9)
    1.0
    """

    config: FeatureConfig
    scaler_mean: np.ndarray
    scaler_scale: np.ndarray
    coef: np.ndarray
    intercept: float
    metrics: Mapping[str, Any] = field(default_factory=dict)
    library_version: str = __version__
    detector_config: DetectorConfig = field(default_factory=DetectorConfig)
    box_regressor: BoxRegressor | None = None
    convnet: ConvNet | None = None
    weights: np.ndarray = field(init=False, repr=False)
    bias: float = field(init=False, repr=False)

    def __post_init__(self):
        if not isinstance(self.config, FeatureConfig):
            raise ValueError(f"config must be a FeatureConfig; got {type(self.config).__name__}")
        if not isinstance(self.detector_config, DetectorConfig):
            raise ValueError(f"detector_config must be a DetectorConfig; got {type(self.detector_config).__name__}")
        n = self.config.n_features
        if self.box_regressor is not None:
            if not isinstance(self.box_regressor, BoxRegressor) or self.box_regressor.n_features != n:
                raise ValueError(f"box_regressor must be a BoxRegressor over the model's {n} features")
        if self.convnet is not None and not isinstance(self.convnet, ConvNet):
            raise ValueError(f"convnet must be a ConvNet or None; got {type(self.convnet).__name__}")
        set_ = object.__setattr__
        for name in ("scaler_mean", "scaler_scale", "coef"):
            arr = np.array(getattr(self, name), dtype=np.float64, copy=True)
            if arr.shape != (n,):
                raise ValueError(f"{name} must have shape ({n},) for this feature config, got {arr.shape}")
            arr.setflags(write=False)
            set_(self, name, arr)
        set_(self, "intercept", float(self.intercept))
        set_(self, "metrics", json.loads(json.dumps(dict(self.metrics or {}))))  # a JSON copy
        set_(self, "library_version", str(self.library_version))
        weights = self.coef / self.scaler_scale
        weights.setflags(write=False)
        set_(self, "weights", weights)
        set_(self, "bias", float(self.intercept - np.dot(self.coef, self.scaler_mean / self.scaler_scale)))

    def __repr__(self):
        net = ", convnet" if self.convnet is not None else ""
        return f"VehicleClassifier({self.config!r}, n_features={self.config.n_features}{net})"

    def replace(self, **changes: Any) -> VehicleClassifier:
        """A new model with some fields replaced, e.g. ``model.replace(detector_config=...)``."""
        return dataclasses.replace(self, **changes)

    # --- fitting -------------------------------------------------------------------------------
    @classmethod
    def fit(
        cls,
        features: np.ndarray,
        labels: np.ndarray,
        config: FeatureConfig,
        *,
        C: float = DEFAULT_C,
        max_iter: int = 5000,
        detector_config: DetectorConfig | None = None,
    ) -> VehicleClassifier:
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
        detector_config : DetectorConfig, optional
            Settings saved with the model; the library's defaults when None.
        """
        # scikit-learn only when a model is fitted: loading one for detection stays fast (about 1 s less)
        from sklearn.pipeline import make_pipeline
        from sklearn.preprocessing import StandardScaler
        from sklearn.svm import LinearSVC

        pipe = make_pipeline(StandardScaler(), LinearSVC(C=C, dual=True, max_iter=max_iter, random_state=0))
        pipe.fit(features, labels)
        scaler, svm = pipe[0], pipe[1]
        scale = np.where(scaler.scale_ > 0, scaler.scale_, 1.0)
        return cls(config, scaler.mean_, scale, svm.coef_[0], svm.intercept_[0], detector_config=detector_config or DetectorConfig())

    # --- prediction ----------------------------------------------------------------------------
    def decision_function(self, features: np.ndarray) -> np.ndarray:
        """Signed SVM margin of feature vectors, shape (N,) (or a float for one vector)."""
        return np.asarray(features, dtype=np.float64) @ self.weights + self.bias

    def predict(self, features: np.ndarray) -> np.ndarray:
        """1 where the margin is positive (vehicle), else 0."""
        return (self.decision_function(features) > 0).astype(np.int8)

    def decision_images(self, images: np.ndarray) -> np.ndarray:
        """Margins of RGB ``uint8`` patches ``(N, window, window, 3)``: the network's scores
        where the model has one, else the SVM's."""
        if self.convnet is not None:
            return self.convnet.score_patches(np.asarray(images)).astype(np.float64)[:, 0]
        return self.decision_function(extract_features(images, self.config))

    # --- persistence ---------------------------------------------------------------------------
    def _arrays(self) -> dict[str, np.ndarray]:
        arrays = {
            "scaler_mean": self.scaler_mean,
            "scaler_scale": self.scaler_scale,
            "coef": self.coef,
            "intercept": np.array([self.intercept]),
        }
        if self.box_regressor is not None:
            arrays.update(box_coef=self.box_regressor.coef, box_intercept=self.box_regressor.intercept)
        if self.convnet is not None:
            arrays.update(self.convnet.arrays())
        return arrays

    def save(self, path: str | os.PathLike, *, overwrite: bool = False, inputs=()) -> Path:
        """Write the model as an ``.npz`` of float arrays plus a JSON header, atomically.

        The header holds the feature config, the detector config, the library version, the
        training metrics and a SHA-256 over header and arrays.
        """
        arrays = self._arrays()
        meta = {
            "format": MODEL_FORMAT,
            "format_version": MODEL_FORMAT_VERSION,
            "library_version": self.library_version,
            "feature_format": FEATURE_FORMAT,
            "feature_config": self.config.to_dict(),
            "detector_config": self.detector_config.to_dict(),
            "metrics": dict(self.metrics),
        }
        if self.convnet is not None:
            meta["convnet"] = self.convnet.spec()
        meta["sha256"] = _digest(arrays, meta)
        meta_bytes = np.frombuffer(json.dumps(meta, sort_keys=True).encode("utf-8"), dtype=np.uint8)
        path = Path(path)
        with atomic_output(path, overwrite=overwrite, inputs=inputs) as tmp:
            with open(tmp, "wb") as f:
                np.savez(f, meta=meta_bytes, **arrays)
        return path

    @classmethod
    def load(cls, path: str | os.PathLike) -> VehicleClassifier:
        """Read and check a model file, or a model shipped in the package by its name
        (:data:`SHIPPED_MODELS`: ``"svm"``, ``"convnet"``) where no file of that name exists.

        A model file of format version 1 (library 0.1, which saved no detector settings) is
        migrated: it gets the settings that library ran every model with.

        Raises
        ------
        ModelError
            Missing, truncated, oversized or tampered file; unknown format; feature configuration
            or feature format that the running code does not produce; a model from a newer
            library; arrays whose shapes do not fit the configuration. The message names the
            file and the problem.
        """
        path = shipped_model_path(path)
        input_file(path, "model file", ModelError)
        data = _read_npz(path)
        meta_arr = data["meta"]
        if meta_arr.dtype != np.uint8 or meta_arr.ndim != 1:
            raise ModelError(f"{path}: model header has the wrong type")
        try:
            meta = json.loads(meta_arr.tobytes().decode("utf-8"))
        except (UnicodeDecodeError, json.JSONDecodeError) as exc:
            raise ModelError(f"{path}: model header is not valid JSON: {exc}") from None
        except RecursionError:
            raise ModelError(f"{path}: model header is nested too deeply") from None
        if not isinstance(meta, dict) or meta.get("format") != MODEL_FORMAT:
            raise ModelError(f"{path}: not a {MODEL_FORMAT} file")
        version = meta.get("format_version")
        if version not in (1, MODEL_FORMAT_VERSION):
            raise ModelError(f"{path}: model format version {version!r} is not supported (expected 1 or {MODEL_FORMAT_VERSION})")
        lib = meta.get("library_version", "?")
        if not isinstance(lib, str) or len(lib) > 64:
            raise ModelError(f"{path}: library_version in the header must be a version string")
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
        try:
            detector_config = DetectorConfig.library_0_1() if version == 1 else DetectorConfig.from_dict(meta.get("detector_config"))
        except (TypeError, ValueError) as exc:
            raise ModelError(f"{path}: detector config does not match this code: {exc}") from None
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
        regressor = _box_regressor(path, data, n)
        if regressor is not None:
            arrays.update(box_coef=regressor.coef, box_intercept=regressor.intercept)
        convnet = _convnet(path, data, meta)
        if convnet is not None:
            arrays.update(convnet.arrays())
        if np.any(arrays["scaler_scale"] <= 0):
            raise ModelError(f"{path}: scaler_scale must be positive")
        problem = _implausible_weights(arrays)
        if problem:
            raise ModelError(f"{path}: {problem}")
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
            detector_config=detector_config,
            box_regressor=regressor,
            convnet=convnet,
        )


def _convnet(path: Path, data: dict[str, np.ndarray], meta: dict) -> ConvNet | None:
    """The model file's window-scoring network, if it has one."""
    if "net_w0" not in data:
        if "convnet" in meta:
            raise ModelError(f"{path}: the header describes a network, but the file holds none of its arrays")
        return None
    try:
        ConvNet.check_spec(meta.get("convnet"))
        return ConvNet.from_arrays(data)
    except ValueError as exc:
        raise ModelError(f"{path}: {exc}") from None


def _box_regressor(path: Path, data: dict[str, np.ndarray], n: int) -> BoxRegressor | None:
    """The model file's box refinement, if it has one (files before it have none)."""
    if "box_coef" not in data:
        return None
    coef, intercept = data["box_coef"], data["box_intercept"]
    if coef.dtype != np.float64 or coef.shape != (4, n) or intercept.dtype != np.float64 or intercept.shape != (4,):
        raise ModelError(f"{path}: box refinement arrays are {coef.dtype} {coef.shape} and {intercept.dtype} {intercept.shape}, expected float64 (4, {n}) and (4,)")
    problem = _implausible_weights({"box_coef": coef, "box_intercept": intercept})
    if problem:
        raise ModelError(f"{path}: {problem}")
    try:
        return BoxRegressor(coef, intercept)
    except ValueError as exc:
        raise ModelError(f"{path}: {exc}") from None


def _check_declared_size(path: Path, name: str, zf: zipfile.ZipFile, info: zipfile.ZipInfo) -> None:
    """Refuse an array whose ``.npy`` header declares more bytes than its member holds, before
    NumPy allocates what the header declares (a forged shape of 10^12 would be terabytes)."""
    with zf.open(info) as f:
        try:
            version = np.lib.format.read_magic(f)
            read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
            shape, _, dtype = read(f)
        except ValueError as exc:
            raise ModelError(f"{path}: array {name} has no valid .npy header: {shorten(str(exc))}") from None
        header = f.tell()
    if dtype.hasobject:
        raise ModelError(f"{path}: unreadable model file: array {name} holds Python objects (pickled data), which are never loaded")
    declared = math.prod(shape) * dtype.itemsize
    if declared + header != info.file_size:
        raise ModelError(f"{path}: array {name} declares shape {shorten(str(shape))} ({declared} bytes) but holds "
                         f"{info.file_size - header} bytes")


def _read_npz(path: Path) -> dict[str, np.ndarray]:
    """The arrays of a model file, refusing oversized members before reading them."""
    expected = {"meta", *_ARRAYS}
    try:
        with zipfile.ZipFile(path) as zf:
            infos = {i.filename.removesuffix(".npy"): i for i in zf.infolist()}
            if set(_BOX_ARRAYS) <= set(infos):
                expected |= set(_BOX_ARRAYS)
            if set(ConvNet.array_names()) <= set(infos):
                expected |= set(ConvNet.array_names())
            if set(infos) != expected:
                raise ModelError(f"{path}: not a {MODEL_FORMAT} file: arrays {sorted(infos)}, expected {sorted(expected)}")
            for name, info in infos.items():
                limit = _MAX_HEADER_BYTES if name == "meta" else _MAX_ARRAY_BYTES
                if info.file_size > limit:
                    raise ModelError(f"{path}: array {name} is {info.file_size} bytes unpacked, more than a model holds ({limit})")
                _check_declared_size(path, name, zf, info)
        with np.load(path, allow_pickle=False) as npz:
            return {k: npz[k] for k in expected}
    except ModelError:
        raise
    except zipfile.BadZipFile:
        # np.save of a single array is no zip: say so rather than "bad zip".
        with open(path, "rb") as f:
            magic = f.read(6)
        if magic == b"\x93NUMPY":
            raise ModelError(f"{path}: not a {MODEL_FORMAT} file (a single .npy array, not an .npz archive)") from None
        raise ModelError(f"{path}: unreadable model file (truncated, corrupt or not an .npz)") from None
    except (EOFError, OSError, ValueError, KeyError, zipfile.LargeZipFile, NotImplementedError) as exc:
        raise ModelError(f"{path}: unreadable model file (truncated, corrupt or not an .npz): {exc}") from None


#: The models shipped in the package, by name (``load_model("convnet")``, ``--model convnet``):
#: ``svm``, the seeds' HOG features and linear SVM with the box refinement (the default), and
#: ``convnet``, the same with a window-scoring network (:mod:`~vehicle_detection.convnet`).
SHIPPED_MODELS = {"svm": "default.npz", "convnet": "convnet.npz"}


def shipped_model_path(path: str | os.PathLike) -> Path:
    """``path``, or the package's model of that name (:data:`SHIPPED_MODELS`) where ``path`` is
    one of those names and no such file exists."""
    if isinstance(path, str) and path in SHIPPED_MODELS and not Path(path).exists():
        return Path(str(resources.files("vehicle_detection") / "models" / SHIPPED_MODELS[path]))
    return Path(path)


def default_model_path() -> Path:
    """Path of the model shipped inside the package."""
    return Path(str(resources.files("vehicle_detection") / "models" / "default.npz"))


def load_model(path: str | os.PathLike | None = None) -> VehicleClassifier:
    """A model file or a shipped model's name (see :meth:`VehicleClassifier.load`), or the
    embedded default model for None."""
    return VehicleClassifier.load(default_model_path() if path is None else path)


def load_default_model() -> VehicleClassifier:
    """The embedded default model (see the README for how it was trained and its metrics)."""
    return VehicleClassifier.load(default_model_path())


def __getattr__(name: str):
    """``train``, ``sweep``, ``sweep_configs``, ``split_indices`` and ``with_box_refinement`` moved
    to :mod:`vehicle_detection.training.fit`; still here for one release, with a warning."""
    return deprecation.moved_attribute(__name__, name)
