"""Detections in the formats the field uses: MOTChallenge text, COCO JSON, Parquet, supervision.

* :func:`write_mot` writes a MOTChallenge (MOT15/16/17) ``det``/``res`` text file: one line
  ``frame,id,bb_left,bb_top,bb_width,bb_height,conf,-1,-1,-1`` per box, with **1-based**
  frames (decoded index + 1) and 1-based pixel coordinates as in the MOTChallenge files
  (``bb_left = x1 + 1``, ``bb_top = y1 + 1``; py-motmetrics subtracts the 1 again when it reads
  them), ``id`` the track id (-1 for untracked boxes, as in ``det`` files), width and height in
  pixels (``x2 - x1``, ``y2 - y1``: boxes are x2/y2 exclusive).
* :func:`write_coco` writes COCO detection results for a folder of images: ``images`` (id, file
  name, width, height), ``categories`` (one: ``car``), ``annotations`` (id, image_id,
  category_id, ``bbox`` ``[x, y, w, h]``, ``area``, ``score``, ``iscrowd`` 0, and ``track_id``
  where tracked).
* :func:`write_parquet` (needs ``pyarrow``: ``pip install "vehicle-detection[parquet]"``)
  writes the boxes table with a ``video`` column naming the input, so one file can hold a
  whole batch.
* :func:`write_tables` writes the tables one input asks for (:data:`FORMATS`, the lanes CSV
  included) from its boxes, the same way for videos, images and folders of images.

The conversion to and from ``supervision.Detections`` lives with the table type
(:meth:`~vehicle_detection.detections.Detections.to_supervision`).
"""

from __future__ import annotations

import importlib
import json
import os
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path

import numpy as np

from ..detections import Detections
from ..errors import InputError
from ._files import atomic_output
from .tables import write_boxes_csv, write_lanes_csv

__all__ = ["write_mot", "write_coco", "write_parquet", "read_parquet", "write_tables", "FORMATS", "COCO_CATEGORY"]

COCO_CATEGORY = {"id": 1, "name": "car", "supercategory": "vehicle"}
#: The tables an input can get, and the suffix of each one's default name (``NAME`` + suffix):
#: boxes as CSV, Parquet, MOTChallenge text or COCO JSON (images only), and the lanes CSV.
FORMATS = {"csv": "_boxes.csv", "parquet": "_boxes.parquet", "mot": "_mot.txt", "coco": "_coco.json", "lanes": "_lanes.csv"}


def _optional(module: str, extra: str):
    try:
        return importlib.import_module(module)  # an optional dependency, loaded when asked for
    except ImportError:
        raise ImportError(f"{module} is not installed; pip install \"vehicle-detection[{extra}]\"") from None


def write_mot(path: str | os.PathLike, detections: Detections, *, overwrite: bool = False, inputs: Iterable = ()) -> Path:
    """Write a MOTChallenge text file (``frame,id,x,y,w,h,conf,-1,-1,-1``, 1-based frames and pixels), atomically."""
    lines = []
    for frame, x1, y1, x2, y2, track_id, score in detections.rows():
        lines.append(f"{frame + 1},{track_id},{x1 + 1},{y1 + 1},{x2 - x1},{y2 - y1},{score:.4f},-1,-1,-1")
    with atomic_output(path, overwrite=overwrite, inputs=inputs) as tmp:
        tmp.write_text("".join(line + "\n" for line in lines), encoding="utf-8", newline="\n")
    return Path(path)


def write_coco(
    path: str | os.PathLike,
    detections: Detections,
    files: Sequence[str],
    sizes: Sequence[tuple[int, int]],
    *,
    overwrite: bool = False,
    inputs: Iterable = (),
) -> Path:
    """Write COCO detection JSON for images: ``frame`` indexes ``files`` (names) and ``sizes`` ``(H, W)``.

    Image ids are 1-based positions (``frame + 1``); annotation ids count from 1 in table order.
    """
    if len(files) != len(sizes):
        raise ValueError("files and sizes must have the same length")
    images = [{"id": i + 1, "file_name": str(f), "height": int(h), "width": int(w)} for i, (f, (h, w)) in enumerate(zip(files, sizes))]
    annotations = []
    for k, (frame, x1, y1, x2, y2, track_id, score) in enumerate(detections.rows(), start=1):
        if not 0 <= frame < len(files):
            raise ValueError(f"row {k - 1}: frame {frame} names no image (there are {len(files)})")
        ann = {
            "id": k, "image_id": frame + 1, "category_id": COCO_CATEGORY["id"],
            "bbox": [x1, y1, x2 - x1, y2 - y1], "area": (x2 - x1) * (y2 - y1), "score": round(score, 4), "iscrowd": 0,
        }
        if detections.track_id is not None:
            ann["track_id"] = track_id
        annotations.append(ann)
    doc = {"info": {"description": "vehicle-detection"}, "images": images, "categories": [COCO_CATEGORY], "annotations": annotations}
    with atomic_output(path, overwrite=overwrite, inputs=inputs) as tmp:
        tmp.write_text(json.dumps(doc, indent=1) + "\n", encoding="utf-8")
    return Path(path)


PARQUET_COLUMNS = ("video", "frame", "x1", "y1", "x2", "y2", "track_id", "score", "file")


