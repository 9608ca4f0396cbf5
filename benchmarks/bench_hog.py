"""HOG speed: this library's compiled HOG against ``skimage.feature.hog``, measured in one run.

    python benchmarks/bench_hog.py [--data-dir ../shared/data] [--n 500]

Both compute the same features (the test suite checks equality) on the same 64x64 patches, all
three channels of the default colour space, with scikit-image's unsigned orientations and no
gamma; the script prints microseconds per patch for each, the ratio, the largest difference
between the two, and the time of the embedded model's own HOG (signed, gamma-compressed).
"""

from __future__ import annotations

import argparse
import time

import numpy as np
from skimage.feature import hog

from vehicle_detection.features import FeatureConfig, convert_color, hog_features, hog_input


def _patches(data_dir, n):
    try:
        from vehicle_detection.training.data import load_dataset

        ds = load_dataset(data_dir)
        idx = np.random.default_rng(0).choice(len(ds), n, replace=False)
        return ds.images[idx], "real training patches"
    except Exception as exc:  # no data here: random patches still time the code
        return np.random.default_rng(0).integers(0, 256, (n, 64, 64, 3), dtype=np.uint8), f"random patches ({exc})"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data-dir", default=None)
    ap.add_argument("--n", type=int, default=500)
    args = ap.parse_args()
    cfg = FeatureConfig(orientations=9, signed=False, hog_sqrt=False)  # what skimage computes
    images, what = _patches(args.data_dir, args.n)
    conv = convert_color(images, cfg.color_space)
    hog_features(conv[:2], cfg)  # compile outside the timing

    def ours_batch():
        return hog_features(conv, cfg)

    def ours_one_by_one():
        return np.concatenate([hog_features(c[None], cfg) for c in conv])

    def reference():
        return np.stack([
            np.concatenate([
                hog(c[:, :, ch], cfg.orientations, (cfg.pixels_per_cell,) * 2, (cfg.cells_per_block,) * 2, block_norm="L2-Hys")
                for ch in cfg.hog_channels
            ])
            for c in conv
        ])

    def best(f, repeat=3):
        times, out = [], None
        for _ in range(repeat):
            t = time.perf_counter()
            out = f()
            times.append(time.perf_counter() - t)
        return min(times) / len(conv) * 1e6, out

    t_ref, ref = best(reference, repeat=1)
    t_one, one = best(ours_one_by_one)
    t_batch, batch = best(ours_batch)
    print(f"HOG of {len(conv)} {what}, {cfg.color_space} channels {cfg.hog_channels}, {cfg.orientations} orientations, "
          f"{cfg.pixels_per_cell}px cells, {cfg.cells_per_block}x{cfg.cells_per_block} blocks ({batch.shape[1]} values each)")
    print(f"skimage.feature.hog          : {t_ref:9.1f} us/patch")
    print(f"ours, one patch per call     : {t_one:9.1f} us/patch   {t_ref / t_one:6.1f}x faster")
    print(f"ours, batch (both cores)     : {t_batch:9.1f} us/patch   {t_ref / t_batch:6.1f}x faster")
    print(f"largest difference from skimage: {max(np.abs(batch - ref).max(), np.abs(one - ref).max()):.2e}")
    model_cfg = FeatureConfig()
    model_in = hog_input(convert_color(images, model_cfg.color_space), model_cfg)
    hog_features(model_in[:2], model_cfg)
    t_model, _ = best(lambda: hog_features(model_in, model_cfg))
    print(f"embedded model's HOG ({model_cfg.orientations} signed bins, gamma), batch: {t_model:9.1f} us/patch")


if __name__ == "__main__":
    main()
