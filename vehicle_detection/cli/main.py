"""The ``vehicle-detection`` command.

Subcommands: ``download``, ``train``, ``sweep``, ``calibrate``, ``detect``, ``evaluate``, ``mine-negatives``. Errors a user can
cause, usage errors included, print one line on stderr (``vehicle-detection: error: ...``) and
exit non-zero; ``--debug`` prints the traceback before that line (the exit code stays the same).

Exit codes: 0 success; 1 internal error (a bug: please report it); 2 bad command line;
3 bad input file; 4 bad or mismatched model file; 5 output refused or not writable;
6 download failed; 7 some inputs of a batch failed (each named on stderr); 130 interrupted (Ctrl-C, SIGTERM or SIGHUP).

A closed standard output (``vehicle-detection ... | head -1``) does not stop a run: the rest of
the report is discarded, the outputs are written, and the exit status is the run's own.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
import traceback
from contextlib import contextmanager
from pathlib import Path

from .. import __version__
from ..errors import InputError, OutputError, UsageError, VehicleDetectionError

__all__ = ["main", "build_parser"]



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


def _fraction(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 0.0 <= value < 1.0:
        raise argparse.ArgumentTypeError(f"expected a fraction in [0, 1), got {text!r}")
    return value


def _horizon(text: str) -> float | str:
    if text in ("auto", "plan"):
        return text
    try:
        return _fraction(text)
    except argparse.ArgumentTypeError:
        raise argparse.ArgumentTypeError(f"expected a fraction in [0, 1), 'auto' or 'plan', got {text!r}") from None


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
    from ..features import COLOR_SPACES, FeatureConfig

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
    from ..features import FeatureConfig

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
    except ValueError as exc:  # an option value that cannot work: a bad command line
        raise UsageError(str(exc)) from None


def build_parser() -> argparse.ArgumentParser:
    from ..io.video import X264_PRESETS

    parser = _Parser(
        prog="vehicle-detection",
        description="Find and track vehicles in dashcam images and video (HOG + linear SVM).",
        epilog="Exit codes: 0 ok, 1 internal error, 2 usage, 3 bad input, 4 bad model, 5 output refused, 6 download failed, 7 some inputs of a batch failed, 130 interrupted.",
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
    p.add_argument("--extra-negatives", action="append", default=[], metavar="DIR",
                   help="add the non-vehicle PNGs of DIR (laid out as DIR/non-vehicles/<source>/, e.g. from mine-negatives, "
                   "or PNGs directly in DIR), each source with its own split groups; repeatable")
    p.add_argument("--labels", nargs="+", default=[], metavar="L.json",
                   help="hand-labelled frames of your own cameras (the evaluate format): their cars are added as vehicle "
                   "patches, and the box refinement is learned from them. Never pass frames you score later")
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

    p = sub.add_parser(
        "calibrate",
        help="calibrate the camera from chessboard photos (and derive the bird's-eye view from straight-road frames)",
        description="Finds the inner chessboard corners (sub-pixel) in every photo of DIR, skips photos without a full "
        "board (saying why), crops photos a pixel or two larger than the majority size at the right and bottom "
        "(larger differences are skipped; nothing is rescaled), and fits the camera matrix and lens distortion. "
        "With --straight, also derives the bird's-eye transform for lane finding and distances from frames of a "
        "straight road (undistorted first).",
    )
    p.add_argument("dir", metavar="DIR", help="folder of chessboard photos")
    p.add_argument("--out", default=None, help="camera file to write (JSON); omitted: report only")
    p.add_argument("--pattern", default="9x6", help="inner corners per row x per column (default %(default)s)")
    p.add_argument("--straight", nargs="+", default=[], metavar="IMG",
                   help="frames of a straight road with both lane lines, for the bird's-eye transform (e.g. straight_lines1.jpg straight_lines2.jpg)")
    p.add_argument("--json", action="store_true", help="print the report as one JSON object on the last line")
    p.add_argument("--overwrite", action="store_true", help="replace an existing camera file")
    _add_common(p)

    p = sub.add_parser(
        "detect", help="detect vehicles in images, folders of images, and videos",
        description="Detect and track vehicles. One INPUT (an image, a folder of images or a video) writes its "
        "outputs next to it (or --out, --boxes). Several inputs, globs, folders of videos, or any of the batch "
        "options (--out-dir, --jobs, --skip-existing, --no-video, --start/--end/--frames, --format, --table, "
        "--scheduler) run a batch: each input is processed on its own, a failing one is reported by name and the "
        "others go on; the exit status is 7 when some failed (or the input's own code with one input).",
    )
    p.add_argument("inputs", nargs="+", metavar="INPUT", help="image, folder of images or videos, video, or glob pattern")
    p.add_argument("--out", default=None, help="annotated output of a single input (default: next to the input, *_detected)")
    p.add_argument("--boxes", default=None, help="CSV of boxes of a single input (default: next to the input, *_boxes.csv)")
    b = p.add_argument_group("batches")
    b.add_argument("--out-dir", default=None, metavar="DIR", help="write every input's outputs into DIR (default names)")
    b.add_argument("--jobs", type=_positive_int, default=1, metavar="N",
                   help="process N inputs at once in N processes, sharing the cores between them (default %(default)s)")
    b.add_argument("--skip-existing", action="store_true", help="skip an input whose outputs all exist (rewrite nothing)")
    b.add_argument("--no-video", action="store_true", help="write the tables only: no annotated video or images")
    b.add_argument("--start", type=int, default=None, metavar="A", help="first decoded frame (default 0)")
    b.add_argument("--end", type=int, default=None, metavar="B", help="stop before this decoded frame (default: the end)")
    b.add_argument("--frames", default=None, metavar="A-B", help="decoded frames A to B inclusive (instead of --start/--end)")
    b.add_argument("--format", default="csv", metavar="FMT[,FMT]",
                   help="tables per input: csv (default), parquet (needs pyarrow), mot (MOTChallenge text), coco (COCO "
                   "JSON, images only); comma-separated for several")
    b.add_argument("--table", default=None, metavar="ALL.parquet", help="also one Parquet table of all inputs, with a video column")
    b.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run one task per input on a dask.distributed cluster (needs vehicle-detection[distributed])")
    b.add_argument("--chunk-frames", type=_positive_int, default=None, metavar="N",
                   help="with --scheduler and --no-video: split each video into chunks of N frames (the tracker continues across)")
    p.add_argument("--model", default=None, help="model file (default: the embedded model)")
    p.add_argument("--horizon", type=_horizon, default=None, metavar="FRACTION|auto|plan",
                   help="the camera's horizon (where the road vanishes), as a fraction of the frame height from the top; "
                   "'auto' estimates it from the footage, 'plan' keeps the search bands where the model's plan has them "
                   "(made for the project camera, whose horizon is 0.583). Default: the model's setting (auto)")
    p.add_argument("--full-search-every", type=_positive_int, default=None, metavar="N",
                   help="videos: search whole frames every N frames, in between only the frame edges, the horizon "
                   "and around tracked vehicles (default: the model's plan, 1: every frame whole)")
    p.add_argument("--overwrite", action="store_true", help="replace existing outputs (never the input)")
    p.add_argument("--preset", default="ultrafast", choices=X264_PRESETS, metavar="PRESET",
                   help="x264 speed preset for videos: %(choices)s (default %(default)s: fastest, larger files)")
    p.add_argument("--crf", type=int, default=23, choices=range(0, 52), metavar="CRF",
                   help="x264 quality for videos, 0-51, lower is better (default %(default)s)")
    p.add_argument("--camera", default=None, metavar="CAMERA.json",
                   help="undistort every frame with this camera file (from 'calibrate') before the search; with its "
                   "bird's-eye transform, boxes also get distances (m) and relative speeds (m/s)")
    p.add_argument("--lanes", action="store_true", help="find and draw the lane, its radius and the car's offset (needs --camera with a bird's-eye transform)")
    p.add_argument("--lanes-csv", default=None, metavar="L.csv", help="write frame,curvature_m,offset_m per frame (implies --lanes)")
    p.add_argument("--no-progress", action="store_true")
    _add_common(p)

    p = sub.add_parser(
        "evaluate",
        help="score the detector (or a boxes CSV) against hand-labelled frames",
        description="Precision, recall and F1 at IoU 0.5 and 0.7, mean IoU of matched boxes, AP50, false positives "
        "per minute, and MOTA / IDF1 / HOTA where the labels carry track ids. Each labels file names its video "
        "or image folder (relative to the file); the detector runs on it, or --boxes scores an existing CSV.",
    )
    p.add_argument("--labels", required=True, nargs="+", help="annotation JSON file(s) (format: dev_set/README.md)")
    source = p.add_mutually_exclusive_group()
    source.add_argument("--video", default=None, help="the labelled video or image folder, instead of the one the labels name")
    source.add_argument("--boxes", default=None, help="score this boxes CSV instead of running the detector")
    p.add_argument("--model", default=None, help="model file (default: the embedded model)")
    p.add_argument("--horizon", type=_horizon, default=None, metavar="FRACTION|auto|plan",
                   help="the camera's horizon (where the road vanishes), as a fraction of the frame height from the top; "
                   "'auto' estimates it from the footage, 'plan' keeps the search bands where the model's plan has them "
                   "(made for the project camera, whose horizon is 0.583). Default: the model's setting (auto)")
    p.add_argument("--camera", default=None, metavar="CAMERA.json",
                   help="undistort every frame with this camera file before the search (the boxes are mapped back to the "
                   "original frames, where the labels are, before scoring)")
    p.add_argument("--json", action="store_true", help="print the scores as one JSON object on the last line")
    p.add_argument("--report", default=None, metavar="DIR",
                   help="write into DIR (created) cameras.md and cameras.csv, the scores of each camera, and per camera a "
                   "contact sheet failures_<camera>.png of every miss, false positive and loose match (at most 60 tiles)")
    p.add_argument("--overwrite", action="store_true", help="write into a --report folder that is not empty (replacing its files of the same names)")
    p.add_argument("--no-progress", action="store_true")
    _add_common(p)

    p = sub.add_parser(
        "mine-negatives",
        help="cut the detector's hot windows that are not vehicles out of footage, as new training negatives",
        description="Hard-negative mining. Searches each frame (or every k-th) of the inputs and keeps the hot windows "
        "that are certainly not vehicles: in labelled frames (and frames between labelled ones, with the car boxes "
        "interpolated), windows with IoU < --max-iou with every car and mostly outside the ignore regions; in "
        "unlabelled footage, windows wholly inside a --negative-region. Near duplicates are dropped. The 64x64 patches, "
        "as the classifier saw them, are written as PNGs to OUT/non-vehicles/NAME/ for `train --extra-negatives OUT`. "
        "Leave out (--frames) every frame you will score later.",
    )
    p.add_argument("inputs", nargs="*", metavar="INPUT", help="video or folder of images without labels (needs --negative-region)")
    p.add_argument("--labels", action="append", default=[], metavar="L.json",
                   help="annotation file; adds the video or image folder it names, with its labels (repeatable)")
    p.add_argument("--out", required=True, metavar="DIR", help="root folder: patches go to DIR/non-vehicles/NAME/")
    p.add_argument("--name", default="HardNegatives", help="source folder name under non-vehicles/ (default %(default)s)")
    p.add_argument("--model", default=None, help="model file (default: the embedded model)")
    p.add_argument("--horizon", type=_horizon, default=None, metavar="FRACTION",
                   help="search bands at this horizon (a fraction of the frame height from the top), for footage of "
                   "another camera; default: the plan's bands")
    p.add_argument("--frames", default=None, metavar="RANGES",
                   help="only these frame indexes, e.g. 0-89,160-250 (inclusive; default all)")
    p.add_argument("--every", type=_positive_int, default=1, metavar="K", help="search every K-th frame (default %(default)s)")
    p.add_argument("--threshold", type=float, default=None,
                   help="SVM margin above which a window is taken (default: the model's search threshold; -1 also takes "
                   "the negatives inside the SVM margin)")
    p.add_argument("--negative-region", action="append", default=[], metavar="X1,Y1,X2,Y2",
                   help="a place where no vehicle can be; windows must lie wholly inside one (repeatable; required for "
                   "inputs without labels)")
    p.add_argument("--max-gap", type=int, default=10, help="skip frames farther than this from a labelled frame (default %(default)s)")
    p.add_argument("--max-iou", type=_positive_float, default=0.1, help="largest IoU of a negative with any car (below; default %(default)s)")
    p.add_argument("--max-car-cover", type=_positive_float, default=0.1,
                   help="largest fraction of a negative's area inside a car box (below; default %(default)s)")
    p.add_argument("--dedupe-iou", type=_positive_float, default=0.5,
                   help="drop a window with this IoU with a kept one of the same scale (default %(default)s)")
    p.add_argument("--dedupe-frames", type=int, default=5, help="... kept in its frame or this many frames before (default %(default)s)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing OUT/non-vehicles/NAME/ folder")
    p.add_argument("--json", action="store_true", help="print the counts as one JSON object on the last line")
    p.add_argument("--no-progress", action="store_true")
    _add_common(p)
    return parser


# --- commands ----------------------------------------------------------------------------------


def _cmd_download(args) -> int:
    from ..training.data import default_data_dir
    from ..training.download import download_archives

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
    from ..classifier import DEFAULT_C, train, with_box_refinement
    from ..training.data import check_split_sizes, default_data_dir, load_dataset
    from ..metrics.detection import load_annotations
    from ..training.mining import labelled_dataset

    config = _feature_config(args)
    root = default_data_dir(args.data_dir)
    if args.model is not None:
        _check_model_output(args.model, root, overwrite=args.overwrite)
    t = time.perf_counter()
    ds = load_dataset(args.data_dir, drop_duplicates=args.drop_duplicates, extra_negatives=args.extra_negatives)
    load_s = time.perf_counter() - t
    labels = [load_annotations(p) for p in args.labels]
    if labels:
        ds = ds.concatenate(labelled_dataset(labels))
    check_split_sizes(ds.labels, ds.groups, name=str(root))  # before any feature is computed
    model = train(ds, config, C=args.C if args.C is not None else DEFAULT_C, random_state=args.seed)
    if labels:
        model = with_box_refinement(model, labels)
    extra = {}
    if args.extra_negatives:
        from ..training.data import _list_extra

        extra_sources = {source for d in args.extra_negatives for source, _ in _list_extra(Path(d))}
        extra = {"extra_negatives": {k: v for k, v in ds.counts().items() if k in extra_sources}}
    model = model.replace(metrics={**model.metrics, "load_seconds": round(load_s, 3), "drop_duplicates": bool(args.drop_duplicates), **extra})
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


def _check_model_output(model, root: Path, *, overwrite: bool) -> None:
    """The training data are inputs: ``--model`` may not be an archive or lie in a class folder."""
    from ..io._files import check_output_path
    from ..training.data import CLASSES

    model = Path(model)
    check_output_path(model, overwrite=overwrite, inputs=[root / f"{c}.zip" for c in CLASSES])
    target = model.resolve()
    for cls in CLASSES:
        folder = (root / cls).resolve()
        if target == folder or folder in target.parents:
            raise OutputError(
                f"{model}: model path is inside the training images folder {root / cls}; save the model elsewhere"
            )


def _csv_ints(text: str, what: str) -> list[int]:
    try:
        return [int(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise UsageError(f"--{what}: expected comma-separated integers, got {text!r}") from None


def _cmd_sweep(args) -> int:
    import numpy as np

    from ..classifier import DEFAULT_C, split_indices, sweep, sweep_configs
    from ..training.data import CLASSES, MIN_IMAGES_PER_CLASS, check_split_sizes, default_data_dir, load_dataset

    try:
        pairs = [tuple(int(v) for v in p.lower().split("x")) for p in args.color_features.split(",") if p.strip()]
        if any(len(p) != 2 for p in pairs):
            raise ValueError
    except ValueError:
        raise UsageError(f"--color-features: expected pairs like 16x16,0x0, got {args.color_features!r}") from None
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
    except ValueError as exc:  # an option value that cannot work: a bad command line
        raise UsageError(str(exc)) from None
    least = MIN_IMAGES_PER_CLASS * len(CLASSES)
    if args.subsample is not None and args.subsample < least:
        raise UsageError(f"--subsample {args.subsample}: too few images; at least {least} ({MIN_IMAGES_PER_CLASS} per class) are needed")
    root = default_data_dir(args.data_dir)
    ds = load_dataset(args.data_dir)
    check_split_sizes(ds.labels, ds.groups, name=str(root))  # before any work, not by scikit-learn
    if args.subsample and args.subsample < len(ds) - 2 * len(CLASSES):  # else: all of it
        _, keep = split_indices(ds.labels, test_size=args.subsample / len(ds), random_state=0)
        ds = ds.subset(np.sort(keep))
        check_split_sizes(ds.labels, ds.groups, name=f"{root} (--subsample {args.subsample})")
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


def _cmd_calibrate(args) -> int:
    from ..road.camera import calibrate
    from ..io.images import list_images, read_image

    try:
        cols, rows = (int(v) for v in args.pattern.lower().split("x"))
        if cols < 2 or rows < 2:
            raise ValueError
    except ValueError:
        raise UsageError(f"--pattern: expected inner corners like 9x6, got {args.pattern!r}") from None
    folder = Path(args.dir)
    if not folder.is_dir():
        raise InputError(f"{folder}: no such folder of chessboard photos")
    photos = list_images(folder)
    straight = [Path(p) for p in args.straight]
    if args.out is not None:
        from ..io._files import check_output_path

        check_output_path(args.out, overwrite=args.overwrite, inputs=[*photos, *straight])
    t = time.perf_counter()
    camera = calibrate(folder, (cols, rows))
    if straight:
        from ..road.lanes import birds_eye_from_straight

        frames = [read_image(p) for p in straight]
        for p, f in zip(straight, frames):
            camera.check_size(f.shape[1], f.shape[0], str(p))
        camera = camera.replace(birds_eye=birds_eye_from_straight(frames, camera))
    w, h = camera.image_size
    print(f"{folder}: {len(camera.images_used)} of {len(photos)} photos used ({w}x{h}), RMS reprojection error {camera.rms:.3f} px")
    for name in camera.images_cropped:
        print(f"  {name}: cropped to {w}x{h} (right and bottom edges)")
    for name, why in camera.images_skipped.items():
        print(f"  {name}: skipped: {why}")
    worst = max(camera.per_image_rms.items(), key=lambda kv: kv[1])
    print(f"  largest per-photo RMS: {worst[0]} {worst[1]:.2f} px")
    if camera.birds_eye is not None:
        be = camera.birds_eye
        print(f"bird's-eye view from {len(straight)} straight-road frame(s): {be.xm_per_px * 100:.2f} cm per pixel across, "
              f"{be.ym_per_px * 100:.2f} cm per pixel along the road")
    if args.out is not None:
        camera.save(args.out, overwrite=args.overwrite, inputs=[*photos, *straight])
        print(f"camera saved to {args.out} ({time.perf_counter() - t:.1f} s)")
    else:
        print("camera not saved (pass --out camera.json to save it)")
    if args.json:
        report = {
            "rms": camera.rms,
            "images_used": len(camera.images_used),
            "images_cropped": list(camera.images_cropped),
            "images_skipped": camera.images_skipped,
            "image_size": list(camera.image_size),
            "per_image_rms": camera.per_image_rms,
            "birds_eye": None if camera.birds_eye is None else camera.birds_eye.to_dict(),
            "out": args.out,
        }
        print(json.dumps(report))
    return 0


def _load_camera(path):
    if path is None:
        return None
    from ..road.camera import Camera

    return Camera.load(path)


def _load_detector(model_path, horizon: float | str | None = None, full_search_every: int | None = None):
    from ..detector import Detector

    detector = Detector.load(model_path or None, horizon=horizon)
    if full_search_every is None:
        return detector
    config = detector.config
    return Detector(detector.model, config.replace(plan=dataclasses.replace(config.plan, full_search_every=full_search_every)))


#: Exit status of a batch in which some inputs failed (each is reported on stderr).
SOME_FAILED = 7

_BATCH_OPTIONS = ("out_dir", "skip_existing", "no_video", "start", "end", "frames", "table", "scheduler", "chunk_frames")


def _is_batch(args) -> bool:
    if len(args.inputs) > 1 or args.jobs > 1 or args.format != "csv":
        return True
    if any(getattr(args, name) not in (None, False) for name in _BATCH_OPTIONS):
        return True
    import glob

    from ..pipeline.batch import VIDEO_EXTENSIONS

    inp = Path(args.inputs[0])
    if not inp.exists():
        return glob.has_magic(str(inp))
    return inp.is_dir() and any(e.suffix.lower() in VIDEO_EXTENSIONS and e.is_file() for e in inp.iterdir())


def _detect_range(args) -> tuple[int, int | None] | None:
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


def _cmd_detect_many(args) -> int:
    from ..pipeline.batch import detect_many

    if args.out or args.boxes:
        raise UsageError("--out and --boxes name the outputs of one input; in a batch use --out-dir (default names)")
    if args.camera or args.lanes or args.lanes_csv or args.full_search_every is not None:
        raise UsageError("--camera, --lanes, --lanes-csv and --full-search-every apply to one input at a time, not to a batch")
    formats = [f.strip() for f in args.format.split(",") if f.strip()]
    if args.table is not None and Path(args.table).suffix.lower() != ".parquet":
        raise UsageError(f"--table {args.table}: the table of all inputs is a Parquet file (.parquet)")
    if "parquet" in formats or args.table is not None:
        try:
            import pyarrow  # noqa: F401
        except ImportError:
            raise UsageError('--format parquet and --table need pyarrow: pip install "vehicle-detection[parquet]"') from None
    t = time.perf_counter()

    def report(r) -> None:
        if r.error is not None:
            print(f"vehicle-detection: error: {r.error}", file=sys.stderr, flush=True)
        elif r.skipped:
            print(f"{r.path}: skipped, outputs complete", flush=True)
        else:
            print(f"{r.path}: {r.n_boxes} boxes in {r.n_frames} frames; wrote {', '.join(map(str, r.outputs))} ({r.seconds:.1f} s)", flush=True)

    results = detect_many(
        args.inputs, out_dir=args.out_dir, jobs=args.jobs, skip_existing=args.skip_existing, video=not args.no_video,
        frames=_detect_range(args), model=args.model, horizon=args.horizon, overwrite=args.overwrite, formats=formats,
        table=args.table, scheduler=args.scheduler, chunk_frames=args.chunk_frames, preset=args.preset, crf=args.crf,
        progress=not args.no_progress, on_result=report,
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


def _cmd_detect(args) -> int:
    if _is_batch(args):
        return _cmd_detect_many(args)
    args.input = args.inputs[0]
    return _cmd_detect_one(args)


def _cmd_detect_one(args) -> int:
    from ..io._files import check_output_path, output_batch
    from ..detections import Detections
    from ..viz.drawing import draw_detections
    from ..io.images import check_image_output, list_images, read_image, write_image
    from ..pipeline.batch import default_outputs, input_kind, unknown_type
    from ..io.tables import write_boxes_csv
    from ..pipeline.video import process_video

    inp = Path(args.input)
    if not inp.exists():
        raise InputError(f"{inp}: no such file or folder")
    kind = input_kind(inp)
    if kind is None:
        raise InputError(unknown_type(inp))
    default_out, tables = default_outputs(inp, kind)
    default_boxes = tables["csv"]
    out = Path(args.out) if args.out else default_out
    boxes = Path(args.boxes) if args.boxes else default_boxes
    # Refuse bad outputs before any work. The model file is an input too.
    model_inputs = [Path(args.model)] if args.model else []
    if out.resolve() == boxes.resolve():
        raise OutputError(f"{out}: the annotated output and the boxes CSV cannot be the same file")
    if kind == "image":
        check_image_output(out)  # a format Pillow can write, before any work
    if kind == "folder" and out.exists() and not out.is_dir():
        raise OutputError(f"{out}: exists and is not a folder; the annotated images of a folder go into a folder")
    lanes_csv = Path(args.lanes_csv) if args.lanes_csv else None
    lanes = args.lanes or lanes_csv is not None
    if args.camera:
        model_inputs.append(Path(args.camera))
    camera = _load_camera(args.camera)
    if lanes and (camera is None or camera.birds_eye is None):
        raise UsageError("--lanes needs --camera CAMERA.json with a bird's-eye transform (made by 'calibrate DIR --straight IMG ...')")
    if lanes_csv is not None and lanes_csv.resolve() in (out.resolve(), boxes.resolve()):
        raise OutputError(f"{lanes_csv}: the lanes CSV must be a file of its own")
    for o in (out, boxes, *([lanes_csv] if lanes_csv else [])):
        if kind != "folder" or o is not out:
            check_output_path(o, overwrite=args.overwrite, inputs=[inp, *model_inputs])
    files = list_images(inp) if kind == "folder" else [inp]
    outs = [out / f.name for f in files] if kind == "folder" else [out]
    inputs = [*files, *model_inputs]
    if kind == "folder":
        for o in outs:
            check_image_output(o)  # e.g. .webp without a WebP encoder
            check_output_path(o, overwrite=args.overwrite, inputs=inputs)
        check_output_path(boxes, overwrite=args.overwrite, inputs=inputs)
    detector = _load_detector(args.model, args.horizon, args.full_search_every)
    t = time.perf_counter()
    # All outputs of the run are committed together at the end: a run that fails or is stopped
    # part-way (a corrupt image, Ctrl-C, SIGTERM, a full disk) leaves no new file, no .partial
    # file, no new folder, and every previous output (--overwrite) exactly as it was.
    with output_batch():
        if kind == "video":
            tracker = detector.new_tracker()
            table = process_video(
                inp, out, detector=detector, overwrite=args.overwrite, progress=not args.no_progress,
                preset=args.preset, crf=args.crf, camera=camera, lanes=lanes, lanes_csv=lanes_csv, tracker=tracker,
            )
            write_boxes_csv(boxes, table, overwrite=args.overwrite, inputs=inputs)
            n = len(table.frames())
            report = [f"{inp}: {len(table)} boxes in {n} frames; wrote {out} and {boxes} ({time.perf_counter() - t:.1f} s)"]
            if tracker.state.overlays is not None:
                report.extend(tracker.state.overlays.describe())
            if tracker.state.horizon is not None:
                plan = detector.config.plan
                cropped = tracker.state.overlays is not None and tracker.state.overlays.cropped
                report.append(f"horizon: {tracker.state.horizon:.3f} of the {'picture' if cropped else 'frame'} height, estimated from the video "
                              f"(the plan's {plan.reference_horizon:.3f}); search bands moved accordingly")
            if lanes_csv is not None:
                report.append(f"lanes: {lanes_csv}")
        else:
            found, lane_rows = [], []
            for i, (f, o) in enumerate(zip(files, outs)):
                image = read_image(f)
                if camera is not None:
                    camera.check_size(image.shape[1], image.shape[0], str(f))
                    image = camera.undistort(image)
                det = detector.detect_image(image).replace(frame=i)
                shown = image
                if camera is not None and camera.birds_eye is not None:
                    from ..road.lanes import DistanceTracker, LaneTracker, draw_lane, lane_row

                    det = DistanceTracker(camera.birds_eye, 25.0).update(det)
                    if lanes:
                        lane = LaneTracker(camera.birds_eye).step(image)
                        lane_rows.append(lane_row(i, lane))
                        shown = draw_lane(image, lane, camera.birds_eye)
                write_image(o, draw_detections(shown, det), overwrite=args.overwrite, inputs=inputs)
                found.append(det)
                print(f"{f}: {len(det)} vehicles -> {o}")  # progress; o appears at the end
            names = [f.name for f, det in zip(files, found) for _ in range(len(det))] if kind == "folder" else None
            write_boxes_csv(boxes, Detections.concatenate(found), overwrite=args.overwrite, inputs=inputs, files=names)
            report = [f"boxes: {boxes}"]
            if lanes_csv is not None:
                from ..io.tables import write_lanes_csv

                write_lanes_csv(lanes_csv, lane_rows, overwrite=args.overwrite, inputs=inputs)
                report.append(f"lanes: {lanes_csv}")
    for line in report:
        print(line)
    return 0


def _detect_for_labels(labels, source: Path, detector, progress: bool, camera=None):
    """Run the detector over what a labels file covers: ``(Detections, fps or None)``."""
    from contextlib import closing
    from itertools import islice

    from ..detections import Detections
    from ..io.images import list_images, read_image
    from ..pipeline.video import process_video
    from ..io.video import probe_video, read_frames

    last = max(labels.frames) + 1
    if source.is_dir():
        files = list_images(source)
        if len(files) < last:
            raise InputError(f"{labels.path}: labels image {last - 1}, but {source} has only {len(files)} images")
        for i, lab in labels.frames.items():
            if lab.file is not None and files[i].name != lab.file:
                raise InputError(f"{labels.path}: frame {i} is labelled as {lab.file}, but image {i} of {source} is {files[i].name}")
        if camera is None:
            return Detections.concatenate(detector.detect_image(read_image(files[i])).replace(frame=i) for i in labels.frames), None
        found = Detections.concatenate(detector.detect_image(camera.undistort(read_image(files[i]))).replace(frame=i) for i in labels.frames)
        return found.replace(xyxy=camera.boxes_to_original(found.xyxy)), None
    # Labels beyond the end of the video would silently count as missed cars: check first, by
    # decoding (the container's frame count is only an estimate for some formats).
    with closing(read_frames(source)) as frames:
        n_decoded = sum(1 for _ in islice(frames, last))
    if n_decoded < last:
        beyond = [f for f in labels.frames if f >= n_decoded]
        raise InputError(
            f"{labels.path}: labels frame(s) {', '.join(map(str, beyond))}, but {source} has only "
            f"{n_decoded} decoded frames (0..{n_decoded - 1}); wrong video or labels?"
        )
    table = process_video(source, None, detector=detector, progress=progress, max_frames=last, camera=camera)
    if camera is not None:  # the labels are in the original (distorted) frames
        table = table.replace(xyxy=camera.boxes_to_original(table.xyxy))
    return table, probe_video(source).fps


def _print_report(name: str, r: dict) -> None:
    print(f"{name}: {r['n_frames']} frames, {r['n_cars']} cars")
    for key in ("at_iou_0.5", "at_iou_0.7"):
        s = r[key]
        print(
            f"  IoU >= {key[-3:]}: precision {s['precision']:.3f}  recall {s['recall']:.3f}  F1 {s['f1']:.3f}  "
            f"mean IoU {s['mean_iou']:.3f}  (tp {s['tp']}, fp {s['fp']}, fn {s['fn']}, ignored {s['ignored']})"
        )
    extra = f"  AP50 {r['ap50']:.3f}" if "ap50" in r else " "
    if "fp_per_minute" in r:
        extra += f"  false positives per minute {r['fp_per_minute']:.1f}"
    print(extra)
    if "tracking" in r:
        t = r["tracking"]
        print(f"  tracking: MOTA {t['mota']:.3f}  IDF1 {t['idf1']:.3f}  HOTA {t['hota']:.3f}  (DetA {t['deta']:.3f}, AssA {t['assa']:.3f}, id switches {t['id_switches']})")


def _evaluate_sources(args, all_labels) -> dict[str, Path | None]:
    """The video or image folder of each labels file (``--video`` or the one it names)."""
    sources = {}
    for labels in all_labels:
        source = sources[str(labels.path)] = Path(args.video) if args.video else labels.source
        if source is None and not args.boxes:
            raise InputError(f"{labels.path}: the labels name no video; give --video")
        if source is None and args.report:
            raise InputError(f"{labels.path}: the labels name no video (key 'video'); --report reads the labelled frames from it")
        if args.report and not source.exists():
            raise InputError(f"{labels.path}: {source} not found; --report reads the labelled frames from it")
    return sources


def _json_scores(pooled: dict) -> dict:
    """Pooled scores as the top level of ``evaluate --json`` lays them out: IoU 0.5 flat, 0.7 nested."""
    return {**pooled["at_iou_0.5"], "iou_threshold": 0.5, "at_iou_0.7": pooled["at_iou_0.7"]}


def _cmd_evaluate(args) -> int:
    from ..metrics.detection import evaluation_report, load_annotations, pool_by_camera, pool_reports
    from ..metrics.reporting import ReportSource, check_report_dir, labels_camera
    from ..io.tables import read_boxes_csv

    all_labels = [load_annotations(p) for p in args.labels]
    for labels in all_labels:
        if not labels.frames:
            raise InputError(f"{labels.path}: no labelled frames; nothing to score")
    if args.boxes and len(all_labels) > 1:
        raise UsageError("--boxes scores one CSV against one labels file")
    if args.video and len(all_labels) > 1:
        raise UsageError("--video applies to one labels file; with several, each names its own video")
    if args.camera and args.boxes:
        raise UsageError("--camera applies when the detector runs, not to --boxes")
    sources = _evaluate_sources(args, all_labels)
    if args.report:
        check_report_dir(args.report, overwrite=args.overwrite)
    detector = None if args.boxes else _load_detector(args.model, args.horizon)
    camera = _load_camera(args.camera)
    t = time.perf_counter()
    reports, items = {}, []
    for labels in all_labels:
        name, source = str(labels.path), sources[str(labels.path)]
        if args.boxes:
            found, fps = read_boxes_csv(args.boxes), None
        else:
            found, fps = _detect_for_labels(labels, source, detector, progress=not args.no_progress, camera=camera)
        reports[name] = evaluation_report(found, labels, fps=fps)
        _print_report(name, reports[name])
        items.append(ReportSource(labels, found, source, labels_camera(labels, source)))
    cameras = {str(it.annotations.path): it.camera for it in items}
    by_camera = pool_by_camera(reports, cameras)
    pooled = pool_reports(reports.values())
    _print_pooled(by_camera, pooled, len(reports))
    print(f"scored in {time.perf_counter() - t:.1f} s")
    if args.report:
        _write_evaluate_report(args, items, by_camera, pooled, sources)
    if args.json:
        print(json.dumps(_evaluate_json(reports, cameras, by_camera, pooled)))
    return 0


def _print_pooled(by_camera: dict, pooled: dict, n_files: int) -> None:
    """A block per camera (when a camera has several files, or there are several cameras), then "all"."""
    if len(by_camera) > 1 or n_files > len(by_camera):
        for cam, p in by_camera.items():
            _print_report(f"camera {cam}", {k: v for k, v in p.items() if k != "labels"})
    if n_files > 1:
        _print_report("all", pooled)


def _write_evaluate_report(args, items, by_camera: dict, pooled: dict, sources: dict) -> None:
    from ..metrics.reporting import write_evaluation_report

    inputs = [*args.labels, *(s for s in sources.values() if s is not None), *filter(None, [args.boxes, args.model, args.camera])]
    written = write_evaluation_report(args.report, items, by_camera, pooled, overwrite=args.overwrite, inputs=inputs)
    for file, counts in written.items():
        extra = f" ({counts['shown']} tiles, {counts['left_out']} left out)" if counts else ""
        print(f"report: {Path(args.report) / file}{extra}")


def _evaluate_json(reports: dict, cameras: dict, by_camera: dict, pooled: dict) -> dict:
    """``evaluate --json``: the pooled scores, ``files`` (each with its ``camera``) and ``cameras``."""
    files = {name: {**r, "camera": cameras[name]} for name, r in reports.items()}
    per_camera = {cam: {**_json_scores(p), "n_cars": p["n_cars"], "labels": p["labels"]} for cam, p in by_camera.items()}
    return {**_json_scores(pooled), "files": files, "cameras": per_camera}


def _frame_ranges(text: str) -> set[int]:
    """``"0-89,160-250,300"`` -> the frame indexes (inclusive ranges)."""
    out: set[int] = set()
    for part in text.split(","):
        part = part.strip()
        if not part:
            continue
        lo, sep, hi = part.partition("-")
        try:
            a, b = int(lo), int(hi) if sep else int(lo)
        except ValueError:
            raise UsageError(f"--frames: expected ranges like 0-89,160-250, got {text!r}") from None
        if a < 0 or b < a:
            raise UsageError(f"--frames: {part!r} is not a range of frame indexes (first <= last, both >= 0)")
        out.update(range(a, b + 1))
    if not out:
        raise UsageError(f"--frames: no frames in {text!r}")
    return out


def _regions(texts: list[str]):
    import numpy as np

    boxes = []
    for text in texts:
        try:
            box = [int(v) for v in text.split(",")]
        except ValueError:
            box = []
        if len(box) != 4 or box[2] <= box[0] or box[3] <= box[1] or min(box) < 0:
            raise UsageError(f"--negative-region: expected X1,Y1,X2,Y2 whole pixels with X2 > X1 and Y2 > Y1, got {text!r}")
        boxes.append(box)
    return np.array(boxes, dtype=np.int64).reshape(-1, 4) if boxes else None


def _cmd_mine_negatives(args) -> int:
    from ..metrics.detection import load_annotations
    from ..training.mining import MiningSource, mine_negatives, write_negatives

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
    from ..training.mining import _refuse_inputs

    dest = Path(args.out) / "non-vehicles" / args.name
    _refuse_inputs(dest, inputs)
    if dest.exists() and not args.overwrite:
        raise OutputError(f"{dest}: output exists; pass --overwrite to replace it")
    if args.horizon == "auto":
        raise UsageError("mine-negatives --horizon takes a fraction of the frame height (or 'plan'), not 'auto'")
    detector = _load_detector(args.model, args.horizon)
    t = time.perf_counter()

    def progress(name, index):
        if index % 50 == 0:
            print(f"{name}: frame {index}", file=sys.stderr, flush=True)

    mined = mine_negatives(
        sources, detector, every=args.every, frames=frames, threshold=args.threshold, negative_regions=regions,
        max_gap=args.max_gap, max_iou=args.max_iou, max_car_cover=args.max_car_cover, dedupe_iou=args.dedupe_iou,
        dedupe_frames=args.dedupe_frames, progress=None if args.no_progress else progress,
    )
    for name, st in mined.stats.items():
        print(
            f"{name}: {st['frames']} frames searched ({st['skipped_frames']} skipped: no labels within --max-gap), "
            f"{st['hot']} hot windows, {st['far']} away from vehicles, {st['duplicates']} near duplicates dropped, {st['kept']} kept"
        )
    if len(mined):
        out = write_negatives(mined, args.out, args.name, overwrite=args.overwrite, inputs=inputs)
        print(f"mined {len(mined)} negatives -> {out} ({time.perf_counter() - t:.1f} s)")
    else:
        out = None
        print(f"mined 0 negatives; nothing written ({time.perf_counter() - t:.1f} s)")
    if args.json:
        print(json.dumps({"mined": len(mined), "folder": None if out is None else str(out), "inputs": mined.stats}))
    return 0


_COMMANDS = {
    "download": _cmd_download,
    "train": _cmd_train,
    "sweep": _cmd_sweep,
    "calibrate": _cmd_calibrate,
    "detect": _cmd_detect,
    "evaluate": _cmd_evaluate,
    "mine-negatives": _cmd_mine_negatives,
}


class _GuardedStdout:
    """Standard output that turns quiet, instead of failing, once its reader has gone.

    On the first ``BrokenPipeError`` (``... | head -1``) the file descriptor is pointed at
    ``os.devnull``, so that the rest of the report, and the interpreter's final flush, are
    discarded silently while the run finishes its real outputs.
    """

    def __init__(self, stream) -> None:
        self._stream = stream
        self.broken = False

    def _mute(self) -> None:
        self.broken = True
        try:
            fd = self._stream.fileno()
            devnull = os.open(os.devnull, os.O_WRONLY)
        except (OSError, ValueError, AttributeError):
            return
        try:
            os.dup2(devnull, fd)
        finally:
            os.close(devnull)

    def write(self, text: str) -> int:
        if not self.broken:
            try:
                return self._stream.write(text)
            except BrokenPipeError:
                self._mute()
        return len(text)

    def flush(self) -> None:
        if not self.broken:
            try:
                self._stream.flush()
            except BrokenPipeError:
                self._mute()

    def __getattr__(self, name):
        return getattr(self._stream, name)


@contextmanager
def _guarded_stdout():
    real = sys.stdout
    if real is None:
        yield
        return
    guard = sys.stdout = _GuardedStdout(real)
    try:
        yield
    finally:
        guard.flush()  # a pipe closed early shows up here when stdout is block-buffered
        if sys.stdout is guard:
            sys.stdout = real


def main(argv=None) -> int:
    """Run the command line; returns the exit code (see module docstring)."""
    with _guarded_stdout():
        parser = build_parser()
        args = parser.parse_args(argv)
        return _run(args)


def _run(args) -> int:
    from ..io._files import interrupt_on_signals

    # With --debug the traceback comes first, then the same one-line message and exit code.
    # SIGTERM (timeout, docker stop, systemd) and SIGHUP (a closed terminal) stop a run like
    # Ctrl-C: KeyboardInterrupt, so the same clean-up runs and the exit status is 130.
    try:
        with interrupt_on_signals():
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
