"""Many inputs at once: local processes (``jobs``) or a dask.distributed cluster.

:func:`detect_many` is what ``vehicle-detection detect INPUT...`` runs when given several inputs
(or globs, or a folder of videos), or any of the batch-only options (``--jobs``,
``--skip-existing``, ``--table``, ``--scheduler``, ``--chunk-frames``).

* Each input is processed by :func:`~vehicle_detection.pipeline.inputs.run_input`, as
  ``detect INPUT`` processes one (same options, same outputs, same default names, in
  ``out_dir`` when given), its outputs committed together.
* A failing input is reported (:class:`~vehicle_detection.pipeline.inputs.InputResult` with
  ``error``) and does not stop the others.
* ``jobs=N`` runs N worker processes and splits the machine's cores between them: numba threads
  (``NUMBA_NUM_THREADS`` / ``numba.set_num_threads``), the detector's search threads and the
  codec threads (PyAV) are ``max(1, cores // N)`` in each.
* With a dask ``client`` (or a scheduler's address), one task per input runs on the cluster;
  with ``chunk_frames`` and no video, a long video is split into chunks of that many frames,
  processed in order, each continuing the previous chunk's tracker state, and joined with the
  tracker's back-fill exactly as a local run (:func:`track_chunk`, :func:`join_chunks`).

A worker process sets its thread counts (:func:`~vehicle_detection.pipeline._threads.init_worker`,
from a module that imports nothing heavy) before numba is loaded in it.
"""

from __future__ import annotations

import contextlib
import glob
import itertools
import logging
import multiprocessing
import os
import re
import signal
import socket
import struct
import time
from collections.abc import Iterable, Sequence
from concurrent.futures import FIRST_COMPLETED, CancelledError, wait
from contextlib import contextmanager
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from ..deprecation import old_keywords
from ..detections import Detections
from ..detector import HORIZON_FRAMES, Detector
from ..errors import ClusterError, InputError, OutputError, UsageError, VehicleDetectionError, cli_message, one_line, require
from ..io import (
    PARTIAL_SUFFIX, check_output_path, check_outputs, interrupt_on_signals, output_batch, read_boxes_csv, read_parquet,
    write_coco, write_parquet, write_tables,
)
from ..io.images import list_images
from ..io.video import probe_video, read_frames
from ..tracker import Tracker, TrackerState
from ..viz.report import summarize
from ._threads import init_worker, set_numba_threads
from .inputs import InputOptions, InputResult, Outputs, check_input_outputs, default_outputs, expand_inputs, run_input
from .video import SEARCH_WORKERS

__all__ = ["detect_many", "track_chunk", "join_chunks", "detect_chunked", "connect", "SCHEDULER_TIMEOUT"]

#: Seconds to wait for a dask scheduler to answer, when connecting and when it stops answering.
SCHEDULER_TIMEOUT = 10.0


@dataclass(frozen=True)
class _Task:
    """Everything a worker needs for one input (picklable)."""

    path: Path
    kind: str  # "video", "image" or "folder"
    outputs: Outputs
    options: InputOptions
    detector: Detector
    threads: int | None = None
    shared: tuple[Path, ...] = ()  # outputs written with other inputs' (the images' COCO dataset)

    def images(self) -> list[Path]:
        """The images of a folder input (in the frame range), [] when they cannot be listed."""
        if self.kind != "folder":
            return [self.path] if self.kind == "image" else []
        start, end = self.options.frames
        try:
            return list_images(self.path)[start:end]
        except VehicleDetectionError:
            return []

    def complete(self) -> bool:
        """Whether every output is there already (outputs are committed together, so they are complete)."""
        files = [*self.outputs.files(self.kind, self.images()), *self.shared]
        return bool(files) and all(p.is_file() for p in files)


_DETECTORS: dict = {}


def _detector(model: str | os.PathLike | None, horizon: float | str | None) -> Detector:
    """The detector of a model file at a horizon, loaded once per process."""
    key = (None if model is None else str(model), horizon)
    if key not in _DETECTORS:
        _DETECTORS[key] = Detector.load(model, horizon=horizon)
    return _DETECTORS[key]


