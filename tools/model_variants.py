"""Score variants of the embedded model, camera by camera (writeup 3.4's tables).

    python tools/model_variants.py VARIANT [VARIANT ...] [--group NAME LABELS [LABELS ...]]...

A VARIANT is one of:

* ``embedded``: the model as shipped;
* comma-separated ``field=value`` pairs of :class:`vehicle_detection.tracker.TrackerConfig`, e.g.
  ``motion=0.1`` or ``smoothing=0.7,motion=0.2``: the embedded model with those tracker settings;
* ``refine=L1.json+L2.json``: the embedded model with its box refinement fitted again on those
  labels files only (:func:`vehicle_detection.training.with_box_refinement`, as ``train --labels``
  fits it), e.g. on one camera's frames to score it on another camera it never saw.

For each, the model is saved into a temporary folder, and every group of labels files is scored
by the command line, as a user would::

    vehicle-detection evaluate --labels LABELS... --model M --json

One line per setting and group: F1 at IoU 0.5 and 0.7, the mean IoU of matched boxes, and HOTA
(AssA) where the labels carry track ids. The default groups are the tune frames of both dev
cameras; score held-out frames only once a setting has been chosen on these.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
DEV = REPO / "dev_set"
GROUPS = {
    "project tune": [DEV / "clip_A.json", DEV / "test_video.json", DEV / "test_images.json", DEV / "clip_A_tracks.json"],
    "highway tune": [DEV / "highway_dashcam_tune.json"],
}


def model_with(setting: str, folder: Path) -> Path | None:
    """The embedded model saved as ``setting`` says (see the module); None for ``embedded``."""
    if setting == "embedded":
        return None
    import vehicle_detection as vd

    model = vd.load_default_model()
    path = folder / f"model_{len(list(folder.iterdir()))}.npz"
    if setting.startswith("refine="):
        from vehicle_detection.training import with_box_refinement

        files = [Path(p) for p in setting.removeprefix("refine=").split("+") if p]
        if not files:
            raise SystemExit(f"{setting!r}: refine= takes labels files joined by '+'")
        old = model.metrics.get("box_refinement", {})  # refit as the embedded model was fitted
        options = {"alpha": old["alpha"]} if "alpha" in old else {}
        cfg = model.detector_config.tracker
        model = with_box_refinement(model, [vd.load_annotations(p) for p in files], cluster_iou=cfg.cluster_iou, box_vote=cfg.box_vote, **options)
        model.save(path)
        return path
    config = model.detector_config
    changes = {}
    for pair in setting.split(","):
        name, _, value = pair.partition("=")
        if not value:
            raise SystemExit(f"{setting!r}: each setting is field=value (e.g. motion=0.1)")
        changes[name.strip()] = float(value)
    try:
        tracker = dataclasses.replace(config.tracker, **changes)
    except TypeError as exc:
        raise SystemExit(f"{setting!r}: {exc}") from None
    model.replace(detector_config=config.replace(tracker=tracker)).save(path)
    return path


def evaluate(labels: list[Path], model: Path | None) -> str:
    cmd = [sys.executable, "-m", "vehicle_detection.cli", "evaluate", "--labels", *map(str, labels), "--json", "--no-progress"]
    if model is not None:
        cmd += ["--model", str(model)]
    done = subprocess.run(cmd, capture_output=True, text=True, cwd=REPO)
    if done.returncode:
        raise SystemExit(f"evaluate failed ({done.returncode}): {done.stderr.strip()}")
    report = json.loads(done.stdout)
    a, b = report["all"]["at_iou_0.5"], report["all"]["at_iou_0.7"]
    line = f"F1 {a['f1']:.3f} / {b['f1']:.3f}, mean IoU {a['mean_iou']:.3f} (tp {a['tp']}, fp {a['fp']}, fn {a['fn']})"
    tracks = [f["tracking"] for f in report["files"].values() if "tracking" in f]
    for t in tracks:
        line += f"; HOTA {t['hota']:.3f} (AssA {t['assa']:.3f})"
    return line


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("settings", nargs="+", metavar="VARIANT",
                    help="'embedded', field=value[,field=value...] of TrackerConfig, or refine=L1.json[+L2.json...]")
    ap.add_argument("--group", nargs="+", action="append", metavar=("NAME", "LABELS"),
                    help="a name and its labels files (repeatable); default: the tune frames of both dev cameras")
    args = ap.parse_args(argv)
    groups = {g[0]: [Path(p) for p in g[1:]] for g in args.group} if args.group else GROUPS
    if any(not files for files in groups.values()):
        raise SystemExit("--group takes a name and at least one labels file")
    with tempfile.TemporaryDirectory() as tmp:
        for setting in args.settings:
            model = model_with(setting, Path(tmp))
            for name, files in groups.items():
                print(f"{setting:28s} {name:14s} {evaluate(files, model)}", flush=True)


if __name__ == "__main__":
    main()
