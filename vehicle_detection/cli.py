"""The ``vehicle-detection`` command.

Subcommands: ``download``, ``train``, ``sweep``, ``detect``, ``evaluate``. Errors a user can
cause, usage errors included, print one line on stderr (``vehicle-detection: error: ...``) and
exit non-zero; ``--debug`` prints the traceback before that line (the exit code stays the same).

Exit codes: 0 success; 1 internal error (a bug: please report it); 2 bad command line;
3 bad input file; 4 bad or mismatched model file; 5 output refused or not writable;
6 download failed; 130 interrupted (Ctrl-C).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import traceback
from pathlib import Path

from . import __version__
from .errors import InputError, OutputError, VehicleDetectionError

__all__ = ["main", "build_parser"]

VIDEO_EXTENSIONS = (".mp4", ".mov", ".avi", ".mkv", ".m4v", ".webm", ".mpg", ".mpeg", ".wmv", ".flv", ".ts", ".m2ts", ".mts")


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line like every other error (argparse prints the usage first)."""

    def error(self, message: str):
        self.exit(2, f"vehicle-detection: error: {message} (see '{self.prog} --help')\n")


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 1, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 1, got {text!r}")
    return value


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {text!r}") from None
    if not 0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}")
    return value


def _add_common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--debug", action="store_true", help="show the full traceback on errors")


def _add_feature_options(p: argparse.ArgumentParser) -> None:
    from .features import COLOR_SPACES, FeatureConfig

    d = FeatureConfig()
    g = p.add_argument_group("features (defaults: the embedded model's)")
    g.add_argument("--color-space", choices=COLOR_SPACES, default=d.color_space)
    g.add_argument("--hog-channels", default=",".join(map(str, d.hog_channels)), help="e.g. 0,1,2 or 0 (default %(default)s)")
    g.add_argument("--orientations", type=int, default=d.orientations)
    g.add_argument("--pixels-per-cell", type=int, default=d.pixels_per_cell)
    g.add_argument("--cells-per-block", type=int, default=d.cells_per_block)
    g.add_argument("--signed", type=int, choices=(0, 1), default=int(d.signed), help="signed (0-360) orientations (default %(default)s)")
    g.add_argument("--hog-sqrt", type=int, choices=(0, 1), default=int(d.hog_sqrt), help="gamma-compress before HOG (default %(default)s)")
    g.add_argument("--spatial-size", type=int, default=d.spatial_size, help="0 disables spatial bins")
    g.add_argument("--hist-bins", type=int, default=d.hist_bins, help="0 disables colour histograms")


def _feature_config(args):
    from .features import FeatureConfig

    try:
        channels = tuple(int(c) for c in str(args.hog_channels).split(",") if c.strip())
        return FeatureConfig(
            color_space=args.color_space,
            hog_channels=channels,
            orientations=args.orientations,
            pixels_per_cell=args.pixels_per_cell,
            cells_per_block=args.cells_per_block,
            signed=bool(args.signed),
            hog_sqrt=bool(args.hog_sqrt),
            spatial_size=args.spatial_size,
            hist_bins=args.hist_bins,
        )
    except ValueError as exc:
        raise InputError(str(exc)) from None


