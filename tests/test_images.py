"""Tests of vehicle_detection.io.images: decoding files, checking arrays, writing and listing images."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from PIL import Image

from vehicle_detection.errors import InputError, OutputError
from vehicle_detection.io.images import as_rgb_uint8, decode_image, list_images, read_image, write_image

HYP = settings(deadline=None, max_examples=30, database=None)


def _picture(seed: int = 0, h: int = 64, w: int = 64) -> np.ndarray:
    """A smooth-ish RGB picture whose three channels differ clearly (so a swap is visible)."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    r = 200 * x / (w - 1) + 20  # left-to-right ramp, mean ~120
    g = 60 + 40 * np.sin(y / 6.0)  # horizontal stripes, mean ~60
    b = 230 - 30 * (x + y) / (h + w)  # bright, mean ~215
    img = np.stack([r, g, b], axis=-1) + rng.normal(0, 1.5, (h, w, 3))
    return np.clip(np.rint(img), 0, 255).astype(np.uint8)


def _save(img: Image.Image, path: Path, **kw) -> Path:
    img.save(path, **kw)
    return path


# --------------------------------------------------------------------------------------------
# read_image: PNG and JPEG agree
# --------------------------------------------------------------------------------------------
def test_png_and_jpeg_load_alike(tmp_path):
    src = _picture()
    png = _save(Image.fromarray(src), tmp_path / "pic.png")
    jpg = _save(Image.fromarray(src), tmp_path / "pic.jpg", quality=95)
    a, b = read_image(png), read_image(jpg)
    for img in (a, b):
        assert img.dtype == np.uint8
        assert img.shape == (64, 64, 3)
        assert img.min() >= 0 and img.max() <= 255
    np.testing.assert_array_equal(a, src)  # PNG is lossless
    diff = np.abs(a.astype(np.int16) - b.astype(np.int16))
    assert diff.mean() < 3
    # Same channel order: per-channel means match the source (and differ from each other).
    src_means = src.reshape(-1, 3).mean(axis=0)
    assert np.ptp(src_means) > 50  # the channels are distinguishable
    np.testing.assert_allclose(b.reshape(-1, 3).mean(axis=0), src_means, atol=2.0)
    np.testing.assert_allclose(a.reshape(-1, 3).mean(axis=0), src_means, atol=1e-9)


def test_pure_red_png_is_rgb_not_bgr(tmp_path):
    red = np.zeros((8, 10, 3), np.uint8)
    red[..., 0] = 255
    img = read_image(_save(Image.fromarray(red), tmp_path / "red.png"))
    assert img.shape == (8, 10, 3)
    assert (img[..., 0] == 255).all()
    assert (img[..., 1:] == 0).all()


def test_pure_red_jpeg_is_rgb_not_bgr(tmp_path):
    red = np.zeros((16, 16, 3), np.uint8)
    red[..., 0] = 255
    img = read_image(_save(Image.fromarray(red), tmp_path / "red.jpg", quality=95))
    assert img[..., 0].min() > 240
    assert img[..., 1:].max() < 15


# --------------------------------------------------------------------------------------------
# read_image: other modes
# --------------------------------------------------------------------------------------------
def test_grayscale_png_gives_three_equal_channels(tmp_path):
    grey = np.random.default_rng(1).integers(0, 256, (20, 30), dtype=np.uint8)
    path = _save(Image.fromarray(grey), tmp_path / "grey.png")
    assert Image.open(path).mode == "L"
    img = read_image(path)
    assert img.dtype == np.uint8 and img.shape == (20, 30, 3)
    for c in range(3):
        np.testing.assert_array_equal(img[..., c], grey)


def test_one_bit_png_gives_black_and_white(tmp_path):
    bits = np.random.default_rng(2).integers(0, 2, (12, 9)).astype(bool)
    img = read_image(_save(Image.fromarray(bits).convert("1"), tmp_path / "bits.png"))
    assert img.shape == (12, 9, 3)
    np.testing.assert_array_equal(img[..., 1], np.where(bits, 255, 0))
    np.testing.assert_array_equal(img[..., 0], img[..., 2])


def test_rgba_png_drops_alpha_without_blending(tmp_path):
    rng = np.random.default_rng(3)
    rgba = rng.integers(0, 256, (16, 24, 4), dtype=np.uint8)
    rgba[..., 3] = rng.integers(0, 256, (16, 24))  # varied alpha, including 0
    path = _save(Image.fromarray(rgba), tmp_path / "rgba.png")
    assert Image.open(path).mode == "RGBA"
    img = read_image(path)
    assert img.shape == (16, 24, 3)
    np.testing.assert_array_equal(img, rgba[..., :3])


