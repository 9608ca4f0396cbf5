"""The evaluation report folder: per-camera tables and contact sheets of the failures.

``vehicle-detection evaluate --report DIR`` writes, into ``DIR``:

* ``cameras.md`` and ``cameras.csv``: one row per camera (:func:`camera_rows`), and a last row
  ``all`` when there are several cameras;
* ``failures_<camera>.png``: one contact sheet per camera, a 256-colour PNG
  (:func:`camera_sheet`), with a tile for every miss, false positive and loose match
  (:func:`~vehicle_detection.metrics.detection.find_failures`) of the camera's labels files, at most
  ``limit`` tiles (:func:`select_failures`: misses and false positives first).

The frames of the tiles are read again from the labelled video or images, after scoring: a video
is decoded from its start up to the last frame needed, and each needed frame is cut into its
tiles at once and dropped, so memory holds tiles (about 150 kB each), never the frames of a
video.
"""

from __future__ import annotations

import os
from collections.abc import Collection, Iterable, Iterator, Mapping, Sequence
from contextlib import closing
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image

from ..io import plural
from ..detections import Detections
from ..errors import InputError, OutputError, output_exists
from ..io import atomic_output, output_batch
from ..io.images import list_images, read_image
from ..io.video import probe_video, read_frames
from ..viz.drawing import SHEET_COLORS, failure_sheet, failure_tile
from .detection import FAILURE_KINDS, Annotations, Failure, camera_name, find_failures

__all__ = [
    "ReportSource",
    "MAX_TILES",
    "frame_size",
    "labels_camera",
    "labelled_images",
    "select_failures",
    "camera_sheet",
    "camera_rows",
    "cameras_csv",
    "cameras_markdown",
    "check_report_dir",
    "write_evaluation_report",
]

#: Tiles of one contact sheet at most (a sheet of 60 tiles is about 1.6 x 2.6 kpx).
MAX_TILES = 60


@dataclass(frozen=True, eq=False)
class ReportSource:
    """One labels file of an evaluation, with what was reported on its frames.

    Attributes
    ----------
    annotations : Annotations
    detections : Detections
        The reported boxes, with the labels' frame indexes.
    source : Path
        The labelled video or folder of images the frames are read from.
    camera : str
        The camera it is pooled under (:func:`labels_camera`).
    """

    annotations: Annotations
    detections: Detections
    source: Path
    camera: str

    @property
    def name(self) -> str:
        """The labels file's name, for captions (``clip_A.json``)."""
        return self.annotations.path.name if self.annotations.path is not None else "labels"


# --------------------------------------------------------------------------------------------
# Frames
# --------------------------------------------------------------------------------------------
def frame_size(source: str | os.PathLike, annotations: Annotations | None = None) -> tuple[int, int] | None:
    """``(width, height)`` of a labelled video, or of a folder's first labelled image; None if unreadable.

    Parameters
    ----------
    source : path-like
        A video file or a folder of images.
    annotations : Annotations, optional
        For a folder: the image of its first labelled frame is measured (else the first image).
    """
    source = Path(source)
    try:
        if source.is_dir():
            files = list_images(source)
            first = min(annotations.frames, default=0) if annotations is not None else 0
            image = read_image(files[first if first < len(files) else 0])
            return int(image.shape[1]), int(image.shape[0])
        return probe_video(source).size
    except InputError:
        return None


def labels_camera(annotations: Annotations, source: str | os.PathLike | None) -> str:
    """The camera of a labels file: its ``camera`` key, else its frames' size (``"1280x720"``), else ``"unknown"``."""
    if annotations.camera:
        return annotations.camera
    return camera_name(annotations, frame_size(source, annotations) if source is not None else None)


def labelled_images(source: str | os.PathLike, frames: Collection[int]) -> Iterator[tuple[int, np.ndarray]]:
    """The wanted frames of a video or folder of images, in increasing order.

    Parameters
    ----------
    source : path-like
        A video (decoded from its start up to the last wanted frame) or a folder of images (the
        wanted positions in sorted name order, as the labels number them).
    frames : collection of int
        0-based frame indexes.

    Yields
    ------
    (int, ndarray of uint8, shape (H, W, 3))
        Each wanted frame index that exists and its RGB frame; one frame is alive at a time.
    """
    wanted = sorted(set(int(f) for f in frames))
    if not wanted:
        return
    source = Path(source)
    if source.is_dir():
        files = list_images(source)
        for i in wanted:
            if i < len(files):
                yield i, read_image(files[i])
        return
    keep = set(wanted)
    with closing(read_frames(source)) as decoded:
        for i, image in enumerate(decoded):
            if i in keep:
                yield i, image
            if i >= wanted[-1]:
                break


