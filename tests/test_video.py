"""Tests for vehicle_detection.io.video: probing, decoding, encoding, damaged files and cleanup.

The videos are made in ``tmp_path`` with PyAV directly (``tests/media.py``), small and fast.
"""

from __future__ import annotations

import os
import threading
import time
from contextlib import closing
from fractions import Fraction
from pathlib import Path

import av
import numpy as np
import pytest

import media
from media import encode, frame_number, moving_square_frames, numbered_frames
from vehicle_detection.io import video as video_module
from vehicle_detection.io._files import PARTIAL_SUFFIX
from vehicle_detection.errors import InputError, OutputError
from vehicle_detection.io.video import VideoInfo, VideoWriter, probe_video, read_frames

ROOT = Path(__file__).resolve().parents[1]
TEST_VIDEO = ROOT / "test_video.mp4"

needs_test_video = pytest.mark.skipif(not TEST_VIDEO.is_file(), reason="test_video.mp4 not in the checkout")


# --- helpers ---------------------------------------------------------------------------------


def video_threads() -> list[str]:
    return [t.name for t in threading.enumerate() if t.name.startswith("vehicle_detection-video")]


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def write_video(path: Path, frames: list[np.ndarray], fps: float = 25.0, **kwargs) -> None:
    height, width = frames[0].shape[:2]
    with VideoWriter(path, fps, (width, height), **kwargs) as writer:
        for frame in frames:
            writer.write(frame)


def read_all(path: Path) -> tuple[list[np.ndarray], InputError | None]:
    """Every frame read_frames yields, and the InputError it ends with (None if it ends cleanly)."""
    got = []
    try:
        for frame in read_frames(path):
            got.append(frame)
    except InputError as exc:
        return got, exc
    return got, None


# --- probing and reading the sample video ------------------------------------------------------


@needs_test_video
def test_probe_test_video():
    info = probe_video(TEST_VIDEO)
    assert info == VideoInfo(width=1280, height=720, fps=25.0, n_frames=38, duration=pytest.approx(1.52))
    assert info.size == (1280, 720)


@needs_test_video
def test_read_test_video_gives_38_rgb_frames():
    frames = list(read_frames(TEST_VIDEO, prefetch=2))
    assert len(frames) == 38
    for frame in frames:
        assert frame.shape == (720, 1280, 3)
        assert frame.dtype == np.uint8
        assert frame.flags.c_contiguous and frame.flags.writeable
    # Every frame is its own array (no shared, reused buffer) and the video changes over time.
    assert len({id(f) for f in frames}) == 38
    assert not any(np.shares_memory(a, b) for a, b in zip(frames, frames[1:]))
    assert np.abs(frames[0].astype(int) - frames[-1].astype(int)).mean() > 1
    frames[0][0, 0] = 0  # writeable in fact, not only flagged
    # The arrays stay valid after the decoder is gone: a second decode gives the same pixels.
    again = list(read_frames(TEST_VIDEO))
    assert all(np.array_equal(a, b) for a, b in zip(frames[1:], again[1:]))


def test_frames_are_rgb_and_in_order(tmp_path):
    # Odd-looking width: the decoder pads rows for alignment, the yielded array must not be.
    path = encode(tmp_path / "n.mp4", numbered_frames(30, width=98, height=64), options={"bf": "3", "g": "7"})
    frames = list(read_frames(path))
    assert [frame_number(f) for f in frames] == list(range(30))  # presentation order, B-frames reordered
    assert all(f.shape == (64, 98, 3) and f.flags.c_contiguous and f.flags.writeable for f in frames)
    red = encode(tmp_path / "red.mp4", [np.full((48, 64, 3), (255, 0, 0), np.uint8)] * 2)
    mean = next(iter(read_frames(red))).reshape(-1, 3).mean(axis=0)
    assert mean[0] > 240 and mean[1] < 15 and mean[2] < 15  # R first


@needs_test_video
def test_break_stops_the_decoder_thread():
    gen = read_frames(TEST_VIDEO, prefetch=2)
    assert video_threads() == []  # decoding starts on the first next(), not before
    first = next(gen)
    assert first.shape == (720, 1280, 3)
    assert video_threads() == ["vehicle_detection-video-decoder"]
    time.sleep(0.3)  # let the thread fill the queue and block on it
    start = time.perf_counter()
    gen.close()
    assert time.perf_counter() - start < 1.0
    assert video_threads() == []

    # The usual form: the generator is dropped after the loop.
    for i, _ in enumerate(read_frames(TEST_VIDEO)):
        if i == 3:
            break
    assert video_threads() == []


