"""Download and check the two public training archives.

The classifier is trained on the Udacity vehicle / non-vehicle image sets, published as two zip
archives. :func:`download_archives` fetches both into a data folder, skipping any already present
and valid, and checks that each holds the expected folders of PNG images.

Downloads are resume-safe. Bytes are written to ``NAME.part`` beside the destination and renamed to
``NAME`` only once the transfer is complete and has passed every check, so a file under the final
name is always whole. An interrupted transfer keeps its ``.part`` file, and the next call asks the
server for the rest (an HTTP ``Range`` request) instead of starting again.

This is why the download is not pooch's (the field's downloader, as scikit-image uses it): pooch
1.9 streams into a temporary file that it deletes when the transfer breaks, so an interrupted
download of these archives (tens of MB each) starts again from zero; and it would add
``requests`` to the command-line install. What pooch gives besides (a checksum, an atomic
rename) is done here too.

The md5 sums of the public originals are not known, so the archives are checked structurally:
each must be a readable zip whose PNG members fall into the expected folders in the expected
numbers (see :data:`ARCHIVES`). A known md5 can still be given to :func:`download_file`.

Examples
--------
>>> from vehicle_detection.training.download import download_archives
>>> paths = download_archives("data")  # doctest: +SKIP
>>> paths["vehicles"]  # doctest: +SKIP
PosixPath('data/vehicles.zip')
"""

from __future__ import annotations

import hashlib
import http.client
import os
import posixpath
import re
import sys
import urllib.error
import urllib.parse
import urllib.request
import zipfile
import zlib
from collections import Counter
from collections.abc import Callable, Mapping
from contextlib import suppress
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType

from tqdm.auto import tqdm

from ..errors import DownloadError, InputError, OutputError

__all__ = [
    "Archive",
    "ARCHIVES",
    "DEFAULT_BASE_URL",
    "PART_SUFFIX",
    "part_path",
    "download_file",
    "verify_archive",
    "download_archives",
]

#: Where the public archives live; ``download_archives(base_url=...)`` points elsewhere.
DEFAULT_BASE_URL = "https://s3.amazonaws.com/udacity-sdc/Vehicle_Tracking"

#: Suffix of an unfinished download, kept beside the destination so that a later call can resume.
PART_SUFFIX = ".part"

_USER_AGENT = "vehicle-detection (python urllib)"
_HASH_CHUNK = 1 << 20
_MAX_PROBLEMS_SHOWN = 8


@dataclass(frozen=True)
class Archive:
    """A training archive: where it is published and which PNG images it must contain.

    Parameters
    ----------
    name : str
        Short name, e.g. ``"vehicles"``.
    url : str
        Public address of the archive. Its last path component is the file name used on disk
        (:attr:`filename`).
    layout : mapping of str to int
        Expected number of PNG members per folder inside the zip, folders written with ``/`` and
        without a trailing slash, e.g. ``{"vehicles/GTI_Far": 834, ...}``. PNG files in any other
        folder make the archive invalid. Stored as a read-only mapping.
    """

    name: str
    url: str
    layout: Mapping[str, int] = field(hash=False)

    def __post_init__(self) -> None:
        layout = dict(self.layout)
        for folder, count in layout.items():
            if not isinstance(folder, str) or not isinstance(count, int) or count < 0:
                raise ValueError(
                    f"Archive {self.name!r}: layout must map folder names to counts >= 0, "
                    f"got {folder!r}: {count!r}"
                )
        object.__setattr__(self, "layout", MappingProxyType(layout))
        if not self.filename:
            raise ValueError(f"Archive {self.name!r}: url {self.url!r} does not end in a file name")

    @property
    def filename(self) -> str:
        """File name of the archive: the last component of :attr:`url`'s path."""
        path = urllib.parse.urlsplit(self.url).path
        return urllib.parse.unquote(posixpath.basename(path))

    @property
    def n_images(self) -> int:
        """Total number of PNG images the archive must hold."""
        return sum(self.layout.values())


