"""Many inputs at once: local processes (``jobs``) or a dask.distributed cluster.

:func:`detect_many` is what ``vehicle-detection detect INPUT...`` runs when given several inputs
or any of the batch options (``--out-dir``, ``--jobs``, ``--skip-existing``, ``--no-video``,
``--start``/``--end``/``--frames``, ``--format``, ``--table``, ``--scheduler``).

* Each input is processed as ``detect INPUT`` would (same outputs, same default names, in
  ``out_dir`` when given), its outputs committed together (:func:`~vehicle_detection._files.output_batch`).
* A failing input is reported (:class:`InputResult` with ``error``) and does not stop the others.
* ``jobs=N`` runs N worker processes and splits the machine's cores between them: numba threads
  (``NUMBA_NUM_THREADS`` / ``numba.set_num_threads``), the detector's search threads and the
  codec threads (PyAV) are set to ``max(1, cores // N)`` in each.
* With a dask ``client`` (or ``scheduler`` address), one task per input runs on the cluster; with
  ``chunk_frames`` and no video, a long video is split into chunks of that many frames, processed
  in order, each continuing the previous chunk's tracker state, and joined with the tracker's
  back-fill exactly as a local run (:func:`track_chunk`, :func:`join_chunks`).

This module imports nothing heavy at import time, so that a worker process can set its thread
counts before numba is loaded.
"""

from __future__ import annotations

import glob
import os
import sys
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from ..errors import InputError, OutputError, UsageError, VehicleDetectionError

__all__ = ["InputResult", "detect_many", "expand_inputs", "track_chunk", "join_chunks", "detect_chunked", "FORMATS"]

VIDEO_EXTENSIONS = (".mp4", ".mov", ".avi", ".mkv", ".m4v", ".webm", ".mpg", ".mpeg", ".wmv", ".flv", ".ts", ".m2ts", ".mts")
#: Table formats: file name suffix of each (``NAME`` + suffix, beside the annotated output).
FORMATS = {"csv": "_boxes.csv", "parquet": "_boxes.parquet", "mot": "_mot.txt", "coco": "_coco.json"}


@dataclass(frozen=True)
class InputResult:
    """What happened to one input of :func:`detect_many`.

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
    """

    path: Path
    outputs: tuple[Path, ...] = ()
    n_boxes: int | None = None
    error: str | None = None
    skipped: bool = False
    n_frames: int = 0
    seconds: float = 0.0
    exit_code: int = 0

    @property
    def ok(self) -> bool:
        return self.error is None


@dataclass
class _Task:
    """Everything a worker needs for one input (picklable)."""

    path: Path
    kind: str  # "video", "image" or "folder"
    out: Path | None  # annotated video / image / folder; None: no video
    tables: dict[str, Path]  # format -> path
    model: str | None = None
    horizon: float | str | None = None
    overwrite: bool = False
    preset: str = "ultrafast"
    crf: int = 23
    start: int = 0
    end: int | None = None
    threads: int | None = None
    progress: bool = False
    files: list[Path] = field(default_factory=list)  # images of a folder

    def outputs(self) -> list[Path]:
        outs = []
        if self.out is not None:
            outs += [self.out / f.name for f in self.files] if self.kind == "folder" else [self.out]
        return outs + list(self.tables.values())


# --- inputs and output names --------------------------------------------------------------------


def unknown_type(path: Path) -> str:
    """The one-line error for an input that is no image, video or folder."""
    from ..io.images import IMAGE_EXTENSIONS

    return (f"{path}: unknown file type {path.suffix!r}; expected an image ({', '.join(IMAGE_EXTENSIONS)}) "
            f"or a video ({', '.join(VIDEO_EXTENSIONS)})")


def input_kind(path: Path) -> str | None:
    """``"folder"``, ``"image"`` or ``"video"`` by what ``path`` is (a folder) or its suffix; None: neither."""
    from ..io.images import IMAGE_EXTENSIONS

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
    from ..io.images import IMAGE_EXTENSIONS

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
            for m in matches:
                mp = Path(m)
                kind = input_kind(mp)
                if kind is not None:
                    add(mp, kind)
            continue
        if not p.exists():
            add(p, None, f"{p}: no such file or folder")
            continue
        kind = input_kind(p)
        if kind == "folder":
            entries = sorted(e for e in p.iterdir() if e.is_file() and not e.name.startswith("."))
            videos = [e for e in entries if e.suffix.lower() in VIDEO_EXTENSIONS]
            images = [e for e in entries if e.suffix.lower() in IMAGE_EXTENSIONS]
            for v in videos:
                add(v, "video")
            if images or not videos:
                add(p, "folder", None if images else f"{p}: no videos or images in this folder")
        elif kind is None:
            add(p, None, unknown_type(p))
        else:
            add(p, kind)
    return out


