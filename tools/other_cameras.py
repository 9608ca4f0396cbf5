"""Clip A as other cameras would see it: cropped, tilted and rescaled, with its labels moved along.

    python tools/other_cameras.py OUT_DIR

Writes, for each simulated camera, ``NAME.mp4`` and ``NAME_clip_A.json`` / ``NAME_clip_A_tracks.json``
(the dev set's labels mapped into the new frame; a car less than half inside becomes an ignore
region) into OUT_DIR, then scores them with::

    vehicle-detection evaluate --labels OUT_DIR/NAME_clip_A.json OUT_DIR/NAME_clip_A_tracks.json [--horizon plan]

A crop that starts lower or higher moves the road's vanishing point up or down in the frame, as a
camera tilted down or up would; the resize changes the frame size and the cars' size in pixels. A
small crop scaled up to 1280x720 is a longer lens: the cars as they would look closer (the
``zoomed`` views, 1.5 and 2 times). The ``dusk`` views take the light away: each pixel
multiplied by 0.35 or 0.2, with Gaussian noise of standard deviation 4 or 6 levels added (a fixed
seed) before the encoding, as a camera at dusk raises its gain; two of them are of tilted views,
whose horizon must be found without the road's lines. The ``pillarbox`` view is a 4:3 picture at
dusk between black bars in a small 16:9 frame (``PILLARBOX``: the bars' columns), whose bars must
never be searched; the ``letterbox`` view a wide picture (2.39:1) between black bars above and
below (``LETTERBOX``: the bars' rows). The ``timestamp`` view is clip A with a dashcam's burned-in
caption at its bottom left (date, time and speed, white on a black outline; the seconds and the
speed change once a second): a static overlay, never to be boxed. The ``mirrored`` view is clip A
flipped left to right: the road as a camera in left-hand traffic sees it (the United Kingdom,
Japan, India, Australia), the cars to the left of the camera's lane, showing their right flanks.

``--only NAME [NAME ...]`` writes those views alone.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import cv2
import numpy as np

from vehicle_detection.geometry import mirror_boxes

REPO = Path(__file__).resolve().parents[1]
DEV_SET = REPO / "dev_set"

#: name: (crop x0, y0, x1, y1 in the 1280x720 frame, output width, height)
CAMERAS = {
    "tilted_down_960x540": ((80, 90, 1200, 720), (960, 540)),
    "tilted_up_960x472": ((0, 0, 1280, 630), (960, 472)),
    "tilted_down_1280x600": ((0, 120, 1280, 720), (1280, 600)),
    # a longer lens: the cars 1.5 and 2 times as large, as closer cars would be (the right half of
    # the road, where clip A's cars drive; the horizon stays near the middle)
    "zoomed_1.5x_1280x720": ((427, 180, 1280, 660), (1280, 720)),
    "zoomed_2x_1280x720": ((640, 220, 1280, 580), (1280, 720)),
    # dusk: the whole frame, darker and noisier (LIGHT)
    "dusk_0.35_1280x720": ((0, 0, 1280, 720), (1280, 720)),
    "dusk_0.2_1280x720": ((0, 0, 1280, 720), (1280, 720)),
    # dusk on the tilted cameras: no road lines to find the horizon by, and the bands must move
    "dusk_0.2_tilted_down_960x540": ((80, 90, 1200, 720), (960, 540)),
    "dusk_0.2_tilted_up_960x472": ((0, 0, 1280, 630), (960, 472)),
    # a 4:3 picture between black pillarbox bars in a small 16:9 frame, at dusk: the picture 480x360
    # between bars of 80 columns, in a 640x360 frame
    "dusk_0.35_pillarbox_640x360": ((160, 0, 1120, 720), (480, 360)),
    # a 2.39:1 picture between black letterbox bars in a 1280x720 frame: the picture 1280x536
    # (the road from row 90 to 626 of clip A) between bars of 92 rows
    "letterbox_1280x720": ((0, 90, 1280, 626), (1280, 536)),
    # clip A with a dashcam's caption burned in at the bottom left (TIMESTAMP)
    "timestamp_1280x720": ((0, 0, 1280, 720), (1280, 720)),
    # left-hand traffic: clip A flipped left to right (MIRRORED)
    "mirrored_1280x720": ((0, 0, 1280, 720), (1280, 720)),
}
#: name: columns of black bar added on each side of the view (its frame that much wider)
PILLARBOX = {"dusk_0.35_pillarbox_640x360": 80}
#: name: rows of black bar added above and below the view (its frame that much taller)
LETTERBOX = {"letterbox_1280x720": 92}
#: views with a caption burned in
TIMESTAMP = {"timestamp_1280x720"}
#: views flipped left to right
MIRRORED = {"mirrored_1280x720"}
#: name: (light kept, noise standard deviation in levels) of the views with less light
LIGHT = {"dusk_0.35_1280x720": (0.35, 4.0), "dusk_0.35_pillarbox_640x360": (0.35, 4.0), "dusk_0.2_1280x720": (0.2, 6.0), "dusk_0.2_tilted_down_960x540": (0.2, 6.0),
         "dusk_0.2_tilted_up_960x472": (0.2, 6.0)}


def _move(box, crop, size, bar=0, top=0, mirror=False):
    """``box`` moved into the view of ``crop`` resized to ``size`` (flipped left to right with
    ``mirror``), then ``bar`` columns right and ``top`` rows down."""
    x0, y0, x1, y1 = crop
    sx, sy = size[0] / (x1 - x0), size[1] / (y1 - y0)
    out = [(box[0] - x0) * sx, (box[1] - y0) * sy, (box[2] - x0) * sx, (box[3] - y0) * sy]
    if mirror:
        out = mirror_boxes(out, size[0])[0].tolist()
    full = (out[2] - out[0]) * (out[3] - out[1])
    clipped = [max(0.0, out[0]), max(0.0, out[1]), min(size[0], out[2]), min(size[1], out[3])]
    inside = max(0.0, clipped[2] - clipped[0]) * max(0.0, clipped[3] - clipped[1])
    return [int(round(v)) + (bar if k % 2 == 0 else top) for k, v in enumerate(clipped)], (inside / full if full > 0 else 0.0)


def _caption(view: np.ndarray, index: int, fps: int = 25) -> np.ndarray:
    """``view`` with a dashcam's caption at its bottom left: date, time and speed (RGB)."""
    seconds = 14 * 3600 + 3 * 60 + 7 + index // fps
    text = f"2026/11/27 {seconds // 3600:02d}:{seconds // 60 % 60:02d}:{seconds % 60:02d}  {96 + (index // fps) % 5} km/h"
    out = np.ascontiguousarray(view)
    origin = (24, view.shape[0] - 24)
    cv2.putText(out, text, origin, cv2.FONT_HERSHEY_SIMPLEX, 0.9, (0, 0, 0), 5, cv2.LINE_AA)
    cv2.putText(out, text, origin, cv2.FONT_HERSHEY_SIMPLEX, 0.9, (255, 255, 255), 2, cv2.LINE_AA)
    return out