def test_la_png_drops_alpha(tmp_path):
    la = np.random.default_rng(4).integers(0, 256, (10, 10, 2), dtype=np.uint8)
    path = _save(Image.fromarray(la), tmp_path / "la.png")
    assert Image.open(path).mode == "LA"
    img = read_image(path)
    for c in range(3):
        np.testing.assert_array_equal(img[..., c], la[..., 0])


def test_16bit_grayscale_png_scaled_by_257(tmp_path):
    rng = np.random.default_rng(5)
    v = rng.integers(0, 65536, (32, 40), dtype=np.uint16)
    v[0, :6] = [0, 128, 129, 257, 385, 65535]  # exact and half-way cases
    pil = Image.fromarray(v)
    assert pil.mode == "I;16"
    path = _save(pil, tmp_path / "deep.png")
    assert Image.open(path).mode.startswith("I")  # the file really is 16-bit
    img = read_image(path)
    # Reference: round half to even, as np.rint; 128/257 and 385/257 are not half-way.
    want = np.floor(v.astype(np.float64) / 257 + 0.5).astype(np.uint8)
    assert img.dtype == np.uint8 and img.shape == (32, 40, 3)
    for c in range(3):
        np.testing.assert_array_equal(img[..., c], want)
    assert list(img[0, :6, 0]) == [0, 0, 1, 1, 1, 255]


def test_palette_png_expanded(tmp_path):
    palette_colors = np.array([[255, 0, 0], [0, 255, 0], [0, 0, 255], [10, 20, 30]], np.uint8)
    idx = np.random.default_rng(6).integers(0, 4, (14, 11), dtype=np.uint8)
    pil = Image.frombytes("P", idx.shape[::-1], idx.tobytes())
    pal = np.zeros((256, 3), np.uint8)
    pal[:4] = palette_colors
    pil.putpalette(pal.ravel().tolist())
    path = _save(pil, tmp_path / "pal.png")
    assert Image.open(path).mode == "P"
    img = read_image(path)
    np.testing.assert_array_equal(img, palette_colors[idx])


def test_palette_png_with_transparency_drops_alpha(tmp_path):
    idx = np.array([[0, 1], [1, 0]], np.uint8)
    pil = Image.frombytes("P", idx.shape[::-1], idx.tobytes())
    pil.putpalette([9, 8, 7, 200, 100, 50] + [0] * (254 * 3))
    pil.info["transparency"] = 0
    path = tmp_path / "palt.png"
    pil.save(path, transparency=0)
    img = read_image(path)
    np.testing.assert_array_equal(img, np.array([[[9, 8, 7], [200, 100, 50]], [[200, 100, 50], [9, 8, 7]]], np.uint8))


def test_decode_image_from_bytes():
    src = _picture(7, 10, 12)
    buf = io.BytesIO()
    Image.fromarray(src).save(buf, format="PNG")
    np.testing.assert_array_equal(decode_image(buf.getvalue()), src)


# --------------------------------------------------------------------------------------------
# read_image: refusals name the file
# --------------------------------------------------------------------------------------------
def _encoded(fmt: str) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(_picture(8)).save(buf, format=fmt, **({"quality": 95} if fmt == "JPEG" else {}))
    return buf.getvalue()


@pytest.mark.parametrize(
    "name, content",
    [
        ("empty.png", b""),
        ("truncated.png", "png-half"),
        ("truncated.jpg", "jpeg-half"),
        ("notes.png", b"this is a text file, not a picture\n" * 5),
        ("garbage.jpg", bytes(range(256)) * 4),
    ],
)
def test_bad_files_raise_input_error_naming_the_file(tmp_path, name, content):
    if content == "png-half":
        data = _encoded("PNG")
        content = data[: len(data) // 2]
    elif content == "jpeg-half":
        data = _encoded("JPEG")
        content = data[: len(data) // 2]
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(InputError) as info:
        read_image(path)
    assert str(path) in str(info.value)


def test_missing_file_and_folder_raise_input_error(tmp_path):
    missing = tmp_path / "nope.png"
    with pytest.raises(InputError) as info:
        read_image(missing)
    assert str(missing) in str(info.value)
    folder = tmp_path / "dir.png"
    folder.mkdir()
    with pytest.raises(InputError) as info:
        read_image(folder)
    assert str(folder) in str(info.value)


def test_input_error_is_a_value_error():
    # Callers catching ValueError (the documented base) catch it too.
    with pytest.raises(ValueError):
        decode_image(b"", "x")


# --------------------------------------------------------------------------------------------
# as_rgb_uint8
# --------------------------------------------------------------------------------------------
@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.float16])
def test_float_arrays_refused_with_scale_hint(dtype):
    with pytest.raises(InputError) as info:
        as_rgb_uint8(np.zeros((4, 4, 3), dtype), name="frame")
    msg = str(info.value)
    assert "0-1" in msg and "0-255" in msg
    assert "frame" in msg


