"""What sharing the image pyramid between scales would do to the SVM's margins (docs/experiments.md, "One gradient pass shared by all scales").

    python tools/pyramid_margins.py [IMAGE_OR_VIDEO ...] [--frames N]

Today each scale ``s`` of the plan resizes its band by ``1/s`` and computes gradients and 8-pixel
cells there. A shared pyramid computes gradients once per octave and takes every scale's cells
as sums over that image, ``8 s / o`` pixels wide at octave ``o``. Two such pyramids are scored:

* ``one pass``: every scale from the working frame's own gradients (one octave, ``o = 1``; cells of
  12, 16, 24 and 32 pixels are sums of 4-pixel cells);
* ``octaves``: scales 1, 2 and 4 as today, 1.5 from octave 1 (12-pixel cells) and 3 from octave 2
  (12-pixel cells), as Dollar et al.'s fast feature pyramids approximate the scales between
  octaves.

For every window of the embedded model's plan, searched as crops (``window_border="crop"``,
threshold 0.3), on the frames (default: the shipped test images and
every 8th frame of the shipped test video), the margin the search gives it today is compared with
the margin of the same window when its HOG comes from a shared pyramid; its spatial bins and
colour histograms stay today's. The windows are cut from each band as the search resized it, so
today's margins are recomputed from 64-pixel crops, and the tool stops unless they agree with the
search's own to 1e-4. One line per scale and pyramid (an octave's own scale is computed as today
and not listed): the correlation of the margins, the mean and spread of the change in margin
units, and how many of today's hot windows (margin above the plan's threshold) stay hot and how
many others become hot.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]


def frames_of(paths: list[Path], every: int) -> list[np.ndarray]:
    import vehicle_detection as vd

    out = []
    for path in paths:
        if path.suffix.lower() in {".jpg", ".jpeg", ".png"}:
            out.append(vd.read_image(path))
        else:
            out.extend(f for i, f in enumerate(vd.read_frames(path)) if i % every == 0)
    return out


def crops(image: np.ndarray, corners: np.ndarray, side: int) -> np.ndarray:
    """Square crops ``(n, side, side, 3)`` at integer ``corners`` ``(n, 2)`` (x, y), mirrored beyond the edges."""
    import cv2

    padded = cv2.copyMakeBorder(image, side, side, side, side, cv2.BORDER_REFLECT_101)
    return np.stack([padded[y + side : y + 2 * side, x + side : x + 2 * side] for x, y in corners])


def hog_margin(patches: np.ndarray, cell: int, model) -> np.ndarray:
    """The HOG part of the margins (``hog @ weights[hog]``) of patches with cells of ``cell`` pixels."""
    from vehicle_detection.features import convert_color, hog_features, hog_input

    cfg = model.config
    big = dataclasses.replace(cfg, window=patches.shape[1], pixels_per_cell=cell)
    hog = hog_features(hog_input(convert_color(patches, cfg.color_space), big), big)
    return hog.astype(np.float64) @ model.weights[cfg.layout()["hog"]]


def octave_patches(work: np.ndarray, band, corners: np.ndarray, scale: float, octave: int, config) -> tuple[np.ndarray, int]:
    """The windows of a band of ``scale`` (band-pixel ``corners``, the search's order) cut from its
    region of the working frame at octave ``octave`` (the frame resized by ``1/octave``), and the
    cell size that gives them the band's cell grid: ``(patches (n, side, side, 3), cell)``."""
    import cv2

    w = work.shape[1]
    x1, y1 = band.x0 + round(band.image.shape[1] * band.sx), band.y0 + round(band.image.shape[0] * band.sy)
    region = work[band.y0 : y1, max(0, band.x0) : min(w, x1)]
    if band.x0 < 0 or x1 > w:  # mirrored beyond the frame, as the band was
        region = cv2.copyMakeBorder(region, 0, 0, max(0, -band.x0), max(0, x1 - w), cv2.BORDER_REFLECT_101)
    if octave != 1:
        region = cv2.resize(region, (round(region.shape[1] / octave), round(region.shape[0] / octave)), interpolation=cv2.INTER_AREA)
    f = scale / octave
    at = np.rint(corners * [band.sx, band.sy] / octave).astype(np.int64)
    return crops(region, at, round(config.window * f)), round(config.pixels_per_cell * f)


PYRAMIDS = {"one pass": lambda s: 1, "octaves": lambda s: int(2 ** np.floor(np.log2(s)))}


def crop_search(model):
    """``model`` searching windows as their crops (``window_border="crop"``, at the threshold that
    search ran with, 0.3): the features the training patches have, which the pyramids approximate."""
    plan = dataclasses.replace(model.detector_config.plan, window_border="crop", threshold=0.3)
    return model.replace(detector_config=model.detector_config.replace(plan=plan))


def band_margins(work: np.ndarray, model, k: int) -> dict[str, np.ndarray] | None:
    """Margins of the windows of the plan's scale ``k`` in the working frame: the search's, today's
    recomputed from crops of its band, and each shared pyramid's."""
    from vehicle_detection.features import extract_features
    from vehicle_detection.search import _band

    cfg, plan = model.config, model.detector_config.plan
    s = plan.scales[k]
    band = _band(work, s, cfg, plan.overhang_of(s), plan.y_shift)
    if band is None:
        return None
    ppc, side = cfg.pixels_per_cell, cfg.window
    rr, cc = np.meshgrid(band.rows * ppc, band.cols * ppc, indexing="ij")
    corners = np.stack([cc.ravel(), rr.ravel()], axis=1)
    today_patches = crops(band.image, corners, side)
    today = model.decision_function(extract_features(today_patches, cfg))
    out = {"today": today}
    old_hog = hog_margin(today_patches, ppc, model)
    for name, octave_of in PYRAMIDS.items():
        octave = octave_of(s.scale)
        if octave == s.scale:
            continue  # an octave's own scale: computed as today
        patches, cell = octave_patches(work, band, corners, s.scale, octave, cfg)
        out[name] = today - old_hog + hog_margin(patches, cell, model)
    return out


def main(argv: list[str] | None = None) -> None:
    import vehicle_detection as vd
    from vehicle_detection.refine import working_frame
    from vehicle_detection.search import search

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("inputs", nargs="*", type=Path, help="images or videos (default: the shipped test images and test video)")
    ap.add_argument("--frames", type=int, default=8, metavar="N", help="videos: every Nth frame (default 8)")
    args = ap.parse_args(argv)
    inputs = args.inputs or sorted((REPO / "test_images").glob("*.jpg")) + [REPO / "test_video.mp4"]
    model = crop_search(vd.load_default_model())
    plan = model.detector_config.plan
    frames = frames_of(inputs, args.frames)
    print(f"{len(frames)} frames; plan threshold {plan.threshold:g}")
    rows: dict[tuple[str, float], list[tuple[np.ndarray, np.ndarray]]] = {}
    worst = 0.0
    for frame in frames:
        work, _ = working_frame(frame, plan.reference_height)
        found = search(work, model, plan, all_windows=True)
        for k, s in enumerate(plan.scales):
            margins = None if s.scale == 1 else band_margins(work, model, k)  # scale 1: an octave, as today
            if margins is None:
                continue
            today = margins.pop("today")
            worst = max(worst, float(np.abs(today - found.score[found.data["scale_index"] == k]).max()))
            for name, shared in margins.items():
                rows.setdefault((name, s.scale), []).append((today, shared))
    if worst > 1e-4:
        raise SystemExit(f"today's margins recomputed from crops differ from the search's by {worst:.2g}: the tool is out of date")
    print(f"today's margins recomputed from crops of the bands: within {worst:.1g} of the search's")
    print(f"{'pyramid':9s} {'scale':>5s} {'windows':>8s} {'corr':>6s} {'mean change':>12s} {'sd change':>10s} "
          f"{'sd today':>9s} {'hot today':>9s} {'kept':>5s} {'new':>4s}")
    for (name, scale), parts in sorted(rows.items(), key=lambda kv: (kv[0][1], kv[0][0])):
        a = np.concatenate([p[0] for p in parts])
        b = np.concatenate([p[1] for p in parts])
        hot_a, hot_b = a > plan.threshold, b > plan.threshold
        print(f"{name:9s} {scale:5g} {len(a):8d} {np.corrcoef(a, b)[0, 1]:6.3f} {np.mean(b - a):+12.3f} {np.std(b - a):10.3f} "
              f"{a.std():9.3f} {int(hot_a.sum()):9d} {int((hot_a & hot_b).sum()):5d} {int((hot_b & ~hot_a).sum()):4d}")


if __name__ == "__main__":
    main()
