"""Tests of vehicle_detection.training.download against an in-process HTTP server on 127.0.0.1.

No test touches the network: the server below serves bytes from memory, honours (or, when told,
ignores) ``Range`` requests, and can cut a transfer short or stall in the middle of one.
"""

from __future__ import annotations

import hashlib
import io
import os
import re
import socket
import sys
import threading
import zipfile
from dataclasses import FrozenInstanceError
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from vehicle_detection.training.download import (
    ARCHIVES,
    DEFAULT_BASE_URL,
    Archive,
    download_archives,
    download_file,
    part_path,
    verify_archive,
)
from vehicle_detection.errors import DownloadError, InputError

PAYLOAD = os.urandom(300_000)
PAYLOAD_MD5 = hashlib.md5(PAYLOAD).hexdigest()
CHUNK = 64 * 1024


# --------------------------------------------------------------------------------------------
# Loopback server
# --------------------------------------------------------------------------------------------


class ServerState:
    """What the test server serves and how it misbehaves; also records every request."""

    def __init__(self, base_url: str = "") -> None:
        self.base_url = base_url
        self.files: dict[str, bytes] = {}
        self.status: dict[str, int] = {}  # name -> HTTP error status to answer with
        self.cut: dict[str, int] = {}  # name -> body bytes to send on the next GET, then close
        self.stall: dict[str, int] = {}  # name -> body bytes to send on the next GET, then hang
        self.ignore_range = False  # answer 200 with the whole file even to a Range request
        self.range_shift = 0  # answer a Range request with a slice starting this much later
        self.requests: list[tuple[str, str | None]] = []  # (name, Range header)
        self.lock = threading.Lock()
        self.release = threading.Event()

    def url(self, name: str) -> str:
        return f"{self.base_url}/{name}"

    def reset(self) -> None:
        base_url, release = self.base_url, self.release
        self.__init__(base_url)
        self.release = release

    @property
    def ranges(self) -> list[str | None]:
        return [rng for _, rng in self.requests]


class _Handler(BaseHTTPRequestHandler):
    server: ThreadingHTTPServer

    def log_message(self, format, *args):  # noqa: A002 - silence the default stderr log
        pass

    def do_GET(self):  # noqa: N802 - name fixed by BaseHTTPRequestHandler
        state: ServerState = self.server.state
        name = self.path.lstrip("/")
        rng = self.headers.get("Range")
        with state.lock:
            state.requests.append((name, rng))
            cut = state.cut.pop(name, None)
            stall = state.stall.pop(name, None)
        if name in state.status:
            self.send_error(state.status[name])
            return
        data = state.files.get(name)
        if data is None:
            self.send_error(404)
            return

        status, start = 200, 0
        if rng is not None and not state.ignore_range:
            match = re.fullmatch(r"bytes=(\d+)-", rng)
            assert match, rng
            start = int(match.group(1))
            if start >= len(data):
                self.send_response(416)
                self.send_header("Content-Range", f"bytes */{len(data)}")
                self.send_header("Content-Length", "0")
                self.end_headers()
                return
            status, start = 206, min(start + state.range_shift, len(data) - 1)
        body = data[start:]
        self.send_response(status)
        self.send_header("Content-Type", "application/octet-stream")
        self.send_header("Content-Length", str(len(body)))
        if status == 206:
            self.send_header("Content-Range", f"bytes {start}-{len(data) - 1}/{len(data)}")
        self.end_headers()
        if cut is not None:
            # Announce the whole body, send part of it, then close the connection.
            self.wfile.write(body[:cut])
            self.wfile.flush()
            self.close_connection = True
            return
        if stall is not None:
            self.wfile.write(body[:stall])
            self.wfile.flush()
            state.release.wait(5)
            self.close_connection = True
            return
        self.wfile.write(body)


@pytest.fixture(scope="module")
def _httpd():
    httpd = ThreadingHTTPServer(("127.0.0.1", 0), _Handler)
    httpd.daemon_threads = True
    state = ServerState(f"http://127.0.0.1:{httpd.server_address[1]}")
    httpd.state = state
    thread = threading.Thread(target=httpd.serve_forever, kwargs={"poll_interval": 0.05}, daemon=True)
    thread.start()
    yield state
    state.release.set()
    httpd.shutdown()
    httpd.server_close()
    thread.join(5)