def default_outputs(path: Path, kind: str, out_dir: Path | None = None, formats: Sequence[str] = ("csv",)):
    """``(annotated output, {format: table path})`` under the single-input default names.

    Beside the input, or in ``out_dir``: ``NAME_detected.mp4`` / ``NAME_detected.EXT`` /
    ``NAME_detected/`` and ``NAME_boxes.csv`` (``NAME_detected/boxes.csv`` for a folder of images,
    as ``detect FOLDER``), ``NAME_boxes.parquet``, ``NAME_mot.txt``, ``NAME_coco.json``.
    """
    if path.name in ("", ".", ".."):
        path = Path(os.path.abspath(path))
    base = path.parent if out_dir is None else Path(out_dir)
    stem = path.name if kind == "folder" else path.stem
    if kind == "video":
        out = base / f"{stem}_detected.mp4"
    elif kind == "image":
        out = base / f"{stem}_detected{path.suffix}"
    else:
        out = base / f"{stem}_detected"
    tables = {}
    for fmt in formats:
        if fmt == "csv" and kind == "folder":
            tables[fmt] = out / "boxes.csv"
        else:
            tables[fmt] = base / f"{stem}{FORMATS[fmt]}"
    return out, tables


# --- one input -------------------------------------------------------------------------------------

_DETECTORS: dict = {}
_THREADS: int | None = None


def _detector(model: str | None, horizon: float | str | None):
    key = (model, horizon)
    if key not in _DETECTORS:
        from ..detector import Detector

        _DETECTORS[key] = Detector.load(model or None, horizon=horizon)
    return _DETECTORS[key]


def _set_threads(n: int) -> None:
    """Threads of this process: numba's, the codec's (PyAV) and the search's (``_THREADS``)."""
    global _THREADS
    _THREADS = n
    if "numba" not in sys.modules:
        os.environ["NUMBA_NUM_THREADS"] = str(n)  # numba's thread pool size, read when it loads
    import numba

    numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
    from ..io import video

    video._DECODER_THREADS = video._ENCODER_THREADS = video._SCALER_THREADS = n


def _init_worker(threads: int) -> None:
    """Start of a worker process: threads, and Ctrl-C left to the parent between tasks."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent stops the workers (SIGTERM)
    _set_threads(threads)


def _complete(task: _Task) -> bool:
    return all(p.is_file() for p in task.outputs()) and bool(task.outputs())


def _run_task(task: _Task) -> InputResult:
    """Process one input in this process; errors become the result's ``error`` (interrupts propagate)."""
    from ..io._files import interrupt_on_signals

    t = time.perf_counter()
    try:
        with interrupt_on_signals():  # in a worker process: SIGTERM from the parent cleans up as Ctrl-C
            n_boxes, n_frames = _process(task)
    except VehicleDetectionError as exc:
        return InputResult(task.path, error=_message(task.path, exc), seconds=time.perf_counter() - t, exit_code=exc.exit_code)
    except (Exception, KeyboardInterrupt) as exc:  # noqa: B902  (an interrupted worker reports it)
        if isinstance(exc, KeyboardInterrupt) and _in_main_process():
            raise
        text = "interrupted" if isinstance(exc, KeyboardInterrupt) else f"internal error: {type(exc).__name__}: {_one_line(exc)}"
        code = 130 if isinstance(exc, KeyboardInterrupt) else 1
        return InputResult(task.path, error=f"{task.path}: {text}", seconds=time.perf_counter() - t, exit_code=code)
    return InputResult(task.path, tuple(task.outputs()), n_boxes, n_frames=n_frames, seconds=time.perf_counter() - t)


def _in_main_process() -> bool:
    import multiprocessing

    return multiprocessing.parent_process() is None


def _one_line(exc: BaseException) -> str:
    return " | ".join(part.strip() for part in str(exc).splitlines() if part.strip())


def _message(path: Path, exc: BaseException) -> str:
    text = _one_line(exc)
    return text if text.startswith(str(path)) else f"{path}: {text}"


