"""Video files in and out: decoding and H.264 encoding with PyAV, in background threads.

Inside the library a video frame is, like every image, RGB ``uint8`` with shape ``(H, W, 3)``.
This module only reads and writes frames; :mod:`vehicle_detection.pipeline.video` runs the
detector over them.

Design
------
* **PyAV** (FFmpeg's libraries, linked into this process) does the demuxing, decoding, colour
  conversion and encoding. Frames arrive as numpy arrays without crossing a pipe, failures are
  exceptions rather than log text to parse, the frame count comes from the container's own
  index, and timestamps are exact rationals.
* Decoding (demux, decode, convert to RGB) runs in a background thread that feeds the caller
  through a bounded queue; encoding (convert to YUV, encode, mux) runs in another thread fed the
  same way. FFmpeg releases the GIL while it works, so both overlap with the detector, and
  memory stays bounded by the queues. Closing a reader early or leaving a writer's ``with``
  block by an exception (Ctrl-C included) stops its thread at the next frame. The decoder uses
  slice threads only: frame threads report a damaged packet only after they have output its
  frames (see "Damaged files"), and the detector keeps both cores busy anyway.
* Input paths are opened as ``file:`` URLs with only the file protocol allowed, so a name such as
  ``http:x.mp4`` is a file name, and a playlist cannot make FFmpeg open network URLs.

Frame order and count
---------------------
:func:`read_frames` yields every decoded frame of the first video stream exactly once, in the
decoder's output (presentation) order: frame ``i`` of the iterator is decoded frame ``i``.
Nothing is duplicated or dropped to fit a constant rate, so a variable-frame-rate file keeps one
frame per decoded frame. Frames are turned upright when the file carries a display matrix
(rotation by a multiple of 90 degrees, possibly mirrored), as FFmpeg's players do; other angles
are ignored. :attr:`VideoInfo.width` and :attr:`VideoInfo.height` give the upright size. If the
coded size changes mid-stream, later frames are scaled to the size of the first.

Damaged files
-------------
A file that cannot be opened, has no video stream, or yields no frame raises
:class:`~vehicle_detection.errors.InputError` from :func:`probe_video` or :func:`read_frames`.
A file that is damaged part-way yields every frame decoded before the damage, and then the
iterator raises :class:`~vehicle_detection.errors.InputError` naming the file and the number of
frames read. Damage is any of: the demuxer fails or flags a packet as corrupt (cut short by
the end of the file, or MPEG-TS packets missing), the decoder rejects a packet, or the file ends
before the last packet its index (MP4, MOV) lists. The few frames the decoder still holds for
reordering at that point are dropped, so that the frames yielded are exactly decoded frames
``0 .. n-1``. Errors that the decoder conceals without reporting them are not detected. A file
with no index (MPEG-TS, MPEG-PS) that is cut at the end, between packets, cannot be told from a
shorter file.

Written files
-------------
:class:`VideoWriter` writes H.264 (libx264), ``yuv420p``, converted with the BT.709 matrix to
limited range and tagged so (primaries, transfer, matrix: BT.709; range: limited), in MP4 with
``+faststart`` so that browsers can play it while it downloads. 4:2:0 video needs even
dimensions, so a frame with an odd width or height is padded with one black column on the right
or one black row at the bottom. Reading the file back gives the padded, even size. Because
chroma is shared by 2x2 pixel blocks, the padding can take on a faint tint of the neighbouring
colour. The file appears under its final name only when it is complete (see
:func:`vehicle_detection.io.atomic_output`); an abandoned file is deleted without first being finished.
"""

from __future__ import annotations

import math
import os
import queue
import threading
from collections.abc import Generator, Iterable, Iterator
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import av
import numpy as np
from av.video.reformatter import VideoReformatter

from ._files import _signals_deferred, atomic_output, check_output_path, input_file
from .progress import plural
from .timeline import Timeline, timing
from ..errors import InputError, OutputError

__all__ = ["VideoInfo", "probe_video", "read_frames", "VideoWriter", "Encoding", "X264_PRESETS", "VIDEO_SUFFIXES",
           "check_video_output"]

#: The file name suffixes of the MP4 files :class:`VideoWriter` writes (any case).
VIDEO_SUFFIXES = (".mp4", ".m4v", ".mov")


