"""Hard-negative mining: the detector's own false alarms, cut out as new non-vehicle patches.

The classic recipe (Dalal and Triggs): run the search over footage, keep the hot windows that
are certainly not vehicles, add them to the negatives and retrain. A window is *certainly not a
vehicle* when

* the frame is labelled (or lies between labelled frames, at most ``max_gap`` frames from one;
  the car boxes are then interpolated linearly between the labelled frames before and after), and
  the window overlaps no car: IoU < ``max_iou`` with every car box, and less than
  ``max_car_cover`` of the window's own area inside any car box; and it lies mostly outside the
  ignore regions (less than ``max_ignore_overlap`` of its area inside any one ignore box, the
  rule the evaluation uses), since those hold oncoming and far vehicles;
* or, in footage without labels, it lies wholly inside a region the user names as one where no
  vehicle can be (``negative_regions``, e.g. the sky or the verge).

Frames of a labelled input that no label covers (beyond the first or last labelled frame, or
more than ``max_gap`` frames from any) are skipped. ``negative_regions`` given with labels
further restrict the windows to those regions.

Each window is cut out exactly as the classifier saw it
(:func:`~vehicle_detection.search.window_patches`). Near duplicates are dropped: a window whose
IoU with a window of the same scale already kept, in the same frame or in the
``dedupe_frames`` frames before, is at least ``dedupe_iou`` (windows are taken hardest first),
as are byte-identical patches.

:func:`write_negatives` writes the patches as PNGs into ``OUT/non-vehicles/NAME/``, laid out like
the training set, so that ``load_dataset(..., extra_negatives=[OUT])`` (``vehicle-detection train
--extra-negatives OUT``) adds them. A file is named ``<input>__f<frame>__s<scale>_<x1>_<y1>_<x2>_<y2>.png``;
the loader groups the patches of one input by blocks of frames, so a grouped split keeps
neighbouring frames on one side.

Mine only frames that are not scored later: negatives cut from a frame make that frame (and its
neighbours, which look alike) easy for the retrained model.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import os
import re
import shutil
import tempfile
from collections import deque
from collections.abc import Callable, Iterable, Iterator, Sequence
from contextlib import closing
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from PIL import Image

from ..detections import Detections
from ..deprecation import old_keywords
from ..detector import Detector
from ..errors import InputError, OutputError, output_exists
from ..geometry import box_area, box_intersection, box_iou, match_boxes, mirror_boxes, mirror_image
from ..io import PARTIAL_SUFFIX, refuse_inputs, umask
from ..io.images import list_images, read_image
from ..io.video import probe_video, read_frames
from ..metrics.detection import Annotations, FrameLabels, check_boxes_inside
from ..refine import crop_windows, jittered_windows, working_frame
from .data import MINED_NAME, Dataset

__all__ = [
    "labelled_frames",
    "vehicle_patches",
    "labelled_dataset",
    "MiningSource",
    "MiningOptions",
    "FrameRanges",
    "MinedNegatives",
    "labels_at",
    "negative_mask",
    "mine_negatives",
    "write_negatives",
    "MINED_NAME",
]

_SOURCE_NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*$")


@dataclass(frozen=True)
class MiningSource:
    """One input to mine: a video file or a folder of images, with its labels if any.

    Parameters
    ----------
    path : path-like
        Video file, or folder of images (frames are the images in sorted name order).
    labels : Annotations, optional
        Labels of this input (frame keys as in :func:`~vehicle_detection.metrics.detection.load_annotations`).
    """

    path: Path
    labels: Annotations | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "path", Path(self.path))
        if self.labels is not None and not isinstance(self.labels, Annotations):
            raise ValueError(f"labels must be Annotations; got {type(self.labels).__name__}")


@dataclass(frozen=True, eq=False)
class MinedNegatives:
    """Mined patches and where each came from.

    Attributes
    ----------
    patches : ndarray of uint8, shape (n, 64, 64, 3)
        RGB patches as the classifier saw them.
    windows : Detections
        Each patch's window in its frame (``frame``, SVM margin as ``score``,
        ``data["scale_index"]``).
    inputs : ndarray of str, shape (n,)
        The input (file or folder name without extension) of each patch.
    stats : dict
        Counts per input: ``frames`` searched, ``hot`` windows, ``far`` from every vehicle,
        ``duplicates`` dropped, ``kept``; and ``skipped_frames`` without usable labels.
    """

    patches: np.ndarray
    windows: Detections
    inputs: np.ndarray
    stats: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.patches)

    def file_names(self) -> list[str]:
        """The PNG file name of each patch (see the module docstring)."""
        out = []
        for name, f, k, box in zip(self.inputs, self.windows.frame, self.windows.data["scale_index"], self.windows.xyxy):
            out.append(f"{name}__f{int(f):06d}__s{int(k)}_{'_'.join(str(int(v)) for v in box)}.png")
        return out


# --- which windows are negatives ------------------------------------------------------------------


def _pair_cars(a: FrameLabels, b: FrameLabels) -> tuple[np.ndarray, np.ndarray]:
    """Which car of frame ``a`` is which car of ``b``: by track id where both have ids, else by IoU."""
    if a.ids is not None and b.ids is not None:
        common = [i for i in a.ids.tolist() if i in set(b.ids.tolist())]
        ia = np.array([a.ids.tolist().index(i) for i in common], dtype=np.intp)
        ib = np.array([b.ids.tolist().index(i) for i in common], dtype=np.intp)
        return ia, ib
    if not len(a.cars) or not len(b.cars):
        return np.zeros(0, np.intp), np.zeros(0, np.intp)
    return match_boxes(box_iou(a.cars, b.cars), 0.1)


def labels_at(annotations: Annotations, frame: int, *, max_gap: int = 10) -> FrameLabels | None:
    """The labels of one frame: its own, or interpolated between labelled frames; None if unknown.

    A labelled frame gives its labels. A frame between two labelled frames, at most ``max_gap``
    frames from one of them, gets the car boxes interpolated linearly between the nearest labelled
    frames before and after (cars paired by track id, else by IoU; a car without a partner keeps
    its box from the side that has it), and the ignore boxes of both. Any other frame (before
    the first labelled frame, after the last, or farther than ``max_gap`` from any) gives None.
    """
    frames = annotations.frames
    if frame in frames:
        return frames[frame]
    keys = np.fromiter(frames, dtype=np.int64)
    pos = int(np.searchsorted(keys, frame))
    if pos == 0 or pos == len(keys):
        return None
    f0, f1 = int(keys[pos - 1]), int(keys[pos])
    if min(frame - f0, f1 - frame) > max_gap:
        return None
    a, b = frames[f0], frames[f1]
    t = (frame - f0) / (f1 - f0)
    ia, ib = _pair_cars(a, b)
    cars = [np.rint((1 - t) * a.cars[ia] + t * b.cars[ib]).astype(np.int64).reshape(-1, 4)]
    cars.append(a.cars[np.setdiff1d(np.arange(len(a.cars)), ia)])
    cars.append(b.cars[np.setdiff1d(np.arange(len(b.cars)), ib)])
    ignore = np.concatenate([a.ignore, b.ignore]).reshape(-1, 4)
    return FrameLabels(cars=np.concatenate(cars).reshape(-1, 4), ignore=ignore)


def _fraction_inside(boxes: np.ndarray, regions: np.ndarray) -> np.ndarray:
    """``(n, m)``: the fraction of each box's area inside each region."""
    if not len(boxes) or not len(regions):
        return np.zeros((len(boxes), len(regions)))
    boxes = boxes.astype(np.float64)
    area = box_area(boxes)[:, None]
    inter = box_intersection(boxes, regions.astype(np.float64))
    return np.divide(inter, area, out=np.zeros_like(inter), where=area > 0)


