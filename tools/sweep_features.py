"""Score the feature configurations of notebook 3 on the full training set (random and grouped splits).

    python tools/sweep_features.py --data-dir ../shared/data [--subsample N] [--jobs 2] [--json]

The configurations are :func:`vehicle_detection.viz.plots.showcase_configs` (the classic RGB / HLS /
YCrCb HOG choices, signed orientations and the embedded model's configuration): a curated list,
where ``vehicle-detection sweep`` scores the product of the options it is given.
Each is scored by :func:`vehicle_detection.classifier.sweep` with the library's default C;
prints a Markdown table sorted by grouped-split accuracy (or JSON rows with ``--json``).
"""

from __future__ import annotations

import argparse
import json
import sys
import time


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data-dir", default=None, help="folder with vehicles.zip and non-vehicles.zip (default: $VEHICLE_DETECTION_DATA or ./data)")
    ap.add_argument("--subsample", type=int, default=None, help="use this many patches (stratified) for a quick look")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--json", action="store_true", help="one JSON row per line instead of a table")
    args = ap.parse_args(argv)

    import numpy as np

    from vehicle_detection.viz import plots
    from vehicle_detection.classifier import DEFAULT_C, load_default_model
    from vehicle_detection.training.fit import split_indices, sweep
    from vehicle_detection.training.data import load_dataset

    ds = load_dataset(args.data_dir)
    if args.subsample and args.subsample < len(ds):
        _, keep = split_indices(ds.labels, test_size=args.subsample / len(ds), random_state=0)
        ds = ds.subset(np.sort(keep))
    configs = plots.showcase_configs(load_default_model().config)
    t = time.perf_counter()
    rows = sweep(ds, configs, C=DEFAULT_C, n_jobs=args.jobs)
    print(f"{len(configs)} configurations on {len(ds):,} patches in {time.perf_counter() - t:.0f} s", file=sys.stderr)
    if args.json:
        for r in rows:
            print(json.dumps(r))
        return 0
    for r in rows:
        r["name"] = plots.sweep_label(r)
    print(plots.markdown_table(rows, [
        ("name", "configuration", ""), ("n_features", "features", ","), ("random_accuracy", "random split", ".4f"),
        ("grouped_accuracy", "grouped split", ".4f"), ("feature_seconds", "feature s", ".1f"),
        ("grouped_fit_seconds", "fit s", ".1f"),
    ]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
