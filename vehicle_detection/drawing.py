"""Drawing boxes and tracked vehicles on RGB frames."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike

from .detections import Detections
from .geometry import as_boxes

__all__ = ["draw_boxes", "draw_detections"]

#: Colour of a vehicle's box in annotated videos and figures (RGB).
BOX_COLOR = (0, 255, 0)


def _check_color(color: Any) -> tuple[int, int, int]:
    try:
        values = [int(c) for c in color]
    except (TypeError, ValueError):
        raise ValueError(f"color must be 3 integers in 0..255; got {color!r}") from None
    if len(values) != 3 or any(not 0 <= c <= 255 for c in values) or any(int(c) != c for c in color):
        raise ValueError(f"color must be 3 integers in 0..255; got {color!r}")
    return values[0], values[1], values[2]


def draw_boxes(
    image: np.ndarray,
    boxes: ArrayLike,
    *,
    color: Sequence[int] = BOX_COLOR,
    thickness: int = 3,
    labels: Sequence[str | int] | None = None,
) -> np.ndarray:
    """Draw rectangles, optionally labelled, on a copy of an image.

    Parameters
    ----------
    image : ndarray of uint8, shape (H, W, 3)
        RGB image; it is not modified.
    boxes : array_like, shape (n, 4)
        ``[x1, y1, x2, y2]`` (x2, y2 exclusive); float coordinates are rounded to whole pixels.
        The rectangle's outer edge covers exactly the box's pixels; parts outside the image are
        clipped.
    color : sequence of 3 int, default (0, 255, 0)
        Line colour in the image's channel order (RGB: green by default).
    thickness : int, default 3
        Line width in pixels, >= 1; the lines lie inside the box, growing inward from its edge.
    labels : sequence of str or int, optional
        One label per box (e.g. track ids), written on a filled tag of ``color`` above the box's
        top-left corner (inside the box when there is no room above).

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
        A new C-contiguous array.

    Raises
    ------
    ValueError
        If the image is not ``uint8`` of shape ``(H, W, 3)``, the boxes are malformed, ``labels``
        does not have one entry per box, or ``color``/``thickness`` are invalid.
    """
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"image must be uint8 of shape (H, W, 3); got {image.dtype} of shape {image.shape}")
    col = _check_color(color)
    if isinstance(thickness, bool) or not isinstance(thickness, (int, np.integer)) or thickness < 1:
        raise ValueError(f"thickness must be an integer >= 1; got {thickness!r}")
    thickness = int(thickness)
    box_arr = np.rint(as_boxes(boxes, "boxes"))
    if labels is not None:
        labels = [str(label) for label in labels]
        if len(labels) != len(box_arr):
            raise ValueError(f"labels has {len(labels)} entries for {len(box_arr)} boxes")

    out = np.array(image, dtype=np.uint8, order="C", copy=True)
    h, w = out.shape[:2]
    # Keep coordinates within cv2's int range but well outside the image, so clipping is invisible.
    margin = 2 * thickness + 2
    lo = np.array([-margin, -margin, -margin, -margin])
    hi = np.array([w + margin, h + margin, w + margin, h + margin])
    box_int = np.clip(box_arr, lo, hi).astype(np.int64)

    font = cv2.FONT_HERSHEY_SIMPLEX
    font_scale = 0.6
    text_thickness = max(1, thickness // 2)
    # Black text on light colours, white on dark (Rec. 601 luma).
    text_color = (0, 0, 0) if 0.299 * col[0] + 0.587 * col[1] + 0.114 * col[2] > 127 else (255, 255, 255)
    for i, (x1, y1, x2, y2) in enumerate(box_int.tolist()):
        # cv2's thick lines are centred on their path and wider than asked; four filled bands
        # give edges exactly `thickness` pixels wide, inside the box [x1, x2 - 1] x [y1, y2 - 1].
        xr, yb = max(x2 - 1, x1), max(y2 - 1, y1)
        tx, ty = min(thickness, xr - x1 + 1), min(thickness, yb - y1 + 1)
        for p1, p2 in (
            ((x1, y1), (xr, y1 + ty - 1)),  # top
            ((x1, yb - ty + 1), (xr, yb)),  # bottom
            ((x1, y1), (x1 + tx - 1, yb)),  # left
            ((xr - tx + 1, y1), (xr, yb)),  # right
        ):
            cv2.rectangle(out, p1, p2, col, cv2.FILLED)
        if labels is None or not labels[i]:
            continue
        (tw, th), baseline = cv2.getTextSize(labels[i], font, font_scale, text_thickness)
        tag_h = th + baseline + 4
        top = y1 - tag_h if y1 - tag_h >= 0 else y1
        cv2.rectangle(out, (x1, top), (x1 + tw + 4, top + tag_h - 1), col, cv2.FILLED)
        origin = (x1 + 2, top + 2 + th)  # bottom-left of the text
        cv2.putText(out, labels[i], origin, font, font_scale, text_color, text_thickness, cv2.LINE_AA)
    return out


def draw_detections(image: np.ndarray, detections: Detections, *, color: Sequence[int] = BOX_COLOR, thickness: int = 4) -> np.ndarray:
    """A copy of an RGB frame with each detection's box drawn, labelled ``car <id>`` when tracked.

    With a ``distance_m`` column in ``detections.data``, the label also gives the distance
    (``car 3 24 m``).

    Parameters
    ----------
    image : ndarray of uint8, shape (H, W, 3)
    detections : Detections
        The boxes of this frame.
    color, thickness
        As for :func:`draw_boxes`.

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
    """
    labels = None if detections.track_id is None else [f"car {t}" if t >= 0 else "" for t in detections.track_id.tolist()]
    if "distance_m" in detections.data:  # from detect --lanes / --camera: "car 3  24 m"
        dist = np.asarray(detections.data["distance_m"], dtype=np.float64)
        labels = [
            " ".join(filter(None, [labels[i] if labels else "", f"{d:.0f} m" if np.isfinite(d) else ""]))
            for i, d in enumerate(dist.tolist())
        ]
    return draw_boxes(image, detections.xyxy, color=color, thickness=thickness, labels=labels)
