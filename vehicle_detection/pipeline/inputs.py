"""One input of any kind, with every option: what ``vehicle-detection detect`` does to each input.

An input is a video, an image, or a folder of images (:func:`input_kind`). :func:`run_input`
runs one with :class:`InputOptions` (frame range, road, tables, video or not, encoding) and
writes its outputs (:class:`Outputs`: the annotated video, image or folder, the tables, and
optionally the HTML report and the camera file of a road plane estimated from the footage), all
committed together: a run that fails or is stopped part-way leaves no new file and every
earlier output as it was. The command line runs one input with it, and :func:`detect_many`
(:mod:`vehicle_detection.pipeline.batch`) runs each input of a batch with it, so every option
works the same in both.
"""

from __future__ import annotations

import glob
import os
import time
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path

from ..io import plural
from ..detections import Detections
from ..detector import Detector
from ..errors import InputError, OutputError, UsageError, require
from ..footage.horizon import TOLERANCE
from ..io import FORMATS, Encoding, check_outputs, output_batch, write_tables
from ..io.images import IMAGE_EXTENSIONS, check_image_output, list_images, read_image, write_image
from ..io.video import check_video_output, probe_video
from ..road.autocamera import RoadEstimate, save_estimate
from ..road.survey import Road
from ..tracker import Tracker, TrackerState
from ..viz.drawing import draw_detections
from ..viz.report import RunSummary, summarize, write_html_report
from .video import frame_range, run_video

__all__ = [
    "VIDEO_EXTENSIONS",
    "CAMERA_SUFFIX",
    "InputOptions",
    "Outputs",
    "InputResult",
    "input_kind",
    "unknown_type",
    "expand_inputs",
    "default_outputs",
    "check_input_outputs",
    "run_input",
]

VIDEO_EXTENSIONS = (".mp4", ".mov", ".avi", ".mkv", ".m4v", ".webm", ".mpg", ".mpeg", ".wmv", ".flv", ".ts", ".m2ts", ".mts")
#: The suffix of the default name of the camera file of a road plane estimated from the footage (``NAME_camera.json``).
CAMERA_SUFFIX = "_camera.json"
#: What each table format is called in messages.
_TABLE_NAMES = {"csv": "boxes CSV", "lanes": "lanes CSV"}


@dataclass(frozen=True)
class InputOptions:
    """How each input is processed, and what is written for it.

    Parameters
    ----------
    frames : range or (int, int), optional
        Only decoded frames ``start <= index < end`` (images of a folder: positions in sorted
        order); the tables keep the decoded indexes. Stored as ``(start, end)``.
    road : Road, optional
        Undistortion, distances and lanes (:class:`~vehicle_detection.road.survey.Road`).
    video : bool
        Write the annotated video / image / images; False writes the tables only.
    formats : sequence of str
        Tables by default name: keys of :data:`~vehicle_detection.io.formats.FORMATS` (``csv``,
        ``parquet``, ``mot``, ``coco`` for images, ``lanes``, which finds lanes).
    encoding : Encoding
        x264 preset and quality of annotated videos.
    overwrite : bool
        Replace existing outputs (never an input).
    progress : bool
        A progress bar for videos (on a terminal).
    inputs : tuple of Path
        Other files the run reads (a model file, a camera file): no output may be one of them.
    image_horizon : bool
        Images (``--horizon auto``): move the search bands to the horizon estimated from each
        image's own road lines, else from the cars found in it
        (:meth:`~vehicle_detection.detector.Detector.image_horizon`), when the detector estimates
        horizons; an image that gives none is searched where the plan says, and a note says so. False: images are searched where the plan says
        (a video's horizon is estimated from its first frames in any case).
    report : bool
        Also write the run's HTML report (:func:`~vehicle_detection.viz.report.write_html_report`),
        ``NAME_report.html`` beside the tables; needs matplotlib (the ``report`` extra).

    With ``road.lanes`` and no road plane (no camera file with a bird's-eye transform), each input
    gets the plane estimated from its own frames (:meth:`Road.for_footage`), or runs without
    lanes when they show no lane lines.
    """

    frames: tuple[int, int | None] | range | None = None
    road: Road = field(default_factory=Road)
    video: bool = True
    formats: tuple[str, ...] = ("csv",)
    encoding: Encoding = field(default_factory=Encoding)
    overwrite: bool = False
    progress: bool = False
    inputs: tuple[Path, ...] = ()
    image_horizon: bool = False
    report: bool = False

    def __post_init__(self) -> None:
        formats = tuple(dict.fromkeys(self.formats)) or ("csv",)
        for fmt in formats:
            if fmt not in FORMATS:
                raise UsageError(f"unknown table format {fmt!r}; choose from {', '.join(FORMATS)}")
        object.__setattr__(self, "formats", formats)
        object.__setattr__(self, "frames", frame_range(self.frames))
        object.__setattr__(self, "inputs", tuple(Path(p) for p in self.inputs))
        if "lanes" in formats and not self.road.lanes:
            object.__setattr__(self, "road", replace(self.road, lanes=True))  # the lanes table finds lanes


