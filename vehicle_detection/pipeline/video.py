"""The pipeline layer: detection and tracking over a video file, and drawing the results.

:mod:`vehicle_detection.video` only reads and writes frames; this module connects it to the
detector (:mod:`vehicle_detection.detector`), the boxes CSV (:mod:`vehicle_detection.tables`)
and drawing (:mod:`vehicle_detection.drawing`).
"""

from __future__ import annotations

import itertools
import os
import sys
from collections import deque
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

from ..io._files import check_output_path, output_batch
from ..errors import InputError, OutputError
from ..io.images import check_frame_shape
from ..io.video import VideoWriter, probe_video, read_frames

__all__ = ["process_video"]


def _in_notebook() -> bool:
    """True inside a Jupyter kernel, where ``tqdm.auto`` draws a widget (stderr is no terminal there)."""
    shell = sys.modules.get("IPython")
    try:
        return shell is not None and type(shell.get_ipython()).__name__ == "ZMQInteractiveShell"
    except Exception:
        return False


def _prepared(source, helper: ThreadPoolExecutor, camera, lane_tracker, lanes_ahead: deque, ahead: int = 3):
    """Frames undistorted (when ``camera``) in ``helper``, ``ahead`` frames in advance.

    With ``lane_tracker``, the lane of each frame is found in the same (single) helper thread,
    so in frame order; its future is appended to ``lanes_ahead`` as the frame is yielded.
    """

    def work(frame):
        if camera is not None:
            frame = camera.undistort(frame)
        return frame, None if lane_tracker is None else helper.submit(lane_tracker.step, frame)

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


