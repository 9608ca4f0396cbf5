"""``vehicle-detection detect``: one input, or a batch, with the same options.

Every input, alone or in a batch, is run by :func:`~vehicle_detection.pipeline.inputs.run_input`
with the same :class:`~vehicle_detection.pipeline.inputs.InputOptions` (frames, camera and
lanes, tables, video or not, encoding). One input may name its outputs (``--out``, ``--boxes``,
``--lanes-csv``); a batch (several inputs, globs, a folder of videos, or a batch-only option)
writes default names and runs :func:`~vehicle_detection.pipeline.batch.detect_many`.
"""

from __future__ import annotations

import glob
import sys
import time
from dataclasses import replace
from pathlib import Path

from ..errors import InputError, UsageError
from ..io import Encoding
from ..pipeline.batch import SCHEDULER_TIMEOUT, detect_many
from ..pipeline.inputs import (
    VIDEO_EXTENSIONS, InputOptions, InputResult, default_outputs, expand_inputs, input_kind, run_input, unknown_type,
)
from ..road.survey import Road
from .options import load_camera, load_detector

__all__ = ["run", "SOME_FAILED"]

#: Exit status of a batch in which some inputs failed (each is reported on stderr).
SOME_FAILED = 7

#: Options that only a batch has (with one input, they run a batch of one).
_BATCH_ONLY = ("skip_existing", "table", "scheduler", "chunk_frames")


def run(args) -> int:
    batch = _is_batch(args)
    if batch and (args.out or args.boxes or args.lanes_csv):
        raise UsageError("--out, --boxes and --lanes-csv name the outputs of one input; in a batch use --out-dir "
                         "(default names) and --format lanes")
    if args.scheduler_timeout is not None and args.scheduler is None:
        raise UsageError("--scheduler-timeout is the wait for a dask scheduler; give --scheduler ADDRESS too")
    options = _options(args)
    return _detect_many(args, options) if batch else _detect_one(args, options)


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
        return a, b + 1
    if args.start is None and args.end is None:
        return None
    a = 0 if args.start is None else args.start
    if a < 0 or (args.end is not None and args.end <= a):
        raise UsageError(f"--start {a} --end {args.end}: expected 0 <= start < end")
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
    lanes = args.lanes or args.lanes_csv is not None or "lanes" in formats
    camera = load_camera(args.camera)
    if lanes and (camera is None or camera.birds_eye is None):
        raise UsageError("--lanes needs --camera CAMERA.json with a bird's-eye transform (made by 'calibrate DIR --straight IMG ...')")
    inputs = tuple(Path(p) for p in (args.model, args.camera) if p)
    return InputOptions(
        frames=_frames(args), road=Road(camera, lanes=lanes), video=not args.no_video, formats=formats,
        encoding=Encoding(args.preset, args.crf), overwrite=args.overwrite, progress=not args.no_progress, inputs=inputs,
        image_horizon=args.horizon == "auto",
    )


def _detect_one(args, options: InputOptions) -> int:
    if args.out and not options.video:
        raise UsageError("--out names the annotated output, and --no-video writes none; give one of them")
    inp = Path(args.inputs[0])
    if not inp.exists():
        raise InputError(f"{inp}: no such file or folder")
    kind = input_kind(inp)
    if kind is None:
        raise InputError(unknown_type(inp))
    outputs = default_outputs(inp, kind, None if args.out_dir is None else Path(args.out_dir), options.formats, video=options.video,
                              annotated=args.out)
    named = {"csv": args.boxes, "lanes": args.lanes_csv}
    tables = {**outputs.tables, **{fmt: Path(p) for fmt, p in named.items() if p}}
    outputs = replace(outputs, tables=tables)
    detector = load_detector(args.model, args.horizon, args.full_search_every)
    result = run_input(inp, options, detector=detector, outputs=outputs)
    print(_summary(result))
    for line in result.notes:
        print(line)
    return 0


def _summary(r: InputResult) -> str:
    files = [str(o) for o in r.outputs]
    wrote = files[0] if len(files) == 1 else f"{', '.join(files[:-1])} and {files[-1]}"
    return f"{r.path}: {r.n_boxes} boxes in {r.n_frames} frames; wrote {wrote} ({r.seconds:.1f} s)"


def _detect_many(args, options: InputOptions) -> int:
    t = time.perf_counter()
    if "coco" in options.formats and any(kind == "video" for _, kind, _ in expand_inputs(args.inputs)):
        print("coco: COCO JSON is written for images only; the videos get the other formats", file=sys.stderr)

    def report(r: InputResult) -> None:
        if r.error is not None:
            print(f"vehicle-detection: error: {r.error}", file=sys.stderr, flush=True)
        elif r.skipped:
            print(f"{r.path}: skipped, outputs complete", flush=True)
        else:
            print(_summary(r), flush=True)

    detector = load_detector(args.model, args.horizon, args.full_search_every)
    results = detect_many(
        args.inputs, args.out_dir, options, detector=detector, jobs=args.jobs, skip_existing=args.skip_existing,
        table=args.table, client=args.scheduler, chunk_frames=args.chunk_frames, on_result=report,
        scheduler_timeout=args.scheduler_timeout or SCHEDULER_TIMEOUT,
    )
    failed = [r for r in results if not r.ok]
    done = sum(1 for r in results if r.ok and not r.skipped)
    frames = sum(r.n_frames for r in results if r.ok and not r.skipped)
    secs = time.perf_counter() - t
    print(f"{done} done, {sum(r.skipped for r in results)} skipped, {len(failed)} failed; {frames} frames in {secs:.1f} s "
          f"({frames / secs if secs > 0 else 0:.1f} frames/s)" + (f"; table {args.table}" if args.table else ""))
    if not failed:
        return 0
    return failed[0].exit_code if len(results) == 1 else SOME_FAILED
