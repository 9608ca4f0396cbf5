"""Drawing boxes and tracked vehicles on RGB frames, and contact sheets of an evaluation's failures.

Every image here is RGB ``uint8`` of shape ``(H, W, 3)``; nothing is modified in place, except
the ``out`` array :func:`draw_boxes` and :func:`draw_detections` are given.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike

from ..detections import Detections
from ..geometry import as_boxes

__all__ = ["draw_boxes", "draw_detections", "place_labels", "draw_caption", "context_region", "tile_view", "add_caption",
           "failure_tile", "failure_sheet"]

#: Colour of a vehicle's box in annotated videos and figures (RGB).
BOX_COLOR = (0, 255, 0)
#: Failure sheets (RGB): labelled cars (the blue of the notebooks' labelled-frames figure),
#: reported boxes (as in annotated videos) and ignore regions.
LABEL_COLOR = (47, 123, 255)
REPORTED_COLOR = BOX_COLOR
IGNORE_COLOR = (255, 0, 255)
#: Caption colour of each kind of failure (RGB, dark enough to read on the white caption strip).
KIND_COLORS = {"miss": (210, 0, 0), "false positive": (200, 100, 0), "loose": (120, 110, 0)}
_HEADER_BACKGROUND = (30, 30, 30)
_TILE_BACKGROUND = (40, 40, 40)
#: Every flat colour of a failure sheet, to keep exactly when the sheet is reduced to a palette.
SHEET_COLORS = (LABEL_COLOR, REPORTED_COLOR, IGNORE_COLOR, *KIND_COLORS.values(), (0, 0, 0), (255, 255, 255),
                _HEADER_BACKGROUND, _TILE_BACKGROUND)
_FONT = cv2.FONT_HERSHEY_SIMPLEX
_TEXT_SCALE = 0.45
_LINE_HEIGHT = 16


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
    out: np.ndarray | None = None,
) -> np.ndarray:
    """Draw rectangles, optionally labelled, on a copy of an image (or on ``out``).

    Parameters
    ----------
    image : ndarray of uint8, shape (H, W, 3)
        RGB image; it is not modified.
    boxes : array_like, shape (n, 4), or Detections
        ``[x1, y1, x2, y2]`` (x2, y2 exclusive); float coordinates are rounded to whole pixels.
        A :class:`Detections` gives its ``xyxy`` (:func:`draw_detections` also labels them).
        The rectangle's outer edge covers exactly the box's pixels; parts outside the image are
        clipped.
    color : sequence of 3 int, default (0, 255, 0)
        Line colour in the image's channel order (RGB: green by default).
    thickness : int, default 3
        Line width in pixels, >= 1; the lines lie inside the box, growing inward from its edge.
    labels : sequence of str or int, optional
        One label per box (e.g. track ids), written on a filled tag of ``color`` next to the box
        (:func:`place_labels`: above its top-left corner where there is room, always inside the
        image, no tag over another; a tag that fits nowhere is left out). Tags are drawn over
        every box's lines.
    out : ndarray of uint8, shape (H, W, 3), optional
        Where to draw: a C-contiguous, writeable array of the image's shape, which gets the
        image and the boxes. ``out=image`` draws in place, without a copy. By default a new
        array.

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
        A new C-contiguous array, or ``out``.

    Raises
    ------
    ValueError
        If the image is not ``uint8`` of shape ``(H, W, 3)``, the boxes are malformed, ``labels``
        does not have one entry per box, ``color``/``thickness`` are invalid, or ``out`` is not
        as said.
    """
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"image must be uint8 of shape (H, W, 3); got {image.dtype} of shape {image.shape}")
    col = _check_color(color)
    if isinstance(thickness, bool) or not isinstance(thickness, (int, np.integer)) or thickness < 1:
        raise ValueError(f"thickness must be an integer >= 1; got {thickness!r}")
    thickness = int(thickness)
    if isinstance(boxes, Detections):
        boxes = boxes.xyxy
    box_arr = np.rint(as_boxes(boxes, "boxes"))
    if labels is not None:
        labels = [str(label) for label in labels]
        if len(labels) != len(box_arr):
            raise ValueError(f"labels has {len(labels)} entries for {len(box_arr)} boxes")

    out = _canvas(image, out)
    h, w = out.shape[:2]
    # Keep coordinates within cv2's int range but well outside the image, so clipping is invisible.
    margin = 2 * thickness + 2
    lo = np.array([-margin, -margin, -margin, -margin])
    hi = np.array([w + margin, h + margin, w + margin, h + margin])
    box_int = np.clip(box_arr, lo, hi).astype(np.int64)

    font_scale = 0.6
    text_thickness = max(1, thickness // 2)
    # Black text on light colours, white on dark (Rec. 601 luma).
    text_color = (0, 0, 0) if 0.299 * col[0] + 0.587 * col[1] + 0.114 * col[2] > 127 else (255, 255, 255)
    for x1, y1, x2, y2 in box_int.tolist():
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
    if labels is None:
        return out
    named = [i for i, label in enumerate(labels) if label]
    metrics = [cv2.getTextSize(labels[i], _FONT, font_scale, text_thickness) for i in named]
    sizes = [(tw + 4, th + baseline + 4) for (tw, th), baseline in metrics]
    rects, shown = place_labels(box_arr[named], np.array(sizes, np.int64).reshape(-1, 2), out.shape)
    for i, ((_, th), _), (rx1, ry1, rx2, ry2), ok in zip(named, metrics, rects.tolist(), shown.tolist()):
        if ok:
            cv2.rectangle(out, (rx1, ry1), (rx2 - 1, ry2 - 1), col, cv2.FILLED)
            cv2.putText(out, labels[i], (rx1 + 2, ry1 + 2 + th), _FONT, font_scale, text_color, text_thickness, cv2.LINE_AA)
    return out


def _canvas(image: np.ndarray, out: np.ndarray | None) -> np.ndarray:
    """The array to draw on: a copy of ``image``, or ``out`` holding it."""
    if out is None:
        return np.array(image, dtype=np.uint8, order="C", copy=True)
    if not (isinstance(out, np.ndarray) and out.dtype == np.uint8 and out.shape == image.shape
            and out.flags.c_contiguous and out.flags.writeable):
        raise ValueError(f"out must be a writeable, C-contiguous uint8 array of shape {image.shape}; got "
                         + (f"{out.dtype} of shape {out.shape}" if isinstance(out, np.ndarray) else type(out).__name__))
    if out is not image:
        np.copyto(out, image)
    return out


def place_labels(boxes: ArrayLike, sizes: ArrayLike, frame_shape: tuple[int, ...], *, gap: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Where to put each box's label tag: next to its box, inside the frame, none over another.

    A tag's place of choice is just above its box, left-aligned with it (moved inside the frame
    where that reaches past an edge). Tags are placed one by one, those of the boxes reaching
    lowest in the frame (the nearest vehicles) first; each takes, of the places inside the frame
    that keep ``gap`` pixels from every tag placed before it, the one nearest (city-block
    distance) to its place of choice. The places tried lie against the box's sides, the frame's
    edges and the tags already placed.

    Parameters
    ----------
    boxes : array_like, shape (n, 4)
        ``[x1, y1, x2, y2]`` of the boxes (x2, y2 exclusive).
    sizes : array_like of int, shape (n, 2)
        ``(width, height)`` in pixels of each box's tag.
    frame_shape : tuple
        ``(H, W, ...)`` of the frame.
    gap : int, default 1
        Least number of pixels between two tags, >= 0.

    Returns
    -------
    rects : ndarray of int64, shape (n, 4)
        Each tag's ``[x1, y1, x2, y2]`` (x2, y2 exclusive), inside the frame; pairwise disjoint
        (``gap`` pixels apart) among the tags shown.
    shown : ndarray of bool, shape (n,)
        False for a tag that fits nowhere (larger than the frame, or the frame full of tags); its
        rect is then its place of choice.

    Examples
    --------
    >>> rects, shown = place_labels([[10, 40, 60, 80], [20, 40, 70, 80]], [[40, 12], [40, 12]], (100, 100))
    >>> rects.tolist(), shown.tolist()
    ([[10, 28, 50, 40], [20, 15, 60, 27]], [True, True])
    """
    b = as_boxes(boxes, "boxes")
    wh = np.asarray(sizes, dtype=np.int64).reshape(-1, 2)
    if len(wh) != len(b):
        raise ValueError(f"sizes has {len(wh)} rows for {len(b)} boxes")
    if isinstance(gap, bool) or not isinstance(gap, (int, np.integer)) or gap < 0:
        raise ValueError(f"gap must be an integer >= 0; got {gap!r}")
    h, w = int(frame_shape[0]), int(frame_shape[1])
    box = np.rint(b).astype(np.int64)
    rects = np.zeros((len(b), 4), np.int64)
    shown = np.zeros(len(b), bool)
    placed = np.zeros((0, 4), np.int64)
    for i in sorted(range(len(b)), key=lambda k: (-box[k, 3], k)):
        tw, th = (int(v) for v in wh[i])
        x1, y1, x2, y2 = box[i].tolist()
        hx, hy = w - tw, h - th  # the largest top-left corner inside the frame
        px, py = min(max(x1, 0), max(hx, 0)), min(max(y1 - th, 0), max(hy, 0))
        rects[i] = px, py, px + tw, py + th
        if tw > w or th > h or tw <= 0 or th <= 0:
            continue
        xs = np.array([px, x1, x2 - tw, 0, hx, *(placed[:, 2] + gap), *(placed[:, 0] - gap - tw)], np.int64)
        ys = np.array([py, y1, y2, 0, hy, *(placed[:, 3] + gap), *(placed[:, 1] - gap - th)], np.int64)
        xs, ys = np.unique(xs[(xs >= 0) & (xs <= hx)]), np.unique(ys[(ys >= 0) & (ys <= hy)])
        cx, cy = (a.ravel() for a in np.meshgrid(xs, ys))
        free = np.ones(len(cx), bool)
        if len(placed):
            free = ~((cx[:, None] < placed[None, :, 2] + gap) & (placed[None, :, 0] < cx[:, None] + tw + gap)
                     & (cy[:, None] < placed[None, :, 3] + gap) & (placed[None, :, 1] < cy[:, None] + th + gap)).any(axis=1)
        if not free.any():
            continue
        cost = np.where(free, np.abs(cx - px) + np.abs(cy - py), np.iinfo(np.int64).max)
        k = int(np.argmin(cost))
        rects[i] = cx[k], cy[k], cx[k] + tw, cy[k] + th
        shown[i] = True
        placed = np.vstack([placed, rects[i]])
    return rects, shown