@pytest.fixture
def server(_httpd, monkeypatch):
    """The loopback server, reset to serve ``f.bin`` (300,000 random bytes) properly."""
    monkeypatch.setenv("no_proxy", "127.0.0.1,localhost")
    _httpd.reset()
    _httpd.files["f.bin"] = PAYLOAD
    return _httpd


def _closed_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return sock.getsockname()[1]


# --------------------------------------------------------------------------------------------
# download_file
# --------------------------------------------------------------------------------------------


def test_full_download_matches_source(server, tmp_path):
    dest = tmp_path / "sub" / "f.bin"
    out = download_file(server.url("f.bin"), dest, md5=PAYLOAD_MD5, progress=False, chunk_size=CHUNK)
    assert out == dest
    assert dest.read_bytes() == PAYLOAD
    assert hashlib.md5(dest.read_bytes()).hexdigest() == PAYLOAD_MD5
    assert not part_path(dest).exists()
    assert server.ranges == [None]


def test_interrupted_transfer_keeps_part_and_resumes(server, tmp_path):
    dest = tmp_path / "f.bin"
    server.cut["f.bin"] = 100_000
    with pytest.raises(DownloadError) as info:
        download_file(server.url("f.bin"), dest, md5=PAYLOAD_MD5, progress=False, chunk_size=CHUNK)
    message = str(info.value)
    assert server.url("f.bin") in message
    assert "100,000 of 300,000 bytes" in message
    assert "resume" in message
    assert not dest.exists()
    part = part_path(dest)
    assert part.name == "f.bin.part"
    assert part.read_bytes() == PAYLOAD[:100_000]

    download_file(server.url("f.bin"), dest, md5=PAYLOAD_MD5, progress=False, chunk_size=CHUNK)
    assert server.ranges == [None, "bytes=100000-"]
    assert dest.read_bytes() == PAYLOAD
    assert not part.exists()


def test_stalled_transfer_times_out_and_keeps_part(server, tmp_path):
    dest = tmp_path / "f.bin"
    server.stall["f.bin"] = 5_000
    with pytest.raises(DownloadError, match=r"5,000 of 300,000 bytes.*timed out.*resume"):
        download_file(server.url("f.bin"), dest, progress=False, chunk_size=CHUNK, timeout=0.3)
    assert not dest.exists()
    assert part_path(dest).read_bytes() == PAYLOAD[:5_000]


@settings(
    max_examples=15,
    deadline=None,
    database=None,
    suppress_health_check=[HealthCheck.function_scoped_fixture],
)
@given(cut=st.integers(min_value=0, max_value=len(PAYLOAD) - 1))
def test_resume_from_any_cut_point(server, tmp_path_factory, cut):
    server.reset()
    server.files["f.bin"] = PAYLOAD
    dest = tmp_path_factory.mktemp("resume") / "f.bin"
    server.cut["f.bin"] = cut
    with pytest.raises(DownloadError, match="resume"):
        download_file(server.url("f.bin"), dest, progress=False, chunk_size=CHUNK)
    assert not dest.exists()
    download_file(server.url("f.bin"), dest, md5=PAYLOAD_MD5, progress=False, chunk_size=CHUNK)
    assert dest.read_bytes() == PAYLOAD
    assert server.ranges == [None, f"bytes={cut}-" if cut else None]


def test_server_ignoring_range_restarts_from_zero(server, tmp_path):
    dest = tmp_path / "f.bin"
    # A partial file whose bytes are NOT a prefix of the payload: appending to it would corrupt
    # the result, so this only passes if the 200 answer really restarts the file.
    part_path(dest).write_bytes(b"\0" * 100_000)
    server.ignore_range = True
    download_file(server.url("f.bin"), dest, progress=False, chunk_size=CHUNK)
    assert server.ranges == ["bytes=100000-"]
    assert dest.read_bytes() == PAYLOAD
    assert not part_path(dest).exists()


