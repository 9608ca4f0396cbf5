"""Where a video run's time goes: seconds per stage, from every thread of the run.

A :class:`Timeline` is an optional argument of :func:`~vehicle_detection.pipeline.process_video`
(and of the pieces it is made of: :func:`~vehicle_detection.io.read_frames`,
:class:`~vehicle_detection.io.VideoWriter`, :meth:`~vehicle_detection.detector.Detector.track_frames`).
Without one, those functions measure nothing: they time their stages on :data:`UNTIMED`, whose
clock reads 0 and whose laps add nothing (one method call per stage and frame); with one, each
stage adds the seconds it took, frame by frame, twice: on the wall clock
(:func:`time.perf_counter`) and in CPU time of its own thread (:func:`time.thread_time`).

On 2 cores the two differ: a stage whose thread waits for a core takes more wall time than
CPU time, and FFmpeg decodes and x264 encodes in threads of their own, which no stage's thread
time includes. :func:`~vehicle_detection.pipeline.process_video` also records the process's CPU
time over the run (:attr:`Timeline.cpu`), and the table gives the rest as its own line: CPU
time of no stage (FFmpeg's and x264's threads, the garbage collector, the main thread's work
between stages, a thread loading the kernels; ``footage`` counts its own ``read_wait`` again).

The stages, in the order of :data:`STAGES`, and the thread each runs in:

======================  ===========  ======================================================
stage                   thread       what
======================  ===========  ======================================================
``decode``              decoder      demux and decode one frame (FFmpeg)
``to_rgb``              decoder      convert it to RGB (and turn it upright)
``decoder_wait``        decoder      wait for room in the queue to the consumer
``read_wait``           main         wait for the decoder's next frame
``warmup``              main         compile the search kernels (a fresh install), then wait
                                     for the thread that loads them while the first
                                     frames are measured: twice a run
``footage``             main         measure the first frames (horizon, black bars), once
                                     a run; their ``read_wait`` is part of it, and so is a
                                     wait for the kernels when the horizon is read off
                                     the cars
``prepare``             helper       undistort, find lanes (only with a camera)
``search``              search pool  the sliding-window search (:meth:`Detector.windows`)
``search_wait``         main         wait for the search of the next frame in order
``track``               main         advance the tracker, measure distances
``draw``                main         draw lanes and boxes on the frame
``write``               main         hand the frame to the encoder (a copy, if any)
``write_wait``          main         wait for room in the queue to the encoder
``to_yuv``              encoder      convert RGB to YUV 4:2:0 (BT.709)
``encode``              encoder      encode (x264) and mux
``encoder_wait``        encoder      wait for the next frame to encode
======================  ===========  ======================================================

The waits are the time a thread was blocked on its queue (or future), so a stage that keeps
the others waiting shows up as their waits (on the wall clock; a wait takes almost no CPU time).
"""

from __future__ import annotations

import threading
import time
from typing import NamedTuple

__all__ = ["Timeline", "Mark", "STAGES", "UNTIMED", "timing"]

#: Every stage, in pipeline order, with the thread it runs in.
STAGES: dict[str, str] = {
    "decode": "decoder",
    "to_rgb": "decoder",
    "decoder_wait": "decoder",
    "read_wait": "main",
    "warmup": "main",
    "footage": "main",
    "prepare": "helper",
    "search": "search",
    "search_wait": "main",
    "track": "main",
    "draw": "main",
    "write": "main",
    "write_wait": "main",
    "to_yuv": "encoder",
    "encode": "encoder",
    "encoder_wait": "encoder",
}


class Mark(NamedTuple):
    """A moment on both clocks of a :class:`Timeline`, in seconds: what :meth:`Timeline.now` gives."""

    wall: float  #: :func:`time.perf_counter`
    cpu: float  #: :func:`time.thread_time`: CPU time of the thread that took the mark