def make_camera(name: str, crop, size, out_dir: Path) -> list[Path]:
    import vehicle_detection as vd

    x0, y0, x1, y1 = crop
    bar, top = PILLARBOX.get(name, 0), LETTERBOX.get(name, 0)
    frame_size = (size[0] + 2 * bar, size[1] + 2 * top)
    video = out_dir / f"{name}.mp4"
    frames = vd.read_frames(DEV_SET / "project_video_clip_A.mp4")
    light, noise = LIGHT.get(name, (1.0, 0.0))
    rng = np.random.default_rng(0)
    try:
        with vd.VideoWriter(video, 25, frame_size, overwrite=True, crf=18) as writer:
            for index, frame in enumerate(frames):
                view = cv2.resize(np.ascontiguousarray(frame[y0:y1, x0:x1]), size, interpolation=cv2.INTER_AREA)
                if name in LIGHT:
                    view = np.clip(np.rint(view * light + rng.normal(0.0, noise, view.shape)), 0, 255).astype(np.uint8)
                if name in MIRRORED:
                    view = np.ascontiguousarray(view[:, ::-1])
                if name in TIMESTAMP:
                    view = _caption(view, index)
                if bar or top:
                    view = cv2.copyMakeBorder(view, top, top, bar, bar, cv2.BORDER_CONSTANT, value=(0, 0, 0))
                writer.write(view)
    finally:
        frames.close()
    written = [video]
    mirror = name in MIRRORED
    for labels in ("clip_A", "clip_A_tracks"):
        doc = json.loads((DEV_SET / f"{labels}.json").read_text())
        doc["video"] = video.name
        doc["camera"] = name  # evaluate pools (and --report names) the files by camera
        for entry in doc["frames"].values():
            cars, ids = [], []
            ignore = [b for b, share in (_move(b, crop, size, bar, top, mirror) for b in entry.get("ignore", [])) if share > 0]
            for i, box in enumerate(entry["cars"]):
                moved, share = _move(box, crop, size, bar, top, mirror)
                if share >= 0.5:
                    cars.append(moved)
                    if "ids" in entry:
                        ids.append(entry["ids"][i])
                elif share > 0:
                    ignore.append(moved)
            entry["cars"], entry["ignore"] = cars, ignore
            if "ids" in entry:
                entry["ids"] = ids
        path = out_dir / f"{name}_{labels}.json"
        path.write_text(json.dumps(doc))
        written.append(path)
    return written


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("out_dir", type=Path)
    ap.add_argument("--only", nargs="+", choices=sorted(CAMERAS), metavar="NAME", help="these views alone")
    args = ap.parse_args()
    args.out_dir.mkdir(parents=True, exist_ok=True)
    for name, (crop, size) in CAMERAS.items():
        if args.only and name not in args.only:
            continue
        for path in make_camera(name, crop, size, args.out_dir):
            print(path)


if __name__ == "__main__":
    main()
