"""Safe output files: never overwrite an input, never leave a half-written file that looks done.

Every writer in the package goes through :func:`atomic_output`: the data are written to a hidden
``.NAME.XXXX.partial`` file beside the destination and renamed over it only once complete, so an
interrupted run (Ctrl-C, a crash, a kill) leaves at most a ``.partial`` file, never a truncated
file under the final name, and an existing output being replaced stays as it was until the new
one is complete.

Several outputs of one run can be committed together with :func:`output_batch`: inside the block
each completed output waits under its ``.partial`` name, and all are renamed into place at the
end of the block, or all are deleted if the block fails, leaving every previous output intact.

Only regular files are ever replaced: an existing output that is a symlink (even to a regular
file), a FIFO, a device (``/dev/null``) or a socket is refused, with or without ``overwrite``,
because renaming over it would replace the special file itself.
"""

from __future__ import annotations

import contextvars
import os
import signal
import stat
import tempfile
import threading
from collections.abc import Iterable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

from ..errors import InputError, OutputError, VehicleDetectionError, output_exists

__all__ = [
    "atomic_output",
    "check_output_path",
    "check_outputs",
    "refuse_inputs",
    "umask",
    "output_batch",
    "interrupt_on_signals",
    "read_text",
    "input_file",
    "PARTIAL_SUFFIX",
    "MAX_TEXT_BYTES",
]

PARTIAL_SUFFIX = ".partial"


