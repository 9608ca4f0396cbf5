"""Bad input, one case each: images, videos, outputs, models, downloads; interrupted runs; properties.

Every case asserts the exact outcome: the exception type and that its message names the file and
the problem, or the exact converted result. The kill tests run ``vehicle-detection detect`` in a
subprocess and stop it midway with SIGKILL and with SIGINT (Ctrl-C).

No test reaches the network: downloads go to a loopback server, and an autouse fixture refuses any
other connection.
"""

from __future__ import annotations

import hashlib
import io
import json
import os
import pickle
import signal
import socket
import struct
import subprocess
import sys
import threading
import time
import zipfile
import zlib
from fractions import Fraction
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from PIL import Image

import media
from vehicle_detection import __version__
from vehicle_detection.io._files import PARTIAL_SUFFIX, atomic_output, check_output_path
from vehicle_detection.io.tables import BOXES_CSV_HEADER, read_boxes_csv
from vehicle_detection.classifier import VehicleClassifier, _digest, default_model_path
from vehicle_detection.errors import DownloadError, InputError, ModelError, OutputError
from vehicle_detection.metrics.detection import Annotations, FrameLabels, evaluate_detections
from vehicle_detection.features import FEATURE_FORMAT, FeatureConfig, extract_features
from vehicle_detection.heatmap import add_heat, heat_to_boxes, label_heat
from vehicle_detection.io.images import as_rgb_uint8, decode_image, read_image, write_image
from vehicle_detection.config import DetectorConfig
from vehicle_detection.detections import Detections
from vehicle_detection.pipeline import process_video
from vehicle_detection.tracker import Tracker, TrackerConfig
from vehicle_detection.io.video import probe_video, read_frames

REPO = Path(__file__).resolve().parents[1]
TEST_VIDEO = REPO / "test_video.mp4"
HYP = settings(deadline=None, max_examples=int(os.environ.get("HYP_EXAMPLES", 40)), database=None, suppress_health_check=[HealthCheck.too_slow])

needs_test_video = pytest.mark.skipif(not TEST_VIDEO.is_file(), reason="test_video.mp4 not in the checkout")
posix_only = pytest.mark.skipif(sys.platform == "win32", reason="POSIX signals and /proc")


# ----------------------------------------------------------------------------------------------
# helpers
# ----------------------------------------------------------------------------------------------


@pytest.fixture(autouse=True)
def _no_network(monkeypatch):
    """Refuse every connection that is not to this machine (the tests must never need a network)."""
    real_connect = socket.socket.connect

    def connect(self, address):
        host = address[0] if isinstance(address, tuple) else address
        if self.family in (socket.AF_INET, socket.AF_INET6) and host not in ("127.0.0.1", "::1", "localhost"):
            raise ConnectionRefusedError(f"test tried to reach the network: {address!r}")
        return real_connect(self, address)

    real_getaddrinfo = socket.getaddrinfo

    def getaddrinfo(host, *args, **kwargs):  # no DNS query either
        if host not in ("127.0.0.1", "::1", "localhost", None):
            raise socket.gaierror(socket.EAI_NONAME, f"test tried to look up {host!r}")
        return real_getaddrinfo(host, *args, **kwargs)

    monkeypatch.setattr(socket.socket, "connect", connect)
    monkeypatch.setattr(socket, "getaddrinfo", getaddrinfo)
    monkeypatch.setenv("no_proxy", "*")
    for var in ("http_proxy", "https_proxy", "HTTP_PROXY", "HTTPS_PROXY"):
        monkeypatch.delenv(var, raising=False)


def sha256(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def png_bytes(arr: np.ndarray, color_type: int, bit_depth: int = 16) -> bytes:
    """A PNG written by hand (no library in the loop): ``arr`` (H, W, samples) as stored."""
    arr = np.asarray(arr)
    if arr.ndim == 2:
        arr = arr[:, :, None]
    h, w = arr.shape[:2]
    dtype = ">u2" if bit_depth == 16 else "u1"
    raw = b"".join(b"\x00" + arr[y].astype(dtype).tobytes() for y in range(h))

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", w, h, bit_depth, color_type, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")


def picture(h: int = 48, w: int = 64, seed: int = 0) -> np.ndarray:
    """RGB uint8 picture whose channels differ clearly, so that a channel swap would show."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w]
    img = np.stack([20 + 200 * x // w, 60 + 40 * (y % 7), 230 - x // 4], axis=-1) + rng.integers(0, 3, (h, w, 3))
    return np.clip(img, 0, 255).astype(np.uint8)


def assert_error(excinfo, path: Path | str, *fragments: str) -> str:
    """The message starts with the file's name and contains every fragment (the problem)."""
    msg = str(excinfo.value)
    assert msg.startswith(f"{path}: "), msg
    for fragment in fragments:
        assert fragment in msg, (fragment, msg)
    return msg


