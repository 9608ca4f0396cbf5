"""Feature extraction: colour conversion, spatial bins, colour histograms and HOG.

Everything is driven by one frozen :class:`FeatureConfig`, saved with every model, so training
and detection cannot disagree on colour space, cell size or bin counts.

The feature vector of a ``window x window`` RGB patch is, in this order::

    [spatial bins (S*S*3) | colour histograms (3*bins) | HOG of each chosen channel]

computed on the patch after conversion to ``config.color_space``.

HOG
---
The HOG here is one implementation, compiled with numba, used for both training and detection.
It reproduces ``skimage.feature.hog(channel, orientations, (ppc, ppc), (cpb, cpb),
block_norm='L2-Hys', feature_vector=True)`` on each channel (tests check this to float
precision) at a small fraction of the cost:

* gradients are central differences, zero on the image border (as scikit-image does);
* each pixel votes its magnitude into one orientation bin of its cell (unsigned, 0-180 deg); the
  bin of an integer gradient ``(gx, gy)`` comes from a lookup table built with the same
  floating-point expression scikit-image uses, so bin boundaries agree exactly;
* blocks of ``cpb x cpb`` cells are normalised with L2-Hys (clip at 0.2).

For the sliding-window search (:mod:`vehicle_detection.search`) the cells of a whole search
region are computed once. :func:`region_blocks` normalises every block of the region once: a
window's HOG is its blocks, and it sees the region's gradient across its own border (the
search's default, ``SearchPlan.window_border="frame"``). :func:`region_hog` also records, per
cell, how the votes of its border rows and columns change when that border is a window's border
(where a cropped patch has zero gradient); with those corrections the search reproduces, window
by window, the exact features a cropped patch gives (``window_border="crop"``).

``skimage.feature.hog(visualize=True)`` is used only to draw HOG pictures (:func:`hog_image`).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numba
import numpy as np

from ._jit import njit
from .errors import InputError
from .io.images import as_rgb_uint8

__all__ = [
    "COLOR_SPACES",
    "FEATURE_FORMAT",
    "FeatureConfig",
    "convert_color",
    "bin_spatial",
    "color_histogram",
    "hog_input",
    "hog_features",
    "SQRT_LUT",
    "extract_features",
    "hog_image",
    "RegionHOG",
    "region_hog",
    "region_blocks",
]

#: Bump when the numbers a given :class:`FeatureConfig` produces change; saved with each model.
FEATURE_FORMAT = 1

COLOR_SPACES = ("RGB", "HSV", "LUV", "HLS", "YUV", "YCrCb")
#: Fewest HOG blocks along a window side: the fast search (``search._score_hog``) treats the first,
#: the inner and the last block of a window as different border classes, and needs all three.
MIN_BLOCKS_PER_WINDOW = 3
_CV2_CODES = {
    "HSV": cv2.COLOR_RGB2HSV,
    "LUV": cv2.COLOR_RGB2LUV,
    "HLS": cv2.COLOR_RGB2HLS,
    "YUV": cv2.COLOR_RGB2YUV,
    "YCrCb": cv2.COLOR_RGB2YCrCb,
}
_EPS = 1e-5  # scikit-image's block-normalisation epsilon


@dataclass(frozen=True)
class FeatureConfig:
    """What features to extract from a ``window x window`` patch.

    Parameters
    ----------
    color_space : str
        One of :data:`COLOR_SPACES`; all features are computed in this space (8-bit OpenCV
        conventions: H of HSV/HLS is 0-179, the rest 0-255).
    hog_channels : tuple of int
        Channels (of the converted image) that get a HOG, e.g. ``(0,)`` or ``(0, 1, 2)``.
    orientations : int
        HOG orientation bins over 0-180 degrees.
    pixels_per_cell : int
        HOG cell side, in pixels; must divide ``window``.
    cells_per_block : int
        HOG block side, in cells; at most ``window // pixels_per_cell - 2``, so that a window
        holds at least :data:`MIN_BLOCKS_PER_WINDOW` (3) blocks along a side.
    signed : bool
        Signed gradient orientations (0-360 degrees) instead of unsigned (0-180). Signed bins
        keep the polarity of edges (a car's dark underside against the bright road), which
        scikit-image's HOG cannot express; unsigned HOG equals ``skimage.feature.hog``.
    hog_sqrt : bool
        Square-root gamma compression of each channel before its gradients (the
        ``transform_sqrt`` of Dalal and Triggs), quantised to 8 bits so that gradients stay
        integers: ``round(255 * sqrt(v / 255))``.
    spatial_size : int
        Side of the spatially binned patch (block means); 0 disables. Must divide ``window``.
    hist_bins : int
        Bins per channel of the colour histogram over 0-255 (equal widths); 0 disables.
    window : int
        Side of the square training patch, in pixels (64 for the GTI/KITTI images).
    """

    color_space: str = "YCrCb"
    hog_channels: tuple[int, ...] = (0, 1, 2)
    orientations: int = 16
    pixels_per_cell: int = 8
    cells_per_block: int = 2
    signed: bool = True
    hog_sqrt: bool = True
    spatial_size: int = 16
    hist_bins: int = 32
    window: int = 64

    def __post_init__(self):
        problems = []
        try:
            channels = tuple(self.hog_channels)
        except TypeError:
            channels = ()
        if any(isinstance(c, bool) or not isinstance(c, (int, np.integer)) for c in channels):
            problems.append(f"hog_channels {self.hog_channels!r} must be integers")
        else:
            object.__setattr__(self, "hog_channels", tuple(int(c) for c in channels))
        if self.color_space not in COLOR_SPACES:
            problems.append(f"color_space {self.color_space!r} is not one of {COLOR_SPACES}")
        ch = self.hog_channels
        if not ch or any(c not in (0, 1, 2) for c in ch) or len(set(ch)) != len(ch) or list(ch) != sorted(ch):
            problems.append(f"hog_channels {ch!r} must be distinct, sorted channels from 0, 1, 2")
        for name in ("orientations", "pixels_per_cell", "cells_per_block", "window", "spatial_size", "hist_bins"):
            v = getattr(self, name)
            low = 0 if name in ("spatial_size", "hist_bins") else 1
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < low:
                problems.append(f"{name} must be an integer >= {low}, got {v!r}")
        for name in ("signed", "hog_sqrt"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                problems.append(f"{name} must be True or False, got {getattr(self, name)!r}")
        if not problems:
            if not 2 <= self.orientations <= 64:
                problems.append("orientations must be within 2..64")
            if self.pixels_per_cell < 4 or self.window % self.pixels_per_cell:
                problems.append("pixels_per_cell must be >= 4 and divide window")
            elif self.window // self.pixels_per_cell < MIN_BLOCKS_PER_WINDOW:
                problems.append(
                    f"pixels_per_cell {self.pixels_per_cell} leaves {self.window // self.pixels_per_cell} cells per "
                    f"window of {self.window}; the sliding-window search needs at least {MIN_BLOCKS_PER_WINDOW} blocks "
                    f"(a first, an inner and a last) along a side"
                )
            elif self.window // self.pixels_per_cell - self.cells_per_block + 1 < MIN_BLOCKS_PER_WINDOW:
                cpw = self.window // self.pixels_per_cell
                problems.append(
                    f"cells_per_block must be at most {cpw - MIN_BLOCKS_PER_WINDOW + 1} with {cpw} cells per window "
                    f"(got {self.cells_per_block}, which leaves {max(0, cpw - self.cells_per_block + 1)} blocks along a "
                    f"side); the sliding-window search needs at least {MIN_BLOCKS_PER_WINDOW} (a first, an inner and a last)"
                )
            if self.spatial_size and self.window % self.spatial_size:
                problems.append("spatial_size must be 0 or divide window")
            elif self.spatial_size and self.pixels_per_cell % (self.window // self.spatial_size):
                problems.append(
                    "spatial bins (window // spatial_size pixels) must divide pixels_per_cell, so that the "
                    "sliding-window search can share them between windows"
                )
            if not 0 <= self.hist_bins <= 256:
                problems.append("hist_bins must be within 0..256")
        if problems:
            raise ValueError("invalid FeatureConfig: " + "; ".join(problems))

    # --- derived sizes -------------------------------------------------------------------------
    @property
    def cells_per_window(self) -> int:
        return self.window // self.pixels_per_cell

    @property
    def blocks_per_window(self) -> int:
        return self.cells_per_window - self.cells_per_block + 1

    @property
    def block_size(self) -> int:
        """Length of one normalised block: ``cells_per_block**2 * orientations``."""
        return self.cells_per_block**2 * self.orientations

    @property
    def hog_length(self) -> int:
        return len(self.hog_channels) * self.blocks_per_window**2 * self.block_size

    @property
    def spatial_length(self) -> int:
        return self.spatial_size**2 * 3

    @property
    def hist_length(self) -> int:
        return self.hist_bins * 3

    @property
    def n_features(self) -> int:
        return self.spatial_length + self.hist_length + self.hog_length

    def layout(self) -> dict[str, slice]:
        """Where each part lies in the feature vector: ``{'spatial', 'hist', 'hog'}`` -> slice."""
        a = self.spatial_length
        b = a + self.hist_length
        return {"spatial": slice(0, a), "hist": slice(a, b), "hog": slice(b, b + self.hog_length)}

    # --- persistence ---------------------------------------------------------------------------
    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["hog_channels"] = list(self.hog_channels)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> FeatureConfig:
        """Inverse of :meth:`to_dict`; unknown or missing fields are refused (``ValueError``)."""
        names = {f.name for f in dataclasses.fields(cls)}
        if not isinstance(d, dict):
            raise ValueError(f"feature config must be a JSON object, got {type(d).__name__}")
        unknown, missing = set(d) - names, names - set(d)
        if unknown or missing:
            raise ValueError(
                f"feature config fields differ from this version's: unknown {sorted(unknown)}, missing {sorted(missing)}"
            )
        return cls(**d)


# --- colour, spatial bins, histograms ---------------------------------------------------------


def convert_color(image: np.ndarray, color_space: str) -> np.ndarray:
    """Convert RGB ``uint8`` pixels to ``color_space`` (8-bit OpenCV conventions).

    Parameters
    ----------
    image : ndarray of uint8, shape (..., 3)
        RGB pixels; any leading shape (a batch of patches is converted in one call).
    color_space : str
        One of :data:`COLOR_SPACES`.

    Returns
    -------
    ndarray of uint8, same shape
    """
    if color_space not in COLOR_SPACES:
        raise ValueError(f"color_space {color_space!r} is not one of {COLOR_SPACES}")
    if image.dtype != np.uint8 or image.shape[-1] != 3:
        raise InputError(f"convert_color expects RGB uint8 (..., 3), got {image.dtype} {image.shape}")
    if color_space == "RGB" or image.size == 0:
        return image
    # One row of pixels: OpenCV's vectorised path, identical to converting image by image.
    flat = np.ascontiguousarray(image).reshape(1, -1, 3)
    return cv2.cvtColor(flat, _CV2_CODES[color_space]).reshape(image.shape)


@njit(nogil=True)
def _bin_spatial_one(images, i, size, out):
    _, h, w, c = images.shape
    fy = h // size
    fx = w // size
    inv = 1.0 / (fy * fx)
    for by in range(size):
        for bx in range(size):
            for ch in range(c):
                s = np.int64(0)  # a Python 0 plus uint8 stays uint8 without the JIT (NumPy 2)
                for y in range(by * fy, (by + 1) * fy):
                    for x in range(bx * fx, (bx + 1) * fx):
                        s += images[i, y, x, ch]
                out[i, (by * size + bx) * c + ch] = s * inv


@njit(nogil=True, parallel=True)
def _bin_spatial_batch(images, size, out):
    for i in numba.prange(images.shape[0]):
        _bin_spatial_one(images, i, size, out)


def bin_spatial(image: np.ndarray, size: int) -> np.ndarray:
    """Spatially binned colours: the mean of each ``f x f`` block, ``f = side // size``.

    Parameters
    ----------
    image : ndarray of uint8, shape (N, H, W, 3) or (H, W, 3)
        Patches whose height and width are divisible by ``size``.
    size : int
        Output side.

    Returns
    -------
    ndarray of float32, shape (N, size*size*3) or (size*size*3,)
        Block means in row-major ``(y, x, channel)`` order.
    """
    single = image.ndim == 3
    batch = np.ascontiguousarray(image[None] if single else image)
    n, h, w, c = batch.shape
    if h % size or w % size:
        raise ValueError(f"patch of {h}x{w} cannot be binned to {size}x{size}")
    out = np.empty((n, size * size * c), np.float32)
    if n:
        _bin_spatial_batch(batch, size, out)
    return out[0] if single else out


@njit(nogil=True)
def _histogram_one(images, i, bins, out):
    _, h, w, c = images.shape
    for ch in range(c):
        for b in range(bins):
            out[i, ch * bins + b] = 0.0
    for y in range(h):
        for x in range(w):
            for ch in range(c):
                out[i, ch * bins + (np.int32(images[i, y, x, ch]) * bins) // 256] += 1.0


@njit(nogil=True, parallel=True)
def _histogram_batch(images, bins, out):
    for i in numba.prange(images.shape[0]):
        _histogram_one(images, i, bins, out)


def color_histogram(image: np.ndarray, bins: int) -> np.ndarray:
    """Per-channel histograms of ``uint8`` values over 0-255 in ``bins`` equal bins.

    The bin of value ``v`` is ``v * bins // 256`` (exact integer arithmetic).

    Parameters
    ----------
    image : ndarray of uint8, shape (N, H, W, 3) or (H, W, 3)
    bins : int

    Returns
    -------
    ndarray of float32, shape (N, 3*bins) or (3*bins,)
        Pixel counts, channel 0's bins first.
    """
    single = image.ndim == 3
    batch = np.ascontiguousarray(image[None] if single else image)
    out = np.empty((batch.shape[0], batch.shape[3] * bins), np.float32)
    if len(batch):
        _histogram_batch(batch, bins, out)
    return out[0] if single else out


# --- HOG ---------------------------------------------------------------------------------------


#: 8-bit square-root gamma table used when ``FeatureConfig.hog_sqrt`` is set.
SQRT_LUT = np.rint(np.sqrt(np.arange(256) / 255.0) * 255.0).astype(np.uint8)
SQRT_LUT.setflags(write=False)


@lru_cache(maxsize=16)
def _orientation_lut(orientations: int, signed: bool = False) -> np.ndarray:
    """Bin of every integer gradient ``(gy, gx)`` in -255..255.

    ``lut[gy + 255, gx + 255]``. Unsigned bins are computed as scikit-image computes them (same
    floating-point expression and float32 bounds), so they agree exactly; the value
    ``orientations`` marks the (measure-zero) gradients scikit-image counts in no bin. Signed
    bins split 0-360 degrees the same way.
    """
    span = 360.0 if signed else 180.0
    g = np.arange(-255, 256, dtype=np.float64)
    gy, gx = np.meshgrid(g, g, indexing="ij")
    ang = np.arctan2(gy, gx) * (180 / np.pi) % span
    # scikit-image compares against bounds stored as C float: [180/n*i, 180/n*(i+1))
    bounds = np.array([np.float32(span / orientations * i) for i in range(orientations + 1)], dtype=np.float64)
    lut = np.full(ang.shape, orientations, dtype=np.uint8)
    for i in range(orientations):
        lut[(ang >= bounds[i]) & (ang < bounds[i + 1])] = i
    lut.setflags(write=False)
    return lut


@njit(nogil=True, inline="always")
def _gradient(chan, y, x, h, w):
    """Central differences, zero on the image border (scikit-image's convention)."""
    gx = 0
    gy = 0
    if 0 < x < w - 1:
        gx = np.int32(chan[y, x + 1]) - np.int32(chan[y, x - 1])
    if 0 < y < h - 1:
        gy = np.int32(chan[y + 1, x]) - np.int32(chan[y - 1, x])
    return gx, gy


@njit(nogil=True)
def _cell_votes(chan, lut, ppc, n_cr, n_cc, nb, cells):
    """HOG cell histograms of one channel: cells (n_cr, n_cc, nb) float64, zeroed."""
    h, w = chan.shape
    for cy in range(n_cr):
        for y in range(cy * ppc, (cy + 1) * ppc):
            for cx in range(n_cc):
                for x in range(cx * ppc, (cx + 1) * ppc):
                    gx, gy = _gradient(chan, y, x, h, w)
                    b = lut[gy + 255, gx + 255]
                    if b < nb:
                        cells[cy, cx, b] += math.sqrt(gx * gx + gy * gy)


@njit(nogil=True)
def _region_variants(image, channels, lut, ppc, nb, variants):
    """Cell histograms of chosen channels of a search region, as seen from any window.

    image (H, W, C) uint8; variants (len(channels), 3, 3, H // ppc, W // ppc, nb), float64 or
    float32 (summed in float64 either way), all overwritten. ``variants[k, 0, 0]`` are the cells
    of channel ``channels[k]``;
    ``variants[k, v, h]`` the cells as a cropped window sees them when its top (v=1) or bottom
    (v=2) border and its left (h=1) or right (h=2) border runs along the cell's edge: the crop
    has no gradient across its border, so a border pixel votes |gx| at 0 deg (top/bottom),
    |gy| at 90 deg (left/right), or nothing (corner) instead of its full gradient.
    """
    h, w = image.shape[0], image.shape[1]
    n_ch = channels.shape[0]
    n_cr, n_cc = variants.shape[3], variants.shape[4]
    # One cell at a time (small arrays that stay in the fastest cache): its histogram, and its
    # change when its top/bottom/left/right edge is a window border (d 0-3) plus the extra
    # change of its top-left/top-right/bottom-left/bottom-right pixel at a corner (d 4-7).
    # Bin ``nb`` collects the votes counted in no bin, without a branch (not copied out).
    cell = np.empty(nb + 1)
    d = np.empty((8, nb + 1))
    for k in range(n_ch):
        ch = channels[k]
        v = variants[k]
        for cy in range(n_cr):
            for cx in range(n_cc):
                cell[:] = 0.0
                d[:] = 0.0
                for ry in range(ppc):
                    y = cy * ppc + ry
                    top = ry == 0
                    bottom = ry == ppc - 1
                    inner_y = 0 < y < h - 1
                    for rx in range(ppc):
                        x = cx * ppc + rx
                        gx = 0
                        gy = 0
                        if 0 < x < w - 1:
                            gx = np.int32(image[y, x + 1, ch]) - np.int32(image[y, x - 1, ch])
                        if inner_y:
                            gy = np.int32(image[y + 1, x, ch]) - np.int32(image[y - 1, x, ch])
                        m = math.sqrt(gx * gx + gy * gy)
                        b = lut[gy + 255, gx + 255]
                        cell[b] += m
                        left = rx == 0
                        right = rx == ppc - 1
                        if not (top or bottom or left or right):
                            continue
                        if top or bottom:
                            e = 0 if top else 1
                            bh = lut[255, gx + 255]
                            d[e, bh] += abs(gx)
                            d[e, b] -= m
                        if left or right:
                            e = 2 if left else 3
                            bv = lut[gy + 255, 255]
                            d[e, bv] += abs(gy)
                            d[e, b] -= m
                        if (top or bottom) and (left or right):
                            # Both gradients zeroed: the vote is 0. The two edge changes sum to
                            # (mh - m) + (mv - m); this brings the total to -m.
                            e = (4 if left else 5) if top else (6 if left else 7)
                            bh = lut[255, gx + 255]
                            bv = lut[gy + 255, 255]
                            d[e, b] += m
                            d[e, bh] -= abs(gx)
                            d[e, bv] -= abs(gy)
                for o in range(nb):
                    c = cell[o]
                    t = c + d[0, o]
                    bo = c + d[1, o]
                    v[0, 0, cy, cx, o] = c
                    v[1, 0, cy, cx, o] = t
                    v[2, 0, cy, cx, o] = bo
                    v[0, 1, cy, cx, o] = c + d[2, o]
                    v[0, 2, cy, cx, o] = c + d[3, o]
                    v[1, 1, cy, cx, o] = t + d[2, o] + d[4, o]
                    v[1, 2, cy, cx, o] = t + d[3, o] + d[5, o]
                    v[2, 1, cy, cx, o] = bo + d[2, o] + d[6, o]
                    v[2, 2, cy, cx, o] = bo + d[3, o] + d[7, o]


@njit(nogil=True, fastmath=True)
def _l2hys(block):
    """L2-Hys normalisation in place (scikit-image's: eps 1e-5, clip at 0.2)."""
    n = block.shape[0]
    s = 0.0
    for j in range(n):
        s += block[j] * block[j]
    inv = 1.0 / math.sqrt(s + 1e-10)
    s = 0.0
    for j in range(n):
        v = min(block[j] * inv, 0.2)
        block[j] = v
        s += v * v
    inv = 1.0 / math.sqrt(s + 1e-10)
    for j in range(n):
        block[j] = block[j] * inv


@njit(nogil=True, inline="always")
def _edge_variant(block_class, a, cpb):
    """Which variant cell ``a`` (0..cpb-1 along one axis) of a block of this class uses.

    A block on the window's first (class 1) or last (class 2) row or column sees its first or
    last cell with the window border along that edge (variant 1 or 2); every other cell, and
    every cell of an interior block (class 0), is the plain cell (variant 0).
    """
    if block_class == 1 and a == 0:
        return 1
    if block_class == 2 and a == cpb - 1:
        return 2
    return 0


@njit(nogil=True, fastmath=True)
def _gather_block(variants, r, c, cpb, vclass, hclass, block):
    """Copy the cells of the block at (r, c) into ``block``, then L2-Hys normalise it.

    ``variants[vr, hc]`` are the cell histograms seen by a patch whose border runs along the
    cell's top (vr=1) or bottom (vr=2) and left (hc=1) or right (hc=2) edge. ``vclass`` says
    whether the block lies on the patch's top (1) or bottom (2) border, ``hclass`` likewise for
    left (1) and right (2); 0 is the interior.
    """
    nb = variants.shape[4]
    i = 0
    for a in range(cpb):
        vr = _edge_variant(vclass, a, cpb)
        for b in range(cpb):
            hc = _edge_variant(hclass, b, cpb)
            for k in range(nb):
                block[i] = variants[vr, hc, r + a, c + b, k]
                i += 1
    _l2hys(block)


@njit(nogil=True)
def _cell_squares(variants, ss):
    """Sum of squares of every cell histogram of every variant: ss (3, 3, n_cr, n_cc) float64."""
    n_cr, n_cc, nb = variants.shape[2], variants.shape[3], variants.shape[4]
    for a in range(3):
        for b in range(3):
            for r in range(n_cr):
                for c in range(n_cc):
                    t = 0.0
                    for o in range(nb):
                        t += variants[a, b, r, c, o] * variants[a, b, r, c, o]
                    ss[a, b, r, c] = t


@njit(nogil=True, fastmath=True, inline="always")
def _clipped_block(variants, ss, r, c, cpb, vclass, hclass, block):
    """L2-Hys of the block at (r, c) of a border class, but for its last scale factor.

    Writes the block's first-normalised, clipped values into ``block`` (float32 or float64)
    and returns the factor that finishes the normalisation: ``block * factor`` is what
    :func:`_gather_block` followed by :func:`_l2hys` gives. The cells' sums of squares ``ss``
    come from :func:`_cell_squares`, each computed once for every block it is in.
    """
    nb = variants.shape[4]
    s1 = 0.0
    for a in range(cpb):
        vr = _edge_variant(vclass, a, cpb)
        for b in range(cpb):
            s1 += ss[vr, _edge_variant(hclass, b, cpb), r + a, c + b]
    # float32 factors: float32 cells are scaled in float32 (float64 ones stay float64)
    inv1 = np.float32(1.0 / math.sqrt(s1 + 1e-10))
    clip = np.float32(0.2)
    s2 = 0.0
    for a in range(cpb):
        vr = _edge_variant(vclass, a, cpb)
        for b in range(cpb):
            src = variants[vr, _edge_variant(hclass, b, cpb), r + a, c + b]
            base = (a * cpb + b) * nb
            for o in range(nb):
                v = min(src[o] * inv1, clip)
                block[base + o] = v
                s2 += v * v
    return 1.0 / math.sqrt(s2 + 1e-10)


@njit(nogil=True)
def _hog_one(images, i, channels, lut, ppc, cpb, nb, out):
    """HOG of each chosen channel of patch ``i``. images: (N, H, W, C) uint8; out: (N, F) float32."""
    _, h, w, _ = images.shape
    n_cr = h // ppc
    n_cc = w // ppc
    n_br = n_cr - cpb + 1
    n_bc = n_cc - cpb + 1
    bs = cpb * cpb * nb
    per_ch = n_br * n_bc * bs
    variants = np.empty((1, 1, n_cr, n_cc, nb), np.float64)
    block = np.empty(bs, np.float64)
    for ci in range(channels.shape[0]):
        variants[:] = 0.0
        _cell_votes(images[i, :, :, channels[ci]], lut, ppc, n_cr, n_cc, nb, variants[0, 0])
        base = ci * per_ch
        for r in range(n_br):
            for c in range(n_bc):
                _gather_block(variants, r, c, cpb, 0, 0, block)
                o = base + (r * n_bc + c) * bs
                for j in range(bs):
                    out[i, o + j] = block[j]


@njit(nogil=True, parallel=True)
def _hog_batch(images, channels, lut, ppc, cpb, nb, out):
    for i in numba.prange(images.shape[0]):
        _hog_one(images, i, channels, lut, ppc, cpb, nb, out)


@njit(nogil=True)
def _features_serial(images, size, bins, hog_images, channels, lut, ppc, cpb, nb, spatial, hist, hog):
    """All three feature parts of every patch on the calling thread (for small batches in several
    threads at once, where parallel kernels would queue for the thread pool)."""
    for i in range(images.shape[0]):
        if size:
            _bin_spatial_one(images, i, size, spatial)
        if bins:
            _histogram_one(images, i, bins, hist)
        _hog_one(hog_images, i, channels, lut, ppc, cpb, nb, hog)


def hog_input(converted: np.ndarray, config: FeatureConfig) -> np.ndarray:
    """The pixels the HOG sees: colour-converted pixels, gamma-compressed if ``config.hog_sqrt``."""
    if not config.hog_sqrt:
        return converted
    flat = np.ascontiguousarray(converted).reshape(1, -1, converted.shape[-1] if converted.ndim > 2 else 1)
    return cv2.LUT(flat, SQRT_LUT).reshape(converted.shape) if converted.size else converted


def hog_features(images: np.ndarray, config: FeatureConfig) -> np.ndarray:
    """HOG of ``config.hog_channels`` of patches already passed through :func:`hog_input`.

    Parameters
    ----------
    images : ndarray of uint8, shape (N, H, W, 3)
        Patches in ``config.color_space`` (and gamma-compressed: :func:`hog_input`).
    config : FeatureConfig

    Returns
    -------
    ndarray of float32, shape (N, n_hog)
        Per channel, scikit-image's ``feature_vector`` order
        ``(block_row, block_col, cell_row, cell_col, orientation)``; channels concatenated.
    """
    images = np.ascontiguousarray(images)
    n, h, w, _ = images.shape
    ppc, cpb, nb = config.pixels_per_cell, config.cells_per_block, config.orientations
    n_br, n_bc = h // ppc - cpb + 1, w // ppc - cpb + 1
    if n_br < 1 or n_bc < 1:
        raise ValueError(f"patch of {h}x{w} is too small for {cpb}x{cpb} blocks of {ppc}-pixel cells")
    channels = np.asarray(config.hog_channels, dtype=np.int64)
    out = np.empty((n, len(channels) * n_br * n_bc * cpb * cpb * nb), dtype=np.float32)
    if n:
        _hog_batch(images, channels, _orientation_lut(nb, config.signed), ppc, cpb, nb, out)
    return out


def _check_patches(images: np.ndarray, config: FeatureConfig) -> np.ndarray:
    if not isinstance(images, np.ndarray):
        images = np.asarray(images)
    if images.ndim == 3:
        images = as_rgb_uint8(images, name="patch")[None]
    if images.ndim != 4 or images.shape[-1] != 3 or images.dtype != np.uint8:
        raise InputError(f"expected RGB uint8 patches of shape (N, {config.window}, {config.window}, 3), got {images.dtype} {images.shape}")
    if images.shape[1:3] != (config.window, config.window):
        raise InputError(
            f"patches must be {config.window}x{config.window} pixels for this model, got {images.shape[1]}x{images.shape[2]}; "
            "resize them first (cv2.resize)"
        )
    return images


def extract_features(images: np.ndarray, config: FeatureConfig, *, parallel: bool = True) -> np.ndarray:
    """Feature vectors of RGB patches, as the classifier sees them.

    Parameters
    ----------
    images : ndarray of uint8, shape (N, window, window, 3) or (window, window, 3)
        RGB patches.
    config : FeatureConfig
    parallel : bool
        Spread the patches over numba's threads (large batches); False computes them on the
        calling thread, without the GIL (small batches, each in a thread of its own).

    Returns
    -------
    ndarray of float32, shape (N, config.n_features) or (config.n_features,)
        ``[spatial | hist | hog]``, see :meth:`FeatureConfig.layout`.

    Raises
    ------
    InputError
        Wrong dtype, channel count or patch size.
    """
    single = np.ndim(images) == 3
    batch = _check_patches(images, config)
    conv = convert_color(batch, config.color_space)
    if not parallel:
        feats = _serial_features(np.ascontiguousarray(conv), config)
        return feats[0] if single else feats
    parts = []
    if config.spatial_size:
        parts.append(bin_spatial(conv, config.spatial_size))
    if config.hist_bins:
        parts.append(color_histogram(conv, config.hist_bins))
    parts.append(hog_features(hog_input(conv, config), config))
    feats = np.concatenate(parts, axis=1) if len(parts) > 1 else parts[0]
    return feats[0] if single else feats


def _serial_features(conv: np.ndarray, config: FeatureConfig) -> np.ndarray:
    """:func:`extract_features` of colour-converted patches, on this thread (same values)."""
    n, h, w, c = conv.shape
    size, bins = config.spatial_size, config.hist_bins
    ppc, cpb, nb = config.pixels_per_cell, config.cells_per_block, config.orientations
    channels = np.asarray(config.hog_channels, dtype=np.int64)
    n_hog = len(channels) * (h // ppc - cpb + 1) * (w // ppc - cpb + 1) * cpb * cpb * nb
    out = np.empty((n, size * size * c + c * bins + n_hog), np.float32)
    parts = np.split(out, [size * size * c, size * size * c + c * bins], axis=1)  # views: written in place
    if n:
        hog_pixels = np.ascontiguousarray(hog_input(conv, config))
        _features_serial(conv, size, bins, hog_pixels, channels, _orientation_lut(nb, config.signed), ppc, cpb, nb, *parts)
    return out


def hog_image(channel: np.ndarray, config: FeatureConfig) -> np.ndarray:
    """Picture of the HOG of one channel (scikit-image's visualisation), for figures only.

    scikit-image draws unsigned orientations: a signed config is drawn with half as many
    unsigned bins, after the config's gamma compression.

    Parameters
    ----------
    channel : ndarray of uint8, shape (H, W)

    Returns
    -------
    ndarray of float64, shape (H, W)

    Raises
    ------
    MissingDependencyError
        Without scikit-image (``pip install "vehicle-detection[notebooks]"``).
    """
    from .errors import require

    hog = require("skimage.feature", "notebooks", "the HOG picture (hog_image)").hog
    if config.hog_sqrt:
        channel = SQRT_LUT[channel]
    _, picture = hog(
        channel,
        orientations=config.orientations // 2 if config.signed else config.orientations,
        pixels_per_cell=(config.pixels_per_cell,) * 2,
        cells_per_block=(config.cells_per_block,) * 2,
        block_norm="L2-Hys",
        visualize=True,
        feature_vector=True,
    )
    return picture


# --- region HOG for the sliding-window search --------------------------------------------------


@dataclass(frozen=True)
class RegionHOG:
    """Cell histograms of one channel of a search region, as seen from any window.

    Attributes
    ----------
    variants : ndarray of float64, shape ([n_channels,] 3, 3, n_cell_rows, n_cell_cols, orientations)
        ``variants[..., 0, 0, :, :, :]`` are the cell histograms; ``variants[v, h]`` the histograms a cropped
        window sees when its top (v=1) or bottom (v=2) border and its left (h=1) or right (h=2)
        border runs along the cell's edge, where the crop has zero gradient across the border.
    """

    variants: np.ndarray

    @property
    def cells(self) -> np.ndarray:
        return self.variants[..., 0, 0, :, :, :]


def region_hog(image: np.ndarray, config: FeatureConfig, out: np.ndarray | None = None) -> RegionHOG:
    """Cell histograms of a whole search region, for each of ``config.hog_channels``.

    Parameters
    ----------
    image : ndarray of uint8, shape (H, W, 3) or (H, W)
        The region after :func:`hog_input`; a 2-D array is one channel.
    config : FeatureConfig
    out : ndarray of float64 or float32, shape (n_channels, 3, 3, H // ppc, W // ppc, orientations), optional
        Where to write the variants (reused across frames by the search).

    Returns
    -------
    RegionHOG
        Its ``variants`` have shape ``(n_channels, 3, 3, ...)``, or ``(3, 3, ...)`` for a 2-D
        image. Cells cover the top-left ``(H // ppc) x (W // ppc)`` cells.
    """
    single = image.ndim == 2
    img = np.ascontiguousarray(image[:, :, None] if single else image)
    channels = np.array([0] if single else config.hog_channels, dtype=np.int64)
    ppc, nb = config.pixels_per_cell, config.orientations
    n_cr, n_cc = img.shape[0] // ppc, img.shape[1] // ppc
    v = np.empty((len(channels), 3, 3, n_cr, n_cc, nb), np.float64) if out is None else out
    _region_variants(img, channels, _orientation_lut(nb, config.signed), ppc, nb, v)
    return RegionHOG(v[0] if single else v)


@njit(nogil=True)
def _region_cells(planes, lut, ppc, nb, acc, rows, mag, cells):
    """Cell histograms of a region's channels, with the region's own gradient everywhere.

    planes (C, H, W) uint8, one channel after the other (contiguous rows); cells
    (C, H // ppc, W // ppc, nb) float32, overwritten. Central differences, zero on the region's
    border only (scikit-image's convention for the region as one image). Row by row: the
    gradients, magnitudes and table indices of the whole row first (loops the compiler
    vectorises), then the votes into a row of cells, summed in float32 accumulators that stay in
    the fastest cache; bin ``nb`` collects the votes counted in no bin, without a branch. A
    cell's even and odd columns vote into two accumulators, added at the end: neighbouring
    pixels often vote into the same bin, and one accumulator would make each vote wait for the
    one before. ``lut`` is :func:`_orientation_lut`
    flattened: the bin of ``(gy, gx)`` at ``(gy + 255) * 511 + gx + 255``. Work arrays
    (:func:`_cell_work`, contents irrelevant): acc (2, W // ppc, nb + 1) float32, rows
    (3, W // ppc * ppc) int32, mag (W // ppc * ppc,) float32, passed in rather than allocated
    here: a kernel without allocations compiles faster (a first run's start). The output comes
    last, as in every kernel here.
    """
    n_ch, h, w = planes.shape
    n_cr, n_cc = cells.shape[1], cells.shape[2]
    n = n_cc * ppc  # the columns the cells cover (n <= w)
    gx, gy, index = rows[0], rows[1], rows[2]
    even, odd = acc[0], acc[1]
    for k in range(n_ch):
        image = planes[k]
        for cy in range(n_cr):
            acc[:] = 0.0
            for y in range(cy * ppc, (cy + 1) * ppc):
                row = image[y]
                if 0 < y < h - 1:
                    up, down = image[y - 1], image[y + 1]
                    for x in range(n):
                        gy[x] = np.int32(down[x]) - np.int32(up[x])
                else:
                    gy[:] = 0
                for x in range(1, min(n, w - 1)):
                    gx[x] = np.int32(row[x + 1]) - np.int32(row[x - 1])
                gx[0] = 0
                if n == w:
                    gx[w - 1] = 0
                for x in range(n):
                    mag[x] = math.sqrt(np.float32(gx[x] * gx[x] + gy[x] * gy[x]))
                    index[x] = (gy[x] + 255) * 511 + gx[x] + 255
                for cx in range(n_cc):
                    a, b = even[cx], odd[cx]
                    x0 = cx * ppc
                    for x in range(x0, x0 + ppc - 1, 2):
                        a[lut[index[x]]] += mag[x]
                        b[lut[index[x + 1]]] += mag[x + 1]
                    if ppc % 2:
                        a[lut[index[x0 + ppc - 1]]] += mag[x0 + ppc - 1]
            for cx in range(n_cc):
                for o in range(nb):
                    cells[k, cy, cx, o] = even[cx, o] + odd[cx, o]


def _cell_work(n_cc: int, ppc: int, nb: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The work arrays of :func:`_region_cells` for ``n_cc`` cells a row (a few kilobytes)."""
    n = n_cc * ppc
    return np.empty((2, n_cc, nb + 1), np.float32), np.empty((3, n), np.int32), np.empty(n, np.float32)


def _planes(image: np.ndarray, channels, out: np.ndarray | None = None) -> np.ndarray:
    """The chosen channels of an (H, W, C) image as contiguous (len(channels), H, W) planes
    (written into ``out`` when given: the search reuses it across frames)."""
    if out is None:
        out = np.empty((len(channels),) + image.shape[:2], image.dtype)
    for k, ch in enumerate(channels):
        out[k] = image[:, :, ch]
    return out


@njit(nogil=True, fastmath=True)
def _block_map(cells, cpb, blocks):
    """Every block of a region, L2-Hys normalised once (:func:`_l2hys`, as a patch's blocks are).

    cells (C, n_cr, n_cc, nb) float32; blocks (C, n_cr - cpb + 1, n_cc - cpb + 1, cpb * cpb * nb)
    float32, overwritten, in scikit-image's order within a block (cell row, cell column, bin).
    """
    n_ch, nb = cells.shape[0], cells.shape[3]
    n_br, n_bc = blocks.shape[1], blocks.shape[2]
    for k in range(n_ch):
        for r in range(n_br):
            for c in range(n_bc):
                out = blocks[k, r, c]
                i = 0
                for a in range(cpb):
                    for b in range(cpb):
                        for o in range(nb):
                            out[i] = cells[k, r + a, c + b, o]
                            i += 1
                _l2hys(out)


def region_blocks(image: np.ndarray, config: FeatureConfig, cells: np.ndarray | None = None,
                  out: np.ndarray | None = None) -> np.ndarray:
    """The normalised HOG blocks of a whole search region, computed once for all its windows.

    The gradient is the region's own everywhere but on the region's border: a window of the
    region sees, across its own border, the pixels around it (as detectors computing the HOG of a
    whole image do), where a cropped patch sees none (:func:`hog_features`, what the training
    patches give). A window's HOG is its blocks, in order; only the cells along its border differ
    from its crop's.

    Parameters
    ----------
    image : ndarray of uint8, shape (H, W, 3)
        The region after :func:`hog_input`.
    config : FeatureConfig
    cells, out : ndarray of float32, optional
        Work arrays of shapes ``(n_channels, H // ppc, W // ppc, orientations)`` and the result's,
        reused across frames by the search.

    Returns
    -------
    ndarray of float32, shape (n_channels, H // ppc - cpb + 1, W // ppc - cpb + 1, cpb * cpb * orientations)
        Block ``[k, r, c]`` of channel ``config.hog_channels[k]`` has its top-left cell at
        cell row ``r``, column ``c``.
    """
    channels = config.hog_channels
    ppc, nb, cpb = config.pixels_per_cell, config.orientations, config.cells_per_block
    n_cr, n_cc = image.shape[0] // ppc, image.shape[1] // ppc
    if cells is None:
        cells = np.empty((len(channels), n_cr, n_cc, nb), np.float32)
    if out is None:
        out = np.empty((len(channels), max(n_cr - cpb + 1, 0), max(n_cc - cpb + 1, 0), cpb * cpb * nb), np.float32)
    _region_cells(_planes(image, channels), _flat_lut(nb, config.signed), ppc, nb, *_cell_work(n_cc, ppc, nb), cells)
    _block_map(cells, cpb, out)
    return out


@lru_cache(maxsize=16)
def _flat_lut(orientations: int, signed: bool) -> np.ndarray:
    """:func:`_orientation_lut` as one row (for :func:`_region_cells`)."""
    lut = np.ascontiguousarray(_orientation_lut(orientations, signed).ravel())
    lut.setflags(write=False)
    return lut
