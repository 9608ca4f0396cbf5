"""What one model's search costs against another's: the search alone, alternately, in one process.

    python tools/plan_cost.py MODEL_A MODEL_B [--rounds 4] [--frames 40]

Searches the first ``--frames`` frames of clip A (``dev_set/project_video_clip_A.mp4``, frames in
memory, one thread) with each model's own plan, the two models alternating round by round (A B,
B A, ...), and prints milliseconds a frame of each round and the ratio A / B of each round. For
two plans of one classifier, save the other plan with the model (e.g. the embedded model before
a plan change: ``git show REV:vehicle_detection/models/default.npz > before.npz``).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("model_a", type=Path)
    ap.add_argument("model_b", type=Path)
    ap.add_argument("--rounds", type=int, default=4)
    ap.add_argument("--frames", type=int, default=40)
    args = ap.parse_args()

    import vehicle_detection as vd
    from vehicle_detection.search import search

    models = {"A": vd.VehicleClassifier.load(args.model_a), "B": vd.VehicleClassifier.load(args.model_b)}
    frames = []
    for frame in vd.read_frames(REPO / "dev_set" / "project_video_clip_A.mp4"):
        frames.append(frame)
        if len(frames) >= args.frames:
            break
    for model in models.values():
        search(frames[0], model)  # kernels loaded, work arrays made
    ms = {"A": [], "B": []}
    for r in range(args.rounds):
        for name in ("AB" if r % 2 == 0 else "BA"):
            t = time.perf_counter()
            for frame in frames:
                search(frame, models[name])
            ms[name].append(1000 * (time.perf_counter() - t) / len(frames))
    for name, path in (("A", args.model_a), ("B", args.model_b)):
        print(f"{name} ({path.name}): {' '.join(f'{x:.1f}' for x in ms[name])} ms a frame")
    print(f"ratio A / B, round by round: {' '.join(f'{a / b:.3f}' for a, b in zip(ms['A'], ms['B']))}")


if __name__ == "__main__":
    main()