#: Caption text and panel (RGB), and the panel's opacity over the frame.
CAPTION_COLOR = (255, 255, 255)
CAPTION_PANEL = (0, 0, 0)
CAPTION_ALPHA = 0.7


def draw_caption(
    image: np.ndarray,
    lines: Sequence[str],
    *,
    area: Sequence[int] | None = None,
    scale: float | None = None,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """Lines of white text on a dark panel in the top-left corner of the picture.

    The panel is black at :data:`CAPTION_ALPHA` opacity over the frame, so the text reads on a
    bright sky as on a night road (a contrast ratio of at least 7 to 1 on a white frame).

    Parameters
    ----------
    image : ndarray of uint8, shape (H, W, 3)
        RGB frame; it is not modified (unless it is ``out``).
    lines : sequence of str
        The caption, one entry a line.
    area : sequence of 4 int, optional
        ``(x1, y1, x2, y2)`` of the picture inside black bars
        (:func:`~vehicle_detection.footage.overlays.active_area`); the caption lies inside it. Default:
        the whole image.
    scale : float, optional
        Font scale (OpenCV's Hershey simplex). Default: the picture's height over 720, between
        0.4 and 1; smaller when a line would not fit the picture's width.
    out : ndarray of uint8, shape (H, W, 3), optional
        Where to draw, as for :func:`draw_boxes`.

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
        A new array, or ``out``.
    """
    image = np.asarray(image)
    if image.dtype != np.uint8 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"image must be uint8 of shape (H, W, 3); got {image.dtype} of shape {image.shape}")
    out = _canvas(image, out)
    h, w = out.shape[:2]
    ax1, ay1, ax2, ay2 = (0, 0, w, h) if area is None else (int(v) for v in area)
    ax1, ay1, ax2, ay2 = max(ax1, 0), max(ay1, 0), min(ax2, w), min(ay2, h)
    lines = [str(line) for line in lines]
    if not lines or ax2 <= ax1 or ay2 <= ay1:
        return out
    s = float(scale) if scale is not None else min(1.0, max(0.4, (ay2 - ay1) / 720))
    widest = max(cv2.getTextSize(line, _FONT, 1.0, 2)[0][0] for line in lines)
    if scale is None and widest * s > 0.9 * (ax2 - ax1):
        s = max(0.3, 0.9 * (ax2 - ax1) / widest)
    thick = 2 if s >= 0.7 else 1
    margin, step, pad = round(30 * s), round(40 * s), max(2, round(8 * s))
    sizes = [cv2.getTextSize(line, _FONT, s, thick) for line in lines]
    th, baseline = sizes[0][0][1], sizes[0][1]
    x, y0 = ax1 + margin, ay1 + margin + th
    px1, py1 = max(ax1, x - pad), max(ay1, y0 - th - pad)
    px2 = min(ax2, x + max(tw for (tw, _), _ in sizes) + pad)
    py2 = min(ay2, y0 + step * (len(lines) - 1) + baseline + pad)
    if px2 > px1 and py2 > py1:
        roi = out[py1:py2, px1:px2]
        panel = np.empty_like(roi)
        panel[:] = CAPTION_PANEL
        out[py1:py2, px1:px2] = cv2.addWeighted(panel, CAPTION_ALPHA, roi, 1 - CAPTION_ALPHA, 0)
    clip = out[ay1:ay2, ax1:ax2]  # text outside the picture would be cut at its edge
    for i, line in enumerate(lines):
        cv2.putText(clip, line, (x - ax1, y0 + step * i - ay1), _FONT, s, CAPTION_COLOR, thick, cv2.LINE_AA)
    return out