def test_unexpected_content_range_start_restarts(server, tmp_path):
    dest = tmp_path / "f.bin"
    part_path(dest).write_bytes(PAYLOAD[:100_000])
    server.range_shift = 10  # answers 206 from byte 100,010 instead of 100,000
    download_file(server.url("f.bin"), dest, md5=PAYLOAD_MD5, progress=False, chunk_size=CHUNK)
    assert server.ranges == ["bytes=100000-", None]
    assert dest.read_bytes() == PAYLOAD


def test_416_on_complete_part_finishes_without_refetching(server, tmp_path):
    dest = tmp_path / "f.bin"
    part_path(dest).write_bytes(PAYLOAD)  # e.g. killed after the transfer, before the rename
    download_file(server.url("f.bin"), dest, md5=PAYLOAD_MD5, progress=False)
    assert server.ranges == [f"bytes={len(PAYLOAD)}-"]
    assert dest.read_bytes() == PAYLOAD
    assert not part_path(dest).exists()


def test_416_on_overlong_part_restarts(server, tmp_path):
    dest = tmp_path / "f.bin"
    part_path(dest).write_bytes(PAYLOAD + b"junk")
    download_file(server.url("f.bin"), dest, progress=False, chunk_size=CHUNK)
    assert server.ranges == [f"bytes={len(PAYLOAD) + 4}-", None]
    assert dest.read_bytes() == PAYLOAD


def test_complete_part_with_known_size_needs_no_request(server, tmp_path):
    dest = tmp_path / "f.bin"
    part_path(dest).write_bytes(PAYLOAD)
    download_file(server.url("f.bin"), dest, size=len(PAYLOAD), md5=PAYLOAD_MD5, progress=False)
    assert server.requests == []
    assert dest.read_bytes() == PAYLOAD


def test_md5_mismatch_deletes_file(server, tmp_path):
    dest = tmp_path / "f.bin"
    wrong = "0" * 32
    with pytest.raises(DownloadError) as info:
        download_file(server.url("f.bin"), dest, md5=wrong, progress=False, chunk_size=CHUNK)
    message = str(info.value)
    assert "md5 mismatch" in message
    assert f"expected {wrong}, got {PAYLOAD_MD5}" in message
    assert "deleted" in message
    assert not dest.exists()
    assert not part_path(dest).exists()


def test_md5_is_case_insensitive(server, tmp_path):
    dest = tmp_path / "f.bin"
    download_file(server.url("f.bin"), dest, md5=PAYLOAD_MD5.upper(), progress=False)
    assert dest.read_bytes() == PAYLOAD


def test_size_mismatch_deletes_file(server, tmp_path):
    dest = tmp_path / "f.bin"
    with pytest.raises(DownloadError) as info:
        download_file(server.url("f.bin"), dest, size=len(PAYLOAD) + 1, progress=False)
    message = str(info.value)
    assert "wrong size" in message
    assert "expected 300,001 bytes, got 300,000" in message
    assert "deleted" in message
    assert not dest.exists()
    assert not part_path(dest).exists()


@pytest.mark.parametrize("status", [404, 500])
def test_http_error_names_url(server, tmp_path, status):
    server.status["broken.bin"] = status
    url = server.url("broken.bin")
    with pytest.raises(DownloadError, match=rf"{re.escape(url)}: .*HTTP {status}"):
        download_file(url, tmp_path / "broken.bin", progress=False)
    assert list(tmp_path.iterdir()) == []


def test_missing_file_is_404(server, tmp_path):
    url = server.url("nothing-here.zip")
    with pytest.raises(DownloadError, match=rf"{re.escape(url)}: .*HTTP 404"):
        download_file(url, tmp_path / "x.zip", progress=False)


def test_connection_refused(tmp_path, monkeypatch):
    monkeypatch.setenv("no_proxy", "127.0.0.1,localhost")
    url = f"http://127.0.0.1:{_closed_port()}/f.bin"
    with pytest.raises(DownloadError, match=rf"{re.escape(url)}: cannot reach the server"):
        download_file(url, tmp_path / "f.bin", progress=False, timeout=2)
    assert list(tmp_path.iterdir()) == []


