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
EXIF orientation tag      applied (rotated / mirrored upright), as browsers and
                          ``PIL.ImageOps.exif_transpose`` do
========================  ==========================================================

Frame shapes are checked before the pixels are decoded (:func:`check_frame_shape`): the search
scales every frame to 720 pixels high keeping its shape, so a 20000x50 picture (3 KB as a PNG)
would need gigabytes. Frames wider than 8:1 or taller than 1:4 (width:height) are refused, and so
is any frame larger than 720 x 5760 pixels once scaled to the search height. Pillow's
decompression-bomb limit (100 megapixels) applies as well.

Arrays passed to the public API go through :func:`as_rgb_uint8`, which applies the same rules to
arrays (and refuses floats), so that a BGR/float/grey mix-up fails loudly instead of silently
producing garbage features. Files are read and written with Pillow (RGB); OpenCV, with its BGR
order, decodes only 16-bit colour files, and its output is reordered to RGB at once.
"""

from __future__ import annotations

import functools
import io
import warnings
import os
from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError

from ._files import atomic_output, input_file
from ..errors import InputError, OutputError, shorten

__all__ = [
    "IMAGE_EXTENSIONS",
    "image_size",
    "MAX_WIDTH_TO_HEIGHT",
    "MAX_HEIGHT_TO_WIDTH",
    "SEARCH_HEIGHT",
    "MAX_SCALED_PIXELS",
    "check_frame_shape",
    "check_image_output",
    "read_image",
    "decode_image",
    "as_rgb_uint8",
    "as_image",
    "write_image",
    "list_images",
]

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".webp")

#: What an image array must be, for messages (grey (H, W) and (H, W, 1), RGBA and uint16 are converted).
EXPECTED_IMAGE = "expected an RGB uint8 image of shape (H, W, 3)"

#: Largest image, in pixels, decoded (decompression bombs). Checked here, image by image, rather
#: than by changing Pillow's global ``Image.MAX_IMAGE_PIXELS`` for the whole process.
MAX_IMAGE_PIXELS = 100_000_000

#: Widest accepted frame, width / height (a 1280x720 dashcam frame is 1.78; a 360-degree
#: panorama strip 6 to 8).
MAX_WIDTH_TO_HEIGHT = 8
#: Tallest accepted frame, height / width (a phone video shot upright is 1.78).
MAX_HEIGHT_TO_WIDTH = 4
#: Height every frame is scaled to before the search (:attr:`SearchPlan.reference_height`).
SEARCH_HEIGHT = 720
#: Largest frame once scaled to ``reference_height`` (default: 720 x 5760, the widest frame).
MAX_SCALED_PIXELS = SEARCH_HEIGHT * SEARCH_HEIGHT * MAX_WIDTH_TO_HEIGHT


def check_frame_shape(height: int, width: int, name: str = "image", *, reference_height: int = SEARCH_HEIGHT) -> None:
    """Refuse a frame whose shape would make the search use unbounded memory.

    The search scales every frame to ``reference_height`` pixels high keeping its shape, so
    memory grows with the width-to-height ratio, not with the file's size: a 100000x1 PNG would
    become 72 million x 720 pixels. Call this before decoding (images) or before the first frame
    (videos: :func:`vehicle_detection.io.video.probe_video` gives the size).

    Parameters
    ----------
    height, width : int
        The upright frame size in pixels.
    name : str
        The file, for the message.
    reference_height : int
        Height the frame will be scaled to (720 by default).

    Raises
    ------
    InputError
        If a side is < 1, the frame is wider than ``MAX_WIDTH_TO_HEIGHT``:1 or taller than
        1:``MAX_HEIGHT_TO_WIDTH``, or it exceeds ``MAX_SCALED_PIXELS`` once scaled.
    """
    height, width = int(height), int(width)
    if height < 1 or width < 1:
        raise InputError(f"{name}: empty image of {width}x{height} pixels")
    if width > MAX_WIDTH_TO_HEIGHT * height:
        raise InputError(
            f"{name}: image of {width}x{height} pixels is too wide (more than {MAX_WIDTH_TO_HEIGHT}:1); crop it first"
        )
    if height > MAX_HEIGHT_TO_WIDTH * width:
        raise InputError(
            f"{name}: image of {width}x{height} pixels is too tall (more than 1:{MAX_HEIGHT_TO_WIDTH}); crop it first"
        )
    scaled_width = max(1, round(width * reference_height / height))
    if scaled_width * reference_height > MAX_SCALED_PIXELS:
        raise InputError(
            f"{name}: image of {width}x{height} pixels would be {scaled_width}x{reference_height} once scaled "
            f"to the search height, more than {MAX_SCALED_PIXELS} pixels"
        )


# EXIF orientation (tag 0x0112) -> how to turn the stored pixels upright.
_ORIENTATION_TAG = 0x0112


def _exif_orientation(img: Image.Image) -> int:
    try:
        value = int(img.getexif().get(_ORIENTATION_TAG, 1))
    except Exception:  # a damaged EXIF block does not make the pixels unreadable
        return 1
    return value if 1 <= value <= 8 else 1


def image_size(path: str | os.PathLike) -> tuple[int, int]:
    """``(width, height)`` of an image file as :func:`read_image` would return it (EXIF
    orientation applied), from its header: no pixel is decoded.

    Raises
    ------
    InputError
        If the file cannot be opened as an image.
    """
    try:
        with Image.open(path) as img:
            w, h = img.size
            return (h, w) if _exif_orientation(img) >= 5 else (w, h)
    except (OSError, ValueError, Image.DecompressionBombError) as exc:
        raise InputError(f"{path}: not a readable image ({shorten(str(exc))})") from None


def _orient(arr: np.ndarray, orientation: int) -> np.ndarray:
    """Pixels stored with EXIF ``orientation`` turned upright (what exif_transpose shows)."""
    if orientation == 2:
        arr = arr[:, ::-1]
    elif orientation == 3:
        arr = arr[::-1, ::-1]
    elif orientation == 4:
        arr = arr[::-1]
    elif orientation == 5:
        arr = arr.swapaxes(0, 1)
    elif orientation == 6:
        arr = arr.swapaxes(0, 1)[:, ::-1]
    elif orientation == 7:
        arr = arr[::-1, ::-1].swapaxes(0, 1)
    elif orientation == 8:
        arr = arr.swapaxes(0, 1)[::-1]
    else:
        return arr
    return np.ascontiguousarray(arr)


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
    import cv2  # only for these rare files: reading an image otherwise needs Pillow alone

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
        If the bytes are empty, truncated, or not an image Pillow can read, or the shape is
        refused by :func:`check_frame_shape` (checked before the pixels are decoded).
    """
    if not data:
        raise InputError(f"{name}: empty file, not an image")
    try:
        with warnings.catch_warnings():
            # Pillow warns above its own limit; ours is below, checked just after.
            warnings.simplefilter("ignore", Image.DecompressionBombWarning)
            img = Image.open(io.BytesIO(data))
        with img:
            stored_size = img.size
            width, height = stored_size
            if width * height > MAX_IMAGE_PIXELS:
                raise InputError(f"{name}: image of {width}x{height} pixels is larger than {MAX_IMAGE_PIXELS:,} pixels")
            # Before the pixels are decoded. A PNG may keep its EXIF after the pixels (Pillow
            # would decode them to find it): then only the shapes refused either way round.
            if img.format != "PNG" or "exif" in img.info:
                file_orientation = _exif_orientation(img)
                if file_orientation >= 5:  # stored sideways
                    width, height = height, width
                check_frame_shape(height, width, name)
            else:
                file_orientation = 1
                if max(width, height) > MAX_WIDTH_TO_HEIGHT * min(width, height):
                    check_frame_shape(height, width, name)
            img.load()  # Pillow checks the whole file (truncation) first
            # What is left to apply: Pillow turns TIFFs upright itself while loading (and drops
            # the tag); a PNG's eXIf chunk after the pixels is only known now.
            orientation = _exif_orientation(img)
            if file_orientation == 1:
                file_orientation = orientation
            arr = None
            if _is_16bit_colour(img, data):
                raw = _decode_16bit_colour(data, stored_size)  # OpenCV: stored orientation
                if raw is not None:
                    arr = _orient(as_rgb_uint8(raw, name=name), file_orientation)  # round(v / 257)
            if arr is None:
                arr = _orient(_from_pil(img, name), orientation)
        check_frame_shape(arr.shape[0], arr.shape[1], name)
        return arr
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
    if path.exists():  # a device (/dev/zero) or a FIFO would be read forever, or block
        input_file(path, "image file")
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
        ``uint8`` or ``uint16`` array of shape (H, W), (H, W, 1), (H, W, 3) or (H, W, 4): a grey
        image, (H, W) or (H, W, 1), has its grey value copied to R, G and B; RGBA has its alpha
        dropped; uint16 is scaled to 8 bits (the rules of the module docstring).
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
        (a ``ValueError``) Float, bool or signed arrays, wrong number of dimensions or channels,
        naming the dtype and shape expected and given; empty images, or images of more than
        ``MAX_IMAGE_PIXELS`` (100 million) pixels.

    Examples
    --------
    >>> as_rgb_uint8(np.zeros((2, 3), np.uint8)).shape
    (2, 3, 3)
    >>> as_rgb_uint8(np.zeros((480, 640)))
    Traceback (most recent call last):
    ...
    vehicle_detection.errors.InputError: image: expected an RGB uint8 image of shape (H, W, 3), got float64 of shape (480, 640) (0-1 versus 0-255 is ambiguous; scale and convert to uint8 yourself)
    """
    arr = np.asarray(image)
    if arr.ndim >= 2 and arr.shape[0] * arr.shape[1] > MAX_IMAGE_PIXELS:  # before any copy
        raise InputError(f"{name}: image of {arr.shape[1]}x{arr.shape[0]} pixels is larger than {MAX_IMAGE_PIXELS:,} pixels")
    if arr.dtype not in (np.uint8, np.uint16) or not (arr.ndim == 2 or (arr.ndim == 3 and arr.shape[2] in (1, 3, 4))):
        hint = " (0-1 versus 0-255 is ambiguous; scale and convert to uint8 yourself)" if arr.dtype.kind == "f" else ""
        raise InputError(f"{name}: {EXPECTED_IMAGE}, got {arr.dtype} of shape {arr.shape}{hint}")
    if arr.dtype == np.uint16:
        arr = np.rint(arr.astype(np.float32) / 257.0).astype(np.uint8)
    if arr.ndim == 2:
        arr = np.repeat(arr[:, :, None], 3, axis=2)
    elif arr.shape[2] == 1:
        arr = np.repeat(arr, 3, axis=2)
    elif arr.shape[2] == 4:
        arr = np.ascontiguousarray(arr[:, :, :3])
    if arr.shape[0] == 0 or arr.shape[1] == 0:
        raise InputError(f"{name}: empty image of shape {arr.shape}")
    return arr


def as_image(image, *, name: str = "image") -> np.ndarray:
    """An image given as a file path, a Pillow image or an array, as RGB ``uint8`` ``(H, W, 3)``.

    What :meth:`~vehicle_detection.detector.Detector.detect_image` accepts: the one conversion at
    the API edge.

    Parameters
    ----------
    image : str, path-like, PIL.Image.Image or array_like
        A file path is read with :func:`read_image`; a Pillow image is converted by the rules of
        the module docstring (its EXIF orientation applied, as :func:`read_image` does); an array
        goes through :func:`as_rgb_uint8`.
    name : str
        Used in error messages for Pillow images and arrays.

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)

    Raises
    ------
    InputError
        If the file cannot be read as an image, the image breaks the rules above, or ``image`` is
        none of these types (bytes, say: decode them with :func:`decode_image`).

    Examples
    --------
    >>> from PIL import Image
    >>> as_image(Image.new("L", (64, 32), 200)).shape
    (32, 64, 3)
    """
    if isinstance(image, (str, os.PathLike)):
        return read_image(image)
    if isinstance(image, Image.Image):
        try:
            arr = _orient(_from_pil(image, name), _exif_orientation(image))
        except (OSError, SyntaxError) as exc:  # a lazily opened file that is truncated or corrupt
            raise InputError(f"{name}: corrupt or truncated image: {exc}") from None
        check_frame_shape(arr.shape[0], arr.shape[1], name)
        return arr
    if isinstance(image, (bytes, bytearray, memoryview)):
        raise InputError(f"{name}: got {type(image).__name__}; pass a file path, a PIL image or an array (decode_image decodes bytes)")
    if not isinstance(image, np.ndarray) and not hasattr(image, "__array__") and not isinstance(image, (list, tuple)):
        raise InputError(
            f"{name}: expected an RGB uint8 array of shape (H, W, 3), a PIL image or an image file path; got {type(image).__name__}"
        )
    return as_rgb_uint8(image, name=name)


@functools.lru_cache(maxsize=None)
def _writable_rgb_format(fmt: str) -> str | None:
    """None if Pillow can write an RGB image as ``fmt``, else why not."""
    try:
        Image.new("RGB", (8, 8)).save(io.BytesIO(), format=fmt)
    except KeyError:
        return "Pillow can read this format but not write it"
    except Exception as exc:  # "cannot write mode RGB as XBM", "HDF5 save handler not installed"
        return str(exc) or type(exc).__name__
    return None


def check_image_output(path: str | os.PathLike) -> str:
    """The Pillow format an RGB image written to ``path`` would have; refuse if there is none.

    Checked from the extension (case-insensitive) with a trial write of a tiny RGB image to
    memory, so that an extension Pillow reads but cannot write (``.xbm``, ``.h5``, ``.psd``) is
    refused before any work.

    Raises
    ------
    OutputError
        Unknown extension, or a format Pillow cannot write in RGB.
    """
    path = Path(path)
    fmt = Image.registered_extensions().get(path.suffix.lower())
    if fmt is None:
        raise OutputError(f"{path}: unknown image extension {path.suffix!r}; use .png or .jpg")
    why = _writable_rgb_format(fmt)
    if why is not None:
        raise OutputError(f"{path}: cannot write {fmt} images ({why}); use .png or .jpg")
    return fmt


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

    Raises
    ------
    InputError
        If ``image`` is not an image array (see :func:`as_rgb_uint8`).
    OutputError
        If the extension is not a format Pillow can write (:func:`check_image_output`), the
        output is refused (:func:`vehicle_detection.io.check_output_path`), or writing
        fails (disk full, ...); the message names ``path``.
    """
    rgb = as_rgb_uint8(image, name=str(path))
    path = Path(path)
    fmt = check_image_output(path)
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