def check_video_output(path: str | os.PathLike) -> Path:
    """Refuse an annotated video's path whose suffix is not an MP4's (``o.png`` would hold MP4 bytes).

    Raises
    ------
    OutputError
        Naming the path and the suffixes accepted.
    """
    path = Path(path)
    if path.suffix.lower() not in VIDEO_SUFFIXES:
        raise OutputError(f"{path}: an annotated video is written as MP4; name it {' or '.join(VIDEO_SUFFIXES)}, "
                          f"not {path.suffix or 'without a suffix'}")
    return path

#: Largest decoded frame index anything here takes (a video of 2**31 frames runs for over two
#: years at 30 frames a second).
MAX_FRAME = 2**31 - 1

X264_PRESETS = (
    "ultrafast",
    "superfast",
    "veryfast",
    "faster",
    "fast",
    "medium",
    "slow",
    "slower",
    "veryslow",
    "placebo",
)


@dataclass(frozen=True)
class Encoding:
    """How an annotated video is encoded: x264's speed preset and quality.

    Parameters
    ----------
    preset : str, default "ultrafast"
        One of :data:`X264_PRESETS`. ``ultrafast`` leaves the most CPU to the detector (files
        about twice the size of ``veryfast`` at the same ``crf``).
    crf : int, default 23
        Constant rate factor, 0 (lossless) to 51; lower is better and larger.
    """

    preset: str = "ultrafast"
    crf: int = 23

    def __post_init__(self) -> None:
        if self.preset not in X264_PRESETS:
            raise ValueError(f"preset must be one of {', '.join(X264_PRESETS)}; got {self.preset!r}")
        if isinstance(self.crf, bool) or not isinstance(self.crf, (int, np.integer)) or not 0 <= self.crf <= 51:
            raise ValueError(f"crf must be an integer from 0 to 51, got {self.crf!r}")

#: Frames buffered between :meth:`VideoWriter.write` and the encoder thread.
_WRITE_QUEUE_SIZE = 4
#: Bytes the muxer collects before each write to the output file.
_OUTPUT_BUFFER_BYTES = 1 << 20
#: Decoder threading: slice threads only (one thread for single-slice streams). Frame threads
#: report a decoding error only after they have output the damaged frames, which would break
#: the rule that only frames from before the damage are yielded; the detector keeps both cores
#: busy anyway.
_DECODER_THREAD_TYPE = "SLICE"

#: FFmpeg's codes for BT.709 (AVCOL_PRI_BT709 = AVCOL_TRC_BT709 = AVCOL_SPC_BT709) and for
#: limited ("tv", "MPEG") range (AVCOL_RANGE_MPEG).
_BT709 = 1
_LIMITED_RANGE = 1

_END = object()  # end-of-stream marker in the frame queues

#: Display matrix (signs of its 2x2 part, row-major) -> (np.rot90 quarter turns, then mirror
#: left-right), matching what FFmpeg's autorotation shows.
_ORIENTATIONS = {
    (1, 0, 0, 1): (0, False),
    (0, -1, 1, 0): (1, False),
    (-1, 0, 0, -1): (2, False),
    (0, 1, -1, 0): (3, False),
    (-1, 0, 0, 1): (0, True),
    (1, 0, 0, -1): (2, True),
    (0, -1, -1, 0): (1, True),
    (0, 1, 1, 0): (3, True),
}


# --------------------------------------------------------------------------------------------
# Helpers
# --------------------------------------------------------------------------------------------


def _reason(exc: BaseException) -> str:
    """One line saying what went wrong, without the file name (the caller adds it)."""
    if isinstance(exc, av.error.FFmpegError):
        text = exc.strerror or type(exc).__name__
    elif isinstance(exc, OSError):
        text = exc.strerror or str(exc)
    else:
        text = str(exc) or type(exc).__name__
    return " ".join(text.split())


def _url(path: Path) -> str:
    # "file:" stops FFmpeg from reading "a:b.mp4" as protocol "a".
    return "file:" + os.fspath(path.absolute())


def _put(q: queue.Queue, item, stop: threading.Event) -> bool:
    """Put ``item`` on a bounded queue unless ``stop`` is set first; return whether it was put."""
    while not stop.is_set():
        try:
            q.put(item, timeout=0.05)
            return True
        except queue.Full:
            continue
    return False


def _drain(q: queue.Queue) -> None:
    try:
        while True:
            q.get_nowait()
    except queue.Empty:
        pass