class Timeline:
    """Seconds spent in each stage of a video run, added up over its frames, from any thread.

    Each stage has wall seconds and CPU seconds of the thread it ran in.

    Attributes
    ----------
    frames : int
        Frames the run processed (set by :func:`~vehicle_detection.pipeline.process_video`;
        0 until then).
    wall : float
        Seconds the run took from the first frame decoded to the last one encoded (set by
        :func:`~vehicle_detection.pipeline.process_video`).
    cpu : float
        CPU seconds of the whole process over the same run, all threads (FFmpeg's and x264's
        included; set by :func:`~vehicle_detection.pipeline.process_video`). Like ``frames``
        and ``wall``, those of one run: a timeline is for one run.

    Examples
    --------
    >>> timeline = Timeline()  # doctest: +SKIP
    >>> process_video("test_video.mp4", "out.mp4", timeline=timeline)  # doctest: +SKIP
    >>> print(timeline.table())  # doctest: +SKIP
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._seconds: dict[str, float] = {}
        self._cpu: dict[str, float] = {}
        self._counts: dict[str, int] = {}
        self.frames = 0
        self.wall = 0.0
        self.cpu = 0.0

    @staticmethod
    def now() -> Mark:
        """Now on both clocks, for this thread: the start of a stage, to :meth:`lap` on."""
        return Mark(time.perf_counter(), time.thread_time())

    def add(self, stage: str, seconds: float, cpu: float = 0.0) -> None:
        """Add ``seconds`` of wall time and ``cpu`` seconds of CPU time to ``stage`` (one call per frame, or several)."""
        with self._lock:
            self._seconds[stage] = self._seconds.get(stage, 0.0) + seconds
            self._cpu[stage] = self._cpu.get(stage, 0.0) + cpu
            self._counts[stage] = self._counts.get(stage, 0) + 1

    def lap(self, stage: str, since: Mark) -> Mark:
        """Add the time from ``since`` (:meth:`now` or a lap, in this thread) to now to ``stage``; return now."""
        now = self.now()
        self.add(stage, now.wall - since.wall, now.cpu - since.cpu)
        return now

    def timed(self, stage: str, function):
        """``function``, adding the seconds of each call to ``stage``."""

        def timed(*args, **kwargs):
            t = self.now()
            try:
                return function(*args, **kwargs)
            finally:
                self.lap(stage, t)

        return timed

    def seconds(self, stage: str) -> float:
        """Seconds of wall time spent in ``stage`` in all (0.0 if it never ran)."""
        return self._seconds.get(stage, 0.0)

    def cpu_seconds(self, stage: str) -> float:
        """CPU seconds the thread of ``stage`` spent in it in all (0.0 if it never ran)."""
        return self._cpu.get(stage, 0.0)

    def count(self, stage: str) -> int:
        """Times ``stage`` was measured."""
        return self._counts.get(stage, 0)

    @property
    def stages(self) -> list[str]:
        """The stages measured, in :data:`STAGES` order (others after, in the order first seen)."""
        known = [s for s in STAGES if s in self._seconds]
        return known + [s for s in self._seconds if s not in STAGES]

    def per_frame_ms(self, clock: str = "wall") -> dict[str, float]:
        """Milliseconds per frame of each stage measured: its seconds over :attr:`frames`.

        ``clock``: ``"wall"`` (the default) or ``"cpu"`` (CPU time of the stage's thread).
        """
        if clock not in ("wall", "cpu"):
            raise ValueError(f"clock must be 'wall' or 'cpu', not {clock!r}")
        seconds = self._seconds if clock == "wall" else self._cpu
        n = max(self.frames, 1)
        return {s: 1000.0 * seconds[s] / n for s in self.stages}

    def table(self) -> str:
        """The stages as a small text table: thread, wall ms a frame, share of the wall time, CPU ms a frame.

        With the process's CPU time (:attr:`cpu`), two more lines: CPU time that no stage's
        thread spent (FFmpeg's codec threads, the garbage collector, ...), and the process's.
        """
        n = max(self.frames, 1)
        wall_ms = 1000.0 * self.wall / n
        cpu = self.per_frame_ms("cpu")
        lines = [f"{'stage':<13} {'thread':<8} {'ms/frame':>9} {'% wall':>7} {'cpu ms':>7}"]
        for stage, ms in self.per_frame_ms().items():
            share = f"{100.0 * ms / wall_ms:6.0f}%" if wall_ms > 0 else "      -"
            lines.append(f"{stage:<13} {STAGES.get(stage, '?'):<8} {ms:9.2f} {share} {cpu[stage]:7.2f}")
        if self.cpu > 0:
            cpu_ms = 1000.0 * self.cpu / n
            lines.append(f"{'other':<13} {'-':<8} {'':>9} {'':>7} {cpu_ms - sum(cpu.values()):7.2f}"
                         "   (CPU time of no stage: FFmpeg's and x264's threads, the collector, the rest)")
            busy = f"{self.cpu / self.wall:.2f} cores busy" if self.wall > 0 else "-"
            lines.append(f"{'process':<13} {'all':<8} {'':>9} {'':>7} {cpu_ms:7.2f}   ({busy})")
        fps = f"{self.frames / self.wall:.1f} fps" if self.wall > 0 else "-"
        lines.append(f"{'wall':<13} {'':<8} {wall_ms:9.2f}    100%   ({self.frames} frames, {fps})")
        return "\n".join(lines)

    def __repr__(self) -> str:
        return f"Timeline(frames={self.frames}, wall={self.wall:.3f}, cpu={self.cpu:.3f}, stages={len(self._seconds)})"


_ZERO = Mark(0.0, 0.0)  # the time on the clock of a run without a timeline


class _Untimed:
    """The clock of a run without a :class:`Timeline`: :meth:`Timeline.now`, :meth:`~Timeline.add`,
    :meth:`~Timeline.lap` and :meth:`~Timeline.timed` that measure nothing, so the stages need no ``None`` checks."""

    __slots__ = ()

    @staticmethod
    def now() -> Mark:
        return _ZERO

    def add(self, stage: str, seconds: float, cpu: float = 0.0) -> None:
        pass

    def lap(self, stage: str, since: Mark) -> Mark:
        return _ZERO

    def timed(self, stage: str, function):
        return function

    def __repr__(self) -> str:
        return "UNTIMED"


#: What a stage times itself on when the run has no timeline.
UNTIMED = _Untimed()


def timing(timeline: Timeline | None) -> Timeline | _Untimed:
    """``timeline``, or :data:`UNTIMED` for None: the clock a pipeline stage laps on."""
    return UNTIMED if timeline is None else timeline
