"""Augmentation of training patches for other cameras and other light.

The archives' patches come from two cameras in daylight. Another dashcam sees cars brighter or
darker, with other contrast and tone curves, softer (optics, motion, smaller sensors), through
heavier compression, and framed a little larger or smaller by the sliding-window search. Each
function here takes RGB ``uint8`` patches of shape ``(N, S, S, 3)`` and an explicit
:class:`numpy.random.Generator`, draws one set of parameters per patch, and returns new patches
of the same shape and dtype (the input is never modified):

* :func:`flip` mirrors left and right;
* :func:`scale_jitter` zooms in (resize up, crop the centre) or out (resize down, reflect-pad);
* :func:`blur` applies a Gaussian blur;
* :func:`photometric` changes gamma, contrast and brightness;
* :func:`jpeg` re-compresses at a random JPEG quality.

:func:`augment` chains them as an :class:`AugmentConfig` says (in that order: geometry, optics,
tone, compression), ``copies`` times per patch, and says which patch each copy comes from:
:func:`vehicle_detection.training.fit.train` gives each copy its source's label and puts it on
its source's side of every split (a grouped split does not leak). The same generator state gives
the same patches.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from ..errors import shorten

__all__ = ["MAX_COPIES", "AugmentConfig", "augment", "blur", "flip", "jpeg", "photometric", "scale_jitter"]


def _is_real(value: Any) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


def _is_int(value: Any) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


#: The most augmented copies of each patch: each copy of the archives' 17,760 patches holds
#: about 0.7 GB of features.
MAX_COPIES = 8


@dataclass(frozen=True)
class AugmentConfig:
    """How many augmented copies of each training patch to make, and how far each transform goes.

    Parameters
    ----------
    copies : int, default 0
        Augmented copies per patch, 0 (no augmentation) to :data:`MAX_COPIES`.
    flip : float, default 0.5
        Probability of a left-right mirror, in ``[0, 1]``.
    scale : float, default 0.05
        Zoom factor drawn log-uniformly from ``[1 / (1 + scale), 1 + scale]``, in ``[0, 1]``:
        above 1 the centre is enlarged and cropped back, below 1 the patch is shrunk and padded
        by reflection.
    blur : float, default 0.2
        Probability of a Gaussian blur, in ``[0, 1]``.
    blur_sigma : (float, float), default (0.4, 0.8)
        Range of the blur's standard deviation in pixels, ``0 < low <= high``.
    gamma : float, default 0.15
        Gamma drawn log-uniformly from ``[exp(-gamma), exp(gamma)]``, >= 0; applied to values
        scaled to 0..1 (``v ** gamma``).
    contrast : float, default 0.15
        Contrast factor drawn from ``[1 - contrast, 1 + contrast]`` about each patch's mean, in
        ``[0, 1)``.
    brightness : float, default 0.06
        Offset drawn from ``[-brightness, brightness]`` of the full range (255), in ``[0, 1]``.
    jpeg : float, default 0.3
        Probability of a JPEG re-compression, in ``[0, 1]``.
    jpeg_quality : (int, int), default (60, 95)
        Range of the JPEG quality (inclusive), ``1 <= low <= high <= 100``.

    Notes
    -----
    The default ranges are the milder of the two sets measured on the dev cameras' tune frames
    (the stronger: ``scale`` 0.1, ``blur`` 0.3 with sigma 0.5 to 1.2, ``gamma`` 0.3,
    ``contrast`` 0.25, ``brightness`` 0.12, ``jpeg`` 0.5 at quality 30 to 90). Neither improved
    the embedded model's detection at its detector settings, so the embedded model is trained
    without augmentation (``copies`` 0).

    Raises
    ------
    ValueError
        If a value is out of range or of the wrong type; the message names the field.
    """

    copies: int = 0
    flip: float = 0.5
    scale: float = 0.05
    blur: float = 0.2
    blur_sigma: tuple[float, float] = (0.4, 0.8)
    gamma: float = 0.15
    contrast: float = 0.15
    brightness: float = 0.06
    jpeg: float = 0.3
    jpeg_quality: tuple[int, int] = (60, 95)

    def __post_init__(self) -> None:
        if not _is_int(self.copies) or not 0 <= self.copies <= MAX_COPIES:
            raise ValueError(f"AugmentConfig.copies must be an integer from 0 to {MAX_COPIES}; got {shorten(repr(self.copies))}")
        object.__setattr__(self, "copies", int(self.copies))
        rules = {
            "flip": (lambda v: 0.0 <= v <= 1.0, "a probability in [0, 1]"),
            "scale": (lambda v: 0.0 <= v <= 1.0, "a number in [0, 1]"),
            "blur": (lambda v: 0.0 <= v <= 1.0, "a probability in [0, 1]"),
            "gamma": (lambda v: 0.0 <= v <= 2.0, "a number in [0, 2]"),
            "contrast": (lambda v: 0.0 <= v < 1.0, "a number in [0, 1)"),
            "brightness": (lambda v: 0.0 <= v <= 1.0, "a number in [0, 1]"),
            "jpeg": (lambda v: 0.0 <= v <= 1.0, "a probability in [0, 1]"),
        }
        for name, (ok, rule) in rules.items():
            value = getattr(self, name)
            if not _is_real(value) or not math.isfinite(value) or not ok(float(value)):
                raise ValueError(f"AugmentConfig.{name} must be {rule}; got {value!r}")
            object.__setattr__(self, name, float(value))
        sigma = self._pair("blur_sigma", _is_real)
        if not (all(math.isfinite(s) for s in sigma) and 0 < sigma[0] <= sigma[1] <= 10):
            raise ValueError(f"AugmentConfig.blur_sigma must be (low, high) with 0 < low <= high <= 10; got {self.blur_sigma!r}")
        object.__setattr__(self, "blur_sigma", (float(sigma[0]), float(sigma[1])))
        quality = self._pair("jpeg_quality", _is_int)
        if not 1 <= quality[0] <= quality[1] <= 100:
            raise ValueError(f"AugmentConfig.jpeg_quality must be (low, high) with 1 <= low <= high <= 100; got {self.jpeg_quality!r}")
        object.__setattr__(self, "jpeg_quality", (int(quality[0]), int(quality[1])))

    def _pair(self, name: str, kind) -> tuple:
        value = getattr(self, name)
        try:
            pair = tuple(value)
        except TypeError:
            pair = ()
        if len(pair) != 2 or not all(kind(v) for v in pair):
            raise ValueError(f"AugmentConfig.{name} must be a pair of numbers (low, high); got {value!r}")
        return pair

    def replace(self, **changes) -> AugmentConfig:
        """A copy with some fields changed (validated again)."""
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict:
        """The fields as a JSON-ready dict (pairs as lists)."""
        d = dataclasses.asdict(self)
        d["blur_sigma"], d["jpeg_quality"] = list(self.blur_sigma), list(self.jpeg_quality)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> AugmentConfig:
        """Inverse of :meth:`to_dict`; unknown fields are refused (``ValueError``), missing ones take the defaults."""
        if not isinstance(d, dict):
            raise ValueError(f"augment config must be a JSON object, got {type(d).__name__}")
        unknown = set(d) - {f.name for f in dataclasses.fields(cls)}
        if unknown:
            raise ValueError(f"augment config has unknown fields {sorted(unknown)}")
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})


# --- the transforms --------------------------------------------------------------------------


def _check(images: np.ndarray) -> np.ndarray:
    images = np.asarray(images)
    if images.dtype != np.uint8 or images.ndim != 4 or images.shape[3] != 3 or images.shape[1] != images.shape[2]:
        raise ValueError(f"patches must be RGB uint8 of shape (N, S, S, 3); got {images.dtype} {images.shape}")
    return images


def _chosen(rng: np.random.Generator, n: int, p: float) -> np.ndarray:
    return rng.random(n) < p


def flip(images: np.ndarray, rng: np.random.Generator, *, p: float = 0.5) -> np.ndarray:
    """Mirror each patch left-right with probability ``p``.

    Parameters
    ----------
    images : ndarray of uint8, shape (N, S, S, 3)
    rng : numpy.random.Generator
    p : float

    Returns
    -------
    ndarray of uint8, shape (N, S, S, 3)
    """
    images = _check(images)
    out = images.copy()
    chosen = _chosen(rng, len(images), p)
    out[chosen] = images[chosen, :, ::-1]
    return out


def _zoom(image: np.ndarray, factor: float) -> np.ndarray:
    side = image.shape[0]
    size = max(1, int(round(side * factor)))
    if size == side:
        return image.copy()
    interpolation = cv2.INTER_AREA if size < side else cv2.INTER_LINEAR
    resized = cv2.resize(image, (size, size), interpolation=interpolation)
    if size > side:
        a = (size - side) // 2
        return np.ascontiguousarray(resized[a : a + side, a : a + side])
    a = (side - size) // 2
    b = side - size - a
    return cv2.copyMakeBorder(resized, a, b, a, b, cv2.BORDER_REFLECT_101)


def scale_jitter(images: np.ndarray, rng: np.random.Generator, *, scale: float = 0.05) -> np.ndarray:
    """Zoom each patch about its centre by a factor drawn log-uniformly from ``[1 / (1 + scale), 1 + scale]``.

    Above 1 the patch is enlarged (bilinear) and its centre cropped back to ``S x S``; below 1
    it is shrunk (area averaging) and padded back to ``S x S`` by reflection
    (``cv2.BORDER_REFLECT_101``), so no black border appears. A factor that changes the side by
    less than half a pixel leaves the patch as it is.

    Parameters
    ----------
    images : ndarray of uint8, shape (N, S, S, 3)
    rng : numpy.random.Generator
    scale : float
        In ``[0, 1]``; 0 leaves every patch unchanged.

    Returns
    -------
    ndarray of uint8, shape (N, S, S, 3)
    """
    images = _check(images)
    factors = np.exp(rng.uniform(-1.0, 1.0, len(images)) * math.log1p(scale))
    if not len(images):
        return images.copy()
    return np.stack([_zoom(im, f) for im, f in zip(images, factors)])


def blur(images: np.ndarray, rng: np.random.Generator, *, p: float = 0.2, sigma: tuple[float, float] = (0.4, 0.8)) -> np.ndarray:
    """Gaussian-blur each patch with probability ``p``, its standard deviation drawn from ``sigma``.

    Parameters
    ----------
    images : ndarray of uint8, shape (N, S, S, 3)
    rng : numpy.random.Generator
    p : float
    sigma : (float, float)
        Range of the standard deviation in pixels (uniform); the kernel reaches 3 sigma, the
        border is reflected.

    Returns
    -------
    ndarray of uint8, shape (N, S, S, 3)
    """
    images = _check(images)
    chosen = _chosen(rng, len(images), p)
    sigmas = rng.uniform(sigma[0], sigma[1], len(images))
    out = images.copy()
    for i in np.flatnonzero(chosen):
        k = 2 * int(math.ceil(3 * sigmas[i])) + 1
        out[i] = cv2.GaussianBlur(images[i], (k, k), sigmas[i], borderType=cv2.BORDER_REFLECT_101)
    return out


def photometric(
    images: np.ndarray, rng: np.random.Generator, *, gamma: float = 0.15, contrast: float = 0.15, brightness: float = 0.06
) -> np.ndarray:
    """Change each patch's tone curve, contrast and brightness, in that order.

    With values ``v`` scaled to 0..1: ``v ** g`` with ``g`` log-uniform in
    ``[exp(-gamma), exp(gamma)]``; then ``m + c * (v - m)`` with ``m`` the patch's mean (over
    its pixels and channels) and ``c`` uniform in ``[1 - contrast, 1 + contrast]``; then
    ``+ b`` with ``b`` uniform in ``[-brightness, brightness]``; clipped to 0..1 and rounded
    back to 0..255. Colours keep their hue (the same curve applies to the three channels).

    Parameters
    ----------
    images : ndarray of uint8, shape (N, S, S, 3)
    rng : numpy.random.Generator
    gamma, contrast, brightness : float
        0 turns a change off.

    Returns
    -------
    ndarray of uint8, shape (N, S, S, 3)
    """
    images = _check(images)
    n = len(images)
    gammas = np.exp(rng.uniform(-1.0, 1.0, n) * gamma)
    contrasts = 1.0 + rng.uniform(-1.0, 1.0, n) * contrast
    offsets = rng.uniform(-1.0, 1.0, n) * brightness
    levels = np.arange(256, dtype=np.float64) / 255.0
    # One 256-entry curve per patch: the mean after gamma comes from the patch's histogram.
    hists = np.stack([np.bincount(im.ravel(), minlength=256) for im in images]) if n else np.zeros((0, 256))
    curves = levels[None, :] ** gammas[:, None]  # (n, 256)
    means = (hists * curves).sum(axis=1, keepdims=True) / (images[0].size if n else 1)
    curves = means + contrasts[:, None] * (curves - means) + offsets[:, None]
    luts = np.clip(np.rint(curves * 255.0), 0, 255).astype(np.uint8)
    out = np.empty_like(images)
    for i in range(n):
        out[i] = cv2.LUT(images[i], luts[i])
    return out


def jpeg(images: np.ndarray, rng: np.random.Generator, *, p: float = 0.3, quality: tuple[int, int] = (60, 95)) -> np.ndarray:
    """Re-compress each patch as JPEG with probability ``p``, its quality drawn from ``quality``.

    Encoded and decoded with OpenCV (``cv2.imencode`` / ``cv2.imdecode``, 4:2:0 chroma
    subsampling as cameras use): block artefacts, ringing and colour bleeding.

    Parameters
    ----------
    images : ndarray of uint8, shape (N, S, S, 3)
    rng : numpy.random.Generator
    p : float
    quality : (int, int)
        Inclusive range of the JPEG quality (uniform), within 1..100.

    Returns
    -------
    ndarray of uint8, shape (N, S, S, 3)
    """
    images = _check(images)
    chosen = _chosen(rng, len(images), p)
    qualities = rng.integers(quality[0], quality[1] + 1, len(images))
    out = images.copy()
    for i in np.flatnonzero(chosen):
        ok, data = cv2.imencode(".jpg", images[i, :, :, ::-1], [cv2.IMWRITE_JPEG_QUALITY, int(qualities[i])])
        if not ok:  # pragma: no cover - OpenCV encodes any uint8 image
            raise RuntimeError("JPEG encoding failed")
        out[i] = cv2.imdecode(data, cv2.IMREAD_COLOR)[:, :, ::-1]
    return out


def augment(images: np.ndarray, config: AugmentConfig, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """``config.copies`` augmented copies of each patch.

    Each copy is, in turn, mirrored (:func:`flip`), zoomed (:func:`scale_jitter`), blurred
    (:func:`blur`), changed in tone (:func:`photometric`) and re-compressed (:func:`jpeg`), with
    parameters drawn independently per copy.

    Parameters
    ----------
    images : ndarray of uint8, shape (N, S, S, 3)
        RGB patches.
    config : AugmentConfig
    rng : numpy.random.Generator
        The only source of randomness: the same state gives the same copies.

    Returns
    -------
    copies : ndarray of uint8, shape (N * config.copies, S, S, 3)
        The copies of patch ``i`` are rows ``i * copies`` to ``(i + 1) * copies - 1``.
    origin : ndarray of int64, shape (N * config.copies,)
        The index in ``images`` of each copy's source patch.
    """
    images = _check(images)
    origin = np.repeat(np.arange(len(images), dtype=np.int64), config.copies)
    out = images[origin]
    out = flip(out, rng, p=config.flip)
    out = scale_jitter(out, rng, scale=config.scale)
    out = blur(out, rng, p=config.blur, sigma=config.blur_sigma)
    out = photometric(out, rng, gamma=config.gamma, contrast=config.contrast, brightness=config.brightness)
    out = jpeg(out, rng, p=config.jpeg, quality=config.jpeg_quality)
    return out, origin