def _check_outputs(task: _Task, inputs: list[Path]) -> None:
    from ..io._files import check_output_path
    from ..io.images import check_image_output

    if task.kind == "folder" and task.out is not None and task.out.exists() and not task.out.is_dir():
        raise OutputError(f"{task.out}: exists and is not a folder; the annotated images of a folder go into a folder")
    if task.kind == "image" and task.out is not None:
        check_image_output(task.out)
    for o in task.outputs():
        if task.kind == "folder" and task.out is not None and o.parent == task.out and o.suffix != ".csv":
            check_image_output(o)
        check_output_path(o, overwrite=task.overwrite, inputs=inputs)


def _process(task: _Task) -> tuple[int, int]:
    """Detect in one input and write its outputs together; ``(boxes, frames)``."""
    from ..io._files import output_batch
    from ..detections import Detections

    path = task.path
    if task.kind == "folder":
        from ..io.images import list_images

        task.files = list_images(path)[task.start : task.end]
    model_inputs = [Path(task.model)] if task.model else []
    inputs = [path, *task.files, *model_inputs]
    if "coco" in task.tables and task.kind == "video":
        raise InputError(f"{path}: COCO JSON is written for images and folders of images, not videos (use mot or csv)")
    _check_outputs(task, inputs)
    detector = _detector(task.model, task.horizon)
    workers = _THREADS or 2
    with output_batch():
        if task.kind == "video":
            from .video import process_video

            table = process_video(
                path, task.out, detector=detector, overwrite=task.overwrite, progress=task.progress, preset=task.preset,
                crf=task.crf, start=task.start, end=task.end, workers=workers,
            )
            from ..io.video import probe_video

            n_frames = _frames_done(probe_video(path).n_frames, task.start, task.end)
            _write_tables(task, table, inputs, names=None, sizes=None)
        else:
            from ..viz.drawing import draw_detections
            from ..io.images import read_image, write_image

            files = task.files if task.kind == "folder" else [path]
            found, sizes = [], []
            first = task.start if task.kind == "folder" else 0
            for i, f in enumerate(files, start=first):
                image = read_image(f)
                sizes.append(image.shape[:2])
                det = detector.detect_image(image).replace(frame=i)
                if task.out is not None:
                    o = task.out / f.name if task.kind == "folder" else task.out
                    write_image(o, draw_detections(image, det), overwrite=task.overwrite, inputs=inputs)
                found.append(det)
            table = Detections.concatenate(found) if found else Detections.empty()
            names = [f.name for f, det in zip(files, found) for _ in range(len(det))]
            _write_tables(task, table, inputs, names=(names, [f.name for f in files]), sizes=sizes, first=first)
            n_frames = len(files)
    return len(table), n_frames


def _frames_done(n: int | None, start: int, end: int | None) -> int:
    if n is None:
        return 0
    return max(0, min(n, end if end is not None else n) - start)


def _write_tables(task: _Task, table, inputs, *, names, sizes, first: int = 0) -> None:
    from ..io.tables import write_boxes_csv

    row_names = None if names is None or task.kind != "folder" else names[0]
    for fmt, dest in task.tables.items():
        if fmt == "csv":
            write_boxes_csv(dest, table, overwrite=task.overwrite, inputs=inputs, files=row_names)
        elif fmt == "mot":
            from ..io.formats import write_mot

            write_mot(dest, table, overwrite=task.overwrite, inputs=inputs)
        elif fmt == "parquet":
            from ..io.formats import write_parquet

            t = table if row_names is None else table.replace(data={"file": row_names})
            write_parquet(dest, [(task.path.name, t)], overwrite=task.overwrite, inputs=inputs)
        elif fmt == "coco":
            from ..io.formats import write_coco

            shifted = table.replace(frame=table.frame - first) if len(table) else table
            write_coco(dest, shifted, names[1], sizes, overwrite=task.overwrite, inputs=inputs)


# --- chunks of one video (tracker state across chunk borders) ------------------------------------