# --------------------------------------------------------------------------------------------
# Probing
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class VideoInfo:
    """What :func:`probe_video` found out about a video file.

    Attributes
    ----------
    width, height : int
        Size in pixels of the frames :func:`read_frames` yields: the size of the first decoded
        frame, swapped when the file asks for a 90 or 270 degree display rotation.
    fps : float
        Average frame rate in frames per second: the container's average rate, else the rate
        the codec declares, else the stream's base rate; 0.0 if none is known. It is the float
        of an exact rational, so ``Fraction(fps).limit_denominator(10_000)`` gives back rates
        such as ``30000 / 1001``.
    n_frames : int or None
        Number of frames the container declares (MP4/MOV: the video track's sample table; some
        other containers have a count in their header), else estimated as
        ``round(duration * fps)``, or None if unknown. Use it for progress bars and
        plausibility checks, not as a promise: :func:`read_frames` yields the frames that
        actually decode (an MP4 edit list, for one, can hide some).
    duration : float or None
        Duration in seconds that the container declares (all streams), or None if unknown.
    """

    width: int
    height: int
    fps: float
    n_frames: int | None
    duration: float | None

    @property
    def size(self) -> tuple[int, int]:
        """``(width, height)``, the order :class:`VideoWriter` takes."""
        return (self.width, self.height)


@dataclass(frozen=True)
class _Layout:
    """How to decode a probed file: stream, coded frame size, and the turn to upright."""

    stream_index: int
    coded_width: int
    coded_height: int
    quarter_turns: int
    mirror: bool


class _Damage(Exception):
    """Raised inside the decoding loop; the caller turns it into an InputError naming the file."""


def _open_input(path: Path) -> av.container.InputContainer:
    try:
        # Metadata are never used; undecodable text in them must not make the file unreadable.
        return av.open(_url(path), "r", container_options={"protocol_whitelist": "file"}, metadata_errors="replace")
    except av.error.PermissionError as exc:
        raise InputError(f"{path}: cannot read file: {_reason(exc)}") from None
    except av.error.FFmpegError as exc:
        raise InputError(f"{path}: not a readable video file ({_reason(exc)})") from None


def _video_stream(container: av.container.InputContainer, path: Path) -> av.video.stream.VideoStream:
    for stream in container.streams.video:
        if not stream.disposition & av.stream.Disposition.attached_pic:  # skip cover pictures
            if stream.codec_context is None:
                raise InputError(f"{path}: no decoder for the video stream (unknown codec, or a damaged header)")
            return stream
    raise InputError(f"{path}: contains no video stream")


def _orientation(frame: av.VideoFrame) -> tuple[int, bool]:
    """``(quarter_turns, mirror)`` that turn ``frame`` upright, from its display matrix."""
    side = frame.side_data.get("DISPLAYMATRIX")
    if side is None:
        return 0, False
    matrix = np.frombuffer(bytes(side), dtype=np.int32)
    if matrix.size != 9:
        return 0, False
    unit = matrix[[0, 1, 3, 4]] / 65536.0  # 16.16 fixed point
    snapped = np.round(unit)
    if np.abs(unit - snapped).max() > 0.02:  # not a multiple of 90 degrees
        return 0, False
    return _ORIENTATIONS.get(tuple(int(v) for v in snapped), (0, False))


def _setup_decoder(stream: av.video.stream.VideoStream, threads: int) -> None:
    ctx = stream.codec_context
    ctx.thread_type = _DECODER_THREAD_TYPE
    ctx.thread_count = threads


def _decoded_frames(container, stream, path: Path) -> Iterator[av.VideoFrame]:
    """Every decoded frame of ``stream`` in output order; raises :class:`_Damage` after the last good one."""
    damage = None
    try:
        for packet in container.demux(stream):
            if packet.size == 0:  # the demuxer's end-of-stream marker: flushed below
                continue
            if packet.is_corrupt:
                damage = "the demuxer found a damaged or cut-short packet"
                break
            try:
                frames = stream.decode(packet)
            except av.error.FFmpegError as exc:
                damage = f"the {stream.codec_context.name} decoder rejected a packet ({_reason(exc)})"
                break
            yield from frames
        else:
            entries = stream.index_entries
            if len(entries):
                last = entries[len(entries) - 1]
                if last.pos >= 0 and last.pos + last.size > path.stat().st_size:
                    damage = "the file ends before the last packet its index lists"
    except av.error.FFmpegError as exc:
        damage = f"reading the file failed ({_reason(exc)})"
    if damage is None:
        try:
            yield from stream.decode(None)  # frames still held for reordering
        except av.error.FFmpegError as exc:
            damage = f"the {stream.codec_context.name} decoder failed at the end ({_reason(exc)})"
    if damage is not None:
        # The frames the decoder still holds are dropped: with a packet missing they could
        # come out with a gap, and frame i would no longer be decoded frame i.
        raise _Damage(damage)