@dataclass(frozen=True)
class Outputs:
    """Where one input's outputs go.

    Attributes
    ----------
    annotated : Path or None
        The annotated video, image, or folder of images; None: none is written.
    tables : mapping of str to Path
        Format -> file.
    report : Path or None
        The HTML report; None: none is written.
    camera : Path or None
        The camera file of the road plane estimated from the footage (``detect --save-camera``);
        None: none is written (nor when nothing is estimated).
    """

    annotated: Path | None
    tables: Mapping[str, Path]
    report: Path | None = None
    camera: Path | None = None

    def files(self, kind: str, images: Sequence[Path] = ()) -> list[Path]:
        """Every file written for an input of ``kind`` (for a folder, one annotated image per
        file of ``images``), the annotated ones first, then the tables, the report and the camera file."""
        if self.annotated is None:
            drawn = []
        elif kind == "folder":
            drawn = [self.annotated / f.name for f in images]
        else:
            drawn = [self.annotated]
        return [*drawn, *self.tables.values(), *(p for p in (self.report, self.camera) if p is not None)]


@dataclass(frozen=True)
class InputResult:
    """What happened to one input.

    Attributes
    ----------
    path : Path
        The input (a video, an image, or a folder of images).
    outputs : tuple of Path
        Its outputs (written, or found complete when ``skipped``).
    n_boxes : int or None
        Boxes found (None when skipped or failed).
    error : str or None
        One-line message when the input failed, else None.
    skipped : bool
        Its outputs were all there already (``skip_existing``); nothing was rewritten.
    n_frames : int
        Frames (or images) processed.
    seconds : float
        Wall time of the input.
    exit_code : int
        The CLI exit code of its error (0 when it succeeded).
    notes : tuple of str
        What else the run found out, one line each: the road plane estimated from the footage
        (or why there is none), the footage's black bars and overlays and its horizon (videos),
        each image's count (folders of images).
    image : tuple or None
        An image input: ``(size, boxes)``, its ``(H, W)`` as searched and its boxes, for the one
        COCO dataset of a batch's images (:func:`~vehicle_detection.pipeline.batch.detect_many`);
        None for videos and folders.
    summary : RunSummary or None
        Frames, vehicles, boxes, speed and outputs (:func:`~vehicle_detection.viz.report.summarize`):
        ``summary.line()`` is what ``detect`` prints. None when skipped or failed.
    estimate : RoadEstimate or None
        The road plane estimated from the footage, or why there is none (lanes without a road
        plane); None when nothing was estimated.
    cli_error : str or None
        ``error`` in the command line's words (its flags, ``--overwrite``, where ``error`` says
        ``overwrite=True``), when they differ; :attr:`cli_message` is the one to print.
    """

    path: Path
    outputs: tuple[Path, ...] = ()
    n_boxes: int | None = None
    error: str | None = None
    skipped: bool = False
    n_frames: int = 0
    seconds: float = 0.0
    exit_code: int = 0
    notes: tuple[str, ...] = ()
    image: tuple | None = None
    summary: RunSummary | None = None
    estimate: RoadEstimate | None = None
    cli_error: str | None = None

    @property
    def ok(self) -> bool:
        return self.error is None

    @property
    def cli_message(self) -> str | None:
        """The error as the command line says it (None when the input did not fail)."""
        return self.cli_error if self.cli_error is not None else self.error


# --- inputs and output names --------------------------------------------------------------------


def unknown_type(path: Path) -> str:
    """The one-line error for an input that is no image, video or folder."""
    return (f"{path}: unknown file type {path.suffix!r}; expected an image ({', '.join(IMAGE_EXTENSIONS)}) "
            f"or a video ({', '.join(VIDEO_EXTENSIONS)})")


