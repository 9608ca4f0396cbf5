"""What a run measures of the road, frame by frame: the lens undone, distances, and the lane.

:class:`Road` is the setting (which camera, whether to find lanes); :meth:`Road.for_footage`
completes it for one input: lanes asked for without a road plane get the plane estimated from
the input's own frames (:mod:`vehicle_detection.road.autocamera`), or no lanes when the footage
shows none; :meth:`Road.survey` starts
the stateful part for one video (or one image), a :class:`RoadSurvey`, which the pipeline asks
frame by frame, in order: undistort the frame, find its lane, give the boxes their distances and
relative speeds, and draw the lane.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from ..detections import Detections
from ..errors import InputError
from ..io.tables import DISTANCE_COLUMNS
from ..io.video import probe_video
from ..footage.shots import ShotCuts, next_shot
from .autocamera import EstimateSettings, RoadEstimate, estimate_birds_eye, road_transform
from .camera import Camera
from .distance import DistanceTracker
from .lanes import DASH_PERIOD_M, BirdsEye, Lane, LaneTracker, draw_lane, lane_row

__all__ = ["Road", "RoadSurvey"]


@dataclass(frozen=True)
class Road:
    """What to measure of the road around the detections.

    Parameters
    ----------
    camera : Camera, optional
        Undistort every frame before the search (:meth:`Camera.undistort`); frames must have
        the camera's image size.
    lanes : bool
        Find the lane in every frame (:class:`~vehicle_detection.road.lanes.LaneTracker`) and
        draw it with its radius of curvature and the car's offset. Needs a road plane.
    birds_eye : BirdsEye, optional
        The road plane (default: ``camera.birds_eye``). When known, every box gets
        ``distance_m`` and ``relative_speed_mps`` in its ``data`` (NaN where unknown).
    dash_period_m : float
        The road's dash period, from the start of one dash of a lane line to the start of the
        next, m: the scale along the road of a plane estimated from the footage
        (:meth:`for_footage`; :class:`~vehicle_detection.road.autocamera.EstimateSettings`).
        Default 12 m, a US lane line (10 ft of paint, 30 ft of gap); Californian freeways are
        often striped 12 ft on 48 ft, 14.6 m.
    """

    camera: Camera | None = None
    lanes: bool = False
    birds_eye: BirdsEye | None = None
    dash_period_m: float = DASH_PERIOD_M

    @property
    def estimates(self) -> bool:
        """Whether :meth:`for_footage` estimates a road plane: lanes are asked for and none is known."""
        return self.lanes and self.plane is None

    @property
    def plane(self) -> BirdsEye | None:
        """The road plane: ``birds_eye``, else the camera's, else None."""
        if self.birds_eye is not None:
            return self.birds_eye
        return None if self.camera is None else self.camera.birds_eye

    def check_frame(self, width: int, height: int, what: str) -> None:
        """Refuse frames of ``width`` x ``height`` that are not the camera's size (:class:`InputError` naming ``what``)."""
        if self.camera is not None:
            self.camera.check_size(width, height, what)

    def check(self, width: int, height: int, what: str) -> None:
        """Refuse frames of ``width`` x ``height`` that this road cannot measure.

        Raises
        ------
        InputError
            Naming ``what``: the frames are not the camera's or the road plane's size, or lanes
            are asked for without a road plane.
        """
        if self.camera is not None:
            self.camera.check_size(width, height, what)
        plane = self.plane
        if plane is not None and tuple(plane.image_size) != (width, height):
            w, h = plane.image_size
            raise InputError(f"{what} is {width}x{height}, but the bird's-eye transform is for {w}x{h} frames")
        if self.lanes and plane is None:
            raise InputError("lanes need a bird's-eye transform: a camera file made with 'calibrate --straight' (or birds_eye=), "
                             "or Road.for_footage, which estimates it from the footage")

    def for_footage(self, footage: str | os.PathLike | Sequence[np.ndarray], *, start: int = 0) -> tuple[Road, RoadEstimate | None]:
        """This road for one input: the road plane estimated from the footage when lanes need one.

        Parameters
        ----------
        footage : path-like or sequence of ndarray
            A video (:func:`~vehicle_detection.road.autocamera.road_transform` samples its first
            seconds from frame ``start``), or the RGB frames (images) to estimate from, all of
            one size.
        start : int
            First decoded frame of the video to look at.

        Returns
        -------
        road : Road
            Itself when no lanes are asked for or a road plane is known; else with the plane
            estimated from the footage (frames undistorted with ``camera`` first; the scale along
            the road from ``dash_period_m``), or without
            lanes when the footage shows no lane lines (never a guess).
        estimate : RoadEstimate or None
            What the estimate found (``estimate.reason``: why there is no plane), None when
            nothing was estimated.

        Raises
        ------
        InputError
            If the frames are not of one size, or not of the camera's size.
        """
        if not self.estimates:
            return self, None
        if isinstance(footage, (str, os.PathLike)):
            if self.camera is not None:
                info = probe_video(footage)
                self.camera.check_size(info.width, info.height, f"{footage}: the video")
            birds_eye, estimate = road_transform(footage, self.camera, start=start, settings=EstimateSettings(dash_period_m=self.dash_period_m))
        else:
            sizes = {f.shape[:2] for f in footage}
            if self.camera is not None:
                for h, w in sizes:
                    self.camera.check_size(w, h, "the image")
            if len(sizes) > 1:
                raise InputError(f"the images are of {len(sizes)} sizes; a road plane is estimated from images of one camera "
                                 "(give --camera, or run each size on its own)")
            settings = EstimateSettings(dash_period_m=self.dash_period_m, min_frames=1, min_dash_frames=1)
            birds_eye, estimate = estimate_birds_eye(footage, self.camera, settings)
        if birds_eye is None:
            return replace(self, lanes=False), estimate
        return replace(self, birds_eye=birds_eye), estimate

    def survey(self, fps: float = 25.0, *, shot_cuts: ShotCuts | None = None) -> RoadSurvey:
        """The road of one video at ``fps`` frames per second (or of one image), from its first
        frame; with ``shot_cuts``, the lane is found afresh after each cut between shots
        (:mod:`~vehicle_detection.footage.shots`)."""
        return RoadSurvey(self, fps, shot_cuts=shot_cuts)