def draw_detections(
    image: np.ndarray,
    detections: Detections,
    *,
    color: Sequence[int] = BOX_COLOR,
    thickness: int = 4,
    out: np.ndarray | None = None,
) -> np.ndarray:
    """A copy of an RGB frame with each detection's box drawn, labelled ``car <id>`` when tracked.

    With a ``distance_m`` column in ``detections.data``, the label also gives the distance
    (``car 3 24 m``).

    Parameters
    ----------
    image : ndarray of uint8, shape (H, W, 3)
    detections : Detections
        The boxes of this frame.
    color, thickness, out
        As for :func:`draw_boxes` (``out=image`` draws on the frame itself).

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
    return draw_boxes(image, detections.xyxy, color=color, thickness=thickness, labels=labels, out=out)


# --------------------------------------------------------------------------------------------
# Contact sheets of failures
# --------------------------------------------------------------------------------------------
def context_region(
    boxes: ArrayLike, frame_shape: tuple[int, ...], *, aspect: float = 4 / 3, context: float = 0.6, min_side: int = 96
) -> np.ndarray:
    """The part of a frame to show around some boxes: their union with a margin, at an aspect ratio.

    Parameters
    ----------
    boxes : array_like, shape (n, 4)
        ``[x1, y1, x2, y2]``, n >= 1.
    frame_shape : tuple
        ``(H, W, ...)`` of the frame.
    aspect : float, default 4/3
        Width over height of the region, when the frame has room for it.
    context : float, default 0.6
        Margin on every side, as a fraction of the union's longer side.
    min_side : int, default 96
        The region's height is at least this (and its width ``aspect`` times it), frame allowing.

    Returns
    -------
    ndarray of int64, shape (4,)
        ``[x1, y1, x2, y2]`` inside the frame, with ``x2 > x1`` and ``y2 > y1``.
    """
    b = as_boxes(boxes, "boxes")
    h, w = int(frame_shape[0]), int(frame_shape[1])
    x1, y1 = b[:, 0].min(), b[:, 1].min()
    x2, y2 = b[:, 2].max(), b[:, 3].max()
    margin = context * max(x2 - x1, y2 - y1, 1.0)
    rh = max(y2 - y1 + 2 * margin, (x2 - x1 + 2 * margin) / aspect, float(min_side))
    rw = rh * aspect
    cx, cy = (x1 + x2) / 2, (y1 + y2) / 2
    out = []
    for centre, side, limit in ((cx, rw, w), (cy, rh, h)):
        side = min(side, limit)
        lo = min(max(centre - side / 2, 0.0), limit - side)  # shifted inside the frame
        out.append((int(round(lo)), int(round(lo + side))))
    (ax, bx), (ay, by) = out
    return np.array([ax, ay, max(bx, ax + 1), max(by, ay + 1)], dtype=np.int64)


def tile_view(
    image: np.ndarray,
    region: ArrayLike,
    size: tuple[int, int],
    layers: Sequence[tuple[ArrayLike, Sequence[int], int]] = (),
    *,
    background: Sequence[int] = _TILE_BACKGROUND,
) -> np.ndarray:
    """A region of an image scaled to fit a tile, with boxes drawn at the tile's scale.

    Parameters
    ----------
    image : ndarray of uint8, shape (H, W, 3)
        RGB frame.
    region : array_like, shape (4,)
        ``[x1, y1, x2, y2]`` of the frame to show (inside it).
    size : (int, int)
        ``(width, height)`` of the tile; the region is scaled to fit and centred, the rest
        filled with ``background``.
    layers : sequence of (boxes, color, thickness)
        Boxes ``(n, 4)`` in frame pixels, drawn in order (later layers on top), each as
        :func:`draw_boxes` draws them; parts outside the region are clipped.
    background : sequence of 3 int

    Returns
    -------
    ndarray of uint8, shape (height, width, 3)
    """
    x1, y1, x2, y2 = (int(v) for v in np.asarray(region).reshape(4))
    tw, th = int(size[0]), int(size[1])
    crop = np.ascontiguousarray(np.asarray(image)[y1:y2, x1:x2])
    scale = min(tw / crop.shape[1], th / crop.shape[0])
    cw, ch = max(1, round(crop.shape[1] * scale)), max(1, round(crop.shape[0] * scale))
    interpolation = cv2.INTER_AREA if scale < 1 else cv2.INTER_LINEAR
    out = np.empty((th, tw, 3), np.uint8)
    out[:] = _check_color(background)
    ox, oy = (tw - cw) // 2, (th - ch) // 2
    out[oy : oy + ch, ox : ox + cw] = cv2.resize(crop, (cw, ch), interpolation=interpolation)
    view = out[oy : oy + ch, ox : ox + cw]
    offset = np.array([x1, y1, x1, y1], np.float64)
    for boxes, color, thickness in layers:
        b = as_boxes(boxes, "boxes")
        if len(b):
            view = draw_boxes(view, (b - offset) * scale, color=color, thickness=thickness)
    out[oy : oy + ch, ox : ox + cw] = view
    return out


def _fit_text(text: str, width: int, scale: float = _TEXT_SCALE) -> str:
    """``text``, shortened in the middle with ``...`` until it is at most ``width`` pixels wide."""
    fits = lambda t: cv2.getTextSize(t, _FONT, scale, 1)[0][0] <= width  # noqa: E731
    if fits(text):
        return text
    keep = len(text)
    while keep > 1:
        keep -= 1
        short = text[: (keep + 1) // 2] + "..." + text[len(text) - keep // 2 :]
        if fits(short):
            return short
    return "..."


def add_caption(
    tile: np.ndarray, lines: Sequence[tuple[str, Sequence[int]]], *, background: Sequence[int] = (255, 255, 255)
) -> np.ndarray:
    """A tile with lines of text in a strip below it.

    Parameters
    ----------
    tile : ndarray of uint8, shape (H, W, 3)
    lines : sequence of (str, color)
        Each line and its RGB colour; a line too wide for the tile is shortened in the middle.
    background : sequence of 3 int
        The strip's colour.

    Returns
    -------
    ndarray of uint8, shape (H + 16 * len(lines) + 6, W, 3)
    """
    h, w = tile.shape[:2]
    strip = np.empty((_LINE_HEIGHT * len(lines) + 6, w, 3), np.uint8)
    strip[:] = _check_color(background)
    for i, (text, color) in enumerate(lines):
        cv2.putText(strip, _fit_text(text, w - 8), (4, _LINE_HEIGHT * (i + 1)), _FONT, _TEXT_SCALE,
                    _check_color(color), 1, cv2.LINE_AA)
    return np.concatenate([np.asarray(tile, np.uint8), strip], axis=0)


def failure_tile(
    image: np.ndarray,
    failure: Any,
    cars: ArrayLike,
    ignore: ArrayLike,
    reported: ArrayLike,
    title: str,
    *,
    size: tuple[int, int] = (256, 192),
) -> np.ndarray:
    """One failure of an evaluation, shown in its context and captioned.

    Parameters
    ----------
    image : ndarray of uint8, shape (H, W, 3)
        The labelled RGB frame.
    failure : Failure
        From :func:`vehicle_detection.metrics.detection.find_failures`: its ``box`` and ``partner`` set
        the region shown, its ``kind`` and ``iou`` the caption's second line.
    cars, ignore, reported : array_like, shape (n, 4)
        The frame's labelled cars (blue), ignore regions (magenta, thin) and reported boxes
        (green): all of them, so the tile shows what lies around the failure too. The failure's
        own box is drawn thicker (blue for a miss or a loose match, green for a false positive).
    title : str
        The caption's first line (e.g. the labels file and frame).
    size : (int, int), default (256, 192)
        ``(width, height)`` of the picture above the caption.

    Returns
    -------
    ndarray of uint8, shape (size[1] + 38, size[0], 3)
    """
    around = [failure.box] if failure.partner is None else [failure.box, failure.partner]
    region = context_region(around, image.shape, aspect=size[0] / size[1])
    own = REPORTED_COLOR if failure.kind == "false positive" else LABEL_COLOR
    layers = [(ignore, IGNORE_COLOR, 1), (cars, LABEL_COLOR, 2), (reported, REPORTED_COLOR, 2), ([failure.box], own, 4)]
    view = tile_view(image, region, size, layers)
    iou = f"best IoU {failure.iou:.2f}" if failure.kind != "loose" else f"IoU {failure.iou:.2f}"
    return add_caption(view, [(title, (0, 0, 0)), (f"{failure.kind}  {iou}", KIND_COLORS.get(failure.kind, (0, 0, 0)))])


def _legend(width: int, title: str, note: str) -> np.ndarray:
    """The sheet's header: a title, a note, and the colour key, white on dark grey."""
    head = np.empty((3 * _LINE_HEIGHT + 14, width, 3), np.uint8)
    head[:] = _HEADER_BACKGROUND
    white = (255, 255, 255)
    cv2.putText(head, _fit_text(title, width - 12, 0.55), (6, _LINE_HEIGHT + 2), _FONT, 0.55, white, 1, cv2.LINE_AA)
    cv2.putText(head, _fit_text(note, width - 12), (6, 2 * _LINE_HEIGHT + 4), _FONT, _TEXT_SCALE, white, 1, cv2.LINE_AA)
    x, y = 6, 3 * _LINE_HEIGHT + 6
    for name, color in (("labelled car", LABEL_COLOR), ("reported box", REPORTED_COLOR), ("ignore region", IGNORE_COLOR)):
        cv2.rectangle(head, (x, y - 9), (x + 22, y + 1), color, 2)
        cv2.putText(head, name, (x + 28, y), _FONT, _TEXT_SCALE, white, 1, cv2.LINE_AA)
        x += 40 + cv2.getTextSize(name, _FONT, _TEXT_SCALE, 1)[0][0]
    cv2.putText(head, "thick: the failure's own box", (x, y), _FONT, _TEXT_SCALE, white, 1, cv2.LINE_AA)
    return head


