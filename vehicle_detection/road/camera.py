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
"""

from __future__ import annotations

import json
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

__all__ = ["Camera", "calibrate", "find_chessboard", "MAX_CROP"]

#: Largest difference (pixels, per dimension) from the majority size that is cropped away.
MAX_CROP = 2
_FORMAT = "vehicle-detection camera 1"


def find_chessboard(image: np.ndarray, pattern: tuple[int, int] = (9, 6)) -> np.ndarray | None:
    """Inner corners of a whole chessboard, to sub-pixel accuracy.

    Uses OpenCV's sector-based detector (``cv2.findChessboardCornersSB`` with
    ``CALIB_CB_ACCURACY``), which locates each corner to a fraction of a pixel itself (see the
    writeup for how it compares with ``findChessboardCorners`` and ``cornerSubPix``).

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
        if w < 1 or h < 1:
            raise ValueError(f"image_size must be positive (width, height); got {self.image_size}")
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
        pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
        norm = (pts - self.matrix[:2, 2]) / np.diag(self.matrix)[:2]
        obj = np.c_[norm, np.ones(len(norm))]
        out, _ = cv2.projectPoints(obj, np.zeros(3), np.zeros(3), self.matrix, self.distortion)
        return out.reshape(-1, 2)

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
        if not isinstance(d, dict) or d.get("format") != _FORMAT:
            raise InputError(f"{name}: not a camera file (expected \"format\": \"{_FORMAT}\")")
        try:
            birds_eye = None
            if d.get("birds_eye") is not None:
                birds_eye = BirdsEye.from_dict(d["birds_eye"])
            rms = d.get("rms")
            return cls(
                image_size=tuple(d["image_size"]),
                matrix=d["matrix"],
                distortion=d["distortion"],
                rms=float("nan") if rms is None else float(rms),
                images_used=tuple(map(str, d.get("images_used", ()))),
                images_cropped=tuple(map(str, d.get("images_cropped", ()))),
                images_skipped={str(k): str(v) for k, v in dict(d.get("images_skipped", {})).items()},
                birds_eye=birds_eye,
                per_image_rms={str(k): float(v) for k, v in dict(d.get("per_image_rms", {})).items()},
            )
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{name}: malformed camera file: {exc}") from None

    @classmethod
    def load(cls, path: str | os.PathLike) -> Camera:
        """Read a camera file written by :meth:`save`."""
        text = read_text(path, "camera file", "JSON")
        try:
            d = json.loads(text)
        except ValueError as exc:
            raise InputError(f"{path}: not a camera file: invalid JSON ({exc})") from None
        return cls.from_dict(d, str(path))

    def replace(self, **changes) -> Camera:
        return replace(self, **changes)


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
    per_image = {}
    for name, o, i, r, t in zip(used, object_points, image_points, rvecs, tvecs):
        p, _ = cv2.projectPoints(o, r, t, matrix, dist)
        per_image[name] = round(float(np.sqrt(np.mean(np.sum((p.reshape(-1, 2) - i.reshape(-1, 2)) ** 2, axis=1)))), 4)
    return Camera((width, height), matrix, dist.reshape(-1), float(rms), tuple(used), tuple(cropped), skipped, per_image_rms=per_image)