# ----------------------------------------------------------------------------------------------
# Images: converted by the documented rules, or refused naming the file and the problem
# ----------------------------------------------------------------------------------------------


def test_grayscale_png_becomes_grey_rgb(tmp_path):
    grey = np.random.default_rng(1).integers(0, 256, (9, 13), dtype=np.uint8)
    path = tmp_path / "grey.png"
    Image.fromarray(grey).save(path)
    img = read_image(path)
    assert img.dtype == np.uint8 and img.shape == (9, 13, 3)
    for c in range(3):
        np.testing.assert_array_equal(img[:, :, c], grey)


def test_rgba_png_drops_alpha_without_blending(tmp_path):
    rgba = np.random.default_rng(2).integers(0, 256, (7, 11, 4), dtype=np.uint8)
    rgba[0, 0, 3] = 0  # fully transparent pixel: its colour is kept, not blended with anything
    path = tmp_path / "rgba.png"
    Image.fromarray(rgba).save(path)
    np.testing.assert_array_equal(read_image(path), rgba[:, :, :3])


@pytest.mark.parametrize(
    ("color_type", "samples", "keep"),
    [(0, 1, [0, 0, 0]), (2, 3, [0, 1, 2]), (4, 2, [0, 0, 0]), (6, 4, [0, 1, 2])],
    ids=["grey16", "rgb16", "grey_alpha16", "rgba16"],
)
def test_16bit_png_scaled_by_257_in_rgb_order(tmp_path, color_type, samples, keep):
    # Every 16-bit kind follows the documented rule round(v / 257) (Pillow alone would cut
    # colour samples to their high byte); values chosen where the two rules differ.
    rng = np.random.default_rng(color_type)
    stored = rng.integers(0, 65536, (5, 6, samples), dtype=np.uint16)
    stored[0, 0, 0] = 386  # round(386 / 257) = 2, 386 >> 8 = 1
    path = tmp_path / f"sixteen_{color_type}.png"
    path.write_bytes(png_bytes(stored, color_type))
    img = read_image(path)
    expected = np.rint(stored[:, :, keep].astype(np.float64) / 257).astype(np.uint8)
    np.testing.assert_array_equal(img, expected)


def test_bgr_rgb_boundary(tmp_path):
    # A file written by OpenCV (BGR in memory) reads back as RGB; a written image is RGB on disk.
    red_bgr = np.zeros((4, 5, 3), np.uint8)
    red_bgr[..., 2] = 255
    cv2.imwrite(str(tmp_path / "red.png"), red_bgr)
    np.testing.assert_array_equal(read_image(tmp_path / "red.png")[0, 0], [255, 0, 0])
    pic = picture()
    write_image(tmp_path / "pic.png", pic)
    np.testing.assert_array_equal(cv2.imread(str(tmp_path / "pic.png"))[..., ::-1], pic)
    # Arrays cannot be told apart by content: the documented rule is "RGB", and float arrays
    # (the usual sign of an unconverted OpenCV/matplotlib image) are refused, not guessed.
    with pytest.raises(InputError) as info:
        as_rgb_uint8(pic.astype(np.float32) / 255, name="frame 3")
    assert_error(info, "frame 3", "expected an RGB uint8 image of shape (H, W, 3), got float32 of shape (48, 64, 3)", "ambiguous")


def test_wrong_patch_size_for_the_classifier_refused():
    cfg = FeatureConfig()
    for shape in [(32, 32, 3), (64, 63, 3), (1, 65, 64, 3)]:
        with pytest.raises(InputError) as info:
            extract_features(np.zeros(shape, np.uint8), cfg)
        h, w = shape[-3], shape[-2]
        assert f"patches must be 64x64 pixels for this model, got {h}x{w}" in str(info.value)
    with pytest.raises(InputError, match=r"expected RGB uint8 patches of shape \(N, 64, 64, 3\), got uint8 \(64, 64\)"):
        extract_features(np.zeros((64, 64), np.uint8), cfg)  # 2-D: one grey patch or a row of them?


def test_wrong_patch_size_in_training_archive_names_the_member(tmp_path):
    from vehicle_detection.training.data import load_dataset

    good, small = io.BytesIO(), io.BytesIO()
    Image.fromarray(picture(64, 64)).save(good, format="PNG")
    Image.fromarray(picture(32, 48)).save(small, format="PNG")
    for cls, data in (("vehicles", small.getvalue()), ("non-vehicles", good.getvalue())):
        with zipfile.ZipFile(tmp_path / f"{cls}.zip", "w") as zf:
            zf.writestr(f"{cls}/set/image1.png", good.getvalue())
            zf.writestr(f"{cls}/set/image2.png", data)
    with pytest.raises(InputError) as info:
        load_dataset(tmp_path)
    assert_error(info, tmp_path / "vehicles/set/image2.png", "training patches must be 64x64, got 48x32")