def track_chunk(path, start: int, end: int | None, state=None, *, detector=None, model=None, horizon=None, workers: int | None = None):
    """Search and track decoded frames ``start <= index < end`` of a video, continuing ``state``.

    Returns ``(steps, state)``: ``steps`` is one ``(index, found, backfill)`` triple per frame
    (decoded index, the tracker's output and its back-fill for earlier frames), ``state`` the
    :class:`~vehicle_detection.tracker.TrackerState` after the last frame, to pass to the next
    chunk. :func:`join_chunks` turns the steps of all chunks, in order, into the table that
    :func:`~vehicle_detection.pipeline.process_video` returns.
    """
    import itertools

    from ..tracker import Tracker, TrackerState
    from ..io.video import read_frames

    detector = detector or _detector(model, horizon)
    if state is None:
        state = TrackerState(frame_index=start)
    if state.frame_index != start:
        raise ValueError(f"the tracker state continues at frame {state.frame_index}, not at {start}; chunks must follow each other")
    tracker = Tracker(detector.config.tracker, state)
    frames = read_frames(path)
    try:
        # The first chunk estimates the camera's horizon; the state carries it to the others.
        steps = [
            (index, found, backfill)
            for _, index, found, backfill in detector._steps(itertools.islice(frames, start, end), tracker, workers or _THREADS or 2)
        ]
    finally:
        frames.close()
    return steps, tracker.state.copy()


def join_chunks(steps: Sequence, lag: int):
    """The per-frame ``(index, found, backfill)`` steps of a whole video (or range) -> one table.

    Exactly what :meth:`~vehicle_detection.detector.Detector.track_frames` reports: each frame's
    boxes, then the back-fill of the ``lag`` following frames that falls on it, sorted by track
    id (stable).
    """
    import numpy as np

    from ..detections import Detections

    out = []
    for j, (index, found, _) in enumerate(steps):
        parts = found
        for i in range(j + 1, min(j + lag, len(steps) - 1) + 1):
            fill = steps[i][2]
            if len(fill):
                extra = fill.at_frame(index)
                if len(extra):
                    parts = Detections.concatenate([parts, extra])
        out.append(parts[np.argsort(parts.track_id, kind="stable")])
    return Detections.concatenate(out) if out else Detections.empty(tracked=True)


def detect_chunked(path, chunk_frames: int, *, client=None, model=None, horizon=None, start: int = 0, end: int | None = None):
    """Boxes of a video processed in chunks of ``chunk_frames`` frames, in order (locally, or as a
    chain of dask tasks on ``client``); identical to :func:`~vehicle_detection.pipeline.process_video`."""
    from ..io.video import probe_video

    n = probe_video(path).n_frames
    stop = n if end is None else (min(end, n) if n is not None else end)
    if stop is None:
        raise InputError(f"{path}: the frame count is unknown; cannot split into chunks (give --end)")
    bounds = [(a, min(a + chunk_frames, stop)) for a in range(start, stop, chunk_frames)]
    lag = max(0, _detector(model, horizon).config.tracker.min_hits - 1)
    if client is None:
        steps, state = [], None
        for a, b in bounds:
            part, state = track_chunk(path, a, b, state, model=model, horizon=horizon)
            steps += part
        return join_chunks(steps, lag)
    futures, state = [], None
    for a, b in bounds:
        fut = client.submit(_chunk_task, str(path), a, b, state, model, horizon, pure=False)
        futures.append(fut)
        state = client.submit(_second, fut, pure=False)
    results = client.gather(futures)
    steps = [s for part, _ in results for s in part]
    return join_chunks(steps, lag)


def _chunk_task(path, a, b, state, model, horizon):
    return track_chunk(path, a, b, state, model=model, horizon=horizon)


def _second(pair):
    return pair[1]


def _run_chunked(task: _Task, client, chunk_frames: int) -> InputResult:
    """One video as chunks on the cluster; the tables are written here (the client)."""
    from ..io._files import output_batch

    t = time.perf_counter()
    try:
        model_inputs = [Path(task.model)] if task.model else []
        inputs = [task.path, *model_inputs]
        if "coco" in task.tables:
            raise InputError(f"{task.path}: COCO JSON is written for images and folders of images, not videos (use mot or csv)")
        _check_outputs(task, inputs)
        from ..io.video import probe_video

        info = probe_video(task.path)
        table = detect_chunked(task.path, chunk_frames, client=client, model=task.model, horizon=task.horizon, start=task.start, end=task.end)
        with output_batch():
            _write_tables(task, table, inputs, names=None, sizes=None)
    except VehicleDetectionError as exc:
        return InputResult(task.path, error=_message(task.path, exc), seconds=time.perf_counter() - t, exit_code=exc.exit_code)
    except Exception as exc:
        return InputResult(task.path, error=f"{task.path}: internal error: {type(exc).__name__}: {_one_line(exc)}", seconds=time.perf_counter() - t, exit_code=1)
    n_frames = _frames_done(info.n_frames, task.start, task.end)
    return InputResult(task.path, tuple(task.outputs()), len(table), n_frames=n_frames, seconds=time.perf_counter() - t)


