"""``vehicle-detection detect``: one input, or a batch, with the same options.

Every input, alone or in a batch, is run by :func:`~vehicle_detection.pipeline.inputs.run_input`
with the same :class:`~vehicle_detection.pipeline.inputs.InputOptions` (frames, camera and
lanes, tables, video or not, encoding, report). A run's outputs go together: every default output
(annotated video, image or folder, tables, report, camera file) goes into one folder, ``--out-dir``,
else the folder of ``--out``, else the current folder (:data:`CURRENT_FOLDER`), under the default
names of :func:`~vehicle_detection.pipeline.inputs.default_outputs` (after ``--out``'s name when
given). One input may name its outputs one by one (``--out``, ``--boxes``, ``--lanes-csv``,
``--save-camera PATH``); a batch (several inputs, globs, a folder of videos, or a batch-only option)
writes default names and runs :func:`~vehicle_detection.pipeline.batch.detect_many`.

Lanes without a camera file with a bird's-eye transform: each input's road plane is estimated from
its own frames (:meth:`~vehicle_detection.road.survey.Road.for_footage`), printed, and saved with
``--save-camera`` (``NAME_camera.json`` with the other outputs, or ``--save-camera PATH``); where the footage shows no lane lines, the input runs without lanes and says so.

Each input ends with one summary line (:meth:`~vehicle_detection.viz.report.RunSummary.line`).
With ``--json``, standard output is one JSON object (``inputs``: each input's summary, notes and
road estimate, or its error) and the human lines go to standard error.
"""

from __future__ import annotations

import glob
import json
import sys
import time
from dataclasses import replace
from pathlib import Path

from ..errors import InputError, UsageError, require, shorten
from ..io import Encoding
from ..io.video import MAX_FRAME
from ..pipeline.batch import SCHEDULER_TIMEOUT, detect_many
from ..pipeline.inputs import (
    VIDEO_EXTENSIONS, InputOptions, InputResult, default_outputs, expand_inputs, input_kind, run_input, unknown_type,
)
from ..road.survey import Road
from .options import load_camera, load_detector


__all__ = ["run", "SOME_FAILED"]

#: Exit status of a batch in which some inputs failed (each is reported on stderr).
SOME_FAILED = 7

#: Where a run's outputs go without --out-dir or --out: the current folder, as most commands do.
#: Not beside the input: that writes into data folders (perhaps read-only, or shared), and a later
#: ``detect FOLDER`` would take the annotated videos there for inputs.
CURRENT_FOLDER = Path(".")

#: Options that only a batch has (with one input, they run a batch of one).
_BATCH_ONLY = ("skip_existing", "table", "scheduler", "chunk_frames")


def run(args) -> int:
    batch = _is_batch(args)
    if batch and (args.out or args.boxes or args.lanes_csv or args.save_camera is not None):
        raise UsageError("--out, --boxes, --lanes-csv and --save-camera name the outputs of one input; in a batch use "
                         "--out-dir (default names) and --format lanes")
    if args.scheduler_timeout is not None and args.scheduler is None:
        raise UsageError("--scheduler-timeout is the wait for a dask scheduler; give --scheduler ADDRESS too")
    options = _options(args)
    human = sys.stderr if args.json else sys.stdout
    return _detect_many(args, options, human) if batch else _detect_one(args, options, human)


def _is_batch(args) -> bool:
    if len(args.inputs) > 1 or args.jobs > 1 or any(getattr(args, name) not in (None, False) for name in _BATCH_ONLY):
        return True
    inp = Path(args.inputs[0])
    if not inp.exists():
        return glob.has_magic(str(inp))
    return inp.is_dir() and any(e.suffix.lower() in VIDEO_EXTENSIONS and e.is_file() for e in inp.iterdir())


def _frames(args) -> tuple[int, int | None] | None:
    """``--frames A-B`` or ``--start``/``--end``: decoded frames ``start <= index < end``."""
    if args.frames is not None:
        if args.start is not None or args.end is not None:
            raise UsageError("give --frames A-B or --start/--end, not both")
        lo, sep, hi = args.frames.partition("-")
        try:
            a, b = int(lo), int(hi)
        except ValueError:
            raise UsageError(f"--frames: expected A-B (inclusive decoded frame indexes), got {args.frames!r}") from None
        if not sep or a < 0 or b < a:
            raise UsageError(f"--frames: expected A-B with 0 <= A <= B, got {args.frames!r}")
        if b > MAX_FRAME:
            raise UsageError(f"--frames: frame {shorten(b)} is beyond any video (frame indexes are at most {MAX_FRAME})")
        return a, b + 1
    if args.start is None and args.end is None:
        return None
    a = 0 if args.start is None else args.start
    if a < 0 or (args.end is not None and args.end <= a):
        raise UsageError(f"--start {shorten(a)} --end {shorten(args.end)}: expected 0 <= start < end")
    if max(a, args.end or 0) > MAX_FRAME + 1:
        raise UsageError(f"--start {shorten(a)} --end {shorten(args.end)}: beyond any video (frame indexes are at most {MAX_FRAME})")
    return a, args.end