#: The two training archives, by name.
ARCHIVES: Mapping[str, Archive] = MappingProxyType(
    {
        "vehicles": Archive(
            "vehicles",
            f"{DEFAULT_BASE_URL}/vehicles.zip",
            {
                "vehicles/GTI_Far": 834,
                "vehicles/GTI_Left": 909,
                "vehicles/GTI_MiddleClose": 419,
                "vehicles/GTI_Right": 664,
                "vehicles/KITTI_extracted": 5966,
            },
        ),
        "non-vehicles": Archive(
            "non-vehicles",
            f"{DEFAULT_BASE_URL}/non-vehicles.zip",
            {
                "non-vehicles/GTI": 3900,
                "non-vehicles/Extras": 5068,
            },
        ),
    }
)


# --------------------------------------------------------------------------------------------
# Downloading
# --------------------------------------------------------------------------------------------


def download_file(
    url: str,
    dest: str | os.PathLike,
    *,
    md5: str | None = None,
    size: int | None = None,
    progress: bool = True,
    chunk_size: int = 1 << 20,
    timeout: float = 30,
) -> Path:
    """Download ``url`` to ``dest``, resuming an earlier interrupted attempt.

    Bytes go to ``dest + ".part"``. If that file exists the server is asked only for the missing
    bytes (``Range: bytes=N-``); they are appended when it answers ``206 Partial Content`` starting
    at byte N, and the file is restarted from zero when it answers ``200`` (no range support).
    Once the transfer is complete and the checks pass, the ``.part`` file is renamed to ``dest``.

    Parameters
    ----------
    url : str
        Address to fetch (``http``, ``https`` or anything else :mod:`urllib.request` opens).
    dest : path-like
        Final file path. Missing parent folders are created.
    md5 : str, optional
        Expected md5 of the file, as 32 hexadecimal digits.
    size : int, optional
        Expected size in bytes. Without it the length the server announces is checked.
    progress : bool
        Show a progress bar on stderr (only when stderr is a terminal).
    chunk_size : int
        Bytes read per step.
    timeout : float
        Seconds to wait for the connection and for each read.

    Returns
    -------
    Path
        ``dest``.

    Raises
    ------
    DownloadError
        If the server cannot be reached or answers with an HTTP error, if the transfer ends before
        the announced length (the ``.part`` file is kept: calling again resumes), or if the
        finished file has the wrong size or md5 (it is deleted). Also if ``dest`` already exists
        and does not match ``md5`` / ``size``; it is then left alone.
    InputError
        If ``md5``, ``size``, ``chunk_size`` or ``timeout`` is malformed.
    OutputError
        If the file cannot be written.

    Notes
    -----
    If ``dest`` exists it is checked against ``md5`` and ``size`` (when given) and returned without
    contacting the server. Two processes must not download to the same ``dest`` at once.
    """
    return _download(
        url,
        Path(dest),
        md5=md5,
        size=size,
        progress=progress,
        chunk_size=chunk_size,
        timeout=timeout,
    )


def _download(
    url: str,
    dest: Path,
    *,
    md5: str | None,
    size: int | None,
    progress: bool,
    chunk_size: int,
    timeout: float,
    check: Callable[[Path], None] | None = None,
) -> Path:
    """Body of :func:`download_file`; ``check(part)`` runs on the finished file before the rename.

    ``check`` must raise :class:`DownloadError` to reject the file (and delete it).
    """
    md5 = _normalise_md5(md5)
    if size is not None and (isinstance(size, bool) or not isinstance(size, int) or size < 0):
        raise InputError(f"size must be a whole number of bytes >= 0, got {size!r}")
    if isinstance(chunk_size, bool) or not isinstance(chunk_size, int) or chunk_size <= 0:
        raise InputError(f"chunk_size must be a positive whole number, got {chunk_size!r}")
    if not timeout > 0:
        raise InputError(f"timeout must be positive, got {timeout!r}")

    if dest.is_dir():
        raise OutputError(f"{dest}: download destination is a folder; give a file name")
    if dest.exists():
        _check_existing(dest, md5=md5, size=size)
        return dest

    part = part_path(dest)
    try:
        dest.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{dest.parent}: cannot create the download folder: {exc.strerror or exc}") from exc
    if size is not None and _file_size(part) > size:
        # Longer than the whole file can be: not a prefix of it.
        _remove(part)

    announced = _fetch(url, part, size=size, progress=progress, chunk_size=chunk_size, timeout=timeout)

    bad = _mismatch(part, md5=md5, size=size if size is not None else announced)
    if bad is not None:
        _remove(part)
        what, expected, got = bad
        if what == "size":
            raise DownloadError(
                f"{url}: downloaded file has the wrong size: expected {expected:,} bytes, got {got:,}; the file was deleted"
            )
        raise DownloadError(f"{url}: md5 mismatch: expected {expected}, got {got}; the downloaded file was deleted")
    if check is not None:
        try:
            check(part)
        except DownloadError:
            _remove(part)
            raise
    try:
        os.replace(part, dest)
    except OSError as exc:
        raise OutputError(f"{dest}: cannot move the finished download into place: {exc.strerror or exc}") from exc
    return dest