class RoadSurvey:
    """The road of one video, asked frame by frame in order (see :meth:`Road.survey`).

    Attributes
    ----------
    lane_rows : list of (int, float or None, float or None)
        ``(frame, radius_m, offset_m)`` of every frame :meth:`record` was given (the lanes CSV).
    """

    def __init__(self, road: Road, fps: float = 25.0, *, shot_cuts: ShotCuts | None = None) -> None:
        self.road = road
        plane = road.plane
        self._lanes = LaneTracker(plane) if road.lanes else None
        self._cuts, self._shot = shot_cuts, (None, ())  # the last frame's thumbnail and changes
        self._distances = None if plane is None else DistanceTracker(plane, fps)
        self.lane_rows: list[tuple[int, float | None, float | None]] = []

    @property
    def finds_lanes(self) -> bool:
        return self._lanes is not None

    @property
    def changes_frames(self) -> bool:
        """Whether :meth:`undistort` or :meth:`find_lane` has work to do."""
        return self.road.camera is not None or self._lanes is not None

    def undistort(self, frame: np.ndarray) -> np.ndarray:
        """The frame with the lens distortion undone (the frame itself without a camera)."""
        return frame if self.road.camera is None else self.road.camera.undistort(frame)

    def find_lane(self, frame: np.ndarray) -> Lane | None:
        """The lane of the next (undistorted) frame; None when lanes are not asked for or not found.

        A frame that starts a new shot is searched afresh: no fit of the last shot is kept.
        """
        if self._lanes is None:
            return None
        if self._cuts is not None:
            cut, thumb, changes = next_shot(frame, *self._shot, self._cuts)
            self._shot = (thumb, changes)
            if cut:
                self._lanes.reset()
        return self._lanes.step(frame)

    def measure(self, found: Detections) -> Detections:
        """The next frame's boxes with ``distance_m`` and ``relative_speed_mps`` when the road
        plane is known (else ``found`` as it is)."""
        return found if self._distances is None else self._distances.update(found)

    def complete(self, table: Detections) -> Detections:
        """The run's table with the distance columns even when it has no box (else as it is)."""
        if self._distances is None or len(table):
            return table
        return table.replace(data={**table.data, **{c: np.zeros(0) for c in DISTANCE_COLUMNS}})

    def record(self, frame: int, lane: Lane | None) -> None:
        """Add frame ``frame``'s lane (or its absence) to :attr:`lane_rows`, when lanes are asked for."""
        if self._lanes is not None:
            self.lane_rows.append(lane_row(frame, lane))

    def draw(self, frame: np.ndarray, lane: Lane | None, area: tuple[int, int, int, int] | None = None) -> np.ndarray:
        """The (undistorted) frame with its lane drawn, when lanes are asked for; else the frame.
        ``area``: the picture inside black bars, where the lane is drawn (default: the frame's
        own, :func:`~vehicle_detection.road.lanes.draw_lane`)."""
        return frame if self._lanes is None else draw_lane(frame, lane, self.road.plane, area=area)
