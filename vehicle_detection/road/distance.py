"""Distances ahead and relative speeds of the tracked vehicles, on the road plane.

A box's distance ahead is that of the bottom centre of the box, a point on the road, through the
ground-plane homography of :class:`~vehicle_detection.road.lanes.BirdsEye`. Box edges are whole
pixels and move a pixel at a time, and one pixel row is a metre or more at 30 m: a car closing in
steadily would jump from one row's distance to the next, stay, and now and then jump back as its
box jitters. So each track's distance goes through a constant-velocity Kalman filter
(:class:`DistanceFilter`) whose measurement noise is the distance one pixel row spans at the
box's bottom (:meth:`DistanceTracker.sigmas`): near boxes, whose rows are a few centimetres
apart, are followed closely, far ones are smoothed over more frames. A track's relative speed is
the least-squares slope of its measured distances over its last frames.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field

import numpy as np

from ..detections import Detections
from ..io.tables import DISTANCE_COLUMNS
from .lanes import BirdsEye

__all__ = ["DistanceFilter", "DistanceTracker", "smooth_distances"]


@dataclass
class DistanceFilter:
    """A constant-velocity Kalman filter of one track's distance ahead.

    The state is the distance (m) and its rate of change (m per frame); between two updates the
    rate changes by a random relative acceleration of standard deviation ``accel_mps2``.

    Parameters
    ----------
    fps : float
        Frames per second of the video (frame numbers are converted to time with it).
    accel_mps2 : float
        Standard deviation of the relative acceleration between the cars, m/s^2: the larger, the
        faster the filter follows a change of speed, and the less it smooths.
    speed_mps : float
        Standard deviation of the relative speed before the first measurements, m/s.

    Examples
    --------
    >>> f = DistanceFilter(fps=30)
    >>> [round(f.update(i, d, 0.5), 2) for i, d in enumerate([20.0, 20.0, 19.0, 19.0])]
    [20.0, 20.0, 19.58, 19.29]
    """

    fps: float
    accel_mps2: float = 1.0
    speed_mps: float = 5.0
    _x: np.ndarray | None = field(default=None, repr=False)
    _p: np.ndarray | None = field(default=None, repr=False)
    _frame: int | None = field(default=None, repr=False)

    @property
    def frame(self) -> int | None:
        """Frame of the last update (None before the first)."""
        return self._frame

    def update(self, frame: int, distance: float, sigma: float) -> float:
        """Add the distance measured in ``frame`` (later than the last), return the filtered distance.

        Parameters
        ----------
        frame : int
            Frame number; frames without a measurement in between are predicted over.
        distance : float
            Measured distance, m (finite).
        sigma : float
            Its standard deviation, m (positive; infinite: the measurement is ignored).

        Returns
        -------
        float
            The filtered distance in ``frame``, m.
        """
        z, r = float(distance), max(float(sigma), 1e-6) ** 2
        if self._x is None:
            v = self.speed_mps / self.fps
            self._x, self._p, self._frame = np.array([z, 0.0]), np.diag([r if np.isfinite(r) else 1e6, v * v]), int(frame)
            return z
        dt = max(0, int(frame) - self._frame)
        self._frame = max(self._frame, int(frame))
        q = (self.accel_mps2 / self.fps**2) ** 2  # m per frame^2, squared
        f = np.array([[1.0, dt], [0.0, 1.0]])
        x = f @ self._x
        p = f @ self._p @ f.T + q * np.array([[dt**4 / 4, dt**3 / 2], [dt**3 / 2, dt**2]])
        if np.isfinite(r):
            gain = p[:, 0] / (p[0, 0] + r)
            x = x + gain * (z - x[0])
            p = p - np.outer(gain, p[0])
        self._x, self._p = x, p
        return float(x[0])


def smooth_distances(frames, distances, sigmas, fps: float, **kwargs) -> np.ndarray:
    """The distances of one track through a :class:`DistanceFilter`, in frame order.

    Parameters
    ----------
    frames : array_like of int, shape (n,)
        Frame of each measurement (any order; ties keep their order).
    distances, sigmas : array_like of float, shape (n,)
        Measured distances and their standard deviations, m; NaN distances are skipped (and
        stay NaN).
    fps : float
    **kwargs
        ``accel_mps2``, ``speed_mps`` of :class:`DistanceFilter`.

    Returns
    -------
    ndarray of float64, shape (n,)
        The filtered distance of each measurement, in the input's order.
    """
    frames = np.asarray(frames).ravel()
    d = np.asarray(distances, dtype=np.float64).ravel()
    s = np.broadcast_to(np.asarray(sigmas, dtype=np.float64), d.shape)
    out = np.full(d.shape, np.nan)
    f = DistanceFilter(fps, **kwargs)
    for i in np.argsort(frames, kind="stable"):
        if np.isfinite(d[i]):
            out[i] = f.update(int(frames[i]), d[i], s[i])
    return out


@dataclass
class DistanceTracker:
    """Distance ahead and relative speed of each tracked vehicle.

    ``update(detections)`` adds ``distance_m`` and ``relative_speed_mps`` to ``detections.data``.
    A box's measured distance is that of the bottom centre of the box
    (:meth:`BirdsEye.ground_distance`; NaN beyond ``max_distance_m`` or above the horizon). For
    a tracked box, with ``smooth`` (the default), ``distance_m`` is its track's distance through
    a :class:`DistanceFilter` (relative accelerations of ``accel_mps2``; each measurement's
    standard deviation :meth:`sigmas`), so a car closing in gets distances that fall frame by
    frame instead of in steps of one pixel row; untracked boxes get the measured distance.
    ``relative_speed_mps`` is the least-squares slope of the track's measured distances over its
    last ``window`` frames (default one second) times ``fps``; positive: pulling away; NaN until
    ``min_points`` frames (default half the window), and for untracked boxes. Boxes are taken in
    frame order, so a whole table at once gives what its frames one by one would.
    """

    birds_eye: BirdsEye
    fps: float
    window: int | None = None
    min_points: int | None = None
    max_distance_m: float = 150.0
    smooth: bool = True
    accel_mps2: float = 1.0
    pixel_sigma: float = 0.6
    _history: dict = field(default_factory=dict, repr=False)
    _filters: dict = field(default_factory=dict, repr=False)

    def __post_init__(self) -> None:
        if self.window is None:  # one second of frames: box bottoms jitter by a pixel or two
            self.window = max(3, int(round(self.fps)))
        if self.min_points is None:
            self.min_points = max(2, self.window // 2)

    def _bottoms(self, xyxy) -> np.ndarray:
        xyxy = np.asarray(xyxy, dtype=np.float64).reshape(-1, 4)
        return np.c_[(xyxy[:, 0] + xyxy[:, 2]) / 2, xyxy[:, 3]]

    def distances(self, xyxy: np.ndarray) -> np.ndarray:
        """Measured distance of each box's bottom centre, m (NaN beyond ``max_distance_m`` or the horizon)."""
        d = self.birds_eye.ground_distance(self._bottoms(xyxy))
        d[~(d <= self.max_distance_m)] = np.nan
        return d

    def sigmas(self, xyxy: np.ndarray) -> np.ndarray:
        """Standard deviation of each box's measured distance, m.

        ``pixel_sigma`` times the distance between the rows half a pixel above and below the
        box's bottom (a whole-pixel edge that jitters by about a pixel: 0.6 px by default);
        infinite where either row is at or above the horizon.
        """
        bottom = self._bottoms(xyxy)
        above = self.birds_eye.ground_distance(bottom - [0.0, 0.5])
        below = self.birds_eye.ground_distance(bottom + [0.0, 0.5])
        s = np.abs(above - below) * self.pixel_sigma
        s[~np.isfinite(s)] = np.inf
        return s

    def update(self, detections: Detections) -> Detections:
        raw = self.distances(detections.xyxy)
        d = raw.copy()
        speed = np.full(len(d), np.nan)
        if detections.track_id is not None:
            sig = self.sigmas(detections.xyxy) if self.smooth else None
            tracks, frames = detections.track_id.tolist(), detections.frame.tolist()
            for i in np.argsort(detections.frame, kind="stable").tolist():
                t, f = tracks[i], frames[i]
                if t < 0:
                    continue
                hist = self._history.setdefault(t, deque(maxlen=self.window))
                if np.isfinite(raw[i]):
                    hist.append((f, raw[i]))
                    if self.smooth:
                        d[i] = self._filters.setdefault(t, DistanceFilter(self.fps, self.accel_mps2)).update(f, raw[i], sig[i])
                if len(hist) >= self.min_points:
                    fr, dist = np.array(hist).T
                    if np.ptp(fr) > 0:
                        speed[i] = np.polyfit(fr, dist, 1)[0] * self.fps
            live = set(tracks)
            for t in [t for t in self._history if t not in live]:
                if detections.frame.size and self._history[t] and detections.frame.max() - self._history[t][-1][0] > self.window:
                    del self._history[t]
                    self._filters.pop(t, None)
        return detections.replace(data={**detections.data, DISTANCE_COLUMNS[0]: d, DISTANCE_COLUMNS[1]: speed})
