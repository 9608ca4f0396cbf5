"""Small video files for the tests, made with PyAV directly (not through the code under test)."""

from __future__ import annotations

import os
from fractions import Fraction
from pathlib import Path

import av
import numpy as np


def moving_square_frames(n: int, width: int = 160, height: int = 96) -> list[np.ndarray]:
    """Smooth background with a bright square moving right: easy on H.264, still distinct frames."""
    yy, xx = np.mgrid[0:height, 0:width]
    frames = []
    for i in range(n):
        frame = np.empty((height, width, 3), np.uint8)
        frame[..., 0] = 40 + xx * 150 // width
        frame[..., 1] = 60 + yy * 120 // height
        frame[..., 2] = 90
        x0 = (8 + 10 * i) % max(1, width - 32)
        frame[30:62, x0 : x0 + 32] = (230, 200, 40)
        frames.append(frame)
    return frames


def numbered_frames(n: int, width: int = 96, height: int = 64) -> list[np.ndarray]:
    """Frame ``i`` is flat grey with its number in binary as black/white columns (survives lossy coding)."""
    frames = []
    for i in range(n):
        frame = np.full((height, width, 3), 128, np.uint8)
        for bit in range(8):
            frame[:, 8 * bit + 4 : 8 * bit + 12] = 255 if (i >> bit) & 1 else 0
        frames.append(frame)
    return frames


def frame_number(frame: np.ndarray) -> int:
    """Read back the number :func:`numbered_frames` drew."""
    return sum(1 << bit for bit in range(8) if frame[:, 8 * bit + 6 : 8 * bit + 10].mean() > 128)


def encode(
    path: Path,
    frames: list[np.ndarray],
    *,
    codec: str = "libx264",
    format: str | None = None,
    rate: int | Fraction = 25,
    pts: list[int] | None = None,
    time_base: Fraction | None = None,
    pix_fmt: str = "yuv420p",
    options: dict[str, str] | None = None,
    container_options: dict[str, str] | None = None,
    rotation: float | None = None,
    hflip: bool = False,
    vflip: bool = False,
) -> Path:
    """Encode RGB ``frames`` to ``path`` with PyAV; ``pts`` (in ``time_base``) makes variable rates."""
    height, width = frames[0].shape[:2] if frames else (48, 64)
    with av.open(os.fspath(path), "w", format=format, container_options=container_options or {}) as out:
        stream = out.add_stream(codec, rate=rate, options=options or {})
        stream.width, stream.height, stream.pix_fmt = width, height, pix_fmt
        if time_base is not None:
            stream.codec_context.time_base = time_base
            stream.time_base = time_base
        if rotation is not None or hflip or vflip:
            stream.set_display_rotation(rotation or 0, hflip=hflip, vflip=vflip)
        out.start_encoding()  # writes the header even if there is no frame
        for i, rgb in enumerate(frames):
            frame = av.VideoFrame.from_ndarray(rgb, format="rgb24").reformat(format=pix_fmt)
            if pts is not None:
                frame.pts = pts[i]
                frame.time_base = time_base
            out.mux(stream.encode(frame))
        out.mux(stream.encode(None))
    return path


def copy_packets(src: Path, dest: Path, *, max_frames: int | None = None, loops: int = 1) -> Path:
    """Stream-copy the video of ``src`` (its first ``max_frames`` packets, ``loops`` times over)."""
    with av.open(os.fspath(src)) as inp, av.open(os.fspath(dest), "w") as out:
        ist = inp.streams.video[0]
        ost = out.add_stream_from_template(ist)
        packets = [p for p in inp.demux(ist) if p.size][:max_frames]
        step = max(p.pts for p in packets) + (packets[1].pts - packets[0].pts if len(packets) > 1 else 1)
        for loop in range(loops):
            for p in packets:
                copy = av.Packet(bytes(p))
                copy.pts, copy.dts = p.pts + loop * step, p.dts + loop * step
                copy.time_base, copy.is_keyframe = p.time_base, p.is_keyframe
                copy.stream = ost
                out.mux(copy)
    return dest


def decoded_count(path: Path) -> int:
    """Frames PyAV decodes from the first video stream, errors ignored (a plain reference)."""
    n = 0
    with av.open(os.fspath(path)) as inp:
        stream = inp.streams.video[0]
        for packet in inp.demux(stream):
            if not packet.size:  # the end-of-stream marker: flushed below
                continue
            try:
                n += len(stream.decode(packet))
            except av.error.FFmpegError:
                pass
        n += len(stream.decode(None))
    return n


def packets(path: Path) -> list[tuple[int, int]]:
    """``(pos, size)`` of each video packet in file order."""
    with av.open(os.fspath(path)) as inp:
        return [(p.pos, p.size) for p in inp.demux(video=0) if p.size]