def input_kind(path: Path) -> str | None:
    """``"folder"``, ``"image"`` or ``"video"`` by what ``path`` is (a folder) or its suffix; None: neither."""
    if path.is_dir():
        return "folder"
    suffix = path.suffix.lower()
    if suffix in IMAGE_EXTENSIONS:
        return "image"
    if suffix in VIDEO_EXTENSIONS:
        return "video"
    return None


def expand_inputs(specs: Iterable[str | os.PathLike]) -> list[tuple[Path, str | None, str | None]]:
    """Files, globs and folders -> ``(path, kind, problem)`` in order, duplicates dropped.

    A folder holding videos gives each video (sorted by name); a folder holding images is one
    image-folder input (as ``detect FOLDER``); a folder with both gives both. ``problem`` is a
    one-line reason the input cannot be processed (missing, unknown type, empty folder), else None.
    """
    out: list[tuple[Path, str | None, str | None]] = []
    seen: set[Path] = set()

    def add(p: Path, kind: str | None, problem: str | None = None) -> None:
        key = Path(os.path.abspath(p))
        if key not in seen:
            seen.add(key)
            out.append((p, kind, problem))

    for spec in specs:
        text = os.fspath(spec)
        p = Path(text)
        if not p.exists() and glob.has_magic(text):
            matches = sorted(glob.glob(text))
            if not matches:
                add(p, None, f"{p}: no file matches this pattern")
            for m in map(Path, matches):
                if input_kind(m) is not None:
                    add(m, input_kind(m))
        elif not p.exists():
            add(p, None, f"{p}: no such file or folder")
        elif input_kind(p) == "folder":
            for item in _folder_inputs(p):
                add(*item)
        else:
            kind = input_kind(p)
            add(p, kind, unknown_type(p) if kind is None else None)
    return out


def _folder_inputs(folder: Path) -> list[tuple[Path, str, str | None]]:
    """A folder's videos (each an input), then the folder itself when it holds images (or nothing)."""
    entries = sorted(e for e in folder.iterdir() if e.is_file() and not e.name.startswith("."))
    videos = [(e, "video", None) for e in entries if e.suffix.lower() in VIDEO_EXTENSIONS]
    has_images = any(e.suffix.lower() in IMAGE_EXTENSIONS for e in entries)
    if has_images or not videos:
        videos.append((folder, "folder", None if has_images else f"{folder}: no videos or images in this folder"))
    return videos


def default_outputs(
    path: Path,
    kind: str,
    out_dir: Path | None = None,
    formats: Sequence[str] = ("csv",),
    *,
    video: bool = True,
    annotated: str | os.PathLike | None = None,
    report: bool = False,
    camera: bool = False,
) -> Outputs:
    """The outputs of one input under the default names, all in one folder.

    In ``out_dir``, else beside the input (the command line passes the current folder):
    ``NAME_detected.mp4`` / ``NAME_detected.EXT`` / ``NAME_detected/`` (None when not
    ``video``) and the tables ``NAME`` + the suffix of :data:`~vehicle_detection.io.formats.FORMATS`
    (``NAME_boxes.csv``, ...), except the boxes CSV of a folder of images,
    ``NAME_detected/boxes.csv`` (as ``detect FOLDER``); with ``report``, ``NAME_report.html``;
    with ``camera``, the camera file of the road plane estimated from the footage,
    ``NAME_camera.json``.

    ``annotated`` (``--out``) names the annotated output, and the run after it: the others go
    beside it (unless ``out_dir`` is given) and take its name, less a final ``_detected``
    (``X/clip.mp4`` and ``X/clip_detected.mp4`` both give ``X/clip_boxes.csv``), not the input's.

    Examples
    --------
    >>> out = default_outputs(Path("data/clip.mp4"), "video", Path("."), ("csv", "lanes"), report=True)
    >>> [str(p) for p in out.files("video")]
    ['clip_detected.mp4', 'clip_boxes.csv', 'clip_lanes.csv', 'clip_report.html']
    >>> [str(p) for p in default_outputs(Path("data/clip.mp4"), "video", annotated="X/run.mp4", camera=True).files("video")]
    ['X/run.mp4', 'X/run_boxes.csv', 'X/run_camera.json']
    """
    if path.name in ("", ".", ".."):
        path = Path(os.path.abspath(path))
    stem = path.name if kind == "folder" else path.stem
    if annotated is not None:
        annotated = Path(annotated)
        if annotated.name in ("", ".", ".."):
            annotated = Path(os.path.abspath(annotated))
        if out_dir is None:
            out_dir = annotated.parent
        named = annotated.name if kind == "folder" else annotated.stem
        stem = named.removesuffix("_detected") or named
    base = path.parent if out_dir is None else Path(out_dir)
    suffix = {"video": ".mp4", "image": path.suffix}.get(kind, "")
    out = base / f"{stem}_detected{suffix}" if annotated is None else annotated
    tables = {fmt: out / "boxes.csv" if (fmt == "csv" and kind == "folder") else base / f"{stem}{FORMATS[fmt]}" for fmt in formats}
    return Outputs(out if video else None, tables, base / f"{stem}_report.html" if report else None,
                   base / f"{stem}{CAMERA_SUFFIX}" if camera else None)


