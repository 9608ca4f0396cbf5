"""A video through the detector: decode, undistort, detect and track, measure, draw, encode.

:mod:`vehicle_detection.io.video` only reads and writes frames; :func:`process_video` connects
it to the detector (:mod:`vehicle_detection.detector`), the road (:mod:`vehicle_detection.road`),
drawing (:mod:`vehicle_detection.viz.drawing`) and the tables (:func:`~vehicle_detection.io.write_tables`).
"""

from __future__ import annotations

import itertools
import os
import time
from collections import deque
from collections.abc import Iterable, Iterator, Mapping
from concurrent.futures import ThreadPoolExecutor
from contextlib import ExitStack, closing
from dataclasses import replace
from pathlib import Path

import numpy as np

from ..deprecation import old_keywords
from ..detections import Detections
from ..detector import Detector
from ..errors import InputError, UsageError, shorten
from ..io import check_outputs, output_batch, progress_bar, write_tables
from ..io.images import check_frame_shape
from ..io.timeline import Timeline, timing
from ..io.video import MAX_FRAME, Encoding, VideoWriter, probe_video, read_frames
from ..road.survey import Road, RoadSurvey
from ..tracker import Tracker, TrackerState
from ..viz.drawing import draw_detections

__all__ = ["process_video", "run_video", "frame_range"]

#: Frames searched at once when no thread budget is given.
SEARCH_WORKERS = 2


def frame_range(frames: range | tuple[int | None, int | None] | None) -> tuple[int, int | None]:
    """``(start, end)`` of decoded frames ``start <= index < end`` (``end`` None: to the last).

    ``frames`` is None (every frame), a ``range`` with step 1, or ``(start, end)`` with either
    None.

    Raises
    ------
    UsageError
        If it is not a range of frame indexes (``0 <= start <= end``).
    """
    if frames is None:
        return 0, None
    if isinstance(frames, range):
        if frames.step != 1:
            raise UsageError("frames: a range with step 1")
        start, end = frames.start, frames.stop
    else:
        start, end = frames
    start = 0 if start is None else int(start)
    if start < 0 or (end is not None and int(end) < start):
        raise UsageError(f"frames: ({start}, {end}) is not a range of frame indexes (0 <= start <= end)")
    if max(start, 0 if end is None else int(end)) > MAX_FRAME + 1:
        raise UsageError(f"frames: ({shorten(start)}, {shorten(end)}) reaches beyond any video (frame indexes are at most {MAX_FRAME})")
    return start, None if end is None else int(end)


def _prepared(source: Iterable[np.ndarray], helper: ThreadPoolExecutor, survey: RoadSurvey, lanes_ahead: deque,
              ahead: int = 3, timeline: Timeline | None = None) -> Iterator[np.ndarray]:
    """Frames undistorted in ``helper``, ``ahead`` frames in advance.

    With lanes, the lane of each frame is found in the same (single) helper thread, so in frame
    order; its future is appended to ``lanes_ahead`` as the frame is yielded.
    """
    clock = timing(timeline)
    undistort, find_lane = clock.timed("prepare", survey.undistort), clock.timed("prepare", survey.find_lane)

    def work(frame):
        frame = undistort(frame)
        return frame, helper.submit(find_lane, frame) if survey.finds_lanes else None

    pending: deque = deque()
    for frame in source:
        pending.append(helper.submit(work, frame))
        if len(pending) > ahead:
            frame, lane = pending.popleft().result()
            if lane is not None:
                lanes_ahead.append(lane)
            yield frame
    while pending:
        frame, lane = pending.popleft().result()
        if lane is not None:
            lanes_ahead.append(lane)
        yield frame


def _legacy(kwargs: dict) -> dict:
    """The earlier keywords (``boxes_csv``, ``start``, ``camera``, ...) as the new objects."""
    start, end = kwargs.pop("start", 0), kwargs.pop("end", None)
    if "frames" not in kwargs and (start or end is not None or "max_frames" in kwargs):
        kwargs["frames"] = (start, end)
    limit = kwargs.pop("max_frames", None)
    if limit is not None:
        a, b = frame_range(kwargs.get("frames"))
        kwargs["frames"] = (a, a + limit if b is None else min(b, a + limit))
    enc = {k: kwargs.pop(k) for k in ("crf", "preset") if k in kwargs}
    if enc:
        kwargs["encoding"] = replace(kwargs.get("encoding") or Encoding(), **enc)
    road = {k: kwargs.pop(k) for k in ("camera", "lanes", "birds_eye") if k in kwargs}
    if road:
        kwargs["road"] = replace(kwargs.get("road") or Road(), **road)
    tables = dict(kwargs.get("tables") or {})
    for old, fmt in (("boxes_csv", "csv"), ("lanes_csv", "lanes")):
        value = kwargs.pop(old, None)
        if value is not None:
            tables[fmt] = value
    if tables:
        kwargs["tables"] = tables
    if "workers" in kwargs:
        kwargs["threads"] = kwargs.pop("workers")
    return kwargs


