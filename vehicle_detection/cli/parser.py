"""The command line's options: one parser, one sub-parser per command.

Usage errors are one line like every other error (``vehicle-detection: error: ...``, exit 2).
"""

from __future__ import annotations

import argparse
import math

from .. import __version__
from ..config import TRAFFIC
from ..features import COLOR_SPACES, FeatureConfig
from ..errors import shorten
from ..io.video import X264_PRESETS
from ..refine import MAX_ALPHA, MIN_ALPHA, REFINE_ALPHA
from ..training.augment import MAX_COPIES

__all__ = ["build_parser"]

EPILOG = ("Exit codes: 0 ok, 1 internal error, 2 usage, 3 bad input, 4 bad model, 5 output refused, 6 download failed, "
          "7 some inputs of a batch failed, 8 dask cluster unreachable or lost, 130 interrupted.")


class _Parser(argparse.ArgumentParser):
    """argparse, but a usage error is one line like every other error (argparse prints the usage first)."""

    def error(self, message: str):
        self.exit(2, f"vehicle-detection: error: {message} (see '{self.prog} --help')\n")


def _whole_number(minimum: int, maximum: int | None = None):
    """An argparse type: a whole number from ``minimum`` (to ``maximum``), else a one-line usage error."""

    def parse(text: str) -> int:
        try:
            value = int(text) if len(text) <= 20 else None
        except ValueError:
            value = None
        if value is None or value < minimum or (maximum is not None and value > maximum):
            want = f">= {minimum}" if maximum is None else f"from {minimum} to {maximum}"
            raise argparse.ArgumentTypeError(f"expected a whole number {want}, got {shorten(repr(text))}")
        return value

    return parse


_positive_int = _whole_number(1)
_count = _whole_number(0)


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


def _finite_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number, got {text[:40]!r}") from None
    if not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text[:40]!r}")
    return value


