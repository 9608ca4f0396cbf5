"""``vehicle-detection mine-negatives``: the detector's own false alarms, as new training negatives."""

from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from ..errors import InputError, OutputError, UsageError, shorten
from ..geometry import MAX_COORD
from ..io import refuse_inputs
from ..io.video import MAX_FRAME
from ..metrics.detection import load_annotations
from ..training.mining import FrameRanges, MiningOptions, MiningSource, mine_negatives, write_negatives
from .options import human_print, load_detector


__all__ = ["run"]


def _frame_ranges(text: str) -> FrameRanges:
    """``"0-89,160-250,300"`` -> the frame indexes (inclusive ranges), never listed one by one."""
    out = []
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        lo, sep, hi = part.partition("-")
        try:
            a, b = int(lo), int(hi) if sep else int(lo)
        except ValueError:
            raise UsageError(f"--frames: expected ranges like 0-89,160-250, got {shorten(text)!r}") from None
        if a < 0 or b < a:
            raise UsageError(f"--frames: {shorten(part)!r} is not a range of frame indexes (first <= last, both >= 0)")
        if b > MAX_FRAME:
            raise UsageError(f"--frames: frame {shorten(b)} is beyond any video (frame indexes are at most {MAX_FRAME})")
        out.append((a, b))
    if not out:
        raise UsageError(f"--frames: no frames in {shorten(text)!r}")
    return FrameRanges(tuple(out))


def _regions(texts: list[str]):
    boxes = []
    for text in texts:
        try:
            box = [int(v) for v in text.split(",")]
        except ValueError:
            box = []
        if len(box) != 4 or box[2] <= box[0] or box[3] <= box[1] or min(box) < 0 or max(box) > MAX_COORD:
            raise UsageError(f"--negative-region: expected X1,Y1,X2,Y2 whole pixels (at most {MAX_COORD}) with X2 > X1 and Y2 > Y1, got {shorten(text)!r}")
        boxes.append(box)
    return np.array(boxes, dtype=np.int64).reshape(-1, 4) if boxes else None


def run(args) -> int:
    if not args.inputs and not args.labels:
        raise UsageError("give the footage to mine: INPUT (with --negative-region) and/or --labels L.json")
    frames = _frame_ranges(args.frames) if args.frames else None
    regions = _regions(args.negative_region)
    if args.max_gap < 0 or args.dedupe_frames < 0:
        raise UsageError("--max-gap and --dedupe-frames must be >= 0")
    sources, seen = [], set()
    for path in args.labels:
        labels = load_annotations(path)
        if labels.source is None:
            raise InputError(f"{labels.path}: the labels name no video or image folder")
        if not labels.source.exists():
            raise InputError(f"{labels.path}: names {labels.source}, which does not exist")
        key = labels.source.resolve()
        if key in seen:
            raise UsageError(f"{labels.source} is named by two labels files; give one")
        seen.add(key)
        sources.append(MiningSource(labels.source, labels))
    for inp in map(Path, args.inputs):
        if not inp.exists():
            raise InputError(f"{inp}: no such video or folder")
        if inp.resolve() in seen:
            continue  # labelled through --labels
        if regions is None:
            raise UsageError(f"{inp}: no labels for this input; give --negative-region (a place no vehicle can be) or its --labels file")
        seen.add(inp.resolve())
        sources.append(MiningSource(inp))
    inputs = [s.path for s in sources] + [Path(p) for p in args.labels] + ([Path(args.model)] if args.model else [])
    dest = Path(args.out) / "non-vehicles" / args.name
    refuse_inputs(dest, inputs)
    if dest.exists() and not args.overwrite:
        raise OutputError(f"{dest}: output exists; pass --overwrite to replace it")
    if args.horizon == "auto":
        raise UsageError("mine-negatives --horizon takes a fraction of the frame height (or 'plan'), not 'auto'")
    detector = load_detector(args.model, args.horizon, traffic=args.traffic)
    t = time.perf_counter()

    def progress(name, index):
        if index % 50 == 0:
            print(f"{name}: frame {index}", file=sys.stderr, flush=True)

    options = MiningOptions(
        every=args.every, frames=frames, threshold=args.threshold, negative_regions=regions, max_gap=args.max_gap,
        max_iou=args.max_iou, max_car_cover=args.max_car_cover, dedupe_iou=args.dedupe_iou, dedupe_frames=args.dedupe_frames,
    )
    mined = mine_negatives(sources, detector, options, progress=None if args.no_progress else progress)
    say = human_print(args)
    for name, st in mined.stats.items():
        say(
            f"{name}: {st['frames']} frames searched ({st['skipped_frames']} skipped: no labels within --max-gap), "
            f"{st['hot']} hot windows, {st['far']} away from vehicles, {st['duplicates']} near duplicates dropped, {st['kept']} kept"
        )
    if len(mined):
        out = write_negatives(mined, args.out, args.name, overwrite=args.overwrite, inputs=inputs)
        say(f"mined {len(mined)} negatives -> {out} ({time.perf_counter() - t:.1f} s)")
    else:
        out = None
        say(f"mined 0 negatives; nothing written ({time.perf_counter() - t:.1f} s)")
    if args.json:
        print(json.dumps({"mined": len(mined), "folder": None if out is None else str(out), "inputs": mined.stats}))
    return 0
