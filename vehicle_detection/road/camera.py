"""Camera calibration from chessboard photos, and undistortion.

:func:`calibrate` finds the inner corners of a chessboard (9x6 by default) in each photo, refines
them to sub-pixel accuracy, and fits the pinhole camera matrix and the lens distortion
(``cv2.calibrateCamera``). Photos without a full board are skipped, with the reason. Photos a
pixel or two larger than the majority size (two of the project's 20 are 1281x721 against
1280x720) are **cropped** at the right and bottom edges to the majority size, so the pixel grid
and the optical centre stay where they are (nothing is rescaled); photos that differ by more
than :data:`MAX_CROP` pixels, or are smaller, are skipped.

The result is a frozen :class:`Camera`, saved as JSON (never a pickle) with the image size,
the matrix, the distortion coefficients, the RMS reprojection error in pixels, and which photos
were used, cropped or skipped. :meth:`Camera.undistort` uses a remap table computed once per
camera. A camera file may also carry the bird's-eye transform of
:mod:`vehicle_detection.road.lanes` (``birds_eye``), derived from straight-road frames.

A :class:`Camera` is checked for plausibility when it is made (from a file, by :func:`calibrate`
or in code), so that a finite but absurd file cannot undistort every frame to nothing:

- the focal lengths ``fx`` and ``fy`` lie within :data:`FOCAL_RANGE` times the image width
  (horizontal fields of view of about 6 to 160 degrees), and ``fy / fx`` within 0.5 to 2;
- the principal point lies inside the image; the matrix has no skew and its last row is
  ``[0, 0, 1]`` (OpenCV's lens model);
- the distortion keeps at least :data:`MIN_VALID_FRACTION` of the undistorted frame inside the
  original image, and is one-to-one out to the image's corners (the remap never folds back);
- a bird's-eye transform is made for the same image size and is itself plausible (see
  :class:`~vehicle_detection.road.lanes.BirdsEye`).

:meth:`Camera.load` reads each field strictly and names the field at fault: a bad file is an
:class:`~vehicle_detection.errors.InputError` (exit status 3) of one line.
"""

from __future__ import annotations

import json
import math
import os
from collections import Counter
from dataclasses import dataclass, field, replace
from functools import cached_property
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from ..errors import InputError
from ..io import atomic_output, read_text
from ..io.images import list_images, read_image
from .lanes import BirdsEye

__all__ = ["Camera", "calibrate", "find_chessboard", "MAX_CROP", "FOCAL_RANGE", "MIN_VALID_FRACTION", "MAX_IMAGE_SIDE"]

#: Largest difference (pixels, per dimension) from the majority size that is cropped away.
MAX_CROP = 2
#: Plausible focal lengths in multiples of the image width: horizontal fields of view of about
#: 160 degrees (0.1) to 6 degrees (10). The project camera's is 0.90.
FOCAL_RANGE = (0.1, 10.0)
#: Smallest share of the undistorted frame that must come from inside the original image.
MIN_VALID_FRACTION = 0.5
#: Largest image side a camera file may give, pixels.
MAX_IMAGE_SIDE = 65536
_FORMAT = "vehicle-detection camera 1"


def find_chessboard(image: np.ndarray, pattern: tuple[int, int] = (9, 6)) -> np.ndarray | None:
    """Inner corners of a whole chessboard, to sub-pixel accuracy.

    Uses OpenCV's sector-based detector (``cv2.findChessboardCornersSB`` with
    ``CALIB_CB_ACCURACY``), which locates each corner to a fraction of a pixel itself (see
    docs/experiments.md, "Calibration", for how it compares with ``findChessboardCorners`` and ``cornerSubPix``).

    Parameters
    ----------
    image : ndarray, shape (H, W, 3) or (H, W), uint8
        RGB or grey photo.
    pattern : (int, int)
        Inner corners per row and per column.

    Returns
    -------
    ndarray, shape (cols * rows, 2), float32, or None
        The corners row by row; None when no board with all its inner corners is found, or when
        the board is cut by the image edge (an inner corner less than half a square from it).
    """
    corners, _ = _find_board(image, pattern)
    return corners


