"""Image files in and out: the one place where pixels enter or leave the library.

Inside the library an image is always RGB ``uint8`` with shape ``(H, W, 3)``. Files are decoded
with Pillow, which refuses truncated files instead of padding them with grey, and are converted
by these documented rules:

========================  ==========================================================
file or array             becomes
========================  ==========================================================
RGB 8-bit                 as is
grayscale (L, 1-bit)      the grey value copied to R, G and B
RGBA, LA, palette         alpha dropped (no blending), palette expanded
16-bit (I;16, I)          scaled to 8 bits: ``round(v / 257)``
16-bit colour PNG, TIFF   the same ``round(v / 257)`` per sample (RGB, RGBA, grey + alpha; alpha
                          dropped), not Pillow's truncation to the high byte
CMYK, YCbCr               converted to RGB by Pillow
float images              refused: 0-1 versus 0-255 is ambiguous (the classic bug)
========================  ==========================================================

Arrays passed to the public API go through :func:`as_rgb_uint8`, which applies the same rules to
arrays (and refuses floats), so that a BGR/float/grey mix-up fails loudly instead of silently
producing garbage features. Files are read and written with Pillow (RGB); OpenCV, with its BGR
order, decodes only 16-bit colour files, and its output is reordered to RGB at once.
"""

from __future__ import annotations

import io
import os
from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError

from ._files import atomic_output
from .errors import InputError

__all__ = ["IMAGE_EXTENSIONS", "read_image", "decode_image", "as_rgb_uint8", "write_image", "list_images"]

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")

# Pillow refuses to open images larger than this many pixels (decompression bombs).
Image.MAX_IMAGE_PIXELS = 100_000_000


def _from_pil(img: Image.Image, name: str) -> np.ndarray:
    mode = img.mode
    if mode in ("RGB",):
        arr = np.asarray(img)
    elif mode in ("L", "1"):
        arr = np.asarray(img.convert("L"))
    elif mode in ("I;16", "I;16B", "I;16L", "I;16N", "I"):
        raw = np.asarray(img)
        if raw.min(initial=0) < 0 or raw.max(initial=0) > 65535:
            raise InputError(f"{name}: integer image with values outside 0..65535 is not supported")
        arr = np.rint(raw.astype(np.float32) / 257.0).astype(np.uint8)
    elif mode in ("F",):
        raise InputError(f"{name}: floating-point image file; convert it to 8-bit RGB first")
    else:  # RGBA, LA, P, PA, CMYK, YCbCr, LAB, HSV, ...
        arr = np.asarray(img.convert("RGB"))
    return as_rgb_uint8(arr, name=name)


def _is_16bit_colour(img: Image.Image, data: bytes) -> bool:
    """Whether Pillow would cut this file's 16-bit colour samples to their high byte."""
    if img.format == "PNG":
        # IHDR comes first: bit depth at byte 24, colour type at 25 (2 RGB, 4 grey + alpha, 6 RGBA).
        return len(data) > 25 and data[24] == 16 and data[25] in (2, 4, 6)
    if img.format == "TIFF" and img.mode not in ("I;16", "I;16B", "I;16L", "I;16N", "I"):
        bits = getattr(img, "tag_v2", {}).get(258, ())
        return 16 in (bits if isinstance(bits, tuple) else (bits,))
    return False


def _decode_16bit_colour(data: bytes, size: tuple[int, int]) -> np.ndarray | None:
    """16-bit RGB of a 16-bit colour file, decoded by OpenCV; None if it cannot."""
    import cv2

    arr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if arr is None or arr.dtype != np.uint16 or arr.shape[:2] != (size[1], size[0]):
        return None
    if arr.ndim == 3 and arr.shape[2] in (3, 4):
        arr = np.ascontiguousarray(arr[:, :, 2::-1])  # BGR(A) -> RGB, alpha dropped
    return arr


