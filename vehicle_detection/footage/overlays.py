"""What in a frame is not the scene: black bars around the picture, and the camera car's own parts.

Footage from other cameras carries things the project camera's does not, and the classifier
fires on some of them:

* **black bars** (letterbox rows, pillarbox columns) around a picture of another shape than
  the frame (:func:`active_area`). The search is run on the picture inside them;
* **static overlays**: the camera car's bonnet, dashboard or windscreen mount, and text or
  logos burnt into the recording (:func:`static_mask`). They stay where they are while the scene
  moves, so a window on them would keep a track alive for as long as the video lasts. Windows
  lying mostly on them are dropped (:func:`mask_share`).

Both are measured once from a video's first frames (:class:`Overlays`, via
:func:`find_overlays`); a single image gets the bars only, as one frame cannot tell what stays
still. Images are RGB ``uint8`` arrays ``(H, W, 3)``; boxes are ``[x1, y1, x2, y2]`` with ``x2``
and ``y2`` exclusive.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import cv2
import numpy as np

__all__ = ["BarParams", "MaskParams", "Overlays", "active_area", "static_mask", "find_overlays", "mask_integral", "mask_share"]


@dataclass(frozen=True)
class BarParams:
    """What counts as a black bar (:func:`active_area`).

    Parameters
    ----------
    black_level : int
        A bar's pixels are at most this bright in every channel (0..255) ...
    black_share : float
        ... all but this share of each bar line's pixels over all frames (compression specks).
    spread : float
        Largest standard deviation of a bar line's pixels over all frames: bars are flat.
    min_bar : int
        Bars thinner than this many pixels are ignored.
    max_bar : float
        Largest bar, as a fraction of the frame side; a dark edge reaching further is the
        picture (a black frame, a dark scene), not a bar.
    """

    black_level: int = 32
    black_share: float = 0.01
    spread: float = 4.0
    min_bar: int = 2
    max_bar: float = 0.35


@dataclass(frozen=True)
class MaskParams:
    """What counts as a static overlay (:func:`static_mask`).

    Sizes are in cells of the working image: frames are measured in grey at ``height`` rows, in
    square cells of ``cell`` of its pixels (24 frame pixels at 720 rows).

    Parameters
    ----------
    height : int
        Rows of the working image.
    cell : int
        Cell side in working pixels.
    min_frames : int
        Fewest frames to find anything from.
    still_level : float
        A pixel is still when its grey over the frames spans at most twice this (grey levels,
        0..255): compression noise only.
    still_share : float
        A cell is still when at least this share of its pixels is; a cell where less than half
        of them are has moved.
    min_moving : float
        Share of the cells that must have moved: the frames must show the scene going by,
        else nothing is masked (a standing car sees a still world).
    dark_level : float
        Brightest mean grey (over the frames and the cell) of a dark cell ...
    dark_ratio : float
        ... and at most this fraction of the median grey of the cells that moved (at night
        nearly everything is dark: only what is much darker than the scene counts).
    min_area : float
        Smallest dark region, as a share of the frame.
    edge_level : float
        Gradient magnitude of an edge in an overlay (3x3 Sobel of the mean frame: a step of
        ``s`` grey levels gives ``4 s``) ...
    edge_share : float
        ... at least this share of a cell's pixels must be still and lie on such edges for it
        to hold text (between the strokes, the scene moves).
    min_text : int
        Fewest cells of a text overlay region: a line of text spans several.
    overlay_band : float
        Text overlays are looked for in this fraction of the rows at the top and at the bottom.
    max_overlay : float
        Largest text overlay region, as a share of the frame.
    """

    height: int = 360
    cell: int = 12
    min_frames: int = 6
    still_level: float = 3.0
    still_share: float = 0.9
    min_moving: float = 0.1
    dark_level: float = 40.0
    dark_ratio: float = 0.5
    min_area: float = 0.01
    edge_level: float = 200.0
    edge_share: float = 0.05
    min_text: int = 3
    overlay_band: float = 0.15
    max_overlay: float = 0.02


def _frame_list(frames: np.ndarray | Iterable[np.ndarray]) -> list[np.ndarray]:
    """One ``(H, W, 3)`` image, an ``(N, H, W, 3)`` array or an iterable of images -> list of images."""
    if isinstance(frames, np.ndarray) and frames.ndim == 3:
        frames = [frames]
    out = [np.asarray(f) for f in frames]
    if not out:
        raise ValueError("no frames")
    shape = out[0].shape
    if len(shape) != 3 or shape[2] != 3 or any(f.shape != shape for f in out) or any(f.dtype != np.uint8 for f in out):
        raise ValueError(f"frames must be RGB uint8 images (H, W, 3) of one shape; got {[f.shape for f in out[:3]]}")
    return out


# --- black bars ------------------------------------------------------------------------------


def _bar_lines(strips: np.ndarray, p: BarParams) -> int:
    """How many lines of ``strips`` (N, lines, length), from line 0 inwards, are bar lines."""
    if not strips.shape[1]:
        return 0
    lines = np.moveaxis(strips, 1, 0).reshape(strips.shape[1], -1)
    ok = ((lines > p.black_level).mean(axis=1) <= p.black_share) & (lines.std(axis=1) <= p.spread)
    return int(np.argmin(ok)) if not ok.all() else len(ok)


def _strips(images: list[np.ndarray], edge: str, start: int, stop: int) -> np.ndarray:
    """The brightest channel of lines ``start:stop`` counted from one ``edge`` inwards, every
    fourth pixel along them (bars are flat): (N, stop - start, length / 4)."""
    if edge == "top":
        parts = [f[start:stop, ::4] for f in images]
    elif edge == "bottom":
        parts = [f[::-1][start:stop, ::4] for f in images]
    elif edge == "left":
        parts = [f[::4, start:stop].transpose(1, 0, 2) for f in images]
    else:
        parts = [f[::4, ::-1][:, start:stop].transpose(1, 0, 2) for f in images]
    return np.stack(parts).max(axis=3)


def _side(images: list[np.ndarray], edge: str, depth: int, p: BarParams) -> int:
    """Width of the bar at one ``edge``, looking ``depth`` lines in; -1 when dark all the way.

    Lines are checked in blocks of doubling size, so a frame without a bar costs one line."""
    start, size = 0, 1
    while start < depth:
        stop = min(depth, start + size)
        n = _bar_lines(_strips(images, edge, start, stop), p)
        if n < stop - start:
            return start + n
        start, size = stop, max(8, 2 * size)
    return -1


def _pair(a: int, b: int, p: BarParams) -> int:
    """The bar to cut at both ends of an axis, from the bars found at each: 0 unless both sides have one."""
    if a < 0 or b < 0:
        return 0  # dark beyond max_bar: a dark picture
    small, large = min(a, b), max(a, b)
    if small < p.min_bar or large > 2 * small + 4:
        return 0  # one side only, or far from symmetric: the dark edge of a scene
    return small


def active_area(frames: np.ndarray | Iterable[np.ndarray], params: BarParams = BarParams()) -> tuple[int, int, int, int]:
    """The picture inside black letterbox or pillarbox bars.

    A bar is a run of lines (rows at the top and bottom, columns at the left and right) from
    the frame edge inwards, each near-black and flat in every frame. Bars come in pairs, as a
    picture is centred: both ends of an axis must have one, of similar width (the larger at
    most twice the smaller plus 4 pixels), and both are cut by the smaller. A dark edge reaching
    beyond ``max_bar`` of the side is the picture (a black frame, a night sky).

    Parameters
    ----------
    frames : ndarray of uint8, shape (H, W, 3) or (N, H, W, 3), or iterable of them
        One image or several frames of one video.
    params : BarParams

    Returns
    -------
    (x1, y1, x2, y2) : tuple of int
        The picture, ``x2`` and ``y2`` exclusive; ``(0, 0, W, H)`` when there are no bars.
    """
    images = _frame_list(frames)
    h, w = images[0].shape[:2]
    depth_y, depth_x = max(1, int(params.max_bar * h)), max(1, int(params.max_bar * w))
    top, bottom = (_side(images, e, depth_y, params) for e in ("top", "bottom"))
    left, right = (_side(images, e, depth_x, params) for e in ("left", "right"))
    dy, dx = _pair(top, bottom, params), _pair(left, right, params)
    return dx, dy, w - dx, h - dy


# --- static overlays -------------------------------------------------------------------------


def _grey_stack(frames: list[np.ndarray], height: int) -> np.ndarray:
    """The frames in grey at ``height`` rows, uint8 (N, height, w)."""
    h, w = frames[0].shape[:2]
    size = (max(1, round(w * height / h)), height)
    grey = [cv2.resize(cv2.cvtColor(np.ascontiguousarray(f), cv2.COLOR_RGB2GRAY), size, interpolation=cv2.INTER_AREA) for f in frames]
    return np.stack(grey)


def _cell_means(values: np.ndarray, cell: int) -> np.ndarray:
    """Means of ``values`` (h, w) over cells of ``cell`` pixels; partial cells at the far edges count."""
    h, w = values.shape
    gh, gw = -(-h // cell), -(-w // cell)
    padded = np.pad(values.astype(np.float32), ((0, gh * cell - h), (0, gw * cell - w)), mode="edge")
    return padded.reshape(gh, cell, gw, cell).mean(axis=(1, 3))


def _components(cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """8-connected components of a bool grid: labels (0 = none) and per label (area, touches border)."""
    n, labels, stats, _ = cv2.connectedComponentsWithStats(cells.astype(np.uint8), connectivity=8)
    gh, gw = cells.shape
    x, y, cw, ch, area = (stats[:, i] for i in range(5))
    border = (x == 0) | (y == 0) | (x + cw == gw) | (y + ch == gh)
    return labels, np.stack([area, border], axis=1)


def _dark_regions(still: np.ndarray, grey: np.ndarray, level: float, p: MaskParams) -> np.ndarray:
    """Still dark cells in regions that touch the frame border and cover ``min_area`` of it."""
    labels, stats = _components(still & (grey <= level))
    keep = (stats[:, 0] >= p.min_area * still.size) & (stats[:, 1] == 1)
    keep[0] = False
    return keep[labels]


def _outline(cells: np.ndarray, pixels: np.ndarray, cell: int) -> np.ndarray:
    """``cells`` in working pixels, grown by the ``pixels`` (still and dark) within two cells of them:
    the cells along a region's outline are part scene, part region, and only the region is still."""
    near = cv2.dilate(cells.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    return _upsample(cells, cell, pixels.shape) | (_upsample(near, cell, pixels.shape) & pixels)


def _upsample(cells: np.ndarray, cell: int, shape: tuple[int, int]) -> np.ndarray:
    """A cell grid in pixels of ``cell`` per cell, cut to ``shape``."""
    return np.repeat(np.repeat(cells, cell, axis=0), cell, axis=1)[: shape[0], : shape[1]]


def _text_regions(edges: np.ndarray, p: MaskParams) -> np.ndarray:
    """Cells full of still edges in small regions within the top and bottom ``overlay_band``."""
    gh = edges.shape[0]
    band = np.zeros(gh, bool)
    rows = int(round(p.overlay_band * gh))
    band[:rows] = True
    band[gh - rows :] = True
    labels, stats = _components((edges >= p.edge_share) & band[:, None])
    keep = (stats[:, 0] >= p.min_text) & (stats[:, 0] <= p.max_overlay * edges.size)
    keep[0] = False
    return keep[labels]


def static_mask(frames: np.ndarray | Iterable[np.ndarray], params: MaskParams = MaskParams()) -> np.ndarray:
    """Parts of the frames that belong to the camera car or the recording, not to the scene.

    The rule, on cells of the grey working image (:class:`MaskParams`): a cell is **still**
    when nearly all its pixels stay within compression noise over the frames,
    and has **moved** when most do not. Nothing is masked unless ``min_moving`` of the cells
    moved: the frames must show the scene going by, so that stillness means riding with the
    camera. Then two kinds of region are masked:

    * a **dark region**: still cells darker than ``dark_level`` and than ``dark_ratio`` of the
      moving scene's median grey, 8-connected, touching the frame border and covering
      ``min_area`` of the frame (bonnet edge, dashboard, windscreen mount); or
    * a **text overlay**: cells of which ``edge_share`` of the pixels are still and lie on strong
      edges of the mean frame (the scene may show between the letters), in a region of
      ``min_text`` cells to ``max_overlay`` of the frame within the top or bottom
      ``overlay_band`` of the rows (timestamps, logos).

    So a still region that is neither dark nor full of edges (sky, an empty road, a bright
    bonnet) is never masked, nor is a dark one inside the picture (a dark car ahead keeping its
    distance), nor anything while the whole scene stands still.

    Parameters
    ----------
    frames : ndarray of uint8, shape (N, H, W, 3), or iterable of (H, W, 3)
        Consecutive frames of one video (a second or less will do while driving).
    params : MaskParams

    Returns
    -------
    ndarray of bool, shape (H, W)
        True on the overlays, in working pixels (``H / height`` frame pixels): a dark region's
        cells, and its still dark pixels within two cells of them (the cells along its outline
        are part scene); a text overlay's cells. All False with fewer than ``min_frames`` frames.
    """
    images = _frame_list(frames)
    h, w = images[0].shape[:2]
    if len(images) < params.min_frames:
        return np.zeros((h, w), bool)
    stack = _grey_stack(images, params.height)
    quiet = stack.max(axis=0) - stack.min(axis=0) <= 2 * params.still_level
    mean = stack.mean(axis=0, dtype=np.float32)
    share = _cell_means(quiet, params.cell)
    still, moved = share >= params.still_share, share < 0.5
    if moved.mean() < params.min_moving:
        return np.zeros((h, w), bool)
    grey = _cell_means(mean, params.cell)
    level = min(params.dark_level, params.dark_ratio * float(np.median(grey[moved])))
    dark = _outline(_dark_regions(still, grey, level, params), quiet & (mean <= level), params.cell)
    gradient = np.hypot(cv2.Sobel(mean, cv2.CV_32F, 1, 0), cv2.Sobel(mean, cv2.CV_32F, 0, 1))
    text = _text_regions(_cell_means(quiet & (gradient >= params.edge_level), params.cell), params)
    work = dark | _upsample(text, params.cell, dark.shape)
    return cv2.resize(work.astype(np.uint8), (w, h), interpolation=cv2.INTER_NEAREST).astype(bool)


# --- both, and windows on the mask -------------------------------------------------------------


@dataclass(frozen=True, eq=False)
class Overlays:
    """What a video's first frames showed besides the scene.

    Attributes
    ----------
    shape : (int, int)
        ``(H, W)`` of the frames.
    area : (int, int, int, int)
        The picture inside black bars (:func:`active_area`), ``(x1, y1, x2, y2)``.
    mask : ndarray of bool, shape (H, W), or None
        Static overlays (:func:`static_mask`) in frame pixels; None when there are none.
    """

    shape: tuple[int, int]
    area: tuple[int, int, int, int]
    mask: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self):
        h, w = shape = tuple(int(v) for v in self.shape)
        x1, y1, x2, y2 = area = tuple(int(v) for v in self.area)
        if not (0 <= x1 < x2 <= w and 0 <= y1 < y2 <= h):
            raise ValueError(f"area {area} is not a box inside frames of {w}x{h}")
        object.__setattr__(self, "shape", shape)
        object.__setattr__(self, "area", area)
        if self.mask is not None:
            mask = np.asarray(self.mask)
            if mask.shape != shape or mask.dtype != bool:
                raise ValueError(f"mask must be bool of shape {shape}; got {mask.dtype} {mask.shape}")
            mask = mask.copy()
            mask.flags.writeable = False
            object.__setattr__(self, "mask", mask)

    @property
    def cropped(self) -> bool:
        """Whether the picture is smaller than the frame."""
        return self.area != (0, 0, self.shape[1], self.shape[0])

    @property
    def masked_share(self) -> float:
        """Share of the picture's pixels that the mask covers."""
        if self.mask is None:
            return 0.0
        x1, y1, x2, y2 = self.area
        return float(self.mask[y1:y2, x1:x2].mean())

    def crop(self, frame: np.ndarray) -> np.ndarray:
        """The picture of ``frame`` (a view)."""
        if frame.shape[:2] != tuple(self.shape):
            raise ValueError(f"frame of {frame.shape[1]}x{frame.shape[0]} pixels; these overlays are of {self.shape[1]}x{self.shape[0]}")
        x1, y1, x2, y2 = self.area
        return frame[y1:y2, x1:x2]

    def describe(self) -> list[str]:
        """One line for the picture when cut from bars, one for the mask when there is one."""
        x1, y1, x2, y2 = self.area
        lines = [f"picture: {x2 - x1}x{y2 - y1} inside black bars"] if self.cropped else []
        if self.mask is not None:
            lines.append(f"static overlay: {100 * self.masked_share:.0f} % of the picture masked")
        return lines


