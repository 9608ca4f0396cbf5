"""Track vehicles over video frames: integrate detection heat, find hot blobs, follow them.

Per frame, :meth:`Tracker.update` takes the positive detection windows and their SVM margins and

1. builds the frame's heat map at ``cell``-pixel resolution (:func:`~.heatmap.add_heat`); each
   window adds ``1 + score_gain * max(score, 0)``, so a confident window counts more than a
   marginal one while every window counts at least 1;
2. integrates it, ``integrated = decay * integrated + current``, so evidence accumulates over
   the last few frames and a flicker of windows fades;
3. labels the blobs of integrated heat above ``threshold`` and boxes those of plausible size and
   shape (:func:`~.heatmap.blob_boxes`). A blob is a candidate only if it holds some heat of
   the *current* frame: integrated heat alone only echoes earlier frames, and counting the echo
   as a new sighting would let one burst of windows reach ``min_hits`` on its own afterglow;
4. associates candidates one to one with the live tracks by IoU (see :class:`Tracker`), smooths
   matched tracks' boxes, ages unmatched ones, retires stale ones and opens new tracks.

The whole state lives in a :class:`TrackerState`, so a video can be processed in chunks:
``Tracker(config, state=first.state)`` continues exactly where ``first`` stopped.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from .detections import Detections
from .geometry import box_iou, inset_boxes, match_boxes
from .heatmap import _blob_boxes, _check_aspect_range, _check_min_size, _core_boxes, _peaks, add_heat, label_heat, split_blobs, vote_boxes

if TYPE_CHECKING:
    from .footage.overlays import Overlays

__all__ = [
    "window_heat","TrackerConfig", "Track", "TrackerState", "Tracker"]


def _is_int(value: Any) -> bool:
    return isinstance(value, (int, np.integer)) and not isinstance(value, (bool, np.bool_))


def _is_real(value: Any) -> bool:
    return isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, (bool, np.bool_))


#: Fields added after model files were first saved; older files load with them off (0).
_ADDED_FIELDS = ("cluster_iou", "box_vote", "motion")


@dataclass(frozen=True)
class TrackerConfig:
    """Parameters of a :class:`Tracker`.

    Parameters
    ----------
    decay : float, default 0.6
        Weight of the previous integrated heat, in ``[0, 1)``:
        ``integrated = decay * integrated + current``. 0 uses the current frame only; 1 is
        refused (heat would never fade). A car covered by heat ``h`` every frame settles at
        ``h / (1 - decay)``.
    threshold : float, default 3.0
        Integrated heat a cell must exceed to belong to a blob, finite and >= 0.
    cell : int, default 8
        Heat-map cell side in frame pixels, >= 1.
    min_hits : int, default 3
        Frames a track must be matched (including the frame that opened it) before it is
        confirmed and reported, >= 1.
    max_misses : int, default 5
        Consecutive unmatched frames a track survives; it is retired on miss ``max_misses + 1``.
        >= 0.
    smoothing : float, default 0.5
        Weight of the new blob box in a matched track's box,
        ``box = (1 - smoothing) * predicted + smoothing * blob``, in ``(0, 1]`` (1: no
        smoothing).
    motion : float, default 0.0
        Gain of the tracks' constant-velocity motion model, in ``[0, 1]``: each track keeps a
        velocity (pixels a frame of each box edge), predicts its box one frame ahead
        (``predicted = box + velocity``) before it is matched, and corrects the velocity by
        ``motion`` times the blob's distance from the prediction. Together with ``smoothing``
        (the position gain) this is an alpha-beta filter, the steady state of a Kalman filter
        of constant velocity (as SORT tracks with). 0 turns it off: a track's box is a moving
        average of its blobs and lags behind a car that moves in the frame.
    match_iou : float, default 0.2
        Smallest IoU at which a blob can be matched to a track, in ``(0, 1]``.
    min_size : (float, float), default (32, 32)
        Smallest blob box ``(width, height)`` in frame pixels (see :func:`~.heatmap.blob_boxes`).
    aspect_range : (float, float), default (0.3, 4.0)
        Inclusive range of blob box ``width / height``.
    peak_fraction : float, default 0.3
        If positive, a blob's box is cut to its cells holding at least this fraction of the
        blob's peak integrated heat (see :func:`~.heatmap.heat_to_boxes`), in ``[0, 1)``.
    split_size : (float, float), default (64, 64)
        A blob with two or more cores (cells above ``peak_fraction`` of its peak) at least this
        large (width, height in frame pixels: the smallest search window) is split, one box per
        core: two cars side by side.
    score_gain : float, default 1.0
        Heat of a window is ``1 + score_gain * max(score, 0)``, finite and >= 0; 0 makes every
        window count 1 whatever its margin.
    cluster_iou : float, default 0.0
        If positive, a blob whose windows' boxes fall into several clusters (boxes overlapping
        at this IoU), one per vehicle, is split into them (:func:`~.heatmap.split_blobs`): cars
        side by side whose heat touches. For windows refined to their vehicles
        (:mod:`~vehicle_detection.refine`); 0 turns it off. In ``[0, 1]``.
    box_vote : float, default 0.0
        With ``cluster_iou``, each box moves this fraction of the way from its blob's extent to
        the weighted mean of its windows' boxes (:func:`~.heatmap.vote_boxes`), in ``[0, 1]``;
        0 keeps the blob boxes.
    window_inset : (float, float, float, float), default (-0.05, 0.05, -0.05, 0.15)
        A window adds its heat to its box inset by these fractions (left, top, right, bottom)
        of its width and height, each in ``(-0.5, 0.5)``: where the classifier puts the
        vehicle inside the windows it accepts. Square windows that take in a vehicle wider
        than tall reach above and below it, and heat over their whole height would make boxes
        too tall.

    Raises
    ------
    ValueError
        If a value is out of range or of the wrong type; the message names the field.
    """

    decay: float = 0.6
    threshold: float = 3.0
    cell: int = 8
    min_hits: int = 3
    max_misses: int = 5
    smoothing: float = 0.5
    motion: float = 0.0
    match_iou: float = 0.2
    min_size: tuple[float, float] = (32, 32)
    aspect_range: tuple[float, float] = (0.3, 4.0)
    score_gain: float = 1.0
    peak_fraction: float = 0.3
    split_size: tuple[float, float] = (64, 64)
    cluster_iou: float = 0.0
    box_vote: float = 0.0
    window_inset: tuple[float, float, float, float] = (-0.05, 0.05, -0.05, 0.15)

    def __post_init__(self) -> None:
        def real(name: str, ok, rule: str) -> None:
            value = getattr(self, name)
            if not _is_real(value) or not np.isfinite(value) or not ok(float(value)):
                raise ValueError(f"TrackerConfig.{name} must be {rule}; got {value!r}")
            object.__setattr__(self, name, float(value))

        def integer(name: str, low: int) -> None:
            value = getattr(self, name)
            if not _is_int(value) or value < low:
                raise ValueError(f"TrackerConfig.{name} must be an integer >= {low}; got {value!r}")
            object.__setattr__(self, name, int(value))

        real("decay", lambda v: 0.0 <= v < 1.0, "a number in [0, 1)")
        real("threshold", lambda v: v >= 0.0, "a finite number >= 0")
        real("smoothing", lambda v: 0.0 < v <= 1.0, "a number in (0, 1]")
        real("motion", lambda v: 0.0 <= v <= 1.0, "a number in [0, 1]")
        real("match_iou", lambda v: 0.0 < v <= 1.0, "a number in (0, 1]")
        real("score_gain", lambda v: v >= 0.0, "a finite number >= 0")
        real("peak_fraction", lambda v: 0.0 <= v < 1.0, "a number in [0, 1)")
        real("cluster_iou", lambda v: 0.0 <= v <= 1.0, "a number in [0, 1]")
        real("box_vote", lambda v: 0.0 <= v <= 1.0, "a number in [0, 1]")
        integer("cell", 1)
        integer("min_hits", 1)
        integer("max_misses", 0)
        try:
            object.__setattr__(self, "min_size", _check_min_size(self.min_size))
            object.__setattr__(self, "aspect_range", _check_aspect_range(self.aspect_range))
            object.__setattr__(self, "split_size", _check_min_size(self.split_size))
        except ValueError as exc:
            raise ValueError(f"TrackerConfig.{exc}") from None
        try:
            inset = tuple(float(v) for v in self.window_inset)
        except (TypeError, ValueError):
            inset = ()
        if len(inset) != 4 or not all(-0.5 < v < 0.5 for v in inset):
            raise ValueError(f"TrackerConfig.window_inset must be 4 numbers (left, top, right, bottom) in (-0.5, 0.5); got {self.window_inset!r}")
        object.__setattr__(self, "window_inset", inset)

    def to_dict(self) -> dict:
        """Plain JSON data (pairs as lists)."""
        return {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(self).items()}

    @classmethod
    def from_dict(cls, d: Any) -> TrackerConfig:
        """The inverse of :meth:`to_dict`; unknown or missing fields raise ``ValueError``, except
        ``cluster_iou``, ``box_vote`` and ``motion``, which settings saved before them lack (they
        load off)."""
        names = {f.name for f in dataclasses.fields(cls)}
        if isinstance(d, dict):
            d = {**{k: 0.0 for k in _ADDED_FIELDS}, **d}
        if not isinstance(d, dict) or set(d) != names:
            got = sorted(d) if isinstance(d, dict) else type(d).__name__
            raise ValueError(f"tracker settings must have exactly the fields {sorted(names)}; got {got}")
        return cls(**d)


def window_heat(scores, score_gain: float = 1.0) -> np.ndarray:
    """Heat a window adds: ``1 + score_gain * max(score, 0)`` (float64, one per window).

    Parameters
    ----------
    scores : array_like of float, shape (n,)
        Window margins above the search threshold.
    score_gain : float
        0 makes every window count 1.
    """
    return 1.0 + score_gain * np.maximum(np.asarray(scores, dtype=np.float64), 0.0)


@dataclass
class Track:
    """One followed vehicle.

    Attributes
    ----------
    track_id : int
        Unique within a tracker (until :meth:`Tracker.reset`), increasing in order of creation.
    box : ndarray of float64, shape (4,)
        Smoothed ``[x1, y1, x2, y2]`` in frame pixels (x2, y2 exclusive).
    velocity : ndarray of float64, shape (4,)
        Change of each box edge a frame (:attr:`TrackerConfig.motion`; zero without it).
    hits : int
        Frames in which a blob was matched to the track, including the one that opened it.
    misses : int
        Consecutive frames without a match, up to now (0 if matched in the last frame).
    age : int
        Frames since the track was opened, counting that frame (1 on its first frame).
    confirmed : bool
        ``hits`` has reached ``min_hits`` at some point; stays true until the track is retired.
    score : float
        Peak integrated heat of the blob last matched to the track.
    history : list of (int, ndarray)
        While unconfirmed: ``(frame_index, box)`` of each frame since the track opened.
    backfill : list of (int, ndarray)
        Set on the frame the track is confirmed (empty otherwise): its boxes on the earlier
        frames of its history, so an offline consumer that holds frames back
        ``min_hits - 1`` frames (:meth:`vehicle_detection.detector.Detector.track`) can report
        the vehicle from the frame it appeared, while no track is ever born from one frame.
    """

    track_id: int
    box: np.ndarray
    hits: int = 1
    misses: int = 0
    age: int = 1
    confirmed: bool = False
    score: float = 0.0
    history: list = field(default_factory=list)
    backfill: list = field(default_factory=list)
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(4))

    def int_box(self) -> np.ndarray:
        """The box rounded to whole pixels (halves up), ``int64`` shape (4,)."""
        return _int_boxes([self.box])[0]

    def copy(self) -> Track:
        """An independent copy (the box array is copied)."""
        return Track(
            track_id=self.track_id,
            box=np.array(self.box, dtype=np.float64, copy=True),
            hits=self.hits,
            misses=self.misses,
            age=self.age,
            confirmed=self.confirmed,
            score=self.score,
            history=[(i, b.copy()) for i, b in self.history],
            backfill=[(i, b.copy()) for i, b in self.backfill],
            velocity=np.array(self.velocity, dtype=np.float64, copy=True),
        )


@dataclass
class TrackerState:
    """Everything a :class:`Tracker` remembers between frames.

    Attributes
    ----------
    integrated : ndarray of float32, shape (H // cell, W // cell), or None
        Integrated heat; None before the first frame.
    tracks : list of Track
        Live tracks (confirmed or not), in increasing ``track_id``.
    next_id : int
        Id of the next track to open.
    frame_index : int
        Number of frames processed so far (the 0-based index of the next frame).
    frame_shape : (int, int) or None
        ``(H, W)`` of the frames seen; None before the first frame.
    horizon : float or None
        The camera horizon the detector estimated for these frames (None: none found, or not
        looked for yet); kept here so that a video processed in chunks is searched the same
        way in every chunk.
    horizon_searched : bool
        Whether the detector has looked for the horizon.
    horizon_source : str or None
        Where ``horizon`` was read: ``"lines"`` (the road's lines) or ``"cars"`` (the cars
        found at several candidate horizons); None with no ``horizon``.
    horizon_retry : (int, int) or None
        Where neither the lines nor the cars of a shot gave a horizon: the index of the shot's
        first frame, and of the frame before which its horizon is measured again (on the frames
        just before it); None otherwise.
    overlays : Overlays or None
        The black bars and static overlays the detector found in these frames
        (:class:`~vehicle_detection.footage.overlays.Overlays`; None: not looked for yet), kept for
        later chunks like ``horizon``. Immutable, so copies share it.
    overlays_searched : bool
        Whether the detector has looked for them.
    shot_thumbnail : ndarray of float32 or None
        The thumbnail of the last frame the detector checked for a cut between shots
        (:mod:`~vehicle_detection.footage.shots`), kept so that the first frame of a later chunk is
        checked against the last of the one before; None before the first frame.
    shot_changes : tuple of float
        The changes of the last frames checked (:func:`~vehicle_detection.footage.shots.next_shot`).
    cuts : tuple of int
        The frames at which the tracker started afresh (:meth:`Tracker.cut`), in order.
    shot_start : int or None
        The index of the current shot's first frame: the last cut, else the first frame
        tracked (a range of a video starts at its first frame); None before the first frame.
    gain : float or None
        What the detector multiplies these frames by for the search (dark footage,
        :mod:`~vehicle_detection.footage.exposure`; 1.0 for daylight); None: not measured yet.
    """

    integrated: np.ndarray | None = None
    tracks: list[Track] = field(default_factory=list)
    next_id: int = 0
    frame_index: int = 0
    frame_shape: tuple[int, int] | None = None
    horizon: float | None = None
    horizon_searched: bool = False
    horizon_source: str | None = None
    horizon_retry: tuple[int, int] | None = None
    overlays: Overlays | None = None
    overlays_searched: bool = False
    shot_thumbnail: np.ndarray | None = None
    shot_changes: tuple[float, ...] = ()
    cuts: tuple[int, ...] = ()
    shot_start: int | None = None
    gain: float | None = None

    def copy(self) -> TrackerState:
        """A deep copy: updating either afterwards leaves the other unchanged."""
        return TrackerState(
            integrated=None if self.integrated is None else self.integrated.copy(),
            tracks=[t.copy() for t in self.tracks],
            next_id=self.next_id,
            frame_index=self.frame_index,
            frame_shape=self.frame_shape,
            horizon=self.horizon,
            horizon_searched=self.horizon_searched,
            horizon_source=self.horizon_source,
            horizon_retry=self.horizon_retry,
            overlays=self.overlays,
            overlays_searched=self.overlays_searched,
            shot_thumbnail=None if self.shot_thumbnail is None else self.shot_thumbnail.copy(),
            shot_changes=tuple(self.shot_changes),
            cuts=tuple(self.cuts),
            shot_start=self.shot_start,
            gain=self.gain,
        )


def _check_state(state: TrackerState, config: TrackerConfig) -> TrackerState:
    if not _is_int(state.next_id) or not _is_int(state.frame_index) or state.next_id < 0 or state.frame_index < 0:
        raise ValueError("state.next_id and state.frame_index must be integers >= 0")
    if state.shot_start is not None and not (_is_int(state.shot_start) and 0 <= state.shot_start <= state.frame_index):
        raise ValueError("state.shot_start must be None or an integer from 0 to state.frame_index")
    if (state.integrated is None) != (state.frame_shape is None):
        raise ValueError("state.integrated and state.frame_shape must both be set or both be None")
    if state.frame_shape is not None:
        state.frame_shape = _frame_hw(state.frame_shape)
        h, w = state.frame_shape
        expected = (h // config.cell, w // config.cell)
        arr = state.integrated
        if not isinstance(arr, np.ndarray) or arr.shape != expected or arr.dtype != np.float32:
            raise ValueError(
                f"state.integrated must be float32 of shape {expected} for frames of {state.frame_shape} at "
                f"cell={config.cell}; got {getattr(arr, 'dtype', type(arr))} of shape {np.shape(arr)} "
                "(was the state made with another cell size?)"
            )
    ids = [t.track_id for t in state.tracks]
    if any(i >= state.next_id for i in ids) or len(set(ids)) != len(ids):
        raise ValueError("state.tracks must have distinct track ids below state.next_id")
    return state


def _predict(track: Track, frame_shape: tuple[int, int] | None) -> np.ndarray:
    """The track's box one frame ahead at its velocity, kept inside the frame. When that would
    leave no box (a car shrinking or leaving faster than the filter can follow), the track is
    stopped (its velocity set to zero) and its box is returned."""
    if not track.velocity.any():
        return track.box
    box = track.box + track.velocity
    if frame_shape is not None:
        h, w = frame_shape
        box = np.clip(box, 0.0, [w, h, w, h])
    if box[2] - box[0] < 1.0 or box[3] - box[1] < 1.0:
        track.velocity = np.zeros(4)
        return track.box
    return box


def _int_boxes(boxes: list) -> np.ndarray:
    """Whole-pixel boxes, halves rounded up (the tracker's float boxes as reported)."""
    return np.floor(np.asarray(boxes, dtype=np.float64).reshape(-1, 4) + 0.5).astype(np.int64)


def _frame_hw(frame_shape: Any) -> tuple[int, int]:
    try:
        dims = tuple(frame_shape)
    except TypeError:
        dims = ()
    if len(dims) not in (2, 3) or not all(_is_int(d) and d > 0 for d in dims):
        raise ValueError(f"frame_shape must be (H, W) or (H, W, C) of positive integers; got {frame_shape!r}")
    return int(dims[0]), int(dims[1])


class Tracker:
    """Turn per-frame detection windows into stable, identified vehicle boxes.

    Parameters
    ----------
    config : TrackerConfig, default TrackerConfig()
    state : TrackerState, optional
        Where to resume (e.g. ``other.state`` to continue another tracker's video). It is copied,
        so the two trackers never share data. Default: a fresh start.

    Raises
    ------
    ValueError
        If ``state`` is inconsistent or does not fit ``config`` (heat map of another cell size).

    Notes
    -----
    **Association.** Candidates and live tracks are matched one to one among the pairs with
    IoU >= ``match_iou``; the matching has the most pairs and, among those, the largest total
    IoU (:func:`scipy.optimize.linear_sum_assignment`), as in
    :func:`vehicle_detection.metrics.detection.match_frame`.

    **Life cycle.** Tracks are matched by their boxes predicted one frame ahead
    (:attr:`TrackerConfig.motion`; without it, their boxes). A matched track takes the blob's
    box into its moving average with the prediction, ``hits += 1``, ``misses = 0``, and is
    confirmed once ``hits >= min_hits``. An unmatched track coasts to its predicted box and
    ``misses += 1``; it is retired when ``misses > max_misses``. An unmatched candidate
    opens a new unconfirmed track (``hits = 1``) with the next id. Every live track's ``age``
    grows by one per frame.

    **Reported tracks.** :meth:`update` returns the confirmed live tracks: those matched this
    frame and those coasting for at most ``max_misses`` frames, so a car the
    detector loses for a few frames keeps its box and id. A one-frame false positive is never
    reported when ``min_hits >= 2``: its blob's later frames hold no current heat, so they are
    not candidates.
    """

    def __init__(self, config: TrackerConfig = TrackerConfig(), state: TrackerState | None = None) -> None:
        if not isinstance(config, TrackerConfig):
            raise ValueError(f"config must be a TrackerConfig; got {type(config).__name__}")
        if state is not None and not isinstance(state, TrackerState):
            raise ValueError(f"state must be a TrackerState or None; got {type(state).__name__}")
        self._config = config
        self._state = TrackerState() if state is None else _check_state(state.copy(), config)
        self._backfill = Detections.empty(tracked=True)

    @property
    def config(self) -> TrackerConfig:
        """The tracker's parameters."""
        return self._config

    @property
    def state(self) -> TrackerState:
        """The live state (not a copy): read it, snapshot it with ``.copy()``, or pass it to a new
        :class:`Tracker` (which copies it). Do not modify it."""
        return self._state

    def reset(self) -> None:
        """Forget everything, as if new: no heat, no tracks, ids restart at 0."""
        self._state = TrackerState()
        self._backfill = Detections.empty(tracked=True)

    @property
    def shot_start(self) -> int:
        """The index of the current shot's first frame (:attr:`TrackerState.shot_start`; before
        the first frame, the next frame's)."""
        st = self._state
        return st.frame_index if st.shot_start is None else st.shot_start

    @property
    def tracks(self) -> list[Track]:
        """Copies of the confirmed live tracks after the last update, in increasing ``track_id``."""
        return [t.copy() for t in self._state.tracks if t.confirmed]

    def cut(self) -> None:
        """The footage cut to another shot (:mod:`~vehicle_detection.footage.shots`): forget the heat
        and the live tracks, confirmed or not. Track ids go on from :attr:`TrackerState.next_id`,
        and the frame counter and the footage's measurements are kept; the next frame's index
        is added to :attr:`TrackerState.cuts`."""
        st = self._state
        st.cuts = (*st.cuts, st.frame_index)
        st.shot_start = st.frame_index
        if st.integrated is not None:
            st.integrated = np.zeros_like(st.integrated)
        st.tracks = []

    @property
    def backfill(self) -> Detections:
        """Boxes of tracks confirmed by the last update on the frames before it (see :class:`Track`).

        Their ``frame`` column says which earlier frame each box belongs to.
        """
        return self._backfill

    def update(
        self, detections: Detections, frame_shape: tuple[int, ...], measure: Callable[[np.ndarray], np.ndarray] | None = None
    ) -> Detections:
        """Process one frame's detections.

        Parameters
        ----------
        detections : Detections
            Positive detection windows of the frame in frame pixels (parts outside the frame are
            ignored), with their margins above the search threshold as ``score`` (finite); a
            window adds heat ``1 + score_gain * max(score, 0)``. ``Detections.empty()`` for a
            frame without detections.
        frame_shape : (H, W) or (H, W, C)
            Shape of the frame; the same for every call (``frame.shape`` will do).
        measure : callable, optional
            Maps the frame's blob boxes ``(n, 4)`` (whole pixels) to boxes measured better (e.g. from
            the frame's pixels, :meth:`~vehicle_detection.detector.Detector.fit_boxes`), before
            they are matched to the tracks and averaged into them; the tracker itself never
            reads pixels.

        Returns
        -------
        Detections
            The confirmed live tracks (matched this frame, or unmatched for at most
            ``max_misses`` frames) in increasing ``track_id``: whole-pixel boxes (halves
            rounded up), ``track_id``, the peak integrated heat of each track's last blob as
            ``score``, and this frame's index as ``frame``.

        Raises
        ------
        ValueError
            If ``detections`` is not a :class:`Detections`, or ``frame_shape`` is invalid or
            differs from that of earlier frames. The state is unchanged when this is raised.
        """
        if not isinstance(detections, Detections):
            raise ValueError(f"detections must be a Detections; got {type(detections).__name__}")
        st = self._state
        hw = _frame_hw(frame_shape)
        if st.frame_shape is not None and hw != st.frame_shape:
            raise ValueError(
                f"frame_shape {hw} differs from the earlier frames' {st.frame_shape}; "
                "use a new Tracker (or reset()) for another video"
            )
        integrated, cand, peaks = self._heat_stage(detections, hw)
        if measure is not None and len(cand):
            cand = np.asarray(measure(cand), np.float64).reshape(-1, 4)
        kept, next_id = self._associate(cand, peaks)

        index = st.frame_index
        if st.shot_start is None:
            st.shot_start = index
        st.integrated = integrated
        st.tracks = kept
        st.next_id = next_id
        st.frame_index += 1
        st.frame_shape = hw
        fill = [(i, b, t.track_id, t.score) for t in kept for i, b in t.backfill]
        self._backfill = Detections(
            _int_boxes([b for _, b, _, _ in fill]),
            score=[sc for *_, sc in fill],
            track_id=[tid for _, _, tid, _ in fill],
            frame=np.array([i for i, *_ in fill], np.int64),
        )
        confirmed = [t for t in kept if t.confirmed]
        return Detections(
            _int_boxes([t.box for t in confirmed]),
            score=[t.score for t in confirmed],
            track_id=np.array([t.track_id for t in confirmed], np.int64),
            frame=index,
        )

    def _heat_stage(self, detections: Detections, hw: tuple[int, int]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Steps 1-3: this frame's heat, integrated, and its candidate blobs ``(integrated, boxes, peaks)``."""
        cfg, st = self._config, self._state
        win = inset_boxes(detections.xyxy, cfg.window_inset)
        weights = window_heat(detections.score, cfg.score_gain)

        # 1-2. Heat of this frame, integrated.
        map_shape = (hw[0] // cfg.cell, hw[1] // cfg.cell)
        current = add_heat(np.zeros(map_shape, dtype=np.float32), win, weights, cell=cfg.cell)
        if st.integrated is None:
            integrated = current
        else:
            integrated = st.integrated * np.float32(cfg.decay)
            integrated += current

        # 3. Candidate blobs: hot enough, plausible, and seen in this frame.
        labels, n = label_heat(integrated, cfg.threshold)
        cand, blobs = _blob_boxes(labels, n, cfg.cell, cfg.min_size, cfg.aspect_range)
        if blobs:
            fresh = _peaks(current, labels, blobs) > 0
            cand = cand[fresh]
            blobs = [b for b, f in zip(blobs, fresh.tolist()) if f]
        peaks = _peaks(integrated, labels, blobs)
        if cfg.peak_fraction > 0 and blobs:
            cand, peaks, _ = _core_boxes(integrated, labels, blobs, cfg.cell, cfg.peak_fraction, cfg.split_size)
        if cfg.cluster_iou > 0 and len(cand):
            cand, peaks = split_blobs(cand, peaks, win, weights, iou=cfg.cluster_iou)
            cand = vote_boxes(cand, win, weights, iou=cfg.cluster_iou, fraction=cfg.box_vote)
        return integrated, cand, peaks

    def _associate(self, cand: np.ndarray, peaks: np.ndarray) -> tuple[list[Track], int]:
        """Step 4: association and track life cycle: candidates matched to the live tracks;
        ``(live tracks, next id)``."""
        cfg, st = self._config, self._state
        tracks = st.tracks
        matched_track = np.zeros(len(tracks), dtype=bool)
        matched_cand = np.zeros(len(cand), dtype=bool)
        # Each track's box one frame ahead (its box itself without a motion model).
        predicted = [_predict(t, st.frame_shape) for t in tracks]
        if tracks and len(cand):
            rows, cols = match_boxes(box_iou(np.stack(predicted), cand), cfg.match_iou)
            s = cfg.smoothing
            for r, c in zip(rows.tolist(), cols.tolist()):
                t = tracks[r]
                t.box = (1.0 - s) * predicted[r] + s * cand[c]
                if cfg.motion > 0:
                    t.velocity = t.velocity + cfg.motion * (cand[c] - predicted[r])
                t.hits += 1
                t.misses = 0
                t.score = float(peaks[c])
                t.backfill = []
                if not t.confirmed and t.hits >= cfg.min_hits:
                    t.confirmed = True
                    t.backfill = t.history
                    t.history = []
                elif not t.confirmed:
                    t.history.append((st.frame_index, t.box.copy()))
                matched_track[r] = True
                matched_cand[c] = True

        kept: list[Track] = []
        for t, matched, ahead in zip(tracks, matched_track.tolist(), predicted):
            t.age += 1
            if not matched:
                t.backfill = []
                t.misses += 1
                if t.misses > cfg.max_misses:
                    continue
                t.box = ahead  # coasting: where the motion model says (its box without one)
            kept.append(t)
        next_id = st.next_id
        for c in np.flatnonzero(~matched_cand).tolist():
            kept.append(
                Track(
                    track_id=next_id,
                    box=cand[c].astype(np.float64),
                    confirmed=cfg.min_hits <= 1,
                    score=float(peaks[c]),
                    history=[] if cfg.min_hits <= 1 else [(st.frame_index, cand[c].astype(np.float64))],
                )
            )
            next_id += 1
        return kept, next_id