def _damaged(path: Path, n_read: int, declared: int | None, damage: _Damage) -> InputError:
    if n_read == 0:
        return InputError(f"{path}: no video frame could be decoded: {damage}")
    read = f"{n_read} of the {declared} frames the file declares" if declared else plural(n_read, "frame")
    return InputError(f"{path}: video is damaged or truncated: decoded {read}, then {damage}")


def _probe(path: str | os.PathLike) -> tuple[Path, VideoInfo, _Layout]:
    """Probe ``path``; return it as a Path, its :class:`VideoInfo` and how to decode it."""
    path = Path(path)
    try:
        st = path.stat()
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read file: {exc.strerror or exc}") from None
    if path.is_dir():
        raise InputError(f"{path}: is a folder, not a video file")
    input_file(path, "video file")  # a device or a FIFO: refused before it is opened
    if st.st_size == 0:
        raise InputError(f"{path}: file is empty")

    with _open_input(path) as container:
        stream = _video_stream(container, path)
        # The first frame gives the real frame size and the display matrix (PyAV exposes the
        # matrix on frames only).
        _setup_decoder(stream, 0)  # one frame: FFmpeg chooses the threads
        declared = stream.frames or None
        first = None
        try:
            first = next(_decoded_frames(container, stream, path), None)
        except _Damage as damage:
            raise _damaged(path, 0, declared, damage) from None
        if first is None:
            raise InputError(f"{path}: no video frame could be decoded (the video stream is empty)")
        turns, mirror = _orientation(first)
        width, height = (first.height, first.width) if turns % 2 else (first.width, first.height)
        ctx = stream.codec_context
        rate = stream.average_rate or ctx.framerate or stream.base_rate
        fps = float(rate) if rate and rate > 0 else 0.0
        duration = container.duration / av.time_base if container.duration and container.duration > 0 else None
        n_frames = declared
        if n_frames is None and duration is not None and fps > 0:
            n_frames = round(duration * fps)
        layout = _Layout(stream.index, first.width, first.height, turns, mirror)
    info = VideoInfo(width=width, height=height, fps=fps, n_frames=n_frames, duration=duration)
    return path, info, layout


def probe_video(path: str | os.PathLike) -> VideoInfo:
    """Read a video file's header and first frame: frame size, frame rate, frame count, duration.

    Parameters
    ----------
    path : path-like
        The video file.

    Returns
    -------
    VideoInfo
        Facts about the first video stream (cover pictures are skipped).

    Raises
    ------
    InputError
        If the file does not exist, is a folder, is empty, is not something FFmpeg can open,
        has no video stream, or its first frame does not decode. The message names the file
        and the reason.

    Notes
    -----
    Only the header and the first frame are decoded, so a file damaged further on probes
    fine; :func:`read_frames` reports the damage.
    """
    return _probe(path)[1]


# --------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------


def read_frames(
    path: str | os.PathLike, *, prefetch: int = 4, threads: int = 0, timeline: Timeline | None = None
) -> Generator[np.ndarray, None, None]:
    """Decode a video file frame by frame.

    The file is probed right away, so a missing or unreadable file raises here. Decoding starts
    at the first ``next()`` and then runs in a background thread, up to ``prefetch`` frames
    ahead of the consumer.

    Parameters
    ----------
    path : path-like
        The video file.
    prefetch : int, default 4
        Decoded frames to buffer (at 720p, 2.7 MB each).
    threads : int, default 0
        Decoder (slice) threads and colour conversion threads; 0 lets FFmpeg choose (one per
        core). A process that shares the cores with others gives its share.
    timeline : Timeline, optional
        Filled with the seconds of the stages ``decode``, ``to_rgb`` and ``decoder_wait`` (the
        decoder thread) and ``read_wait`` (the consumer's wait for a frame).

    Yields
    ------
    ndarray of uint8, shape (height, width, 3)
        Every decoded frame of the first video stream exactly once, in order, as RGB. Each is a
        new C-contiguous, writeable array that the consumer owns. See the module docstring for
        variable frame rates and rotation.

    Raises
    ------
    InputError
        If :func:`probe_video` refuses the file, or, after the last good frame, if the file is
        damaged part-way. See "Damaged files" in the module docstring.
    ValueError
        If ``prefetch`` is not a positive integer.

    Notes
    -----
    Stopping early (``break``) stops the decoding thread as soon as the generator is closed.
    CPython does this when the last reference disappears, for example with
    ``for frame in read_frames(p): ... break``. When you keep a reference, call ``.close()`` or
    use :func:`contextlib.closing`.

    Examples
    --------
    >>> from contextlib import closing
    >>> with closing(read_frames("test_video.mp4")) as frames:  # doctest: +SKIP
    ...     first = next(frames)
    >>> first.shape  # doctest: +SKIP
    (720, 1280, 3)
    """
    if isinstance(prefetch, bool) or not isinstance(prefetch, (int, np.integer)) or prefetch < 1:
        raise ValueError(f"prefetch must be a positive integer, got {prefetch!r}")
    threads = _check_threads(threads)
    path, _, layout = _probe(path)
    return _decode(path, layout, int(prefetch), threads, timeline)