def _positive_float(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a number > 0, got {shorten(repr(text))}") from None
    if not 0 < value < float("inf"):
        raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {shorten(repr(text))}")
    return value


def _alpha(text: str) -> float:
    """A ridge penalty: below 1e-6 the fit's matrix is singular in floating point."""
    value = _positive_float(text)
    if not MIN_ALPHA <= value <= MAX_ALPHA:
        raise argparse.ArgumentTypeError(f"expected a ridge penalty from {MIN_ALPHA:g} to {MAX_ALPHA:g}, got {shorten(text)}")
    return value


def _dash_period(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = float("nan")
    if not 2.0 <= value <= 50.0:
        raise argparse.ArgumentTypeError(f"expected metres from one dash to the next, 2 to 50, got {text!r}")
    return value


def _add_common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--debug", action="store_true", help="show the full traceback on errors")


def _add_feature_options(p: argparse.ArgumentParser) -> None:
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


def build_parser() -> argparse.ArgumentParser:
    """The parser of ``vehicle-detection`` and all its commands."""
    parser = _Parser(
        prog="vehicle-detection",
        description="Find and track vehicles in dashcam images and video (HOG + linear SVM).",
        epilog=EPILOG,
    )
    parser.add_argument("--version", action="version", version=f"%(prog)s {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    for add in (_add_download, _add_train, _add_refine, _add_sweep, _add_calibrate, _add_detect, _add_report, _add_evaluate,
                _add_mine_negatives):
        add(sub)
    return parser


def _add_download(sub) -> None:
    p = sub.add_parser("download", help="download the training archives into a data folder")
    p.add_argument("--data-dir", default=None, help="destination (default: $VEHICLE_DETECTION_DATA or ./data)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    _add_common(p)


def _add_traffic(p, learned: bool = False, default: str = "the model's setting; the embedded model's is right") -> None:
    """``--traffic``: of the footage searched, or (``learned``) of the labelled frames learned from."""
    what = ("the labelled frames are learned flipped left to right, as the detector searches such footage, and the "
            "model is saved for left-hand traffic") if learned else "each picture is searched flipped left to right"
    p.add_argument("--traffic", choices=TRAFFIC, default=None,
                   help=f"the side of the road the traffic keeps to: with 'left' (the United Kingdom, Japan, India, "
                   f"Australia) {what} (default: {default})")


def _add_train(sub) -> None:
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
    p.add_argument("--augment", type=_whole_number(0, MAX_COPIES), default=0, metavar="N",
                   help="add N augmented copies of each training patch (mirror, zoom, blur, gamma, contrast, brightness, "
                   "JPEG artefacts) for other cameras and light; a copy is trained on only where its source patch is "
                   f"(0 to {MAX_COPIES}; default %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="random seed of the splits and of the augmentation")
    p.add_argument("--classifier", choices=("svm", "convnet"), default="svm",
                   help="svm: HOG features and a linear SVM, with the box refinement (the default); convnet: also a small "
                   "convolutional network that scores the windows and gives each its car's edges, trained on the patches "
                   "and the --labels frames (needs the train-cnn extra: PyTorch)")
    p.add_argument("--rounds", type=_positive_int, default=2, help="convnet: training rounds, each after the first with the "
                   "previous round's hard negatives from the labelled frames (default %(default)s)")
    p.add_argument("--epochs", type=_positive_int, default=8, help="convnet: epochs a round (default %(default)s)")
    _add_traffic(p, learned=True, default="right")
    p.add_argument("--json", action="store_true", help="print the report as one JSON object on stdout (the human lines go to stderr)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing model file")
    _add_feature_options(p)
    _add_common(p)


def _add_refine(sub) -> None:
    p = sub.add_parser(
        "refine",
        help="fit a model's box refinement to hand-labelled frames of your own camera (no training data needed)",
        description="Fits the box refinement (the map from a hot window's features to its car's four edges) to the cars "
        "of hand-labelled frames of your camera, and saves the model with it; the classifier, the search plan and the "
        "tracker settings stay the base model's. A refinement fitted to one camera fits another camera's cars poorly "
        "(writeup 3.4): label about 25 frames of yours with 50 cars or more (format: dev_set/README.md); far fewer "
        "cars fit worse than the base model. Never pass frames you score later.",
    )
    p.add_argument("--labels", required=True, nargs="+", metavar="L.json", help="annotation JSON file(s) of your camera's frames")
    p.add_argument("--out", required=True, metavar="MODEL.npz", help="where to save the refined model")
    p.add_argument("--model", default=None, help="base model file (default: the embedded model)")
    p.add_argument("--alpha", type=_alpha, default=None,
                   help=f"ridge penalty of the refinement, {MIN_ALPHA:g} to {MAX_ALPHA:g} (default: the base model's, else {REFINE_ALPHA:g})")
    p.add_argument("--mirror", action=argparse.BooleanOptionalAction, default=None,
                   help="also learn from the frames flipped left to right, for left-hand and right-hand traffic alike "
                        "(default: as the base model's refinement was fitted)")
    _add_traffic(p, learned=True, default="the base model's setting")
    p.add_argument("--json", action="store_true", help="print a summary as one JSON object on stdout (the human lines go to stderr)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing model file (never an input)")
    _add_common(p)


def _add_sweep(sub) -> None:
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


def _add_calibrate(sub) -> None:
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
    p.add_argument("--out", default="camera.json",
                   help="camera file to write (JSON; default %(default)s in the current folder, refused if it exists "
                   "without --overwrite)")
    p.add_argument("--pattern", default="9x6", help="inner corners per row x per column (default %(default)s)")
    p.add_argument("--straight", nargs="+", default=[], metavar="IMG",
                   help="frames of a straight road with both lane lines, for the bird's-eye transform (e.g. straight_lines1.jpg straight_lines2.jpg)")
    p.add_argument("--json", action="store_true", help="print the report as one JSON object on stdout (the human lines go to stderr)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing camera file")
    _add_common(p)


def _add_detect(sub) -> None:
    p = sub.add_parser(
        "detect", help="detect vehicles in images, folders of images, and videos",
        description="Detect and track vehicles. One INPUT (an image, a folder of images or a video) writes its "
        "outputs together into the current folder (or --out-dir DIR, or the folder of --out, named after it); "
        "--boxes, --lanes-csv and --save-camera PATH name one output each. Several inputs, globs, folders of videos, "
        "or any of the batch options (--jobs, --skip-existing, --table, --scheduler, --chunk-frames) run a batch: "
        "each input is processed on its own, with the same options as one input, a failing one is reported by name "
        "and the others go on; the exit status is 7 when some failed (or the input's own code with one input).",
    )
    p.add_argument("inputs", nargs="+", metavar="INPUT", help="image, folder of images or videos, video, or glob pattern")
    p.add_argument("--out", default=None, help="annotated output of a single input (default: NAME_detected in the current folder); the other "
                   "outputs go beside it, named after it (OUT_boxes.csv, ...)")
    p.add_argument("--boxes", default=None, help="CSV of boxes of a single input (default: NAME_boxes.csv with the other outputs)")
    p.add_argument("--out-dir", default=None, metavar="DIR", help="write every input's outputs into DIR (default: the current folder; default names)")
    p.add_argument("--no-video", action="store_true", help="write the tables only: no annotated video or images")
    p.add_argument("--start", type=int, default=None, metavar="A", help="first decoded frame (default 0)")
    p.add_argument("--end", type=int, default=None, metavar="B", help="stop before this decoded frame (default: the end)")
    p.add_argument("--frames", default=None, metavar="A-B", help="decoded frames A to B inclusive (instead of --start/--end)")
    p.add_argument("--format", default="csv", metavar="FMT[,FMT]",
                   help="tables per input: csv (default), parquet (needs pyarrow), mot (MOTChallenge text), coco (COCO "
                   "JSON, images only), lanes (the lanes CSV, NAME_lanes.csv; finds lanes); comma-separated for several")
    b = p.add_argument_group("batches")
    b.add_argument("--jobs", type=_positive_int, default=1, metavar="N",
                   help="process N inputs at once in N processes, sharing the cores between them (default %(default)s)")
    b.add_argument("--skip-existing", action="store_true", help="skip an input whose outputs all exist (rewrite nothing)")
    b.add_argument("--table", default=None, metavar="ALL.parquet", help="also one Parquet table of all inputs, with a video column")
    b.add_argument("--scheduler", default=None, metavar="ADDRESS",
                   help="run one task per input on a dask.distributed cluster (needs vehicle-detection[distributed])")
    b.add_argument("--scheduler-timeout", type=_positive_float, default=None, metavar="SECONDS",
                   help="with --scheduler: wait this long for the scheduler to answer (default 10); exit 8 when it does not")
    b.add_argument("--chunk-frames", type=_positive_int, default=None, metavar="N",
                   help="with --scheduler and --no-video: split each video into chunks of N frames (the tracker continues across)")
    p.add_argument("--model", default=None, help="model file (default: the embedded model)")
    p.add_argument("--horizon", type=_horizon, default=None, metavar="FRACTION|auto|plan",
                   help="the camera's horizon (where the road vanishes), as a fraction of the frame height from the top; "
                   "'auto' estimates it from the footage, 'plan' keeps the search bands where the model's plan has them "
                   "(made for the project camera, whose horizon is 0.583). Default: the model's setting (auto)")
    _add_traffic(p)
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
    p.add_argument("--lanes", action="store_true",
                   help="find and draw the lane, its radius and the car's offset; boxes get distances. The road plane "
                   "(bird's-eye view) is the --camera file's when it has one, else estimated from each input's own frames "
                   "(printed); an input without visible lane lines runs without lanes, saying so")
    p.add_argument("--lanes-csv", default=None, metavar="L.csv",
                   help="write frame,curvature_m,offset_m per frame of a single input (implies --lanes; a batch: --format lanes)")
    p.add_argument("--save-camera", nargs="?", const="", default=None, metavar="C.json",
                   help="save the road plane estimated from the footage of a single input as a camera file, for "
                   "--camera C.json next time (default: NAME_camera.json with the other outputs; implies --lanes; "
                   "written only when a plane is found)")
    p.add_argument("--dash-period", type=_dash_period, default=None, metavar="M",
                   help="lanes without a camera file: metres from the start of one dash of a lane line to the start of "
                   "the next, which sets the scale along the road, so the distances (default 12: a US lane line, 10 ft of "
                   "paint and 30 ft of gap; Californian freeways are often striped 12 ft on 48 ft: 14.6)")
    p.add_argument("--report", action="store_true",
                   help="also write NAME_report.html per input, beside its outputs: track timeline, contact sheet, boxes "
                   "per frame, distances and lanes (needs vehicle-detection[report])")
    p.add_argument("--json", action="store_true",
                   help="print one JSON object on standard output (each input's summary, notes and road estimate); the "
                   "human lines go to standard error")
    p.add_argument("--no-progress", action="store_true")
    _add_common(p)


def _add_report(sub) -> None:
    p = sub.add_parser(
        "report", help="write the HTML page of a run from its boxes CSV",
        description="One self-contained HTML page (figures as embedded PNGs, no script, nothing fetched): a track "
        "timeline, a contact sheet of every track's first, middle and last box (cut from --video), boxes per frame, "
        "each car's distance (a run with distances) and the lane's radius and offset (--lanes). Needs "
        "vehicle-detection[report] (matplotlib).",
    )
    p.add_argument("boxes", metavar="RUN_CSV", help="the boxes CSV of a detect run (NAME_boxes.csv, or --boxes)")
    p.add_argument("--video", default=None, metavar="V", help="the video the boxes are of: the contact sheet's pictures")
    p.add_argument("--lanes", default=None, metavar="L.csv", help="the run's lanes CSV (--lanes-csv, --format lanes)")
    p.add_argument("--out", default=None, metavar="R.html", help="the page to write (default: NAME_report.html beside RUN_CSV)")
    p.add_argument("--title", default=None, help="the page's heading (default: the video's or the CSV's name)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing page")
    p.add_argument("--json", action="store_true", help="print one JSON object naming the page written")
    _add_common(p)


def _add_evaluate(sub) -> None:
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
    _add_traffic(p)
    p.add_argument("--camera", default=None, metavar="CAMERA.json",
                   help="undistort every frame with this camera file before the search (the boxes are mapped back to the "
                   "original frames, where the labels are, before scoring)")
    p.add_argument("--json", action="store_true",
                   help="print the scores as one JSON object on stdout: files, cameras, all (the human lines go to stderr)")
    p.add_argument("--report", default=None, metavar="DIR",
                   help="write into DIR (created) cameras.md and cameras.csv, the scores of each camera, and per camera a "
                   "contact sheet failures_<camera>.png of every miss, false positive and loose match (at most 60 tiles)")
    p.add_argument("--overwrite", action="store_true", help="write into a --report folder that is not empty (replacing its files of the same names)")
    p.add_argument("--no-progress", action="store_true")
    _add_common(p)


def _add_mine_negatives(sub) -> None:
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
    _add_traffic(p)
    p.add_argument("--frames", default=None, metavar="RANGES",
                   help="only these frame indexes, e.g. 0-89,160-250 (inclusive; default all)")
    p.add_argument("--every", type=_positive_int, default=1, metavar="K", help="search every K-th frame (default %(default)s)")
    p.add_argument("--threshold", type=_finite_float, default=None,
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
    p.add_argument("--json", action="store_true", help="print the counts as one JSON object on stdout (the human lines go to stderr)")
    p.add_argument("--no-progress", action="store_true")
    _add_common(p)
