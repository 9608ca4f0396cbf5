"""The detector over hand-labelled footage: the boxes to score, and their scores.

A labels file (:func:`~vehicle_detection.metrics.detection.load_annotations`) names a video or a
folder of images. :func:`detect_labelled` runs a detector over what it covers (a video from its
first frame up to its last labelled frame, tracked as in a whole run; the labelled images of a
folder, each on its own), and :func:`evaluate_labelled` scores the result
(:func:`~vehicle_detection.metrics.detection.evaluation_report`). ``vehicle-detection evaluate``
and the notebooks use these two.
"""

from __future__ import annotations

import os
from contextlib import closing
from itertools import islice
from pathlib import Path
from typing import Any

from ..detections import Detections
from ..detector import Detector
from ..errors import InputError
from ..io import progress_bar
from ..io.images import check_frame_shape, list_images
from ..io.video import probe_video, read_frames
from ..road.camera import Camera
from ..training.mining import labelled_frames
from .detection import Annotations, check_boxes_inside, evaluation_report

__all__ = ["detect_labelled", "evaluate_labelled"]


def detect_labelled(
    labels: Annotations,
    detector: Detector,
    *,
    source: str | os.PathLike | None = None,
    camera: Camera | None = None,
    end: int | None = None,
    progress: bool = False,
) -> tuple[Detections, float | None]:
    """The detector's boxes over what ``labels`` covers, in the labels' (original) frames.

    Parameters
    ----------
    labels : Annotations
    detector : Detector
    source : path-like, optional
        The labelled video or image folder (default: the one the labels name).
    camera : Camera, optional
        Undistort every frame before the search; the boxes are mapped back to the original
        (distorted) frames, where the labels are.
    end : int, optional
        A video: run up to this decoded frame (default: just past the last labelled one).
    progress : bool
        Show a progress bar on a terminal.

    Returns
    -------
    (Detections, float or None)
        The boxes (tracked for a video; ``frame`` the decoded index or the image's position) and
        the video's frame rate (None for images).

    Raises
    ------
    InputError
        If the source has fewer frames or images than the labels name, or an image is not the
        one the labels name.
    """
    source = Path(source) if source is not None else labels.source
    if source is None:
        raise InputError(f"{labels.path}: the labels name no video or image folder; give the source")
    if source.is_dir():
        return _detect_images(labels, source, detector, camera), None
    info = probe_video(source)
    check_frame_shape(info.height, info.width, str(source))  # bounded search memory, before any frame
    check_boxes_inside(labels, info.width, info.height, source=source)  # boxes beyond the frame: other labels
    if camera is not None:
        camera.check_size(info.width, info.height, f"{source}: the video")
    last = max(labels.frames) + 1 if labels.frames else 0
    _check_length(labels, source, last)
    with closing(read_frames(source)) as frames:
        frames = islice(frames, max(last, end or 0))
        if camera is not None:
            frames = map(camera.undistort, frames)
        with progress_bar(end or last, source.name, enabled=progress) as bar:
            found = []
            for _, boxes in detector.track_frames(frames):
                found.append(boxes)
                if bar is not None:
                    bar.update()
    table = Detections.concatenate(found) if found else Detections.empty(tracked=True)
    if camera is not None:  # the labels are in the original (distorted) frames
        table = table.replace(xyxy=camera.boxes_to_original(table.xyxy))
    return table, info.fps


def _detect_images(labels: Annotations, source: Path, detector: Detector, camera: Camera | None) -> Detections:
    files = list_images(source)
    last = max(labels.frames) + 1 if labels.frames else 0
    if len(files) < last:
        raise InputError(f"{labels.path}: labels image {last - 1}, but {source} has only {len(files)} images")
    for i, lab in labels.frames.items():
        if lab.file is not None and files[i].name != lab.file:
            raise InputError(f"{labels.path}: frame {i} is labelled as {lab.file}, but image {i} of {source} is {files[i].name}")
    if camera is None:  # labelled_frames: the images, once their labels are found inside them
        return Detections.concatenate(detector.detect_image(im).replace(frame=i) for i, im, _ in labelled_frames(labels, source))
    found = Detections.concatenate(detector.detect_image(camera.undistort(im)).replace(frame=i) for i, im, _ in labelled_frames(labels, source))
    return found.replace(xyxy=camera.boxes_to_original(found.xyxy))


def _check_length(labels: Annotations, source: Path, last: int) -> None:
    """Labels beyond the end of the video would silently count as missed cars: refuse them, after
    decoding (the container's frame count is only an estimate for some formats)."""
    with closing(read_frames(source)) as frames:
        n_decoded = sum(1 for _ in islice(frames, last))
    if n_decoded < last:
        beyond = [f for f in labels.frames if f >= n_decoded]
        raise InputError(
            f"{labels.path}: labels frame(s) {', '.join(map(str, beyond))}, but {source} has only "
            f"{n_decoded} decoded frames (0..{n_decoded - 1}); wrong video or labels?"
        )


def evaluate_labelled(
    labels: Annotations,
    detector: Detector,
    *,
    source: str | os.PathLike | None = None,
    camera: Camera | None = None,
    progress: bool = False,
) -> tuple[dict[str, Any], Detections]:
    """Score the detector on ``labels``: ``(report, boxes)``.

    The report is :func:`~vehicle_detection.metrics.detection.evaluation_report` of the boxes of
    :func:`detect_labelled` (with false positives per minute for a video); the parameters are
    those of :func:`detect_labelled`.
    """
    found, fps = detect_labelled(labels, detector, source=source, camera=camera, progress=progress)
    return evaluation_report(found, labels, fps=fps), found