def _check_threads(threads) -> int:
    if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads < 0:
        raise ValueError(f"threads must be a whole number >= 0 (0: FFmpeg chooses), got {threads!r}")
    return int(threads)


def _to_rgb(frame: av.VideoFrame, layout: _Layout, scaler: VideoReformatter, threads: int) -> np.ndarray:
    """An upright RGB copy of ``frame`` that nothing else references."""
    rgb = scaler.reformat(frame, width=layout.coded_width, height=layout.coded_height, format="rgb24", threads=threads)
    array = rgb.to_ndarray()  # a view of the new frame's buffer, which it keeps alive
    if layout.quarter_turns:
        array = np.rot90(array, layout.quarter_turns)
    if layout.mirror:
        array = array[:, ::-1]
    # Copy if the view is strided (rotated, or rows padded for alignment) or is the decoder's
    # own buffer (an RGB codec needs no conversion).
    if rgb is frame or not (array.flags.c_contiguous and array.flags.writeable):
        array = array.copy(order="C")
    return array


class _DecodeState:
    """Filled in by the decoder thread for the consumer."""

    def __init__(self) -> None:
        self.error: BaseException | None = None


def _decoder_thread(
    path: Path,
    layout: _Layout,
    q: queue.Queue,
    stop: threading.Event,
    state: _DecodeState,
    threads: int,
    timeline: Timeline | None,
) -> None:
    n_read = 0
    try:
        with _open_input(path) as container:
            stream = container.streams[layout.stream_index]
            _setup_decoder(stream, threads)
            scaler = VideoReformatter()
            clock = timing(timeline)
            try:
                t = clock.now()
                for frame in _decoded_frames(container, stream, path):
                    t = clock.lap("decode", t)
                    rgb = _to_rgb(frame, layout, scaler, threads)
                    t = clock.lap("to_rgb", t)
                    if not _put(q, rgb, stop):
                        return
                    t = clock.lap("decoder_wait", t)
                    n_read += 1
            except _Damage as damage:
                state.error = _damaged(path, n_read, stream.frames or None, damage)
    except InputError as exc:
        state.error = exc
    except av.error.FFmpegError as exc:
        state.error = InputError(f"{path}: decoding failed after {plural(n_read, 'frame')}: {_reason(exc)}")
    except BaseException as exc:  # a bug: re-raised as it is in the consumer's thread
        state.error = exc
    finally:
        _put(q, _END, stop)


def _decode(
    path: Path, layout: _Layout, prefetch: int, threads: int, timeline: Timeline | None
) -> Generator[np.ndarray, None, None]:
    q: queue.Queue = queue.Queue(maxsize=prefetch)
    stop = threading.Event()
    state = _DecodeState()
    thread = threading.Thread(
        target=_decoder_thread,
        args=(path, layout, q, stop, state, threads, timeline),
        name="vehicle_detection-video-decoder",
        daemon=True,
    )
    thread.start()
    n_yielded = 0
    clock = timing(timeline)
    try:
        while True:
            t = clock.now()
            item = q.get()
            clock.lap("read_wait", t)
            if item is _END:
                break
            n_yielded += 1
            yield item
    finally:
        # On early close or an exception: unblock a put the thread may be waiting in, and wait
        # for it to close the file (it checks ``stop`` after every frame).
        stop.set()
        _drain(q)
        thread.join()
    if state.error is not None:
        raise state.error
    if n_yielded == 0:
        raise InputError(f"{path}: no video frame could be decoded")


