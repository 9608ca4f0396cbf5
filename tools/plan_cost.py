"""What one model's search costs against another's: the search alone, alternately, in one process.

    python tools/plan_cost.py MODEL_A MODEL_B [--rounds 4] [--frames 40]
    python tools/plan_cost.py --scales [MODEL] [--rounds 3] [--frames 30]

Searches the first ``--frames`` frames of clip A (``dev_set/project_video_clip_A.mp4``, frames in
memory, one thread) with each model's own plan, the two models alternating round by round (A B,
B A, ...), and prints milliseconds a frame of each round and the ratio A / B of each round. For
two plans of one classifier, save the other plan with the model (e.g. the embedded model before
a plan change: ``git show REV:vehicle_detection/models/default.npz > before.npz``).

``--scales`` times one model's plan (default: the embedded model's) scale by scale: each scale
searched alone, then all together, round after round, and prints the least milliseconds a frame
of each over the rounds.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("model_a", type=Path, nargs="?")
    ap.add_argument("model_b", type=Path, nargs="?")
    ap.add_argument("--scales", action="store_true", help="one model's plan, scale by scale")
    ap.add_argument("--rounds", type=int, default=None, help="rounds (default 4; 3 with --scales)")
    ap.add_argument("--frames", type=int, default=None, help="frames of clip A (default 40; 30 with --scales)")
    args = ap.parse_args()
    two_models = args.model_a is not None and args.model_b is not None
    if two_models == args.scales:
        ap.error("give two models, or --scales and at most one")
    rounds = args.rounds if args.rounds is not None else (3 if args.scales else 4)

    import vehicle_detection as vd
    from vehicle_detection.search import search

    frames = []
    for frame in vd.read_frames(REPO / "dev_set" / "project_video_clip_A.mp4"):
        frames.append(frame)
        if len(frames) >= (args.frames or (30 if args.scales else 40)):
            break
    if args.scales:
        per_scale(vd.VehicleClassifier.load(args.model_a) if args.model_a else vd.load_default_model(), frames, rounds)
        return
    models = {"A": vd.VehicleClassifier.load(args.model_a), "B": vd.VehicleClassifier.load(args.model_b)}
    for model in models.values():
        search(frames[0], model)  # kernels loaded, work arrays made
    ms = {"A": [], "B": []}
    for r in range(rounds):
        for name in ("AB" if r % 2 == 0 else "BA"):
            t = time.perf_counter()
            for frame in frames:
                search(frame, models[name])
            ms[name].append(1000 * (time.perf_counter() - t) / len(frames))
    for name, path in (("A", args.model_a), ("B", args.model_b)):
        print(f"{name} ({path.name}): {' '.join(f'{x:.1f}' for x in ms[name])} ms a frame")
    print(f"ratio A / B, round by round: {' '.join(f'{a / b:.3f}' for a, b in zip(ms['A'], ms['B']))}")


def per_scale(model, frames: list, rounds: int) -> None:
    """Milliseconds a frame of ``model``'s plan, each scale searched alone and all together (one thread)."""
    import dataclasses

    import cv2

    from vehicle_detection.search import search

    cv2.setNumThreads(1)  # the search's resizes on this thread, as in one search worker
    plan = model.detector_config.plan
    plans = {f"{model.config.window * s.scale:.0f} px": dataclasses.replace(plan, scales=(s,)) for s in plan.scales}
    plans["all"] = plan
    search(frames[0], model, plan)  # kernels loaded, work arrays made
    ms: dict = {name: [] for name in plans}
    for _ in range(rounds):
        for name, p in plans.items():
            t = time.perf_counter()
            for frame in frames:
                search(frame, model, p)
            ms[name].append(1000 * (time.perf_counter() - t) / len(frames))
    print(f"the search alone, one thread, least of {rounds} rounds of {len(frames)} frames of clip A (window sides at 720 rows):")
    for name, xs in ms.items():
        print(f"{name:>7}: {min(xs):.2f} ms a frame")
    print(f"sum of the scales alone: {sum(min(ms[n]) for n in plans if n != 'all'):.2f} ms")


if __name__ == "__main__":
    main()