@needs_test_video
def test_read_with_closing_and_prefetch_validation():
    with closing(read_frames(TEST_VIDEO, prefetch=1)) as frames:
        assert next(frames).shape == (720, 1280, 3)
    for bad in (0, -1, 1.5, True):
        with pytest.raises(ValueError, match="prefetch"):
            read_frames(TEST_VIDEO, prefetch=bad)


# --- bad input files ---------------------------------------------------------------------------


def test_missing_file(tmp_path):
    path = tmp_path / "nope.mp4"
    with pytest.raises(InputError, match=r"nope\.mp4: no such file"):
        probe_video(path)
    with pytest.raises(InputError, match=r"nope\.mp4"):
        read_frames(path)  # raised at the call, before iterating


def test_folder(tmp_path):
    folder = tmp_path / "clip.mp4"
    folder.mkdir()
    with pytest.raises(InputError, match=r"clip\.mp4: is a folder"):
        probe_video(folder)


def test_empty_file(tmp_path):
    path = tmp_path / "empty.mp4"
    path.touch()
    with pytest.raises(InputError, match=r"empty\.mp4: file is empty"):
        probe_video(path)
    with pytest.raises(InputError, match=r"empty\.mp4: file is empty"):
        read_frames(path)


@pytest.mark.parametrize(
    "content",
    [b"this is not a video\n" * 20, bytes(np.random.default_rng(0).integers(0, 256, 20_000, dtype=np.uint8))],
    ids=["text", "noise"],
)
def test_not_a_video(tmp_path, content):
    path = tmp_path / "notes.mp4"
    path.write_bytes(content)
    with pytest.raises(InputError, match=r"notes\.mp4: not a readable video file \(.+\)$"):
        probe_video(path)
    with pytest.raises(InputError, match=r"notes\.mp4: not a readable video file"):
        read_frames(path)


def test_audio_only_file(tmp_path):
    path = tmp_path / "tone.m4a"
    with av.open(os.fspath(path), "w") as out:
        stream = out.add_stream("aac", rate=16000)
        samples = (np.sin(np.arange(8000) / 5) * 8000).astype(np.int16).reshape(1, -1)
        frame = av.AudioFrame.from_ndarray(samples, format="s16", layout="mono")
        frame.sample_rate = 16000
        out.mux(stream.encode(frame))
        out.mux(stream.encode(None))
    with pytest.raises(InputError, match=r"tone\.m4a: contains no video stream$"):
        probe_video(path)


def test_video_stream_without_frames(tmp_path):
    path = encode(tmp_path / "none.avi", [], codec="mpeg4", format="avi")
    with av.open(os.fspath(path)) as inp:
        assert len(inp.streams.video) == 1  # the stream is there, it has no frame
    with pytest.raises(InputError, match=r"none\.avi: no video frame could be decoded"):
        probe_video(path)
    with pytest.raises(InputError, match=r"none\.avi: no video frame could be decoded"):
        list(read_frames(path))


def test_undecodable_metadata_text_is_ignored(tmp_path):
    path = tmp_path / "meta.mp4"
    with av.open(os.fspath(path), "w") as out:
        out.metadata["title"] = "TITLE-XXXX"
        stream = out.add_stream("libx264", rate=25)
        stream.width, stream.height, stream.pix_fmt = 96, 64, "yuv420p"
        for rgb in numbered_frames(3):
            out.mux(stream.encode(av.VideoFrame.from_ndarray(rgb, format="rgb24")))
        out.mux(stream.encode(None))
    data = path.read_bytes()
    assert data.count(b"TITLE-XXXX") == 1
    path.write_bytes(data.replace(b"TITLE-XXXX", b"\xff\xfe\xc3(-XXXXX"))  # not UTF-8
    assert probe_video(path).n_frames == 3
    assert [frame_number(f) for f in read_frames(path)] == [0, 1, 2]


