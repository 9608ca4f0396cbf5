"""The detector: a model, a search plan and a tracker, applied to images and frame sequences.

:class:`Detector` is what the command line and the notebooks use:

* :meth:`Detector.detect_image` finds vehicles in one picture: scored windows
  (:func:`~vehicle_detection.search.search`) -> heat weighted by margin
  (:mod:`~vehicle_detection.heatmap`) -> threshold -> one box per blob;
* :meth:`Detector.track` follows vehicles through frames with a
  :class:`~vehicle_detection.tracker.Tracker`, which integrates heat over recent frames to
  reject one-frame false positives and keeps a stable, smoothed box per vehicle.

Footage of other cameras is measured from its first frames (:meth:`Detector.for_footage`):
the horizon the search bands move to (:mod:`~vehicle_detection.footage.horizon`), and the black bars
and static overlays (:mod:`~vehicle_detection.footage.overlays`): only the picture inside the bars is
searched, and windows lying mostly on the camera car's static parts are dropped before they
make heat.
"""

from __future__ import annotations

import copy
import itertools
import threading
from collections import deque
from collections.abc import Iterable, Iterator
from concurrent.futures import ThreadPoolExecutor
from contextlib import closing

import numpy as np

from .warmup import compile_search_kernels, load_search_kernels
from .classifier import VehicleClassifier, load_default_model
from .config import DetectorConfig
from .detections import Detections
from .footage.exposure import brighten, exposure_gain, picture_level
from .geometry import inset_boxes, mirror_boxes, mirror_image
from .heatmap import add_heat, heat_to_boxes, split_blobs, vote_boxes
from .footage.horizon import TOLERANCE, estimate_horizon, horizon_from_cars
from .io.images import as_image, as_rgb_uint8
from .io.timeline import Timeline, timing
from .footage.overlays import Overlays, active_area, find_overlays, mask_integral, mask_share
from .refine import fit_sides
from .search import search, window_patches
from .footage.shots import next_shot
from .tracker import Tracker, TrackerState, window_heat

__all__ = ["Detector"]

#: Frames at the start of a video that the horizon and the overlays are estimated from. They
#: are held in memory until they are searched (about 33 MB at 1280x720).
HORIZON_FRAMES = 12
#: A window with more than this share of its area on the static overlay mask is dropped.
MASKED_SHARE = 0.35


def _load_kernels(model: VehicleClassifier, plan) -> None:
    """:func:`~vehicle_detection.warmup.load_search_kernels` in a thread of its own: a kernel it
    fails to load is compiled on first use instead, so its errors are the search's to report."""
    try:
        load_search_kernels(model, plan)
    except Exception:  # noqa: BLE001  (the first search compiles the kernel and raises the same error there)
        pass


def _rgb_frames(frames: Iterable, first: int) -> Iterator[np.ndarray]:
    """``frames`` as RGB ``uint8`` ``(H, W, 3)`` (:func:`~vehicle_detection.io.images.as_rgb_uint8`:
    grey, RGBA and uint16 converted, anything else refused naming the frame), the first one
    being frame ``first``."""
    for i, frame in enumerate(frames, start=first):
        yield as_rgb_uint8(frame, name=f"frame {i}")


def _footage_overlays(first: list) -> Overlays | None:
    """The overlays of a video's first frames, measured on those up to the first that is not RGB
    ``uint8`` of the first one's shape (the search reports that one, where it always has)."""
    good: list[np.ndarray] = []
    for frame in first:
        frame = np.asarray(frame)
        if frame.dtype != np.uint8 or frame.ndim != 3 or frame.shape[2] != 3 or (good and frame.shape != good[0].shape):
            break
        good.append(frame)
    return find_overlays(good) if good else None


#: Largest gain :meth:`Detector.with_gain` takes (the exposure rule's own gains are at most its
#: ``max_gain``, 4 by default).
MAX_GAIN = 64.0


