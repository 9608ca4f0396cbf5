"""Distances ahead and relative speeds of the tracked vehicles, on the road plane.

A box's distance ahead is that of the bottom centre of the box, a point on the road, through the
ground-plane homography of :class:`~vehicle_detection.road.lanes.BirdsEye`; a track's relative
speed is the least-squares slope of its successive distances over its last frames.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from ..detections import Detections
from ..io.tables import DISTANCE_COLUMNS
from .lanes import BirdsEye

__all__ = ["DistanceTracker"]


@dataclass
class DistanceTracker:
    """Distance ahead and relative speed of each tracked vehicle.

    ``update(detections)`` adds ``distance_m`` (from the bottom centre of the box, through
    :meth:`BirdsEye.ground_distance`; NaN beyond ``max_distance_m`` or above the horizon) and
    ``relative_speed_mps`` (the least-squares slope of the track's distances over its last
    ``window`` frames, default one second, times ``fps``; positive: pulling away; NaN until
    ``min_points`` frames, default half the window, and for untracked boxes) to
    ``detections.data``.
    """

    birds_eye: BirdsEye
    fps: float
    window: int | None = None
    min_points: int | None = None
    max_distance_m: float = 150.0
    _history: dict = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        if self.window is None:  # one second of frames: box bottoms jitter by a pixel or two
            self.window = max(3, int(round(self.fps)))
        if self.min_points is None:
            self.min_points = max(2, self.window // 2)

    def distances(self, xyxy: np.ndarray) -> np.ndarray:
        xyxy = np.asarray(xyxy, dtype=np.float64).reshape(-1, 4)
        bottom = np.c_[(xyxy[:, 0] + xyxy[:, 2]) / 2, xyxy[:, 3]]
        d = self.birds_eye.ground_distance(bottom)
        d[~(d <= self.max_distance_m)] = np.nan
        return d

    def update(self, detections: Detections) -> Detections:
        d = self.distances(detections.xyxy)
        speed = np.full(len(d), np.nan)
        if detections.track_id is not None:
            for i, (t, f) in enumerate(zip(detections.track_id.tolist(), detections.frame.tolist())):
                if t < 0:
                    continue
                hist = self._history.setdefault(t, deque(maxlen=self.window))
                if np.isfinite(d[i]):
                    hist.append((f, d[i]))
                if len(hist) >= self.min_points:
                    fr, dist = np.array(hist).T
                    if np.ptp(fr) > 0:
                        speed[i] = np.polyfit(fr, dist, 1)[0] * self.fps
            live = set(detections.track_id.tolist())
            for t in [t for t in self._history if t not in live]:
                if detections.frame.size and self._history[t] and detections.frame.max() - self._history[t][-1][0] > self.window:
                    del self._history[t]
        return detections.replace(data={**detections.data, DISTANCE_COLUMNS[0]: d, DISTANCE_COLUMNS[1]: speed})