def _arrow_table(parts: Iterable[tuple[str, Detections]]):
    pa = _optional("pyarrow", "parquet")
    cols: dict[str, list] = {c: [] for c in PARQUET_COLUMNS}
    for video, det in parts:
        n = len(det)
        cols["video"].append(np.full(n, str(video), dtype=object))
        cols["frame"].append(det.frame)
        for j, c in enumerate(("x1", "y1", "x2", "y2")):
            cols[c].append(det.xyxy[:, j])
        cols["track_id"].append(det.track_id if det.track_id is not None else np.full(n, -1, np.int64))
        cols["score"].append(det.score)
        names = det.data.get("file")
        cols["file"].append(np.asarray(names, dtype=object) if names is not None else np.full(n, None, dtype=object))
    types = {"video": pa.string(), "file": pa.string(), "score": pa.float64()}
    arrays = {}
    for c, chunks in cols.items():
        values = np.concatenate(chunks) if chunks else np.zeros(0, object if c in ("video", "file") else np.int64)
        arrays[c] = pa.array(values.tolist() if values.dtype == object else values, type=types.get(c, pa.int64()))
    return pa.table(arrays)


def write_parquet(
    path: str | os.PathLike, parts: Iterable[tuple[str, Detections]] | Detections, *, video: str | None = None,
    overwrite: bool = False, inputs: Iterable = (),
) -> Path:
    """Write boxes as Parquet, atomically: columns ``video, frame, x1, y1, x2, y2, track_id, score, file``.

    ``parts`` is one :class:`Detections` (named by ``video``) or ``(video, Detections)`` pairs (a
    batch in one table). ``file`` is the image's name for folders of images, else null.
    """
    pq = _optional("pyarrow.parquet", "parquet")
    if isinstance(parts, Detections):
        parts = [(video or "", parts)]
    table = _arrow_table(parts)
    with atomic_output(path, overwrite=overwrite, inputs=inputs) as tmp:
        pq.write_table(table, tmp)
    return Path(path)


def read_parquet(path: str | os.PathLike) -> dict[str, Detections]:
    """Read a Parquet boxes table: ``{video: Detections}`` in order of first appearance."""
    pq = _optional("pyarrow.parquet", "parquet")
    try:
        table = pq.read_table(path)
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: not a readable Parquet file: {exc}") from None
    missing = [c for c in PARQUET_COLUMNS if c not in table.column_names]
    if missing:
        raise InputError(f"{path}: missing column(s) {', '.join(missing)}")
    d = table.to_pydict()
    out: dict[str, Detections] = {}
    videos = d["video"]
    for name in dict.fromkeys(videos):
        idx = [i for i, v in enumerate(videos) if v == name]
        ids = np.array([d["track_id"][i] for i in idx], np.int64)
        files = [d["file"][i] for i in idx]
        det = Detections(
            np.array([[d[c][i] for c in ("x1", "y1", "x2", "y2")] for i in idx], np.int64).reshape(-1, 4),
            score=np.array([d["score"][i] for i in idx], np.float64),
            track_id=None if np.all(ids == -1) else ids,
            frame=np.array([d["frame"][i] for i in idx], np.int64),
            data={"file": np.array(files, dtype=str)} if idx and all(f is not None for f in files) else {},
        )
        out[name] = det
    return out


def write_tables(
    tables: Mapping[str, str | os.PathLike],
    detections: Detections,
    *,
    name: str,
    images: Sequence[tuple[str, tuple[int, int]]] | None = None,
    first: int = 0,
    lanes: Sequence[tuple[int, float | None, float | None]] | None = None,
    overwrite: bool = False,
    inputs: Iterable[str | os.PathLike] = (),
) -> list[Path]:
    """Write the tables of one input, atomically (together inside an :func:`~vehicle_detection.io.output_batch`).

    Parameters
    ----------
    tables : mapping of str to path-like
        Format (a key of :data:`FORMATS`) -> file.
    detections : Detections
        The input's boxes. A ``file`` column in ``data`` (the image each box is in, for a folder
        of images) is written to the CSV and Parquet tables.
    name : str
        The input's name: the ``video`` column of the Parquet table.
    images : sequence of (str, (int, int)), optional
        For images: each image's file name and ``(height, width)``, frame ``first`` first
        (needed for ``coco``).
    first : int
        The frame index of the first of ``images``.
    lanes : sequence of (int, float or None, float or None), optional
        The lanes CSV's rows (``frame, curvature_m, offset_m``; needed for ``lanes``).
    overwrite, inputs
        As for :func:`~vehicle_detection.io.check_output_path`.

    Returns
    -------
    list of Path
        The files written, in the order of ``tables``.
    """
    unknown = sorted(set(tables) - set(FORMATS))
    if unknown:
        raise ValueError(f"unknown table format(s) {', '.join(map(repr, unknown))}; choose from {', '.join(FORMATS)}")
    files = detections.data.get("file")
    inputs = list(inputs)
    out = []
    for fmt, dest in tables.items():
        if fmt == "csv":
            write_boxes_csv(dest, detections, overwrite=overwrite, inputs=inputs, files=None if files is None else list(files))
        elif fmt == "mot":
            write_mot(dest, detections, overwrite=overwrite, inputs=inputs)
        elif fmt == "parquet":
            write_parquet(dest, [(name, detections)], overwrite=overwrite, inputs=inputs)
        elif fmt == "coco":
            if images is None:
                raise ValueError("coco: the images' names and sizes are needed (images=)")
            shifted = detections.replace(frame=detections.frame - first) if len(detections) else detections
            write_coco(dest, shifted, [n for n, _ in images], [size for _, size in images], overwrite=overwrite, inputs=inputs)
        else:  # lanes
            if lanes is None:
                raise ValueError("lanes: the lanes' rows are needed (lanes=)")
            write_lanes_csv(dest, lanes, overwrite=overwrite, inputs=inputs)
        out.append(Path(dest))
    return out
