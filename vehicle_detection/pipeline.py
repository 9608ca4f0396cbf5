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
            for frame, found in detector.track_frames(source, tracker):
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