@pytest.mark.parametrize("dtype", [bool, np.int32, np.int8, np.int64, np.uint32, np.complex64])
def test_other_dtypes_refused(dtype):
    with pytest.raises(InputError) as info:
        as_rgb_uint8(np.zeros((4, 4, 3), dtype))
    assert f"got {np.dtype(dtype).name} of shape (4, 4, 3)" in str(info.value)  # the dtype given, named


@given(
    h=st.integers(1, 12),
    w=st.integers(1, 12),
    form=st.sampled_from(["hw", "hw1", "hw4"]),
    seed=st.integers(0, 2**32 - 1),
)
@HYP
def test_shapes_expanded_or_alpha_dropped(h, w, form, seed):
    rng = np.random.default_rng(seed)
    if form == "hw":
        a = rng.integers(0, 256, (h, w), dtype=np.uint8)
        want = np.stack([a, a, a], axis=-1)
    elif form == "hw1":
        a = rng.integers(0, 256, (h, w, 1), dtype=np.uint8)
        want = np.concatenate([a, a, a], axis=-1)
    else:
        a = rng.integers(0, 256, (h, w, 4), dtype=np.uint8)
        want = a[..., :3].copy()
    before = a.copy()
    out = as_rgb_uint8(a)
    assert out.dtype == np.uint8 and out.shape == (h, w, 3)
    np.testing.assert_array_equal(out, want)
    np.testing.assert_array_equal(a, before)  # input untouched


@given(shape=st.sampled_from([(5, 5, 3), (5, 5), (5, 5, 1), (5, 5, 4)]), seed=st.integers(0, 2**32 - 1))
@HYP
def test_uint16_scaled(shape, seed):
    v = np.random.default_rng(seed).integers(0, 65536, shape, dtype=np.uint16)
    out = as_rgb_uint8(v)
    ref = np.floor(v.astype(np.float64) / 257 + 0.5).astype(np.uint8)  # v/257 is never exactly x.5
    if ref.ndim == 2:
        ref = np.stack([ref] * 3, axis=-1)
    elif ref.shape[2] == 1:
        ref = np.concatenate([ref] * 3, axis=-1)
    else:
        ref = ref[..., :3]
    assert out.dtype == np.uint8 and out.shape == (5, 5, 3)
    np.testing.assert_array_equal(out, ref)


@pytest.mark.parametrize(
    "shape",
    [(5, 5, 2), (5, 5, 5), (5,), (2, 5, 5, 3), (1, 1, 1, 1), (0, 5, 3), (5, 0, 3), (0, 0), ()],
)
def test_bad_shapes_refused(shape):
    with pytest.raises(InputError) as info:
        as_rgb_uint8(np.zeros(shape, np.uint8), name="thing")
    assert "thing" in str(info.value)


def test_conforming_array_returned_without_copy():
    a = np.random.default_rng(9).integers(0, 256, (7, 9, 3), dtype=np.uint8)
    out = as_rgb_uint8(a)
    assert np.shares_memory(out, a)
    np.testing.assert_array_equal(out, a)
    view = a[::2, ::-1]  # non-contiguous, still conforming
    out = as_rgb_uint8(view)
    assert np.shares_memory(out, a)
    np.testing.assert_array_equal(out, view)


def test_python_int_lists_refused():
    with pytest.raises(InputError):
        as_rgb_uint8([[[1, 2, 3]]])  # a Python int list becomes int64: refused, not guessed


# --------------------------------------------------------------------------------------------
# write_image
# --------------------------------------------------------------------------------------------
def _partials(folder: Path) -> list[Path]:
    return [p for p in folder.rglob("*") if p.name.endswith(".partial")]


