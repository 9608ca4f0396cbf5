"""Video files in and out: decoding and encoding through ffmpeg pipes.

Frames cross the process boundary as raw ``rgb24`` bytes, so inside the library a video frame is,
like every image, RGB ``uint8`` with shape ``(H, W, 3)``. The ffmpeg binary is the one bundled with
imageio-ffmpeg (:func:`imageio_ffmpeg.get_ffmpeg_exe`); ffprobe is not needed.

Design notes
------------
* **Own** :class:`subprocess.Popen` **rather than** ``imageio_ffmpeg.read_frames`` /
  ``write_frames``. It is faster because each frame goes straight from the pipe into a new numpy
  array (``readinto``). imageio yields immutable ``bytes``, so a writeable array costs one more
  720p copy (2.7 MB) per frame. It is more robust because imageio's reader stops quietly at the
  end of the output and never checks ffmpeg's exit status or error messages, so a truncated
  file looks like a short, valid one, and its writer pushes frames through
  ``generator.send()`` in the caller's thread. Here stderr is limited to error messages and
  quoted in exceptions, the exit status is checked, an early close kills and reaps ffmpeg at
  once, and paths are passed as ``file:`` URLs, so a name such as ``cam:1.mp4`` or ``-x.mp4`` is
  never taken for a protocol or an option.
* **Not moviepy**: its reader adds per-frame copies and conversions, plus clip and audio machinery.
* Decoding and encoding each run in a background thread linked to the caller by a bounded
  queue, so ffmpeg works on the next frames (ffmpeg and numpy both release the GIL while doing
  so) while the caller runs the detector on the current one. Memory stays bounded by the queue.
* ffmpeg is started in its own process group, so Ctrl-C reaches only Python, which then kills
  ffmpeg itself. ffmpeg never sees the signal and never acts on it by itself.

Frame order and count
---------------------
:func:`read_frames` yields every decoded frame of the first video stream exactly once, in
decoding output (presentation) order. It uses ``-fps_mode passthrough``, so for variable-frame-rate
files, frame ``i`` of the iterator is decoded frame ``i``: no frame is duplicated or dropped to
fit a constant rate. Frames are rotated upright as ffmpeg does by default when the file carries
a display-rotation matrix. :attr:`VideoInfo.width` and :attr:`VideoInfo.height` give that
upright size.

Damaged files
-------------
A file that cannot be opened, has no video stream, or yields no frame raises
:class:`~vehicle_detection.errors.InputError` from :func:`probe_video` or :func:`read_frames`.
A file that is truncated or corrupt part-way through yields every frame that decodes before the
damage, and then the iterator raises :class:`~vehicle_detection.errors.InputError`, naming the
file, when

* ffmpeg exits with a non-zero status, or
* ffmpeg logged at least one error **and** fewer frames came out than
  :attr:`VideoInfo.n_frames` announced.

Decoding errors that do not cost any frame, such as a damaged first GOP that the decoder
conceals, are tolerated silently. When ``n_frames`` is unknown, the second rule cannot apply.

Written files
-------------
:class:`VideoWriter` writes H.264 (libx264), ``yuv420p``, BT.709 limited range (tagged), in MP4
with ``+faststart`` so that browsers can play it while it downloads. 4:2:0 video needs even
dimensions, so a frame with an odd width or height is padded with one black column on the right
or one black row at the bottom. Reading the file back gives the padded, even size. Because
chroma is shared by 2x2 pixel blocks, the padding can take on a faint tint of the neighbouring
colour. The file
appears under its final name only when it is complete (see :mod:`vehicle_detection._files`).
"""

from __future__ import annotations

import io
import itertools
import math
import os
import queue
import re
import struct
import subprocess
import sys
import threading
from collections.abc import Generator, Iterable
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np

from ._files import atomic_output, check_output_path
from .errors import InputError, OutputError

__all__ = ["VideoInfo", "probe_video", "read_frames", "VideoWriter", "X264_PRESETS"]

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