def find_overlays(
    frames: np.ndarray | Iterable[np.ndarray], bars: BarParams = BarParams(), mask: MaskParams = MaskParams()
) -> Overlays:
    """Bars and static overlays of a video's first ``frames`` (the mask measured inside the bars).

    Parameters
    ----------
    frames : ndarray of uint8, shape (N, H, W, 3), or iterable of (H, W, 3)
    bars, mask : BarParams, MaskParams

    Returns
    -------
    Overlays
    """
    images = _frame_list(frames)
    area = active_area(images, bars)
    x1, y1, x2, y2 = area
    inner = static_mask([f[y1:y2, x1:x2] for f in images], mask)
    if not inner.any():
        return Overlays(images[0].shape[:2], area)
    full = np.zeros(images[0].shape[:2], bool)
    full[y1:y2, x1:x2] = inner
    return Overlays(images[0].shape[:2], area, full)


def mask_integral(mask: np.ndarray) -> np.ndarray:
    """Summed-area table of a bool mask (H, W): int32 (H + 1, W + 1), for :func:`mask_share`."""
    out = np.zeros((mask.shape[0] + 1, mask.shape[1] + 1), np.int32)
    np.cumsum(np.cumsum(mask, axis=0, dtype=np.int32), axis=1, out=out[1:, 1:])
    return out


def mask_share(boxes: np.ndarray, integral: np.ndarray) -> np.ndarray:
    """Share of each box's area on the mask of ``integral`` (:func:`mask_integral`).

    Parameters
    ----------
    boxes : ndarray, shape (n, 4)
        Integer ``[x1, y1, x2, y2]``; clipped to the mask.
    integral : ndarray of int32, shape (H + 1, W + 1)

    Returns
    -------
    ndarray of float64, shape (n,)
        In ``[0, 1]``; 0 for boxes of no area inside the mask.
    """
    h, w = integral.shape[0] - 1, integral.shape[1] - 1
    b = np.clip(np.asarray(boxes, np.int64).reshape(-1, 4), 0, [w, h, w, h])
    x1, y1, x2, y2 = b.T
    inside = integral[y2, x2] - integral[y1, x2] - integral[y2, x1] + integral[y1, x1]
    area = (x2 - x1) * (y2 - y1)
    return np.where(area > 0, inside / np.maximum(area, 1), 0.0)