def test_empty_png_refused(tmp_path):
    path = tmp_path / "empty.png"
    path.write_bytes(b"")
    with pytest.raises(InputError) as info:
        read_image(path)
    assert_error(info, path, "empty file, not an image")


@pytest.mark.parametrize("suffix", [".png", ".jpg"])
def test_truncated_image_refused(tmp_path, suffix):
    whole = tmp_path / f"whole{suffix}"
    Image.fromarray(picture(120, 160)).save(whole)
    data = whole.read_bytes()
    path = tmp_path / f"cut{suffix}"
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError) as info:
        read_image(path)
    assert_error(info, path, "corrupt or truncated image")


@pytest.mark.parametrize("content", [b"just some text\n", b"\x00\x00\x00\x18ftypmp42" + bytes(200)], ids=["text", "mp4"])
def test_non_image_named_png_refused(tmp_path, content):
    path = tmp_path / "photo.png"
    path.write_bytes(content)
    with pytest.raises(InputError) as info:
        read_image(path)
    assert_error(info, path, "not an image")


def test_decode_bytes_names_the_source():
    with pytest.raises(InputError) as info:
        decode_image(png_bytes(np.zeros((8, 8), np.uint8), 0, 8)[:45], "vehicles.zip:vehicles/x.png")
    assert_error(info, "vehicles.zip:vehicles/x.png", "corrupt or truncated image")


# ----------------------------------------------------------------------------------------------
# Videos
# ----------------------------------------------------------------------------------------------


def test_missing_video(tmp_path):
    with pytest.raises(InputError) as info:
        probe_video(tmp_path / "gone.mp4")
    assert_error(info, tmp_path / "gone.mp4", "no such file")


def test_empty_video(tmp_path):
    path = tmp_path / "empty.mp4"
    path.write_bytes(b"")
    with pytest.raises(InputError) as info:
        read_frames(path)
    assert_error(info, path, "file is empty")


def test_corrupt_video_refused(tmp_path):
    path = tmp_path / "noise.mp4"
    path.write_bytes(np.random.default_rng(0).integers(0, 256, 50_000, dtype=np.uint8).tobytes())
    with pytest.raises(InputError) as info:
        read_frames(path)
    assert_error(info, path, "not a readable video file")


def test_zero_frame_video_refused(tmp_path):
    path = tmp_path / "zero.mp4"
    media.encode(path, [])  # the MP4 muxer leaves a track without samples out
    with pytest.raises(InputError) as info:
        read_frames(path)
    assert_error(info, path, "contains no video stream")