def _find_board(image: np.ndarray, pattern: tuple[int, int]) -> tuple[np.ndarray | None, str]:
    """``(corners, "")`` or ``(None, why)``."""
    gray = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2GRAY) if image.ndim == 3 else np.ascontiguousarray(image)
    flags = cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
    found, corners = cv2.findChessboardCornersSB(gray, pattern, flags)
    if not found:
        return None, f"no full {pattern[0]}x{pattern[1]} chessboard found"
    corners = corners.reshape(-1, 2).astype(np.float32)
    if not _board_inside(corners, pattern, gray.shape[1], gray.shape[0]):
        return None, f"the {pattern[0]}x{pattern[1]} chessboard is cut by the image edge"
    return corners, ""


def _board_inside(corners: np.ndarray, pattern: tuple[int, int], width: int, height: int) -> bool:
    """Whether every inner corner lies at least half a square inside the image.

    The four squares meeting at a corner must then be at least half visible; a corner closer to
    the edge (a board cut by it) is located from a truncated neighbourhood.
    """
    grid = corners.reshape(pattern[1], pattern[0], 2)
    across = np.linalg.norm(np.diff(grid, axis=1), axis=2)  # (rows, cols - 1)
    down = np.linalg.norm(np.diff(grid, axis=0), axis=2)  # (rows - 1, cols)
    square = np.full(grid.shape[:2], np.inf)
    square[:, :-1] = np.minimum(square[:, :-1], across)
    square[:, 1:] = np.minimum(square[:, 1:], across)
    square[:-1, :] = np.minimum(square[:-1, :], down)
    square[1:, :] = np.minimum(square[1:, :], down)
    x, y = grid[..., 0], grid[..., 1]
    margin = np.minimum(np.minimum(x, width - 1 - x), np.minimum(y, height - 1 - y))
    return bool(np.all(margin >= 0.5 * square))