#: Frames buffered between :meth:`VideoWriter.write` and the encoder thread.
_WRITE_QUEUE_SIZE = 4
#: Seconds to wait for ffmpeg to finish reading the header of an input file.
_PROBE_TIMEOUT = 60.0
#: How much of ffmpeg's stderr goes into an error message.
_STDERR_TAIL_CHARS = 600
#: Memory addresses in ffmpeg's log prefixes ("[h264 @ 0x55d0...]"): noise in an error message.
_ADDRESS_RE = re.compile(r" @ 0x[0-9a-fA-F]+")
#: A ``moov`` box larger than this is not read to count frames (n_frames is estimated instead).
_MAX_MOOV_BYTES = 256 * 1024 * 1024

_END = object()  # end-of-stream marker in the frame queues


# --------------------------------------------------------------------------------------------
# ffmpeg process helpers
# --------------------------------------------------------------------------------------------


def _ffmpeg_exe() -> str:
    import imageio_ffmpeg  # imported lazily: only the video functions need it

    return imageio_ffmpeg.get_ffmpeg_exe()


def _file_url(path: Path) -> str:
    # "file:" stops ffmpeg from reading "a:b.mp4" as protocol "a" or "-x.mp4" as an option.
    return "file:" + os.fspath(path.absolute())


def _popen(cmd: list[str], *, stdin, stdout) -> subprocess.Popen:
    kwargs: dict = {}
    if sys.platform == "win32":
        kwargs["creationflags"] = subprocess.CREATE_NEW_PROCESS_GROUP
    else:
        kwargs["start_new_session"] = True
    return subprocess.Popen(cmd, stdin=stdin, stdout=stdout, stderr=subprocess.PIPE, bufsize=0, **kwargs)


def _reap(proc: subprocess.Popen, *, kill: bool, timeout: float | None = None) -> int:
    """Make sure ``proc`` has exited and been waited for (no zombie); return its exit status.

    With ``kill`` it is killed first. Otherwise it gets ``timeout`` seconds (None: no limit) to
    exit by itself before it is killed.
    """
    if kill and proc.poll() is None:
        try:
            proc.kill()
        except OSError:  # already gone
            pass
    try:
        return proc.wait(timeout=None if kill else timeout)
    except subprocess.TimeoutExpired:
        proc.kill()
        return proc.wait()


def _shorten(text: str, limit: int = _STDERR_TAIL_CHARS) -> str:
    text = " | ".join(line.strip() for line in text.splitlines() if line.strip())
    return text if len(text) <= limit else text[: limit - 3] + "..."


class _StderrCollector(threading.Thread):
    """Drain a process's stderr (so it never blocks on a full pipe), keeping its first and last lines.

    ffmpeg states the cause of a failure first and then one line per task that gave up, so an
    error report needs both ends.
    """

    def __init__(self, stream) -> None:
        super().__init__(name="vehicle_detection-ffmpeg-stderr", daemon=True)
        self._stream = stream
        self._first: list[str] = []
        self._last = ""
        self.n_lines = 0

    def run(self) -> None:
        try:
            # The pipe is unbuffered (bufsize=0); buffer it here so readline is not byte by byte.
            for raw in io.BufferedReader(self._stream):
                line = _ADDRESS_RE.sub("", raw.decode("utf-8", "replace")).strip()
                if line:
                    self.n_lines += 1
                    if len(self._first) < 2:
                        self._first.append(line)
                    else:
                        self._last = line
        except (OSError, ValueError):  # stream closed under us
            pass
        finally:
            try:
                self._stream.close()
            except OSError:
                pass

    def summary(self) -> str:
        """The first two lines of ffmpeg's complaint and the last one, shortened."""
        if not self.n_lines:
            return "(ffmpeg printed no error message)"
        lines = list(self._first)
        if self._last:
            skipped = self.n_lines - len(lines) - 1
            lines += ([f"[{skipped} more]"] if skipped > 0 else []) + [self._last]
        return _shorten("\n".join(lines))

    def first(self) -> str:
        return _shorten(self._first[0], 300) if self._first else ""


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
        Size in pixels of the frames :func:`read_frames` yields: the coded size, swapped when
        the file asks for a 90 or 270 degree display rotation.
    fps : float
        Average frame rate in frames per second (ffmpeg's ``avg_frame_rate``, or the stream's
        base rate ``tbr`` if no average is known). NTSC rates such as 29.97 are returned exactly
        as ``30000 / 1001``. It is 0.0 if ffmpeg reports neither rate.
    n_frames : int or None
        Number of frames the container declares. For MP4/MOV it comes from the video track's
        sample table and is exact for an intact file. For other containers it is estimated as
        ``round(duration * fps)``. It is None if unknown. Use it for progress bars and
        plausibility checks, not as a promise: :func:`read_frames` yields the frames that
        actually decode.
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