def _options(args) -> InputOptions:
    """Everything that applies to each input, alone or in a batch; refused here when it cannot work."""
    formats = tuple(f.strip() for f in args.format.split(",") if f.strip())
    if args.table is not None and Path(args.table).suffix.lower() != ".parquet":
        raise UsageError(f"--table {args.table}: the table of all inputs is a Parquet file (.parquet)")
    if "parquet" in formats or args.table is not None:
        try:
            import pyarrow  # noqa: F401  (an optional dependency: only checked for)
        except ImportError:
            raise UsageError('--format parquet and --table need pyarrow: pip install "vehicle-detection[parquet]"') from None
    lanes = args.lanes or args.lanes_csv is not None or args.save_camera is not None or "lanes" in formats
    camera = load_camera(args.camera)
    if args.save_camera is not None and camera is not None and camera.birds_eye is not None:
        raise UsageError(f"--save-camera saves a road plane estimated from the footage, but the camera file {args.camera} "
                         "has one (it wins): there is nothing to estimate")
    if args.dash_period is not None and (not lanes or (camera is not None and camera.birds_eye is not None)):
        raise UsageError("--dash-period sets the scale of a road plane estimated from the footage: it needs --lanes (or "
                         "--lanes-csv, --save-camera, --format lanes) and no camera file with a bird's-eye view")
    if args.report:
        require("matplotlib.figure", "report", "--report (the HTML report)")
    inputs = tuple(Path(p) for p in (args.model, args.camera) if p)
    road = Road(camera, lanes=lanes) if args.dash_period is None else Road(camera, lanes=lanes, dash_period_m=args.dash_period)
    return InputOptions(
        frames=_frames(args), road=road, video=not args.no_video, formats=formats,
        encoding=Encoding(args.preset, args.crf), overwrite=args.overwrite, progress=not args.no_progress, inputs=inputs,
        image_horizon=args.horizon == "auto",
        report=args.report,
    )


def _detect_one(args, options: InputOptions, human) -> int:
    if args.out and not options.video:
        raise UsageError("--out names the annotated output, and --no-video writes none; give one of them")
    inp = Path(args.inputs[0])
    if not inp.exists():
        raise InputError(f"{inp}: no such file or folder")
    kind = input_kind(inp)
    if kind is None:
        raise InputError(unknown_type(inp))
    # Every default output in one folder (--out-dir, else --out's, else the current one), under one
    # name (--out's, else the input's); an output named by its own flag goes where it says.
    folder = Path(args.out_dir) if args.out_dir is not None else None if args.out else _default_folder(inp, kind)
    outputs = default_outputs(inp, kind, folder, options.formats, video=options.video, annotated=args.out,
                              report=options.report, camera=args.save_camera == "")
    named = {"csv": args.boxes, "lanes": args.lanes_csv}
    tables = {**outputs.tables, **{fmt: Path(p) for fmt, p in named.items() if p}}
    outputs = replace(outputs, tables=tables, camera=Path(args.save_camera) if args.save_camera else outputs.camera)
    detector = load_detector(args.model, args.horizon, args.full_search_every, args.traffic)
    result = run_input(inp, options, detector=detector, outputs=outputs)
    _print_result(result, human)
    if args.json:
        print(json.dumps({"inputs": [_result_dict(result)]}, allow_nan=False))
    return 0


def _default_folder(inp: Path, kind: str) -> Path | None:
    """The current folder; but beside a folder of images run from inside it (``detect .``), where the
    current folder would put the outputs among the inputs (None: beside the input)."""
    if kind == "folder":
        here, folder = Path.cwd().resolve(), inp.resolve()
        if here == folder or folder in here.parents:
            return None
    return CURRENT_FOLDER


def _print_result(r: InputResult, human) -> None:
    """An input's lines for people: its summary (or error, or skip), then its notes."""
    if r.error is not None:
        print(f"vehicle-detection: error: {r.cli_message}", file=sys.stderr, flush=True)
    elif r.skipped:
        print(f"{r.path}: skipped, outputs complete", file=human, flush=True)
    else:
        for line in (r.summary.line(), *r.notes):
            print(line, file=human, flush=True)


def _result_dict(r: InputResult) -> dict:
    """An input's part of ``--json``: its summary, notes and road estimate; or its error, or its skip."""
    if r.error is not None:
        return {"input": str(r.path), "error": r.cli_message, "exit_code": r.exit_code}
    if r.skipped:
        return {"input": str(r.path), "skipped": True, "outputs": [str(o) for o in r.outputs]}
    d = {**r.summary.to_dict(), "notes": list(r.notes)}
    if r.estimate is not None:
        d["road_estimate"] = r.estimate.to_dict()
    return d


def _detect_many(args, options: InputOptions, human) -> int:
    t = time.perf_counter()
    if "coco" in options.formats and any(kind == "video" for _, kind, _ in expand_inputs(args.inputs)):
        print("coco: COCO JSON is written for images only; the videos get the other formats", file=sys.stderr)

    def report(r: InputResult) -> None:
        _print_result(r, human)

    detector = load_detector(args.model, args.horizon, args.full_search_every, args.traffic)
    results = detect_many(
        args.inputs, CURRENT_FOLDER if args.out_dir is None else args.out_dir, options, detector=detector, jobs=args.jobs, skip_existing=args.skip_existing,
        table=args.table, client=args.scheduler, chunk_frames=args.chunk_frames, on_result=report,
        scheduler_timeout=args.scheduler_timeout or SCHEDULER_TIMEOUT,
    )
    failed = [r for r in results if not r.ok]
    done = sum(1 for r in results if r.ok and not r.skipped)
    skipped = sum(r.skipped for r in results)
    frames = sum(r.n_frames for r in results if r.ok and not r.skipped)
    secs = time.perf_counter() - t
    print(f"{done} done, {skipped} skipped, {len(failed)} failed; {frames} frames in {secs:.1f} s "
          f"({frames / secs if secs > 0 else 0:.1f} frames/s)" + (f"; table {args.table}" if args.table else ""), file=human)
    if args.json:
        totals = {"done": done, "skipped": skipped, "failed": len(failed), "frames": frames, "seconds": round(secs, 3),
                  "table": args.table}
        print(json.dumps({"inputs": [_result_dict(r) for r in results], **totals}, allow_nan=False))
    if not failed:
        return 0
    return failed[0].exit_code if len(results) == 1 else SOME_FAILED