@pytest.mark.parametrize("name", ["-cam:1.mp4", "http:x.mp4", "a b#c?.mp4"])
def test_odd_file_names_are_files(tmp_path, name):
    path = tmp_path / name  # "cam:" or "http:" would be a protocol, "#" or "?" a URL part
    write_video(path, moving_square_frames(3))
    assert probe_video(path).n_frames == 3
    assert len(list(read_frames(path))) == 3


# --- damaged files -----------------------------------------------------------------------------


@needs_test_video
def test_truncated_inside_a_packet_yields_good_frames_then_raises(tmp_path):
    data = TEST_VIDEO.read_bytes()
    cut = int(len(data) * 0.3)
    path = tmp_path / "cut.mp4"
    path.write_bytes(data[:cut])
    assert probe_video(path).n_frames == 38  # the index at the front still promises all frames
    complete = sum(1 for pos, size in media.packets(TEST_VIDEO) if pos + size <= cut)
    assert 0 < complete < 38  # no B-frames in this file: one frame per complete packet

    got, error = read_all(path)
    assert error is not None
    assert str(error) == (
        f"{path}: video is damaged or truncated: decoded {complete} of the 38 frames the file declares, "
        "then the demuxer found a damaged or cut-short packet"
    )
    # Exactly the frames before the damage came out, and they are intact.
    assert len(got) == complete
    full = list(read_frames(TEST_VIDEO))
    assert all(np.array_equal(a, b) for a, b in zip(got, full))


@needs_test_video
@pytest.mark.parametrize("k", [5, 20])
def test_truncated_between_packets_raises(tmp_path, k):
    pos, _ = media.packets(TEST_VIDEO)[k]
    path = tmp_path / "short.mp4"
    path.write_bytes(TEST_VIDEO.read_bytes()[:pos])  # the file ends exactly before packet k
    assert media.decoded_count(path) == k  # silently short for a plain decode loop
    got, error = read_all(path)
    assert len(got) == k
    assert str(error) == (
        f"{path}: video is damaged or truncated: decoded {k} of the 38 frames the file declares, "
        "then the file ends before the last packet its index lists"
    )


@needs_test_video
def test_corrupt_packet_in_the_middle_raises(tmp_path):
    data = bytearray(TEST_VIDEO.read_bytes())
    pos, size = media.packets(TEST_VIDEO)[10]
    data[pos + 8 : pos + size] = np.random.default_rng(1).integers(0, 256, size - 8, dtype=np.uint8).tobytes()
    path = tmp_path / "bad.mp4"
    path.write_bytes(bytes(data))
    got, error = read_all(path)
    assert len(got) == 10
    assert str(error).startswith(
        f"{path}: video is damaged or truncated: decoded 10 of the 38 frames the file declares, "
        "then the h264 decoder rejected a packet ("
    )
    full = list(read_frames(TEST_VIDEO))
    assert all(np.array_equal(a, b) for a, b in zip(got, full))


def test_no_decodable_frame(tmp_path):
    # A valid MP4 header whose only frame has been overwritten with garbage.
    path = tmp_path / "garbage.mp4"
    write_video(path, moving_square_frames(1))
    data = bytearray(path.read_bytes())
    mdat = data.index(b"mdat") + 4
    data[mdat:] = b"\xff" * (len(data) - mdat)
    path.write_bytes(bytes(data))
    with pytest.raises(InputError, match=r"garbage\.mp4: no video frame could be decoded: the h264 decoder"):
        probe_video(path)
    with pytest.raises(InputError, match=r"garbage\.mp4: no video frame could be decoded: the h264 decoder"):
        list(read_frames(path))


