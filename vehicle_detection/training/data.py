"""The labelled training set: 64x64 ``vehicles`` and ``non-vehicles`` patches (GTI, KITTI).

:func:`load_dataset` reads the two Udacity archives (``vehicles.zip``, ``non-vehicles.zip``)
or their extracted folders from a data folder, chosen in this order: the ``data_dir`` argument
(``--data-dir`` on the command line), the ``VEHICLE_DETECTION_DATA`` environment variable,
``./data``. :func:`vehicle_detection.training.download.download_archives` fetches them.

Honest splits need groups. The GTI folders are time series: consecutive file numbers are the
same car (or the same stretch of road) a few frames apart, so a random split puts near copies on
both sides. The archives do not label tracks; measured on the data, the mean absolute difference
between image ``i`` and ``i + d`` keeps growing up to ``d`` of a few hundred in GTI and is
flat in KITTI. :func:`load_dataset` therefore groups each folder's images into blocks of
``track_length`` consecutive file numbers (a stand-in for the track), and merges the groups of
byte-identical files, so a grouped split (:class:`sklearn.model_selection.GroupShuffleSplit`)
never has the same picture, and rarely the same car, on both sides.

Extra negatives (``extra_negatives``, e.g. the hard negatives of
:func:`vehicle_detection.training.mining.write_negatives`) are added after the archives' patches, each
folder as its own source with its own groups: mined patches (named
``<input>__f<frame>__...png``) are grouped by input and blocks of ``track_length`` frames, other
PNGs by blocks of ``track_length`` file numbers, and no extra group is shared with the archives
(except through byte-identical files, as above).
"""

from __future__ import annotations

import contextlib
import hashlib
import math
import os
import re
import zipfile
from collections.abc import Iterable
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import InputError, shorten
from ..io import input_file
from ..io.images import decode_image

__all__ = [
    "list_extra_negatives",
    "DATA_ENV",
    "CLASSES",
    "MIN_IMAGES_PER_CLASS",
    "Dataset",
    "default_data_dir",
    "load_dataset",
    "find_duplicates",
    "check_split_sizes",
]

DATA_ENV = "VEHICLE_DETECTION_DATA"
#: Archive / top folder name -> label.
CLASSES = {"vehicles": 1, "non-vehicles": 0}
PATCH_SHAPE = (64, 64, 3)
#: Fewest images of each class that training and the sweep accept (see :func:`check_split_sizes`).
MIN_IMAGES_PER_CLASS = 5


def default_data_dir(data_dir: str | os.PathLike | None = None) -> Path:
    """The data folder: ``data_dir`` if given, else ``$VEHICLE_DETECTION_DATA``, else ``./data``."""
    if data_dir is not None:
        return Path(data_dir)
    env = os.environ.get(DATA_ENV)
    return Path(env) if env else Path("data")


