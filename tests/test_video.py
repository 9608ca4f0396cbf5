"""Tests for vehicle_detection.video: probing, decoding, encoding, damaged files and cleanup."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from contextlib import closing
from pathlib import Path

import imageio_ffmpeg
import numpy as np
import pytest

from vehicle_detection._files import PARTIAL_SUFFIX
from vehicle_detection.errors import InputError, OutputError
from vehicle_detection.video import VideoInfo, VideoWriter, probe_video, read_frames

ROOT = Path(__file__).resolve().parents[1]
TEST_VIDEO = ROOT / "test_video.mp4"
FFMPEG = imageio_ffmpeg.get_ffmpeg_exe()

needs_test_video = pytest.mark.skipif(not TEST_VIDEO.is_file(), reason="test_video.mp4 not in the checkout")
linux_only = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="inspects /proc")


# --- helpers ---------------------------------------------------------------------------------


def ffmpeg(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [FFMPEG, "-hide_banner", "-nostdin", "-y", *args], capture_output=True, text=True, check=True
    )


def ffmpeg_frame_count(path: Path) -> int:
    """Frames ffmpeg decodes from the first video stream, counted with the null muxer."""
    proc = subprocess.run(
        [FFMPEG, "-hide_banner", "-nostdin", "-i", os.fspath(path), "-map", "0:v:0", "-f", "null", "-"],
        capture_output=True,
        text=True,
    )
    counts = re.findall(r"frame=\s*(\d+)", proc.stderr)
    assert counts, proc.stderr
    return int(counts[-1])


def ffmpeg_children() -> list[tuple[int, str]]:
    """(pid, state) of this process's ffmpeg children, zombies included."""
    found = []
    me = os.getpid()
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                stat = f.read()
        except OSError:
            continue
        # "pid (comm) state ppid ...": comm may contain spaces, so split at the last ')'.
        comm = stat[stat.index("(") + 1 : stat.rindex(")")]
        state, ppid = stat[stat.rindex(")") + 2 :].split()[:2]
        if int(ppid) == me and comm.startswith("ffmpeg"):
            found.append((int(entry), state))
    return found


def leftovers(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir())


def moving_square_frames(n: int, width: int = 160, height: int = 96) -> list[np.ndarray]:
    """Smooth background with a bright square moving right: easy on H.264, still distinct frames."""
    yy, xx = np.mgrid[0:height, 0:width]
    frames = []
    for i in range(n):
        frame = np.empty((height, width, 3), np.uint8)
        frame[..., 0] = 40 + xx * 150 // width
        frame[..., 1] = 60 + yy * 120 // height
        frame[..., 2] = 90
        x0 = 8 + 10 * i
        frame[30:62, x0 : x0 + 32] = (230, 200, 40)
        frames.append(frame)
    return frames


def write_video(path: Path, frames: list[np.ndarray], fps: float = 25.0, **kwargs) -> None:
    height, width = frames[0].shape[:2]
    with VideoWriter(path, fps, (width, height), **kwargs) as writer:
        for frame in frames:
            writer.write(frame)


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
    assert not np.shares_memory(frames[0], frames[1])
    assert np.abs(frames[0].astype(int) - frames[-1].astype(int)).mean() > 1
    frames[0][0, 0] = 0  # writeable in fact, not only flagged


@needs_test_video
@linux_only
def test_break_kills_ffmpeg_and_thread():
    import threading

    gen = read_frames(TEST_VIDEO, prefetch=2)
    assert ffmpeg_children() == []  # ffmpeg starts on the first next(), not before
    first = next(gen)
    assert first.shape == (720, 1280, 3)
    running = ffmpeg_children()
    assert len(running) == 1 and running[0][1] != "Z"
    time.sleep(0.3)  # let ffmpeg fill the queue and block on the pipe
    start = time.perf_counter()
    gen.close()
    assert time.perf_counter() - start < 1.0  # ffmpeg is killed, not waited for
    assert ffmpeg_children() == []  # neither running nor a zombie
    assert not any(t.name == "vehicle_detection-video-decoder" for t in threading.enumerate())

    # The usual form: the generator is dropped after the loop.
    for i, _ in enumerate(read_frames(TEST_VIDEO)):
        if i == 3:
            break
    assert ffmpeg_children() == []


