"""A look at a whole run: one self-contained HTML page, and the one-line summary of each input.

:func:`write_html_report` turns a run's boxes table (the CSV of ``detect --boxes``, or a
:class:`~vehicle_detection.detections.Detections`), with the video it came from and the lanes
table when there are ones, into one HTML file that any browser opens from disk:

* a track timeline: the frames in which each tracked vehicle was reported;
* a contact sheet: every track's first, middle and last box on its vehicle, cut from the video
  (boxes of frames in which the track was matched to a blob: not those it coasted through);
* the number of boxes in each frame;
* with distances (``detect --lanes``), each tracked vehicle's distance over time, each line
  labelled with its track id;
* with a lanes table, the radius of curvature and the lane-centre offset over time.

Cuts between shots (:mod:`~vehicle_detection.footage.shots`: the run's own, else found in the video) are
dashed vertical lines on every chart over frames.

Figures are drawn with matplotlib (``pip install "vehicle-detection[report]"``) and embedded as
PNG ``data:`` URIs, the crops as JPEG ones; the page has no script, loads nothing from the
network and needs no server.

:func:`summarize` gives what ``detect`` prints at the end of each input: frames, vehicles
(tracks), boxes, mean speed and the outputs written, as a line (:meth:`RunSummary.line`) and as
a JSON-ready dict (:meth:`RunSummary.to_dict`).
"""

from __future__ import annotations

import base64
import html
import io
import os
from collections.abc import Iterable, Mapping, Sequence
from contextlib import closing
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ..io import plural
from ..detections import Detections
from ..errors import InputError, require
from ..io import atomic_output, check_output_path
from ..io.tables import read_boxes_csv, read_lanes_csv
from ..io.video import probe_video, read_frames
from ..footage.shots import ShotCuts, next_shot

__all__ = ["RunSummary", "summarize", "render_html_report", "write_html_report", "track_spans", "matched_rows", "CROP_HEIGHT",
           "MAX_TRACKS"]

#: Height in pixels of each crop of the contact sheet.
CROP_HEIGHT = 96
#: Tracks shown on the contact sheet at most (the longest ones); the timeline shows them all.
MAX_TRACKS = 150


