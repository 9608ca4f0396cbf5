"""The settings a detector runs with, saved in the model file beside the classifier.

The search threshold, the heat thresholds and the tracker's settings are tuned to one model's
margin scale, so they travel with it: a model file carries its
:class:`~vehicle_detection.features.FeatureConfig` (how features are computed) and a
:class:`DetectorConfig` (where to search, and how windows become tracked vehicles).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any, Literal

from .footage.exposure import Exposure
from .footage.horizon import CarHorizon
from .refine import SideFit
from .search import SearchPlan, SearchScale
from .footage.shots import ShotCuts
from .tracker import TrackerConfig

__all__ = ["DetectorConfig"]

#: The sides of the road traffic keeps to (:attr:`DetectorConfig.traffic`).
TRAFFIC = ("right", "left")


@dataclass(frozen=True)
class DetectorConfig:
    """How a :class:`~vehicle_detection.detector.Detector` turns a model's margins into vehicles.

    Parameters
    ----------
    plan : SearchPlan
        Where to search, at which window sizes, and the margin a window needs.
    tracker : TrackerConfig
        Heat, blob and track settings. Its heat and blob settings (``cell``, ``score_gain``,
        ``min_size``, ``aspect_range``, ``peak_fraction``, ``split_size``) apply to single
        images too.
    image_threshold : float
        Heat a single image's blob must exceed (videos use the tracker's integrated threshold).
    auto_horizon : bool
        When the plan fixes no ``horizon``, estimate the camera's horizon from a video's first
        frames (:mod:`~vehicle_detection.footage.horizon`) and move the search bands to it. Where no
        estimate can be made, and for single images, the plan is used as written.
    car_horizon : CarHorizon or None
        With ``auto_horizon``, where the road's lines give no horizon, read it off the cars
        found with the bands at several candidate horizons
        (:func:`~vehicle_detection.footage.horizon.horizon_from_cars`). None: from the lines only.
    auto_overlays : bool
        Search only the picture inside black bars, and drop windows lying mostly on the
        camera car's static parts (bonnet, windscreen mount) or burnt-in text, all found from a
        video's first frames (:mod:`~vehicle_detection.footage.overlays`); single images are cut from
        their own bars. Footage without either is searched as before.
    side_fit : SideFit or None
        Move the boxes' left and right sides onto the vehicle's vertical edges in the frame
        (:func:`~vehicle_detection.refine.fit_sides`): a single image's boxes, and in a video
        each blob's box before the tracker matches it and averages it into its track; None
        reports the boxes as the heat and the tracker give them.
    shot_cuts : ShotCuts or None
        In a video, find the cuts between shots (:mod:`~vehicle_detection.footage.shots`) and start
        the tracker afresh at each (:meth:`~vehicle_detection.tracker.Tracker.cut`): no track,
        and no heat, is carried from one shot into the next. None: the footage is taken as one
        shot.
    exposure : Exposure or None
        Brighten dark footage (dusk, dark cameras) for the search
        (:mod:`~vehicle_detection.footage.exposure`): a video measured on its first frames and at each
        cut, an image or a frame searched on its own on itself. None: searched as it is.
    traffic : {"right", "left"}
        The side of the road the footage's traffic keeps to. A model learns the traffic of its
        labelled frames (right-hand, for the embedded model): which flank the cars beside the
        camera show, and the cars themselves. With ``"left"`` (the United Kingdom, Japan, India,
        Australia) each picture is searched flipped left to right, and its windows and refined
        boxes are flipped back: the model sees right-hand traffic, and the boxes are where the
        cars are. Everything else (bars, overlays, light, horizon, heat, tracks, side fit) works
        on the frame as it is.
    """

    plan: SearchPlan = field(default_factory=SearchPlan)
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    image_threshold: float = 3.0
    auto_horizon: bool = True
    auto_overlays: bool = True
    side_fit: SideFit | None = field(default_factory=SideFit)
    shot_cuts: ShotCuts | None = field(default_factory=ShotCuts)
    exposure: Exposure | None = field(default_factory=Exposure)
    car_horizon: CarHorizon | None = field(default_factory=CarHorizon)
    traffic: Literal["right", "left"] = "right"

    def __post_init__(self) -> None:
        if not isinstance(self.plan, SearchPlan):
            raise ValueError(f"DetectorConfig.plan must be a SearchPlan; got {type(self.plan).__name__}")
        if not isinstance(self.tracker, TrackerConfig):
            raise ValueError(f"DetectorConfig.tracker must be a TrackerConfig; got {type(self.tracker).__name__}")
        t = self.image_threshold
        if isinstance(t, bool) or not isinstance(t, (int, float)) or not math.isfinite(t) or t < 0:
            raise ValueError(f"DetectorConfig.image_threshold must be a finite number >= 0; got {t!r}")
        object.__setattr__(self, "image_threshold", float(t))
        for name in ("auto_horizon", "auto_overlays"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"DetectorConfig.{name} must be True or False; got {getattr(self, name)!r}")
        if self.side_fit is not None and not isinstance(self.side_fit, SideFit):
            raise ValueError(f"DetectorConfig.side_fit must be a SideFit or None; got {type(self.side_fit).__name__}")
        if self.shot_cuts is not None and not isinstance(self.shot_cuts, ShotCuts):
            raise ValueError(f"DetectorConfig.shot_cuts must be a ShotCuts or None; got {type(self.shot_cuts).__name__}")
        if self.exposure is not None and not isinstance(self.exposure, Exposure):
            raise ValueError(f"DetectorConfig.exposure must be an Exposure or None; got {type(self.exposure).__name__}")
        if self.car_horizon is not None and not isinstance(self.car_horizon, CarHorizon):
            raise ValueError(f"DetectorConfig.car_horizon must be a CarHorizon or None; got {type(self.car_horizon).__name__}")
        if self.traffic not in TRAFFIC:
            raise ValueError(f"DetectorConfig.traffic must be one of {', '.join(map(repr, TRAFFIC))}; got {self.traffic!r}")

    @classmethod
    def library_0_1(cls) -> DetectorConfig:
        """The settings library 0.1 ran every model with (its model files saved none).

        Model files of format 1 load with these; comparing with them shows what later settings
        changed (the writeup does).
        """
        plan = SearchPlan(
            scales=(
                SearchScale(1.0, 400, 496, step=2),
                SearchScale(1.5, 400, 544, step=1),
                SearchScale(2.0, 400, 592, step=1),
                SearchScale(3.0, 400, 688, step=1),
            ),
            threshold=0.3,
            reference_height=720,
            overhang=0.0,
            horizon=None,
            coarse_margin=None,
            window_border="crop",
        )
        tracker = TrackerConfig(
            decay=0.6, threshold=6.0, cell=8, min_hits=3, max_misses=5, smoothing=0.3, match_iou=0.2, min_size=(32, 32),
            aspect_range=(0.3, 4.0), score_gain=1.0, peak_fraction=0.3, split_size=(64, 64), window_inset=(0.0, 0.0, 0.0, 0.0),
        )
        return cls(plan=plan, tracker=tracker, image_threshold=2.0, auto_horizon=False, auto_overlays=False, side_fit=None,
                   shot_cuts=None, exposure=None, car_horizon=None)

    def replace(self, **changes: Any) -> DetectorConfig:
        """A copy with some fields replaced."""
        return replace(self, **changes)

    def at_horizon(self, horizon: float | str | None) -> DetectorConfig:
        """A copy searching at ``horizon``.

        Parameters
        ----------
        horizon : float, "auto", "plan" or None
            A fraction of the frame height: that horizon, fixed. ``"auto"``: estimated from
            the footage. ``"plan"``: the plan's bands as written, never moved. None: unchanged.
        """
        if horizon is None:
            return self
        if horizon == "auto":
            return replace(self, plan=replace(self.plan, horizon=None), auto_horizon=True)
        if horizon == "plan":
            return replace(self, plan=replace(self.plan, horizon=None), auto_horizon=False)
        if isinstance(horizon, str):
            raise ValueError(f"horizon must be a fraction, 'auto' or 'plan'; got {horizon!r}")
        return replace(self, plan=replace(self.plan, horizon=float(horizon)))

    def to_dict(self) -> dict:
        """Plain JSON data."""
        return {
            "plan": self.plan.to_dict(),
            "tracker": self.tracker.to_dict(),
            "image_threshold": self.image_threshold,
            "auto_horizon": self.auto_horizon,
            "auto_overlays": self.auto_overlays,
            "side_fit": None if self.side_fit is None else self.side_fit.to_dict(),
            "shot_cuts": None if self.shot_cuts is None else self.shot_cuts.to_dict(),
            "exposure": None if self.exposure is None else self.exposure.to_dict(),
            "car_horizon": None if self.car_horizon is None else self.car_horizon.to_dict(),
            "traffic": self.traffic,
        }

    @classmethod
    def from_dict(cls, d: Any) -> DetectorConfig:
        """The inverse of :meth:`to_dict`.

        Files saved before ``auto_horizon`` load with it False (their bands as they were
        searched); files saved before ``auto_overlays`` with it True (it changes nothing on
        footage without bars or static overlays, such as the project camera's); files saved
        before ``side_fit`` with None (their boxes as they were reported), before
        ``shot_cuts`` with None (their videos tracked as one shot), before ``exposure``
        with None (dark footage searched as it is), before ``car_horizon`` with None
        (the horizon from the road's lines only), and before ``traffic`` with ``"right"``.

        Raises
        ------
        ValueError
            If a key is missing or unknown, or a value is out of range.
        """
        keys = {"plan", "tracker", "image_threshold"}
        optional = ("auto_horizon", "auto_overlays", "side_fit", "shot_cuts", "exposure", "car_horizon", "traffic")
        if not isinstance(d, dict) or not keys <= set(d) <= keys | set(optional):
            raise ValueError(
                "expected an object with 'plan', 'tracker', 'image_threshold' and optionally "
                + ", ".join(f"'{k}'" for k in optional)
            )
        side_fit, shot_cuts, exposure, cars = d.get("side_fit"), d.get("shot_cuts"), d.get("exposure"), d.get("car_horizon")
        return cls(
            plan=SearchPlan.from_dict(d["plan"]),
            tracker=TrackerConfig.from_dict(d["tracker"]),
            image_threshold=d["image_threshold"],
            auto_horizon=d.get("auto_horizon", False),
            auto_overlays=d.get("auto_overlays", True),
            side_fit=None if side_fit is None else SideFit.from_dict(side_fit),
            shot_cuts=None if shot_cuts is None else ShotCuts.from_dict(shot_cuts),
            exposure=None if exposure is None else Exposure.from_dict(exposure),
            car_horizon=None if cars is None else CarHorizon.from_dict(cars),
            traffic=d.get("traffic", "right"),
        )