@dataclass(frozen=True)
class Dataset:
    """Training patches with labels and provenance.

    Attributes
    ----------
    images : ndarray of uint8, shape (N, 64, 64, 3)
        RGB patches.
    labels : ndarray of int8, shape (N,)
        1 for a vehicle, 0 for anything else.
    sources : ndarray of str, shape (N,)
        Source folder, e.g. ``'vehicles/GTI_Far'``.
    names : ndarray of str, shape (N,)
        File path inside the archive or data folder.
    groups : ndarray of int64, shape (N,)
        Group id for leakage-free splits (see module docstring).
    digests : ndarray of str, shape (N,)
        SHA-1 of each file's bytes (equal digests = byte-identical files).
    """

    images: np.ndarray
    labels: np.ndarray
    sources: np.ndarray
    names: np.ndarray
    groups: np.ndarray
    digests: np.ndarray

    def __len__(self) -> int:
        return len(self.labels)

    def subset(self, index) -> Dataset:
        """The patches selected by a boolean mask or index array."""
        return Dataset(*(getattr(self, f)[index] for f in ("images", "labels", "sources", "names", "groups", "digests")))

    @classmethod
    def from_patches(cls, parts: Iterable[tuple[np.ndarray, list[str], str]], *, label: int) -> Dataset:
        """Patches made in memory, one class: ``(patches, names, group_key)`` per part.

        Patches of one ``group_key`` share a group; the source is each name's folder.
        """
        parts = [p for p in parts if len(p[0])]
        if not parts:
            return cls(np.zeros((0, *PATCH_SHAPE), np.uint8), *(np.zeros(0, d) for d in (np.int8, str, str, np.int64, str)))
        images = np.concatenate([p[0] for p in parts])
        names = np.array([n for p in parts for n in p[1]])
        keys = [p[2] for p in parts for _ in p[1]]
        _, groups = np.unique(keys, return_inverse=True)
        digests = np.array([hashlib.sha1(im.tobytes()).hexdigest() for im in images])
        sources = np.array([n.rsplit("/", 1)[0] for n in names])
        return cls(images, np.full(len(images), label, np.int8), sources, names, groups.astype(np.int64), digests)

    def concatenate(self, other: Dataset) -> Dataset:
        """This set followed by ``other``, whose groups are renumbered to stay apart from these."""
        offset = int(self.groups.max()) + 1 if len(self) else 0
        fields = ("images", "labels", "sources", "names", "digests")
        joined = {f: np.concatenate([getattr(self, f), getattr(other, f)]) for f in fields}
        return Dataset(groups=np.concatenate([self.groups, other.groups + offset]), **joined)

    def counts(self) -> dict[str, int]:
        """Number of patches per source folder, sorted by folder."""
        src, n = np.unique(self.sources, return_counts=True)
        return {str(s): int(c) for s, c in zip(src, n)}


def _file_number(name: str) -> int:
    nums = re.findall(r"\d+", name.rsplit("/", 1)[-1])
    return int(nums[-1]) if nums else 0


#: The largest PNG member of a training archive read (the patches are 64x64 PNGs of a few KB; a
#: 64x64 RGBA PNG stored uncompressed is under 17 KB).
MAX_PATCH_BYTES = 1 << 20
#: The most bytes a training archive's PNG members may unpack to (the real archives: under 70 MB each).
MAX_ARCHIVE_BYTES = 2 << 30


def _list_members(root: Path, cls: str, stack: contextlib.ExitStack) -> tuple[list[str], callable]:
    """Names of the PNG patches of one class and a function reading one name's bytes (an
    archive stays open until ``stack`` closes)."""
    archive, folder = root / f"{cls}.zip", root / cls
    if archive.is_file():
        try:
            zf = stack.enter_context(zipfile.ZipFile(archive))
        except (zipfile.BadZipFile, OSError) as exc:
            raise InputError(f"{archive}: not a readable zip archive ({exc}); delete it and download again") from None
        infos = [
            i
            for i in zf.infolist()
            if i.filename.lower().endswith(".png") and i.filename.startswith(f"{cls}/") and not i.filename.rsplit("/", 1)[-1].startswith(".")
        ]
        # a zip bomb declares its sizes: refuse it before inflating a byte
        big = next((i for i in infos if i.file_size > MAX_PATCH_BYTES), None)
        if big is not None:
            raise InputError(f"{archive}: member {shorten(big.filename)} unpacks to {big.file_size} bytes; a training patch "
                             f"is a small PNG (at most {MAX_PATCH_BYTES} bytes): not the training archive?")
        total = sum(i.file_size for i in infos)
        if total > MAX_ARCHIVE_BYTES:
            raise InputError(f"{archive}: its PNG members unpack to {total} bytes, more than {MAX_ARCHIVE_BYTES}: "
                             "not the training archive?")
        names = [i.filename for i in infos]

        def read(name, zf=zf, archive=archive):
            try:
                return zf.read(name)
            except (zipfile.BadZipFile, OSError, EOFError) as exc:
                raise InputError(f"{archive}: member {name} is corrupt ({exc})") from None

        return names, read
    if folder.is_dir():
        names = sorted(
            p.relative_to(root).as_posix() for p in folder.rglob("*.png") if not p.name.startswith(".")
        )
        return names, lambda name: (root / name).read_bytes()
    raise InputError(
        f"{root}: neither {cls}.zip nor a {cls}/ folder found; run `vehicle-detection download` "
        f"or point --data-dir (or ${DATA_ENV}) at the folder holding them"
    )