# --------------------------------------------------------------------------------------------
# The summary line
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RunSummary:
    """What one input of a ``detect`` run gave.

    Attributes
    ----------
    input : str
        The input (a video, an image or a folder of images).
    frames : int
        Every frame (or image) processed, with boxes or without.
    boxes : int
        Boxes reported.
    tracks : int or None
        Distinct tracked vehicles (track ids >= 0); None when the boxes are not tracked (images).
    seconds : float or None
        Wall time, when known.
    outputs : tuple of str
        The files written.
    unit : str
        ``"frame"`` (a video) or ``"image"`` (an image or a folder of images).
    """

    input: str
    frames: int
    boxes: int
    tracks: int | None = None
    seconds: float | None = None
    outputs: tuple[str, ...] = ()
    unit: str = "frame"

    def __post_init__(self) -> None:
        if self.unit not in ("frame", "image"):
            raise ValueError(f"unit must be 'frame' or 'image'; got {self.unit!r}")
        for name in ("frames", "boxes"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < 0:
                raise ValueError(f"{name} must be an integer >= 0; got {value!r}")
        if self.tracks is not None and (isinstance(self.tracks, bool) or not isinstance(self.tracks, (int, np.integer)) or self.tracks < 0):
            raise ValueError(f"tracks must be an integer >= 0 or None; got {self.tracks!r}")
        if self.seconds is not None and not (np.isfinite(self.seconds) and self.seconds >= 0):
            raise ValueError(f"seconds must be a finite number >= 0 or None; got {self.seconds!r}")
        object.__setattr__(self, "frames", int(self.frames))
        object.__setattr__(self, "boxes", int(self.boxes))
        object.__setattr__(self, "tracks", None if self.tracks is None else int(self.tracks))
        object.__setattr__(self, "outputs", tuple(str(o) for o in self.outputs))

    @property
    def fps(self) -> float | None:
        """Mean frames (images) per second of wall time; None when the time is unknown or 0."""
        if not self.seconds:
            return None
        return self.frames / self.seconds

    def line(self) -> str:
        """One line for people, e.g. ``clip.mp4: 38 frames, 2 vehicles, 76 boxes, 4.1 fps (9.3 s); wrote a.mp4, a.csv``.

        Examples
        --------
        >>> RunSummary("clip.mp4", 1, 1, tracks=1, seconds=0.5, outputs=["b.csv"]).line()
        'clip.mp4: 1 frame, 1 vehicle, 1 box, 2.0 fps (0.5 s); wrote b.csv'
        >>> RunSummary("shots", 3, 0, unit="image").line()
        'shots: 3 images, 0 boxes; nothing written'
        """
        parts = [plural(self.frames, self.unit)]
        if self.tracks is not None:
            parts.append(plural(self.tracks, "vehicle"))
        parts.append(plural(self.boxes, "box", "boxes"))
        if self.fps is not None:
            rate = f"{self.fps:.1f} fps" if self.unit == "frame" else f"{self.fps:.1f} images/s"
            parts.append(f"{rate} ({self.seconds:.1f} s)")
        written = "wrote " + ", ".join(self.outputs) if self.outputs else "nothing written"
        return f"{self.input}: {', '.join(parts)}; {written}"

    def to_dict(self) -> dict[str, Any]:
        """The same as a JSON-ready dict.

        Keys: ``input`` (str), ``unit`` (``"frame"`` or ``"image"``), ``frames``, ``boxes`` (int),
        ``tracks`` (int, or None when untracked), ``seconds`` and ``fps`` (float or None),
        ``outputs`` (list of str).
        """
        return {
            "input": self.input,
            "unit": self.unit,
            "frames": self.frames,
            "tracks": self.tracks,
            "boxes": self.boxes,
            "seconds": None if self.seconds is None else round(float(self.seconds), 3),
            "fps": None if self.fps is None else round(self.fps, 3),
            "outputs": list(self.outputs),
        }


def summarize(
    input: str | os.PathLike,
    detections: Detections,
    *,
    frames: int,
    seconds: float | None = None,
    outputs: Iterable[str | os.PathLike] = (),
    unit: str = "frame",
    first: int = 0,
) -> RunSummary:
    """The summary of one input's run.

    Parameters
    ----------
    input : path-like
        The input, as the user named it.
    detections : Detections
        Every box the run reported for the input.
    frames : int
        Frames (images) processed: all of them, with boxes or without (the boxes table cannot
        tell, since frames without boxes have no rows).
    seconds : float, optional
        Wall time.
    outputs : iterable of path-like
        The files written.
    unit : {"frame", "image"}
    first : int
        The first frame processed (``detect --start``): the boxes lie in frames ``first`` to
        ``first + frames - 1``.

    Returns
    -------
    RunSummary

    Raises
    ------
    ValueError
        If a box lies outside the frames processed.

    Examples
    --------
    >>> d = Detections([[0, 0, 64, 64], [4, 0, 68, 64]], track_id=[0, 0], frame=[0, 1])
    >>> summarize("clip.mp4", d, frames=25).line()
    'clip.mp4: 25 frames, 1 vehicle, 2 boxes; nothing written'
    """
    if len(detections):
        lo, hi = int(detections.frame.min()), int(detections.frame.max())
        if lo < first or hi >= first + frames:
            raise ValueError(f"a box lies in frame {lo if lo < first else hi}, but only frames {first} to {first + frames - 1} "
                             "were processed")
    tracks = None
    if detections.track_id is not None:
        tracks = len(np.unique(detections.track_id[detections.track_id >= 0]))
    return RunSummary(str(input), frames, len(detections), tracks, seconds, tuple(str(o) for o in outputs), unit)


# --------------------------------------------------------------------------------------------
# Tracks
# --------------------------------------------------------------------------------------------


def track_spans(detections: Detections) -> dict[int, np.ndarray]:
    """The rows of each track, in frame order.

    Parameters
    ----------
    detections : Detections
        A tracked table (rows with track id -1 are left out).

    Returns
    -------
    dict of int to ndarray of int64
        Track id -> indexes of its rows, frames increasing; tracks by their first frame, then id.

    Examples
    --------
    >>> d = Detections([[0, 0, 9, 9]] * 3, track_id=[5, 2, 5], frame=[3, 1, 0])
    >>> {k: v.tolist() for k, v in track_spans(d).items()}
    {5: [2, 0], 2: [1]}
    """
    if detections.track_id is None:
        return {}
    ids = detections.track_id
    order = np.lexsort((detections.frame, ids))
    order = order[ids[order] >= 0]
    tracks, starts = np.unique(ids[order], return_index=True)
    groups = dict(zip(tracks.tolist(), np.split(order, starts[1:]))) if len(order) else {}
    return dict(sorted(groups.items(), key=lambda kv: (int(detections.frame[kv[1][0]]), kv[0])))


def matched_rows(detections: Detections, rows: np.ndarray) -> np.ndarray:
    """Which of a track's rows hold a box the tracker matched to a blob (not one it coasted through).

    A confirmed track's score is the peak heat of the blob last matched to it
    (:meth:`~vehicle_detection.tracker.Tracker.update`): a row with the score of the row before
    it, frames later, is a frame the track coasted through on its predicted box, which may have
    left its vehicle (the last rows of most tracks). The rows the tracker back-filled when it
    confirmed the track carry the confirming frame's score: the leading run of equal scores is
    matched.

    Parameters
    ----------
    detections : Detections
        A tracked table.
    rows : ndarray of int, shape (k,)
        One track's rows, frames increasing (:func:`track_spans`).

    Returns
    -------
    ndarray of bool, shape (k,)

    Examples
    --------
    >>> d = Detections([[0, 0, 9, 9]] * 6, score=[4, 4, 4, 5, 5, 5], track_id=0, frame=range(6))
    >>> matched_rows(d, np.arange(6)).tolist()
    [True, True, True, True, False, False]
    """
    rows = np.asarray(rows, np.int64)
    score = detections.score[rows]
    same = np.r_[False, score[1:] == score[:-1]]
    lead = int(np.argmin(same[1:])) + 1 if len(rows) > 1 and not same[1:].all() else len(rows)
    same[:lead] = False
    return ~same


def _runs(frames: np.ndarray) -> list[tuple[int, int]]:
    """``(start, length)`` of each run of consecutive frames in sorted ``frames``."""
    if not len(frames):
        return []
    breaks = np.flatnonzero(np.diff(frames) != 1) + 1
    return [(int(r[0]), len(r)) for r in np.split(frames, breaks)]


# --------------------------------------------------------------------------------------------
# Figures
# --------------------------------------------------------------------------------------------


def _figure_module():

    return require("matplotlib.figure", "report", "the HTML report")


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=100, metadata={"Software": None})
    return "data:image/png;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _mark_cuts(ax, cuts: Sequence[int], *, text: bool = False) -> None:
    """Dashed vertical lines between each cut's frame and the frame before it; with ``text``, "cut" above each."""
    for c in cuts:
        ax.axvline(c - 0.5, color="0.25", ls="--", lw=1.0, zorder=3, gid=f"cut-{c}")
        if text:
            ax.annotate("cut", (c - 0.5, 1.0), xycoords=("data", "axes fraction"), xytext=(2, 2), textcoords="offset points",
                        fontsize=7, color="0.25", va="bottom")