def negative_mask(
    boxes: np.ndarray,
    labels: FrameLabels | None = None,
    regions: np.ndarray | None = None,
    *,
    max_iou: float = 0.1,
    max_car_cover: float = 0.1,
    max_ignore_overlap: float = 0.5,
) -> np.ndarray:
    """Which windows are certainly not vehicles (see the module docstring).

    Parameters
    ----------
    boxes : ndarray, shape (n, 4)
        Windows ``[x1, y1, x2, y2]``.
    labels : FrameLabels, optional
        The frame's cars and ignore regions.
    regions : ndarray, shape (m, 4), optional
        Places no vehicle can be; a window must lie wholly inside one of them.
    max_iou, max_car_cover, max_ignore_overlap : float
        A window is far from the cars if its IoU with every car is below ``max_iou`` and less
        than ``max_car_cover`` of its area is inside any car; it is outside the ignore regions if
        less than ``max_ignore_overlap`` of its area is inside any one of them.

    Returns
    -------
    ndarray of bool, shape (n,)

    Raises
    ------
    ValueError
        If neither labels nor regions are given: with neither, no window is known to be free of
        vehicles.
    """
    boxes = np.asarray(boxes, dtype=np.int64).reshape(-1, 4)
    if labels is None and regions is None:
        raise ValueError("negative_mask needs labels or negative regions: without either, no window is known to be free of vehicles")
    keep = np.ones(len(boxes), bool)
    if labels is not None and len(boxes):
        if len(labels.cars):
            keep &= (box_iou(boxes, labels.cars) < max_iou).all(axis=1)
            keep &= (_fraction_inside(boxes, labels.cars) < max_car_cover).all(axis=1)
        if len(labels.ignore):
            keep &= (_fraction_inside(boxes, labels.ignore) < max_ignore_overlap).all(axis=1)
    if regions is not None and len(boxes):
        regions = np.asarray(regions, dtype=np.int64).reshape(-1, 4)
        keep &= (_fraction_inside(boxes, regions) >= 1.0).any(axis=1) if len(regions) else False
    return keep


