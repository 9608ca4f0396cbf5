"""The writeup's screenshot of the HTML report of ``test_video.mp4``, as headless Chromium draws it.

    python tools/report_screenshot.py [--out output_images/html_report_test_video.png] [--chromium PATH]

Runs ``vehicle-detection detect test_video.mp4 --lanes --report --no-video`` (no camera file: the
road plane is estimated from the clip) in a temporary folder, opens the page in headless Chromium
(a fresh profile, no network services) and saves the screenshot, reduced to 256 colours. This is
the one picture of the writeup that no notebook writes: it shows a browser, not a figure.
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
NAME = "html_report_test_video.png"
WINDOW = (1000, 2050)  # wide enough for the contact sheet, tall enough for the lanes figure


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(REPO / "output_images" / NAME))
    parser.add_argument("--chromium", default=shutil.which("chromium") or shutil.which("chromium-browser") or "chromium")
    args = parser.parse_args(argv)
    from PIL import Image

    from vehicle_detection.cli import main as cli

    with tempfile.TemporaryDirectory() as tmp, tempfile.TemporaryDirectory() as profile:
        out_dir = Path(tmp)
        os.chdir(REPO)  # the page names the video as given: "test_video.mp4", not a path of this machine
        code = cli(["detect", "test_video.mp4", "--lanes", "--report", "--no-video", "--out-dir", str(out_dir), "--no-progress"])
        if code:
            return code
        page, shot = out_dir / "test_video_report.html", out_dir / "shot.png"
        subprocess.run(
            [args.chromium, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
             "--disable-background-networking", "--disable-component-update", "--disable-sync", "--hide-scrollbars",
             f"--user-data-dir={profile}", f"--window-size={WINDOW[0]},{WINDOW[1]}", f"--screenshot={shot}", page.as_uri()],
            check=True, capture_output=True, timeout=120,
        )
        image = Image.open(shot).convert("RGB").quantize(colors=256, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
        image.save(args.out, optimize=True)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
