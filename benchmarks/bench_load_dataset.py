"""Loading the training archives: one decoding thread against several, alternately, in one process.

    python benchmarks/bench_load_dataset.py [DATA_DIR] [--threads N] [--runs R]

DATA_DIR defaults to ``$VEHICLE_DETECTION_DATA`` or ``../shared/data`` (the folder holding
``vehicles.zip`` and ``non-vehicles.zip``). Each run loads the set with ``n_jobs=1`` (the
default, the reference) and then with ``n_jobs=N`` (default 4), and prints the wall time and the
CPU time of the process for each, and their ratio; then the range of each over the runs.
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

from vehicle_detection.training.data import DATA_ENV, load_dataset


def _timed(data_dir, n_jobs: int) -> tuple[float, float, int]:
    wall, cpu = time.perf_counter(), time.process_time()
    n = len(load_dataset(data_dir, n_jobs=n_jobs))
    return time.perf_counter() - wall, time.process_time() - cpu, n


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data_dir", nargs="?", default=None)
    parser.add_argument("--threads", type=int, default=4)
    parser.add_argument("--runs", type=int, default=2)
    args = parser.parse_args()
    shared = Path(__file__).resolve().parents[2] / "shared" / "data"
    data_dir = args.data_dir or os.environ.get(DATA_ENV) or shared
    rows = {1: [], args.threads: []}
    for run in range(1, args.runs + 1):
        for n_jobs in rows:
            wall, cpu, n = _timed(data_dir, n_jobs)
            rows[n_jobs].append((wall, cpu))
            print(f"run {run}: n_jobs={n_jobs}: {n} patches, {wall:.2f} s wall, {cpu:.2f} s CPU")
        (w1, c1), (wn, cn) = rows[1][-1], rows[args.threads][-1]
        print(f"run {run}: n_jobs={args.threads} / n_jobs=1: wall x{wn / w1:.2f}, CPU x{cn / c1:.2f}")
    for n_jobs, r in rows.items():
        walls, cpus = [w for w, _ in r], [c for _, c in r]
        print(f"n_jobs={n_jobs} over {len(r)} runs: wall {min(walls):.2f} to {max(walls):.2f} s, "
              f"CPU {min(cpus):.2f} to {max(cpus):.2f} s")


if __name__ == "__main__":
    main()