def decode_image(data: bytes, name: str = "<bytes>") -> np.ndarray:
    """Decode an encoded image (PNG, JPEG, ...) held in memory.

    Parameters
    ----------
    data : bytes
        The file's bytes.
    name : str
        Used in error messages (the file or archive member the bytes came from).

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
        RGB pixels, converted by the rules in the module docstring.

    Raises
    ------
    InputError
        If the bytes are empty, truncated, or not an image Pillow can read.
    """
    if not data:
        raise InputError(f"{name}: empty file, not an image")
    try:
        with Image.open(io.BytesIO(data)) as img:
            img.load()  # Pillow checks the whole file (truncation) first
            if _is_16bit_colour(img, data):
                arr = _decode_16bit_colour(data, img.size)
                if arr is not None:
                    return as_rgb_uint8(arr, name=name)  # round(v / 257)
            return _from_pil(img, name)
    except InputError:
        raise
    except UnidentifiedImageError:
        raise InputError(f"{name}: not an image (or a format Pillow cannot read)") from None
    except (OSError, SyntaxError, ValueError) as exc:  # truncated or corrupt data
        raise InputError(f"{name}: corrupt or truncated image: {exc}") from None
    except Image.DecompressionBombError as exc:
        raise InputError(f"{name}: image too large: {exc}") from None


def read_image(path: str | os.PathLike) -> np.ndarray:
    """Read an image file as RGB ``uint8``.

    Parameters
    ----------
    path : path-like
        Image file (PNG, JPEG, BMP, TIFF, WebP).

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
        RGB pixels; PNG and JPEG give the same dtype, range and channel order.

    Raises
    ------
    InputError
        Missing file, a folder, or undecodable content; the message names the file.
    """
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{path}: is a folder, not an image file")
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read: {exc.strerror or exc}") from None
    return decode_image(data, str(path))


def as_rgb_uint8(image, *, name: str = "image") -> np.ndarray:
    """Check an array at the API edge and return it as RGB ``uint8`` ``(H, W, 3)``.

    Parameters
    ----------
    image : array_like
        ``uint8`` or ``uint16`` array of shape (H, W), (H, W, 1), (H, W, 3) or (H, W, 4).
        Channel order is taken to be RGB: the library cannot tell BGR from RGB by content, so
        arrays from ``cv2.imread`` must be converted by the caller (``image[..., ::-1]``).
    name : str
        Used in error messages.

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
        The same array when it already conforms (no copy), else a converted copy.

    Raises
    ------
    InputError
        Float, bool or signed arrays, wrong number of dimensions or channels, or empty images.
    """
    arr = np.asarray(image)
    if arr.dtype == np.uint16:
        arr = np.rint(arr.astype(np.float32) / 257.0).astype(np.uint8)
    elif arr.dtype != np.uint8:
        hint = " (0-1 versus 0-255 is ambiguous; scale and convert to uint8 yourself)" if arr.dtype.kind == "f" else ""
        raise InputError(f"{name}: expected an RGB uint8 image, got dtype {arr.dtype}{hint}")
    if arr.ndim == 2:
        arr = np.repeat(arr[:, :, None], 3, axis=2)
    elif arr.ndim == 3 and arr.shape[2] == 1:
        arr = np.repeat(arr, 3, axis=2)
    elif arr.ndim == 3 and arr.shape[2] == 4:
        arr = np.ascontiguousarray(arr[:, :, :3])
    elif not (arr.ndim == 3 and arr.shape[2] == 3):
        raise InputError(f"{name}: expected shape (H, W), (H, W, 3) or (H, W, 4), got {arr.shape}")
    if arr.shape[0] == 0 or arr.shape[1] == 0:
        raise InputError(f"{name}: empty image of shape {arr.shape}")
    return arr


def write_image(path: str | os.PathLike, image, *, overwrite: bool = False, inputs=()) -> Path:
    """Write an RGB ``uint8`` image (format from the file extension), atomically.

    Parameters
    ----------
    path : path-like
        Destination; missing folders are created.
    image : ndarray of uint8, shape (H, W, 3)
        RGB pixels.
    overwrite : bool
        Replace an existing file.
    inputs : iterable of path-like
        Files the run reads; never overwritten.

    Returns
    -------
    Path
    """
    rgb = as_rgb_uint8(image, name=str(path))
    path = Path(path)
    fmt = Image.registered_extensions().get(path.suffix.lower())
    if fmt is None:
        raise InputError(f"{path}: unknown image extension {path.suffix!r}")
    with atomic_output(path, overwrite=overwrite, inputs=inputs) as tmp:
        Image.fromarray(rgb).save(tmp, format=fmt)
    return path


def list_images(folder: str | os.PathLike) -> list[Path]:
    """Image files in a folder (not recursive), sorted by name.

    Raises
    ------
    InputError
        If the folder does not exist or holds no image.
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"{folder}: no such folder")
    files = sorted(p for p in folder.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS)
    if not files:
        raise InputError(f"{folder}: no image files ({', '.join(IMAGE_EXTENSIONS)}) in this folder")
    return files