def failure_sheet(tiles: Sequence[np.ndarray], title: str, note: str = "", *, ncols: int = 6, gap: int = 4) -> np.ndarray:
    """Tiles of equal size on a grid, ``ncols`` a row, under a header with the colour key.

    Parameters
    ----------
    tiles : sequence of ndarray of uint8, shape (h, w, 3)
        From :func:`failure_tile`, all the same shape; may be empty.
    title, note : str
        The header's two lines (e.g. the camera and the counts; what was left out).
    ncols : int, default 6
        Tiles per row (fewer when there are fewer tiles).
    gap : int, default 4
        White pixels between tiles and around them.

    Returns
    -------
    ndarray of uint8, shape (H, W, 3)
        At least 640 pixels wide, so that the header fits.
    """
    if ncols < 1 or gap < 0:
        raise ValueError(f"ncols must be >= 1 and gap >= 0; got {ncols}, {gap}")
    shapes = {t.shape for t in tiles}
    if len(shapes) > 1:
        raise ValueError(f"tiles must all have one shape; got {sorted(shapes)}")
    th, tw = next(iter(shapes))[:2] if shapes else (0, 0)
    cols = max(1, min(ncols, len(tiles)))
    rows = -(-len(tiles) // cols)
    width = max(640, gap + cols * (tw + gap))
    grid = np.full((gap + rows * (th + gap), width, 3), 255, np.uint8)
    for k, tile in enumerate(tiles):
        r, c = divmod(k, cols)
        y, x = gap + r * (th + gap), gap + c * (tw + gap)
        grid[y : y + th, x : x + tw] = tile
    return np.concatenate([_legend(width, title, note), grid], axis=0)