def part_path(dest: str | os.PathLike) -> Path:
    """Return the path of the unfinished download for ``dest``: ``dest`` + :data:`PART_SUFFIX`."""
    dest = Path(dest)
    return dest.with_name(dest.name + PART_SUFFIX)


class _RangeNotSatisfiable(Exception):
    """The server answered 416; ``total`` is the full length it reported, if any."""

    def __init__(self, total: int | None) -> None:
        super().__init__(total)
        self.total = total


def _fetch(
    url: str, part: Path, *, size: int | None, progress: bool, chunk_size: int, timeout: float
) -> int | None:
    """Bring ``part`` up to date with ``url``; return the full length the server announced.

    Raises :class:`DownloadError` when the transfer ends before the announced length.
    """
    # At most two passes: the second only after discarding a partial file the server would not
    # continue (an unexpected Content-Range, or a 416 that does not confirm it is complete).
    for _ in range(2):
        offset = _file_size(part)
        if size is not None and offset == size and offset > 0:
            return size  # already complete: nothing to ask for
        try:
            response = _open(url, offset, timeout)
        except _RangeNotSatisfiable as exc:
            if exc.total is not None and exc.total == offset:
                return offset  # the partial file is the whole file
            _remove(part)
            continue

        with response:
            total = _content_length(response)
            if response.status == 206:
                content_range = _parse_content_range(response.headers.get("Content-Range"))
                if content_range is None or content_range[0] != offset:
                    # Not the slice we asked for: start over rather than splice wrong bytes.
                    _remove(part)
                    continue
                start, _end, full = content_range
                if full is not None:
                    total = full
                elif total is not None:
                    total += start
                mode = "ab"
            else:
                # 200 (or another success without a range): the body is the whole file.
                offset = 0
                mode = "wb"
            received, error = _copy_body(
                response,
                part,
                mode=mode,
                offset=offset,
                total=total,
                progress=progress,
                chunk_size=chunk_size,
            )

        if total is not None and received < total:
            reason = f" ({_describe(error)})" if error is not None else ""
            raise DownloadError(
                f"{url}: download cut short: {received:,} of {total:,} bytes arrived{reason}; "
                f"the partial file {part} is kept and running again resumes from it"
            )
        if error is not None:
            # Length unknown, so we cannot tell how much is missing; the partial file is kept.
            raise DownloadError(
                f"{url}: download interrupted after {received:,} bytes ({_describe(error)}); "
                f"the partial file {part} is kept and running again resumes from it"
            )
        return total
    raise DownloadError(
        f"{url}: the server did not send the requested byte range even after restarting from "
        f"zero; cannot download"
    )


def _open(url: str, offset: int, timeout: float) -> http.client.HTTPResponse:
    """Open ``url``, asking for bytes from ``offset`` on when it is positive."""
    headers = {"User-Agent": _USER_AGENT, "Accept-Encoding": "identity"}
    if offset > 0:
        headers["Range"] = f"bytes={offset}-"
    try:
        request = urllib.request.Request(url, headers=headers)
        return urllib.request.urlopen(request, timeout=timeout)
    except urllib.error.HTTPError as exc:
        with exc:
            if exc.code == 416 and offset > 0:
                content_range = _parse_content_range(exc.headers.get("Content-Range"))
                raise _RangeNotSatisfiable(content_range[2] if content_range else None) from None
            raise DownloadError(f"{url}: the server answered HTTP {exc.code} {exc.reason}") from exc
    except urllib.error.URLError as exc:
        raise DownloadError(f"{url}: cannot reach the server: {_describe(exc.reason)}") from exc
    except ValueError as exc:
        raise InputError(f"{url!r}: not a valid URL: {exc}") from exc
    except (OSError, http.client.HTTPException) as exc:
        raise DownloadError(f"{url}: request failed: {_describe(exc)}") from exc