def find_duplicates(digests: np.ndarray) -> list[np.ndarray]:
    """Groups of byte-identical files.

    Parameters
    ----------
    digests : ndarray of str, shape (N,)

    Returns
    -------
    list of ndarray of int
        Index arrays (sorted) of each group of two or more identical files.
    """
    _, inverse, counts = np.unique(digests, return_inverse=True, return_counts=True)
    order = np.argsort(inverse, kind="stable")
    splits = np.split(order, np.cumsum(counts)[:-1])
    return [np.sort(g) for g in splits if len(g) > 1]


#: File names of mined patches (:mod:`~vehicle_detection.training.mining`):
#: ``<input>__f<frame>__s<scale>_<x1>_<y1>_<x2>_<y2>.png``.
MINED_NAME = re.compile(r"^(?P<stem>.+)__f(?P<frame>\d+)__s(?P<scale>\d+)_(?P<box>\d+_\d+_\d+_\d+)\.png$")


def _group_keys(sources: np.ndarray, names: np.ndarray, track_length: int) -> list[str]:
    """The archives' grouping: folder and block of ``track_length`` consecutive file numbers."""
    return [f"{s}#{_file_number(n) // track_length}" for s, n in zip(sources, names)]


def _extra_group_keys(sources: np.ndarray, names: np.ndarray, track_length: int) -> list[str]:
    """Extra negatives: mined patches by input and block of frames, others by file-number block."""
    keys = []
    for s, n in zip(sources, names):
        m = MINED_NAME.match(n.rsplit("/", 1)[-1])
        if m:
            keys.append(f"extra:{s}#{m['stem']}#{int(m['frame']) // track_length}")
        else:
            keys.append(f"extra:{s}#{_file_number(n) // track_length}")
    return keys


def _groups(key_sets: list[list[str]], digests: np.ndarray) -> np.ndarray:
    """Group ids: equal keys share one; each key set numbered after the previous (so the
    archives' ids do not depend on what is added after them); byte-identical files merged."""
    parts, offset = [], 0
    for keys in key_sets:
        _, ids = np.unique(np.array(keys, dtype=str), return_inverse=True)
        ids = ids.astype(np.int64).reshape(-1) + offset
        parts.append(ids)
        offset = int(ids.max()) + 1 if len(ids) else offset
    groups = np.concatenate(parts) if parts else np.zeros(0, np.int64)
    # Byte-identical files must share a group: union the groups of each duplicate set.
    parent = np.arange(groups.max() + 1 if len(groups) else 0)

    def find(a):
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for dup in find_duplicates(digests):
        roots = {find(g) for g in groups[dup]}
        r0 = min(roots)
        for r in roots:
            parent[r] = r0
    return np.array([find(g) for g in groups], dtype=np.int64)


def list_extra_negatives(folder: str | os.PathLike) -> list[tuple[str, Path]]:
    """``(source, file)`` of every PNG of an extra negatives folder, sorted by source and number.

    ``folder`` is either laid out like the data folder (PNGs under ``folder/non-vehicles/<source>/``)
    or a folder of PNGs itself (source ``non-vehicles/<its name>``, subfolders included). Hidden
    files and folders (such as an unfinished ``.NAME.XXXX.partial``) are skipped.
    """
    folder = Path(folder)
    if not folder.is_dir():
        if folder.exists() or folder.is_symlink():
            raise InputError(f"{folder}: not a folder; --extra-negatives takes folders of 64x64 PNG negatives")
        raise InputError(f"{folder}: extra negatives folder not found")
    root = folder / "non-vehicles" if (folder / "non-vehicles").is_dir() else folder
    out = []
    for p in root.rglob("*"):
        rel = p.relative_to(root)
        if p.suffix.lower() != ".png" or any(part.startswith(".") for part in rel.parts) or (p.is_dir() and not p.is_symlink()):
            continue
        if not p.exists():
            raise InputError(f"{p}: a symlink to nothing in an extra negatives folder; remove it")
        input_file(p, "PNG image")  # a device (/dev/zero), a FIFO or a folder named .png
        if "vehicles" in rel.parts[:-1]:
            raise InputError(f"{p}: an extra negatives folder may not hold a vehicles/ folder; only negatives are added")
        sub = rel.parent.as_posix()
        base = folder.name if root == folder else ""
        source = "/".join(x for x in ("non-vehicles", base, "" if sub == "." else sub) if x)
        out.append((source, p))
    out.sort(key=lambda e: (e[0], _file_number(e[1].name), e[1].name))
    return out