_INPUT_RE = re.compile(r"^Input #0, (?P<format>.+?), from ", re.M)
_STREAM_RE = re.compile(r"^\s*Stream #0:(?P<index>\d+)[^:]*: (?P<kind>\w+): (?P<rest>.*)$")
_SIZE_RE = re.compile(r"(?<![\w/])(?P<w>\d{1,6})x(?P<h>\d{1,6})(?!\w)")
_FPS_RE = re.compile(r"(?<![\w.])(?P<v>\d+(?:\.\d+)?)(?P<k>k?) fps\b")
_TBR_RE = re.compile(r"(?<![\w.])(?P<v>\d+(?:\.\d+)?)(?P<k>k?) tbr\b")
_DURATION_RE = re.compile(r"^\s*Duration: (?P<h>\d+):(?P<m>\d\d):(?P<s>\d\d(?:\.\d+)?)", re.M)
_ROTATION_RE = re.compile(r"rotation of (?P<deg>-?\d+(?:\.\d+)?) degrees")


def _rate(match: re.Match | None) -> float | None:
    if match is None:
        return None
    value = float(match["v"]) * (1000.0 if match["k"] else 1.0)
    return value if value > 0 else None


def _snap_ntsc(fps: float) -> float:
    """ffmpeg prints rates to two decimals; restore the exact NTSC rates (N * 1000 / 1001)."""
    for base in (24, 30, 48, 60, 120, 240):
        exact = base * 1000 / 1001
        if abs(fps - exact) < 0.006:
            return exact
    return fps


def _ffmpeg_open_error(stderr: str) -> str:
    """The most useful line of ffmpeg's complaint about an input it could not open."""
    for line in stderr.splitlines():
        if "Error opening input:" in line:
            return line.split("Error opening input:", 1)[1].strip()
    lines = [ln for ln in stderr.splitlines() if ln.strip() and "output file must be specified" not in ln]
    return _shorten(lines[-1], 300) if lines else "ffmpeg could not read it"


def _probe(path: str | os.PathLike) -> tuple[Path, VideoInfo, int]:
    """Probe ``path``; return it as a Path, its :class:`VideoInfo` and the ffmpeg stream index."""
    path = Path(path)
    try:
        st = path.stat()
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read file: {exc.strerror or exc}") from None
    if path.is_dir():
        raise InputError(f"{path}: is a folder, not a video file")
    if st.st_size == 0:
        raise InputError(f"{path}: file is empty")

    cmd = [_ffmpeg_exe(), "-hide_banner", "-nostdin", "-i", _file_url(path)]
    proc = _popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL)
    try:
        _, err = proc.communicate(timeout=_PROBE_TIMEOUT)
    except subprocess.TimeoutExpired:
        _reap(proc, kill=True)
        raise InputError(f"{path}: ffmpeg could not read the header within {_PROBE_TIMEOUT:g} s") from None
    except BaseException:
        _reap(proc, kill=True)
        raise
    stderr = err.decode("utf-8", "replace")

    header = _INPUT_RE.search(stderr)
    if header is None:
        raise InputError(f"{path}: not a readable video file (ffmpeg: {_ffmpeg_open_error(stderr)})")
    container = header["format"]

    # First video stream that is a real stream, not a cover picture.
    lines = stderr[header.start() :].splitlines()
    for i, line in enumerate(lines):
        m = _STREAM_RE.match(line)
        if m and m["kind"] == "Video" and "(attached pic)" not in line:
            stream_index, rest = int(m["index"]), m["rest"]
            block = []  # the stream's indented metadata and side data
            for following in lines[i + 1 :]:
                if _STREAM_RE.match(following) or not following.startswith("    "):
                    break
                block.append(following)
            break
    else:
        raise InputError(f"{path}: contains no video stream")

    size = _SIZE_RE.search(rest)
    if size is None or int(size["w"]) == 0 or int(size["h"]) == 0:
        raise InputError(f"{path}: cannot determine the frame size of the video stream ({_shorten(rest, 200)})")
    width, height = int(size["w"]), int(size["h"])
    rotation = _ROTATION_RE.search("\n".join(block))
    if rotation is not None and round(float(rotation["deg"])) % 180 == 90:
        width, height = height, width  # ffmpeg's autorotation turns the frames upright

    fps = _rate(_FPS_RE.search(rest)) or _rate(_TBR_RE.search(rest)) or 0.0
    fps = _snap_ntsc(fps)

    d = _DURATION_RE.search(stderr)
    duration = int(d["h"]) * 3600 + int(d["m"]) * 60 + float(d["s"]) if d else None
    if duration is not None and duration <= 0:
        duration = None

    n_frames = None
    if "mp4" in container.split(",") or "mov" in container.split(","):
        n_frames = _mp4_sample_count(path, stream_index)
    if n_frames is None and duration is not None and fps > 0:
        n_frames = round(duration * fps)
    return path, VideoInfo(width=width, height=height, fps=fps, n_frames=n_frames, duration=duration), stream_index