# --- many inputs ------------------------------------------------------------------------------------


def _frame_range(frames) -> tuple[int, int | None]:
    if frames is None:
        return 0, None
    if isinstance(frames, range):
        if frames.step != 1:
            raise UsageError("frames: a range with step 1")
        return frames.start, frames.stop
    start, end = frames
    start = 0 if start is None else int(start)
    if start < 0 or (end is not None and int(end) < start):
        raise UsageError(f"frames: ({start}, {end}) is not a range of frame indexes (0 <= start <= end)")
    return start, None if end is None else int(end)


def detect_many(
    paths: Iterable[str | os.PathLike] | str | os.PathLike,
    out_dir: str | os.PathLike | None = None,
    jobs: int = 1,
    skip_existing: bool = False,
    video: bool = True,
    frames: tuple[int | None, int | None] | range | None = None,
    *,
    model: str | os.PathLike | None = None,
    horizon: float | str | None = None,
    overwrite: bool = False,
    formats: Sequence[str] = ("csv",),
    table: str | os.PathLike | None = None,
    client=None,
    scheduler: str | None = None,
    chunk_frames: int | None = None,
    preset: str = "ultrafast",
    crf: int = 23,
    progress: bool = False,
    on_result=None,
) -> list[InputResult]:
    """Detect vehicles in many videos, images and folders of images.

    Parameters
    ----------
    paths : path-like or iterable of them
        Files, glob patterns and folders (see :func:`expand_inputs`).
    out_dir : path-like, optional
        Write each input's outputs here under the default names (else beside each input).
    jobs : int
        Worker processes (the cores are shared between them; see the module notes).
    skip_existing : bool
        Skip an input whose outputs all exist (from an earlier run: outputs are committed
        together, so they are complete); nothing of it is rewritten.
    video : bool
        Write the annotated video / images; False writes the tables only (no encoding).
    frames : (start, end) or range, optional
        Only decoded frames ``start <= index < end`` (images of a folder: positions in sorted
        order); the tables keep the decoded indexes.
    model, horizon, overwrite, preset, crf
        As for ``vehicle-detection detect``.
    formats : sequence of str
        Tables to write per input: ``csv`` (default), ``parquet``, ``mot``, ``coco`` (images).
    table : path-like, optional
        Also one Parquet file (``.parquet``, needs ``pyarrow``) for all inputs, with a ``video``
        column (the input's file name), built from the per-input tables once all are done.
    client : dask.distributed.Client, optional
        Run one task per input on this cluster (``scheduler``: its address, to connect here).
    chunk_frames : int, optional
        On a cluster, without video: split each video into chunks of this many frames.
    on_result : callable, optional
        Called with each :class:`InputResult` as it finishes (the CLI prints them).

    Returns
    -------
    list of InputResult
        One per input, in input order.
    """
    if isinstance(paths, (str, os.PathLike)):
        paths = [paths]
    formats = list(dict.fromkeys(formats)) or ["csv"]
    for fmt in formats:
        if fmt not in FORMATS:
            raise UsageError(f"unknown table format {fmt!r}; choose from {', '.join(FORMATS)}")
    if jobs < 1:
        raise UsageError("jobs must be >= 1")
    if chunk_frames is not None and (chunk_frames < 1 or video):
        raise UsageError("chunk_frames (--chunk-frames) needs a number >= 1 and no video (--no-video): the encoder needs the whole video in one task")
    if table is not None and Path(table).suffix.lower() != ".parquet":
        raise UsageError(f"{table}: the table of all inputs is a Parquet file (.parquet)")
    start, end = _frame_range(frames)
    if model is not None and not Path(model).is_file():
        raise InputError(f"{model}: model file not found")
    items = expand_inputs(paths)
    results: dict[int, InputResult] = {}
    tasks: dict[int, _Task] = {}
    claimed: dict[Path, Path] = {}
    for k, (p, kind, problem) in enumerate(items):
        if problem is not None:
            results[k] = InputResult(p, error=problem, exit_code=3)
            continue
        out, tables = default_outputs(p, kind, None if out_dir is None else Path(out_dir), formats)
        task = _Task(
            p, kind, out if video else None, tables, model=None if model is None else str(model), horizon=horizon,
            overwrite=overwrite, preset=preset, crf=crf, start=start, end=end, progress=progress and jobs == 1 and client is None,
        )
        for o in [out, *tables.values()]:
            key = Path(os.path.abspath(o))
            if key in claimed:
                raise UsageError(f"{claimed[key]} and {p} would both write {o}; give them different names or out-dirs")
            claimed[key] = p
        tasks[k] = task
    report = on_result or (lambda r: None)
    for k in list(tasks):
        task = tasks[k]
        if skip_existing:
            if task.kind == "folder":
                from ..io.images import list_images

                try:
                    task.files = list_images(task.path)[start:end]
                except VehicleDetectionError:
                    task.files = []
            if _complete(task):
                results[k] = InputResult(task.path, tuple(task.outputs()), skipped=True)
                del tasks[k]
    for k in sorted(results):
        report(results[k])

    own_client = None
    if client is None and scheduler is not None:
        try:
            from dask.distributed import Client
        except ImportError:
            raise UsageError('--scheduler needs dask.distributed: pip install "vehicle-detection[distributed]"') from None
        client = own_client = Client(scheduler)
    try:
        if client is not None:
            _run_dask(tasks, client, chunk_frames, results, report)
        elif jobs == 1 or len(tasks) <= 1:
            if jobs > 1:
                _set_threads(max(1, (os.cpu_count() or 1)))
            for k, task in tasks.items():
                results[k] = _run_task(task)
                report(results[k])
        else:
            _run_pool(tasks, jobs, results, report)
    finally:
        if own_client is not None:
            own_client.close()
    ordered = [results[k] for k in range(len(items))]
    if table is not None:
        _write_combined(Path(table), ordered, overwrite=overwrite)
    return ordered