# --- mining ---------------------------------------------------------------------------------------


def _frames_of(path: Path, labels: Annotations | None = None) -> Iterator[tuple[int, Callable[[], np.ndarray]]]:
    """``(index, load)`` per frame of a video or image folder; ``load()`` gives the RGB frame.

    With ``labels``, they must fit the input: no labelled frame beyond its last frame (checked
    up front for a folder, at the end for a video), and no labelled box beyond the frame (checked
    up front for a video, as each labelled image is loaded for a folder).
    """
    if path.is_dir():
        files = list_images(path)
        for i, lab in (labels.frames.items() if labels is not None else ()):
            if i >= len(files):
                raise InputError(f"{labels.path}: labels image {i}, but {path} has only {len(files)} images")
            if lab.file is not None and files[i].name != lab.file:
                raise InputError(f"{labels.path}: frame {i} is labelled as {lab.file}, but image {i} of {path} is {files[i].name}")

        def load(i: int, f: Path) -> np.ndarray:
            image = read_image(f)
            if labels is not None:
                check_boxes_inside(labels, image.shape[1], image.shape[0], [i], f)
            return image

        for i, f in enumerate(files):
            yield i, (lambda i=i, f=f: load(i, f))
        return
    if not path.exists():
        raise InputError(f"{path}: no such video or folder")
    if labels is not None:
        info = probe_video(path)
        check_boxes_inside(labels, info.width, info.height, source=path)
    n = 0
    with closing(read_frames(path)) as frames:
        for i, frame in enumerate(frames):
            n = i + 1
            yield i, (lambda frame=frame: frame)
    beyond = [i for i in (labels.frames if labels is not None else ()) if i >= n]
    if beyond:
        raise InputError(
            f"{labels.path}: labels frame(s) {', '.join(map(str, beyond))}, but {path} has only {n} decoded frames; wrong video or labels?"
        )