def test_bad_arguments(tmp_path):
    with pytest.raises(InputError, match="md5"):
        download_file("http://127.0.0.1:1/x", tmp_path / "x", md5="abc", progress=False)
    with pytest.raises(InputError, match="size"):
        download_file("http://127.0.0.1:1/x", tmp_path / "x", size=-1, progress=False)
    with pytest.raises(InputError, match="chunk_size"):
        download_file("http://127.0.0.1:1/x", tmp_path / "x", chunk_size=0, progress=False)


def test_existing_valid_dest_is_not_downloaded(server, tmp_path):
    dest = tmp_path / "f.bin"
    dest.write_bytes(PAYLOAD)
    assert download_file(server.url("f.bin"), dest, md5=PAYLOAD_MD5, size=len(PAYLOAD)) == dest
    assert server.requests == []


def test_existing_mismatched_dest_is_reported_and_kept(server, tmp_path):
    dest = tmp_path / "f.bin"
    dest.write_bytes(b"something else")
    with pytest.raises(DownloadError, match=r"existing file has the wrong md5.*delete it"):
        download_file(server.url("f.bin"), dest, md5=PAYLOAD_MD5)
    with pytest.raises(DownloadError, match=r"expected 300,000 bytes, got 14"):
        download_file(server.url("f.bin"), dest, size=len(PAYLOAD))
    assert dest.read_bytes() == b"something else"
    assert server.requests == []


class _FakeTTY(io.StringIO):
    def isatty(self) -> bool:
        return True


def test_progress_bar_only_on_a_terminal(server, tmp_path, monkeypatch, capsys):
    download_file(server.url("f.bin"), tmp_path / "a.bin", progress=True)  # stderr is not a tty
    assert capsys.readouterr().err == ""

    fake = _FakeTTY()
    monkeypatch.setattr(sys, "stderr", fake)
    download_file(server.url("f.bin"), tmp_path / "b.bin", progress=False)
    assert fake.getvalue() == ""
    download_file(server.url("f.bin"), tmp_path / "c.bin", progress=True)
    assert "c.bin" in fake.getvalue()
    assert capsys.readouterr().out == ""


# --------------------------------------------------------------------------------------------
# verify_archive
# --------------------------------------------------------------------------------------------

CARS = Archive("cars", "http://example.invalid/data/cars.zip", {"cars/A": 3, "cars/B": 2})
ROADS = Archive("roads", "http://example.invalid/data/roads.zip", {"roads": 4})


def _zip_bytes(layout: dict[str, int], extra: tuple[str, ...] = (), stored: bool = False) -> bytes:
    buf = io.BytesIO()
    compression = zipfile.ZIP_STORED if stored else zipfile.ZIP_DEFLATED
    with zipfile.ZipFile(buf, "w", compression) as zf:
        for folder, count in layout.items():
            zf.writestr(f"{folder}/", b"")
            for i in range(count):
                zf.writestr(f"{folder}/img{i:04d}.png", f"not really a png {folder} {i}".encode() * 8)
        for name in extra:
            zf.writestr(name, b"extra")
    return buf.getvalue()


def _write_zip(path: Path, layout: dict[str, int], extra: tuple[str, ...] = ()) -> Path:
    path.write_bytes(_zip_bytes(layout, extra))
    return path


def test_archive_dataclass():
    assert CARS.filename == "cars.zip"
    assert CARS.n_images == 5
    with pytest.raises(FrozenInstanceError):
        CARS.name = "x"
    with pytest.raises(TypeError):
        CARS.layout["cars/A"] = 9
    assert hash(CARS) == hash(Archive("cars", CARS.url, dict(CARS.layout)))
    with pytest.raises(ValueError):
        Archive("bad", "http://example.invalid/", {})
    with pytest.raises(ValueError):
        Archive("bad", "http://example.invalid/x.zip", {"a": -1})


def test_archives_constant_describes_the_public_archives():
    assert set(ARCHIVES) == {"vehicles", "non-vehicles"}
    assert ARCHIVES["vehicles"].url == f"{DEFAULT_BASE_URL}/vehicles.zip"
    assert ARCHIVES["non-vehicles"].url == f"{DEFAULT_BASE_URL}/non-vehicles.zip"
    assert ARCHIVES["vehicles"].n_images == 8792
    assert ARCHIVES["non-vehicles"].n_images == 8968
    assert ARCHIVES["vehicles"].layout["vehicles/KITTI_extracted"] == 5966
    assert ARCHIVES["non-vehicles"].layout["non-vehicles/Extras"] == 5068