@needs_test_video
def test_read_with_closing_and_prefetch_validation():
    with closing(read_frames(TEST_VIDEO, prefetch=1)) as frames:
        assert next(frames).shape == (720, 1280, 3)
    with pytest.raises(ValueError, match="prefetch"):
        read_frames(TEST_VIDEO, prefetch=0)


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
    with pytest.raises(InputError, match=r"empty\.mp4"):
        list(read_frames(path))


def test_text_file_named_mp4(tmp_path):
    path = tmp_path / "notes.mp4"
    path.write_text("this is not a video\n" * 20)
    with pytest.raises(InputError, match=r"notes\.mp4: not a readable video file \(ffmpeg: .+\)"):
        probe_video(path)
    with pytest.raises(InputError, match=r"notes\.mp4"):
        list(read_frames(path))


def test_audio_only_file(tmp_path):
    path = tmp_path / "tone.m4a"
    ffmpeg("-f", "lavfi", "-i", "sine=frequency=440:duration=0.5", "-c:a", "aac", path.as_posix())
    with pytest.raises(InputError, match=r"tone\.m4a: contains no video stream"):
        probe_video(path)


def test_odd_file_names_are_not_protocols_or_options(tmp_path):
    frames = moving_square_frames(3)
    path = tmp_path / "-cam:1.mp4"  # "cam:" would be a protocol, "-..." an option
    write_video(path, frames)
    assert len(list(read_frames(path))) == 3


@needs_test_video
def test_truncated_file_yields_good_frames_then_raises(tmp_path):
    data = TEST_VIDEO.read_bytes()
    path = tmp_path / "cut.mp4"
    path.write_bytes(data[: int(len(data) * 0.3)])
    # The header (moov is at the front of this file) still promises all 38 frames.
    assert probe_video(path).n_frames == 38
    decodable = ffmpeg_frame_count(path)
    assert 0 < decodable < 38

    got = []
    with pytest.raises(InputError, match=r"cut\.mp4: video is damaged or truncated: decoded \d+ of the 38 frames"):
        for frame in read_frames(path):
            got.append(frame)
    # Exactly the frames ffmpeg can decode before the damage came out, and they are intact.
    assert len(got) == decodable
    full = list(read_frames(TEST_VIDEO))
    for a, b in zip(got, full):
        assert np.array_equal(a, b)


def test_no_decodable_frame(tmp_path):
    # A valid MP4 header whose only frame has been overwritten with garbage.
    path = tmp_path / "garbage.mp4"
    write_video(path, moving_square_frames(1))
    data = bytearray(path.read_bytes())
    mdat = data.index(b"mdat") + 4
    data[mdat:] = b"\xff" * (len(data) - mdat)
    path.write_bytes(bytes(data))
    with pytest.raises(InputError, match=r"garbage\.mp4: no video frame could be decoded: \[h264\]"):
        list(read_frames(path))


# --- variable frame rate and rotation ----------------------------------------------------------


def test_variable_frame_rate_frames_are_not_duplicated(tmp_path):
    path = tmp_path / "vfr.mp4"
    # 50 source frames, 10 dropped (a gap in time) and a jump after frame 20: irregular timestamps.
    ffmpeg(
        "-f", "lavfi", "-i", "testsrc2=size=160x120:rate=25:duration=2",
        "-vf", r"select='not(between(n\,5\,14))',setpts='N/25/TB+if(gt(N\,20)\,0.37/TB\,0)'",
        "-fps_mode", "vfr", "-c:v", "libx264", "-preset", "ultrafast", path.as_posix(),
    )  # fmt: skip
    expected = ffmpeg_frame_count(path)
    assert expected == 40
    frames = list(read_frames(path))
    assert len(frames) == expected
    # Consecutive frames differ (testsrc2 moves): nothing was duplicated to fill the gaps.
    assert all(not np.array_equal(a, b) for a, b in zip(frames, frames[1:]))


@needs_test_video
def test_rotated_video_reports_upright_size(tmp_path):
    path = tmp_path / "rotated.mp4"
    ffmpeg("-display_rotation", "90", "-i", TEST_VIDEO.as_posix(), "-map", "0:v", "-frames:v", "3", "-c", "copy",
           path.as_posix())  # fmt: skip
    info = probe_video(path)
    assert (info.width, info.height) == (720, 1280)
    frames = list(read_frames(path))
    assert [f.shape for f in frames] == [(1280, 720, 3)] * 3


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