def labelled_frames(annotations: Annotations, source: str | os.PathLike | None = None, *,
                    flip: bool = False) -> Iterator[tuple[int, np.ndarray, FrameLabels]]:
    """``(index, frame, labels)`` of every labelled frame of an annotation file's video or folder.

    ``source`` replaces the video or folder the file names. ``flip``: each frame flipped left to
    right, and its labels with it (frames of left-hand traffic, learned as right-hand traffic:
    :attr:`~vehicle_detection.config.DetectorConfig.traffic`). Raises :class:`InputError` if the
    labels do not fit it (see :func:`_frames_of`).
    """
    source = annotations.source if source is None else Path(source)
    if source is None:
        raise InputError(f"{annotations.path}: the labels name no video")
    last = max(annotations.frames, default=-1)
    for index, load in _frames_of(source, annotations):
        if index in annotations.frames:
            frame, labels = load(), annotations.frames[index]
            if flip:
                width = frame.shape[1]
                frame = mirror_image(frame)
                labels = dataclasses.replace(labels, cars=mirror_boxes(labels.cars, width), ignore=mirror_boxes(labels.ignore, width))
            yield index, frame, labels
        if index >= last:
            return


def vehicle_patches(
    frame: np.ndarray, cars: np.ndarray, rng: np.random.Generator, *, per_car: int = 4, side: int = 64,
    reference_height: int = 720, widen: tuple[float, float] = (1.0, 1.2), shift: float = 0.05,
) -> np.ndarray:
    """Square patches of labelled vehicles, framed as the training set frames them.

    Each patch is centred on its vehicle (moved by up to ``shift`` of its side), as wide as the
    vehicle's larger dimension times a factor drawn from ``widen``, cut from the frame resized
    to ``reference_height`` rows (as the search sees it) and resized to ``side`` pixels.

    Returns
    -------
    ndarray of uint8, shape (len(cars) * per_car, side, side, 3)
    """
    work, f = working_frame(frame, reference_height)
    cars = np.asarray(cars, np.float64).reshape(-1, 4) * f
    if not len(cars):
        return np.zeros((0, side, side, 3), np.uint8)
    wins = np.concatenate([jittered_windows(c, rng, per_car, size_range=widen, shift=shift) for c in cars])
    return crop_windows(work, wins, side)


def labelled_dataset(annotations: Sequence[Annotations], *, per_car: int = 12, block: int = 30, random_state: int = 0,
                     flip: bool = False) -> Dataset:
    """Vehicle patches (:func:`vehicle_patches`) of every car of labelled frames, as training data.

    Each annotation file is a source ``vehicles/labelled_<input>``; its patches are grouped by
    blocks of ``block`` frames, so a grouped split keeps neighbouring frames on one side.
    ``flip``: the frames flipped left to right (:func:`labelled_frames`), for frames of left-hand
    traffic.
    """
    rng = np.random.default_rng(random_state)
    for ann in annotations:
        if ann.source is None:
            raise InputError(f"{ann.path}: the labels name no video or image folder (key 'video')")
        if not ann.n_cars:
            raise InputError(f"{ann.path}: no labelled cars; the labels add vehicles (and the box refinement) from the cars of labelled frames")
    parts = []
    for ann in annotations:
        name = _input_name(ann.source)
        for index, frame, labels in labelled_frames(ann, flip=flip):
            patches = vehicle_patches(frame, labels.cars, rng, per_car=per_car)
            names = [f"vehicles/labelled_{name}/{name}__f{index}__{k}.png" for k in range(len(patches))]
            parts.append((patches, names, f"{name}/{index // block}"))
    return Dataset.from_patches(parts, label=1)


def _input_name(path: Path) -> str:
    path = Path(os.path.abspath(path))
    name = path.stem if path.is_file() else path.name
    return re.sub(r"[^A-Za-z0-9._-]+", "_", name).strip("._") or "input"


