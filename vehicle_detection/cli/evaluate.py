"""``vehicle-detection evaluate``: the detector (or a boxes CSV) scored against hand-labelled frames."""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import numpy as np

from ..errors import InputError, UsageError
from ..io.tables import read_boxes_csv
from ..io.images import image_size, list_images
from ..io.video import probe_video
from ..metrics.detection import check_boxes_inside, evaluation_report, load_annotations, pool_by_camera, pool_reports
from ..metrics.reporting import ReportSource, check_report_dir, labels_camera, write_evaluation_report
from ..metrics.runner import evaluate_labelled
from .options import human_print, load_camera, load_detector

__all__ = ["run"]


def _print_report(name: str, r: dict, say=print) -> None:
    say(f"{name}: {r['n_frames']} frames, {r['n_cars']} cars")
    for key in ("at_iou_0.5", "at_iou_0.7"):
        s = r[key]
        say(
            f"  IoU >= {key[-3:]}: precision {s['precision']:.3f}  recall {s['recall']:.3f}  F1 {s['f1']:.3f}  "
            f"mean IoU {s['mean_iou']:.3f}  (tp {s['tp']}, fp {s['fp']}, fn {s['fn']}, ignored {s['ignored']})"
        )
    extra = f"  AP50 {r['ap50']:.3f}" if "ap50" in r else " "
    if "fp_per_minute" in r:
        extra += f"  false positives per minute {r['fp_per_minute']:.1f}"
    say(extra)
    if "tracking" in r:
        t = r["tracking"]
        say(f"  tracking: MOTA {t['mota']:.3f}  IDF1 {t['idf1']:.3f}  HOTA {t['hota']:.3f}  (DetA {t['deta']:.3f}, AssA {t['assa']:.3f}, id switches {t['id_switches']})")


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


def _check_fit(labels, found, source: Path, boxes_csv) -> None:
    """With ``--boxes`` no frame is decoded: the labels and the CSV are checked against the
    labelled video's (or image folder's) frame count and frame size as the detector's run
    checks them, so that labels of another video, or rows of another run, are refused rather
    than scored as misses.

    Raises
    ------
    InputError
        A labelled frame or a CSV row beyond the footage's frames, or a labelled box beyond its
        frame.
    """
    if source.is_dir():
        images = list_images(source)
        n, sizes = len(images), {}
        count = str(n)
        for i in labels.frames:
            if i < n:
                sizes[i] = image_size(images[i])
    else:
        info = probe_video(source)
        # the container's count is a plausibility bound (an edit list can hide a few frames)
        n = None if info.n_frames is None else math.ceil(info.n_frames * 1.01) + 2
        count = f"about {info.n_frames}"
        sizes = dict.fromkeys(labels.frames, (info.width, info.height))
    if n is not None:
        beyond = sorted(i for i in labels.frames if i >= n)
        if beyond:
            raise InputError(f"{labels.path}: labels frame {beyond[0]}, but {source} has {count} frames; wrong video or labels?")
        rows = np.asarray(found.frame)
        if rows.size and rows.max() >= n:
            raise InputError(f"{boxes_csv}: a row at frame {int(rows.max())}, but {source} has {count} frames; boxes of another video?")
    for i, (w, h) in sizes.items():
        check_boxes_inside(labels, w, h, frames=[i], source=source)


def run(args) -> int:
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
    if args.traffic and args.boxes:
        raise UsageError("--traffic applies when the detector runs, not to --boxes")
    sources = _evaluate_sources(args, all_labels)
    if args.report:
        check_report_dir(args.report, overwrite=args.overwrite)
    detector = None if args.boxes else load_detector(args.model, args.horizon, traffic=args.traffic)
    camera = load_camera(args.camera)
    say = human_print(args)
    t = time.perf_counter()
    reports, items = {}, []
    for labels in all_labels:
        name, source = str(labels.path), sources[str(labels.path)]
        if args.boxes:
            found = read_boxes_csv(args.boxes)
            if source is not None and source.exists():
                _check_fit(labels, found, source, args.boxes)
            reports[name] = evaluation_report(found, labels)
        else:
            reports[name], found = evaluate_labelled(labels, detector, source=source, camera=camera, progress=not args.no_progress)
        _print_report(name, reports[name], say)
        items.append(ReportSource(labels, found, source, labels_camera(labels, source)))
    cameras = {str(it.annotations.path): it.camera for it in items}
    by_camera = pool_by_camera(reports, cameras)
    pooled = pool_reports(reports.values())
    _print_pooled(by_camera, pooled, len(reports), say)
    say(f"scored in {time.perf_counter() - t:.1f} s")
    if args.report:
        _write_evaluate_report(args, items, by_camera, pooled, sources, say)
    if args.json:
        print(json.dumps(_evaluate_json(reports, cameras, by_camera, pooled)))
    return 0


def _print_pooled(by_camera: dict, pooled: dict, n_files: int, say=print) -> None:
    """A block per camera (when a camera has several files, or there are several cameras), then "all"."""
    if len(by_camera) > 1 or n_files > len(by_camera):
        for cam, p in by_camera.items():
            _print_report(f"camera {cam}", {k: v for k, v in p.items() if k != "labels"}, say)
    if n_files > 1:
        _print_report("all", pooled, say)


def _write_evaluate_report(args, items, by_camera: dict, pooled: dict, sources: dict, say=print) -> None:
    inputs = [*args.labels, *(s for s in sources.values() if s is not None), *filter(None, [args.boxes, args.model, args.camera])]
    written = write_evaluation_report(args.report, items, by_camera, pooled, overwrite=args.overwrite, inputs=inputs)
    for file, counts in written.items():
        extra = f" ({counts['shown']} tiles, {counts['left_out']} left out)" if counts else ""
        say(f"report: {Path(args.report) / file}{extra}")


def _evaluate_json(reports: dict, cameras: dict, by_camera: dict, pooled: dict) -> dict:
    """``evaluate --json``: one schema at every level.

    ``{"files": {labels: S + camera}, "cameras": {camera: S + labels}, "all": S}``, where each
    ``S`` holds ``n_frames``, ``n_cars``, ``at_iou_0.5`` and ``at_iou_0.7`` (``precision``,
    ``recall``, ``f1``, ``mean_iou``, ``tp``, ``fp``, ``fn``, ...) and, where they apply,
    ``ap50``, ``fp_per_minute`` and ``tracking``.
    """
    files = {name: {**r, "camera": cameras[name]} for name, r in reports.items()}
    return {"files": files, "cameras": dict(by_camera), "all": dict(pooled)}