def _run_task(task: _Task) -> InputResult:
    """Process one input in this process; errors become the result's ``error`` (interrupts propagate)."""
    t = time.perf_counter()
    try:
        with interrupt_on_signals():  # in a worker process: SIGTERM from the parent cleans up as Ctrl-C
            r = run_input(task.path, task.options, detector=task.detector, outputs=task.outputs, threads=task.threads)
            return replace(r, outputs=(*r.outputs, *task.shared)) if task.shared else r
    except VehicleDetectionError as exc:
        return InputResult(task.path, error=_message(task.path, exc), seconds=time.perf_counter() - t, exit_code=exc.exit_code,
                           cli_error=_message(task.path, exc, cli=True))
    except (Exception, KeyboardInterrupt) as exc:  # noqa: B902  (an interrupted worker reports it)
        if isinstance(exc, KeyboardInterrupt) and multiprocessing.parent_process() is None:
            raise
        text = "interrupted" if isinstance(exc, KeyboardInterrupt) else f"internal error: {type(exc).__name__}: {one_line(exc)}"
        code = 130 if isinstance(exc, KeyboardInterrupt) else 1
        return InputResult(task.path, error=f"{task.path}: {text}", seconds=time.perf_counter() - t, exit_code=code)


def _message(path: Path, exc: BaseException, *, cli: bool = False) -> str:
    """The one-line error of an input, naming it; ``cli``: in the command line's words (:func:`cli_message`)."""
    text = cli_message(exc) if cli else one_line(exc)
    return text if text.startswith(str(path)) else f"{path}: {text}"


# --- chunks of one video (tracker state across chunk borders) ------------------------------------


