"""``vehicle-detection sweep``: feature configurations compared on the random and grouped splits."""

from __future__ import annotations

import json
import sys

import numpy as np

from ..classifier import DEFAULT_C
from ..errors import UsageError
from ..training.data import CLASSES, MIN_IMAGES_PER_CLASS, check_split_sizes, default_data_dir, load_dataset
from ..training.fit import split_indices, sweep, sweep_configs
from .options import csv_ints

__all__ = ["run"]


def run(args) -> int:
    try:
        pairs = [tuple(int(v) for v in p.lower().split("x")) for p in args.color_features.split(",") if p.strip()]
        if any(len(p) != 2 for p in pairs):
            raise ValueError
    except ValueError:
        raise UsageError(f"--color-features: expected pairs like 16x16,0x0, got {args.color_features!r}") from None
    try:
        configs = sweep_configs(
            color_spaces=tuple(c.strip() for c in args.color_spaces.split(",") if c.strip()),
            hog_channels=tuple(tuple(csv_ints(s, "hog-channels")) for s in args.hog_channels.split(";") if s.strip()),
            orientations=tuple(csv_ints(args.orientations, "orientations")),
            pixels_per_cell=tuple(csv_ints(args.pixels_per_cell, "pixels-per-cell")),
            cells_per_block=tuple(csv_ints(args.cells_per_block, "cells-per-block")),
            color_features=tuple(pairs),
            signed=tuple(bool(v) for v in csv_ints(args.signed, "signed")),
            hog_sqrt=tuple(bool(v) for v in csv_ints(args.hog_sqrt, "hog-sqrt")),
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