class Detector:
    """Vehicle detector over images and videos.

    Parameters
    ----------
    model : VehicleClassifier, optional
        Defaults to the embedded model.
    config : DetectorConfig, optional
        Search plan, heat and tracker settings; defaults to the ones saved with ``model``, to
        which its thresholds are tuned.

    Examples
    --------
    >>> import vehicle_detection as vd
    >>> detector = vd.Detector()
    >>> found = detector.detect_image(vd.read_image("test_images/test1.jpg"))
    >>> len(found), found.track_id is None
    (2, True)
    """

    _overlays: Overlays | None = None  # the footage's bars and mask (with_overlays); None: each frame's bars
    _mask_sums: np.ndarray | None = None  # summed-area table of the mask
    _gain: float | None = None  # the footage's gain for the search (with_gain); None: each frame's own

    def __init__(self, model: VehicleClassifier | None = None, config: DetectorConfig | None = None):
        self.model = load_default_model() if model is None else model
        if not isinstance(self.model, VehicleClassifier):
            raise ValueError(f"model must be a VehicleClassifier; got {type(self.model).__name__}")
        self.config = self.model.detector_config if config is None else config
        if not isinstance(self.config, DetectorConfig):
            raise ValueError(f"config must be a DetectorConfig; got {type(self.config).__name__}")

    @classmethod
    def load(cls, path=None, *, horizon: float | str | None = None, traffic: str | None = None) -> Detector:
        """A detector from a model file (the embedded model when ``path`` is None), with its
        saved settings, searching at ``horizon`` (see :meth:`DetectorConfig.at_horizon`), for
        ``traffic`` (``"right"`` or ``"left"``, :attr:`DetectorConfig.traffic`; None: the
        model's setting)."""
        model = load_default_model() if path is None else VehicleClassifier.load(path)
        config = model.detector_config.at_horizon(horizon)
        return cls(model, config if traffic is None else config.replace(traffic=traffic))

    def __repr__(self) -> str:
        return f"Detector({self.model!r}, {self.config!r})"

    @property
    def estimates_horizon(self) -> bool:
        """Whether the search bands follow the camera's horizon estimated from a video's first frames."""
        return self.config.auto_horizon and self.config.plan.horizon is None

    def with_horizon(self, horizon: float | None) -> Detector:
        """This detector with its plan's bands moved to ``horizon`` (None: as written)."""
        if horizon is None:
            return self
        out = copy.copy(self)  # a subclass stays one
        out.config = self.config.at_horizon(float(horizon))
        return out

    def with_overlays(self, overlays: Overlays | None) -> Detector:
        """This detector searching only ``overlays.area`` and dropping windows on ``overlays.mask``
        (None: as configured, each frame cut from its own bars when ``auto_overlays``)."""
        if overlays is None:
            return self
        out = copy.copy(self)
        out._overlays = overlays
        out._mask_sums = None if overlays.mask is None else mask_integral(overlays.mask)
        return out

    def with_gain(self, gain: float | None) -> Detector:
        """This detector searching frames multiplied by ``gain`` (dark footage,
        :mod:`~vehicle_detection.footage.exposure`; None: as configured, each frame by its own measure)."""
        if gain is None:
            return self
        if isinstance(gain, bool) or not isinstance(gain, (int, float, np.integer, np.floating)) or not 0 < gain <= MAX_GAIN:
            raise ValueError(f"gain must be a number in (0, {MAX_GAIN:g}] or None; got {gain!r}")
        out = copy.copy(self)
        out._gain = float(gain)
        return out

    def _search_gain(self, picture: np.ndarray) -> float:
        """What ``picture`` is multiplied by for the search: the footage's gain, else its own."""
        rule = self.config.exposure
        if rule is None:
            return 1.0
        return self._gain if self._gain is not None else exposure_gain(picture_level(picture), rule)

    def _moved_to(self, estimate: float | None) -> float | None:
        """The horizon to search at for an estimate: None when there is none or it is the reference's."""
        if estimate is None or abs(estimate - self.config.plan.reference_horizon) <= TOLERANCE:
            return None
        return estimate

    def for_footage(
        self, frames: Iterator[np.ndarray], tracker: Tracker, *, workers: int = 1
    ) -> tuple[Detector, Iterator[np.ndarray]]:
        """The detector for a video's frames, and the frames (none consumed).

        The first time (for a fresh ``tracker``), the first :data:`HORIZON_FRAMES` frames are
        measured, and what is found is kept in ``tracker.state``, so later chunks of the same
        video are searched the same way:

        * with ``auto_overlays``, the black bars and static overlays
          (:func:`~vehicle_detection.footage.overlays.find_overlays`): the returned detector searches the
          picture inside the bars and drops windows with more than :data:`MASKED_SHARE` of their
          area on the mask;
        * with ``exposure``, whether the picture is dark
          (:func:`~vehicle_detection.footage.exposure.exposure_gain` of the median of the frames'
          levels): the returned detector searches the frames brightened by that gain;
        * with :attr:`estimates_horizon`, the horizon of the picture (brightened); the returned
          detector searches there, unless the estimate lies within
          :data:`~vehicle_detection.footage.horizon.TOLERANCE` of the plan's ``reference_horizon``.

        ``workers`` frames are measured at once (threads); the result is the same.
        :meth:`steps` measures each new shot again (:meth:`shot_cut`).
        """
        overlays, exposure, horizon = self.config.auto_overlays, self.config.exposure, self.estimates_horizon
        if not (overlays or exposure or horizon):
            return self, frames
        state = tracker.state
        if (overlays and not state.overlays_searched) or (exposure and state.gain is None) or (horizon and not state.horizon_searched):
            first = list(itertools.islice(frames, HORIZON_FRAMES))
            frames = itertools.chain(first, frames)
            self._measure(first, state, workers)
        return self._for_state(state), frames

    def _measure(self, first: list, state: TrackerState, workers: int, *, new_shot: bool = False, start: int | None = None) -> None:
        """Measure what :meth:`for_footage` says on ``first``, the first frames of the footage or
        (``new_shot``) of a new shot, the one of index ``start`` (default: ``state.frame_index``),
        into ``state``. A new shot whose horizon cannot be estimated keeps the last shot's (the
        same camera, as likely as not)."""
        overlays, exposure, horizon = self.config.auto_overlays, self.config.exposure, self.estimates_horizon
        if overlays and (new_shot or not state.overlays_searched):
            state.overlays = _footage_overlays(first)
            state.overlays_searched = True
        pictures = self._pictures(first, state)
        if exposure and (new_shot or state.gain is None):
            levels = [picture_level(p) for p in pictures if np.ndim(p) == 3 and np.shape(p)[2] == 3]
            state.gain = exposure_gain(float(np.median(levels)), exposure) if levels else 1.0
        if horizon and (new_shot or not state.horizon_searched):
            start = state.frame_index if start is None else start
            self._measure_horizon(first, state, workers, start=start, end=start + len(first), keep_last=new_shot)

    def _measure_horizon(self, frames: list, state: TrackerState, workers: int, *, start: int, end: int, keep_last: bool) -> bool:
        """Estimate the horizon of ``frames``, the frames before ``end`` of the shot that began at
        ``start``, into ``state``: from the road's lines, else (``car_horizon``) from the cars. With
        ``keep_last``, no estimate keeps the horizon ``state`` has. Where neither gives one, the
        shot is measured again later (:meth:`steps`), when it is twice as old: cars come and go.
        Whether an estimate was made."""
        pictures = [brighten(p, state.gain) if state.gain is not None else p for p in self._pictures(frames, state)]
        estimate, source = estimate_horizon(pictures, min_frames=min(3, len(frames)), workers=workers), "lines"
        if estimate is None and self.config.car_horizon is not None:
            estimate, source = self._horizon_from_cars(frames, state, workers), "cars"
        if estimate is not None or not keep_last:
            state.horizon = self._moved_to(estimate)
            state.horizon_source = source if state.horizon is not None else None
        state.horizon_searched = True
        again = estimate is None and self.config.car_horizon is not None
        # at twice the shot's age: before frames 24, 48, 96, ... of it (a first measurement on
        # fewer frames, a short first chunk, keeps the same schedule)
        state.horizon_retry = (start, start + 2 * max(HORIZON_FRAMES, end - start)) if again else None
        return estimate is not None

    def _pictures(self, frames: list, state: TrackerState) -> list:
        """``frames`` cut to the picture inside the footage's bars (``state.overlays``, with
        ``auto_overlays``); frames of another size as they are."""
        cut = state.overlays if self.config.auto_overlays else None
        return [cut.crop(f) if cut is not None and np.shape(f)[:2] == cut.shape else f for f in frames]

    def _horizon_from_cars(self, first: list, state: TrackerState, workers: int) -> float | None:
        """The horizon of ``first`` read off the cars found with the bands at each candidate
        horizon of ``config.car_horizon`` (:func:`~vehicle_detection.footage.horizon.horizon_from_cars`),
        searching as ``state`` says otherwise (bars, overlays, light); None if they do not agree."""
        rule = self.config.car_horizon
        frames = [f for f in first if np.shape(f) == np.shape(first[0]) and np.asarray(f).dtype == np.uint8]
        if not frames or np.ndim(frames[0]) != 3 or np.shape(frames[0])[2] != 3:
            return None
        load_search_kernels(self.model, self.config.plan)  # a thread may be loading them now: wait for it
        frames = frames[:: max(1, len(frames) // rule.frames)][: rule.frames]
        base = self.with_gain(state.gain)
        cut = state.overlays if self.config.auto_overlays else None
        base = base.with_overlays(cut)
        top, height = (cut.area[1], cut.area[3] - cut.area[1]) if cut is not None and cut.cropped else (0, frames[0].shape[0])

        def hits(job):
            candidate, frame = job
            found = base.with_horizon(candidate).windows(frame)
            boxes = np.asarray(found.data.get("box", found.xyxy), np.float64).reshape(-1, 4) - (0, top, 0, top)
            return candidate, boxes, found.score

        jobs = [(c, f) for c in rule.candidates for f in frames]
        with ThreadPoolExecutor(max_workers=max(1, workers), thread_name_prefix="horizon") as pool:
            return horizon_from_cars(pool.map(hits, jobs), height, rule)

    def image_horizon(self, image: np.ndarray) -> tuple[float | None, str | None]:
        """The horizon of one image, and where it was read.

        From the image's road lines (:func:`~vehicle_detection.footage.horizon.estimate_horizon`), else,
        with ``config.car_horizon``, from the cars found in it with the bands at each candidate
        horizon. Both are read inside the image's own black bars (with ``auto_overlays``), as a
        fraction of the height of the picture there, from the top: where the search places its
        bands. What ``detect --horizon auto`` does for images; :meth:`detect_image` itself
        searches where the plan says.

        Parameters
        ----------
        image : ndarray of uint8, shape (H, W, 3)
            An RGB image of a road ahead.

        Returns
        -------
        (float or None, str or None)
            The horizon and ``"lines"`` or ``"cars"``; ``(None, None)`` when neither gives one.
        """
        image = as_rgb_uint8(image, name="image")
        state = TrackerState()
        if self.config.auto_overlays:  # the search's bands are placed in the picture inside the bars
            state.overlays, state.overlays_searched = Overlays(image.shape[:2], active_area(image)), True
        estimate = estimate_horizon(self._pictures([image], state), min_frames=1)
        if estimate is not None:
            return estimate, "lines"
        if self.config.car_horizon is None:
            return None, None
        estimate = self._horizon_from_cars([image], state, workers=1)
        return (estimate, "cars") if estimate is not None else (None, None)

    def _for_state(self, state: TrackerState) -> Detector:
        """This detector searching as the footage measured in ``state`` says."""
        det = self.with_horizon(state.horizon).with_gain(state.gain)
        return det.with_overlays(state.overlays) if self.config.auto_overlays else det

    def windows(self, frame: np.ndarray, around: np.ndarray | None = None) -> Detections:
        """Windows of one RGB ``uint8`` frame whose margin exceeds the plan's threshold.

        Only the picture is searched: inside the footage's black bars (:meth:`with_overlays`,
        set by :meth:`for_footage`), else, with ``auto_overlays``, inside the frame's own
        (:func:`~vehicle_detection.footage.overlays.active_area`). Windows with more than
        :data:`MASKED_SHARE` of their area on the footage's static overlays are dropped. With
        ``exposure``, a dark picture is searched brightened (by the footage's gain,
        :meth:`with_gain`, else by its own; :mod:`~vehicle_detection.footage.exposure`).

        Parameters
        ----------
        around : ndarray (n, 4), optional
            None searches the whole plan; boxes (live tracks) search only between full
            searches' regions (see :class:`~vehicle_detection.search.SearchPlan`).

        Returns
        -------
        Detections
            The windows in frame pixels, their SVM margins as ``score`` and ``data["scale_index"]``.
            In left-hand traffic (``config.traffic``) the picture is searched flipped left to right
            and the windows flipped back, so they lie on the flipped picture's grid, not the
            frame's: :meth:`patches` cuts what the classifier scored.
        """
        picture, shift = self._searched_picture(as_rgb_uint8(frame, name="frame"))
        if shift is None:
            found = self._search(picture, around)
        else:
            inside = None if around is None else np.asarray(around, np.float64).reshape(-1, 4) - shift
            found = self._search(picture, inside)
            data = {k: v + shift if k == "box" else v for k, v in found.data.items()}
            found = found.replace(xyxy=found.xyxy + shift, data=data)
        if self._mask_sums is None or not len(found):
            return found
        return found[mask_share(found.xyxy, self._mask_sums) <= MASKED_SHARE]

    def patches(self, frame: np.ndarray, windows: Detections) -> np.ndarray:
        """The patches the classifier scored for ``windows``, windows :meth:`windows` found in
        ``frame``: cut from the picture it searched (inside the bars, brightened, flipped in
        left-hand traffic) by :func:`~vehicle_detection.search.window_patches`.

        Returns
        -------
        ndarray of uint8, shape (len(windows), window, window, 3)
        """
        picture, shift = self._searched_picture(as_rgb_uint8(frame, name="frame"))
        boxes = np.asarray(windows.xyxy) if shift is None else np.asarray(windows.xyxy) - shift
        if self._left:
            boxes = mirror_boxes(boxes, picture.shape[1])
        return window_patches(self._oriented(picture), windows.replace(xyxy=boxes), self.model, self.config.plan)

    def _searched_picture(self, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
        """The picture :meth:`windows` searches in ``frame`` (inside the bars, brightened), and its
        offset in the frame as ``[x, y, x, y]`` (None: the whole frame)."""
        overlays = self._picture(frame)
        if overlays is None or not overlays.cropped:
            return brighten(frame, self._search_gain(frame)), None
        picture = overlays.crop(frame)
        return brighten(picture, self._search_gain(picture)), np.array(overlays.area[:2] * 2)

    def _search(self, picture: np.ndarray, around: np.ndarray | None) -> Detections:
        """:func:`~vehicle_detection.search.search` of ``picture``; in left-hand traffic
        (``config.traffic``) of the picture flipped left to right, its windows flipped back."""
        if not self._left:
            return search(picture, self.model, self.config.plan, around=around)
        width = picture.shape[1]
        flipped = None if around is None else mirror_boxes(np.asarray(around, np.float64).reshape(-1, 4), width)
        found = search(self._oriented(picture), self.model, self.config.plan, around=flipped)
        data = {k: mirror_boxes(v, width) if k == "box" else v for k, v in found.data.items()}
        return found.replace(xyxy=mirror_boxes(found.xyxy, width), data=data)

    @property
    def _left(self) -> bool:
        return self.config.traffic == "left"

    def _oriented(self, picture: np.ndarray) -> np.ndarray:
        """``picture`` as the model learned its traffic: flipped left to right in left-hand traffic."""
        return mirror_image(picture) if self._left else picture

    def _picture(self, frame: np.ndarray) -> Overlays | None:
        """The footage's overlays, else with ``auto_overlays`` the bars of ``frame`` itself, else None."""
        if self._overlays is None and self.config.auto_overlays:
            return Overlays(frame.shape[:2], active_area(frame))
        return self._overlays

    @staticmethod
    def _inside(found: Detections, overlays: Overlays | None) -> Detections:
        """``found`` cut to the picture: a box from heat cells anchored at the frame's corner may
        reach up to a cell into the bars."""
        if overlays is None or not overlays.cropped or not len(found):
            return found
        x1, y1, x2, y2 = overlays.area
        xy = np.clip(found.xyxy, [x1, y1, x1, y1], [x2, y2, x2, y2])
        if np.array_equal(xy, found.xyxy):
            return found
        keep = (xy[:, 2] > xy[:, 0]) & (xy[:, 3] > xy[:, 1])
        return found[keep].replace(xyxy=xy[keep])

    def _scheduled_around(self, tracker: Tracker, frame_index: int, shot_start: int) -> np.ndarray | None:
        """What :meth:`windows` searches in frame ``frame_index``: None (whole) or the live tracks' boxes.

        The first ``min_hits`` frames of the shot starting at ``shot_start``
        (:attr:`Tracker.shot_start <vehicle_detection.tracker.Tracker.shot_start>` where the
        tracker has reached the frame) are searched whole: a vehicle seen from the shot's start
        is then confirmed, and reported from its first frame, as with every frame searched whole."""
        every = self.config.plan.full_search_every
        if every <= 1 or frame_index % every == 0 or frame_index - shot_start < self.config.tracker.min_hits:
            return None
        tracks = tracker.state.tracks
        return np.stack([t.box for t in tracks]) if tracks else np.zeros((0, 4))

    def _tracker_input(self, windows: Detections) -> Detections:
        """What the tracker takes: each window as the box it stands for (refined where the model
        refines, :mod:`~vehicle_detection.refine`), its margin above the plan's threshold as score."""
        score = windows.score - self.config.plan.threshold
        if "box" in windows.data:
            return Detections(windows.data["box"], score=score, frame=windows.frame)
        return windows.replace(score=score)

    def heat(self, frame_shape: tuple[int, ...], windows: Detections) -> np.ndarray:
        """Heat of one frame's windows as the tracker adds it, ``float32 (H // cell, W // cell)``."""
        cell = self.config.tracker.cell
        h, w = frame_shape[:2]
        heat = np.zeros((h // cell, w // cell), np.float32)
        return add_heat(heat, *self._heat_boxes(windows), cell=cell)

    def _heat_boxes(self, windows: Detections) -> tuple[np.ndarray, np.ndarray]:
        """The boxes the windows add heat to, and their weights (as :meth:`Tracker.update` does)."""
        boxes = self._tracker_input(windows)
        cfg = self.config.tracker
        return inset_boxes(boxes.xyxy, cfg.window_inset), window_heat(boxes.score, cfg.score_gain)

    def detect_image(self, image, windows: Detections | None = None) -> Detections:
        """Vehicles in one image: one box per heat blob.

        Parameters
        ----------
        image : ndarray of uint8, shape (H, W, 3), PIL.Image.Image, str or path-like
            An RGB ``uint8`` array, a Pillow image, or an image file's path; converted once by
            :func:`~vehicle_detection.images.as_image` (grey and RGBA become RGB; floats, and
            anything else, are refused with an ``InputError`` saying what is expected).
        windows : Detections, optional
            The image's hot windows when already computed (:meth:`windows`), to search once.
            An image is searched where the plan says (one frame is too little to estimate the
            horizon reliably); a camera whose horizon sits elsewhere needs :meth:`with_horizon`.
            With ``auto_overlays``, only the picture inside the image's black bars is searched
            (one frame cannot tell what stays still, so nothing is masked).

        Returns
        -------
        Detections
            One box per vehicle with the peak heat of its blob as ``score``; untracked.
        """
        image = as_image(image)
        if windows is None:
            windows = self.windows(image)
        heat = self.heat(image.shape, windows)
        cfg = self.config.tracker
        boxes, peaks = heat_to_boxes(
            heat, self.config.image_threshold, cell=cfg.cell, min_size=cfg.min_size, aspect_range=cfg.aspect_range,
            peak_fraction=cfg.peak_fraction, split_size=cfg.split_size,
        )
        if cfg.cluster_iou > 0:
            win, weights = self._heat_boxes(windows)
            boxes, peaks = split_blobs(boxes, peaks, win, weights, iou=cfg.cluster_iou)
            boxes = vote_boxes(boxes, win, weights, iou=cfg.cluster_iou, fraction=cfg.box_vote)
        picture = self._picture(image)
        return self.fit_boxes(image, self._inside(Detections(boxes, score=peaks), picture), area=self._area(picture))

    def new_tracker(self) -> Tracker:
        """A fresh :class:`~vehicle_detection.tracker.Tracker` with this detector's settings."""
        return Tracker(self.config.tracker)

    def step(self, frame: np.ndarray, tracker: Tracker) -> Detections:
        """Detect in one frame and advance ``tracker`` by it (live use: no lag, no back-fill).

        ``frame`` is converted as :meth:`track` says (grey becomes RGB; floats are refused).

        Live, nothing is seen ahead, so the horizon is not estimated: the plan as written, or
        :meth:`with_horizon`; each frame is cut from its own black bars, and nothing is masked
        unless :meth:`with_overlays` says. A frame that starts a new shot is searched whole,
        and the tracker starts afresh there (:meth:`shot_cut`).
        """
        frame = as_rgb_uint8(frame, name=f"frame {tracker.state.frame_index}")  # grey, RGBA, uint16: RGB once, here
        cut = self.shot_cut(frame, tracker)
        around = None if cut else self._scheduled_around(tracker, tracker.state.frame_index, tracker.shot_start)
        wins = self.windows(frame) if around is None else self.windows(frame, around)
        return self.track_step(frame.shape, wins, tracker, frame, cut=cut)

    def track_step(
        self,
        frame_shape: tuple[int, ...],
        windows: Detections,
        tracker: Tracker,
        frame: np.ndarray | None = None,
        *,
        cut: bool | None = None,
    ) -> Detections:
        """Advance ``tracker`` by one frame's hot windows (from :meth:`windows`).

        With ``frame`` (the frame the windows were found in), each blob's box has its sides
        fitted to the frame (:meth:`fit_boxes`) before the tracker matches it and averages it
        into its track, so the fitted boxes are smoothed along the track like any other; and,
        with ``config.shot_cuts``, when the frame starts a new shot (:meth:`shot_cut`) the
        tracker forgets the last shot's tracks and heat first (:meth:`Tracker.cut`). ``cut``
        says it instead when the caller has already checked the frame.
        """
        if cut is None:
            cut = frame is not None and self.shot_cut(frame, tracker)
        if cut:
            tracker.cut()
        measure = None
        if frame is not None and self.config.side_fit is not None:
            def measure(boxes):
                return fit_sides(frame, boxes, self.config.side_fit, area=self._area())
        return self._inside(tracker.update(self._tracker_input(windows), frame_shape, measure), self._overlays)

    def shot_cut(self, frame: np.ndarray, tracker: Tracker) -> bool:
        """Whether ``frame``, the next frame of ``tracker``'s video, starts a new shot
        (:func:`~vehicle_detection.footage.shots.next_shot` with ``config.shot_cuts``; always False
        when that is None). Each frame must be checked once, in order: the tracker's state
        keeps the last frame's thumbnail."""
        rule = self.config.shot_cuts
        if rule is None:
            return False
        frame = as_rgb_uint8(frame, name="frame")
        st = tracker.state
        cut, st.shot_thumbnail, st.shot_changes = next_shot(frame, st.shot_thumbnail, st.shot_changes, rule)
        return cut

    def _area(self, picture: Overlays | None = None) -> tuple[int, int, int, int] | None:
        """The picture inside black bars (``picture``'s, else the footage's), None for the whole frame."""
        picture = picture if picture is not None else self._overlays
        return None if picture is None else picture.area

    def fit_boxes(self, frame: np.ndarray, found: Detections, *, area: tuple[int, int, int, int] | None = None) -> Detections:
        """``found`` with each box's sides fitted to its vehicle's edges in ``frame``
        (:func:`~vehicle_detection.refine.fit_sides`, with ``config.side_fit``; unchanged when
        that is None). ``area`` is the picture inside black bars (default: the footage's,
        :meth:`with_overlays`, else the whole frame). :meth:`detect_image` reports boxes fitted
        so; in a video the tracker fits each blob before smoothing (:meth:`track_step`)."""
        fit = self.config.side_fit
        if fit is None or not len(found):
            return found
        frame = as_rgb_uint8(frame, name="frame")
        return found.replace(xyxy=fit_sides(frame, found.xyxy, fit, area=area if area is not None else self._area()))

    def track_frames(
        self,
        frames: Iterable[np.ndarray],
        tracker: Tracker | None = None,
        *,
        workers: int = 2,
        timeline: Timeline | None = None,
    ) -> Iterator[tuple[np.ndarray, Detections]]:
        """Like :meth:`track`, also yielding each frame: ``(frame, detections)`` pairs.

        The search of the next ``workers`` frames runs in a thread pool (its compiled kernels
        release the GIL), so both cores work; the tracker is advanced in frame order. Output
        lags ``min_hits - 1`` frames behind the input (fixed-lag smoothing): when a track is
        confirmed, its boxes on the held-back frames before confirmation are filled in, so a
        vehicle is reported from the frame it appeared, and still no track is born from a
        single frame.

        With :attr:`estimates_horizon`, the search bands follow the horizon estimated from the
        first frames (:meth:`for_footage`); where neither the road's lines nor the cars give one
        there, the shot is measured again later, and the bands move when it is found. Where the
        footage cuts to another shot (:meth:`shot_cut`), the tracker starts afresh and the new
        shot is measured again (bars, overlays, light, horizon) from its first frames.

        With a search schedule (``plan.full_search_every > 1``), the frames between full
        searches are searched around the tracks live when the frame is submitted (the tracker
        then stands ``workers`` frames or so behind; ``track_margin`` covers the motion).

        A :class:`~vehicle_detection.io.Timeline` is filled with the stages ``warmup``,
        ``footage``, ``search_wait`` and ``track`` (in this thread) and ``search`` (in the pool).
        """
        tracker = tracker or self.new_tracker()
        lag = max(0, self.config.tracker.min_hits - 1)
        held: deque = deque()  # [frame, index, detections], oldest first

        def release():
            frame, _, found = held.popleft()
            return frame, found[np.argsort(found.track_id, kind="stable")]

        with closing(self.steps(frames, tracker, workers, timeline=timeline)) as steps:
            for frame, index, found, fill in steps:
                for entry in held if len(fill) else ():
                    extra = fill.at_frame(entry[1])
                    if len(extra):
                        entry[2] = Detections.concatenate([entry[2], extra])
                held.append([frame, index, found])
                while len(held) > lag:
                    yield release()
        while held:
            yield release()

    def steps(
        self, frames: Iterable[np.ndarray], tracker: Tracker, workers: int, *, timeline: Timeline | None = None,
        before: Iterable[np.ndarray] = (),
    ) -> Iterator[tuple[np.ndarray, int, Detections, Detections]]:
        """The tracker advanced frame by frame, without lag: ``(frame, index, found, backfill)``.

        The next ``workers`` frames are searched in a thread pool meanwhile. ``backfill`` is
        the tracker's back-fill after the frame (boxes for earlier frames of newly confirmed
        tracks). :meth:`track_frames` holds frames back to apply it; a chunked run
        (:func:`~vehicle_detection.pipeline.batch.track_chunk`) keeps the steps to join them later.
        A ``timeline`` is filled as :meth:`track_frames` says.

        A shot whose horizon is to be measured again (``tracker.state.horizon_retry``) is
        measured on copies of its last :data:`HORIZON_FRAMES` frames (the caller may draw on
        the frames it gets back). ``before``: the frames just before ``frames`` (a chunk's
        predecessors), so that such a measurement early in a chunk sees what a whole run sees.
        """
        frames = _rgb_frames(frames, tracker.state.frame_index)  # each frame checked and converted once, here
        before = list(before)
        before = list(_rgb_frames(before, tracker.state.frame_index - len(before)))
        clock = timing(timeline)
        t = clock.now()
        compile_search_kernels(self.model)  # on a fresh install, on both cores; here, so that Ctrl-C stops it
        compiled = clock.lap("warmup", t)
        # Loaded while the first frames are read and measured. A daemon thread: a run that fails or
        # is interrupted meanwhile does not wait for it.
        threading.Thread(target=_load_kernels, args=(self.model, self.config.plan), name="kernels", daemon=True).start()
        det, frames = self.for_footage(iter(frames), tracker, workers=workers)  # the search is not running yet
        measured = clock.lap("footage", compiled)
        load_search_kernels(self.model, self.config.plan)  # waits for the thread
        clock.lap("warmup", measured)
        remeasure = self.config.auto_overlays or self.config.exposure is not None or self.estimates_horizon
        search = clock.timed("search", det.windows)

        def advance(frame, future, cut, det):
            t = clock.now()
            windows = future.result()
            t = clock.lap("search_wait", t)
            index = tracker.state.frame_index
            found = det.track_step(frame.shape, windows, tracker, frame, cut=cut)
            backfill = det._inside(tracker.backfill, det._overlays)
            clock.lap("track", t)
            return frame, index, found, backfill

        pending: deque = deque()
        shot_start = tracker.shot_start  # kept here: the tracker sees the cuts only when it reaches them
        ahead: deque = deque()  # frames read to measure a new shot, not yet searched
        # copies of the last frames, kept while the shot's horizon is to be measured again
        recent: deque = deque((np.array(f) for f in before) if tracker.state.horizon_retry is not None else (),
                              maxlen=HORIZON_FRAMES)
        with ThreadPoolExecutor(max_workers=max(1, workers), thread_name_prefix="search") as pool:
            try:
                while (frame := ahead.popleft() if ahead else next(frames, None)) is not None:
                    index = tracker.state.frame_index + len(pending)  # the frames advanced plus those still searched
                    cut = self.shot_cut(frame, tracker)  # checked now, so that a new shot is searched whole
                    retry = tracker.state.horizon_retry
                    if cut and remeasure:  # a new shot: its bars, overlays, light and horizon measured again
                        t = clock.now()
                        recent.clear()
                        ahead.extend(itertools.islice(frames, max(0, HORIZON_FRAMES - 1 - len(ahead))))
                        self._measure([frame, *itertools.islice(ahead, HORIZON_FRAMES - 1)], tracker.state, workers,
                                      new_shot=True, start=index)
                        det = self._for_state(tracker.state)
                        search = clock.timed("search", det.windows)
                        clock.lap("footage", t)
                    elif (retry is not None and index >= retry[1] and len(recent) == recent.maxlen
                          and self.config.car_horizon is not None):
                        # a shot whose horizon neither its lines nor its cars gave: its last frames, again
                        t = clock.now()
                        if self._measure_horizon(list(recent), tracker.state, workers, start=retry[0], end=index, keep_last=True):
                            det = self._for_state(tracker.state)
                            search = clock.timed("search", det.windows)
                        clock.lap("footage", t)
                    if tracker.state.horizon_retry is not None:
                        recent.append(np.array(frame))
                    else:
                        recent.clear()
                    if cut:
                        shot_start = index
                    around = None if cut else det._scheduled_around(tracker, index, shot_start)
                    args = (frame,) if around is None else (frame, around)  # windows(frame) as before when whole
                    pending.append((frame, pool.submit(search, *args), cut, det))
                    if len(pending) > workers:
                        yield advance(*pending.popleft())
                while pending:
                    yield advance(*pending.popleft())
            finally:
                for entry in pending:
                    entry[1].cancel()

    def track(self, frames: Iterable[np.ndarray], tracker: Tracker | None = None, *, workers: int = 2) -> Iterator[Detections]:
        """Detect and follow vehicles through a sequence of RGB ``uint8`` frames.

        Parameters
        ----------
        frames : iterable of ndarray
            Decoded frames in order, RGB ``uint8`` ``(H, W, 3)``; grey ``(H, W)`` or ``(H, W, 1)``,
            RGBA and ``uint16`` frames are converted (:func:`~vehicle_detection.io.images.as_rgb_uint8`),
            anything else is refused with an ``InputError`` (a ``ValueError``) naming the frame.
        tracker : Tracker, optional
            Pass the tracker of an earlier chunk to continue where it stopped (its frame
            counter continues too); a new one by default.
        workers : int
            Frames searched at once (threads).

        Yields
        ------
        Detections
            One per frame, in order: the frame's tracked vehicles (``frame`` is its index).
        """
        for _, found in self.track_frames(frames, tracker, workers=workers):
            yield found