def track_chunk(
    path: str | os.PathLike,
    start: int,
    end: int | None,
    state: TrackerState | None = None,
    *,
    detector: Detector | None = None,
    model: str | os.PathLike | None = None,
    horizon: float | str | None = None,
    workers: int | None = None,
):
    """Search and track decoded frames ``start <= index < end`` of a video, continuing ``state``.

    Returns ``(steps, state)``: ``steps`` is one ``(index, found, backfill)`` triple per frame
    (decoded index, the tracker's output and its back-fill for earlier frames), ``state`` the
    :class:`~vehicle_detection.tracker.TrackerState` after the last frame, to pass to the next
    chunk. :func:`join_chunks` turns the steps of all chunks, in order, into the table that
    :func:`~vehicle_detection.pipeline.video.process_video` returns. The detector is ``detector``, else the
    one of the model file ``model`` (the embedded model for None) at ``horizon``.
    """
    detector = detector or _detector(model, horizon)
    if state is None:
        state = TrackerState(frame_index=start)
    if state.frame_index != start:
        raise ValueError(f"the tracker state continues at frame {state.frame_index}, not at {start}; chunks must follow each other")
    tracker = Tracker(detector.config.tracker, state)
    frames = read_frames(path)
    try:
        # The first chunk estimates the camera's horizon; the state carries it to the others. A
        # shot still without one is measured again on its last frames, which may lie before start.
        first = max(0, start - HORIZON_FRAMES) if state.horizon_retry is not None else start
        decoded = itertools.islice(frames, first, end)
        before = list(itertools.islice(decoded, start - first))
        steps = [
            (index, found, backfill)
            for _, index, found, backfill in detector.steps(decoded, tracker, workers or SEARCH_WORKERS, before=before)
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


def detect_chunked(
    path: str | os.PathLike,
    chunk_frames: int,
    *,
    client=None,
    detector: Detector | None = None,
    model: str | os.PathLike | None = None,
    horizon: float | str | None = None,
    start: int = 0,
    end: int | None = None,
) -> Detections:
    """Boxes of a video processed in chunks of ``chunk_frames`` frames, in order (locally, or as a
    chain of dask tasks on ``client``); identical to :func:`~vehicle_detection.pipeline.video.process_video`.
    The detector is as for :func:`track_chunk`."""
    n = probe_video(path).n_frames
    stop = n if end is None else (min(end, n) if n is not None else end)
    if stop is None:
        raise InputError(f"{path}: the frame count is unknown; cannot split into chunks (give --end)")
    if start >= stop:
        raise InputError(f"{path}: the frame range starts at frame {start}, after the video's last frame ({n} frames)")
    bounds = [(a, min(a + chunk_frames, stop)) for a in range(start, stop, chunk_frames)]
    detector = detector or _detector(model, horizon)
    lag = max(0, detector.config.tracker.min_hits - 1)
    if client is None:
        steps, state = [], None
        for a, b in bounds:
            part, state = track_chunk(path, a, b, state, detector=detector)
            steps += part
        return join_chunks(steps, lag)
    futures, state = [], None
    for a, b in bounds:
        fut = client.submit(_chunk_task, str(path), a, b, state, detector, pure=False)
        futures.append(fut)
        state = client.submit(_second, fut, pure=False)
    results = client.gather(futures)
    steps = [s for part, _ in results for s in part]
    return join_chunks(steps, lag)


def _chunk_task(path, a, b, state, detector):
    return track_chunk(path, a, b, state, detector=detector)


def _second(pair):
    return pair[1]


def _run_chunked(task: _Task, client, chunk_frames: int) -> InputResult:
    """One video as chunks on the cluster; the tables are written here (the client)."""
    t = time.perf_counter()
    start, end = task.options.frames
    try:
        if "coco" in task.outputs.tables:
            raise InputError(f"{task.path}: COCO JSON is written for images and folders of images, not videos (use mot or csv)")
        if "lanes" in task.outputs.tables:
            raise UsageError(f"{task.path}: lanes are not found in chunks (no --chunk-frames with --lanes)")
        check = [task.path, *task.options.inputs]
        check_input_outputs(task.kind, task.outputs, [], overwrite=task.options.overwrite, inputs=check)
        table = detect_chunked(task.path, chunk_frames, client=client, detector=task.detector, start=start, end=end)
        with output_batch():
            write_tables(task.outputs.tables, table, name=task.path.name, overwrite=task.options.overwrite, inputs=check)
    except VehicleDetectionError as exc:
        return InputResult(task.path, error=_message(task.path, exc), seconds=time.perf_counter() - t, exit_code=exc.exit_code,
                           cli_error=_message(task.path, exc, cli=True))
    except Exception as exc:
        lost = _cluster_failure(exc, client)
        if isinstance(exc, CancelledError):
            raise lost from None  # the scheduler went away: the run stops
        if lost is not None:
            return InputResult(task.path, error=_message(task.path, lost), seconds=time.perf_counter() - t, exit_code=lost.exit_code)
        return InputResult(task.path, error=f"{task.path}: internal error: {type(exc).__name__}: {one_line(exc)}",
                           seconds=time.perf_counter() - t, exit_code=1)
    n_frames, seconds, files = _frames_in(task.path, start, end), time.perf_counter() - t, tuple(task.outputs.files(task.kind))
    summary = summarize(task.path, table, frames=n_frames, seconds=seconds, outputs=files, first=start)
    return InputResult(task.path, files, len(table), n_frames=n_frames, seconds=seconds, summary=summary)


def _frames_in(path: Path, start: int, end: int | None) -> int:
    n = probe_video(path).n_frames
    if n is None:
        return 0
    return max(0, min(n, end if end is not None else n) - start)


# --- many inputs ------------------------------------------------------------------------------------


def _legacy(kwargs: dict) -> dict:
    """The earlier keywords (``video``, ``frames``, ``model``, ``preset``, ...) as the new objects."""
    fields = {k: kwargs.pop(k) for k in ("video", "frames", "formats", "overwrite", "progress") if k in kwargs}
    encoding = {k: kwargs.pop(k) for k in ("preset", "crf") if k in kwargs}
    options = kwargs.get("options") or InputOptions()
    if encoding:
        fields["encoding"] = replace(options.encoding, **encoding)
    if fields:
        kwargs["options"] = replace(options, **fields)
    model, horizon = kwargs.pop("model", None), kwargs.pop("horizon", None)
    if model is not None and not Path(model).is_file():
        raise InputError(f"{model}: model file not found")
    if (model is not None or horizon is not None) and kwargs.get("detector") is None:
        kwargs["detector"] = Detector.load(model, horizon=horizon)
    if model is not None:
        options = kwargs.get("options") or InputOptions()
        kwargs["options"] = replace(options, inputs=(*options.inputs, Path(model)))
    if kwargs.get("scheduler") is not None:
        kwargs["client"] = kwargs.pop("scheduler")
    kwargs.pop("scheduler", None)
    return kwargs


@old_keywords(("video", "frames", "formats", "overwrite", "progress", "preset", "crf", "model", "horizon", "scheduler"), _legacy)
def detect_many(
    paths: Iterable[str | os.PathLike] | str | os.PathLike,
    out_dir: str | os.PathLike | None = None,
    options: InputOptions | None = None,
    *,
    detector: Detector | None = None,
    jobs: int = 1,
    skip_existing: bool = False,
    table: str | os.PathLike | None = None,
    client=None,
    chunk_frames: int | None = None,
    on_result=None,
    scheduler_timeout: float = SCHEDULER_TIMEOUT,
) -> list[InputResult]:
    """Detect vehicles in many videos, images and folders of images.

    Parameters
    ----------
    paths : path-like or iterable of them
        Files, glob patterns and folders (see :func:`~vehicle_detection.pipeline.inputs.expand_inputs`).
    out_dir : path-like, optional
        Write each input's outputs here under the default names (else beside each input).
    options : InputOptions, optional
        How each input is processed and what is written for it: frames, road (camera, lanes),
        video or tables only, table formats, encoding, overwrite, progress (one job only).
    detector : Detector, optional
        Defaults to ``Detector()`` (the embedded model); a detector of your own (its
        :class:`~vehicle_detection.config.DetectorConfig`) reaches every input and worker.
    jobs : int
        Worker processes (the cores are shared between them; see the module notes).
    skip_existing : bool
        Skip an input whose outputs all exist (from an earlier run: outputs are committed
        together, so they are complete); nothing of it is rewritten.
    table : path-like, optional
        Also one Parquet file (``.parquet``, needs ``pyarrow``) for all inputs, with a ``video``
        column (the input's file name), built from the per-input tables once all are done.
    client : dask.distributed.Client or str, optional
        Run one task per input on this cluster (a string: the scheduler's address, to connect).
    chunk_frames : int, optional
        On a cluster, without video: split each video into chunks of this many frames.
    on_result : callable, optional
        Called with each :class:`~vehicle_detection.pipeline.inputs.InputResult` as it finishes
        (the CLI prints them).
    scheduler_timeout : float
        With ``client`` an address: seconds to wait for the scheduler to answer, when connecting
        and when it stops answering (:class:`~vehicle_detection.errors.ClusterError` then).

    Returns
    -------
    list of InputResult
        One per input, in input order. An input whose dask worker died has ``exit_code`` 8.

    Raises
    ------
    ClusterError
        The scheduler cannot be reached, or went away during the run (the inputs it left
        unfinished have no output, not even a ``.partial`` file).

    Notes
    -----
    The earlier keywords (``video``, ``frames``, ``formats``, ``overwrite``, ``progress``,
    ``preset``, ``crf``: now in ``options``; ``model`` and ``horizon``: now a ``detector``;
    ``scheduler``: now ``client``) still work, with a :class:`DeprecationWarning`.
    """
    options = options or InputOptions()
    paths = [paths] if isinstance(paths, (str, os.PathLike)) else list(paths)
    _check_batch(options, jobs, chunk_frames, table)
    if client is not None and jobs > 1:
        raise UsageError("jobs are local worker processes; with a dask cluster (client) its workers run the inputs",
                         cli="--jobs are local worker processes; with a dask cluster (--scheduler) its workers run the inputs")
    if client is None and chunk_frames is not None:
        raise UsageError("chunk_frames splits videos into tasks of a dask cluster; give a client too",
                         cli="--chunk-frames splits videos into tasks of a dask cluster; give --scheduler too")
    detector = detector or Detector()
    tasks, results = _tasks(paths, out_dir, options, detector, progress=options.progress and jobs == 1 and client is None)
    if table is not None:
        _check_table(Path(table), tasks, options)
    tasks, coco = _coco_tasks(tasks, out_dir, options)
    report = on_result or (lambda r: None)
    if skip_existing:
        images_done = all(t.complete() for t in tasks.values() if t.kind == "image")  # their dataset is one file
        for k in [k for k, task in tasks.items() if task.complete() and (task.kind != "image" or images_done)]:
            task = tasks.pop(k)
            results[k] = InputResult(task.path, (*task.outputs.files(task.kind, task.images()), *task.shared), skipped=True)
    if coco is not None and any(t.kind == "image" for t in tasks.values()):
        check_outputs([coco], overwrite=options.overwrite, inputs=[*(t.path for t in tasks.values()), *options.inputs])
    for k in sorted(results):
        report(results[k])
    _run(tasks, jobs, client, chunk_frames, results, report, scheduler_timeout)
    ordered = [results[k] for k in range(len(results))]
    if coco is not None and any(t.kind == "image" for t in tasks.values()):
        _write_coco_dataset(coco, [r for r in ordered if r.image is not None], overwrite=options.overwrite)
    if table is not None:
        _write_combined(Path(table), ordered, overwrite=options.overwrite)
    return ordered


def _check_batch(options: InputOptions, jobs: int, chunk_frames: int | None, table) -> None:
    if jobs < 1:
        raise UsageError("jobs must be >= 1")
    if chunk_frames is not None and (chunk_frames < 1 or options.video):
        raise UsageError("chunk_frames needs a number >= 1 and no video (video=False): the encoder needs the whole video in one task",
                         cli="--chunk-frames needs a number >= 1 and --no-video: the encoder needs the whole video in one task")
    if chunk_frames is not None and (options.road.camera is not None or options.road.lanes or options.report):
        raise UsageError("chunk_frames runs the detector alone: no camera, lanes or report",
                         cli="--chunk-frames runs the detector alone: no --camera, --lanes or --report")
    if table is not None and Path(table).suffix.lower() != ".parquet":
        raise UsageError(f"{table}: the table of all inputs is a Parquet file (.parquet)")


def _tasks(paths, out_dir, options: InputOptions, detector: Detector, *, progress: bool):
    """One task per input (in input order), and the inputs refused at once as results."""
    tasks: dict[int, _Task] = {}
    results: dict[int, InputResult] = {}
    claimed: dict[Path, Path] = {}
    options = replace(options, progress=progress)
    for k, (p, kind, problem) in enumerate(expand_inputs(paths)):
        if problem is not None:
            results[k] = InputResult(p, error=problem, exit_code=3)
            continue
        outputs = default_outputs(p, kind, None if out_dir is None else Path(out_dir), options.formats, video=options.video,
                                  report=options.report)
        for o in [outputs.annotated, *outputs.tables.values(), outputs.report]:
            if o is None:
                continue
            key = Path(os.path.abspath(o))
            if key in claimed:
                raise UsageError(f"{claimed[key]} and {p} would both write {o}; give them different names or out-dirs")
            claimed[key] = p
        tasks[k] = _Task(p, kind, outputs, options, detector)
    _refuse_images_into_folder_inputs(tasks)
    return tasks, results


def _refuse_images_into_folder_inputs(tasks: dict[int, _Task]) -> None:
    """An annotated image may not be written into a folder of images that is an input of the
    same batch: that input would read it as one of its own images (or a half-written one)."""
    folders = {Path(os.path.abspath(t.path)): t.path for t in tasks.values() if t.kind == "folder"}
    for t in tasks.values():
        out = t.outputs.annotated
        if t.kind == "image" and out is not None and Path(os.path.abspath(out)).parent in folders:
            raise OutputError(f"{out}: the annotated image of {t.path} would be written into {folders[Path(os.path.abspath(out)).parent]}, "
                              "a folder of images of this batch, and read as one of its images; choose another --out-dir")


def _coco_tasks(tasks: dict[int, _Task], out_dir, options: InputOptions) -> tuple[dict[int, _Task], Path | None]:
    """COCO where it applies: the single images of a batch make one dataset, ``images_coco.json``
    (in ``out_dir``, else beside the first image; returned, None when there is none); videos get
    the other formats (the boxes CSV when COCO was the only one); folders of images keep their own."""
    if "coco" not in options.formats:
        return tasks, None
    images = [t for t in tasks.values() if t.kind == "image"]
    dest = None
    if images:
        dest = (Path(out_dir) if out_dir is not None else images[0].path.parent) / "images_coco.json"
        for t in tasks.values():
            if Path(os.path.abspath(dest)) in {Path(os.path.abspath(o)) for o in t.outputs.files(t.kind)}:
                raise UsageError(f"{t.path} and the images' COCO dataset would both write {dest}; give another --out-dir")
    out = {}
    for k, t in tasks.items():
        if t.kind in ("video", "image"):
            tables = {f: p for f, p in t.outputs.tables.items() if f != "coco"}
            if not tables and t.kind == "video":
                tables = default_outputs(t.path, t.kind, None if out_dir is None else Path(out_dir), ("csv",)).tables
            t = replace(t, outputs=replace(t.outputs, tables=tables), shared=(dest,) if t.kind == "image" else ())
        out[k] = t
    return out, dest


def _write_coco_dataset(dest: Path, results: Sequence[InputResult], *, overwrite: bool) -> None:
    """One COCO dataset of single images (``r.image``: size and boxes), ``file_name`` relative to its folder."""
    parts, names, sizes = [], [], []
    for i, r in enumerate(results):
        size, boxes = r.image
        parts.append(boxes.replace(frame=np.full(len(boxes), i, dtype=np.int64)))
        try:
            names.append(os.path.relpath(r.path, dest.parent))
        except ValueError:  # another drive
            names.append(str(r.path))
        sizes.append(size)
    table = Detections.concatenate(parts) if parts else Detections.empty()
    with output_batch():
        write_coco(dest, table, names, sizes, overwrite=overwrite, inputs=[r.path for r in results])


def _run(tasks: dict[int, _Task], jobs: int, client, chunk_frames: int | None, results: dict, report,
         timeout: float = SCHEDULER_TIMEOUT) -> None:
    own_client = None
    if isinstance(client, str):
        client = own_client = connect(client, timeout)
    try:
        if client is not None:
            with _quiet_dask(own_client is not None):
                _run_dask(tasks, client, chunk_frames, results, report)
        elif jobs == 1 or len(tasks) <= 1:
            threads = None
            if jobs > 1:
                threads = max(1, os.cpu_count() or 1)
                set_numba_threads(threads)
            for k, task in tasks.items():
                results[k] = _run_task(replace(task, threads=threads))
                report(results[k])
        else:
            _run_pool(tasks, jobs, results, report)
    finally:
        if own_client is not None:
            with _quiet_dask(True):
                try:
                    own_client.close(timeout=timeout)
                except Exception:  # noqa: BLE001  (a scheduler that went away cannot be told goodbye)
                    pass


# --- a dask cluster ---------------------------------------------------------------------------------

#: ``[SCHEME://]HOST:PORT`` (HOST may be ``[IPv6]``).
_ADDRESS = re.compile(r"^(?:(?P<scheme>[a-z]+)://)?(?P<host>\[[0-9A-Fa-f:.]+\]|[^\s:/\[\]]+):(?P<port>\d{1,5})$")
_SCHEMES = ("tcp", "tls", "ws", "wss", "ucx")


def scheduler_address(address: str) -> str:
    """``address`` checked and with its scheme (``HOST:PORT`` -> ``tcp://HOST:PORT``).

    Raises
    ------
    UsageError
        When it is not ``[tcp|tls|ws|wss|ucx://]HOST:PORT`` with a port from 1 to 65535 (or the
        ``inproc://`` address of a cluster in this process).
    """
    if re.match(r"^inproc://\S+$", address):
        return address  # a cluster in this process (LocalCluster(processes=False))
    m = _ADDRESS.match(address.strip())
    scheme = (m and m["scheme"]) or "tcp"
    if m is None or scheme not in _SCHEMES or not 1 <= int(m["port"]) <= 65535:
        raise UsageError(f"--scheduler {address!r}: expected a dask scheduler's address, [{'|'.join(_SCHEMES)}://]HOST:PORT "
                         "with a port from 1 to 65535 (as 'dask scheduler' prints it: tcp://HOST:8786)")
    return f"{scheme}://{m['host']}:{int(m['port'])}"


def connect(address: str, timeout: float = SCHEDULER_TIMEOUT):
    """A ``dask.distributed.Client`` of the scheduler at ``address``.

    Parameters
    ----------
    address : str
        ``tcp://HOST:PORT`` (or ``HOST:PORT``; see :func:`scheduler_address`).
    timeout : float
        Seconds to wait for the scheduler to answer (and, later, to come back when it stops
        answering).

    Raises
    ------
    UsageError
        A malformed address, or a timeout that is not a finite number > 0.
    MissingDependencyError
        dask.distributed is not installed.
    ClusterError
        No scheduler answers at ``address`` within ``timeout`` seconds.
    """
    if not 0 < timeout < float("inf"):
        raise UsageError(f"--scheduler-timeout {timeout!r}: expected a finite number of seconds > 0")
    address = scheduler_address(address)
    distributed = require("distributed", "distributed", "--scheduler")
    _probe_scheduler(address, timeout)
    with _quiet_dask(True):
        try:
            return distributed.Client(address, timeout=timeout, set_as_default=False)
        except (OSError, TimeoutError) as exc:
            raise _unreachable(address, timeout) from exc


def _unreachable(address: str, timeout: float) -> ClusterError:
    return ClusterError(f"{address}: the dask scheduler cannot be reached (no answer within {timeout:g} s; "
                        "is 'dask scheduler' running there, and the port open? --scheduler-timeout waits longer)")


#: Seconds between two tries of a scheduler's port that refused the connection.
_RETRY_S = 0.2


def _probe_scheduler(address: str, timeout: float) -> None:
    """Refuse, within ``timeout``, a TCP address where no dask scheduler answers.

    A port that refuses the connection is tried again until ``timeout`` (a scheduler started
    with the command is still starting), as ``dask.distributed.Client`` does.

    A dask scheduler greets each new connection at once with its handshake: one framed message
    (a little-endian uint64 byte count, a uint64 frame count, the frames' lengths, msgpack).
    Something else listening there (an HTTP server, a listener that never replies, one that
    sends garbage) would keep ``Client`` waiting or fail deep inside it.
    """
    if not address.startswith("tcp://"):
        return  # tls, ws, ucx, inproc: dask's own connection and its timeout
    host, port = address[6:].rsplit(":", 1)
    host = host.strip("[]")
    deadline = time.monotonic() + timeout
    while True:  # a closed port is tried again until the deadline: the scheduler may be starting
        try:
            sock = socket.create_connection((host, int(port)), timeout=max(deadline - time.monotonic(), 0.01))
            break
        except ConnectionRefusedError:
            if time.monotonic() + _RETRY_S >= deadline:
                raise _unreachable(address, timeout) from None
            time.sleep(_RETRY_S)
        except OSError:
            raise _unreachable(address, timeout) from None
    with sock:
        head = b""
        try:
            while len(head) < 16:
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                sock.settimeout(left)
                chunk = sock.recv(16 - len(head))
                if not chunk:
                    break
                head += chunk
        except OSError:
            pass
    if not head:
        raise ClusterError(f"{address}: something listens there, but no dask scheduler answered within {timeout:g} s "
                           "(a web server, or the dashboard's port? 'dask scheduler' prints its tcp:// address)")
    size, frames = (struct.unpack("<QQ", head) if len(head) == 16 else (0, 0))
    if not (0 < size < 1 << 24 and 0 < frames <= 64):
        raise ClusterError(f"{address}: what answers there is not a dask scheduler (its first bytes are no dask message)")


@contextmanager
def _quiet_dask(quiet: bool):
    """dask.distributed's own log lines off (errors are reported once, on one line, by the caller).

    dask's logging configuration gives ``distributed.client`` and its other loggers levels of
    their own, so each is set, not only their parent."""
    if not quiet:
        yield
        return
    names = ["distributed", *(n for n in list(logging.root.manager.loggerDict) if n.startswith("distributed."))]
    levels = {n: logging.getLogger(n).level for n in names}
    for n in names:
        logging.getLogger(n).setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        for n, level in levels.items():
            logging.getLogger(n).setLevel(level)


def _address(client) -> str:
    try:
        return str(client.scheduler.address)
    except AttributeError:
        return "the dask scheduler"


def _cluster_failure(exc: BaseException, client) -> ClusterError | None:
    """The cluster's part in a failed task: a worker that died, or a scheduler that went away; None: neither."""
    if isinstance(exc, CancelledError):
        return ClusterError(f"{_address(client)}: the dask scheduler went away during the run (connection lost)")
    if type(exc).__name__ == "KilledWorker":  # distributed.scheduler.KilledWorker
        worker = getattr(getattr(exc, "last_worker", None), "address", None) or "a worker"
        return ClusterError(f"the dask worker running it ({worker}) died; nothing of it was written")
    return None


def _remove_partials(task: _Task) -> None:
    """Delete the hidden ``.partial`` files of an input whose worker died or was stopped (it may
    not have cleaned up after itself)."""
    for out in task.outputs.files(task.kind, task.images()):
        for tmp in out.parent.glob(f".{glob.escape(out.name)}.*{PARTIAL_SUFFIX}"):
            try:
                tmp.unlink()
            except OSError:
                pass


def _run_pool(tasks: dict[int, _Task], jobs: int, results: dict, report) -> None:
    threads = max(1, (os.cpu_count() or 1) // jobs)
    tasks = {k: replace(task, threads=threads) for k, task in tasks.items()}
    # loky (joblib's) starts fresh interpreters (no fork of a process with threads: numba, PyAV) that,
    # unlike multiprocessing's "spawn", do not re-run the caller's script: detect_many works in a
    # plain script without an ``if __name__ == "__main__":`` guard.
    from joblib.externals.loky import ProcessPoolExecutor  # imported here: 0.07 s that a single input's start need not pay

    pool = ProcessPoolExecutor(max_workers=min(jobs, len(tasks)), initializer=init_worker, initargs=(threads,))
    futures: dict = {}
    try:
        for k, task in tasks.items():
            futures[pool.submit(_run_task, task)] = k
        pending = set(futures)
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for fut in done:
                k = futures[fut]
                try:
                    results[k] = fut.result()
                except Exception as exc:  # a worker died (killed, out of memory)
                    results[k] = InputResult(tasks[k].path, error=f"{tasks[k].path}: worker failed: {type(exc).__name__}: {one_line(exc)}", exit_code=1)
                report(results[k])
    except BaseException:
        # Ctrl-C, SIGTERM: interrupt the running tasks the same way (each cleans up its partial outputs
        # and returns), and start no other. A worker ignores SIGTERM between tasks (init_worker), so it
        # is never killed mid-clean-up, neither by this signal nor by loky, which kills every worker
        # when one dies. Repeated until every task is done: a worker may have taken a queued input
        # after cleaning up the first (a second SIGTERM during a clean-up is ignored).
        for fut in futures:
            fut.cancel()
        procs = list(getattr(pool, "_processes", {}).values())
        for _ in range(600):
            running = [fut for fut in futures if not fut.done()]
            if not running:
                break
            for proc in procs:
                if proc.is_alive():
                    with contextlib.suppress(OSError):
                        os.kill(proc.pid, signal.SIGTERM)
            wait(running, timeout=0.1)
        pool.shutdown(wait=True, kill_workers=any(not fut.done() for fut in futures))
        # A signal that reaches a worker while it opens an output, before the output's own clean-up
        # is in place, leaves that output's hidden partial file behind (seen once in a full test run on a loaded machine):
        # with every worker gone, none of this run's partial files is being written any more.
        for task in tasks.values():
            _remove_partials(task)
        raise
    pool.shutdown(wait=True)


class _Watch:
    """Which worker runs which of the run's futures (polled from the scheduler), so that a worker
    that dies fails its inputs at once, as dask's own ``KilledWorker`` does, rather than leaving
    them to wait for a worker that may never come, or to run again from their start."""

    def __init__(self, client, futures: dict, every: float = 1.0) -> None:
        self.client, self.every = client, every
        self.keys = {fut.key: fut for fut in futures}
        self.running: dict[str, set] = {}  # worker address -> keys of ours it runs
        self.last = 0.0

    def dead(self) -> list[tuple[object, str]]:
        """``(future, worker)`` of our futures whose worker has left the cluster since the last poll."""
        if time.monotonic() - self.last < self.every:
            return []
        self.last = time.monotonic()
        try:
            processing = self.client.sync(self.client.scheduler.processing, workers=None, callback_timeout=2 * self.every)
        except Exception:  # noqa: BLE001  (a scheduler gone is found by the futures themselves)
            return []
        lost = [(self.keys[key], worker) for worker, keys in self.running.items() if worker not in processing
                for key in keys if key in self.keys and not self.keys[key].done()]
        self.running = {w: {k for k in keys if k in self.keys} for w, keys in processing.items()}
        return lost


def _run_dask(tasks: dict[int, _Task], client, chunk_frames: int | None, results: dict, report) -> None:
    """One task per input on the cluster. A worker that dies fails the inputs it ran (exit status
    8, their partial files removed); a scheduler that goes away stops the run with a
    :class:`ClusterError`, after removing the partial files of every unfinished input."""
    as_completed = require("distributed", "distributed", "--scheduler").as_completed
    futures = {}
    try:
        for k, task in tasks.items():
            if chunk_frames is not None and task.kind == "video":
                results[k] = _run_chunked(task, client, chunk_frames)
                report(results[k])
            else:
                futures[client.submit(_run_task, task, pure=False)] = k
        watch = _Watch(client, futures)
        pending = as_completed(list(futures), loop=client.loop)
        while not pending.is_empty():
            for fut, worker in watch.dead():
                k = futures[fut]
                if k not in results:
                    fut.cancel()
                    _remove_partials(tasks[k])
                    results[k] = InputResult(tasks[k].path, error=f"{tasks[k].path}: the dask worker running it ({worker}) died; "
                                             "nothing of it was written", exit_code=ClusterError.exit_code)
                    report(results[k])
            batch = pending.next_batch(block=False)
            if not batch:
                time.sleep(0.05)
            for fut in batch:
                k = futures[fut]
                if k in results:  # failed above: its worker died
                    continue
                try:
                    results[k] = fut.result()
                except Exception as exc:
                    lost = _cluster_failure(exc, client)
                    if lost is None:
                        results[k] = InputResult(tasks[k].path, error=f"{tasks[k].path}: task failed: {type(exc).__name__}: {one_line(exc)}", exit_code=1)
                    elif isinstance(exc, CancelledError):
                        raise lost from None
                    else:
                        _remove_partials(tasks[k])
                        results[k] = InputResult(tasks[k].path, error=_message(tasks[k].path, lost), exit_code=lost.exit_code)
                report(results[k])
    except ClusterError as exc:
        unfinished = [k for k in tasks if k not in results]
        for k in unfinished:
            _remove_partials(tasks[k])
        raise ClusterError(f"{one_line(exc)}; {len(unfinished)} of {len(tasks)} inputs unfinished, nothing of them written") from None


def _check_table(dest: Path, tasks: dict[int, _Task], options: InputOptions) -> None:
    """Refuse the table of all inputs before any work: an input, an output of an input, a special
    file, or an existing file without ``overwrite``."""
    check_output_path(dest, overwrite=options.overwrite, inputs=[t.path for t in tasks.values()] + list(options.inputs))
    for t in tasks.values():
        for o in t.outputs.tables.values():
            if Path(os.path.abspath(o)) == Path(os.path.abspath(dest)):
                raise OutputError(f"{dest}: the table of all inputs would be the {o.suffix[1:]} table of {t.path}; choose another --table")


def _write_combined(dest: Path, results: list[InputResult], *, overwrite: bool) -> None:
    """One Parquet table of every input that has a table, read back from its own output."""
    parts = []
    for r in results:
        if not r.ok:
            continue
        own = [o for o in r.outputs if o.suffix in (".csv", ".parquet")]
        if not own:
            continue
        src = own[0]
        if src.suffix == ".parquet":
            parts += list(read_parquet(src).items())
        else:
            parts.append((r.path.name, read_boxes_csv(src)))
    write_parquet(dest, parts, overwrite=overwrite, inputs=[r.path for r in results])