def _distort(matrix: np.ndarray, distortion: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Pixel positions in the undistorted image -> the original image, ``(n, 2)`` (the remap's source)."""
    import cv2

    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    norm = (pts - matrix[:2, 2]) / np.diag(matrix)[:2]
    obj = np.c_[norm, np.ones(len(norm))]
    out, _ = cv2.projectPoints(obj, np.zeros(3), np.zeros(3), matrix, distortion)
    return out.reshape(-1, 2)


def _implausible(w: int, h: int, m: np.ndarray, d: np.ndarray) -> str:
    """Why a finite camera matrix and distortion cannot be a real camera of ``w x h`` images ("" if they can).

    The message starts with the field at fault, as a camera file names it.
    """
    fx, fy, cx, cy = m[0, 0], m[1, 1], m[0, 2], m[1, 2]
    lo, hi = FOCAL_RANGE
    for field_, f in (("matrix[0][0] (fx)", fx), ("matrix[1][1] (fy)", fy)):
        if not lo * w <= f <= hi * w:
            return (
                f"{field_} = {f:.6g} px is outside {lo:g} to {hi:g} times the image width "
                f"({lo * w:.6g} to {hi * w:.6g} px for {w}x{h} images)"
            )
    if not 0.5 <= fy / fx <= 2:
        return f"matrix[1][1] / matrix[0][0] (fy / fx) = {fy / fx:.3g} is outside 0.5 to 2"
    if not 0 <= cx <= w:
        return f"matrix[0][2] (cx) = {cx:.6g}: the principal point is outside the image (0 to {w} px)"
    if not 0 <= cy <= h:
        return f"matrix[1][2] (cy) = {cy:.6g}: the principal point is outside the image (0 to {h} px)"
    if abs(m[0, 1]) > 1e-6 * fx:
        return f"matrix[0][1] (skew) = {m[0, 1]:.6g} must be 0 (OpenCV's lens model has no skew)"
    if m[1, 0] != 0:
        return f"matrix[1][0] = {m[1, 0]:.6g} must be 0 (a pinhole camera matrix)"
    if not np.array_equal(m[2], [0.0, 0.0, 1.0]):
        return f"matrix[2] = {m[2].tolist()} must be [0, 0, 1] (a pinhole camera matrix)"
    # The undistorted frame takes each pixel from the remap's source in the original image:
    # most of those must lie inside it, ...
    xs, ys = np.meshgrid(np.linspace(0, w - 1, 65), np.linspace(0, h - 1, 37))
    src = _distort(m, d, np.c_[xs.ravel(), ys.ravel()])
    inside = np.isfinite(src).all(axis=1) & (src[:, 0] >= -0.5) & (src[:, 0] <= w - 0.5) & (src[:, 1] >= -0.5) & (src[:, 1] <= h - 0.5)
    if inside.mean() < MIN_VALID_FRACTION:
        return (
            f"distortion {d.tolist()} takes {1 - inside.mean():.0%} of the undistorted frame from outside the image "
            f"(at most {1 - MIN_VALID_FRACTION:.0%} may be)"
        )
    # ... and the remap may not fold over (a polynomial lens model turns round beyond its range):
    # neighbouring pixels keep their order (the Jacobian of the remap stays positive), ...
    grid = src.reshape(xs.shape + (2,))
    across, down = grid[:-1, 1:] - grid[:-1, :-1], grid[1:, :-1] - grid[:-1, :-1]
    det = across[..., 0] * down[..., 1] - across[..., 1] * down[..., 0]
    folded = np.argwhere(~(det > 0))
    if folded.size:
        y, x = folded[0]
        return (
            f"distortion {d.tolist()} folds the image over near ({xs[y, x]:.0f}, {ys[y, x]:.0f}) "
            "(the lens model is not one-to-one there)"
        )
    # ... and along each ray from the principal point to a corner the source moves steadily outward.
    t = np.linspace(0, 1, 257)[1:, None]
    for name, corner in (("top-left", (0, 0)), ("top-right", (w - 1, 0)), ("bottom-left", (0, h - 1)), ("bottom-right", (w - 1, h - 1))):
        ray = np.array([cx, cy]) + t * (np.array(corner, float) - [cx, cy])
        if np.allclose(ray[-1], [cx, cy]):
            continue  # the principal point is this corner
        r = np.hypot(*(_distort(m, d, ray) - [cx, cy]).T)
        bad = np.flatnonzero(~np.isfinite(r[1:]) | (np.diff(r) <= 0))
        if bad.size:
            return (
                f"distortion {d.tolist()} folds the image: the remap turns back {float(t[bad[0] + 1, 0]):.0%} of the way "
                f"from the principal point to the {name} corner (the lens model is not one-to-one there)"
            )
    return ""


@dataclass(frozen=True, eq=False)
class Camera:
    """A calibrated camera: intrinsic matrix and distortion, for one image size.

    Attributes
    ----------
    image_size : (int, int)
        ``(width, height)`` of the images it was calibrated on; :meth:`undistort` refuses others.
    matrix : ndarray, shape (3, 3)
    distortion : ndarray, shape (k,)
        OpenCV's ``(k1, k2, p1, p2, k3)``.
    rms : float
        RMS reprojection error of the calibration, pixels.
    images_used : tuple of str
    images_cropped : tuple of str
        Used after cropping to ``image_size``.
    images_skipped : dict of str to str
        Photo -> why it was not used.
    per_image_rms : dict of str to float
        RMS reprojection error of each photo used, pixels (outliers show here).
    birds_eye : BirdsEye or None
        The perspective transform to the road plane (:mod:`vehicle_detection.road.lanes`), if known.

    Raises
    ------
    ValueError
        If the matrix or distortion is not finite or of the wrong shape, or describes no real
        camera of ``image_size`` (see the module docstring); the message names the field.
    """

    image_size: tuple[int, int]
    matrix: np.ndarray
    distortion: np.ndarray
    rms: float = float("nan")
    images_used: tuple[str, ...] = ()
    images_cropped: tuple[str, ...] = ()
    images_skipped: dict = field(default_factory=dict)
    birds_eye: Any = None
    per_image_rms: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        m = np.array(self.matrix, dtype=np.float64)
        d = np.array(self.distortion, dtype=np.float64).reshape(-1)
        if m.shape != (3, 3) or not np.all(np.isfinite(m)) or not np.all(np.isfinite(d)) or d.size not in (4, 5, 8, 12, 14):
            raise ValueError("camera matrix must be finite 3x3 and distortion 4, 5, 8, 12 or 14 finite numbers")
        w, h = (int(v) for v in self.image_size)
        if not (1 <= w <= MAX_IMAGE_SIDE and 1 <= h <= MAX_IMAGE_SIDE):
            raise ValueError(f"image_size must be (width, height), each 1 to {MAX_IMAGE_SIDE} pixels; got {self.image_size}")
        problem = _implausible(w, h, m, d)
        if problem:
            raise ValueError(problem)
        if self.birds_eye is not None and tuple(self.birds_eye.image_size) != (w, h):
            bw, bh = self.birds_eye.image_size
            raise ValueError(f"birds_eye.image_size is {bw}x{bh}, but the camera's image_size is {w}x{h}")
        m.setflags(write=False)
        d.setflags(write=False)
        set_ = object.__setattr__
        set_(self, "image_size", (w, h))
        set_(self, "matrix", m)
        set_(self, "distortion", d)
        set_(self, "images_used", tuple(self.images_used))
        set_(self, "images_cropped", tuple(self.images_cropped))
        set_(self, "images_skipped", dict(self.images_skipped))
        set_(self, "per_image_rms", dict(self.per_image_rms))

    def __repr__(self) -> str:
        w, h = self.image_size
        return f"Camera({w}x{h}, rms={self.rms:.3f} px, {len(self.images_used)} images, birds_eye={self.birds_eye is not None})"

    # --- undistortion ------------------------------------------------------------------------
    @cached_property
    def _maps(self):
        return cv2.initUndistortRectifyMap(self.matrix, self.distortion, None, self.matrix, self.image_size, cv2.CV_16SC2)

    def check_size(self, width: int, height: int, what: str = "image") -> None:
        """Raise :class:`InputError` unless ``width x height`` is the calibrated size."""
        if (int(width), int(height)) != self.image_size:
            w, h = self.image_size
            raise InputError(
                f"{what} is {width}x{height}, but the camera file was calibrated for {w}x{h} images; "
                "calibrate this camera at this size"
            )

    def undistort(self, image: np.ndarray) -> np.ndarray:
        """The image with the lens distortion removed (same size and camera matrix)."""
        self.check_size(image.shape[1], image.shape[0])
        m1, m2 = self._maps
        return cv2.remap(image, m1, m2, cv2.INTER_LINEAR)

    def undistort_points(self, points) -> np.ndarray:
        """Pixel positions in the distorted image -> positions in the undistorted image, ``(n, 2)``."""
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 1, 2)
        return cv2.undistortPoints(pts, self.matrix, self.distortion, P=self.matrix).reshape(-1, 2)

    def distort_points(self, points) -> np.ndarray:
        """Pixel positions in the undistorted image -> the original (distorted) image, ``(n, 2)``."""
        return _distort(self.matrix, self.distortion, points)

    def boxes_to_original(self, xyxy, samples: int = 9) -> np.ndarray:
        """Boxes found in undistorted frames -> the boxes enclosing them in the original frames.

        Each edge is sampled at ``samples`` points (a straight edge bends under distortion);
        the result is rounded outward and clipped to the image, ``int64 (n, 4)``.
        """
        b = np.asarray(xyxy, dtype=np.float64).reshape(-1, 4)
        if not len(b):
            return np.zeros((0, 4), np.int64)
        t = np.linspace(0, 1, samples)
        x1, y1, x2, y2 = (b[:, i : i + 1] for i in range(4))
        xs = np.concatenate([x1 + (x2 - x1) * t, x1 + (x2 - x1) * t, np.repeat(x1, samples, 1), np.repeat(x2, samples, 1)], axis=1)
        ys = np.concatenate([np.repeat(y1, samples, 1), np.repeat(y2, samples, 1), y1 + (y2 - y1) * t, y1 + (y2 - y1) * t], axis=1)
        d = self.distort_points(np.c_[xs.reshape(-1), ys.reshape(-1)]).reshape(len(b), -1, 2)
        w, h = self.image_size
        out = np.c_[np.floor(d[..., 0].min(1)), np.floor(d[..., 1].min(1)), np.ceil(d[..., 0].max(1)), np.ceil(d[..., 1].max(1))]
        out = np.clip(out, 0, [w, h, w, h]).astype(np.int64)
        out[:, 2] = np.maximum(out[:, 2], out[:, 0] + 1)
        out[:, 3] = np.maximum(out[:, 3], out[:, 1] + 1)
        return out

    # --- files -------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        out = {
            "format": _FORMAT,
            "image_size": list(self.image_size),
            "matrix": self.matrix.tolist(),
            "distortion": self.distortion.tolist(),
            "rms": float(self.rms),
            "images_used": list(self.images_used),
            "images_cropped": list(self.images_cropped),
            "images_skipped": dict(self.images_skipped),
            "per_image_rms": dict(self.per_image_rms),
        }
        if self.birds_eye is not None:
            out["birds_eye"] = self.birds_eye.to_dict()
        return out

    def save(self, path: str | os.PathLike, *, overwrite: bool = False, inputs=()) -> Path:
        """Write the camera as JSON, atomically."""
        text = json.dumps(self.to_dict(), indent=1) + "\n"
        with atomic_output(path, overwrite=overwrite, inputs=inputs) as tmp:
            tmp.write_text(text, encoding="utf-8")
        return Path(path)

    @classmethod
    def from_dict(cls, d: dict, name: str = "camera") -> Camera:
        """A camera from the contents of a camera file, every field checked.

        Raises
        ------
        InputError
            One line naming ``name`` and the field at fault: a missing or mistyped field
            ("malformed camera file"), or values no real camera has ("implausible camera file",
            see the module docstring).
        """
        if not isinstance(d, dict) or d.get("format") != _FORMAT:
            raise InputError(f"{name}: not a camera file (expected \"format\": \"{_FORMAT}\")")
        try:
            size = _whole_numbers(_get(d, "image_size"), "image_size", 2)
            matrix = _numbers(_get(d, "matrix"), "matrix", (3, 3))
            distortion = _numbers(_get(d, "distortion"), "distortion", (None,))
            if len(distortion) not in (4, 5, 8, 12, 14):
                raise _Malformed(f"distortion has {len(distortion)} coefficients; OpenCV's models have 4, 5, 8, 12 or 14")
            rms = d.get("rms")
            if rms is None or (isinstance(rms, float) and math.isnan(rms)):
                rms = float("nan")  # unknown (a camera made in code)
            else:
                rms = _number(rms, "rms")
                if rms < 0:
                    raise _Malformed(f"rms = {rms:g} must be >= 0")
            images_used = _strings(d.get("images_used", []), "images_used")
            images_cropped = _strings(d.get("images_cropped", []), "images_cropped")
            skipped = _mapping(d.get("images_skipped", {}), "images_skipped", _string)
            per_image = _mapping(d.get("per_image_rms", {}), "per_image_rms", _number)
            birds_eye_doc = d.get("birds_eye")
            if birds_eye_doc is not None and not isinstance(birds_eye_doc, dict):
                raise _Malformed(f"birds_eye must be an object or null, got {_show(birds_eye_doc)}")
            if birds_eye_doc is not None:
                be_size = _whole_numbers(_get(birds_eye_doc, "image_size", "birds_eye."), "birds_eye.image_size", 2)
                if be_size != size:
                    raise _Malformed(f"birds_eye.image_size is {be_size[0]}x{be_size[1]}, but the camera's image_size is {size[0]}x{size[1]}")
                be = {
                    "src": _numbers(_get(birds_eye_doc, "src", "birds_eye."), "birds_eye.src", (4, 2)),
                    "dst": _numbers(_get(birds_eye_doc, "dst", "birds_eye."), "birds_eye.dst", (4, 2)),
                    "image_size": _whole_numbers(_get(birds_eye_doc, "image_size", "birds_eye."), "birds_eye.image_size", 2),
                    "warped_size": _whole_numbers(_get(birds_eye_doc, "warped_size", "birds_eye."), "birds_eye.warped_size", 2),
                    "xm_per_px": _number(_get(birds_eye_doc, "xm_per_px", "birds_eye."), "birds_eye.xm_per_px"),
                    "ym_per_px": _number(_get(birds_eye_doc, "ym_per_px", "birds_eye."), "birds_eye.ym_per_px"),
                }
        except _Malformed as exc:
            raise InputError(f"{name}: malformed camera file: {exc}") from None
        try:
            birds_eye = None
            if birds_eye_doc is not None:
                try:
                    birds_eye = BirdsEye(**be)
                except ValueError as exc:
                    raise ValueError(f"birds_eye.{exc}") from None
            return cls(
                image_size=tuple(size),
                matrix=matrix,
                distortion=distortion,
                rms=rms,
                images_used=tuple(images_used),
                images_cropped=tuple(images_cropped),
                images_skipped=skipped,
                birds_eye=birds_eye,
                per_image_rms=per_image,
            )
        except ValueError as exc:
            raise InputError(f"{name}: implausible camera file: {exc}") from None

    @classmethod
    def load(cls, path: str | os.PathLike) -> Camera:
        """Read a camera file written by :meth:`save` (checked as :meth:`from_dict` says)."""
        text = read_text(path, "camera file", "JSON", encoding="utf-8-sig")
        try:
            d = json.loads(text)
        except ValueError as exc:
            raise InputError(f"{path}: not a camera file: invalid JSON ({exc})") from None
        except RecursionError:
            raise InputError(f"{path}: not a camera file: JSON nested too deeply") from None
        return cls.from_dict(d, str(path))

    def replace(self, **changes) -> Camera:
        return replace(self, **changes)