# --------------------------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------------------------


class _OutputFile:
    """The temporary output file, handed to PyAV's muxer as a Python file object.

    Writes are unbuffered and complete (the muxer ignores short writes). With ``+faststart``
    the muxer reopens the file by :attr:`name` to move the index to the front; an absolute path
    is never taken for a protocol. Closing this file before the muxer makes the muxer skip
    writing the index, so abandoning a long video is instant.
    """

    def __init__(self, path: Path) -> None:
        self.name = os.fspath(path.absolute())
        self._raw = open(self.name, "wb", buffering=0)

    def write(self, data) -> int:
        view = memoryview(data).cast("B")
        total = len(view)
        while view:
            view = view[self._raw.write(view) :]
        return total

    def seek(self, offset: int, whence: int = os.SEEK_SET) -> int:
        return self._raw.seek(offset, whence)

    def tell(self) -> int:
        return self._raw.tell()

    def seekable(self) -> bool:
        return True

    def writable(self) -> bool:
        return True

    @property
    def closed(self) -> bool:
        return self._raw.closed

    def close(self) -> None:
        self._raw.close()


class VideoWriter:
    """Encode RGB frames to an H.264 MP4 file, atomically, in a background thread.

    Parameters
    ----------
    path : path-like
        Output file. It appears only once the video is complete (see
        :func:`vehicle_detection.io.atomic_output`). The container is always MP4, whatever
        the suffix, which must be one of :data:`VIDEO_SUFFIXES`.
    fps : float or Fraction
        Frame rate of the output, > 0 (for example :attr:`VideoInfo.fps` of the input). It is
        stored as a fraction with a denominator of at most 10,000, so rates such as
        ``30000 / 1001`` are kept exact.
    size : tuple of int
        ``(width, height)`` of every frame that will be written. Odd values are padded to even
        with a black column on the right or a black row at the bottom, because H.264 4:2:0
        needs even dimensions. The file then has the padded size.
    overwrite : bool, default False
        Allow replacing an existing file at ``path``.
    inputs : iterable of path-like, default ()
        Files being read. ``path`` may never be one of them.
    crf : int, default 23
        x264 constant rate factor, 0 (lossless) to 51. Lower means better quality and larger
        files.
    preset : str, default "veryfast"
        x264 speed preset, one of :data:`X264_PRESETS`. Slower presets give smaller files at
        the same quality.
    threads : int, default 0
        Encoder threads and colour conversion threads; 0 lets FFmpeg choose.
    timeline : Timeline, optional
        Filled with the seconds of the stages ``write`` and ``write_wait`` (:meth:`write`, in
        the caller's thread), ``to_yuv``, ``encode`` and ``encoder_wait`` (the encoder thread).

    Raises
    ------
    ValueError
        If ``fps``, ``size``, ``crf`` or ``preset`` is invalid.
    OutputError
        If ``path`` is an input, a folder, exists without ``overwrite``, or has a suffix not
        in :data:`VIDEO_SUFFIXES`. This is checked here, before any work, and again when the
        file is created.

    Attributes
    ----------
    path : Path
        The final output path.
    fps : float
        Frame rate as given.
    size : tuple of int
        ``(width, height)`` that :meth:`write` expects. The encoded size is
        :attr:`output_size`.

    Notes
    -----
    Use it as a context manager. Entering it creates the temporary file and opens the encoder
    (an encoder that refuses the settings raises :class:`~vehicle_detection.errors.OutputError`
    there). :meth:`write` returns as soon as the frame is queued. When the encoder falls more
    than a few frames behind, it blocks until there is room (backpressure). If the block raises
    (including ``KeyboardInterrupt``), the encoder thread stops, the partial file is deleted,
    and nothing is created under ``path``. If encoding fails, or the block writes no frame,
    :class:`~vehicle_detection.errors.OutputError` is raised with the same cleanup. Call
    :meth:`write` from one thread only.

    Examples
    --------
    >>> with VideoWriter("out.mp4", fps=25, size=(1280, 720)) as writer:  # doctest: +SKIP
    ...     for frame in read_frames("test_video.mp4"):
    ...         writer.write(frame)
    """

    def __init__(
        self,
        path: str | os.PathLike,
        fps: float,
        size: tuple[int, int],
        *,
        overwrite: bool = False,
        inputs: Iterable[str | os.PathLike] = (),
        crf: int = 23,
        preset: str = "veryfast",
        threads: int = 0,
        timeline: Timeline | None = None,
    ) -> None:
        try:
            fps_value = float(fps)
        except (TypeError, ValueError):
            raise ValueError(f"fps must be a positive number, got {fps!r}") from None
        if not (math.isfinite(fps_value) and fps_value > 0):
            raise ValueError(f"fps must be a positive number, got {fps!r}")
        try:
            width, height = size
        except (TypeError, ValueError):
            raise ValueError(f"size must be (width, height), got {size!r}") from None
        if not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) and v > 0 for v in (width, height)):
            raise ValueError(f"size must be two positive integers (width, height), got {size!r}")
        if isinstance(crf, bool) or not isinstance(crf, (int, np.integer)) or not 0 <= crf <= 51:
            raise ValueError(f"crf must be an integer from 0 to 51, got {crf!r}")
        if preset not in X264_PRESETS:
            raise ValueError(f"preset must be one of {', '.join(X264_PRESETS)}; got {preset!r}")
        self.threads = _check_threads(threads)

        self.inputs = tuple(inputs)
        self.overwrite = bool(overwrite)
        self.path = check_output_path(check_video_output(path), overwrite=self.overwrite, inputs=self.inputs)
        self.fps = fps_value
        self._rate = Fraction(fps if isinstance(fps, Fraction) else fps_value).limit_denominator(10_000)
        self.size = (int(width), int(height))
        self.crf = int(crf)
        self.preset = preset
        self._frames_written = 0
        self._atomic = None
        self._file: _OutputFile | None = None
        self._container = None
        self._stream = None
        self._queue: queue.Queue = queue.Queue(maxsize=_WRITE_QUEUE_SIZE)
        self._thread: threading.Thread | None = None
        self._failure: BaseException | None = None
        self._used = False
        self._timeline = timeline

    @property
    def frames_written(self) -> int:
        """Number of frames accepted by :meth:`write` so far."""
        return self._frames_written

    @property
    def output_size(self) -> tuple[int, int]:
        """``(width, height)`` of the encoded video: :attr:`size` rounded up to even numbers."""
        return (self.size[0] + self.size[0] % 2, self.size[1] + self.size[1] % 2)

    def __repr__(self) -> str:
        return f"VideoWriter({os.fspath(self.path)!r}, fps={self.fps:g}, size={self.size})"

    # -- lifecycle ---------------------------------------------------------------------------

    def _open(self, tmp: Path) -> None:
        """Open the MP4 muxer on ``tmp`` and the libx264 encoder."""
        self._file = _OutputFile(tmp)
        self._container = av.open(
            self._file,
            "w",
            format="mp4",
            container_options={"movflags": "+faststart", "protocol_whitelist": "file"},
            buffer_size=_OUTPUT_BUFFER_BYTES,
        )
        stream = self._container.add_stream(
            "libx264", rate=self._rate, options={"crf": str(self.crf), "preset": self.preset}
        )
        stream.width, stream.height = self.output_size
        stream.pix_fmt = "yuv420p"
        ctx = stream.codec_context
        ctx.thread_count = self.threads
        ctx.color_range = _LIMITED_RANGE
        ctx.color_primaries = ctx.color_trc = ctx.colorspace = _BT709
        ctx.open()  # a refusal of the settings surfaces here, not at the first frame
        self._stream = stream

    def __enter__(self) -> VideoWriter:
        if self._used:
            raise RuntimeError("a VideoWriter can be used for one 'with' block only; create a new one")
        self._used = True
        self._atomic = atomic_output(self.path, overwrite=self.overwrite, inputs=self.inputs)
        entered = False
        try:
            # A signal between making the temporary file and this block would leave it behind:
            # it interrupts once the block holds the file.
            with _signals_deferred():
                tmp = self._atomic.__enter__()
                entered = True
            try:
                self._open(tmp)
            except (av.error.FFmpegError, OSError) as exc:
                raise OutputError(f"{self.path}: cannot start the H.264 encoder ({self._settings()}): {_reason(exc)}") from None
            self._thread = threading.Thread(
                target=self._encoder_thread, name="vehicle_detection-video-encoder", daemon=True
            )
            self._thread.start()
        except BaseException as exc:
            if entered:  # else atomic_output has cleaned up after itself
                self._abort()
                self._atomic.__exit__(type(exc), exc, exc.__traceback__)
            raise
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is not None:
            self._abort()
            return bool(self._atomic.__exit__(exc_type, exc, tb))  # deletes the partial file
        try:
            self._finish()
        except BaseException as err:
            self._abort()
            self._atomic.__exit__(type(err), err, err.__traceback__)
            raise
        self._atomic.__exit__(None, None, None)  # renames the finished file into place
        return False

    def _settings(self) -> str:
        return "{}x{}, {} fps, preset {}, crf {}".format(*self.output_size, self._rate, self.preset, self.crf)

    def _encoder_thread(self) -> None:
        """Convert, encode and mux the queued frames; flush and close the file at the end marker."""
        scaler = VideoReformatter()
        stream, container, clock = self._stream, self._container, timing(self._timeline)
        pts = 0
        t = clock.now()
        while True:
            item = self._queue.get()
            t = clock.lap("encoder_wait", t)
            if item is _END:
                break
            if self._failure is not None:
                continue  # keep draining so that write() never blocks on a dead encoder
            try:
                rgb = av.VideoFrame.from_numpy_buffer(item, format="rgb24")
                yuv = scaler.reformat(
                    rgb, format="yuv420p", dst_colorspace="ITU709", dst_color_range="MPEG", threads=self.threads
                )
                del rgb, item  # the frame's array is not needed after the conversion
                t = clock.lap("to_yuv", t)
                yuv.pts = pts
                pts += 1
                container.mux(stream.encode(yuv))
                t = clock.lap("encode", t)
            except BaseException as exc:
                self._failure = exc
        if self._failure is None:
            try:
                container.mux(stream.encode(None))  # the frames x264 still holds
                container.close()  # writes the index, moved to the front (+faststart)
                self._file.close()
                clock.lap("encode", t)
            except BaseException as exc:
                self._failure = exc

    def _encode_error(self) -> OutputError:
        return OutputError(f"{self.path}: encoding the video failed: {_reason(self._failure)}")

    def _finish(self) -> None:
        if self._frames_written == 0:
            raise OutputError(f"{self.path}: no frames were written; refusing to create an empty video")
        self._queue.put(_END)
        self._thread.join()
        if self._failure is not None:
            raise self._encode_error()

    def _abort(self) -> None:
        """Stop the encoder thread and close the file without finishing it; never raises."""
        if self._thread is not None and self._thread.is_alive():
            self._failure = self._failure or OutputError("aborted")
            _drain(self._queue)
            self._queue.put(_END)
            self._thread.join()
        if self._file is not None:
            self._file.close()  # first, so that closing the muxer skips writing the index
        if self._container is not None:
            try:
                self._container.close()  # no-op if the thread closed it already
            except Exception:
                pass

    # -- writing -----------------------------------------------------------------------------

    def write(self, frame: np.ndarray, *, copy: bool = True) -> None:
        """Queue one frame for encoding.

        Parameters
        ----------
        frame : ndarray of uint8, shape (height, width, 3)
            RGB pixels of exactly :attr:`size`.
        copy : bool, default True
            Copy the frame, so the caller may reuse the array right away. False hands the
            array itself to the encoder thread when it can be encoded as it is (C-contiguous,
            and of :attr:`output_size`; else it is copied anyway): the caller gives it up and
            must not change it afterwards. That saves a copy of every frame.

        Raises
        ------
        ValueError
            If the frame is not uint8 or does not have shape ``(height, width, 3)``.
        OutputError
            If encoding has failed. The message names the file and the encoder's reason.
        RuntimeError
            If called outside the ``with`` block.
        """
        if self._thread is None or not self._thread.is_alive():
            raise RuntimeError("VideoWriter.write() must be called inside its 'with' block")
        clock = timing(self._timeline)
        t = clock.now()
        frame = np.asarray(frame)
        width, height = self.size
        if frame.shape != (height, width, 3):
            raise ValueError(
                f"frame has shape {frame.shape}, expected {(height, width, 3)} "
                f"(RGB of size={self.size}, i.e. (width, height))"
            )
        if frame.dtype != np.uint8:
            raise ValueError(f"frame has dtype {frame.dtype}, expected uint8 RGB")
        if self._failure is not None:
            raise self._encode_error()
        if self.output_size != self.size:
            item = np.zeros((self.output_size[1], self.output_size[0], 3), np.uint8)
            item[:height, :width] = frame
        elif copy or not frame.flags.c_contiguous:
            item = np.array(frame, dtype=np.uint8, order="C", copy=True)
        else:
            item = frame
        t = clock.lap("write", t)
        self._queue.put(item)
        clock.lap("write_wait", t)
        self._frames_written += 1