def test_write_png_round_trip_exact(tmp_path):
    src = _picture(10, 33, 47)
    out = write_image(tmp_path / "sub" / "out.png", src)
    assert out == tmp_path / "sub" / "out.png"
    # Read back with Pillow directly (independent of read_image) and with read_image.
    np.testing.assert_array_equal(np.asarray(Image.open(out).convert("RGB")), src)
    np.testing.assert_array_equal(read_image(out), src)
    assert _partials(tmp_path) == []


def test_write_jpeg_keeps_rgb_order(tmp_path):
    src = _picture(11)
    out = write_image(tmp_path / "out.JPG", src)
    back = read_image(out)
    np.testing.assert_allclose(back.reshape(-1, 3).mean(0), src.reshape(-1, 3).mean(0), atol=2.0)


def test_write_refuses_existing_unless_overwrite(tmp_path):
    a, b = _picture(12, 8, 8), _picture(13, 8, 8)
    path = write_image(tmp_path / "x.png", a)
    with pytest.raises(OutputError) as info:
        write_image(path, b)
    assert str(path) in str(info.value)
    np.testing.assert_array_equal(read_image(path), a)  # untouched
    write_image(path, b, overwrite=True)
    np.testing.assert_array_equal(read_image(path), b)
    assert _partials(tmp_path) == []


def test_write_refuses_overwriting_an_input(tmp_path):
    a = _picture(14, 8, 8)
    src = write_image(tmp_path / "in.png", a)
    # Even with overwrite=True, and under another spelling of the same path.
    for dest in (src, tmp_path / "." / "in.png"):
        with pytest.raises(OutputError):
            write_image(dest, a[::-1], overwrite=True, inputs=[src])
    np.testing.assert_array_equal(read_image(src), a)
    assert _partials(tmp_path) == []


def test_write_refuses_bad_arrays_and_extensions_leaving_nothing(tmp_path):
    with pytest.raises(InputError):
        write_image(tmp_path / "f.png", np.zeros((4, 4, 3), np.float32))
    with pytest.raises(OutputError):  # an output that cannot be written (exit 5 on the command line)
        write_image(tmp_path / "f.notanimage", np.zeros((4, 4, 3), np.uint8))
    assert list(tmp_path.iterdir()) == []


def test_write_failure_leaves_no_partial(tmp_path, monkeypatch):
    def boom(self, *a, **k):
        raise RuntimeError("disk on fire")

    monkeypatch.setattr(Image.Image, "save", boom)
    with pytest.raises(RuntimeError):
        write_image(tmp_path / "f.png", np.zeros((4, 4, 3), np.uint8))
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------------------------
# list_images
# --------------------------------------------------------------------------------------------
def test_list_images_sorted_and_filtered(tmp_path):
    tiny = Image.fromarray(np.zeros((2, 2, 3), np.uint8))
    for name in ["b.png", "a.jpg", "c.JPEG", "d.bmp", "e.tif", "f.webp"]:
        tiny.save(tmp_path / name)
    (tmp_path / "notes.txt").write_text("x")
    (tmp_path / "README").write_text("x")
    (tmp_path / "folder.png").mkdir()
    (tmp_path / "folder.png" / "inner.png").write_bytes(b"")
    got = list_images(tmp_path)
    assert [p.name for p in got] == ["a.jpg", "b.png", "c.JPEG", "d.bmp", "e.tif", "f.webp"]
    assert all(p.parent == tmp_path for p in got)


def test_list_images_empty_or_missing_folder(tmp_path):
    (tmp_path / "only.txt").write_text("x")
    with pytest.raises(InputError) as info:
        list_images(tmp_path)
    assert str(tmp_path) in str(info.value)
    missing = tmp_path / "missing"
    with pytest.raises(InputError) as info:
        list_images(missing)
    assert str(missing) in str(info.value)
    a_file = tmp_path / "only.txt"
    with pytest.raises(InputError):
        list_images(a_file)


def test_pillow_global_setting_is_left_alone_and_the_pixel_limit_holds(tmp_path, monkeypatch):
    import PIL.Image

    import vehicle_detection.io.images as images

    assert PIL.Image.MAX_IMAGE_PIXELS == 89_478_485  # Pillow's own default, untouched by the import
    monkeypatch.setattr(images, "MAX_IMAGE_PIXELS", 100 * 100 - 1)
    path = tmp_path / "square.png"
    PIL.Image.new("RGB", (100, 100)).save(path)
    with pytest.raises(InputError, match="square.png: image of 100x100 pixels is larger than 9,999 pixels"):
        read_image(path)