class FrameRanges:
    """Inclusive ranges of frame indexes, ``((first, last), ...)``: ``index in ranges`` is
    answered without listing the frames (``--frames 0-50000000`` on a short video costs nothing)."""

    def __init__(self, ranges):
        self.ranges = tuple((int(a), int(b)) for a, b in ranges)

    def __contains__(self, index) -> bool:
        return any(a <= index <= b for a, b in self.ranges)

    def __iter__(self):
        for a, b in self.ranges:
            yield from range(a, b + 1)

    def __repr__(self) -> str:
        return f"FrameRanges({self.ranges})"


@dataclass(frozen=True)
class MiningOptions:
    """Which frames are searched, which hot windows are taken as negatives, and which are dropped as
    near duplicates.

    Parameters
    ----------
    every : int
        Search every ``every``-th frame (frame index divisible by it).
    frames : iterable of int, optional
        Only these frame indexes (of every input); all by default. Leave out frames you score.
        Stored as a frozenset.
    threshold : float, optional
        SVM margin above which a window is taken; the detector's own (its plan's threshold, the
        windows it calls hot) by default. A lower one also takes the windows inside the margin
        (``-1``: every negative that the SVM's hinge loss still counts).
    negative_regions : array_like, shape (m, 4), optional
        ``[x1, y1, x2, y2]`` places where no vehicle can be; see :func:`negative_mask`.
    max_gap : int
        Frames of a labelled input farther than this from a labelled frame are skipped.
    max_iou, max_car_cover, max_ignore_overlap : float
        See :func:`negative_mask`.
    dedupe_iou : float
        A window with at least this IoU with a kept window of the same scale, in its frame or the
        ``dedupe_frames`` frames before, is dropped (1.0 or more keeps every window).
    dedupe_frames : int
    """

    every: int = 1
    frames: Iterable[int] | None = None
    threshold: float | None = None
    negative_regions: np.ndarray | None = field(default=None, compare=False)
    max_gap: int = 10
    max_iou: float = 0.1
    max_car_cover: float = 0.1
    max_ignore_overlap: float = 0.5
    dedupe_iou: float = 0.5
    dedupe_frames: int = 5

    def __post_init__(self) -> None:
        every = self.every
        if isinstance(every, bool) or not isinstance(every, (int, np.integer)) or every < 1:
            raise ValueError(f"every must be a whole number >= 1; got {every!r}")
        if self.max_gap < 0 or self.dedupe_frames < 0:
            raise ValueError("max_gap and dedupe_frames must be >= 0")
        if self.frames is not None and not isinstance(self.frames, FrameRanges):
            object.__setattr__(self, "frames", frozenset(int(f) for f in self.frames))
        if self.negative_regions is not None:
            regions = np.asarray(self.negative_regions, dtype=np.int64).reshape(-1, 4)
            regions.setflags(write=False)
            object.__setattr__(self, "negative_regions", regions)

    def searches(self, index: int) -> bool:
        """Whether frame ``index`` is searched."""
        return not index % self.every and (self.frames is None or index in self.frames)


def _legacy(kwargs: dict) -> dict:
    """The earlier keywords (``every``, ``frames``, ``dedupe_iou``, ...) as a :class:`MiningOptions`."""
    fields = {k: kwargs.pop(k) for k in list(kwargs) if k in MiningOptions.__dataclass_fields__}
    kwargs["options"] = dataclasses.replace(kwargs.get("options") or MiningOptions(), **fields)
    return kwargs