def _copy_body(
    response: http.client.HTTPResponse,
    part: Path,
    *,
    mode: str,
    offset: int,
    total: int | None,
    progress: bool,
    chunk_size: int,
) -> tuple[int, BaseException | None]:
    """Write the response body to ``part``; return its final size and the read error, if any.

    A read error (timeout, reset connection, truncated chunked body) ends the copy without
    raising, so the caller can report how much arrived. Errors writing the file raise
    :class:`OutputError`.
    """
    error: BaseException | None = None
    try:
        out = open(part, mode)
    except OSError as exc:
        raise OutputError(f"{part}: cannot write the download: {exc.strerror or exc}") from exc
    bar = tqdm(
        total=total,
        initial=offset,
        desc=part.name.removesuffix(PART_SUFFIX),
        unit="B",
        unit_scale=True,
        unit_divisor=1024,
        file=sys.stderr,
        disable=not _progress_wanted(progress),
        dynamic_ncols=True,
    )
    # read1 returns whatever has arrived (up to chunk_size), so bytes received before a stall or
    # a reset are written, not lost in a half-filled buffer.
    read = getattr(response, "read1", response.read)
    with bar, out:
        while True:
            try:
                chunk = read(chunk_size)
            except (OSError, http.client.HTTPException) as exc:
                error = exc
                break
            if not chunk:
                break
            try:
                out.write(chunk)
            except OSError as exc:
                raise OutputError(f"{part}: cannot write the download: {exc.strerror or exc}") from exc
            bar.update(len(chunk))
        try:
            out.flush()
            os.fsync(out.fileno())
        except OSError as exc:
            raise OutputError(f"{part}: cannot write the download: {exc.strerror or exc}") from exc
        received = out.tell()
    return received, error


def _check_existing(dest: Path, *, md5: str | None, size: int | None) -> None:
    """Raise :class:`DownloadError` if the existing ``dest`` does not match ``md5`` / ``size``."""
    bad = _mismatch(dest, md5=md5, size=size)
    if bad is not None:
        what, expected, got = bad
        if what == "size":
            expected, got = f"{expected:,} bytes", f"{got:,}"
        raise DownloadError(f"{dest}: existing file has the wrong {what}: expected {expected}, got {got}; delete it to download it again")


# --------------------------------------------------------------------------------------------
# Checking archives
# --------------------------------------------------------------------------------------------