def build_parser() -> argparse.ArgumentParser:
    from .video import X264_PRESETS

    parser = _Parser(
        prog="vehicle-detection",
        description="Find and track vehicles in dashcam images and video (HOG + linear SVM).",
        epilog="Exit codes: 0 ok, 1 internal error, 2 usage, 3 bad input, 4 bad model, 5 output refused, 6 download failed, 130 interrupted.",
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("download", help="download the training archives into a data folder")
    p.add_argument("--data-dir", default=None, help="destination (default: $VEHICLE_DETECTION_DATA or ./data)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    _add_common(p)

    p = sub.add_parser("train", help="train a classifier and report its accuracy")
    p.add_argument("--data-dir", default=None, help="folder with vehicles.zip and non-vehicles.zip (default: $VEHICLE_DETECTION_DATA or ./data)")
    p.add_argument("--model", default=None, help="where to save the model (.npz); omitted: report only")
    p.add_argument("--C", type=_positive_float, default=None, help="SVM regularisation (default: the library's)")
    p.add_argument("--drop-duplicates", action="store_true", help="drop byte-identical duplicate images first")
    p.add_argument("--seed", type=int, default=0, help="random seed of the splits")
    p.add_argument("--json", action="store_true", help="print the report as one JSON object on the last line")
    p.add_argument("--overwrite", action="store_true", help="replace an existing model file")
    _add_feature_options(p)
    _add_common(p)

    p = sub.add_parser("sweep", help="compare feature configurations (random and grouped splits)")
    p.add_argument("--data-dir", default=None)
    p.add_argument("--color-spaces", default="YCrCb,YUV,LUV,HLS", help="comma-separated (default %(default)s)")
    p.add_argument("--hog-channels", default="0,1,2", help="semicolon-separated channel sets, e.g. '0,1,2;0' (default %(default)s)")
    p.add_argument("--orientations", default="9,16", help="comma-separated (default %(default)s)")
    p.add_argument("--pixels-per-cell", default="8,16")
    p.add_argument("--cells-per-block", default="2")
    p.add_argument("--color-features", default="16x32,0x0", help="spatial x hist pairs, 0x0 = HOG only (default %(default)s)")
    p.add_argument("--signed", default="1", help="signed orientations: 1, 0 or 1,0 for both (default %(default)s)")
    p.add_argument("--hog-sqrt", default="1", help="gamma-compress before HOG: 1, 0 or 1,0 (default %(default)s)")
    p.add_argument("--subsample", type=_positive_int, default=None, help="use this many images (random, stratified) for a quick look")
    p.add_argument("--jobs", type=_positive_int, default=2, help="parallel workers (default %(default)s)")
    p.add_argument("--json", action="store_true", help="print the table as JSON (one row per line)")
    _add_common(p)

    p = sub.add_parser("detect", help="detect vehicles in an image, a folder of images, or a video")
    p.add_argument("input", help="image, folder of images, or video")
    p.add_argument("--out", default=None, help="annotated output (default: next to the input, *_detected)")
    p.add_argument("--boxes", default=None, help="CSV of boxes (default: next to the input, *_boxes.csv)")
    p.add_argument("--model", default=None, help="model file (default: the embedded model)")
    p.add_argument("--overwrite", action="store_true", help="replace existing outputs (never the input)")
    p.add_argument("--preset", default="ultrafast", choices=X264_PRESETS, metavar="PRESET",
                   help="x264 speed preset for videos: %(choices)s (default %(default)s: fastest, larger files)")
    p.add_argument("--crf", type=int, default=23, choices=range(0, 52), metavar="CRF",
                   help="x264 quality for videos, 0-51, lower is better (default %(default)s)")
    p.add_argument("--no-progress", action="store_true")
    _add_common(p)

    p = sub.add_parser("evaluate", help="score detections on a labelled video")
    p.add_argument("--video", required=True)
    p.add_argument("--labels", required=True, help="annotation JSON (see ../shared/data/README.md)")
    p.add_argument("--model", default=None, help="model file (default: the embedded model)")
    p.add_argument("--json", action="store_true", help="print the scores as one JSON object on the last line")
    p.add_argument("--no-progress", action="store_true")
    _add_common(p)
    return parser


# --- commands ----------------------------------------------------------------------------------


def _cmd_download(args) -> int:
    from .data import default_data_dir
    from .download import download_archives

    paths = download_archives(default_data_dir(args.data_dir), progress=not args.no_progress)
    for name, path in paths.items():
        print(f"{name}: {path}")
    return 0


def _train_report(model) -> dict:
    m = model.metrics
    r, g = m.get("random_split", {}), m.get("grouped_split", {})
    return {
        "random_split_accuracy": r.get("accuracy"),
        "grouped_split_accuracy": g.get("accuracy"),
        "random_split_precision": r.get("precision"),
        "random_split_recall": r.get("recall"),
        "grouped_split_precision": g.get("precision"),
        "grouped_split_recall": g.get("recall"),
        "n_train": r.get("n_train"),
        "n_test": r.get("n_test"),
        "grouped_n_train": g.get("n_train"),
        "grouped_n_test": g.get("n_test"),
        "n_images": m.get("n_images"),
        "n_features": m.get("n_features"),
        "load_seconds": m.get("load_seconds"),
        "feature_seconds": m.get("feature_seconds"),
        "fit_seconds": m.get("fit_seconds"),
    }


def _cmd_train(args) -> int:
    from .classifier import DEFAULT_C, train
    from .data import load_dataset

    config = _feature_config(args)
    if args.model is not None:
        from ._files import check_output_path
        from .data import CLASSES, default_data_dir

        # The archives are inputs: --model must never replace one, even with --overwrite.
        root = default_data_dir(args.data_dir)
        check_output_path(args.model, overwrite=args.overwrite, inputs=[root / f"{c}.zip" for c in CLASSES])
    t = time.perf_counter()
    ds = load_dataset(args.data_dir, drop_duplicates=args.drop_duplicates)
    load_s = time.perf_counter() - t
    model = train(ds, config, C=args.C if args.C is not None else DEFAULT_C, random_state=args.seed)
    model.metrics["load_seconds"] = round(load_s, 3)
    model.metrics["drop_duplicates"] = bool(args.drop_duplicates)
    report = _train_report(model)
    m = model.metrics
    print(f"images: {m['n_images']} ({', '.join(f'{k} {v}' for k, v in ds.counts().items())})")
    print(f"features: {m['n_features']} per image ({config})")
    for name in ("random_split", "grouped_split"):
        s = m[name]
        print(
            f"{name.replace('_', ' ')}: accuracy {s['accuracy']:.4f}  precision {s['precision']:.4f}  "
            f"recall {s['recall']:.4f}  (train {s['n_train']}, test {s['n_test']})"
        )
    print(f"time: load {load_s:.1f} s, features {m['feature_seconds']:.1f} s, final fit {m['fit_seconds']:.1f} s (all {m['n_images']} images)")
    if args.model is not None:
        model.save(args.model, overwrite=args.overwrite)
        print(f"model saved to {args.model}")
    else:
        print("model not saved (pass --model OUT.npz to save it)")
    if args.json:
        print(json.dumps(report))
    return 0


def _csv_ints(text: str, what: str) -> list[int]:
    try:
        return [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise InputError(f"--{what}: expected comma-separated integers, got {text!r}") from None


def _cmd_sweep(args) -> int:
    import numpy as np

    from .classifier import DEFAULT_C, split_indices, sweep, sweep_configs
    from .data import load_dataset

    try:
        pairs = [tuple(int(v) for v in p.lower().split("x")) for p in args.color_features.split(",") if p.strip()]
        if any(len(p) != 2 for p in pairs):
            raise ValueError
    except ValueError:
        raise InputError(f"--color-features: expected pairs like 16x16,0x0, got {args.color_features!r}") from None
    try:
        configs = sweep_configs(
            color_spaces=tuple(c.strip() for c in args.color_spaces.split(",") if c.strip()),
            hog_channels=tuple(tuple(_csv_ints(s, "hog-channels")) for s in args.hog_channels.split(";") if s.strip()),
            orientations=tuple(_csv_ints(args.orientations, "orientations")),
            pixels_per_cell=tuple(_csv_ints(args.pixels_per_cell, "pixels-per-cell")),
            cells_per_block=tuple(_csv_ints(args.cells_per_block, "cells-per-block")),
            color_features=tuple(pairs),
            signed=tuple(bool(v) for v in _csv_ints(args.signed, "signed")),
            hog_sqrt=tuple(bool(v) for v in _csv_ints(args.hog_sqrt, "hog-sqrt")),
        )
    except ValueError as exc:
        raise InputError(str(exc)) from None
    ds = load_dataset(args.data_dir)
    if args.subsample and args.subsample < len(ds):
        _, keep = split_indices(ds.labels, test_size=args.subsample / len(ds), random_state=0)
        ds = ds.subset(np.sort(keep))
    print(f"sweeping {len(configs)} configurations on {len(ds)} images with {args.jobs} workers", file=sys.stderr)
    rows = sweep(ds, configs, C=DEFAULT_C, n_jobs=args.jobs)
    if args.json:
        for r in rows:
            print(json.dumps(r))
        return 0
    head = f"{'color':6} {'hog ch':7} {'orient':>6} {'sign':>4} {'sqrt':>4} {'ppc':>4} {'cpb':>4} {'spat':>5} {'hist':>5} {'feats':>6} {'random':>7} {'grouped':>7} {'feat s':>7}"
    print(head)
    for r in rows:
        ch = "".join(str(c) for c in r["hog_channels"])
        print(
            f"{r['color_space']:6} {ch:7} {r['orientations']:>6} {int(r['signed']):>4} {int(r['hog_sqrt']):>4} {r['pixels_per_cell']:>4} {r['cells_per_block']:>4} "
            f"{r['spatial_size']:>5} {r['hist_bins']:>5} {r['n_features']:>6} {r['random_accuracy']:>7.4f} "
            f"{r['grouped_accuracy']:>7.4f} {r['feature_seconds']:>7.2f}"
        )
    return 0


def _load_detector(model_path):
    from .classifier import VehicleClassifier
    from .detector import Detector

    return Detector(VehicleClassifier.load(model_path)) if model_path else Detector()


def _default_outputs(inp: Path, kind: str):
    if inp.name in ("", ".", ".."):  # "." or "..": name the outputs after the real folder
        inp = Path(os.path.abspath(inp))
    if kind == "video":
        return inp.with_name(f"{inp.stem}_detected.mp4"), inp.with_name(f"{inp.stem}_boxes.csv")
    if kind == "image":
        return inp.with_name(f"{inp.stem}_detected{inp.suffix}"), inp.with_name(f"{inp.stem}_boxes.csv")
    return inp.with_name(f"{inp.name}_detected"), inp.with_name(f"{inp.name}_detected") / "boxes.csv"


def _cmd_detect(args) -> int:
    from ._files import check_output_path
    from .boxes import BoxTable, write_boxes_csv
    from .images import IMAGE_EXTENSIONS, list_images, read_image, write_image
    from .pipeline import annotate_frame, process_video

    inp = Path(args.input)
    if not inp.exists():
        raise InputError(f"{inp}: no such file or folder")
    if inp.is_dir():
        kind = "folder"
    elif inp.suffix.lower() in IMAGE_EXTENSIONS:
        kind = "image"
    elif inp.suffix.lower() in VIDEO_EXTENSIONS:
        kind = "video"
    else:
        raise InputError(f"{inp}: unknown file type {inp.suffix!r}; expected an image ({', '.join(IMAGE_EXTENSIONS)}) or a video ({', '.join(VIDEO_EXTENSIONS)})")
    default_out, default_boxes = _default_outputs(inp, kind)
    out = Path(args.out) if args.out else default_out
    boxes = Path(args.boxes) if args.boxes else default_boxes
    # Refuse bad outputs before any work. The model file is an input too.
    model_inputs = [Path(args.model)] if args.model else []
    if out.resolve() == boxes.resolve():
        raise OutputError(f"{out}: the annotated output and the boxes CSV cannot be the same file")
    if kind == "image":
        from PIL import Image

        if out.suffix.lower() not in Image.registered_extensions():
            raise OutputError(f"{out}: unknown image extension {out.suffix!r} for the annotated image")
    if kind == "folder" and out.exists() and not out.is_dir():
        raise OutputError(f"{out}: exists and is not a folder; the annotated images of a folder go into a folder")
    for o in (out, boxes):
        if kind != "folder" or o is boxes:
            check_output_path(o, overwrite=args.overwrite, inputs=[inp, *model_inputs])
    detector = _load_detector(args.model)
    t = time.perf_counter()
    if kind == "video":
        table = process_video(
            inp, out, detector=detector, boxes_csv=boxes, overwrite=args.overwrite, progress=not args.no_progress,
            preset=args.preset, crf=args.crf,
        )
        n = len(set(table.frame.tolist()))
        print(f"{inp}: {len(table)} boxes in {n} frames; wrote {out} and {boxes} ({time.perf_counter() - t:.1f} s)")
        return 0
    files = [inp] if kind == "image" else list_images(inp)
    outs = [out] if kind == "image" else [out / f.name for f in files]
    inputs = [*files, *model_inputs]
    for o in [*outs, boxes]:
        check_output_path(o, overwrite=args.overwrite, inputs=inputs)
    rows = []
    new_folders = [d for d in (out, boxes.parent) if kind == "folder" and not d.exists()]
    written = []
    try:
        for i, (f, o) in enumerate(zip(files, outs)):
            image = read_image(f)
            det = detector.detect_image(image)
            written.append(write_image(o, annotate_frame(image, det.boxes), overwrite=args.overwrite, inputs=inputs))
            rows.extend((i, b, -1, s) for b, s in zip(det.boxes, det.scores))
            print(f"{f}: {len(det.boxes)} vehicles -> {o}")
        write_boxes_csv(boxes, BoxTable.from_rows(rows) if rows else BoxTable.empty(), overwrite=args.overwrite, inputs=inputs)
    except BaseException:
        # A folder that fails part-way (a corrupt image, Ctrl-C) must not leave a half set of
        # annotated images that looks like a result: remove what this run wrote.
        for o in written:
            o.unlink(missing_ok=True)
        for d in new_folders:
            try:
                d.rmdir()  # only if empty
            except OSError:
                pass
        raise
    print(f"boxes: {boxes}")
    return 0


def _cmd_evaluate(args) -> int:
    from contextlib import closing
    from itertools import islice

    from .evaluate import evaluate_detections, load_annotations
    from .pipeline import process_video
    from .video import read_frames

    labels = load_annotations(args.labels)
    if not labels.frames:
        raise InputError(f"{args.labels}: no labelled frames; nothing to score")
    last = max(labels.frames) + 1
    # Labels beyond the end of the video would silently count as missed cars: check first, by
    # decoding (the container's frame count is only an estimate for some formats).
    with closing(read_frames(args.video)) as frames:
        n_decoded = sum(1 for _ in islice(frames, last))
    if n_decoded < last:
        beyond = [f for f in labels.frames if f >= n_decoded]
        raise InputError(
            f"{args.labels}: labels frame(s) {', '.join(map(str, beyond))}, but {args.video} has only "
            f"{n_decoded} decoded frames (0..{n_decoded - 1}); wrong video or labels?"
        )
    detector = _load_detector(args.model)
    t = time.perf_counter()
    table = process_video(args.video, None, detector=detector, progress=not args.no_progress, max_frames=last)
    seconds = time.perf_counter() - t
    results = evaluate_detections(table.by_frame(), labels, iou_thresholds=(0.5, 0.3))
    for thr, s in results.items():
        print(
            f"IoU >= {thr}: precision {s.precision:.3f}  recall {s.recall:.3f}  F1 {s.f1:.3f}  "
            f"FP/frame {s.fp_per_frame:.2f}  (tp {s.tp}, fp {s.fp}, fn {s.fn}, ignored {s.ignored}, frames {s.n_frames})"
        )
    print(f"processed {last} frames in {seconds:.1f} s")
    if args.json:
        main_scores = results[0.5].as_dict()
        out = {k: main_scores[k] for k in ("precision", "recall", "f1", "fp_per_frame", "tp", "fp", "fn", "ignored", "n_frames")}
        out["iou_threshold"] = 0.5
        out["at_iou_0.3"] = results[0.3].as_dict()
        print(json.dumps(out))
    return 0


_COMMANDS = {
    "download": _cmd_download,
    "train": _cmd_train,
    "sweep": _cmd_sweep,
    "detect": _cmd_detect,
    "evaluate": _cmd_evaluate,
}


def main(argv=None) -> int:
    """Run the command line; returns the exit code (see module docstring)."""
    parser = build_parser()
    args = parser.parse_args(argv)
    # With --debug the traceback comes first, then the same one-line message and exit code.
    try:
        return _COMMANDS[args.command](args)
    except KeyboardInterrupt:
        if args.debug:
            traceback.print_exc()
        print("vehicle-detection: interrupted", file=sys.stderr)
        return 130
    except VehicleDetectionError as exc:
        if args.debug:
            traceback.print_exc()
        print(f"vehicle-detection: error: {_one_line(exc)}", file=sys.stderr)
        return exc.exit_code
    except Exception as exc:  # a bug: one line, and how to see more
        if args.debug:
            traceback.print_exc()
        hint = "" if args.debug else " (rerun with --debug for the traceback)"
        print(f"vehicle-detection: internal error: {type(exc).__name__}: {_one_line(exc)}{hint}", file=sys.stderr)
        return 1


def _one_line(exc: BaseException) -> str:
    """The message of ``exc`` on one line (ffmpeg and file names can bring line breaks)."""
    return " | ".join(part.strip() for part in str(exc).splitlines() if part.strip())


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