@old_keywords(tuple(MiningOptions.__dataclass_fields__), _legacy)
def mine_negatives(
    sources: Sequence[MiningSource],
    detector: Detector | None = None,
    options: MiningOptions | None = None,
    *,
    progress: Callable[[str, int], None] | None = None,
) -> MinedNegatives:
    """Cut the hot windows that are certainly not vehicles out of videos or image folders.

    Parameters
    ----------
    sources : sequence of MiningSource
        Inputs, each with its labels or none. An input without labels needs
        ``options.negative_regions``.
    detector : Detector, optional
        Supplies the hot windows (:meth:`~vehicle_detection.detector.Detector.windows`, all
        scales, margin above its plan's threshold); the embedded model's by default.
    options : MiningOptions, optional
        Frames, threshold, regions, distances to the cars, near duplicates.
    progress : callable, optional
        Called as ``progress(input_name, frame_index)`` after each searched frame.

    Returns
    -------
    MinedNegatives

    Notes
    -----
    The earlier keywords (``every=``, ``frames=``, ``dedupe_iou=``, ...: the fields of
    :class:`MiningOptions`) still work, with a :class:`DeprecationWarning`.
    """
    options = options or MiningOptions()
    detector = Detector() if detector is None else detector
    names = [_input_name(s.path) for s in sources]
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise InputError(f"two inputs share the name {dupes[0]!r}; mine them in separate runs (or rename one)")
    for s in sources:
        if s.labels is None and options.negative_regions is None:
            raise InputError(f"{s.path}: no labels for this input; give its annotation file or --negative-region")
    if options.threshold is not None:
        plan = dataclasses.replace(detector.config.plan, threshold=float(options.threshold))
        detector = Detector(detector.model, detector.config.replace(plan=plan))
    found: list[tuple[str, Detections, np.ndarray]] = []  # (input, kept windows, their patches) per frame
    seen: set[str] = set()  # digests of the patches kept, over every input
    stats = {name: _mine(source, name, detector, options, seen, found, progress) for source, name in zip(sources, names)}
    side = detector.model.config.window
    return MinedNegatives(
        patches=np.concatenate([c for _, _, c in found]) if found else np.zeros((0, side, side, 3), np.uint8),
        windows=Detections.concatenate([w for _, w, _ in found]) if found
        else Detections(np.zeros((0, 4), np.int64), data={"scale_index": np.zeros(0, np.int64)}),
        inputs=np.array([name for name, w, _ in found for _ in range(len(w))], dtype=str),
        stats=stats,
    )


def _mine(source: MiningSource, name: str, detector: Detector, options: MiningOptions, seen: set, found: list,
          progress) -> dict[str, int]:
    """Mine one input into ``found``; its counts."""
    st = {"frames": 0, "skipped_frames": 0, "hot": 0, "far": 0, "duplicates": 0, "kept": 0}
    recent: deque = deque()  # (frame, boxes (k, 4), scale_index (k,)) of kept windows
    for index, load in _frames_of(source.path, source.labels):
        if not options.searches(index):
            continue
        labels = None
        if source.labels is not None:
            labels = labels_at(source.labels, index, max_gap=options.max_gap)
            if labels is None:
                st["skipped_frames"] += 1
                continue
        frame = load()
        wins = detector.windows(frame)
        st["frames"] += 1
        st["hot"] += len(wins)
        wins = wins[negative_mask(wins.xyxy, labels, options.negative_regions, max_iou=options.max_iou,
                                  max_car_cover=options.max_car_cover, max_ignore_overlap=options.max_ignore_overlap)]
        st["far"] += len(wins)
        wins = wins[np.argsort(-wins.score, kind="stable")]  # hardest first
        while recent and recent[0][0] < index - options.dedupe_frames:
            recent.popleft()
        crops = detector.patches(frame, wins)
        keep = _new_windows(wins, crops, recent, seen, options.dedupe_iou)
        st["duplicates"] += int(len(wins) - keep.sum())
        st["kept"] += int(keep.sum())
        kept = wins[keep].replace(frame=index)
        recent.append((index, kept.xyxy, kept.data["scale_index"]))
        found.append((name, kept, crops[keep]))
        if progress is not None:
            progress(name, index)
    return st