def verify_archive(path: str | os.PathLike, archive: Archive, *, check_crc: bool = True) -> None:
    """Check that ``path`` is a readable zip with the PNG layout of ``archive``.

    PNG members (``*.png``, any case) are counted per folder and must match ``archive.layout``
    exactly: every expected folder with its count, and no PNG anywhere else. Folders, non-PNG
    files, ``__MACOSX/`` resource forks and dot-files are ignored.

    Parameters
    ----------
    path : path-like
        The zip file.
    archive : Archive
        What it must contain.
    check_crc : bool
        Also read every member and check its CRC (about 0.2 s per 60 MB archive), which catches
        damage inside the file that the layout check cannot see.

    Raises
    ------
    InputError
        Naming the file and the problem: missing, not a zip, truncated or damaged, or the wrong
        layout (each mismatched folder with the counts found and expected).
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    if not path.is_file():
        raise InputError(f"{path}: not a file")
    try:
        with zipfile.ZipFile(path) as zf:
            counts = _count_pngs(zf.infolist())
            problems = _layout_problems(counts, archive.layout)
            if problems:
                shown = problems[:_MAX_PROBLEMS_SHOWN]
                if len(problems) > len(shown):
                    shown.append(f"and {len(problems) - len(shown)} more folders")
                raise InputError(
                    f"{path}: not the expected {archive.filename} layout "
                    f"({sum(counts.values()):,} PNG found, {archive.n_images:,} expected): "
                    + "; ".join(shown)
                )
            if check_crc:
                bad = zf.testzip()
                if bad is not None:
                    raise InputError(f"{path}: damaged zip: member {bad!r} fails its CRC check")
    except zipfile.BadZipFile as exc:
        raise InputError(_why_not_zip(path, exc)) from exc
    except (zlib.error, EOFError) as exc:
        raise InputError(f"{path}: damaged zip: {exc}") from exc
    except (NotImplementedError, RuntimeError) as exc:
        # Unsupported compression method or an encrypted member.
        raise InputError(f"{path}: cannot read this zip: {exc}") from exc
    except OSError as exc:
        raise InputError(f"{path}: cannot read: {exc.strerror or exc}") from exc


def _member_folder(info: zipfile.ZipInfo) -> str | None:
    """Folder of a PNG member, or None for members the layout ignores."""
    if info.is_dir():
        return None
    parts = [p for p in info.filename.replace("\\", "/").split("/") if p not in ("", ".")]
    if not parts or parts[0] == "__MACOSX" or any(p.startswith(".") for p in parts):
        return None
    if not parts[-1].lower().endswith(".png"):
        return None
    return "/".join(parts[:-1])


def _count_pngs(infos: list[zipfile.ZipInfo]) -> Counter[str]:
    counts: Counter[str] = Counter()
    for info in infos:
        folder = _member_folder(info)
        if folder is not None:
            counts[folder] += 1
    return counts


def _layout_problems(counts: Mapping[str, int], layout: Mapping[str, int]) -> list[str]:
    """One line per folder whose PNG count differs from the expected layout."""
    problems = []
    for folder in sorted(set(layout) | set(counts)):
        want, got = layout.get(folder, 0), counts.get(folder, 0)
        if want != got:
            where = folder or "(top level)"
            if folder not in layout:
                problems.append(f"{where}: {got:,} PNG found, none expected")
            else:
                problems.append(f"{where}: {got:,} PNG found, {want:,} expected")
    return problems


def _why_not_zip(path: Path, exc: BaseException) -> str:
    """Explain why ``path`` did not open as a zip: empty, truncated, or something else entirely."""
    try:
        with open(path, "rb") as f:
            head = f.read(4)
        n_bytes = path.stat().st_size
    except OSError:
        return f"{path}: not a readable zip archive ({exc})"
    if n_bytes == 0:
        return f"{path}: empty file, not a zip archive"
    if head == b"PK\x03\x04":
        return (
            f"{path}: truncated or damaged zip archive ({n_bytes:,} bytes; {exc}); "
            f"delete it and download it again"
        )
    return f"{path}: not a zip archive (starts with {head!r})"


# --------------------------------------------------------------------------------------------
# Both archives
# --------------------------------------------------------------------------------------------


def download_archives(
    data_dir: str | os.PathLike,
    *,
    base_url: str = DEFAULT_BASE_URL,
    progress: bool = True,
    archives: Mapping[str, Archive] | None = None,
) -> dict[str, Path]:
    """Download the training archives into ``data_dir`` and check their layout.

    Archives already present are checked and kept; missing ones are downloaded (resuming an
    interrupted attempt) and checked before they get their final name.

    Parameters
    ----------
    data_dir : path-like
        Folder for the archives; created if missing.
    base_url : str
        Address of the folder holding the archives; each is fetched from
        ``base_url + "/" + archive.filename``.
    progress : bool
        Show a progress bar on stderr (only when stderr is a terminal).
    archives : mapping of str to Archive, optional
        What to fetch; defaults to :data:`ARCHIVES`.

    Returns
    -------
    dict of str to Path
        The path of each archive, by name.

    Raises
    ------
    DownloadError
        If a download fails (see :func:`download_file`) or a downloaded archive does not have
        the expected layout (it is deleted).
    InputError
        If an archive already in ``data_dir`` is not valid; it is left alone, and the message
        says to delete it.
    OutputError
        If ``data_dir`` cannot be created or written.
    """
    data_dir = Path(data_dir)
    archives = ARCHIVES if archives is None else archives
    if data_dir.exists() and not data_dir.is_dir():
        raise OutputError(f"{data_dir}: not a folder")
    try:
        data_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"{data_dir}: cannot create the data folder: {exc.strerror or exc}") from exc

    paths: dict[str, Path] = {}
    for name, archive in archives.items():
        dest = data_dir / archive.filename
        url = f"{base_url.rstrip('/')}/{urllib.parse.quote(archive.filename)}"
        if dest.exists():
            try:
                verify_archive(dest, archive)
            except InputError as exc:
                raise InputError(f"{exc}; delete it to download a fresh copy") from exc
        else:
            _download(
                url,
                dest,
                md5=None,
                size=None,
                progress=progress,
                chunk_size=1 << 20,
                timeout=30,
                check=_layout_check(url, archive),
            )
        paths[name] = dest
    return paths


def _layout_check(url: str, archive: Archive) -> Callable[[Path], None]:
    """A ``check`` for :func:`_download` that turns a failed :func:`verify_archive` into an error."""

    def check(part: Path) -> None:
        try:
            verify_archive(part, archive)
        except InputError as exc:
            raise DownloadError(
                f"{url}: the downloaded archive is not valid and was deleted: {exc}"
            ) from exc

    return check


# --------------------------------------------------------------------------------------------
# Small helpers
# --------------------------------------------------------------------------------------------


def _normalise_md5(md5: str | None) -> str | None:
    if md5 is None:
        return None
    value = str(md5).strip().lower()
    if not re.fullmatch(r"[0-9a-f]{32}", value):
        raise InputError(f"md5 must be 32 hexadecimal digits, got {md5!r}")
    return value


def _mismatch(path: Path, *, md5: str | None, size: int | None):
    """``(what, expected, got)`` for the first check ``path`` fails (size, then md5), else None."""
    if size is not None:
        got_size = _file_size(path)
        if got_size != size:
            return "size", size, got_size
    if md5 is not None:
        got_md5 = _md5sum(path)
        if got_md5 != md5:
            return "md5", md5, got_md5
    return None


def _md5sum(path: Path) -> str:
    digest = hashlib.md5(usedforsecurity=False)
    with open(path, "rb") as f:
        while block := f.read(_HASH_CHUNK):
            digest.update(block)
    return digest.hexdigest()


def _file_size(path: Path) -> int:
    """Size of ``path`` in bytes; 0 if it does not exist."""
    try:
        return path.stat().st_size
    except FileNotFoundError:
        return 0


def _remove(path: Path) -> None:
    with suppress(FileNotFoundError):
        path.unlink()


def _content_length(response: http.client.HTTPResponse) -> int | None:
    value = response.headers.get("Content-Length")
    try:
        length = int(value) if value is not None else None
    except ValueError:
        return None
    return length if length is not None and length >= 0 else None


_CONTENT_RANGE = re.compile(r"\s*bytes\s+(?:(\d+)-(\d+)|\*)/(\d+|\*)\s*", re.IGNORECASE)


def _parse_content_range(value: str | None) -> tuple[int | None, int | None, int | None] | None:
    """Parse ``bytes START-END/TOTAL`` or ``bytes */TOTAL``; unknown parts are None.

    Returns None when the header is missing or malformed.
    """
    if value is None:
        return None
    match = _CONTENT_RANGE.fullmatch(value)
    if match is None:
        return None
    start, end, total = match.groups()
    return (
        int(start) if start is not None else None,
        int(end) if end is not None else None,
        int(total) if total != "*" else None,
    )


def _progress_wanted(progress: bool) -> bool:
    if not progress:
        return False
    stream = sys.stderr
    try:
        return stream is not None and stream.isatty()
    except (AttributeError, ValueError):
        return False


def _describe(exc: object) -> str:
    """A short text for an exception or a URLError reason."""
    if isinstance(exc, BaseException):
        text = str(exc) or type(exc).__name__
        if isinstance(exc, TimeoutError) and "timed out" not in text:
            text = f"timed out: {text}"
        return text
    return str(exc)