def process_video(
    path: str | os.PathLike,
    output: str | os.PathLike | None = None,
    *,
    detector=None,
    boxes_csv: str | os.PathLike | None = None,
    overwrite: bool = False,
    progress: bool = True,
    max_frames: int | None = None,
    crf: int = 23,
    preset: str = "ultrafast",
    start: int = 0,
    end: int | None = None,
    workers: int = 2,
    camera=None,
    lanes: bool = False,
    lanes_csv: str | os.PathLike | None = None,
    birds_eye=None,
    tracker=None,
):
    """Detect and track vehicles through a video; write the annotated video and the boxes.

    Decoding (a thread), detection (this thread, numba on both cores) and encoding (a thread)
    overlap.

    Parameters
    ----------
    path : path-like
        Any video FFmpeg (PyAV) reads.
    output : path-like, optional
        Annotated H.264 MP4 to write (atomically); None writes no video.
    detector : Detector, optional
        Defaults to ``Detector()`` (the embedded model).
    boxes_csv : path-like, optional
        CSV of every reported box (``frame,x1,y1,x2,y2,track_id,score``), written atomically
        once the whole video is processed, just before the video is renamed into place; it is
        removed again if the video then fails, so a failed run leaves neither.
    overwrite : bool
        Replace existing outputs (never the input).
    progress : bool
        Show a progress bar on stderr.
    max_frames : int, optional
        Stop after this many frames (counted from ``start``).
    crf, preset : int, str
        x264 quality (lower is better) and speed preset. ``ultrafast`` leaves the most CPU to
        the detector (files about twice the size of ``veryfast`` at the same ``crf``).
    start, end : int, optional
        Only the decoded frames ``start <= index < end`` (default: all). The frames before
        ``start`` are decoded and dropped; ``frame`` in the result stays the decoded index.
    workers : int
        Frames searched at once (threads; see :meth:`Detector.track_frames`).
    camera : Camera, optional
        Undistort every frame before the search (:mod:`vehicle_detection.camera`); the video
        must have the camera's image size (else :class:`InputError`, before any frame).
    lanes : bool
        Find the lane in every frame (:class:`~vehicle_detection.lanes.LaneTracker`) and draw
        it with its radius of curvature and the car's offset. Needs a bird's-eye transform.
    lanes_csv : path-like, optional
        CSV ``frame,curvature_m,offset_m`` (empty fields where no lane), written atomically with
        the boxes CSV; implies ``lanes``.
    birds_eye : BirdsEye, optional
        The road-plane transform; default ``camera.birds_eye``. When known, every box gets
        ``distance_m`` and ``relative_speed_mps`` in its ``data`` (NaN where unknown).
    tracker : Tracker, optional
        The tracker to advance (``detector.new_tracker()`` by default; its frame counter must be
        at ``start``). Afterwards its ``state`` tells, for instance, the horizon the search used.

    Returns
    -------
    Detections
        Every reported box, frame by frame (``frame``: 0-based decoded frame index), tracked.
    """
    from contextlib import ExitStack

    from ..detections import Detections
    from ..detector import Detector
    from ..viz.drawing import draw_detections
    from ..io.tables import DISTANCE_COLUMNS, write_boxes_csv, write_lanes_csv

    path = Path(path)
    detector = detector or Detector()
    # Refuse bad outputs before decoding anything.
    for out in (output, boxes_csv):
        if out is not None:
            check_output_path(out, overwrite=overwrite, inputs=[path])
    if output is not None and boxes_csv is not None and Path(output).resolve() == Path(boxes_csv).resolve():
        raise OutputError(f"{output}: the video and the boxes CSV cannot be the same file")
    info = probe_video(path)
    check_frame_shape(info.height, info.width, str(path))  # bounded search memory, before any frame
    if start < 0 or (end is not None and end < start):
        raise ValueError(f"start ({start}) and end ({end}) must satisfy 0 <= start <= end")
    stop = end
    if max_frames is not None:
        stop = start + max_frames if stop is None else min(stop, start + max_frames)
    total = info.n_frames
    if total is not None:
        total = max(0, min(total, stop if stop is not None else total) - start)
    elif stop is not None:
        total = stop - start
    lanes = lanes or lanes_csv is not None
    if lanes_csv is not None:
        check_output_path(lanes_csv, overwrite=overwrite, inputs=[path])
        if any(o is not None and Path(o).resolve() == Path(lanes_csv).resolve() for o in (output, boxes_csv)):
            raise OutputError(f"{lanes_csv}: the lanes CSV must be a file of its own")
    if camera is not None:
        camera.check_size(info.width, info.height, f"{path}: the video")
    if birds_eye is None and camera is not None:
        birds_eye = camera.birds_eye
    if birds_eye is not None and tuple(birds_eye.image_size) != (info.width, info.height):
        w, h = birds_eye.image_size
        raise InputError(f"{path}: the video is {info.width}x{info.height}, but the bird's-eye transform is for {w}x{h} frames")
    if lanes and birds_eye is None:
        raise InputError("lanes need a bird's-eye transform: a camera file made with 'calibrate --straight' (or birds_eye=)")
    lane_tracker = distances = None
    if lanes:
        from ..road.lanes import LaneTracker, draw_lane, lane_row

        lane_tracker = LaneTracker(birds_eye)
    if birds_eye is not None:
        from ..road.lanes import DistanceTracker

        distances = DistanceTracker(birds_eye, info.fps or 25.0)
    lane_rows = []
    if tracker is None:
        from ..tracker import Tracker, TrackerState

        tracker = Tracker(detector.config.tracker, TrackerState(frame_index=start))  # frames keep their decoded index
    elif tracker.state.frame_index != start:
        raise ValueError(f"the tracker continues at frame {tracker.state.frame_index}, not at start={start}")
    detections = []
    frames = read_frames(path)
    try:
        # All outputs are committed together when the run succeeds (the video last); on any
        # failure, Ctrl-C included, none is, and earlier outputs of the same names stay as they were.
        with output_batch(), ExitStack() as stack:
            writer = None
            if output is not None:
                writer = stack.enter_context(
                    VideoWriter(output, info.fps, info.size, overwrite=overwrite, inputs=[path], crf=crf, preset=preset)
                )
            bar = None
            if progress and (sys.stderr.isatty() or _in_notebook()):
                from tqdm.auto import tqdm

                bar = stack.enter_context(tqdm(total=total, unit="frame", desc=path.name, leave=False))
            source = frames if (start == 0 and stop is None) else itertools.islice(frames, start, stop)
            lanes_ahead: deque = deque()
            if camera is not None or lane_tracker is not None:
                # Undistortion and lane finding run in a helper thread, in frame order, a few
                # frames ahead of the search (OpenCV releases the GIL), not on this thread's path.
                helper = stack.enter_context(ThreadPoolExecutor(max_workers=1, thread_name_prefix="lanes"))
                source = _prepared(source, helper, camera, lane_tracker, lanes_ahead)
            for index, (frame, found) in enumerate(detector.track_frames(source, tracker, workers=workers), start=start):
                if distances is not None:
                    found = distances.update(found)
                detections.append(found)
                lane = None
                if lane_tracker is not None:
                    lane = lanes_ahead.popleft().result()
                    lane_rows.append(lane_row(index, lane))
                if writer is not None:
                    shown = draw_lane(frame, lane, birds_eye) if lane_tracker is not None else frame
                    writer.write(draw_detections(shown, found))
                if bar is not None:
                    bar.update()
            table = Detections.concatenate(detections)
            if distances is not None and not len(table):  # the columns, even without boxes
                table = table.replace(data={**table.data, **{c: np.zeros(0) for c in DISTANCE_COLUMNS}})
            if lanes_csv is not None:
                write_lanes_csv(lanes_csv, lane_rows, overwrite=overwrite, inputs=[path])
            if boxes_csv is not None:
                write_boxes_csv(boxes_csv, table, overwrite=overwrite, inputs=[path])
    finally:
        frames.close()
    return table