# --------------------------------------------------------------------------------------------
# Contact sheets
# --------------------------------------------------------------------------------------------
def _shares(sizes: Sequence[int], limit: int) -> list[int]:
    """Split ``limit`` among groups of ``sizes`` as evenly as they allow: a small group takes
    all it has, and what it leaves goes to the others (water-filling)."""
    shares = [0] * len(sizes)
    left, open_ = max(0, int(limit)), [i for i, n in enumerate(sizes) if n > 0]
    while left and open_:
        each = max(1, left // len(open_))
        for i in list(open_):
            take = min(each, sizes[i] - shares[i], left)
            shares[i] += take
            left -= take
            if shares[i] == sizes[i]:
                open_.remove(i)
    return shares


def _spread(items: Sequence, n: int) -> list:
    """``n`` of ``items`` evenly spaced, first and last included, in order."""
    if n >= len(items):
        return list(items)
    if n <= 0:
        return []
    return [items[int(i)] for i in np.round(np.linspace(0, len(items) - 1, n))]


def select_failures(failures: Sequence[tuple[int, Failure]], limit: int = MAX_TILES) -> list[tuple[int, Failure]]:
    """The failures a sheet shows, at most ``limit``.

    Misses and false positives share the limit evenly (one that has fewer leaves the rest to
    the other); loose matches get what both leave. Within a kind, the failures shown are
    spread evenly over the run (files in order, frames in order), so a long run of the same
    miss does not fill the sheet.

    Parameters
    ----------
    failures : sequence of (int, Failure)
        Each failure with the position of its labels file among the sheet's files.
    limit : int
        Tiles at most (>= 0).

    Returns
    -------
    list of (int, Failure)
        Ordered by kind (:data:`~vehicle_detection.metrics.detection.FAILURE_KINDS`), then file, then frame.
    """
    groups = [sorted((p for p in failures if p[1].kind == k), key=lambda p: (p[0], p[1].frame)) for k in FAILURE_KINDS]
    shares = _shares([len(g) for g in groups[:2]], limit)
    shares.append(min(len(groups[2]), max(0, int(limit)) - sum(shares)))
    return [p for group, n in zip(groups, shares) for p in _spread(group, n)]


def _tile_title(item: ReportSource, frame: int) -> str:
    file = item.annotations.frames[frame].file
    return f"{item.name} {file}" if file else f"{item.name} frame {frame}"


def _tiles_of(item: ReportSource, failures: Sequence[Failure]) -> Iterator[tuple[Failure, np.ndarray]]:
    """Each failure of one labels file with its tile, reading each needed frame once."""
    by_frame: dict[int, list[Failure]] = {}
    for f in failures:
        by_frame.setdefault(f.frame, []).append(f)
    for frame, image in labelled_images(item.source, by_frame):
        labels = item.annotations.frames[frame]
        reported = item.detections.at_frame(frame).xyxy
        for f in by_frame[frame]:
            yield f, failure_tile(image, f, labels.cars, labels.ignore, reported, _tile_title(item, frame))


def _sheet_header(camera: str, failures: Sequence[tuple[int, Failure]], shown: int, limit: int) -> tuple[str, str]:
    count = {k: sum(f.kind == k for _, f in failures) for k in FAILURE_KINDS}
    fps = count["false positive"]
    title = (f"camera {camera}: {count['miss']} missed, {plural(fps, 'false positive')}, "
             f"{count['loose']} loose (IoU 0.5 to 0.7)")
    if not failures:
        return title, "no failures"
    if shown < len(failures):
        return title, f"{shown} of {len(failures)} shown, {len(failures) - shown} left out (at most {limit}: misses and false positives first, spread over the run)"
    return title, f"all {len(failures)} shown"


def camera_sheet(camera: str, items: Sequence[ReportSource], *, limit: int = MAX_TILES) -> tuple[np.ndarray, dict[str, int]]:
    """The contact sheet of one camera's failures.

    Parameters
    ----------
    camera : str
        Named in the header.
    items : sequence of ReportSource
        The camera's labels files; their frames are read again (:func:`labelled_images`).
    limit : int, default 60
        Tiles at most (:func:`select_failures`).

    Returns
    -------
    sheet : ndarray of uint8, shape (H, W, 3)
        RGB (:func:`~vehicle_detection.viz.drawing.failure_sheet`).
    counts : dict of str to int
        ``miss``, ``false positive`` and ``loose`` (all found), ``shown`` and ``left_out``.
    """
    failures = [(i, f) for i, item in enumerate(items) for f in find_failures(item.detections, item.annotations)]
    chosen = select_failures(failures, limit)
    tiles: dict[int, np.ndarray] = {}
    for i, item in enumerate(items):
        mine = [f for k, f in chosen if k == i]
        tiles.update({id(f): tile for f, tile in _tiles_of(item, mine)})
    shown = [tiles[id(f)] for _, f in chosen if id(f) in tiles]
    sheet = failure_sheet(shown, *_sheet_header(camera, failures, len(shown), limit))
    counts = {k: sum(f.kind == k for _, f in failures) for k in FAILURE_KINDS}
    return sheet, {**counts, "shown": len(shown), "left_out": len(failures) - len(shown)}


# --------------------------------------------------------------------------------------------
# Tables
# --------------------------------------------------------------------------------------------
#: Columns of the camera tables: (key, CSV header, Markdown header, format).
_COLUMNS = (
    ("camera", "camera", "camera", ""),
    ("files", "files", "files", "d"),
    ("frames", "frames", "frames", "d"),
    ("cars", "cars", "cars", "d"),
    *(
        (f"{name}_{t}", f"{name}_{t}", f"{head} 0.{t[0]}", fmt)
        for t in ("50", "70")
        for name, head, fmt in (
            ("tp", "TP", "d"), ("fp", "FP", "d"), ("fn", "FN", "d"), ("precision", "precision", ".4f"),
            ("recall", "recall", ".4f"), ("f1", "F1", ".4f"), ("mean_iou", "mean IoU", ".4f"),
        )
    ),
    ("fp_per_frame", "fp_per_frame", "FP per frame", ".4f"),
)  # fmt: skip


def _row(camera: str, pooled: Mapping[str, Any], files: int) -> dict[str, Any]:
    row: dict[str, Any] = {"camera": camera, "files": files, "frames": pooled["n_frames"], "cars": pooled["n_cars"]}
    for t in ("50", "70"):
        scores = pooled[f"at_iou_0.{t[0]}"]
        row.update({f"{k}_{t}": scores[k] for k in ("tp", "fp", "fn", "precision", "recall", "f1", "mean_iou")})
    row["fp_per_frame"] = pooled["at_iou_0.5"]["fp_per_frame"]
    return row


def camera_rows(cameras: Mapping[str, Mapping[str, Any]], overall: Mapping[str, Any] | None = None) -> list[dict[str, Any]]:
    """One table row per camera, and a last row ``all`` when ``overall`` is given.

    Parameters
    ----------
    cameras : mapping of str to mapping
        From :func:`~vehicle_detection.metrics.detection.pool_by_camera`.
    overall : mapping, optional
        From :func:`~vehicle_detection.metrics.detection.pool_reports` over every file.

    Returns
    -------
    list of dict
        Keys ``camera``, ``files``, ``frames``, ``cars``; ``tp_50``, ``fp_50``, ``fn_50``,
        ``precision_50``, ``recall_50``, ``f1_50``, ``mean_iou_50`` and the same at IoU 0.7
        (``_70``); ``fp_per_frame`` (false positives per frame at IoU 0.5).
    """
    rows = [_row(cam, pooled, len(pooled.get("labels", ()))) for cam, pooled in cameras.items()]
    if overall is not None:
        rows.append(_row("all", overall, sum(r["files"] for r in rows)))
    return rows


def _cell(value: Any, fmt: str) -> str:
    return format(value, fmt) if fmt else str(value)


def cameras_csv(rows: Iterable[Mapping[str, Any]]) -> str:
    """:func:`camera_rows` as CSV text: a header and one line per row, rates with 4 decimals."""
    lines = [",".join(c[1] for c in _COLUMNS)]
    lines += [",".join(_cell(r[key], fmt) for key, _, _, fmt in _COLUMNS) for r in rows]
    return "\n".join(lines) + "\n"


def cameras_markdown(rows: Iterable[Mapping[str, Any]]) -> str:
    """:func:`camera_rows` as a Markdown table under a title."""
    head = "| " + " | ".join(c[2] for c in _COLUMNS) + " |"
    rule = "|" + "|".join(" --- " for _ in _COLUMNS) + "|"
    body = ["| " + " | ".join(_cell(r[key], fmt) for key, _, _, fmt in _COLUMNS) + " |" for r in rows]
    note = ("Scores pooled per camera over its labels files: matched one to one at IoU >= 0.5 and >= 0.7; "
            "mean IoU of the matched boxes; false positives per frame at IoU 0.5.")
    return "\n".join(["# Detection by camera", "", note, "", head, rule, *body]) + "\n"


# --------------------------------------------------------------------------------------------
# The folder
# --------------------------------------------------------------------------------------------
def check_report_dir(path: str | os.PathLike, *, overwrite: bool = False) -> Path:
    """Refuse a report folder that is a file, or that exists with files in it, unless ``overwrite``.

    Raises
    ------
    OutputError
        If ``path`` exists and is not a folder, or is a folder that is not empty and
        ``overwrite`` is false.
    """
    path = Path(path)
    if path.exists() or path.is_symlink():
        if not path.is_dir():
            raise OutputError(f"{path}: exists and is not a folder; the report is a folder")
        if not overwrite and any(path.iterdir()):
            raise output_exists(path, "report folder exists and is not empty", "to replace its files")
    return path


def _palette(image: np.ndarray, keep: Sequence[tuple[int, int, int]]):
    """An RGB ``uint8`` image ``(H, W, 3)`` as a 256-colour PIL image whose palette holds ``keep`` exactly.

    A sheet of photographs is about a third the size as a palette PNG; the box, caption and
    background colours stay exact (a median-cut palette alone would only approximate them).
    """
    img = Image.fromarray(np.ascontiguousarray(image, dtype=np.uint8))
    keep = sorted(set(keep))
    base = img.quantize(colors=256 - len(keep), method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
    palette = base.getpalette()[: 3 * (256 - len(keep))] + [v for c in keep for v in c]
    ref = Image.new("P", (1, 1))
    ref.putpalette(palette)
    index = np.array(img.quantize(palette=ref, dither=Image.Dither.NONE))
    for j, color in enumerate(keep, start=256 - len(keep)):  # Pillow's look-up is approximate
        index[(image == color).all(axis=-1)] = j
    out = Image.fromarray(index, mode="P")
    out.putpalette(palette)
    return out


def _write_sheet(path: Path, sheet: np.ndarray, *, overwrite: bool, inputs: Iterable[str | os.PathLike]) -> Path:
    small = _palette(sheet, SHEET_COLORS)
    with atomic_output(path, overwrite=overwrite, inputs=inputs) as tmp:
        small.save(tmp, format="PNG", optimize=True)
    return path


def _write_text(path: Path, text: str, *, overwrite: bool, inputs: Iterable[str | os.PathLike]) -> Path:
    with atomic_output(path, overwrite=overwrite, inputs=inputs) as tmp:
        tmp.write_text(text, encoding="utf-8", newline="\n")
    return path


def write_evaluation_report(
    folder: str | os.PathLike,
    items: Sequence[ReportSource],
    cameras: Mapping[str, Mapping[str, Any]],
    overall: Mapping[str, Any],
    *,
    overwrite: bool = False,
    inputs: Iterable[str | os.PathLike] = (),
    limit: int = MAX_TILES,
) -> dict[str, dict[str, int] | None]:
    """Write ``cameras.md``, ``cameras.csv`` and one ``failures_<camera>.png`` per camera, together.

    The files are written atomically and renamed into place together at the end
    (:func:`~vehicle_detection.io.output_batch`): a failed or interrupted run leaves the
    folder as it was.

    Parameters
    ----------
    folder : path-like
        Created if missing (:func:`check_report_dir` is checked first).
    items : sequence of ReportSource
        Every labels file scored, with its camera.
    cameras : mapping of str to mapping
        From :func:`~vehicle_detection.metrics.detection.pool_by_camera`.
    overall : mapping
        From :func:`~vehicle_detection.metrics.detection.pool_reports` over every file; the tables' row
        ``all`` when there are several cameras.
    overwrite : bool
        Replace existing files of these names.
    inputs : iterable of path-like
        Files the run read; never overwritten.
    limit : int, default 60
        Tiles per sheet at most.

    Returns
    -------
    dict
        By written file name: the sheet's counts (:func:`camera_sheet`) for the PNGs, None for
        the tables.
    """
    folder = check_report_dir(folder, overwrite=overwrite)
    inputs = list(inputs)
    rows = camera_rows(cameras, overall if len(cameras) > 1 else None)
    written: dict[str, dict[str, int] | None] = {}
    with output_batch():
        for name, text in (("cameras.md", cameras_markdown(rows)), ("cameras.csv", cameras_csv(rows))):
            _write_text(folder / name, text, overwrite=overwrite, inputs=inputs)
            written[name] = None
        for camera in cameras:
            sheet, counts = camera_sheet(camera, [it for it in items if it.camera == camera], limit=limit)
            name = f"failures_{camera}.png"
            _write_sheet(folder / name, sheet, overwrite=overwrite, inputs=inputs)
            written[name] = counts
    return written