def _new_windows(wins: Detections, crops: np.ndarray, recent: deque, seen: set, dedupe_iou: float) -> np.ndarray:
    """Which windows (hardest first) are neither near a kept window of their scale nor a patch kept before."""
    keep = np.zeros(len(wins), bool)
    kept_boxes = [(b, k) for _, bs, ks in recent for b, k in zip(bs, ks)]
    for j in range(len(wins)):
        box, k = wins.xyxy[j], int(wins.data["scale_index"][j])
        same = [b for b, kk in kept_boxes if kk == k]
        if same and box_iou(box[None], np.array(same)).max() >= dedupe_iou:
            continue
        digest = hashlib.sha1(crops[j].tobytes()).hexdigest()
        if digest in seen:
            continue
        seen.add(digest)
        keep[j] = True
        kept_boxes.append((box, k))
    return keep


# --- writing --------------------------------------------------------------------------------------


def _remove_empty(folders) -> None:
    """Remove the folders a failed write made, innermost first, where they are still empty."""
    for folder in folders:
        with contextlib.suppress(OSError):
            folder.rmdir()


def write_negatives(
    mined: MinedNegatives,
    out_dir: str | os.PathLike,
    name: str = "HardNegatives",
    *,
    overwrite: bool = False,
    inputs: Iterable[str | os.PathLike] = (),
) -> Path:
    """Write mined patches as PNGs into ``out_dir/non-vehicles/name/``, atomically.

    The folder is written under a hidden ``.name.XXXX.partial`` name beside its destination and
    renamed once complete, so an interrupted run leaves no folder that looks finished.

    Parameters
    ----------
    mined : MinedNegatives
    out_dir : path-like
        Root laid out like the training data (``non-vehicles/<name>/``).
    name : str
        The source folder (letters, digits, ``.``, ``_``, ``-``).
    overwrite : bool
        Replace an existing ``non-vehicles/<name>/`` folder (its old files are removed).
    inputs : iterable of path-like
        Files and folders the run read; the output may not be, contain or lie inside one.

    Returns
    -------
    Path
        The written folder.

    Raises
    ------
    OutputError
        If the folder exists and ``overwrite`` is false, or it cannot be written.
    """
    if not _SOURCE_NAME.fullmatch(name):
        raise OutputError(f"{name!r}: the folder name must be letters, digits, '.', '_' or '-' (no path)")
    dest = Path(out_dir) / "non-vehicles" / name
    refuse_inputs(dest, inputs)
    if dest.exists() and not dest.is_dir():
        raise OutputError(f"{dest}: exists and is not a folder")
    if dest.exists() and not overwrite:
        raise output_exists(dest)
    made = [p for p in (dest.parent, *dest.parent.parents) if not p.exists()]  # the folders made here, innermost first
    try:
        dest.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{name}.", suffix=PARTIAL_SUFFIX, dir=dest.parent))
    except OSError as exc:
        _remove_empty(made)
        raise OutputError(f"{dest}: cannot write output here: {exc.strerror or exc}") from exc
    old = None
    try:
        try:
            for fname, patch in zip(mined.file_names(), mined.patches):
                Image.fromarray(patch).save(tmp / fname, format="PNG")
            os.chmod(tmp, 0o777 & ~umask())
        except OSError as exc:  # a full disk, a quota, a read-only file system
            raise OutputError(f"{dest}: cannot write output: {exc.strerror or exc}") from None
        if dest.exists():
            if not overwrite:
                raise OutputError(f"{dest}: output appeared while writing; pass --overwrite to replace it")
            old = Path(tempfile.mkdtemp(prefix=f".{name}.old.", suffix=PARTIAL_SUFFIX, dir=dest.parent))
            os.replace(dest, old / name)
        os.replace(tmp, dest)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        if old is not None and (old / name).exists() and not dest.exists():
            os.replace(old / name, dest)  # put the old folder back
        _remove_empty(made)
        raise
    finally:
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    return dest