def test_faststart_puts_index_first(tmp_path):
    path = tmp_path / "web.mp4"
    write_video(path, moving_square_frames(2))
    data = path.read_bytes()
    top_level = []
    pos = 0
    while pos + 8 <= len(data):
        size, kind = int.from_bytes(data[pos : pos + 4], "big"), data[pos + 4 : pos + 8]
        top_level.append(kind)
        pos += size
    assert top_level.index(b"moov") < top_level.index(b"mdat")  # playable while downloading
    assert b"moof" not in top_level  # a plain, not a fragmented MP4
    header = subprocess.run([FFMPEG, "-hide_banner", "-i", path.as_posix()], capture_output=True, text=True).stderr
    assert re.search(r"Video: h264 \(High\).*yuv420p\(tv, bt709", header), header  # browser-friendly


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


def test_colour_order_survives_round_trip(tmp_path):
    colours = {"red": (255, 0, 0), "green": (0, 255, 0), "blue": (0, 0, 255), "grey": (128, 128, 128)}
    frames = [np.full((64, 96, 3), rgb, np.uint8) for rgb in colours.values()]
    path = tmp_path / "colours.mp4"
    write_video(path, frames, fps=30000 / 1001)
    assert probe_video(path).fps == pytest.approx(30000 / 1001, abs=1e-9)
    back = list(read_frames(path))
    assert len(back) == 4
    for (name, rgb), frame in zip(colours.items(), back):
        mean = frame.reshape(-1, 3).mean(axis=0)
        assert np.abs(mean - rgb).max() < 8, (name, mean)
    red = back[0].reshape(-1, 3).mean(axis=0)
    assert red[0] > 240 and red[2] < 15


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
    assert leftovers(tmp_path) == []


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


@linux_only
@pytest.mark.parametrize("exc_type", [RuntimeError, KeyboardInterrupt])
def test_exception_in_block_leaves_nothing(tmp_path, exc_type):
    path = tmp_path / "out.mp4"
    with pytest.raises(exc_type, match="boom"):
        with VideoWriter(path, 25, (160, 96)) as writer:
            for frame in moving_square_frames(5):
                writer.write(frame)
            assert len(ffmpeg_children()) == 1
            raise exc_type("boom")
    assert leftovers(tmp_path) == []
    assert not list(tmp_path.glob("*" + PARTIAL_SUFFIX))
    assert ffmpeg_children() == []


@linux_only
def test_zero_frames_raises_and_leaves_nothing(tmp_path):
    path = tmp_path / "empty_out.mp4"
    with pytest.raises(OutputError, match=r"empty_out\.mp4: no frames were written"):
        with VideoWriter(path, 25, (160, 96)):
            pass
    assert leftovers(tmp_path) == []
    assert ffmpeg_children() == []


@linux_only
def test_ffmpeg_dying_raises_output_error(tmp_path):
    path = tmp_path / "dies.mp4"
    frame = np.zeros((96, 160, 3), np.uint8)
    with pytest.raises(OutputError, match=r"dies\.mp4: ffmpeg stopped accepting frames \(exit status -9\)"):
        with VideoWriter(path, 25, (160, 96)) as writer:
            writer.write(frame)
            writer._proc.kill()  # simulate a crash of the encoder
            for _ in range(200):  # the broken pipe surfaces in write() or at the end of the block
                writer.write(frame)
    assert leftovers(tmp_path) == []
    assert ffmpeg_children() == []


def test_encoder_error_message_has_ffmpeg_stderr(tmp_path):
    # x264 refuses frames wider than its limit (16384 pixels): ffmpeg fails on the first frame.
    path = tmp_path / "wide.mp4"
    with pytest.raises(OutputError, match=r"wide\.mp4: ffmpeg failed to encode the video \(exit status \d+\): \[libx264\]"):
        with VideoWriter(path, 25, (16400, 2)) as writer:
            writer.write(np.zeros((2, 16400, 3), np.uint8))
    assert leftovers(tmp_path) == []


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