def _timeline(detections: Detections, spans: Mapping[int, np.ndarray], n_frames: int, cuts: Sequence[int] = ()):
    Figure = _figure_module().Figure
    n = len(spans)
    fig = Figure(figsize=(9.0, min(1.2 + 0.22 * n, 14.0)), layout="constrained")
    ax = fig.add_subplot()
    colors = [f"C{i % 10}" for i in range(n)]
    for row, (tid, idx) in enumerate(spans.items()):
        ax.broken_barh([(a - 0.5, n) for a, n in _runs(detections.frame[idx])], (row - 0.4, 0.8), color=colors[row])
    ax.set_yticks(range(n), [f"car {t}" for t in spans], fontsize=7 if n > 30 else 9)
    ax.set_ylim(n - 0.5, -0.5)
    ax.set_xlim(-0.5, max(n_frames, 1) - 0.5)
    ax.set_xlabel("frame")
    ax.set_title("track timeline: frames in which each vehicle is reported" + (" (dashed: cuts between shots)" if cuts else ""),
                 pad=14 if cuts else None)
    ax.grid(axis="x", alpha=0.3)
    _mark_cuts(ax, cuts, text=True)
    return fig


def _count_steps(frames: np.ndarray, n_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """Boxes per frame as steps ``(values, edges)`` for ``Axes.stairs``: frame i spans
    [i - 0.5, i + 0.5], as on the timeline; the frames without a box are runs of zero between
    the frames with boxes, so the size follows the rows, not the frame numbers (a row at frame
    2**31 - 1 costs what a row at frame 10 costs)."""
    frames_with, counts = np.unique(np.asarray(frames, np.int64), return_counts=True)
    ends = np.r_[-0.5, np.repeat(frames_with, 2) + np.tile([-0.5, 0.5], len(frames_with)), max(n_frames, 1) - 0.5]
    values = np.zeros(len(ends) - 1, np.int64)
    values[1::2][: len(counts)] = counts
    keep = np.r_[True, np.diff(ends) > 0]  # drop the empty steps between neighbouring frames
    ends, values = ends[keep], values[keep[1:]]
    return values, ends


def _boxes_per_frame(detections: Detections, n_frames: int, cuts: Sequence[int] = ()):
    Figure = _figure_module().Figure
    counts, edges = _count_steps(detections.frame, n_frames)
    fig = Figure(figsize=(9.0, 2.6), layout="constrained")
    ax = fig.add_subplot()
    ax.stairs(counts, edges, fill=True, alpha=0.25, color="C0")
    ax.stairs(counts, edges, color="C0")
    ax.set_xlim(-0.5, max(n_frames, 1) - 0.5)
    ax.set_ylim(0, max(int(counts.max(initial=0)), 1) + 0.5)
    ax.yaxis.get_major_locator().set_params(integer=True)
    ax.set_xlabel("frame")
    ax.set_ylabel("boxes")
    ax.set_title("boxes per frame")
    ax.grid(alpha=0.3)
    _mark_cuts(ax, cuts)
    return fig


def _distances(detections: Detections, spans: Mapping[int, np.ndarray], n_frames: int, cuts: Sequence[int] = ()):
    """Each track's distance over the frames, in its timeline row's colour, labelled with its id
    at its last known distance (colours repeat every ten tracks; the labels do not)."""
    Figure = _figure_module().Figure
    dist = np.asarray(detections.data["distance_m"], np.float64)
    fig = Figure(figsize=(9.0, 3.2 if len(spans) <= 12 else 4.4), layout="constrained")
    ax = fig.add_subplot()
    ends = []  # (frame, distance, id, colour) of each line's last known point
    for row, (tid, idx) in enumerate(spans.items()):
        known = np.isfinite(dist[idx])
        if known.any():
            color = f"C{row % 10}"
            ax.plot(detections.frame[idx], dist[idx], ".-", ms=3, lw=1, color=color, label=f"car {tid}")
            last = idx[np.flatnonzero(known)[-1]]
            ends.append((float(detections.frame[last]), float(dist[last]), tid, color))
    if ends:
        lo, hi = min(e[1] for e in ends), max(e[1] for e in ends)
        for (x, y, tid, color), ty in zip(ends, _spread_labels(ends, max(n_frames, 1) / 60, max(hi - lo, 1.0) / 25)):
            ax.annotate(str(tid), (x, y), xytext=(x + max(n_frames, 1) / 300, ty), textcoords="data", fontsize=7, color=color,
                        va="center", gid=f"track-{tid}")
    ax.set_xlim(-0.5, max(n_frames, 1) - 0.5)
    ax.set_xlabel("frame")
    ax.set_ylabel("distance (m)")
    ax.set_title("distance of each tracked vehicle (each line labelled with its track id at its end)")
    ax.grid(alpha=0.3)
    _mark_cuts(ax, cuts)
    return fig


def _spread_labels(ends: Sequence[tuple], near_x: float, step_y: float) -> list[float]:
    """Heights of labels at points ``(x, y, ...)``: labels closer than ``near_x`` along x, in a
    chain, are moved apart in y to ``step_y`` at least, about their mean height."""
    heights = [float(e[1]) for e in ends]
    order = sorted(range(len(ends)), key=lambda i: ends[i][0])
    groups, current = [], [order[0]] if order else []
    for a, b in zip(order, order[1:]):
        if ends[b][0] - ends[a][0] < near_x:
            current.append(b)
        else:
            groups.append(current)
            current = [b]
    if current:
        groups.append(current)
    for group in groups:
        group = sorted(group, key=lambda i: heights[i])
        ys = [heights[i] for i in group]
        for k in range(1, len(ys)):
            ys[k] = max(ys[k], ys[k - 1] + step_y)
        shift = (sum(heights[i] for i in group) - sum(ys)) / len(ys)  # keep the group's mean height
        for i, y in zip(group, ys):
            heights[i] = y + shift
    return heights


def _lanes_figure(lanes: Mapping[str, np.ndarray], n_frames: int, cuts: Sequence[int] = ()):
    Figure = _figure_module().Figure
    fig = Figure(figsize=(9.0, 4.4), layout="constrained")
    top, bottom = fig.subplots(2, 1, sharex=True)
    frames = lanes["frame"]
    radius = lanes["curvature_m"]
    shown = np.where(radius > 0, radius, np.nan)
    top.plot(frames, shown, color="C1", lw=1.2)
    if np.isfinite(shown).any():
        top.set_yscale("log")
    top.set_ylabel("radius (m)")
    top.set_title("lanes: radius of curvature and offset from the lane centre")
    bottom.plot(frames, lanes["offset_m"], color="C2", lw=1.2)
    bottom.axhline(0.0, color="0.5", lw=0.8)
    bottom.set_ylabel("offset (m, + right)")
    bottom.set_xlabel("frame")
    bottom.set_xlim(-0.5, max(n_frames, int(frames.max(initial=0)) + 1, 1) - 0.5)
    for ax in (top, bottom):
        ax.grid(alpha=0.3)
        _mark_cuts(ax, cuts)
    return fig


# --------------------------------------------------------------------------------------------
# Crops
# --------------------------------------------------------------------------------------------


def _picks(detections: Detections, spans: Mapping[int, np.ndarray], limit: int) -> dict[int, list[int]]:
    """Rows of the first, middle and last matched box (:func:`matched_rows`) of the ``limit``
    longest tracks (distinct rows)."""
    longest = sorted(spans, key=lambda t: (-len(spans[t]), t))[:limit]
    keep = set(longest)
    out = {}
    for tid, idx in spans.items():
        if tid in keep:
            on = idx[matched_rows(detections, idx)]
            out[tid] = [int(i) for i in dict.fromkeys([on[0], on[len(on) // 2], on[-1]])]
    return out


def _encode_jpeg(crop: np.ndarray) -> str:
    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(crop).save(buf, format="JPEG", quality=85)
    return "data:image/jpeg;base64," + base64.b64encode(buf.getvalue()).decode("ascii")


def _crop(frame: np.ndarray, box: Sequence[int]) -> np.ndarray:
    """The box's pixels (clipped to the frame) scaled to :data:`CROP_HEIGHT` rows."""
    from PIL import Image

    h, w = frame.shape[:2]
    x1, y1, x2, y2 = (int(v) for v in box)
    x1, x2 = min(max(x1, 0), w - 1), min(max(x2, 1), w)
    y1, y2 = min(max(y1, 0), h - 1), min(max(y2, 1), h)
    patch = frame[y1 : max(y2, y1 + 1), x1 : max(x2, x1 + 1)]
    width = max(1, min(3 * CROP_HEIGHT, round(patch.shape[1] * CROP_HEIGHT / patch.shape[0])))
    return np.asarray(Image.fromarray(patch).resize((width, CROP_HEIGHT), Image.Resampling.BILINEAR))


def _cut_crops(video: Path, detections: Detections, rows: Iterable[int], *, cuts_before: int = 0) -> tuple[dict[int, np.ndarray], list[int]]:
    """Crop of each row's box from ``video``, decoding up to the last frame needed; and the cuts
    between shots (:func:`~vehicle_detection.footage.shots.next_shot`, default rule) in the first
    ``cuts_before`` frames, decoding those too."""

    wanted: dict[int, list[int]] = {}
    for r in rows:
        wanted.setdefault(int(detections.frame[r]), []).append(r)
    crops: dict[int, np.ndarray] = {}
    cuts: list[int] = []
    last = max(wanted, default=-1)
    if last < 0 and cuts_before <= 0:
        return crops, cuts
    seen, shot, rule = 0, (None, ()), ShotCuts()
    with closing(read_frames(video)) as frames:
        for index, frame in enumerate(frames):
            seen = index + 1
            for r in wanted.get(index, ()):
                crops[r] = _crop(frame, detections.xyxy[r])
            if index < cuts_before:
                cut, *shot = next_shot(frame, *shot, rule)
                if cut:
                    cuts.append(index)
            if index >= max(last, cuts_before - 1):
                break
    if seen <= last:
        raise InputError(f"{video}: has {seen} frames, but the boxes name frame {last}; are these the boxes of this video?")
    return crops, cuts


# --------------------------------------------------------------------------------------------
# The page
# --------------------------------------------------------------------------------------------

_STYLE = """
body { font-family: system-ui, -apple-system, "Segoe UI", Roboto, sans-serif; margin: 1.5em auto; max-width: 980px;
       color: #1d1d1f; padding: 0 1em; }
h1 { font-size: 1.5em; margin-bottom: 0.2em; } h2 { font-size: 1.15em; margin-top: 1.8em; border-bottom: 1px solid #ddd; }
table { border-collapse: collapse; } td, th { padding: 3px 10px; text-align: left; vertical-align: middle; }
table.facts td:first-child { color: #666; }
table.sheet tr:nth-child(even) { background: #f5f5f7; }
figure { display: inline-block; margin: 2px 6px; text-align: center; }
figcaption { font-size: 0.75em; color: #555; }
img.plot { max-width: 100%; height: auto; }
p.note { color: #666; font-size: 0.9em; }
"""


def _img(src: str, alt: str, *, cls: str = "", size: tuple[int, int] | None = None) -> str:
    attrs = f' class="{cls}"' if cls else ""
    if size is not None:
        attrs += f' width="{size[0]}" height="{size[1]}"'
    return f'<img src="{src}" alt="{html.escape(alt)}"{attrs}>'


def _figure_img(fig, alt: str) -> str:
    w, h = (int(round(v * 100)) for v in fig.get_size_inches())
    return _img(_png(fig), alt, cls="plot", size=(w, h))


def _as_detections(boxes) -> tuple[Detections, str | None]:
    if isinstance(boxes, Detections):
        return boxes, None
    if isinstance(boxes, (str, os.PathLike)):

        return read_boxes_csv(boxes), str(boxes)
    raise TypeError(f"boxes must be a boxes CSV's path or a Detections; got {type(boxes).__name__}")


def _as_lanes(lanes) -> tuple[dict[str, np.ndarray] | None, str | None]:
    if lanes is None:
        return None, None
    if isinstance(lanes, (str, os.PathLike)):

        return read_lanes_csv(lanes), str(lanes)
    if isinstance(lanes, Mapping):
        missing = [k for k in ("frame", "curvature_m", "offset_m") if k not in lanes]
        if missing:
            raise ValueError(f"lanes needs the columns frame, curvature_m and offset_m; missing {', '.join(missing)}")
        return {k: np.asarray(lanes[k], np.int64 if k == "frame" else np.float64) for k in ("frame", "curvature_m", "offset_m")}, None
    rows = [tuple(r) for r in lanes]  # (frame, radius, offset) rows as lanes.lane_row gives
    arr = np.array([[np.nan if v is None else v for v in r] for r in rows], np.float64).reshape(-1, 3)
    return {"frame": arr[:, 0].astype(np.int64), "curvature_m": arr[:, 1], "offset_m": arr[:, 2]}, None


def _frame_count(detections: Detections, n_frames, lane_table, info) -> tuple[int, str]:
    """How many frames the run had, and how that is known (a note for the page)."""
    last = int(detections.frame.max()) + 1 if len(detections) else 0
    if n_frames is not None:
        if isinstance(n_frames, bool) or not isinstance(n_frames, (int, np.integer)) or n_frames < 0:
            raise ValueError(f"n_frames must be an integer >= 0; got {n_frames!r}")
        if n_frames < last:
            raise ValueError(f"n_frames is {n_frames}, but the boxes name frame {last - 1}")
        return int(n_frames), ""
    if lane_table is not None and len(lane_table["frame"]):
        return max(len(lane_table["frame"]), last), " (one lanes row per frame)"
    if info is not None and info.n_frames:
        return max(int(info.n_frames), last), " (as the video declares)"
    return last, " (at least: up to the last frame with a box)"


def _tracks_fact(spans: Mapping[int, np.ndarray]) -> str:
    """How many tracks the page shows, and the ids they have: the tracker numbers every
    candidate, also those never confirmed as a vehicle, whose ids are then missing."""
    if not spans:
        return "0"
    ids = sorted(spans)
    lo, hi = ids[0], ids[-1]
    if lo == hi:
        return f"1 (id {lo})"
    missing = hi - lo + 1 - len(ids)
    if not missing:
        return f"{len(ids)} (ids {lo} to {hi})"
    return (f"{len(ids)} (ids {lo} to {hi}: the tracker numbers every candidate, and {missing} "
            f"{'candidate was' if missing == 1 else 'candidates were'} never confirmed as vehicles)")


def _cuts_fact(cuts: Sequence[int] | None, source: str) -> list[tuple[str, str]]:
    if cuts is None:
        return []
    if not cuts:
        return [("cuts between shots", f"none{source}")]
    return [("cuts between shots", f"{len(cuts)}: {'frame' if len(cuts) == 1 else 'frames'} {', '.join(map(str, cuts))}{source} "
             "(dashed lines on the charts)")]


def _facts(detections, spans, frames, frames_note, video, info, boxes_name, lanes_name, cuts=None, cuts_source="") -> list[tuple[str, str]]:
    facts = [("frames", f"{frames}{frames_note}"), ("boxes", str(len(detections)))]
    facts.append(("vehicles tracked", _tracks_fact(spans) if detections.track_id is not None else "untracked boxes"))
    facts += _cuts_fact(cuts, cuts_source)
    if info is not None:
        facts.append(("video", f"{video} ({info.width}x{info.height}, {info.fps:.2f} fps)"))
    if boxes_name:
        facts.append(("boxes table", boxes_name))
    if lanes_name:
        facts.append(("lanes table", lanes_name))
    if len(detections) and "file" in detections.data:
        facts.append(("images", str(len(np.unique(detections.data["file"])))))
    return facts


def _timeline_section(detections, spans, frames, cuts=()) -> list[str]:
    body = ["<h2>Track timeline</h2>"]
    if spans:
        body.append(_figure_img(_timeline(detections, spans, frames, cuts), "track timeline"))
    else:
        body.append('<p class="note">No tracks: ' + ("the boxes are not tracked." if detections.track_id is None else "no vehicle was tracked.") + "</p>")
    return body


def _sheet_cell(detections, r: int, tid: int, crops: dict) -> str:
    x1, y1, x2, y2 = detections.xyxy[r].tolist()
    caption = f"frame {int(detections.frame[r])}, {x2 - x1}x{y2 - y1}"
    if r not in crops:
        return f"<figure><figcaption>{html.escape(caption)} at ({x1}, {y1})</figcaption></figure>"
    crop = crops[r]
    pic = _img(_encode_jpeg(crop), f"car {tid}, {caption}", size=(crop.shape[1], crop.shape[0]))
    return f"<figure>{pic}<figcaption>{html.escape(caption)}</figcaption></figure>"


def _sheet_section(detections, spans, video, picks, crops) -> list[str]:
    body = ["<h2>Contact sheet: each track's first, middle and last box</h2>"]
    if not spans:
        return body + ['<p class="note">No tracks to show.</p>']
    body.append('<p class="note">Boxes of frames in which the track was matched to a detection; not those it coasted '
                "through on its predicted box (after its car was lost).</p>")
    if video is None:
        body.append('<p class="note">No video given: the boxes without their pictures.</p>')
    if len(picks) < len(spans):
        body.append(f'<p class="note">The {len(picks)} longest of {len(spans)} tracks.</p>')
    body.append('<table class="sheet"><tr><th>track</th><th>frames</th><th>boxes</th><th>first, middle, last</th></tr>')
    for tid, rows in picks.items():
        idx = spans[tid]
        cells = "".join(_sheet_cell(detections, r, tid, crops) for r in rows)
        first, end = int(detections.frame[idx[0]]), int(detections.frame[idx[-1]])
        body.append(f"<tr><td>car {tid}</td><td>{first}&ndash;{end}</td><td>{len(idx)}</td><td>{cells}</td></tr>")
    body.append("</table>")
    return body


def _counts_section(detections, frames, cuts=()) -> list[str]:
    mean = f"{len(detections) / frames:.2f}" if frames else "no"
    empty = frames - len(np.unique(detections.frame))
    return [
        "<h2>Boxes per frame</h2>",
        _figure_img(_boxes_per_frame(detections, frames, cuts), "boxes per frame"),
        f'<p class="note">{mean} boxes per frame on average; frames without any: {empty}.</p>',
    ]


def _distance_section(detections, spans, frames, cuts=()) -> list[str]:
    if not (spans and "distance_m" in detections.data):
        return []
    dist = np.asarray(detections.data["distance_m"], np.float64)
    known = np.isfinite(dist)
    note = f"distance known for {int(known.sum())} of {len(dist)} boxes"
    if known.any():
        note += f", {dist[known].min():.1f} to {dist[known].max():.1f} m"
    shown = [t for t, idx in spans.items() if known[idx].any()]
    if shown:
        note += f"; each line is labelled with its track id at its end ({', '.join(f'car {t}' for t in shown)})"
    return ["<h2>Distances</h2>", _figure_img(_distances(detections, spans, frames, cuts), "distance of each tracked vehicle"),
            f'<p class="note">{html.escape(note)}.</p>']


def _lanes_section(lane_table, frames, cuts=()) -> list[str]:
    if lane_table is None:
        return []
    if not len(lane_table["frame"]):
        return ["<h2>Lanes</h2>", '<p class="note">The lanes table has no rows.</p>']
    radius, offset = lane_table["curvature_m"], lane_table["offset_m"]
    found = np.isfinite(radius)
    note = f"no lane in {int((~found).sum())} of {len(radius)} frames"
    if found.any():
        note += (f"; median radius {np.median(radius[found]):,.0f} m, offset {np.nanmin(offset):+.2f} to "
                 f"{np.nanmax(offset):+.2f} m (+ right of the lane centre)")
    return ["<h2>Lanes</h2>", _figure_img(_lanes_figure(lane_table, frames, cuts), "radius of curvature and offset"), f'<p class="note">{note}.</p>']


def render_html_report(
    boxes: Detections | str | os.PathLike,
    *,
    video: str | os.PathLike | None = None,
    lanes: str | os.PathLike | Mapping[str, Any] | Iterable[tuple] | None = None,
    n_frames: int | None = None,
    title: str | None = None,
    max_tracks: int = MAX_TRACKS,
    cuts: Iterable[int] | None = None,
) -> str:
    """The HTML report of a run, as text (see :func:`write_html_report`)."""
    detections, boxes_name = _as_detections(boxes)
    lane_table, lanes_name = _as_lanes(lanes)
    _figure_module()  # fail before any decoding when matplotlib is missing
    video = Path(video) if video is not None else None
    info = probe_video(video) if video is not None else None
    frames, frames_note = _frame_count(detections, n_frames, lane_table, info)
    spans = track_spans(detections)
    picks = _picks(detections, spans, max_tracks)
    wanted = [r for rows in picks.values() for r in rows]
    find = cuts is None and video is not None
    crops, found = _cut_crops(video, detections, wanted, cuts_before=frames if find else 0) if video is not None else ({}, [])
    cuts = found if find else None if cuts is None else sorted({int(c) for c in cuts})
    source = ", found in the video" if find else ""
    shown_cuts = [c for c in cuts or () if 0 < c < frames]
    name = title or (video.name if video is not None else Path(boxes_name).name if boxes_name else "detections")
    facts = _facts(detections, spans, frames, frames_note, video, info, boxes_name, lanes_name, cuts, source)
    body = [f"<h1>{html.escape(name)}</h1>", '<table class="facts">']
    body += [f"<tr><td>{html.escape(k)}</td><td>{html.escape(v)}</td></tr>" for k, v in facts]
    body.append("</table>")
    body += _timeline_section(detections, spans, frames, shown_cuts)
    body += _sheet_section(detections, spans, video, picks, crops)
    body += _counts_section(detections, frames, shown_cuts)
    body += _distance_section(detections, spans, frames, shown_cuts)
    body += _lanes_section(lane_table, frames, shown_cuts)
    return (
        "<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\">\n"
        f"<title>{html.escape(name)}: vehicle-detection report</title>\n<style>{_STYLE}</style>\n</head>\n<body>\n"
        + "\n".join(body)
        + "\n</body>\n</html>\n"
    )


def write_html_report(
    path: str | os.PathLike,
    boxes: Detections | str | os.PathLike,
    *,
    video: str | os.PathLike | None = None,
    lanes: str | os.PathLike | Mapping[str, Any] | Iterable[tuple] | None = None,
    n_frames: int | None = None,
    title: str | None = None,
    max_tracks: int = MAX_TRACKS,
    cuts: Iterable[int] | None = None,
    overwrite: bool = False,
) -> Path:
    """Write one self-contained HTML page about a run, atomically.

    Parameters
    ----------
    path : path-like
        The HTML file to write; missing parent folders are created.
    boxes : Detections or path-like
        The run's boxes, or the path of its boxes CSV (:func:`~vehicle_detection.tables.read_boxes_csv`).
    video : path-like, optional
        The video the boxes are of: the contact sheet's crops are cut from it (decoding up to
        the last frame needed), and its size and frame rate are shown. Boxes of a run with
        ``--camera`` lie on undistorted frames, so their crops from the raw video are off by
        the lens distortion near the edges.
    lanes : path-like, mapping or iterable of rows, optional
        The lanes CSV (``frame,curvature_m,offset_m``), those columns as a mapping of arrays,
        or ``(frame, radius_m, offset_m)`` rows as :func:`~vehicle_detection.lanes.lane_row`
        gives (None for no lane).
    n_frames : int, optional
        Frames of the run. Otherwise the lanes table's rows (one per frame), else the frame
        count the video declares, else the frames up to the last with a box.
    title : str, optional
        The page's heading (default: the video's or the CSV's file name).
    max_tracks : int
        Tracks on the contact sheet at most (the longest); every track is on the timeline.
    cuts : iterable of int, optional
        The frames at which the run's footage cut to another shot
        (:attr:`TrackerState.cuts <vehicle_detection.tracker.TrackerState.cuts>`), marked on
        the charts. Default: found in ``video`` (:func:`~vehicle_detection.footage.shots.next_shot`
        with the default :class:`~vehicle_detection.footage.shots.ShotCuts`, decoding every frame of
        the run), else none marked.
    overwrite : bool
        Replace an existing file at ``path``.

    Returns
    -------
    Path
        ``path``.

    Raises
    ------
    InputError
        If the boxes CSV, the lanes CSV or the video cannot be read, or the video has fewer
        frames than the boxes name.
    OutputError
        If ``path`` exists (without ``overwrite``), is an input, or cannot be written; nothing
        is left under ``path`` on failure.
    MissingDependencyError
        If matplotlib is not installed (``pip install "vehicle-detection[report]"``).

    Examples
    --------
    >>> import tempfile
    >>> d = Detections([[10, 10, 74, 74], [12, 10, 76, 74]], track_id=[0, 0], frame=[3, 4])
    >>> with tempfile.TemporaryDirectory() as tmp:
    ...     page = write_html_report(Path(tmp) / "report.html", d, n_frames=10).read_text()
    >>> page.count("<img"), "frames without any: 8" in page
    (2, True)

    With the run's files: ``write_html_report("report.html", "clip_boxes.csv", video="clip.mp4")``.
    """

    inputs = [p for p in (boxes, video, lanes) if isinstance(p, (str, os.PathLike))]
    check_output_path(path, overwrite=overwrite, inputs=inputs)  # before the work
    text = render_html_report(boxes, video=video, lanes=lanes, n_frames=n_frames, title=title, max_tracks=max_tracks, cuts=cuts)
    with atomic_output(path, overwrite=overwrite, inputs=inputs) as tmp:
        tmp.write_text(text, encoding="utf-8", newline="\n")
    return Path(path)
