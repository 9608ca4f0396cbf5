"""The pipeline layer: detection and tracking over a video file, and drawing the results.

:mod:`vehicle_detection.video` only reads and writes frames; this module connects it to the
detector (:mod:`vehicle_detection.detector`) and the box tables (:mod:`vehicle_detection.boxes`).
"""

from __future__ import annotations

import itertools
import os
import sys
from pathlib import Path

import numpy as np

from ._files import check_output_path
from .errors import OutputError
from .video import VideoWriter, probe_video, read_frames

__all__ = ["annotate_frame", "process_video"]


def annotate_frame(frame: np.ndarray, boxes: np.ndarray, track_ids=None) -> np.ndarray:
    """A copy of an RGB frame with each vehicle's box (and track id) drawn on it."""
    from .boxes import draw_boxes

    labels = None if track_ids is None else [f"car {int(t)}" for t in track_ids]
    return draw_boxes(frame, boxes, color=(0, 255, 0), thickness=4, labels=labels)


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
        Stop after this many frames.
    crf, preset : int, str
        x264 quality (lower is better) and speed preset. ``ultrafast`` leaves the most CPU to
        the detector (files about twice the size of ``veryfast`` at the same ``crf``).

    Returns
    -------
    BoxTable
        Every reported box, frame by frame (0-based decoded frame index).
    """
    import contextlib
    from contextlib import ExitStack

    from .boxes import BoxTable, write_boxes_csv
    from .detector import Detector

    path = Path(path)
    detector = detector or Detector()
    # Refuse bad outputs before decoding anything.
    for out in (output, boxes_csv):
        if out is not None:
            check_output_path(out, overwrite=overwrite, inputs=[path])
    if output is not None and boxes_csv is not None and Path(output).resolve() == Path(boxes_csv).resolve():
        raise OutputError(f"{output}: the video and the boxes CSV cannot be the same file")
    info = probe_video(path)
    total = info.n_frames if max_frames is None else min(max_frames, info.n_frames or max_frames)
    tracker = detector.new_tracker()
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
            if progress and sys.stderr.isatty():
                from tqdm import tqdm

                bar = stack.enter_context(tqdm(total=total, unit="frame", desc=path.name, leave=False))
            source = frames if max_frames is None else itertools.islice(frames, max_frames)
            for frame, det in detector.track_frames(source, tracker):
                detections.append(det)
                if writer is not None:
                    writer.write(annotate_frame(frame, det.boxes, det.track_ids))
                if bar is not None:
                    bar.update()
            table = BoxTable.from_rows(
                (d.index, box, tid, score) for d in detections for box, tid, score in zip(d.boxes, d.track_ids, d.scores)
            )
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