def _run_pool(tasks: dict[int, _Task], jobs: int, results: dict, report) -> None:
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    threads = max(1, (os.cpu_count() or 1) // jobs)
    for task in tasks.values():
        task.threads = threads
    ctx = multiprocessing.get_context("spawn")  # no fork of a process with threads (numba, PyAV)
    pool = ProcessPoolExecutor(max_workers=min(jobs, len(tasks)), mp_context=ctx, initializer=_init_worker, initargs=(threads,))
    try:
        futures = {pool.submit(_run_task, task): k for k, task in tasks.items()}
        pending = set(futures)
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for fut in done:
                k = futures[fut]
                try:
                    results[k] = fut.result()
                except Exception as exc:  # a worker died (killed, out of memory)
                    results[k] = InputResult(tasks[k].path, error=f"{tasks[k].path}: worker failed: {type(exc).__name__}: {_one_line(exc)}", exit_code=1)
                report(results[k])
    except BaseException:
        # Ctrl-C, SIGTERM: stop the workers the same way (each cleans up its partial outputs), then wait for them.
        # Repeated until every worker has exited: a worker may have taken the next queued input
        # after cleaning up the first (a second SIGTERM during a clean-up is ignored).
        procs = list(getattr(pool, "_processes", {}).values())
        for _ in range(600):
            alive = [p for p in procs if p.is_alive()]
            if not alive:
                break
            for proc in alive:
                proc.terminate()
            for proc in alive:
                proc.join(0.1)
        pool.shutdown(wait=True, cancel_futures=True)
        raise
    pool.shutdown(wait=True)


def _run_dask(tasks: dict[int, _Task], client, chunk_frames: int | None, results: dict, report) -> None:
    from dask.distributed import as_completed

    futures = {}
    for k, task in tasks.items():
        if chunk_frames is not None and task.kind == "video":
            results[k] = _run_chunked(task, client, chunk_frames)
            report(results[k])
        else:
            futures[client.submit(_run_task, task, pure=False)] = k
    for fut in as_completed(list(futures)):
        k = futures[fut]
        try:
            results[k] = fut.result()
        except Exception as exc:
            results[k] = InputResult(tasks[k].path, error=f"{tasks[k].path}: task failed: {type(exc).__name__}: {_one_line(exc)}", exit_code=1)
        report(results[k])


def _write_combined(dest: Path, results: list[InputResult], *, overwrite: bool) -> None:
    """One Parquet table of every input that has a table, read back from its own output."""
    from ..io.formats import write_parquet
    from ..io.tables import read_boxes_csv

    parts = []
    for r in results:
        if not r.ok:
            continue
        own = [o for o in r.outputs if o.suffix in (".csv", ".parquet")]
        if not own:
            continue
        src = own[0]
        if src.suffix == ".parquet":
            from ..io.formats import read_parquet

            parts += list(read_parquet(src).items())
        else:
            parts.append((r.path.name, read_boxes_csv(src)))
    write_parquet(dest, parts, overwrite=overwrite, inputs=[r.path for r in results])
