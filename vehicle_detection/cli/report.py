"""``vehicle-detection report``: the HTML page of a run, from its boxes CSV.

The page of :func:`~vehicle_detection.viz.report.write_html_report`: a track timeline, a contact
sheet of every track's first, middle and last box (cut from ``--video``), boxes per frame, and
distances and lanes when the run measured them (``--lanes L.csv``). ``detect --report`` writes the
same page at the end of a run.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

from ..viz.report import write_html_report

__all__ = ["run", "default_report_path"]


def default_report_path(boxes: Path) -> Path:
    """``NAME_report.html`` beside ``NAME_boxes.csv`` (any other CSV: its stem + ``_report.html``)."""
    stem = boxes.stem[: -len("_boxes")] if boxes.stem.endswith("_boxes") and len(boxes.stem) > len("_boxes") else boxes.stem
    return boxes.with_name(f"{stem}_report.html")


def run(args) -> int:
    boxes = Path(args.boxes)
    out = Path(args.out) if args.out else default_report_path(boxes)
    write_html_report(out, boxes, video=args.video, lanes=args.lanes, title=args.title, overwrite=args.overwrite)
    if args.json:
        print(f"wrote {out}", file=sys.stderr)
        print(json.dumps({"report": str(out), "boxes": str(boxes), "video": args.video, "lanes": args.lanes}))
    else:
        print(f"wrote {out}")
    return 0