def test_verify_archive_accepts_right_layout_ignoring_junk(tmp_path):
    extra = (
        "__MACOSX/cars/A/._img0000.png",
        "__MACOSX/cars/B/img0000.png",
        "cars/A/.hidden.png",
        ".DS_Store",
        "cars/B/Thumbs.db",
        "cars/README.txt",
    )
    verify_archive(_write_zip(tmp_path / "cars.zip", dict(CARS.layout), extra), CARS)
    verify_archive(_write_zip(tmp_path / "roads.zip", {"roads": 4}), ROADS)


@pytest.mark.parametrize(
    ("layout", "extra", "expected"),
    [
        ({"cars/A": 2, "cars/B": 2}, (), "cars/A: 2 PNG found, 3 expected"),
        ({"cars/A": 3}, (), "cars/B: 0 PNG found, 2 expected"),
        ({"cars/A": 3, "cars/B": 2, "cars/C": 1}, (), "cars/C: 1 PNG found, none expected"),
        ({"cars/A": 3, "cars/B": 2}, ("stray.PNG",), "(top level): 1 PNG found, none expected"),
        ({"Cars/A": 3, "cars/B": 2}, (), "cars/A: 0 PNG found, 3 expected"),
    ],
)
def test_verify_archive_rejects_wrong_layout(tmp_path, layout, extra, expected):
    path = _write_zip(tmp_path / "cars.zip", layout, extra)
    with pytest.raises(InputError) as info:
        verify_archive(path, CARS)
    message = str(info.value)
    assert message.startswith(f"{path}: ")
    assert "layout" in message
    assert expected in message


def test_verify_archive_rejects_non_zip(tmp_path):
    path = tmp_path / "cars.zip"
    path.write_bytes(b"<html><body>Access denied</body></html>")
    with pytest.raises(InputError, match=rf"{re.escape(str(path))}: not a zip archive"):
        verify_archive(path, CARS)
    path.write_bytes(b"")
    with pytest.raises(InputError, match="empty file"):
        verify_archive(path, CARS)


