"""Score variants of the embedded model, camera by camera (the tables of docs/experiments.md).

    python tools/model_variants.py VARIANT [VARIANT ...] [--group NAME LABELS [LABELS ...]]...

A VARIANT is ``embedded`` (the model as shipped) or comma-separated ``key=value`` pairs applied to
the embedded model:

* fields of :class:`vehicle_detection.tracker.TrackerConfig`, e.g. ``motion=0.1`` or
  ``smoothing=0.7,motion=0.2``: those tracker settings;
* ``refine=L1.json+L2.json``: the box refinement fitted again on those labels files only
  (:func:`vehicle_detection.training.with_box_refinement`, as ``train --labels`` fits it), e.g. on
  one camera's frames, to score it on a camera it never saw; ``refine_alpha=A`` sets its ridge
  penalty (default: the embedded refinement's); ``refine=none``: no refinement, but the fixed
  window inset of the models before it (``TrackerConfig``'s default) and no blob splitting or box
  voting;
* ``side_fit=none``: the boxes reported as the heat and the tracker give them, their sides not
  fitted to the frame (:func:`vehicle_detection.refine.fit_sides`); ``side_reach=R`` and
  ``side_prior=P``: the sides fitted with those :class:`vehicle_detection.refine.SideFit` fields;
* ``shot_cuts=none`` or ``shot_cuts=on``: the video tracked as one shot, or the tracker started
  afresh at each cut between shots (:mod:`vehicle_detection.footage.shots`, default settings);
* ``exposure=none`` or ``exposure=on``: dark footage searched as it is, or brightened
  (:mod:`vehicle_detection.footage.exposure`, default settings);
* ``car_horizon=none`` or ``car_horizon=on``: the horizon from the road's lines only, or also
  from the cars where the lines give none (:class:`vehicle_detection.footage.horizon.CarHorizon`);
  ``car_margin=M``: the smallest margin of a window that counts there (its ``min_margin``);
* ``car_candidates=A+B+...``: the candidate horizons the cars are searched at (its ``candidates``,
  fractions of the picture height);
* ``full_search_every=N``, ``edge_width=W``, ``horizon_height=H``, ``track_margin=M``: the search
  schedule's fields of :class:`vehicle_detection.search.SearchPlan` (N above 1 searches whole
  frames every N frames and, in between, only the edges, the horizon and around the tracks);
* ``band_top_K=ROW``: the band of the plan's scale K (0 for the smallest windows) starts at
  ``ROW`` (rows of the plan's reference height, before the horizon moves the bands), e.g.
  ``band_top_3=336``; ``scales=K+K+...``: only those scales of the plan are searched (e.g.
  ``scales=0+2+3+4+5`` leaves out the 96-pixel windows).

For each, the model is saved into a temporary folder, and every group of labels files is scored
by the command line, as a user would::

    vehicle-detection evaluate --labels LABELS... --model M --json

One line per variant and group: F1 at IoU 0.5 and 0.7, the mean IoU of matched boxes, and HOTA
(AssA) where the labels carry track ids. The default groups are the tune frames of both dev
cameras; score held-out frames only once a variant has been chosen on these.
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
    "highway tune": [DEV / "highway_dashcam_tune.json", DEV / "highway_dashcam_tune_extra.json"],
}

PLAN_FIELDS = {"full_search_every": int, "edge_width": int, "horizon_height": int, "track_margin": float}


def _number(variant: str, value: str, kind=float):
    """``kind(value)``; a value that is no number ends the run with one line naming the variant."""
    try:
        return kind(value)
    except ValueError as exc:
        raise SystemExit(f"{variant!r}: {exc}") from None


def _replaced(variant: str, settings, **changes):
    """``dataclasses.replace(settings, **changes)``; a value the settings refuse ends the run
    with one line naming the variant."""
    try:
        return dataclasses.replace(settings, **changes)
    except (TypeError, ValueError) as exc:
        raise SystemExit(f"{variant!r}: {exc}") from None


def model_with(variant: str, folder: Path) -> Path | None:
    """The embedded model saved as ``variant`` says (see the module); None for ``embedded``."""
    if variant == "embedded":
        return None
    import vehicle_detection as vd

    model = vd.load_default_model()
    pairs = {}
    for pair in variant.split(","):
        name, _, value = pair.partition("=")
        if not value:
            raise SystemExit(f"{variant!r}: each part is key=value (e.g. motion=0.1)")
        pairs[name.strip()] = value.strip()
    refine = pairs.pop("refine", "")
    side_fit = pairs.pop("side_fit", None)
    if side_fit not in (None, "none"):
        raise SystemExit(f"{variant!r}: side_fit takes only 'none' (the embedded model fits the sides)")
    sides = {field: _number(variant, pairs.pop(f"side_{field}")) for field in ("reach", "prior") if f"side_{field}" in pairs}
    if sides and side_fit == "none":
        raise SystemExit(f"{variant!r}: side_fit=none and side_reach/side_prior do not go together")
    schedule = {name: pairs.pop(name) for name in PLAN_FIELDS if name in pairs}
    switches = {name: pairs.pop(name, None) for name in ("shot_cuts", "exposure", "car_horizon")}
    car_margin = _number(variant, pairs.pop("car_margin")) if "car_margin" in pairs else None
    candidates = pairs.pop("car_candidates", None)
    tops = {name: pairs.pop(name) for name in list(pairs) if name.startswith("band_top_")}
    kept = pairs.pop("scales", None)
    for name, value in switches.items():
        if value not in (None, "none", "on"):
            raise SystemExit(f"{variant!r}: {name} takes 'none' or 'on'")
    files = [] if refine == "none" else [Path(p) for p in refine.split("+") if p]
    alpha = pairs.pop("refine_alpha", None)
    if alpha is not None and not files:
        raise SystemExit(f"{variant!r}: refine_alpha needs refine=LABELS")
    config = model.detector_config
    tracker = _replaced(variant, config.tracker, **{k: _number(variant, v) for k, v in pairs.items()})
    path = folder / f"model_{len(list(folder.iterdir()))}.npz"
    if files:  # refit by the command line, as a user would (the embedded model's penalty unless told)
        cli("refine", "--labels", *map(str, files), "--out", str(path), *(["--alpha", alpha] if alpha is not None else []))
        model = vd.VehicleClassifier.load(path)
    if refine == "none":
        from vehicle_detection.tracker import TrackerConfig

        tracker = dataclasses.replace(tracker, window_inset=TrackerConfig().window_inset, cluster_iou=0.0)
        model = model.replace(box_regressor=None)
    model = model.replace(detector_config=model.detector_config.replace(tracker=tracker))
    if side_fit == "none":
        model = model.replace(detector_config=model.detector_config.replace(side_fit=None))
    elif sides:
        fit = _replaced(variant, model.detector_config.side_fit, **sides)
        model = model.replace(detector_config=model.detector_config.replace(side_fit=fit))
    defaults = vd.DetectorConfig()  # shot_cuts=on, exposure=on, car_horizon=on: the default settings
    for name, value in switches.items():
        if value is not None:
            setting = None if value == "none" else getattr(defaults, name)
            model = model.replace(detector_config=model.detector_config.replace(**{name: setting}))
    rule_changes = {}  # of the horizon from the cars
    if car_margin is not None:
        rule_changes["min_margin"] = car_margin
    if candidates is not None:
        rule_changes["candidates"] = tuple(_number(variant, v) for v in candidates.split("+"))
    if rule_changes:
        rule = model.detector_config.car_horizon
        if rule is None:
            names = [n for n, v in (("car_margin", car_margin), ("car_candidates", candidates)) if v is not None]
            raise SystemExit(f"{variant!r}: {' and '.join(names)} need{'s' if len(names) == 1 else ''} "
                             "the horizon from the cars (car_horizon=on)")
        model = model.replace(detector_config=model.detector_config.replace(car_horizon=_replaced(variant, rule, **rule_changes)))
    plan = model.detector_config.plan
    if schedule:
        plan = _replaced(variant, plan, **{k: _number(variant, v, PLAN_FIELDS[k]) for k, v in schedule.items()})
    if tops or kept is not None:
        scales = list(plan.scales)
        for name, row in tops.items():
            k = _number(variant, name.removeprefix("band_top_"), int)
            if not 0 <= k < len(scales):
                raise SystemExit(f"{variant!r}: the plan has scales 0 to {len(scales) - 1}, not {k}")
            scales[k] = _replaced(variant, scales[k], y_start=_number(variant, row, int))
        if kept is not None:  # after band_top_K, which counts the plan's own scales
            index = [_number(variant, k, int) for k in kept.split("+")]
            if not index or any(not 0 <= k < len(scales) for k in index):
                raise SystemExit(f"{variant!r}: the plan has scales 0 to {len(scales) - 1}")
            scales = [scales[k] for k in sorted(set(index))]
        plan = _replaced(variant, plan, scales=tuple(scales))
    if plan is not model.detector_config.plan:
        model = model.replace(detector_config=model.detector_config.replace(plan=plan))
    model.save(path, overwrite=True)
    return path


def cli(*args: str) -> str:
    """Run ``vehicle-detection ARGS`` from the repository; its standard output."""
    done = subprocess.run([sys.executable, "-m", "vehicle_detection.cli", *args], capture_output=True, text=True, cwd=REPO)
    if done.returncode:
        raise SystemExit(f"{args[0]} failed ({done.returncode}): {done.stderr.strip()}")
    return done.stdout


def evaluate(labels: list[Path], model: Path | None) -> str:
    report = json.loads(cli("evaluate", "--labels", *map(str, labels), "--json", "--no-progress", *(["--model", str(model)] if model else [])))
    a, b = report["all"]["at_iou_0.5"], report["all"]["at_iou_0.7"]
    line = f"F1 {a['f1']:.3f} / {b['f1']:.3f}, mean IoU {a['mean_iou']:.3f} (tp {a['tp']}, fp {a['fp']}, fn {a['fn']})"
    tracks = [f["tracking"] for f in report["files"].values() if "tracking" in f]
    for t in tracks:
        line += f"; HOTA {t['hota']:.3f} (AssA {t['assa']:.3f})"
    return line


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("variants", nargs="+", metavar="VARIANT",
                    help="'embedded', or key=value[,key=value...]: TrackerConfig fields, refine=L1.json[+L2.json...], refine_alpha=A, side_fit=none, side_reach=R, side_prior=P, shot_cuts=none|on, exposure=none|on, car_horizon=none|on, car_margin=M, car_candidates=A+B+..., full_search_every=N, edge_width=W, horizon_height=H, track_margin=M, band_top_K=ROW, scales=K+K+...")
    ap.add_argument("--group", nargs="+", action="append", metavar=("NAME", "LABELS"),
                    help="a name and its labels files (repeatable); default: the tune frames of both dev cameras")
    args = ap.parse_args(argv)
    groups = {g[0]: [Path(p) for p in g[1:]] for g in args.group} if args.group else GROUPS
    if any(not files for files in groups.values()):
        raise SystemExit("--group takes a name and at least one labels file")
    with tempfile.TemporaryDirectory() as tmp:
        for variant in args.variants:
            model = model_with(variant, Path(tmp))
            for name, files in groups.items():
                print(f"{variant:28s} {name:14s} {evaluate(files, model)}", flush=True)


if __name__ == "__main__":
    main()