@needs_test_video
def test_truncated_video_leaves_no_output(tmp_path):
    data = TEST_VIDEO.read_bytes()
    path = tmp_path / "cut.mp4"
    path.write_bytes(data[: len(data) // 4])
    before = sha256(path)
    with pytest.raises(InputError) as info:
        process_video(path, tmp_path / "out.mp4", detector=fast_probe(), tables={"csv": tmp_path / "out.csv"}, progress=False)
    assert_error(info, path, "video is damaged or truncated: decoded", "of the 38 frames")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["cut.mp4"]  # no video, CSV or .partial
    assert sha256(path) == before


def fast_probe():
    """A real :class:`Detector` searching one small band (fast), that reports one box per frame
    whose width encodes the frame's pixels, so that every CSV row can be traced to the frame it
    was computed from. The frame index is the real tracker's, as in normal runs."""
    from vehicle_detection.detector import Detector
    from vehicle_detection.search import SearchPlan, SearchScale

    def relabel(frame, index):
        box = np.array([[0, 0, content_code(frame) + 1, 1]], np.int64)
        return Detections(box, score=[0.5], track_id=[7], frame=index)

    class FastProbe(Detector):
        def step(self, frame, tracker):
            super().step(frame, tracker)
            return relabel(frame, tracker.state.frame_index - 1)

        def track_frames(self, frames, tracker=None, **kwargs):
            for index, (frame, _) in enumerate(super().track_frames(frames, tracker, **kwargs)):
                yield frame, relabel(frame, index)

    plan = SearchPlan(scales=(SearchScale(1.0, 400, 464, x_stop=192),))
    return FastProbe(config=DetectorConfig(plan=plan))


def content_code(frame: np.ndarray) -> int:
    return zlib.crc32(np.ascontiguousarray(frame).tobytes()) % 100_000


def check_frame_indices(video: Path, csv: Path) -> list[np.ndarray]:
    """Row k of the CSV is decoded frame k: its index and the pixels it was computed from."""
    decoded = list(read_frames(video))
    table = read_boxes_csv(csv)
    assert csv.read_text().splitlines()[0] == BOXES_CSV_HEADER
    assert table.frame.tolist() == list(range(len(decoded)))
    assert (table.xyxy[:, 2] - 1).tolist() == [content_code(f) for f in decoded]
    return decoded


def test_variable_frame_rate_csv_frames_are_decoded_frames(tmp_path):
    path = tmp_path / "vfr.mp4"
    # 25 frames with 5 dropped (a gap) and a timestamp jump after frame 12.
    kept = [n for n in range(25) if not 5 <= n <= 9]
    pts = [4 * n + (37 if i > 12 else 0) for i, n in enumerate(kept)]  # in 1/100 s
    media.encode(path, media.moving_square_frames(25, 96, 64)[:20], pts=pts, time_base=Fraction(1, 100))
    out, csv = tmp_path / "out.mp4", tmp_path / "out.csv"
    table = process_video(path, out, detector=fast_probe(), tables={"csv": csv}, progress=False)
    decoded = check_frame_indices(path, csv)
    assert len(decoded) == 20  # nothing duplicated or dropped to fit a constant rate
    assert len(table) == 20
    assert probe_video(out).n_frames == 20  # one output frame per decoded frame


def test_odd_size_h264_video(tmp_path):
    path = tmp_path / "odd.mp4"  # 321x241: H.264 in 4:4:4 allows odd sizes, 4:2:0 output does not
    media.encode(path, media.moving_square_frames(4, 321, 241), pix_fmt="yuv444p")
    assert probe_video(path).size == (321, 241)
    out, csv = tmp_path / "out.mp4", tmp_path / "out.csv"
    process_video(path, out, detector=fast_probe(), tables={"csv": csv}, progress=False)
    check_frame_indices(path, csv)
    info = probe_video(out)
    assert info.size == (322, 242) and info.n_frames == 4  # padded to even, every frame kept


# ----------------------------------------------------------------------------------------------
# Outputs
# ----------------------------------------------------------------------------------------------


@pytest.mark.parametrize("spelling", ["dotted", "symlink", "hardlink"])
def test_output_resolving_to_the_input_refused(tmp_path, spelling):
    src = tmp_path / "in.png"
    write_image(src, picture())
    before = sha256(src)
    if spelling == "dotted":
        dest = tmp_path / "sub" / ".." / "in.png"
        (tmp_path / "sub").mkdir()
    elif spelling == "symlink":
        dest = tmp_path / "link.png"
        dest.symlink_to(src)
    else:
        dest = tmp_path / "hard.png"
        os.link(src, dest)
    with pytest.raises(OutputError) as info:
        write_image(dest, picture(seed=5), overwrite=True, inputs=[src])
    assert_error(info, dest, "output would overwrite the input")
    assert sha256(src) == before


def test_failed_write_leaves_neither_file_nor_partial(tmp_path):
    dest = tmp_path / "new" / "deeper" / "out.csv"  # missing folders are created
    with pytest.raises(KeyboardInterrupt):
        with atomic_output(dest) as tmp:
            tmp.write_text("frame,x1\n0,")
            raise KeyboardInterrupt
    assert dest.parent.is_dir() and list(dest.parent.iterdir()) == []
    with atomic_output(dest) as tmp:
        tmp.write_text("done\n")
    assert dest.read_text() == "done\n"
    with pytest.raises(OutputError) as info:
        check_output_path(dest)
    assert_error(info, dest, "output exists; pass overwrite=True")  # the Python API's words
    from vehicle_detection.errors import cli_message

    assert "output exists; pass --overwrite" in cli_message(info.value)  # the command line's


@pytest.mark.skipif(not hasattr(signal, "SIGINT") or os.name != "posix", reason="POSIX signals")
def test_a_signal_while_the_output_file_is_made_leaves_no_partial(tmp_path, monkeypatch):
    # Ctrl-C landing just after the temporary file exists, before its clean-up is in place.
    from vehicle_detection.io import _files

    made = []
    real = _files.tempfile.mkstemp

    def mkstemp_then_ctrl_c(*args, **kwargs):
        fd, name = real(*args, **kwargs)
        made.append(name)
        os.kill(os.getpid(), signal.SIGINT)  # its handler runs at the next bytecode
        return fd, name

    monkeypatch.setattr(_files.tempfile, "mkstemp", mkstemp_then_ctrl_c)
    dest = tmp_path / "out.csv"
    with pytest.raises(KeyboardInterrupt):
        with _files.interrupt_on_signals(), atomic_output(dest) as tmp:
            tmp.write_text("never written\n")
    assert made and list(tmp_path.iterdir()) == []


def test_video_failing_at_the_end_takes_the_csv_with_it(tmp_path, monkeypatch):
    # The CSV is renamed into place just before the video; if finishing the video then fails
    # (here: the encoder cannot write its index), neither may be left looking finished.
    from vehicle_detection.io import video as video_module

    src = tmp_path / "in.mp4"
    media.encode(src, media.moving_square_frames(3, 96, 64))

    def broken_finish(self):
        raise OutputError(f"{self.path}: encoding the video failed: No space left on device")

    monkeypatch.setattr(video_module.VideoWriter, "_finish", broken_finish)
    out, csv = tmp_path / "out.mp4", tmp_path / "out.csv"
    with pytest.raises(OutputError) as info:
        process_video(src, out, detector=fast_probe(), tables={"csv": csv}, progress=False)
    assert_error(info, out, "No space left on device")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.mp4"]


# ----------------------------------------------------------------------------------------------
# Interrupted detection: SIGKILL and Ctrl-C midway through a video
# ----------------------------------------------------------------------------------------------


def _processes_mentioning(text: str) -> list[int]:
    found = []
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                cmdline = Path(f"/proc/{entry}/cmdline").read_bytes()
            except OSError:
                continue
            if text.encode() in cmdline:
                found.append(int(entry))
    return found


def _partial_size(folder: Path, final: Path) -> int:
    """Size of the hidden temporary file of ``final`` (0 while there is none)."""
    size = 0
    for p in folder.glob(f".{final.name}.*{PARTIAL_SUFFIX}"):
        try:
            size = max(size, p.stat().st_size)
        except FileNotFoundError:  # renamed or removed meanwhile
            pass
    return size


@posix_only
@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGINT], ids=["SIGKILL", "SIGINT"])
def test_detect_stopped_midway_leaves_no_finished_looking_output(tmp_path, long_video, sig):
    video = tmp_path / "drive.mp4"
    video.write_bytes(long_video.read_bytes())
    before = sha256(video)
    final, csv = tmp_path / "drive_detected.mp4", tmp_path / "drive_boxes.csv"
    proc = subprocess.Popen(
        [sys.executable, "-m", "vehicle_detection.cli", "detect", str(video), "--no-progress"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        # Midway: the hidden temporary video exists and the encoder has flushed frames into it.
        deadline = time.monotonic() + 120
        while True:
            if _partial_size(tmp_path, final) > 100_000:
                break
            assert proc.poll() is None, f"detect ended before it could be stopped: {proc.communicate()}"
            assert time.monotonic() < deadline, "no partial output appeared"
            time.sleep(0.01)
        assert not final.exists() and not csv.exists()
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    # Nothing the run started may outlive it.
    deadline = time.monotonic() + 20
    while _processes_mentioning(str(tmp_path)) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert _processes_mentioning(str(tmp_path)) == []

    assert not final.exists() and not csv.exists()  # nothing under a final name
    assert sha256(video) == before
    leftovers = sorted(p.name for p in tmp_path.iterdir() if p != video)
    if sig == signal.SIGINT:
        assert proc.returncode == 130
        assert err.splitlines() == ["vehicle-detection: interrupted"]
        assert leftovers == []  # the temporary file was removed
    else:
        assert proc.returncode == -signal.SIGKILL
        assert len(leftovers) == 1 and leftovers[0].startswith(f".{final.name}.")
        assert leftovers[0].endswith(PARTIAL_SUFFIX)  # hidden, and named as unfinished


# ----------------------------------------------------------------------------------------------
# Models: data only, checked on load
# ----------------------------------------------------------------------------------------------


def _model_parts() -> tuple[dict, dict]:
    with np.load(default_model_path(), allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files}
    meta = json.loads(arrays.pop("meta").tobytes())
    return arrays, meta


def _write_model(path: Path, arrays: dict, meta: dict, *, sign: bool = True) -> Path:
    meta = dict(meta)
    if sign:
        meta["sha256"] = _digest(arrays, meta)
    with open(path, "wb") as f:
        np.savez(f, meta=np.frombuffer(json.dumps(meta).encode(), np.uint8), **arrays)
    return path


def _tampered(kind: str, path: Path) -> tuple[Path, str]:
    arrays, meta = _model_parts()
    n = len(arrays["coef"])
    if kind == "tampered_weights":
        arrays["coef"] = arrays["coef"].copy()
        arrays["coef"][3] += 0.5
        return _write_model(path, arrays, meta, sign=False), "contents do not match the checksum"
    if kind == "wrong_arrays":
        np.savez(path, weights=arrays["coef"], bias=arrays["intercept"])
        return path, "not a vehicle-detection-model file: arrays ['bias', 'weights']"
    if kind == "truncated":
        data = default_model_path().read_bytes()
        path.write_bytes(data[: len(data) * 2 // 3])
        return path, "unreadable model file (truncated, corrupt or not an .npz)"
    if kind == "shape_mismatch":
        arrays["coef"] = np.zeros(n + 1)
        return _write_model(path, arrays, meta), f"array coef is float64 ({n + 1},), expected float64 ({n},)"
    if kind == "feature_format":
        meta["feature_format"] = FEATURE_FORMAT + 1
        return _write_model(path, arrays, meta), "features were computed by feature format"
    if kind == "feature_config":
        meta["feature_config"] = {**meta["feature_config"], "gamma": 2.2}
        return _write_model(path, arrays, meta), "feature config does not match this code"
    if kind == "newer_library":
        meta["library_version"] = "99.0.0"
        return _write_model(path, arrays, meta), f"trained by vehicle-detection 99.0.0, newer than this {__version__}"
    raise AssertionError(kind)


@pytest.mark.parametrize(
    "kind", ["wrong_arrays", "tampered_weights", "truncated", "shape_mismatch", "feature_format", "feature_config", "newer_library"]
)
def test_bad_model_file_refused(tmp_path, kind):
    path, problem = _tampered(kind, tmp_path / f"{kind}.npz")
    with pytest.raises(ModelError) as info:
        VehicleClassifier.load(path)
    assert_error(info, path, problem)


class _Payload:
    def __init__(self, marker: Path):
        self.marker = marker

    def __reduce__(self):
        return (Path.write_text, (self.marker, "executed"))


@pytest.mark.parametrize("form", ["pickle_file", "object_array"])
def test_model_file_is_never_executed(tmp_path, form):
    marker = tmp_path / "EXECUTED"
    path = tmp_path / "evil.npz"
    if form == "pickle_file":
        path.write_bytes(pickle.dumps(_Payload(marker)))
    else:
        arrays, meta = _model_parts()
        arrays["coef"] = np.array([_Payload(marker)], dtype=object)
        _write_model(path, arrays, meta, sign=False)
    with pytest.raises(ModelError) as info:
        VehicleClassifier.load(path)
    assert_error(info, path, "unreadable model file")
    assert not marker.exists()


# ----------------------------------------------------------------------------------------------
# Downloads (loopback server only)
# ----------------------------------------------------------------------------------------------

PAYLOAD = np.random.default_rng(7).integers(0, 256, 150_000, dtype=np.uint8).tobytes()


class _Handler(BaseHTTPRequestHandler):
    def log_message(self, *args):  # quiet
        pass

    def do_GET(self):  # noqa: N802
        srv = self.server
        rng = self.headers.get("Range")
        srv.requests.append((self.path, rng))
        body = srv.files.get(self.path)
        if body is None:
            self.send_error(404)
            return
        start = int(rng.split("=")[1].rstrip("-")) if rng and srv.honour_range else 0
        self.send_response(206 if start else 200)
        if start:
            self.send_header("Content-Range", f"bytes {start}-{len(body) - 1}/{len(body)}")
        self.send_header("Content-Length", str(len(body) - start))
        self.end_headers()
        self.wfile.write(body[start:])


@pytest.fixture
def server():
    httpd = ThreadingHTTPServer(("127.0.0.1", 0), _Handler)
    httpd.daemon_threads = True
    httpd.files, httpd.requests, httpd.honour_range = {"/f.bin": PAYLOAD}, [], True
    httpd.url = f"http://127.0.0.1:{httpd.server_address[1]}"
    thread = threading.Thread(target=httpd.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    yield httpd
    httpd.shutdown()
    httpd.server_close()
    thread.join(5)


@pytest.mark.parametrize("honour_range", [True, False], ids=["resumed", "restarted"])
def test_partial_download_resumes_or_restarts(server, tmp_path, honour_range):
    from vehicle_detection.training.download import download_file, part_path

    server.honour_range = honour_range
    dest = tmp_path / "f.bin"
    part_path(dest).write_bytes(PAYLOAD[:40_000])  # an earlier, interrupted attempt
    md5 = hashlib.md5(PAYLOAD).hexdigest()
    assert download_file(f"{server.url}/f.bin", dest, md5=md5, progress=False) == dest
    assert dest.read_bytes() == PAYLOAD
    assert not part_path(dest).exists()
    assert server.requests == [("/f.bin", "bytes=40000-")]


def test_checksum_mismatch_deletes_the_file_and_says_so(server, tmp_path):
    from vehicle_detection.training.download import download_file, part_path

    dest = tmp_path / "f.bin"
    part_path(dest).write_bytes(b"X" * 40_000)  # not a prefix of the file: the result is wrong
    with pytest.raises(DownloadError) as info:
        download_file(f"{server.url}/f.bin", dest, md5="0" * 32, progress=False)
    assert_error(info, f"{server.url}/f.bin", "md5 mismatch: expected 00000000", "the downloaded file was deleted")
    assert list(tmp_path.iterdir()) == []


def test_cli_download_of_an_invalid_archive(server, tmp_path, monkeypatch, capsys):
    from vehicle_detection.training import download
    from vehicle_detection.cli import main

    server.files["/vehicles.zip"] = b"<html>moved</html>"  # what a captive portal sends
    monkeypatch.setitem(download.download_archives.__kwdefaults__, "base_url", server.url)
    data = tmp_path / "data"
    assert main(["download", "--data-dir", str(data), "--no-progress"]) == 6
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith(f"vehicle-detection: error: {server.url}/vehicles.zip: ")
    assert "the downloaded archive is not valid and was deleted" in err[0]
    assert list(data.iterdir()) == []


def test_download_never_reaches_the_network(tmp_path):
    from vehicle_detection.training.download import download_archives

    with pytest.raises(DownloadError) as info:
        download_archives(tmp_path, progress=False)  # the public address: refused by the guard
    assert "cannot reach the server" in str(info.value)
    assert list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------------------------------------
# Properties of the pure functions (those not already in test_features/heatmap/evaluate)
# ----------------------------------------------------------------------------------------------

CONFIGS = [
    FeatureConfig(),
    FeatureConfig(color_space="RGB", hog_channels=(0,), signed=False, hog_sqrt=False, spatial_size=0, hist_bins=0),
    FeatureConfig(color_space="HLS", orientations=9, pixels_per_cell=16, spatial_size=8, hist_bins=7),
    FeatureConfig(color_space="LUV", hog_channels=(1, 2), orientations=11, cells_per_block=3),
    FeatureConfig(color_space="HSV", hog_channels=(2,), spatial_size=32, hist_bins=256),
]


@st.composite
def patches(draw):
    n = draw(st.integers(1, 3))
    kind = draw(st.sampled_from(["random", "constant", "two_level"]))
    if kind == "random":
        return draw(hnp.arrays(np.uint8, (n, 64, 64, 3)))
    if kind == "constant":
        return np.full((n, 64, 64, 3), draw(st.integers(0, 255)), np.uint8)
    lo, hi = draw(st.integers(0, 255)), draw(st.integers(0, 255))
    mask = draw(hnp.arrays(np.bool_, (64, 64)))
    return np.broadcast_to(np.where(mask[..., None], hi, lo).astype(np.uint8), (n, 64, 64, 3)).copy()


@HYP
@given(patches(), st.sampled_from(CONFIGS))
def test_extract_features_always_finite(batch, cfg):
    feats = extract_features(batch, cfg)
    assert feats.shape == (len(batch), cfg.n_features) and feats.dtype == np.float32
    assert np.all(np.isfinite(feats))
    # Patches do not influence each other in a batch.
    np.testing.assert_array_equal(extract_features(batch[-1], cfg), feats[-1])


@settings(HYP, max_examples=max(1, HYP.max_examples // 2))
@given(hnp.arrays(np.uint8, (64, 64)), hnp.arrays(np.uint8, (64, 64)), st.sampled_from(CONFIGS))
def test_extract_features_converts_grey_and_rgba_patches_by_the_rule(grey, alpha, cfg):
    rgb = np.repeat(grey[:, :, None], 3, axis=2)
    np.testing.assert_array_equal(extract_features(grey[:, :, None], cfg), extract_features(rgb, cfg))
    rgba = np.dstack([rgb, alpha])
    np.testing.assert_array_equal(extract_features(rgba, cfg), extract_features(rgb, cfg))


@st.composite
def float_heat(draw):
    rows, cols = draw(st.integers(1, 14)), draw(st.integers(1, 14))
    values = draw(hnp.arrays(np.float32, (rows, cols), elements=st.floats(-5, 1e6, width=32)))
    return values, draw(st.integers(1, 16))


@HYP
@given(float_heat(), st.floats(-1, 10), st.sampled_from([0.0, 0.3, 0.6, 0.95]), st.sampled_from([4, 8]))
def test_heat_to_boxes_stays_inside_the_map(case, threshold, peak_fraction, connectivity):
    heat, cell = case
    boxes, peaks = heat_to_boxes(
        heat, threshold, cell=cell, min_size=(0, 0), aspect_range=(0.01, 100),
        connectivity=connectivity, peak_fraction=peak_fraction,
    )  # fmt: skip
    h, w = heat.shape[0] * cell, heat.shape[1] * cell
    assert boxes.shape == (len(peaks), 4)
    assert np.all((boxes[:, 0] >= 0) & (boxes[:, 0] < boxes[:, 2]) & (boxes[:, 2] <= w))
    assert np.all((boxes[:, 1] >= 0) & (boxes[:, 1] < boxes[:, 3]) & (boxes[:, 3] <= h))
    assert np.all(peaks > threshold) and np.all(np.isfinite(peaks))
    assert len(boxes) == label_heat(heat, threshold, connectivity=connectivity)[1]  # no filter: one per blob


@st.composite
def windows_in_a_frame(draw):
    h, w = draw(st.integers(8, 120)), draw(st.integers(8, 160))
    n = draw(st.integers(0, 10))
    boxes = []
    for _ in range(n):
        x1, y1 = draw(st.integers(-w, 2 * w)), draw(st.integers(-h, 2 * h))
        boxes.append([x1, y1, x1 + draw(st.integers(1, w)), y1 + draw(st.integers(1, h))])
    return (h, w), np.array(boxes, np.int64).reshape(-1, 4), draw(st.integers(1, 8))


@HYP
@given(windows_in_a_frame(), st.floats(0, 3))
def test_windows_anywhere_give_boxes_inside_the_frame(case, threshold):
    (h, w), windows, cell = case
    heat = add_heat(np.zeros((h // cell, w // cell), np.float32), windows, cell=cell)
    boxes, _ = heat_to_boxes(heat, threshold, cell=cell, min_size=(0, 0), aspect_range=(0.01, 100))
    assert np.all((boxes[:, 0] >= 0) & (boxes[:, 2] <= w) & (boxes[:, 1] >= 0) & (boxes[:, 3] <= h))
    assert np.all((boxes[:, 2] > boxes[:, 0]) & (boxes[:, 3] > boxes[:, 1]))


@HYP
@given(st.lists(windows_in_a_frame(), min_size=1, max_size=6), st.integers(8, 120), st.integers(8, 160))
def test_tracker_reports_boxes_inside_the_frame(frames, h, w):
    tracker = Tracker(TrackerConfig(cell=4, threshold=0.5, min_hits=1, min_size=(0, 0), aspect_range=(0.01, 100)))
    for i, (_, windows, _) in enumerate(frames):
        found = tracker.update(Detections(windows, score=np.zeros(len(windows))), (h, w, 3))
        assert tracker.state.frame_index == i + 1
        ids = found.track_id.tolist()
        assert ids == sorted(set(ids))
        for x1, y1, x2, y2 in found.xyxy.tolist():
            assert 0 <= x1 < x2 <= w and 0 <= y1 < y2 <= h, ((x1, y1, x2, y2), (h, w))


@st.composite
def labelled_frames(draw):
    def boxes(max_n):
        out = []
        for _ in range(draw(st.integers(0, max_n))):
            x, y = draw(st.integers(0, 50)), draw(st.integers(0, 50))
            out.append([x, y, x + draw(st.integers(1, 30)), y + draw(st.integers(1, 30))])
        return np.array(out, np.int64).reshape(-1, 4)

    return [(boxes(5), boxes(4), boxes(2)) for _ in range(draw(st.integers(1, 4)))]


@HYP
@given(labelled_frames(), st.randoms(use_true_random=False), st.integers(0, 1000), st.integers(0, 1000))
def test_evaluation_invariants(frames, rnd, dx, dy):
    def score(frames, thresholds=(0.3, 0.5, 0.7)):
        ann = Annotations(None, {i: FrameLabels(cars=c, ignore=g) for i, (_, c, g) in enumerate(frames)})
        return {t: s.as_dict() for t, s in evaluate_detections({i: d for i, (d, _, _) in enumerate(frames)}, ann, thresholds).items()}

    base = score(frames)
    # Order of detections, cars and ignore regions does not matter.
    shuffled = [tuple(a[rnd.sample(range(len(a)), len(a))] for a in f) for f in frames]
    assert score(shuffled) == base
    # Nor where the picture is: shifting every box alike changes nothing (boxes stay >= 0).
    shift = np.array([dx, dy, dx, dy])
    assert score([tuple(a + shift for a in f) for f in frames]) == base
    # A looser IoU threshold never matches fewer cars.
    assert base[0.3]["tp"] >= base[0.5]["tp"] >= base[0.7]["tp"]
    # The labels themselves score perfectly at every threshold.
    perfect = score([(c, c, g) for _, c, g in frames])
    for s in perfect.values():
        assert s["tp"] == sum(len(c) for _, c, _ in frames) and s["fp"] == s["fn"] == 0
        assert s["precision"] == s["recall"] == 1.0