def _read_bytes(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:  # unreadable (permissions), or gone since it was listed
        raise InputError(f"{path}: cannot read: {exc.strerror or exc}") from None


def load_dataset(
    data_dir: str | os.PathLike | None = None,
    *,
    drop_duplicates: bool = False,
    track_length: int = 100,
    n_jobs: int = 1,
    extra_negatives: Iterable[str | os.PathLike] = (),
) -> Dataset:
    """Load the training set from the archives or their extracted folders.

    Parameters
    ----------
    data_dir : path-like, optional
        Folder holding ``vehicles.zip`` and ``non-vehicles.zip`` (or ``vehicles/`` and
        ``non-vehicles/``); see :func:`default_data_dir`.
    drop_duplicates : bool
        Keep only the first (by name) of each group of byte-identical files.
    track_length : int
        Consecutive file numbers per group (see module docstring).
    n_jobs : int
        Decoding threads. One is the default: decoding a 64x64 PNG holds the GIL most of its
        time, so more threads take more CPU time and are no faster.
    extra_negatives : iterable of path-like
        Folders of further 64x64 non-vehicle PNGs, such as mined hard negatives: laid out like
        the data folder (``DIR/non-vehicles/<source>/*.png``) or PNGs directly in ``DIR``. Each
        source keeps its own groups (see the module docstring); a source may not share its name
        with an archive folder or another extra folder.

    Returns
    -------
    Dataset
        Sorted by class (vehicles first), then folder, then file number; extra negatives last.

    Raises
    ------
    InputError
        If the data are missing, an archive is unreadable, or a patch is not a 64x64 image;
        the message names the file.
    """
    root = default_data_dir(data_dir)
    if not root.is_dir():
        raise InputError(
            f"{root}: data folder not found; run `vehicle-detection download` or pass --data-dir (or set ${DATA_ENV})"
        )
    with contextlib.ExitStack() as stack:  # the archives are closed once every patch is read
        return _load(root, stack, drop_duplicates, track_length, n_jobs, extra_negatives)


def _load(root: Path, stack: contextlib.ExitStack, drop_duplicates: bool, track_length: int, n_jobs: int, extra_negatives) -> Dataset:
    entries = []
    for cls in CLASSES:
        names, read = _list_members(root, cls, stack)
        if not names:
            raise InputError(f"{root}: no PNG images under {cls}/")
        names.sort(key=lambda n: (n.rsplit("/", 1)[0], _file_number(n), n))
        entries.extend((cls, n, read, root / n) for n in names)
    n_archive = len(entries)
    archive_sources = {n.rsplit("/", 1)[0] for _, n, _, _ in entries}
    extra_sources: dict[str, Path] = {}
    for folder in extra_negatives:
        folder = Path(folder)
        found = list_extra_negatives(folder)
        if not found:
            raise InputError(f"{folder}: no PNG images in this extra negatives folder")
        for source, path in found:
            if source in archive_sources:
                raise InputError(f"{folder}: extra negatives folder {source} has the name of a folder of the training archives; rename it")
            if extra_sources.setdefault(source, folder) != folder:
                raise InputError(f"{folder}: extra negatives folder {source} is also in {extra_sources[source]}; rename one")
            entries.append(("non-vehicles", f"{source}/{path.name}", lambda name, path=path: _read_bytes(path), path))

    def load(entry):
        cls, name, read, shown = entry
        data = read(name)
        img = decode_image(data, str(shown))
        if img.shape != PATCH_SHAPE:
            raise InputError(f"{shown}: training patches must be 64x64, got {img.shape[1]}x{img.shape[0]}")
        return img, hashlib.sha1(data).hexdigest()

    if n_jobs <= 1:
        loaded = [load(entry) for entry in entries]
    else:  # runs of entries, not one task each: a task's hand-over costs as much as a patch's decoding
        size = max(1, -(-len(entries) // (4 * n_jobs)))
        runs = [entries[i : i + size] for i in range(0, len(entries), size)]
        with ThreadPoolExecutor(max_workers=n_jobs) as pool:
            loaded = [item for run in pool.map(lambda run: [load(entry) for entry in run], runs) for item in run]
    images = np.stack([img for img, _ in loaded]) if loaded else np.empty((0, *PATCH_SHAPE), np.uint8)
    digests = np.array([d for _, d in loaded])
    names = np.array([n for _, n, _, _ in entries])
    labels = np.array([CLASSES[c] for c, _, _, _ in entries], dtype=np.int8)
    sources = np.array([n.rsplit("/", 1)[0] for n in names])
    groups = _groups(
        [_group_keys(sources[:n_archive], names[:n_archive], track_length),
         _extra_group_keys(sources[n_archive:], names[n_archive:], track_length)],
        digests,
    )
    ds = Dataset(images, labels, sources, names, groups, digests)
    if drop_duplicates:
        keep = np.ones(len(ds), bool)
        for dup in find_duplicates(digests):
            keep[dup[1:]] = False
        ds = ds.subset(keep)
    return ds


def check_split_sizes(labels, groups, *, test_size: float = 0.2, name: str = "dataset") -> None:
    """Refuse a training set too small for the random and the grouped train/test splits.

    Cheap (labels and groups only): call it before extracting features. The rules:

    * each class needs at least :data:`MIN_IMAGES_PER_CLASS` images, so that the stratified
      split puts both classes on both sides;
    * each class needs more groups than the grouped split can leave out of its training side
      (``ceil(test_size * G)`` held out of ``G`` groups, as
      :class:`~sklearn.model_selection.GroupShuffleSplit` counts), so that the training side
      always holds both classes whatever groups are drawn.

    Parameters
    ----------
    labels : array of int, shape (N,)
        1 vehicle, 0 non-vehicle.
    groups : array of int, shape (N,)
        :attr:`Dataset.groups`.
    test_size : float
        Fraction held out, in (0, 1).
    name : str
        The data folder (or what the data are), for the message.

    Raises
    ------
    InputError
        Naming ``name``, how many images and groups each class has, and how many are needed.
    """
    labels, groups = np.asarray(labels), np.asarray(groups)
    n = len(labels)
    n_groups = len(np.unique(groups))
    # sklearn's shuffle-split arithmetic: ceil(test_size * n) held out, floor((1 - test_size) * n) trained on.
    left_out = n_groups - math.floor((1.0 - test_size) * n_groups)
    need_groups = max(2, left_out + 1)
    have = {cls: (int(np.sum(labels == lab)), len(np.unique(groups[labels == lab]))) for cls, lab in CLASSES.items()}
    n_test = math.ceil(test_size * n)
    n_train = math.floor((1.0 - test_size) * n)
    if (
        all(k >= MIN_IMAGES_PER_CLASS and g >= need_groups for k, g in have.values())
        and n_test >= len(CLASSES)
        and n_train >= len(CLASSES)
    ):
        return
    counts = ", ".join(f"{cls} {k} images in {g} groups" for cls, (k, g) in have.items())
    raise InputError(
        f"{name}: too few training images for the random and grouped train/test splits ({counts}); each class needs at "
        f"least {MIN_IMAGES_PER_CLASS} images and at least {need_groups} groups (the grouped split leaves {left_out} of "
        f"the {n_groups} groups out of training; a group is a block of consecutive file numbers of one folder)"
    )