def probe_video(path: str | os.PathLike) -> VideoInfo:
    """Read a video file's header: frame size, frame rate, frame count and duration.

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
        If the file does not exist, is a folder, is empty, is not something ffmpeg can open, or
        has no video stream. The message names the file and quotes ffmpeg's reason.

    Notes
    -----
    Only the header is read: the file is not decoded. A file truncated part-way may therefore
    probe fine. :func:`read_frames` reports the damage.
    """
    return _probe(path)[1]


# --- MP4/MOV: the frame count from the sample table (ISO/IEC 14496-12 boxes) -------------------


def _boxes(data: bytes, start: int = 0, end: int | None = None):
    """Yield ``(type, payload_start, payload_end)`` for the boxes in ``data[start:end]``."""
    end = len(data) if end is None else end
    pos = start
    while pos + 8 <= end:
        size, kind = struct.unpack_from(">I4s", data, pos)
        header = 8
        if size == 1:
            if pos + 16 > end:
                return
            (size,) = struct.unpack_from(">Q", data, pos + 8)
            header = 16
        elif size == 0:
            size = end - pos
        if size < header or pos + size > end:
            return
        yield kind, pos + header, pos + size
        pos += size


def _child(data: bytes, start: int, end: int, kind: bytes) -> tuple[int, int] | None:
    for k, s, e in _boxes(data, start, end):
        if k == kind:
            return s, e
    return None


def _read_moov(path: Path) -> bytes | None:
    with open(path, "rb") as f:
        file_size = f.seek(0, os.SEEK_END)
        pos = 0
        while pos + 8 <= file_size:
            f.seek(pos)
            head = f.read(16)
            if len(head) < 8:
                return None
            size, kind = struct.unpack_from(">I4s", head)
            header = 8
            if size == 1 and len(head) == 16:
                (size,) = struct.unpack_from(">Q", head, 8)
                header = 16
            elif size == 0:
                size = file_size - pos
            if size < header:
                return None
            if kind == b"moov":
                if size - header > _MAX_MOOV_BYTES:
                    return None
                f.seek(pos + header)
                data = f.read(size - header)
                return data if len(data) == size - header else None
            pos += size
    return None


def _mp4_sample_count(path: Path, stream_index: int) -> int | None:
    """Samples (frames) in MP4/MOV track number ``stream_index``, if it is a video track.

    ffmpeg's mov demuxer makes one stream per ``trak`` box in file order, so stream ``k`` is the
    ``k``-th track. Returns None for anything unexpected (fragmented MP4, compressed ``moov``,
    damage), and the caller then falls back to an estimate.
    """
    try:
        moov = _read_moov(path)
    except OSError:
        return None
    if moov is None:
        return None
    traks = [(s, e) for k, s, e in _boxes(moov) if k == b"trak"]
    if stream_index >= len(traks):
        return None
    mdia = _child(moov, *traks[stream_index], b"mdia")
    if mdia is None:
        return None
    hdlr = _child(moov, *mdia, b"hdlr")
    if hdlr is None or hdlr[1] - hdlr[0] < 12 or moov[hdlr[0] + 8 : hdlr[0] + 12] != b"vide":
        return None
    minf = _child(moov, *mdia, b"minf")
    stbl = _child(moov, *minf, b"stbl") if minf else None
    if stbl is None:
        return None
    for kind in (b"stsz", b"stz2"):
        box = _child(moov, *stbl, kind)
        if box is not None and box[1] - box[0] >= 12:
            (count,) = struct.unpack_from(">I", moov, box[0] + 8)
            return count if count > 0 else None  # 0: fragmented MP4, frames live in 'moof' boxes
    return None