@old_keywords(("boxes_csv", "lanes_csv", "start", "end", "max_frames", "crf", "preset", "workers", "camera", "lanes",
               "birds_eye"), _legacy)
def process_video(
    path: str | os.PathLike,
    output: str | os.PathLike | None = None,
    *,
    detector: Detector | None = None,
    frames: range | tuple[int | None, int | None] | None = None,
    road: Road | None = None,
    encoding: Encoding | None = None,
    tables: Mapping[str, str | os.PathLike] | None = None,
    overwrite: bool = False,
    progress: bool = True,
    tracker: Tracker | None = None,
    threads: int | None = None,
    timeline: Timeline | None = None,
) -> Detections:
    """Detect and track vehicles through a video; write the annotated video and the tables.

    Decoding (a thread), detection (this thread, numba on both cores) and encoding (a thread)
    overlap. All outputs are committed together when the run succeeds (the video last); on any
    failure, Ctrl-C included, none is, and earlier outputs of the same names stay as they were.

    Parameters
    ----------
    path : path-like
        Any video FFmpeg (PyAV) reads.
    output : path-like, optional
        Annotated H.264 MP4 to write; None writes no video.
    detector : Detector, optional
        Defaults to ``Detector()`` (the embedded model).
    frames : range or (int, int), optional
        Only the decoded frames ``start <= index < end`` (default: all; see :func:`frame_range`).
        The frames before ``start`` are decoded and dropped; ``frame`` in the result stays the
        decoded index.
    road : Road, optional
        The camera to undistort every frame with, distances on the road plane, lanes
        (:class:`~vehicle_detection.road.survey.Road`); the video must fit it (else
        :class:`InputError`, before any frame).
    encoding : Encoding, optional
        x264 preset and quality of ``output`` (:class:`~vehicle_detection.io.video.Encoding`).
    tables : mapping of str to path-like, optional
        Tables to write, format -> file (:data:`~vehicle_detection.io.formats.FORMATS`: ``csv``,
        ``parquet``, ``mot``, and ``lanes``, which finds lanes); ``coco`` is for images only.
    overwrite : bool
        Replace existing outputs (never the input).
    progress : bool
        Show a progress bar on stderr (a terminal or a notebook).
    tracker : Tracker, optional
        The tracker to advance (by default a new one; its frame counter must be at ``start``).
        Afterwards its ``state`` tells, for instance, the horizon the search used.
    threads : int, optional
        The run's share of the cores: frames searched at once, and the codec's threads. None:
        :data:`SEARCH_WORKERS` frames at once, and FFmpeg chooses its threads.
    timeline : Timeline, optional
        Filled with the seconds each stage of the run took, from every thread (decode, colour
        conversion, search, tracking, drawing, encoding, and the waits on the queues between
        them), on the wall clock and in CPU time, the frames, the wall time and the process's
        CPU time: see :class:`~vehicle_detection.io.Timeline`.
        Without it nothing is measured.

    Returns
    -------
    Detections
        Every reported box, frame by frame (``frame``: 0-based decoded frame index), tracked;
        with ``distance_m`` and ``relative_speed_mps`` when the road plane is known.
    """
    return run_video(path, output, detector=detector, frames=frames, road=road, encoding=encoding, tables=tables,
                     overwrite=overwrite, progress=progress, tracker=tracker, threads=threads, timeline=timeline)[0]