def check_input_outputs(kind: str, outputs: Outputs, images: Sequence[Path], *, overwrite: bool, inputs: Iterable[Path]) -> None:
    """Refuse the outputs of one input before any work (every kind, the command line's and a batch's).

    The annotated folder of a folder of images must be a folder; annotated images need a format
    Pillow can write; no output may be an input, an existing file (without ``overwrite``), or
    the same file as another output.

    Raises
    ------
    OutputError
        Naming the output and the problem.
    """
    out = outputs.annotated
    if out is not None:
        if kind == "folder" and out.exists() and not out.is_dir():
            raise OutputError(f"{out}: exists and is not a folder; the annotated images of a folder go into a folder")
        for fmt, table in outputs.tables.items():
            if kind != "folder" and Path(out).resolve() == Path(table).resolve():
                what = _TABLE_NAMES.get(fmt, f"{fmt} table")
                raise OutputError(f"{out}: the annotated output and the {what} cannot be the same file")
    if kind == "video" and out is not None:
        check_video_output(out)
    written = outputs.files(kind, images)
    drawn = 0 if out is None else len(images) if kind == "folder" else 1
    for o in written[:drawn] if kind != "video" else ():
        check_image_output(o)  # e.g. .webp without a WebP encoder
    check_outputs(written, overwrite=overwrite, inputs=inputs)


# --- one input -------------------------------------------------------------------------------------