def test_verify_archive_rejects_truncated_zip(tmp_path):
    data = _zip_bytes(dict(CARS.layout))
    path = tmp_path / "cars.zip"
    for keep in (len(data) // 2, len(data) - 10):
        path.write_bytes(data[:keep])
        with pytest.raises(InputError, match=rf"{re.escape(str(path))}: truncated or damaged zip"):
            verify_archive(path, CARS)


def test_verify_archive_catches_damaged_member(tmp_path):
    data = bytearray(_zip_bytes({"roads": 4}, stored=True))
    marker = b"not really a png roads 2"
    at = data.index(marker)
    data[at] ^= 0xFF
    path = tmp_path / "roads.zip"
    path.write_bytes(bytes(data))
    with pytest.raises(InputError, match=r"CRC"):
        verify_archive(path, ROADS)
    verify_archive(path, ROADS, check_crc=False)  # the layout itself is right


def test_verify_archive_missing_file(tmp_path):
    with pytest.raises(InputError, match="no such file"):
        verify_archive(tmp_path / "absent.zip", CARS)
    with pytest.raises(InputError, match="not a file"):
        verify_archive(tmp_path, CARS)


# --------------------------------------------------------------------------------------------
# download_archives
# --------------------------------------------------------------------------------------------


def test_download_archives_end_to_end(server, tmp_path):
    cars, roads = _zip_bytes(dict(CARS.layout)), _zip_bytes(dict(ROADS.layout))
    server.files["data/cars.zip"] = cars
    server.files["data/roads.zip"] = roads
    data_dir = tmp_path / "nested" / "data"
    archives = {"cars": CARS, "roads": ROADS}

    paths = download_archives(data_dir, base_url=server.url("data/"), progress=False, archives=archives)
    assert paths == {"cars": data_dir / "cars.zip", "roads": data_dir / "roads.zip"}
    assert paths["cars"].read_bytes() == cars
    assert paths["roads"].read_bytes() == roads
    assert sorted(p.name for p in data_dir.iterdir()) == ["cars.zip", "roads.zip"]
    assert len(server.requests) == 2

    # Present and valid: nothing is fetched again.
    again = download_archives(data_dir, base_url=server.url("data"), progress=False, archives=archives)
    assert again == paths
    assert len(server.requests) == 2


def test_download_archives_resumes_after_interruption(server, tmp_path):
    cars = _zip_bytes(dict(CARS.layout))
    server.files["cars.zip"] = cars
    server.cut["cars.zip"] = len(cars) // 3
    with pytest.raises(DownloadError, match="resume"):
        download_archives(tmp_path, base_url=server.base_url, progress=False, archives={"cars": CARS})
    assert not (tmp_path / "cars.zip").exists()
    download_archives(tmp_path, base_url=server.base_url, progress=False, archives={"cars": CARS})
    assert (tmp_path / "cars.zip").read_bytes() == cars
    assert server.ranges == [None, f"bytes={len(cars) // 3}-"]


def test_download_archives_deletes_archive_with_wrong_layout(server, tmp_path):
    # The default ARCHIVES, served by the loopback server with a tiny zip in the wrong layout.
    server.files["vehicles.zip"] = _zip_bytes({"vehicles/GTI_Far": 3})
    with pytest.raises(DownloadError) as info:
        download_archives(tmp_path, base_url=server.base_url, progress=False)
    message = str(info.value)
    assert server.url("vehicles.zip") in message
    assert "deleted" in message
    assert "vehicles/GTI_Far: 3 PNG found, 834 expected" in message
    assert list(tmp_path.iterdir()) == []


def test_download_archives_reports_existing_invalid_archive(server, tmp_path):
    bad = _zip_bytes({"cars/A": 1})
    (tmp_path / "cars.zip").write_bytes(bad)
    server.files["cars.zip"] = _zip_bytes(dict(CARS.layout))
    with pytest.raises(InputError, match=r"cars\.zip: .*cars/A: 1 PNG found, 3 expected.*delete it"):
        download_archives(tmp_path, base_url=server.base_url, progress=False, archives={"cars": CARS})
    assert (tmp_path / "cars.zip").read_bytes() == bad
    assert server.requests == []


def test_download_archives_http_error(server, tmp_path):
    with pytest.raises(DownloadError, match=r"/cars\.zip: .*HTTP 404"):
        download_archives(tmp_path, base_url=server.base_url, progress=False, archives={"cars": CARS})
    assert list(tmp_path.iterdir()) == []


# --------------------------------------------------------------------------------------------
# The real archives
# --------------------------------------------------------------------------------------------

REAL_MD5 = {
    "vehicles": "3396fb9ddb465283c78a23311628344c",
    "non-vehicles": "8a6f149fc5dcd74f991299e075c2f0a7",
}


def _shared_data_dir() -> Path | None:
    candidates = []
    if os.environ.get("VEHICLE_DETECTION_DATA"):
        candidates.append(Path(os.environ["VEHICLE_DETECTION_DATA"]))
    candidates.append(Path(__file__).resolve().parents[1].parent / "shared" / "data")
    for folder in candidates:
        if all((folder / a.filename).is_file() for a in ARCHIVES.values()):
            return folder
    return None


def test_real_archives_pass_verification(tmp_path):
    folder = _shared_data_dir()
    if folder is None:
        pytest.skip(
            "real vehicles.zip / non-vehicles.zip not found: set VEHICLE_DETECTION_DATA or put "
            "them in <repo>/../shared/data"
        )
    for name, archive in ARCHIVES.items():
        path = folder / archive.filename
        verify_archive(path, archive)
        # An existing file is checked in place, never fetched (the URL goes nowhere) or changed.
        dead_url = f"http://127.0.0.1:{_closed_port()}/{archive.filename}"
        before = path.stat()
        assert download_file(dead_url, path, md5=REAL_MD5[name], progress=False) == path
        after = path.stat()
        assert (after.st_size, after.st_mtime_ns) == (before.st_size, before.st_mtime_ns)