def run_video(
    path: str | os.PathLike,
    output: str | os.PathLike | None = None,
    *,
    detector: Detector | None = None,
    frames: range | tuple[int | None, int | None] | None = None,
    road: Road | None = None,
    encoding: Encoding | None = None,
    tables: Mapping[str, str | os.PathLike] | None = None,
    overwrite: bool = False,
    progress: bool = True,
    tracker: Tracker | None = None,
    threads: int | None = None,
    timeline: Timeline | None = None,
) -> tuple[Detections, list[tuple[int, float | None, float | None]]]:
    """:func:`process_video`, returning the lane of each frame as well.

    Returns
    -------
    table : Detections
        As :func:`process_video`.
    lane_rows : list of (int, float or None, float or None)
        ``(frame, radius_m, offset_m)`` of every frame when the road finds lanes, else empty.
    """
    path, detector, road = Path(path), detector or Detector(), road or Road()
    start, end = frame_range(frames)
    tables = dict(tables or {})
    if "lanes" in tables:
        road = replace(road, lanes=True)
    info = _check_run(path, output, road, tables, overwrite)
    if tracker is None:
        tracker = Tracker(detector.config.tracker, TrackerState(frame_index=start))  # frames keep their decoded index
    elif tracker.state.frame_index != start:
        raise ValueError(f"the tracker continues at frame {tracker.state.frame_index}, not at start={start}")
    survey = road.survey(info.fps or 25.0, shot_cuts=detector.config.shot_cuts)  # lanes afresh where the tracks are
    encoding, codec = encoding or Encoding(), threads or 0
    clock = timing(timeline)
    started, cpu_started = time.perf_counter(), time.process_time()
    with output_batch(), ExitStack() as stack:
        decoded = stack.enter_context(closing(read_frames(path, threads=codec, timeline=timeline)))
        writer = None
        if output is not None:
            writer = stack.enter_context(VideoWriter(output, info.fps, info.size, overwrite=overwrite, inputs=[path],
                                                     crf=encoding.crf, preset=encoding.preset, threads=codec,
                                                     timeline=timeline))
        bar = stack.enter_context(progress_bar(_n_frames(info.n_frames, start, end), path.name, enabled=progress))
        source = decoded if (start == 0 and end is None) else itertools.islice(decoded, start, end)
        lanes_ahead: deque = deque()
        if survey.changes_frames:
            # Undistortion and lane finding run in a helper thread, in frame order, a few frames
            # ahead of the search (OpenCV releases the GIL), not on this thread's path.
            helper = stack.enter_context(ThreadPoolExecutor(max_workers=1, thread_name_prefix="lanes"))
            source = _prepared(source, helper, survey, lanes_ahead, timeline=timeline)
        found = []
        tracked = detector.track_frames(source, tracker, workers=threads or SEARCH_WORKERS, timeline=timeline)
        for index, (frame, boxes) in enumerate(tracked, start=start):
            t = clock.now()
            boxes = survey.measure(boxes)
            found.append(boxes)
            lane = lanes_ahead.popleft().result() if survey.finds_lanes else None
            survey.record(index, lane)
            t = clock.lap("track", t)
            if writer is not None:
                # The frame is this run's own (decoded, or undistorted, here) and its search is
                # done: the boxes are drawn on it, and the writer takes it without a copy.
                overlays = tracker.state.overlays  # the footage's bars, as the search measured them
                picture = survey.draw(frame, lane, overlays.area if overlays is not None and overlays.shape == frame.shape[:2] else None)
                drawn = draw_detections(picture, boxes, out=picture)
                clock.lap("draw", t)
                writer.write(drawn, copy=False)
            if bar is not None:
                bar.update()
        table = survey.complete(Detections.concatenate(found))
        write_tables(tables, table, name=path.name, lanes=survey.lane_rows, overwrite=overwrite, inputs=[path])
    if timeline is not None:
        timeline.frames, timeline.wall = len(found), time.perf_counter() - started
        timeline.cpu = time.process_time() - cpu_started
    return table, survey.lane_rows


def _check_run(path: Path, output, road: Road, tables: dict, overwrite: bool):
    """Refuse bad outputs and a video the road does not fit, before decoding anything; the video's info."""
    if "coco" in tables:
        raise InputError(f"{path}: COCO JSON is written for images and folders of images, not videos (use mot or csv)")
    check_outputs([o for o in (output, *tables.values()) if o is not None], overwrite=overwrite, inputs=[path])
    info = probe_video(path)
    check_frame_shape(info.height, info.width, str(path))  # bounded search memory, before any frame
    road.check(info.width, info.height, f"{path}: the video")
    return info


def _n_frames(n: int | None, start: int, end: int | None) -> int | None:
    """Frames ``start <= index < end`` of a video of ``n`` (None: unknown)."""
    if n is None:
        return None if end is None else end - start
    return max(0, min(n, end if end is not None else n) - start)
