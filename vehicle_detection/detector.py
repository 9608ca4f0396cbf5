"""The detector: a model, a search plan and a tracker, applied to images and frame sequences.

:class:`Detector` is what the command line and the notebooks use:

* :meth:`Detector.detect_image` finds vehicles in one picture: scored windows
  (:func:`~vehicle_detection.search.search`) -> heat weighted by margin
  (:mod:`~vehicle_detection.heatmap`) -> threshold -> one box per blob;
* :meth:`Detector.track` follows vehicles through frames with a
  :class:`~vehicle_detection.tracker.Tracker`, which integrates heat over recent frames to
  reject one-frame false positives and keeps a stable, smoothed box per vehicle.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np

from .classifier import VehicleClassifier, load_default_model
from .heatmap import add_heat, heat_to_boxes
from .search import SearchPlan, Windows, search
from .tracker import Tracker, TrackerConfig, window_heat

__all__ = ["ImageDetection", "FrameDetection", "Detector"]


@dataclass(frozen=True)
class ImageDetection:
    """Result of :meth:`Detector.detect_image`.

    Attributes
    ----------
    boxes : ndarray of int64, shape (n, 4)
        One box per vehicle, ``[x1, y1, x2, y2]`` in image pixels.
    scores : ndarray of float64, shape (n,)
        Peak heat of each vehicle's blob.
    windows : Windows
        The windows above the plan's threshold.
    heat : ndarray of float32, shape (H // cell, W // cell)
        Heat map before thresholding.
    """

    boxes: np.ndarray
    scores: np.ndarray
    windows: Windows
    heat: np.ndarray


@dataclass(frozen=True)
class FrameDetection:
    """One frame of :meth:`Detector.track`.

    Attributes
    ----------
    index : int
        0-based decoded frame index.
    boxes : ndarray of int64, shape (n, 4)
        Reported (confirmed) vehicles.
    track_ids : ndarray of int64, shape (n,)
    scores : ndarray of float64, shape (n,)
    windows : Windows
        This frame's hot windows.
    """

    index: int
    boxes: np.ndarray
    track_ids: np.ndarray
    scores: np.ndarray
    windows: Windows


@dataclass
class Detector:
    """Vehicle detector over images and videos.

    Parameters
    ----------
    model : VehicleClassifier, optional
        Defaults to the embedded model.
    plan : SearchPlan
        Where to search, at which scales, and the margin a window needs.
    tracker : TrackerConfig
        Heat integration and track life cycle for videos; its ``cell``, ``min_size`` and
        ``aspect_range`` are used for single images too.
    image_threshold : float
        Heat a single image's blob must exceed. Images use the tracker's heat definition; with
        no frames to integrate, single-frame heat is noisier than the tracker's steady state
        (:attr:`~vehicle_detection.tracker.TrackerConfig.frame_threshold`, 2.4 by default),
        which splits a weakly seen car in two on test1.jpg; thresholds 1.0 to 2.0 give one box
        per car on all six test images, and 2.0 is used.
    """

    model: VehicleClassifier | None = None
    plan: SearchPlan = field(default_factory=SearchPlan)
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    image_threshold: float = 2.0

    def __post_init__(self):
        if self.model is None:
            self.model = load_default_model()

    def windows(self, frame: np.ndarray) -> Windows:
        """Hot windows of one RGB ``uint8`` frame (margin above ``plan.threshold``)."""
        return search(frame, self.model, self.plan)

    def heat(self, frame_shape, windows: Windows) -> np.ndarray:
        """Heat of one frame's windows, as the tracker adds it (:func:`~vehicle_detection.tracker.window_heat`)."""
        cell = self.tracker.cell
        h, w = frame_shape[:2]
        heat = np.zeros((h // cell, w // cell), np.float32)
        weights = window_heat(self.window_weights(windows), self.tracker.score_gain)
        return add_heat(heat, windows.boxes, weights, cell=cell)

    def window_weights(self, windows: Windows) -> np.ndarray:
        """Each window's SVM margin above the plan's threshold (what the tracker is given)."""
        return np.asarray(windows.scores - self.plan.threshold, dtype=np.float64)

    def detect_image(self, image: np.ndarray) -> ImageDetection:
        """Vehicles in one RGB ``uint8`` image ``(H, W, 3)``: one box per heat blob."""
        wins = self.windows(image)
        heat = self.heat(image.shape, wins)
        cfg = self.tracker
        boxes, peaks = heat_to_boxes(
            heat, self.image_threshold, cell=cfg.cell, min_size=cfg.min_size, aspect_range=cfg.aspect_range,
            peak_fraction=cfg.peak_fraction, split_size=cfg.split_size,
        )
        return ImageDetection(boxes, np.asarray(peaks, np.float64), wins, heat)

    def new_tracker(self) -> Tracker:
        """A fresh :class:`~vehicle_detection.tracker.Tracker` with this detector's settings."""
        return Tracker(self.tracker)

    def step(self, frame: np.ndarray, tracker: Tracker) -> FrameDetection:
        """Detect in one frame and advance ``tracker`` by it (live use: no lag, no back-fill)."""
        return self._advance(frame, self.windows(frame), tracker)

    def _advance(self, frame: np.ndarray, wins: Windows, tracker: Tracker) -> FrameDetection:
        index = tracker.state.frame_index
        tracks = tracker.update(wins.boxes, self.window_weights(wins), frame.shape)
        return FrameDetection(
            index,
            np.array([t.int_box() for t in tracks], dtype=np.int64).reshape(-1, 4),
            np.array([t.track_id for t in tracks], dtype=np.int64),
            np.array([t.score for t in tracks], dtype=np.float64),
            wins,
        )

    def track_frames(
        self, frames: Iterable[np.ndarray], tracker: Tracker | None = None, *, workers: int = 2
    ) -> Iterator[tuple[np.ndarray, FrameDetection]]:
        """Like :meth:`track`, also yielding each frame: ``(frame, detection)`` pairs.

        The search of the next ``workers`` frames runs in a thread pool (its compiled kernels
        release the GIL), so both cores work; the tracker is advanced in frame order. Output
        lags ``min_hits - 1`` frames behind the input (fixed-lag smoothing): when a track is
        confirmed, its boxes on the held-back frames before confirmation are filled in, so a
        vehicle is reported from the frame it appeared, and still no track is born from a
        single frame.
        """
        tracker = tracker or self.new_tracker()
        lag = max(0, self.tracker.min_hits - 1)
        held: deque = deque()  # (frame, index, boxes, ids, scores, windows), oldest first

        def advance(frame, wins):
            index = tracker.state.frame_index
            tracks = tracker.update(wins.boxes, self.window_weights(wins), frame.shape)
            by_index = {entry[1]: entry for entry in held}
            for t in tracks:
                for i, box in t.backfill:
                    if i in by_index:
                        _, _, boxes, ids, scores, _ = by_index[i]
                        boxes.append(np.floor(box + 0.5).astype(np.int64))
                        ids.append(t.track_id)
                        scores.append(t.score)
            held.append((frame, index, [t.int_box() for t in tracks], [t.track_id for t in tracks], [t.score for t in tracks], wins))

        def release():
            frame, index, boxes, ids, scores, wins = held.popleft()
            order = np.argsort(ids, kind="stable")
            det = FrameDetection(
                index,
                np.array(boxes, dtype=np.int64).reshape(-1, 4)[order],
                np.array(ids, dtype=np.int64)[order],
                np.array(scores, dtype=np.float64)[order],
                wins,
            )
            return frame, det

        pending: deque = deque()
        with ThreadPoolExecutor(max_workers=max(1, workers), thread_name_prefix="search") as pool:
            try:
                for frame in frames:
                    pending.append((frame, pool.submit(self.windows, frame)))
                    if len(pending) > workers:
                        f, fut = pending.popleft()
                        advance(f, fut.result())
                        while len(held) > lag:
                            yield release()
                while pending:
                    f, fut = pending.popleft()
                    advance(f, fut.result())
                    while len(held) > lag:
                        yield release()
                while held:
                    yield release()
            finally:
                for _, fut in pending:
                    fut.cancel()

    def track(self, frames: Iterable[np.ndarray], tracker: Tracker | None = None, *, workers: int = 2) -> Iterator[FrameDetection]:
        """Detect and follow vehicles through a sequence of RGB ``uint8`` frames.

        Parameters
        ----------
        frames : iterable of ndarray
            Decoded frames in order.
        tracker : Tracker, optional
            Pass the tracker of an earlier chunk to continue where it stopped (its frame
            counter continues too); a new one by default.
        workers : int
            Frames searched at once (threads).

        Yields
        ------
        FrameDetection
        """
        for _, det in self.track_frames(frames, tracker, workers=workers):
            yield det