def run_input(
    path: str | os.PathLike,
    options: InputOptions | None = None,
    *,
    detector: Detector | None = None,
    outputs: Outputs | None = None,
    out_dir: str | os.PathLike | None = None,
    threads: int | None = None,
) -> InputResult:
    """Detect vehicles in one video, image or folder of images, and write its outputs together.

    Parameters
    ----------
    path : path-like
        The input.
    options : InputOptions, optional
        Frames, road, tables, video or not, encoding, overwrite, progress, other inputs.
    detector : Detector, optional
        Defaults to ``Detector()`` (the embedded model).
    outputs : Outputs, optional
        Where the outputs go; default: :func:`default_outputs` (in ``out_dir`` when given).
    threads : int, optional
        The run's share of the cores (see :func:`~vehicle_detection.pipeline.video.process_video`).

    Returns
    -------
    InputResult
        The outputs written, the boxes and frames counted, and notes (one line each).

    Raises
    ------
    VehicleDetectionError
        An :class:`InputError` (missing or unreadable input, unknown type), an
        :class:`OutputError` (a refused output), ...; nothing is written then.
    """
    t = time.perf_counter()
    path, options, detector = Path(path), options or InputOptions(), detector or Detector()
    if not path.exists():
        raise InputError(f"{path}: no such file or folder")
    kind = input_kind(path)
    if kind is None:
        raise InputError(unknown_type(path))
    if outputs is None:
        outputs = default_outputs(path, kind, None if out_dir is None else Path(out_dir), options.formats, video=options.video,
                                  report=options.report)
    start, end = options.frames
    images = list_images(path)[start:end] if kind == "folder" else [path] if kind == "image" else []
    _check_range(path, kind, start, end, images)
    if "coco" in outputs.tables and kind == "video":
        raise InputError(f"{path}: COCO JSON is written for images and folders of images, not videos (use mot or csv)")
    read = [path, *images, *options.inputs]
    check_input_outputs(kind, outputs, images, overwrite=options.overwrite, inputs=read)
    if outputs.report is not None:
        require("matplotlib.figure", "report", "the HTML report")  # before any work
    road, estimate = options.road, None
    if road.estimates:  # lanes without a road plane: the plane from the footage, or no lanes
        road, estimate = road.for_footage(path if kind == "video" else _sample_images(path, images, road), start=start)
        # No plane: no lanes to find (the lanes table, if asked for, says "no lane" in every frame).
        formats = options.formats if road.lanes else tuple(f for f in options.formats if f != "lanes")
        options = replace(options, road=road, formats=formats)
    notes = [] if estimate is None else estimate.summary()
    # Lanes asked for, and no lane lines in the footage: the lanes table says "no lane" in every frame.
    unmeasured = estimate is not None and not estimate.ok and "lanes" in outputs.tables
    run_outputs = replace(outputs, tables={k: v for k, v in outputs.tables.items() if k != "lanes"}) if unmeasured else outputs
    first = start if kind != "image" else 0
    with output_batch():
        if kind == "video":
            table, n_frames, more, lane_rows, cuts = _run_video(path, options, detector, run_outputs, threads)
            image = None
        else:
            table, n_frames, more, lane_rows, image = _run_images(path, kind, images, options, detector, run_outputs, read)
            cuts = None
        notes += more
        if estimate is not None and not estimate.ok:
            lane_rows = [(i, None, None) for i in range(first, first + n_frames)]
        if unmeasured:
            write_tables({"lanes": outputs.tables["lanes"]}, table, name=path.name, lanes=lane_rows, overwrite=options.overwrite,
                         inputs=read)
        if outputs.report is not None:
            write_html_report(outputs.report, table, video=path if kind == "video" else None,
                              lanes=lane_rows if (road.lanes or estimate is not None) else None, n_frames=first + n_frames,
                              title=path.name, cuts=cuts, overwrite=options.overwrite)
        if outputs.camera is not None and estimate is not None and estimate.ok:
            save_estimate(outputs.camera, road.plane, estimate, options.road.camera, overwrite=options.overwrite, inputs=read)
        elif outputs.camera is not None:
            notes.append(f"{outputs.camera}: not written (no road plane estimated from the footage)")
            outputs = replace(outputs, camera=None)
    files = tuple(outputs.files(kind, images))
    seconds = time.perf_counter() - t
    summary = summarize(path, table, frames=n_frames, seconds=seconds, outputs=files, unit="frame" if kind == "video" else "image",
                        first=first)
    return InputResult(path, files, len(table), n_frames=n_frames, seconds=seconds, notes=tuple(notes), summary=summary,
                       estimate=estimate, image=image if kind == "image" else None)


