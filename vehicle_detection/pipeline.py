"""The pipeline layer: detection and tracking over a video file, and drawing the results.

:mod:`vehicle_detection.video` only reads and writes frames; this module connects it to the
detector (:mod:`vehicle_detection.detector`), the boxes CSV (:mod:`vehicle_detection.tables`)
and drawing (:mod:`vehicle_detection.drawing`).
"""

from __future__ import annotations

import itertools
import os
import sys
from pathlib import Path

import numpy as np

from ._files import check_output_path
from .errors import OutputError
from .images import check_frame_shape
from .video import VideoWriter, probe_video, read_frames

__all__ = ["process_video"]


def _in_notebook() -> bool:
    """True inside a Jupyter kernel, where ``tqdm.auto`` draws a widget (stderr is no terminal there)."""
    shell = sys.modules.get("IPython")
    try:
        return shell is not None and type(shell.get_ipython()).__name__ == "ZMQInteractiveShell"
    except Exception:
        return False


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

    Returns
    -------
    Detections
        Every reported box, frame by frame (``frame``: 0-based decoded frame index), tracked.
    """
    import contextlib
    from contextlib import ExitStack

    from .detections import Detections
    from .detector import Detector
    from .drawing import draw_detections
    from .tables import write_boxes_csv

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
    tracker = detector.new_tracker()
    if start:
        from .tracker import Tracker, TrackerState

        tracker = Tracker(detector.config.tracker, TrackerState(frame_index=start))  # frames keep their decoded index
    detections = []
    frames = read_frames(path)
    csv_written = False
    try:
        with ExitStack() as stack:
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
            for frame, found in detector.track_frames(source, tracker, workers=workers):
                detections.append(found)
                if writer is not None:
                    writer.write(draw_detections(frame, found))
                if bar is not None:
                    bar.update()
            table = Detections.concatenate(detections)
            if boxes_csv is not None:
                # Written before the video is renamed into place: once the video exists under
                # its final name, the CSV is complete too.
                write_boxes_csv(boxes_csv, table, overwrite=overwrite, inputs=[path])
                csv_written = True
    except BaseException:
        # The video failed after the CSV was renamed into place (the encoder failing to finish the
        # file, Ctrl-C during its final flush): remove the CSV too, so that no output of a
        # failed run is left looking finished.
        if csv_written:
            with contextlib.suppress(OSError):
                Path(boxes_csv).unlink()
        raise
    finally:
        frames.close()
    return table
