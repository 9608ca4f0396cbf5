"""Write hog_reference.npz: HOG of eight patches of the shipped test images, computed by references.

Run once from the repository root (``python tests/data/make_hog_reference.py``); the test
``tests/test_features.py::test_hog_equals_the_stored_reference`` compares the library's HOG with it.
Unsigned HOG comes from scikit-image; signed HOG (which scikit-image cannot compute) from the plain
numpy HOG written from the definition in ``tests/test_features.py``.
"""

import json
import sys
from pathlib import Path

import cv2
import numpy as np
from skimage.feature import hog as sk_hog

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from test_features import numpy_hog  # noqa: E402

from vehicle_detection.features import FeatureConfig, convert_color  # noqa: E402
from vehicle_detection.io.images import read_image  # noqa: E402

# (image, x, y, side): two cars, road, barrier, trees, sky, lane line, car edge.
CROPS = [(1, 820, 400, 140), (1, 1060, 395, 160), (1, 300, 560, 96), (1, 560, 420, 64),
         (2, 100, 300, 128), (3, 600, 100, 120), (4, 250, 600, 80), (5, 980, 420, 100)]


def main() -> None:
    patches = []
    for k, x, y, side in CROPS:
        frame = read_image(HERE.parents[1] / "test_images" / f"test{k}.jpg")
        patches.append(cv2.resize(frame[y : y + side, x : x + side], (64, 64), interpolation=cv2.INTER_AREA))
    patches = np.stack(patches)
    unsigned = FeatureConfig(signed=False, hog_sqrt=False, orientations=9, hog_channels=(0,))
    signed = FeatureConfig(color_space="HLS", signed=True, hog_sqrt=False, orientations=16, hog_channels=(1,))

    def reference(cfg, one_channel):
        conv = convert_color(patches, cfg.color_space)
        return np.stack([np.concatenate([one_channel(p[..., c], cfg) for c in cfg.hog_channels]) for p in conv]).astype(np.float32)

    ppc, cpb = unsigned.pixels_per_cell, unsigned.cells_per_block
    arrays = {
        "patches": patches,
        "unsigned": reference(unsigned, lambda ch, cfg: sk_hog(ch, cfg.orientations, (ppc, ppc), (cpb, cpb), block_norm="L2-Hys")),
        "signed": reference(signed, lambda ch, cfg: numpy_hog(ch, cfg.orientations, ppc, cpb, True)),
        "unsigned_config": np.array(json.dumps(unsigned.to_dict())),
        "signed_config": np.array(json.dumps(signed.to_dict())),
    }
    np.savez_compressed(HERE / "hog_reference.npz", **arrays)


if __name__ == "__main__":
    main()