def umask() -> int:
    """The process's file mode creation mask (read without changing it)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _special_kind(dest: Path) -> str | None:
    """What ``dest`` is when it exists and is not a regular file (a symlink counts); else None."""
    try:
        mode = os.lstat(dest).st_mode
    except OSError:  # missing (or unreadable: the write itself will say so)
        return None
    if stat.S_ISREG(mode):
        return None
    if stat.S_ISLNK(mode):
        return "a symlink"
    if stat.S_ISFIFO(mode):
        return "a FIFO (named pipe)"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    if stat.S_ISDIR(mode):
        return "a folder"
    return "not a regular file"


def _refuse_special(dest: Path) -> None:
    kind = _special_kind(dest)
    if kind is not None:
        raise OutputError(f"{dest}: output exists and is {kind}, not a regular file; refusing to replace it")


def _write_error(dest: Path, exc: OSError) -> OutputError:
    return OutputError(f"{dest}: cannot write output: {exc.strerror or exc}")


def check_output_path(
    dest: str | os.PathLike, *, overwrite: bool = False, inputs: Iterable[str | os.PathLike] = ()
) -> Path:
    """Refuse an output path that is an input, a folder, a special file, or an existing file.

    Parameters
    ----------
    dest : path-like
        Where the output will be written.
    overwrite : bool
        Allow replacing an existing regular file at ``dest`` (never an input, never a symlink,
        FIFO, device or socket).
    inputs : iterable of path-like
        Files and folders the run reads; ``dest`` may not resolve to any of these files, nor lie
        inside any of these folders (the run's next reading would take it for an input),
        whatever ``overwrite`` says.

    Returns
    -------
    Path
        ``dest`` as a :class:`~pathlib.Path`.

    Raises
    ------
    OutputError
        If ``dest`` is an input or lies in an input folder, a folder, below a file instead of a folder, exists and is not a
        regular file (symlinks included, dangling or not), or exists and ``overwrite`` is false.
    """
    dest = Path(dest)
    _refuse_over_inputs(dest, inputs if isinstance(inputs, _Inputs) else _Inputs(inputs))
    if dest.is_dir():
        raise OutputError(f"{dest}: output path is a folder; give a file name")
    _refuse_special(dest)
    for folder in dest.parents:  # the nearest existing ancestor must be a folder
        if folder.exists() or folder.is_symlink():
            if not folder.is_dir():
                what = "a dangling symlink" if not folder.exists() else _special_kind(folder.resolve()) or "a file"
                raise OutputError(f"{dest}: cannot write output here: {folder} is {what}, not a folder")
            break
    if dest.exists() and not overwrite:
        raise output_exists(dest)
    return dest


def check_outputs(
    outputs: Iterable[str | os.PathLike], *, overwrite: bool = False, inputs: Iterable[str | os.PathLike] = ()
) -> list[Path]:
    """:func:`check_output_path` for every output of one run, and no two outputs the same file.

    Returns
    -------
    list of Path
        The outputs, in order.

    Raises
    ------
    OutputError
        As :func:`check_output_path`, or if two outputs name the same file.
    """
    outputs, inputs = [Path(o) for o in outputs], _Inputs(inputs)
    seen: dict[Path, Path] = {}
    for out in outputs:
        key = out.resolve()
        if key in seen:
            raise OutputError(f"{out}: named for two outputs of one run ({seen[key]} too); each output needs a file of its own")
        seen[key] = out
        check_output_path(out, overwrite=overwrite, inputs=inputs)
    return outputs


class _Inputs:
    """A run's inputs, indexed once so that each output is checked against all of them in
    constant time: by resolved path, by device and inode (hard links, other spellings), and
    the folders among them."""

    def __init__(self, inputs: Iterable[str | os.PathLike]) -> None:
        self.paths: dict[Path, Path] = {}
        self.inodes: dict[tuple[int, int], Path] = {}
        self.folders: dict[Path, Path] = {}
        for src in inputs:
            src = Path(src)
            key = src.resolve()
            self.paths.setdefault(key, src)
            try:
                st = os.stat(key)
            except OSError:
                continue
            if stat.S_ISDIR(st.st_mode):
                self.folders.setdefault(key, src)
            else:
                self.inodes.setdefault((st.st_dev, st.st_ino), src)


def _refuse_over_inputs(dest: Path, inputs: _Inputs) -> None:
    key = dest.resolve()
    src = inputs.paths.get(key)
    if src is None and inputs.inodes:
        with suppress(OSError):
            st = os.stat(key)
            src = inputs.inodes.get((st.st_dev, st.st_ino))
    if src is not None and key not in inputs.folders:
        raise OutputError(f"{dest}: output would overwrite the input {src}; choose another output path")
    if inputs.folders:
        for parent in (key, *key.parents):
            if parent in inputs.folders:
                raise OutputError(f"{dest}: output would be written into the input folder {inputs.folders[parent]}; "
                                  "choose another output path")


def refuse_inputs(dest: str | os.PathLike, inputs: Iterable[str | os.PathLike]) -> None:
    """Refuse an output folder that is, contains or lies inside one of ``inputs``.

    Raises
    ------
    OutputError
        Naming the folder and the input.
    """
    d = Path(os.path.abspath(dest))
    for src in inputs:
        s = Path(os.path.abspath(src))
        if s == d or d in s.parents or s in d.parents:
            raise OutputError(f"{dest}: output folder would overwrite or lie inside the input {src}; choose another --out")


# --- committing outputs ------------------------------------------------------------------------


class _Deferring:
    """Set while a signal must wait (see interrupt_on_signals): finished outputs being renamed into
    place, or a temporary file being made before its clean-up is in place."""

    active = 0
    pending: int | None = None


@contextmanager
def _signals_deferred() -> Iterator[None]:
    """A signal caught by :func:`interrupt_on_signals` inside the block interrupts at its end.

    Only in the main thread, where Python runs signal handlers: another thread's block must not
    hold back, or take over, the main thread's interrupt.
    """
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    _Deferring.active += 1
    try:
        yield
    finally:
        _Deferring.active -= 1
    if _Deferring.pending is not None and not _Deferring.active:
        _Deferring.pending = None
        raise KeyboardInterrupt  # a signal arrived in the block: act on it now


def _commit(entries: list[tuple[Path, Path, bool]]) -> None:
    """Rename each finished temporary file over its destination, checking every one first.

    Raises OutputError (and deletes every temporary file not yet renamed) if a destination has
    become unacceptable meanwhile or a rename fails.
    """
    done = 0
    try:
        for tmp, dest, overwrite in entries:  # all checks before the first rename
            _refuse_special(dest)
            if dest.exists() and not overwrite:
                raise output_exists(dest, "output appeared while writing")
            try:
                os.chmod(tmp, 0o666 & ~umask())  # mkstemp creates 0600; give the usual permissions
            except OSError as exc:
                raise _write_error(dest, exc) from None
        with _signals_deferred():  # a signal during the renames acts once they are all done
            for tmp, dest, _ in entries:
                try:
                    os.replace(tmp, dest)
                except OSError as exc:
                    raise _write_error(dest, exc) from None
                done += 1
    except BaseException:
        for tmp, _, _ in entries[done:]:
            with suppress(OSError):
                tmp.unlink()
        raise


class _Batch:
    def __init__(self) -> None:
        self.entries: list[tuple[Path, Path, bool]] = []
        self.created: list[Path] = []  # folders made for the outputs, outermost first


_BATCH: contextvars.ContextVar[_Batch | None] = contextvars.ContextVar("vehicle_detection_output_batch", default=None)


@contextmanager
def output_batch() -> Iterator[None]:
    """Commit every :func:`atomic_output` completed inside the block together, at its end.

    Inside the block a finished output stays under its hidden ``.partial`` name. When the block
    succeeds, every destination is checked again and all are renamed into place (in the order
    they were finished); when it raises (including ``KeyboardInterrupt``), every temporary file
    is deleted, so the previous outputs, if any, are left exactly as they were, and folders
    created for the outputs are removed again if empty. Nested batches join the outer one.
    """
    if _BATCH.get() is not None:
        yield
        return
    batch = _Batch()
    token = _BATCH.set(batch)
    try:
        yield
    except BaseException:
        _BATCH.reset(token)
        for tmp, _, _ in batch.entries:
            with suppress(OSError):
                tmp.unlink()
        for folder in reversed(batch.created):
            with suppress(OSError):
                folder.rmdir()  # only if empty
        raise
    _BATCH.reset(token)
    _commit(batch.entries)


def _make_parents(folder: Path) -> list[Path]:
    """Create ``folder`` and missing ancestors; return those created, outermost first."""
    missing = []
    for f in (folder, *folder.parents):
        if f.exists() or f.is_symlink():
            break
        missing.append(f)
    folder.mkdir(parents=True, exist_ok=True)
    return list(reversed(missing))


@contextmanager
def atomic_output(
    dest: str | os.PathLike,
    *,
    overwrite: bool = False,
    inputs: Iterable[str | os.PathLike] = (),
) -> Iterator[Path]:
    """Yield a temporary path beside ``dest``; rename it to ``dest`` when the block succeeds.

    Missing parent folders are created. On any exception (including ``KeyboardInterrupt``) the
    temporary file is deleted and ``dest`` is left as it was: an existing file being replaced
    is only replaced by the finished new one. Inside :func:`output_batch` the rename waits for
    the end of the batch.

    Parameters
    ----------
    dest : path-like
        Final output path.
    overwrite, inputs
        As for :func:`check_output_path`.

    Yields
    ------
    Path
        The temporary file to write (it exists, empty). Writers that infer the format from the
        file name (ffmpeg) must be told the format explicitly: the name ends in ``.partial``.

    Raises
    ------
    OutputError
        As :func:`check_output_path`; also when writing fails with an ``OSError`` (disk full,
        quota, read-only file system, permission denied...): the message names ``dest``.
    """
    dest = check_output_path(dest, overwrite=overwrite, inputs=inputs)
    batch = _BATCH.get()
    tmp = None
    try:
        # A signal while the file is made would leave it behind: it interrupts once ``tmp`` is
        # known, inside the block that deletes it.
        with _signals_deferred():
            try:
                created = _make_parents(dest.parent)
                if batch is not None:
                    batch.created.extend(created)
                fd, tmp_name = tempfile.mkstemp(prefix=f".{dest.name}.", suffix=PARTIAL_SUFFIX, dir=dest.parent)
            except OSError as exc:
                raise OutputError(f"{dest}: cannot write output here: {exc.strerror or exc}") from exc
            os.close(fd)
            tmp = Path(tmp_name)
        try:
            yield tmp
        except VehicleDetectionError:
            raise
        except OSError as exc:  # ENOSPC, EDQUOT, EROFS, EACCES, EIO... while writing
            raise _write_error(dest, exc) from exc
        if batch is not None:
            batch.entries.append((tmp, dest, overwrite))
        else:
            _commit([(tmp, dest, overwrite)])
    except BaseException:
        if tmp is not None:
            with suppress(OSError):
                tmp.unlink()
        raise


# --- signals -----------------------------------------------------------------------------------


@contextmanager
def interrupt_on_signals(signals: Iterable[str] = ("SIGINT", "SIGTERM", "SIGHUP")) -> Iterator[None]:
    """Within the block, SIGINT, SIGTERM and SIGHUP raise ``KeyboardInterrupt`` like Ctrl-C.

    So ``timeout``, ``docker stop``, systemd and a closed terminal get the same clean-up as
    Ctrl-C: temporary files deleted, previous outputs left intact. Only the first signal raises
    (a second one during the clean-up is ignored), and a signal that arrives while finished
    outputs are being renamed into place, or while a temporary output file is being made, is
    acted on once that is done. Installed only
    when called from the main thread; the previous handlers are restored on exit.
    """
    nums = [getattr(signal, name) for name in signals if hasattr(signal, name)]
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    fired = False

    def handler(signum, frame):
        nonlocal fired
        if fired:
            return
        if _Deferring.active:
            _Deferring.pending = signum
            return
        fired = True
        raise KeyboardInterrupt

    previous = {}
    try:
        for num in nums:
            previous[num] = signal.signal(num, handler)
        yield
    finally:
        for num, old in previous.items():
            signal.signal(num, old if old is not None else signal.SIG_DFL)
        _Deferring.pending = None


# --- reading -----------------------------------------------------------------------------------


#: Largest text input read (a labels, camera or boxes file), bytes.
MAX_TEXT_BYTES = 256 * 1024 * 1024


def input_file(path: str | os.PathLike, what: str, error: type[InputError] = InputError) -> os.stat_result:
    """Check that ``path`` (a symlink is followed) is a regular file that can be read.

    A device (``/dev/zero``), a FIFO or a socket would be read forever, or block: they are
    refused before they are opened, as are folders and missing files.

    Parameters
    ----------
    path : path-like
    what : str
        What the file is, for messages (``"camera file"``).
    error : type
        The :class:`InputError` subclass raised (:class:`~vehicle_detection.errors.ModelError`
        for model files).

    Returns
    -------
    os.stat_result
        Of the file (after following symlinks).
    """
    path = Path(path)
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise error(f"{path}: {what} not found") from None
    except OSError as exc:
        raise error(f"{path}: cannot read {what}: {exc.strerror or exc}") from None
    if stat.S_ISDIR(st.st_mode):
        raise error(f"{path}: is a folder, not a regular file ({what} expected)")
    if not stat.S_ISREG(st.st_mode):
        kind = _special_kind(path.resolve()) or "not a regular file"
        raise error(f"{path}: is {kind}, not a regular file ({what} expected)")
    return st


def read_text(path: str | os.PathLike, what: str, kind: str, *, encoding: str = "utf-8") -> str:
    """Read a text input, turning every failure into an :class:`InputError` naming the file.

    Parameters
    ----------
    path : path-like
        A regular file (or a symlink to one) of at most :data:`MAX_TEXT_BYTES`.
    what : str
        What the file is, for messages (``"annotation file"``).
    kind : str
        Its expected format, for the hint on undecodable bytes (``"JSON"``).
    encoding : str
        ``"utf-8-sig"`` also accepts a byte-order mark.
    """
    path = Path(path)
    st = input_file(path, what)
    if st.st_size > MAX_TEXT_BYTES:
        raise InputError(f"{path}: {what} of {st.st_size} bytes is larger than the {MAX_TEXT_BYTES // 2**20} MiB a {kind} input may be")
    try:
        with open(path, encoding=encoding, newline=None) as fh:
            return fh.read(MAX_TEXT_BYTES + 1)
    except FileNotFoundError:
        raise InputError(f"{path}: {what} not found") from None
    except IsADirectoryError:
        raise InputError(f"{path}: is a folder, not a {what}") from None
    except UnicodeDecodeError as exc:
        raise InputError(f"{path}: not UTF-8 text (byte {exc.start}); is this a {kind} file?") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read {what}: {exc.strerror or exc}") from None