def test_damage_is_always_an_input_error(tmp_path):
    # Cut a small file (index at the front) at many places: each read ends with an InputError
    # naming the file, and the frames it yields are the first frames of the intact file.
    src = tmp_path / "src.mp4"
    encode(src, numbered_frames(40), options={"bf": "2", "g": "9"}, container_options={"movflags": "+faststart"})
    data = src.read_bytes()
    path = tmp_path / "cut.mp4"
    partial = 0
    for cut in range(40, len(data), len(data) // 29):
        path.write_bytes(data[:cut])
        got, error = read_all(path)
        assert error is not None and str(error).startswith(f"{path}: "), (cut, error)
        assert [frame_number(f) for f in got] == list(range(len(got)))
        if got:
            partial += 1
            assert str(error).startswith(f"{path}: video is damaged or truncated: decoded {len(got)} of the 40 frames")
    assert partial >= 10


# --- variable frame rate, containers and rotation ----------------------------------------------


def test_variable_frame_rate_frames_are_not_duplicated_or_dropped(tmp_path):
    # 40 frames with irregular timestamps: a gap of 10 frame times after frame 4, a jump later.
    pts = [*range(5), *range(15, 35), *range(50, 65)]
    path = encode(tmp_path / "vfr.mp4", numbered_frames(40), pts=pts, time_base=Fraction(1, 25))
    assert media.decoded_count(path) == 40
    frames = list(read_frames(path))
    assert [frame_number(f) for f in frames] == list(range(40))  # each decoded frame once, in order
    assert probe_video(path).n_frames == 40


@pytest.mark.parametrize(
    ("codec", "suffix", "container_options"),
    [
        ("mpeg1video", ".ts", {}),
        ("mpeg2video", ".m2ts", {"mpegts_m2ts_mode": "1"}),
        ("mpeg4", ".mpg", {}),
        ("libx264", ".ts", {}),
    ],
)
def test_mpeg_ts_files(tmp_path, codec, suffix, container_options):
    path = tmp_path / f"clip{suffix}"
    encode(path, numbered_frames(12, width=160, height=96), codec=codec, format="mpegts", container_options=container_options)
    with av.open(os.fspath(path)) as inp:
        assert inp.format.name == "mpegts" and inp.streams.video[0].codec_context.name == codec.replace("lib", "").replace("x264", "h264")
    info = probe_video(path)
    assert (info.width, info.height, info.fps) == (160, 96, 25.0)
    assert info.n_frames is not None and abs(info.n_frames - 12) <= 1  # estimated from the duration
    frames = list(read_frames(path))
    assert [frame_number(f) for f in frames] == list(range(12))
    assert all(f.shape == (96, 160, 3) for f in frames)


def corner_picture(h: int = 48, w: int = 64) -> np.ndarray:
    """Grey with a red block at the top left and a blue one at the bottom right: every turn and flip differs."""
    img = np.full((h, w, 3), 128, np.uint8)
    img[:16, :16] = (255, 0, 0)
    img[-16:, -24:] = (0, 0, 255)
    return img


@pytest.mark.parametrize(
    ("rotation", "hflip", "vflip", "upright"),
    [
        (90, False, False, lambda a: np.rot90(a, 1)),
        (-90, False, False, lambda a: np.rot90(a, -1)),
        (180, False, False, lambda a: np.rot90(a, 2)),
        (0, True, False, lambda a: a[:, ::-1]),
        (0, False, True, lambda a: a[::-1]),
        (90, True, False, lambda a: np.rot90(a, 1)[:, ::-1]),
        (-90, True, False, lambda a: np.rot90(a, -1)[:, ::-1]),
        (30, False, False, lambda a: a),  # not a quarter turn: ignored
    ],
)
def test_display_matrix_is_applied(tmp_path, rotation, hflip, vflip, upright):
    # Rotation counter-clockwise as PyAV's set_display_rotation takes it; the expected pictures
    # are what FFmpeg's players (and the ffmpeg command line) show.
    img = corner_picture()
    path = encode(tmp_path / "rot.mp4", [img] * 2, rotation=rotation, hflip=hflip, vflip=vflip,
                  pix_fmt="yuv444p", options={"qp": "0"})  # fmt: skip
    expected = upright(img)
    info = probe_video(path)
    assert (info.height, info.width) == expected.shape[:2]
    frames = list(read_frames(path))
    assert len(frames) == 2
    for frame in frames:
        assert frame.shape == expected.shape and frame.flags.c_contiguous and frame.flags.writeable
        assert np.abs(frame.astype(int) - expected).max() <= 3


def test_size_change_mid_stream_keeps_the_first_size(tmp_path):
    # Two raw H.264 streams of different sizes, one after the other, make one valid stream.
    a = encode(tmp_path / "a.h264", numbered_frames(3, 96, 64), format="h264")
    rows, cols = np.arange(80) * 64 // 80, np.arange(128) * 96 // 128  # 96x64 drawings stretched to 128x80
    b = encode(tmp_path / "b.h264", [f[rows][:, cols] for f in numbered_frames(6, 96, 64)[3:]], format="h264")
    path = tmp_path / "joined.h264"
    path.write_bytes(a.read_bytes() + b.read_bytes())
    assert probe_video(path).size == (96, 64)
    frames = list(read_frames(path))
    assert [f.shape for f in frames] == [(64, 96, 3)] * 6
    assert [frame_number(f) for f in frames] == list(range(6))  # scaled, still readable


# --- writing -----------------------------------------------------------------------------------


def test_round_trip_moving_squares(tmp_path):
    frames = moving_square_frames(10)
    path = tmp_path / "squares.mp4"
    write_video(path, frames, fps=25)
    assert leftovers(tmp_path) == ["squares.mp4"]
    assert path.read_bytes()[4:8] == b"ftyp"
    info = probe_video(path)
    assert (info.width, info.height, info.fps, info.n_frames) == (160, 96, 25.0, 10)
    back = list(read_frames(path))
    assert len(back) == 10
    for original, decoded in zip(frames, back):
        assert decoded.shape == original.shape
        assert np.abs(decoded.astype(int) - original.astype(int)).mean() < 8
    # The square moved: frames came back in order.
    columns = [int(np.argmax(f[46, :, 2] < 70)) for f in back]  # first column of the yellow square
    assert columns == sorted(columns) and columns[0] < columns[-1]


def test_written_file_is_h264_bt709_faststart(tmp_path):
    path = tmp_path / "web.mp4"
    write_video(path, moving_square_frames(3))
    data = path.read_bytes()
    top_level = []
    pos = 0
    while pos + 8 <= len(data):
        size, kind = int.from_bytes(data[pos : pos + 4], "big"), data[pos + 4 : pos + 8]
        top_level.append(kind)
        pos += size
    assert top_level.index(b"moov") < top_level.index(b"mdat")  # playable while downloading
    assert b"moof" not in top_level  # a plain, not a fragmented MP4
    # The container's colour box: nclx, primaries 1, transfer 1, matrix 1 (BT.709), limited range.
    colr = data.index(b"colrnclx") + 8
    assert data[colr : colr + 7] == b"\x00\x01\x00\x01\x00\x01\x00"
    with av.open(os.fspath(path)) as inp:
        assert inp.format.name.startswith("mov,mp4")
        stream = inp.streams.video[0]
        ctx = stream.codec_context
        assert (ctx.name, ctx.profile, ctx.pix_fmt) == ("h264", "High", "yuv420p")
        assert (ctx.color_primaries, ctx.color_trc, ctx.colorspace, ctx.color_range) == (1, 1, 1, 1)
        frame = next(inp.decode(stream))  # the H.264 stream's own tags (VUI), as the decoder sees them
        assert (frame.color_primaries, frame.color_trc, frame.colorspace, frame.color_range) == (1, 1, 1, 1)


def test_crf_and_preset_reach_x264(tmp_path):
    # x264 writes its settings into the stream (an SEI message).
    fast, slow = tmp_path / "fast.mp4", tmp_path / "slow.mp4"
    write_video(fast, moving_square_frames(4), crf=30, preset="ultrafast")
    write_video(slow, moving_square_frames(4), crf=18, preset="medium")
    assert b"crf=30.0" in fast.read_bytes() and b"cabac=0" in fast.read_bytes()  # ultrafast: no CABAC
    assert b"crf=18.0" in slow.read_bytes() and b"cabac=1" in slow.read_bytes()


def test_writer_copies_frames(tmp_path):
    # One buffer reused for every frame, as a drawing loop would: the writer must copy it.
    levels = [0, 200, 40, 160, 80, 240, 120, 20]
    buffer = np.empty((48, 64, 3), np.uint8)
    path = tmp_path / "reuse.mp4"
    with VideoWriter(path, 25, (64, 48)) as writer:
        for level in levels:
            buffer[...] = level
            writer.write(buffer)
    back = [int(round(f.mean())) for f in read_frames(path)]
    assert back == pytest.approx(levels, abs=6)


def test_writer_without_a_copy_takes_the_frames_as_they_are(tmp_path):
    frames = moving_square_frames(6, 64, 48)
    copied, taken = tmp_path / "copied.mp4", tmp_path / "taken.mp4"
    with VideoWriter(copied, 25, (64, 48)) as writer:
        for frame in frames:
            writer.write(frame)
    with VideoWriter(taken, 25, (64, 48)) as writer:
        for i, frame in enumerate(frames):
            # Not C-contiguous (every other frame): copied anyway.
            writer.write(frame if i % 2 else np.asfortranarray(frame), copy=False)
    assert [f.tolist() for f in read_frames(copied)] == [f.tolist() for f in read_frames(taken)]
    odd = tmp_path / "odd.mp4"
    with VideoWriter(odd, 25, (63, 47)) as writer:  # padded to even: copied into the padded frame
        writer.write(frames[0][:47, :63], copy=False)
    assert probe_video(odd).size == (64, 48)


def test_colour_order_and_exact_ntsc_rate(tmp_path):
    colours = {"red": (255, 0, 0), "green": (0, 255, 0), "blue": (0, 0, 255), "grey": (128, 128, 128)}
    frames = [np.full((64, 96, 3), rgb, np.uint8) for rgb in colours.values()]
    path = tmp_path / "colours.mp4"
    write_video(path, frames, fps=30000 / 1001)
    with av.open(os.fspath(path)) as inp:
        assert inp.streams.video[0].average_rate == Fraction(30000, 1001)
    assert probe_video(path).fps == pytest.approx(30000 / 1001, abs=1e-12)
    back = list(read_frames(path))
    assert len(back) == 4
    for (name, rgb), frame in zip(colours.items(), back):
        mean = frame.reshape(-1, 3).mean(axis=0)
        assert np.abs(mean - rgb).max() < 8, (name, mean)


def test_fraction_rate(tmp_path):
    path = tmp_path / "rate.mp4"
    write_video(path, moving_square_frames(3), fps=Fraction(24000, 1001))
    with av.open(os.fspath(path)) as inp:
        assert inp.streams.video[0].average_rate == Fraction(24000, 1001)


def test_odd_size_is_padded_to_even(tmp_path):
    frames = [np.full((241, 321, 3), 200, np.uint8) for _ in range(3)]
    path = tmp_path / "odd.mp4"
    with VideoWriter(path, 25, (321, 241)) as writer:
        assert writer.output_size == (322, 242)
        for frame in frames:
            writer.write(frame)
    assert probe_video(path).size == (322, 242)
    back = list(read_frames(path))
    assert len(back) == 3
    for frame in back:
        assert frame.shape == (242, 322, 3)
        assert np.abs(frame[:241, :321].astype(int) - 200).mean() < 4  # picture at the top left
        assert frame[:, 321].max() < 40 and frame[241, :].max() < 40  # black padding


def test_wrong_frame_raises_value_error(tmp_path):
    path = tmp_path / "bad.mp4"
    with VideoWriter(path, 25, (64, 48)) as writer:
        writer.write(np.zeros((48, 64, 3), np.uint8))
        with pytest.raises(ValueError, match=r"shape \(64, 48, 3\), expected \(48, 64, 3\)"):
            writer.write(np.zeros((64, 48, 3), np.uint8))
        with pytest.raises(ValueError, match=r"shape \(48, 64\), expected"):
            writer.write(np.zeros((48, 64), np.uint8))
        with pytest.raises(ValueError, match="dtype float64"):
            writer.write(np.zeros((48, 64, 3)))
        writer.write(np.zeros((48, 64, 3), np.uint8))
    assert len(list(read_frames(path))) == 2  # the refused frames were not written


def test_writer_argument_validation(tmp_path):
    path = tmp_path / "x.mp4"
    for fps in (0, -1, float("nan"), "fast"):
        with pytest.raises(ValueError, match="fps"):
            VideoWriter(path, fps, (64, 48))
    for size in ((64,), (0, 48), (64.0, 48), None):
        with pytest.raises(ValueError, match="size"):
            VideoWriter(path, 25, size)
    with pytest.raises(ValueError, match="crf"):
        VideoWriter(path, 25, (64, 48), crf=60)
    with pytest.raises(ValueError, match="preset"):
        VideoWriter(path, 25, (64, 48), preset="ludicrous")
    with pytest.raises(RuntimeError, match="with"):
        VideoWriter(path, 25, (64, 48)).write(np.zeros((48, 64, 3), np.uint8))
    writer = VideoWriter(path, 25, (64, 48))
    with writer:
        writer.write(np.zeros((48, 64, 3), np.uint8))
    with pytest.raises(RuntimeError, match="one 'with' block"):
        with writer:
            pass
    assert leftovers(tmp_path) == ["x.mp4"]


def test_refuses_existing_output_without_overwrite(tmp_path):
    path = tmp_path / "exists.mp4"
    path.write_bytes(b"keep me")
    with pytest.raises(OutputError, match="exists"):
        VideoWriter(path, 25, (64, 48))
    assert path.read_bytes() == b"keep me"
    write_video(path, moving_square_frames(2), overwrite=True)
    assert len(list(read_frames(path))) == 2
    assert leftovers(tmp_path) == ["exists.mp4"]


def test_refuses_to_overwrite_an_input(tmp_path):
    src = tmp_path / "input.mp4"
    write_video(src, moving_square_frames(2))
    before = src.read_bytes()
    with pytest.raises(OutputError, match="input"):
        VideoWriter(tmp_path / "." / "input.mp4", 25, (160, 96), overwrite=True, inputs=[src])
    assert src.read_bytes() == before


@pytest.mark.parametrize("exc_type", [RuntimeError, KeyboardInterrupt])
def test_exception_in_block_leaves_nothing(tmp_path, exc_type):
    path = tmp_path / "out.mp4"
    with pytest.raises(exc_type, match="boom"):
        with VideoWriter(path, 25, (160, 96)) as writer:
            for frame in moving_square_frames(5):
                writer.write(frame)
            assert video_threads() == ["vehicle_detection-video-encoder"]
            assert [p.name for p in tmp_path.iterdir()][0].endswith(PARTIAL_SUFFIX)
            raise exc_type("boom")
    assert leftovers(tmp_path) == []
    assert video_threads() == []


def test_zero_frames_raises_and_leaves_nothing(tmp_path):
    path = tmp_path / "empty_out.mp4"
    with pytest.raises(OutputError, match=r"empty_out\.mp4: no frames were written"):
        with VideoWriter(path, 25, (160, 96)):
            pass
    assert leftovers(tmp_path) == []
    assert video_threads() == []


def test_encoder_failure_raises_output_error(tmp_path, monkeypatch):
    # The colour conversion of the second frame fails inside the encoder thread (as a full
    # disk or a codec error would): the failure surfaces in write() or at the end of the block.
    class Failing:
        calls = 0

        def reformat(self, frame, **kwargs):
            Failing.calls += 1
            if Failing.calls >= 2:
                raise av.error.MemoryError(12, "Cannot allocate memory")
            return frame.reformat(**kwargs)

    monkeypatch.setattr(video_module, "VideoReformatter", Failing)
    path = tmp_path / "dies.mp4"
    frame = np.zeros((96, 160, 3), np.uint8)
    with pytest.raises(OutputError) as info:
        with VideoWriter(path, 25, (160, 96)) as writer:
            for _ in range(50):
                writer.write(frame)
    assert str(info.value) == f"{path}: encoding the video failed: Cannot allocate memory"
    assert leftovers(tmp_path) == []
    assert video_threads() == []


def test_encoder_refusing_the_settings(tmp_path):
    # x264 refuses frames wider than its limit (16384 pixels): refused on entering the block.
    path = tmp_path / "wide.mp4"
    with pytest.raises(OutputError, match=r"^.*wide\.mp4: cannot start the H\.264 encoder \(16400x2, 25 fps, preset veryfast, crf 23\): .+"):
        with VideoWriter(path, 25, (16400, 2)) as writer:
            writer.write(np.zeros((2, 16400, 3), np.uint8))
    assert leftovers(tmp_path) == []
    assert video_threads() == []


@needs_test_video
def test_read_write_pipeline(tmp_path):
    out = tmp_path / "copy.mp4"
    info = probe_video(TEST_VIDEO)
    with VideoWriter(out, info.fps, info.size, inputs=[TEST_VIDEO], preset="ultrafast") as writer:
        for i, frame in enumerate(read_frames(TEST_VIDEO)):
            if i == 6:
                break
            frame[:10] = 0  # the writer copied the previous frames; mutating this one is fine
            writer.write(frame)
    assert writer.frames_written == 6
    assert probe_video(out).n_frames == 6
    assert video_threads() == []