# --------------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------------


def read_frames(path: str | os.PathLike, *, prefetch: int = 4) -> Generator[np.ndarray, None, None]:
    """Decode a video file frame by frame.

    The file is probed right away, so a missing or unreadable file raises here. ffmpeg starts
    at the first ``next()``. Decoding then runs in a background thread, up to ``prefetch``
    frames ahead of the consumer.

    Parameters
    ----------
    path : path-like
        The video file.
    prefetch : int, default 4
        Decoded frames to buffer (at 720p, 2.7 MB each).

    Yields
    ------
    ndarray of uint8, shape (height, width, 3)
        Every decoded frame of the first video stream exactly once, in order, as RGB. Each is a
        new C-contiguous, writeable array that the consumer owns. See the module docstring for
        variable frame rates and rotation.

    Raises
    ------
    InputError
        If :func:`probe_video` refuses the file, if no frame can be decoded, or, after the last
        good frame, if the file is damaged part-way. See "Damaged files" in the module
        docstring for the exact rule.
    ValueError
        If ``prefetch`` is not a positive integer.

    Notes
    -----
    Stopping early (``break``) stops ffmpeg and the decoding thread as soon as the generator is
    closed. CPython does this when the last reference disappears, for example with
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
    path, info, stream_index = _probe(path)
    return _decode(path, info, stream_index, int(prefetch))


class _DecodeState:
    """Filled in by the decoder thread for the consumer."""

    def __init__(self) -> None:
        self.partial_bytes = 0
        self.error: BaseException | None = None


def _decoder_thread(stdout, shape: tuple[int, int, int], q: queue.Queue, stop: threading.Event, state: _DecodeState) -> None:
    nbytes = shape[0] * shape[1] * shape[2]
    try:
        while not stop.is_set():
            frame = np.empty(shape, dtype=np.uint8)
            view = memoryview(frame).cast("B")
            got = 0
            while got < nbytes:
                n = stdout.readinto(view[got:])
                if not n:
                    break
                got += n
            if got < nbytes:
                state.partial_bytes = got
                break
            if not _put(q, frame, stop):
                return
    except BaseException as exc:  # a read error on the pipe; reported by the consumer
        state.error = exc
    finally:
        _put(q, _END, stop)


def _decode(path: Path, info: VideoInfo, stream_index: int, prefetch: int) -> Generator[np.ndarray, None, None]:
    cmd = [
        _ffmpeg_exe(),
        "-hide_banner",
        "-nostdin",
        "-nostats",
        "-loglevel",
        "error",
        "-i",
        _file_url(path),
        "-map",
        f"0:{stream_index}",
        "-fps_mode",
        "passthrough",
        "-f",
        "rawvideo",
        "-pix_fmt",
        "rgb24",
        "pipe:1",
    ]
    shape = (info.height, info.width, 3)
    proc = _popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE)
    stderr = _StderrCollector(proc.stderr)
    stderr.start()
    q: queue.Queue = queue.Queue(maxsize=prefetch)
    stop = threading.Event()
    state = _DecodeState()
    thread = threading.Thread(
        target=_decoder_thread,
        args=(proc.stdout, shape, q, stop, state),
        name="vehicle_detection-video-decoder",
        daemon=True,
    )
    thread.start()

    n_yielded = 0
    complete = False
    try:
        while True:
            item = q.get()
            if item is _END:
                break
            n_yielded += 1
            yield item
        complete = True
    finally:
        # On early close or an exception: kill ffmpeg first, so a blocked read returns, then
        # unblock a put the thread may be waiting in, then reap everything.
        stop.set()
        returncode = _reap(proc, kill=not complete, timeout=30)
        _drain(q)
        thread.join()
        proc.stdout.close()
        stderr.join()

    if state.error is not None:
        raise InputError(f"{path}: reading decoded frames from ffmpeg failed: {state.error}") from state.error
    if n_yielded == 0:
        raise InputError(f"{path}: no video frame could be decoded: {stderr.summary()}")
    if returncode != 0:
        raise InputError(
            f"{path}: ffmpeg failed to decode the video (exit status {returncode}) "
            f"after {n_yielded} frame(s): {stderr.summary()}"
        )
    if state.partial_bytes:
        raise InputError(
            f"{path}: decoding ended in the middle of frame {n_yielded} ({state.partial_bytes} of "
            f"{shape[0] * shape[1] * 3} bytes); the frame size {info.width}x{info.height} found "
            f"by probing does not match the decoded frames"
        )
    if stderr.n_lines and info.n_frames is not None and n_yielded < info.n_frames:
        raise InputError(
            f"{path}: video is damaged or truncated: decoded {n_yielded} of the {info.n_frames} "
            f"frames the file declares (ffmpeg: {stderr.first()})"
        )


# --------------------------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------------------------


class VideoWriter:
    """Encode RGB frames to an H.264 MP4 file, atomically, in a background thread.

    Parameters
    ----------
    path : path-like
        Output file. It appears only once the video is complete (see
        :func:`vehicle_detection._files.atomic_output`). The container is always MP4, whatever
        the suffix.
    fps : float
        Frame rate of the output, > 0 (for example :attr:`VideoInfo.fps` of the input). Common
        rates such as ``30000 / 1001`` are kept exact.
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

    Raises
    ------
    ValueError
        If ``fps``, ``size``, ``crf`` or ``preset`` is invalid.
    OutputError
        If ``path`` is an input, a folder, or exists without ``overwrite``. This is checked
        here, before any work, and again when the file is created.

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
    Use it as a context manager. :meth:`write` returns as soon as the frame is queued. When the
    encoder falls more than a few frames behind, it blocks until there is room (backpressure).
    If the block raises (including ``KeyboardInterrupt``), ffmpeg
    is killed, the partial file is deleted, and nothing is created under ``path``. If ffmpeg
    fails, or the block writes no frame, :class:`~vehicle_detection.errors.OutputError` is
    raised with the same cleanup. Call :meth:`write` from one thread only.

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

        self.inputs = tuple(inputs)
        self.overwrite = bool(overwrite)
        self.path = check_output_path(path, overwrite=self.overwrite, inputs=self.inputs)
        self.fps = fps_value
        self.size = (int(width), int(height))
        self.crf = int(crf)
        self.preset = preset
        self._frames_written = 0
        self._atomic = None
        self._proc: subprocess.Popen | None = None
        self._stderr: _StderrCollector | None = None
        self._queue: queue.Queue = queue.Queue(maxsize=_WRITE_QUEUE_SIZE)
        self._thread: threading.Thread | None = None
        self._failure: BaseException | None = None
        self._used = False

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

    def _command(self, tmp: Path) -> list[str]:
        width, height = self.size
        rate = Fraction(self.fps).limit_denominator(10_000)
        filters = []
        if self.output_size != self.size:
            filters.append("pad={}:{}:0:0:black".format(*self.output_size))
        # RGB -> YUV with the BT.709 matrix, and tag the stream accordingly, so players (and
        # read_frames) convert back with the same matrix and colours survive the round trip.
        filters.append("scale=out_color_matrix=bt709:out_range=tv,format=yuv420p")
        return [
            _ffmpeg_exe(),
            "-hide_banner",
            "-nostdin",
            "-nostats",
            "-loglevel",
            "error",
            "-f",
            "rawvideo",
            "-pix_fmt",
            "rgb24",
            "-video_size",
            f"{width}x{height}",
            "-framerate",
            f"{rate.numerator}/{rate.denominator}",
            "-i",
            "pipe:0",
            "-vf",
            ",".join(filters),
            "-c:v",
            "libx264",
            "-preset",
            self.preset,
            "-crf",
            str(self.crf),
            "-pix_fmt",
            "yuv420p",
            "-colorspace",
            "bt709",
            "-color_primaries",
            "bt709",
            "-color_trc",
            "bt709",
            "-color_range",
            "tv",
            "-movflags",
            "+faststart",
            "-f",
            "mp4",
            "-y",  # the temporary file exists (empty) already
            _file_url(tmp),
        ]

    def __enter__(self) -> VideoWriter:
        if self._used:
            raise RuntimeError("a VideoWriter can be used for one 'with' block only; create a new one")
        self._used = True
        self._atomic = atomic_output(self.path, overwrite=self.overwrite, inputs=self.inputs)
        tmp = self._atomic.__enter__()
        try:
            self._proc = _popen(self._command(tmp), stdin=subprocess.PIPE, stdout=subprocess.DEVNULL)
            self._stderr = _StderrCollector(self._proc.stderr)
            self._stderr.start()
            self._thread = threading.Thread(
                target=self._encoder_thread, name="vehicle_detection-video-encoder", daemon=True
            )
            self._thread.start()
        except BaseException as exc:
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

    def _encoder_thread(self) -> None:
        assert self._proc is not None and self._proc.stdin is not None
        fd = self._proc.stdin.fileno()
        while True:
            item = self._queue.get()
            if item is _END:
                return
            if self._failure is not None:
                continue  # keep draining so that write() never blocks on a dead encoder
            try:
                view = memoryview(item).cast("B")
                while view:
                    view = view[os.write(fd, view) :]
            except BaseException as exc:  # BrokenPipeError when ffmpeg has died
                self._failure = exc

    def _ffmpeg_error(self, what: str) -> OutputError:
        returncode = self._proc.poll() if self._proc is not None else None
        status = f" (exit status {returncode})" if returncode is not None else ""
        tail = self._stderr.summary() if self._stderr is not None else ""
        return OutputError(f"{self.path}: {what}{status}: {tail}")

    def _finish(self) -> None:
        if self._frames_written == 0:
            raise OutputError(f"{self.path}: no frames were written; refusing to create an empty video")
        self._queue.put(_END)
        self._thread.join()
        if self._failure is not None:
            _reap(self._proc, kill=True)
            self._stderr.join()
            raise self._ffmpeg_error("ffmpeg stopped accepting frames")
        self._proc.stdin.close()  # EOF: ffmpeg flushes the encoder and writes the MP4 index
        returncode = _reap(self._proc, kill=False)  # no time limit: +faststart rewrites the file
        self._stderr.join()
        if returncode != 0:
            raise self._ffmpeg_error("ffmpeg failed to encode the video")

    def _abort(self) -> None:
        """Kill ffmpeg, stop the encoder thread and reap everything; never raises."""
        proc = self._proc
        if proc is not None:
            _reap(proc, kill=True)  # a write blocked on the pipe now fails; the thread drains
        if self._thread is not None and self._thread.is_alive():
            self._failure = self._failure or OutputError("aborted")
            _drain(self._queue)
            self._queue.put(_END)
            self._thread.join()
        if proc is not None:
            try:
                proc.stdin.close()
            except OSError:
                pass
        if self._stderr is not None:
            self._stderr.join()

    # -- writing -----------------------------------------------------------------------------

    def write(self, frame: np.ndarray) -> None:
        """Queue one frame for encoding.

        Parameters
        ----------
        frame : ndarray of uint8, shape (height, width, 3)
            RGB pixels of exactly :attr:`size`. The frame is copied, so the caller may reuse
            the array right away.

        Raises
        ------
        ValueError
            If the frame is not uint8 or does not have shape ``(height, width, 3)``.
        OutputError
            If ffmpeg has failed. The message ends with ffmpeg's last error lines.
        RuntimeError
            If called outside the ``with`` block.
        """
        if self._proc is None or self._thread is None or not self._thread.is_alive():
            raise RuntimeError("VideoWriter.write() must be called inside its 'with' block")
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
            raise self._ffmpeg_error("ffmpeg stopped accepting frames")
        self._queue.put(np.array(frame, dtype=np.uint8, order="C", copy=True))
        self._frames_written += 1