# --- strict reading of camera files --------------------------------------------------------------


class _Malformed(ValueError):
    """A field of a camera file is missing or of the wrong type (the message names it)."""


def _show(value: Any) -> str:
    text = json.dumps(value) if isinstance(value, (dict, list, str, int, float, bool, type(None))) else repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def _get(d: dict, key: str, prefix: str = "") -> Any:
    if key not in d:
        raise _Malformed(f"no {prefix}{key!r}")
    return d[key]


def _number(value: Any, field_: str) -> float:
    """A finite JSON number (not a boolean)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise _Malformed(f"{field_} must be a number, got {_show(value)}")
    try:
        out = float(value)
    except OverflowError:
        raise _Malformed(f"{field_} = {_show(value)} is too large") from None
    if not math.isfinite(out):
        raise _Malformed(f"{field_} must be a finite number, got {out}")
    return out


def _numbers(value: Any, field_: str, shape: tuple) -> list:
    """Nested lists of finite numbers of ``shape`` (``None``: any length >= 1)."""
    n = shape[0]
    if not isinstance(value, list) or (n is not None and len(value) != n) or not value:
        what = f"a list of {n or ''} numbers".replace("  ", " ") if len(shape) == 1 else f"{n} lists of {shape[1]} numbers"
        raise _Malformed(f"{field_} must be {what}, got {_show(value)}")
    if len(shape) == 1:
        return [_number(v, f"{field_}[{i}]") for i, v in enumerate(value)]
    return [_numbers(v, f"{field_}[{i}]", shape[1:]) for i, v in enumerate(value)]


def _whole_numbers(value: Any, field_: str, n: int) -> list[int]:
    """``n`` whole numbers from 1 to :data:`MAX_IMAGE_SIDE` (a size in pixels)."""
    if not isinstance(value, list) or len(value) != n:
        raise _Malformed(f"{field_} must be {n} whole numbers (width, height), got {_show(value)}")
    out = []
    for i, v in enumerate(value):
        if isinstance(v, bool) or not isinstance(v, (int, float)) or (isinstance(v, float) and not v.is_integer()):
            raise _Malformed(f"{field_}[{i}] must be a whole number of pixels, got {_show(v)}")
        if not 1 <= v <= MAX_IMAGE_SIDE:
            raise _Malformed(f"{field_}[{i}] = {_show(v)} is outside 1 to {MAX_IMAGE_SIDE} pixels")
        out.append(int(v))
    return out


def _string(value: Any, field_: str) -> str:
    if not isinstance(value, str):
        raise _Malformed(f"{field_} must be a string, got {_show(value)}")
    return value


def _strings(value: Any, field_: str) -> list[str]:
    if not isinstance(value, list):
        raise _Malformed(f"{field_} must be a list of file names, got {_show(value)}")
    return [_string(v, f"{field_}[{i}]") for i, v in enumerate(value)]


def _mapping(value: Any, field_: str, parse) -> dict:
    if not isinstance(value, dict):
        raise _Malformed(f"{field_} must be an object (file name: value), got {_show(value)}")
    return {k: parse(v, f"{field_}[{json.dumps(k)}]") for k, v in value.items()}


def calibrate(
    images, pattern: tuple[int, int] = (9, 6), *, names=None, max_crop: int = MAX_CROP
) -> Camera:
    """Calibrate a camera from chessboard photos.

    Parameters
    ----------
    images : path-like folder, or iterable of paths or RGB arrays
        The photos; a folder means every image in it (sorted by name).
    pattern : (int, int)
        Inner corners per row and per column.
    names : list of str, optional
        Names for array inputs (default ``image0``, ``image1``, ...).
    max_crop : int
        Photos at most this many pixels wider/taller than the majority size are cropped at the
        right and bottom; others are skipped.

    Returns
    -------
    Camera

    Raises
    ------
    InputError
        If there are no photos, or fewer than 3 with a full chessboard (the message says why
        each photo was skipped).
    """
    if isinstance(images, (str, os.PathLike)):
        folder = Path(images)
        if not folder.is_dir():
            raise InputError(f"{folder}: not a folder of chessboard photos")
        images = list_images(folder)
        if not images:
            raise InputError(f"{folder}: no images")
    loaded = []
    for i, item in enumerate(images):
        if isinstance(item, (str, os.PathLike)):
            loaded.append((Path(item).name, read_image(item)))
        else:
            loaded.append((names[i] if names else f"image{i}", np.asarray(item)))
    if not loaded:
        raise InputError("no chessboard photos given")
    sizes = Counter((im.shape[1], im.shape[0]) for _, im in loaded)
    width, height = sizes.most_common(1)[0][0]
    obj = np.zeros((pattern[0] * pattern[1], 3), np.float32)
    obj[:, :2] = np.mgrid[0 : pattern[0], 0 : pattern[1]].T.reshape(-1, 2)
    object_points, image_points, used, cropped, skipped = [], [], [], [], {}
    for name, im in loaded:
        h, w = im.shape[:2]
        if (w, h) != (width, height):
            if 0 <= w - width <= max_crop and 0 <= h - height <= max_crop:
                im = im[:height, :width]
                cropped.append(name)
            else:
                skipped[name] = f"size {w}x{h} differs from the majority {width}x{height} by more than a {max_crop}-pixel crop"
                continue
        corners, why = _find_board(im, pattern)
        if corners is None:
            skipped[name] = why
            if name in cropped:
                cropped.remove(name)
            continue
        object_points.append(obj)
        image_points.append(corners.reshape(-1, 1, 2))
        used.append(name)
    if len(used) < 3:
        why = "; ".join(f"{k}: {v}" for k, v in skipped.items())
        raise InputError(
            f"no chessboard to calibrate on: {len(used)} of {len(loaded)} photos show a full "
            f"{pattern[0]}x{pattern[1]} chessboard (at least 3 needed){' (' + why + ')' if len(why) < 300 else ''}"
        )
    rms, matrix, dist, rvecs, tvecs = cv2.calibrateCamera(object_points, image_points, (width, height), None, None)
    problem = _implausible(width, height, matrix, dist.reshape(-1)) if np.all(np.isfinite(matrix)) and np.all(np.isfinite(dist)) else "not finite"
    if problem:
        raise InputError(
            f"the calibration from {len(used)} photos gave an implausible camera ({problem}); "
            "use more photos, with the board in every part of the frame"
        )
    per_image = {}
    for name, o, i, r, t in zip(used, object_points, image_points, rvecs, tvecs):
        p, _ = cv2.projectPoints(o, r, t, matrix, dist)
        per_image[name] = round(float(np.sqrt(np.mean(np.sum((p.reshape(-1, 2) - i.reshape(-1, 2)) ** 2, axis=1)))), 4)
    return Camera((width, height), matrix, dist.reshape(-1), float(rms), tuple(used), tuple(cropped), skipped, per_image_rms=per_image)
