"""``vehicle-detection calibrate``: the camera from chessboard photos, and its bird's-eye view."""

from __future__ import annotations

import json
import time
from pathlib import Path

from ..errors import InputError, UsageError, shorten
from ..io import check_output_path
from ..io.images import list_images, read_image
from ..road.camera import calibrate
from ..road.lanes import birds_eye_from_straight
from .options import human_print

__all__ = ["run"]

#: Most inner corners a chessboard row or column may have (OpenCV needs at least 3).
MAX_CORNERS = 100


def run(args) -> int:
    try:
        cols, rows = (int(v) for v in args.pattern.lower().split("x"))
        if not (3 <= cols <= MAX_CORNERS and 3 <= rows <= MAX_CORNERS):
            raise ValueError
    except ValueError:
        raise UsageError(f"--pattern: expected inner corners like 9x6, each 3 to {MAX_CORNERS}, got {shorten(args.pattern)!r}") from None
    folder = Path(args.dir)
    if not folder.is_dir():
        raise InputError(f"{folder}: no such folder of chessboard photos")
    photos = list_images(folder)
    straight = [Path(p) for p in args.straight]
    if args.out is not None:
        check_output_path(args.out, overwrite=args.overwrite, inputs=[*photos, *straight])
    t = time.perf_counter()
    say = human_print(args)
    camera = calibrate(folder, (cols, rows))
    if straight:
        frames = [read_image(p) for p in straight]
        for p, f in zip(straight, frames):
            camera.check_size(f.shape[1], f.shape[0], str(p))
        camera = camera.replace(birds_eye=birds_eye_from_straight(frames, camera))
    w, h = camera.image_size
    say(f"{folder}: {len(camera.images_used)} of {len(photos)} photos used ({w}x{h}), RMS reprojection error {camera.rms:.3f} px")
    for name in camera.images_cropped:
        say(f"  {name}: cropped to {w}x{h} (right and bottom edges)")
    for name, why in camera.images_skipped.items():
        say(f"  {name}: skipped: {why}")
    worst = max(camera.per_image_rms.items(), key=lambda kv: kv[1])
    say(f"  largest per-photo RMS: {worst[0]} {worst[1]:.2f} px")
    if camera.birds_eye is not None:
        be = camera.birds_eye
        say(f"bird's-eye view from {len(straight)} straight-road frame(s): {be.xm_per_px * 100:.2f} cm per pixel across, "
              f"{be.ym_per_px * 100:.2f} cm per pixel along the road")
    if args.out is not None:
        camera.save(args.out, overwrite=args.overwrite, inputs=[*photos, *straight])
        say(f"camera saved to {args.out} ({time.perf_counter() - t:.1f} s)")
    else:
        say("camera not saved (pass --out camera.json to save it)")
    if args.json:
        report = {
            "rms": camera.rms,
            "images_used": len(camera.images_used),
            "images_cropped": list(camera.images_cropped),
            "images_skipped": camera.images_skipped,
            "image_size": list(camera.image_size),
            "per_image_rms": camera.per_image_rms,
            "birds_eye": None if camera.birds_eye is None else camera.birds_eye.to_dict(),
            "out": args.out,
        }
        print(json.dumps(report))
    return 0