def _sample_images(path: Path, images: Sequence[Path], road: Road, limit: int = 60) -> list:
    """Up to ``limit`` of ``images`` (spread evenly), read: what a road plane is estimated from.

    Raises
    ------
    InputError
        Naming the image that is not of the camera's size, or the folder whose images differ in size.
    """
    step = max(1, -(-len(images) // limit))
    frames = []
    for f in images[::step]:
        frame = read_image(f)
        road.check_frame(frame.shape[1], frame.shape[0], str(f))
        if frames and frame.shape != frames[0].shape:
            raise InputError(f"{path}: its images are not of one size ({f.name} is {frame.shape[1]}x{frame.shape[0]}, "
                             f"{images[0].name} {frames[0].shape[1]}x{frames[0].shape[0]}); the road plane is estimated "
                             "from images of one camera: give --camera, or run each size on its own")
        frames.append(frame)
    return frames


def _check_range(path: Path, kind: str, start: int, end: int | None, images: list[Path]) -> None:
    """Refuse a frame range that holds no frame of a video or folder (an empty table would look like no cars)."""
    if kind == "folder" and not images:
        n = len(list_images(path))
        raise InputError(f"{path}: the frame range {start} to {'the end' if end is None else end - 1} holds none of its {n} images")
    if kind == "video" and start > 0:
        n = probe_video(path).n_frames
        if n is not None and start >= n:
            raise InputError(f"{path}: the frame range starts at frame {start}, after the video's last frame ({n} frames)")


def _run_video(path: Path, options: InputOptions, detector: Detector, outputs: Outputs, threads: int | None):
    start, end = options.frames
    tracker = Tracker(detector.config.tracker, TrackerState(frame_index=start))
    table, lane_rows = run_video(
        path, outputs.annotated, detector=detector, frames=(start, end), road=options.road, encoding=options.encoding,
        tables=outputs.tables, overwrite=options.overwrite, progress=options.progress, tracker=tracker, threads=threads,
    )
    # the cuts the run made (none without a rule: the report then finds them in the video)
    cuts = tracker.state.cuts if detector.config.shot_cuts is not None else None
    return table, tracker.state.frame_index - start, _video_notes(tracker, detector), lane_rows, cuts


def _video_notes(tracker: Tracker, detector: Detector) -> list[str]:
    """What the run measured of the footage: its black bars and overlays, its horizon, its light, and its cuts between shots."""
    state = tracker.state
    notes = list(state.overlays.describe()) if state.overlays is not None else []
    if state.horizon is not None:
        cropped = state.overlays is not None and state.overlays.cropped
        source = "the cars found in the video" if state.horizon_source == "cars" else "the video's road lines"
        notes.append(f"horizon: {state.horizon:.3f} of the {'picture' if cropped else 'frame'} height, estimated from "
                     f"{source} (the plan's {detector.config.plan.reference_horizon:.3f}); search bands moved accordingly")
    if state.gain is not None and state.gain > 1.0:
        notes.append(f"dark picture: searched {state.gain:.1f} times as bright (the frames written are as they were)")
    if state.cuts:  # each shot is measured again: the lines above are the last shot's
        shown = ", ".join(map(str, state.cuts[:8])) + (", ..." if len(state.cuts) > 8 else "")
        notes = [f"last shot: {note}" for note in notes]
        notes.append(f"{plural(len(state.cuts), 'cut')} between shots ({'frame' if len(state.cuts) == 1 else 'frames'} {shown}): "
                     "tracks started afresh and the footage measured again there")
    return notes


def _run_images(path: Path, kind: str, images: list[Path], options: InputOptions, detector: Detector, outputs: Outputs,
                read: list[Path]):
    """Each image on its own (no tracking): undistorted, searched, measured, drawn; then the tables."""
    first = options.frames[0] if kind == "folder" else 0
    found, sizes, lanes, notes = [], [], [], []
    drawn = outputs.files(kind, images)[: len(images)] if outputs.annotated is not None else [None] * len(images)
    for i, (f, o) in enumerate(zip(images, drawn), start=first):
        survey = options.road.survey()  # each image on its own
        image = read_image(f)
        options.road.check(image.shape[1], image.shape[0], str(f))
        image = survey.undistort(image)
        sizes.append(image.shape[:2])
        searcher = detector
        if options.image_horizon and detector.estimates_horizon:
            searcher, note = _image_horizon(detector, image, f)
            notes.append(note)
        boxes = survey.measure(searcher.detect_image(image).replace(frame=i))
        lane = survey.find_lane(image)
        survey.record(i, lane)
        lanes += survey.lane_rows
        if o is not None:
            write_image(o, draw_detections(survey.draw(image, lane), boxes), overwrite=options.overwrite, inputs=read)
        found.append(boxes)
        if kind == "folder":
            notes.append(f"{f}: {plural(len(boxes), 'vehicle')}" + (f" -> {o}" if o is not None else ""))
    table = Detections.concatenate(found) if found else Detections.empty()
    if kind == "folder":
        table = table.replace(data={**table.data, "file": [f.name for f, boxes in zip(images, found) for _ in range(len(boxes))]})
    write_tables(outputs.tables, table, name=path.name, images=[(f.name, s) for f, s in zip(images, sizes)], first=first,
                 lanes=lanes, overwrite=options.overwrite, inputs=read)
    return table, len(images), notes, lanes, ((sizes[0], table) if len(images) == 1 else None)


def _image_horizon(detector: Detector, image, name: Path) -> tuple[Detector, str]:
    """The detector for one image at the horizon of its own road lines, and a note saying what was done."""
    reference = detector.config.plan.reference_horizon
    estimate, source = detector.image_horizon(image)
    if estimate is None:
        what = "road lines or cars" if detector.config.car_horizon is not None else "road lines"
        return detector, (f"{name}: horizon: no {what} to estimate it from in this image; searched where the plan "
                          f"says ({reference:.3f} of the height)")
    source = "the image's road lines" if source == "lines" else "the cars found in the image"
    if abs(estimate - reference) <= TOLERANCE:
        return detector, f"{name}: horizon: {estimate:.3f} of the height, estimated from {source} (the plan's {reference:.3f}: bands unchanged)"
    return detector.with_horizon(estimate), (f"{name}: horizon: {estimate:.3f} of the height, estimated from {source} (the plan's "
                                             f"{reference:.3f}); search bands moved accordingly")
