"""Peak memory of the command line on hostile inputs that declare huge sizes (issue 45).

Each case is built in a temporary folder and run as its own process; its peak resident memory
(the process's ``VmHWM``, Linux) is printed beside the exit code and the seconds, with
``vehicle-detection --version`` as the reference of a process that does nothing.

    python benchmarks/memory_ceiling.py [--limit-mb 1024]

Exits 1 if a case reaches ``--limit-mb`` or runs past ``--timeout`` seconds.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
import zipfile
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
VIDEO = REPO / "test_video.mp4"
IMAGE = REPO / "test_images" / "test1.jpg"


def signed_model(folder: Path, change) -> Path:
    """The embedded model with its header changed by ``change`` and its digest recomputed."""
    from vehicle_detection.classifier import _digest, default_model_path

    with np.load(default_model_path(), allow_pickle=False) as npz:
        arrays = {k: npz[k] for k in npz.files if k != "meta"}
        meta = json.loads(npz["meta"].tobytes())
    change(meta)
    meta["sha256"] = _digest(arrays, meta)
    out = folder / "forged.npz"
    np.savez(out, meta=np.frombuffer(json.dumps(meta).encode(), np.uint8), **arrays)
    return out


def huge_header(folder: Path) -> Path:
    """The embedded model with ``coef.npy``'s header claiming 10**12 elements."""
    model = signed_model(folder, lambda meta: None)
    out = folder / "huge_header.npz"
    with zipfile.ZipFile(model) as src, zipfile.ZipFile(out, "w") as dst:
        for info in src.infolist():
            data = src.read(info)
            if info.filename == "coef.npy":
                end = 10 + int.from_bytes(data[8:10], "little")
                header = data[10:end].decode("latin1")
                a = header.index("'shape': (") + 10
                header = (header[:a] + "1000000000000," + header[header.index(")", a):]).ljust(end - 11) + "\n"
                data = data[:8] + len(header).to_bytes(2, "little") + header.encode("latin1") + data[end:]
            dst.writestr(info, data)
    return out


def zip_bomb(folder: Path) -> Path:
    """A data folder whose ``vehicles.zip`` holds a PNG member unpacking to 3 GiB."""
    data = folder / "data"
    data.mkdir()
    for cls in ("vehicles", "non-vehicles"):
        with zipfile.ZipFile(data / f"{cls}.zip", "w", compression=zipfile.ZIP_DEFLATED) as zf:
            with zf.open(f"{cls}/set/bomb.png", "w", force_zip64=True) as f:
                block = bytes(1 << 24)
                for _ in range(3 * 64 if cls == "vehicles" else 1):
                    f.write(block)
    return data


def cases(folder: Path) -> dict[str, list[str]]:
    many = folder / "many"
    many.mkdir()

    def scales(meta):
        plan = meta["detector_config"]["plan"]
        plan["scales"] = (plan["scales"] * 5000)[:5000]

    boxes = folder / "boxes.csv"
    boxes.write_text("frame,x1,y1,x2,y2,track_id,score\n0,10,10,50,50,1,1.0\n30000000,10,10,50,50,1,1.0\n"
                     f"{2**31 - 1},10,10,50,50,2,1.0\n")
    return {
        "reference: --version": ["--version"],
        "model with 5,000 scales": ["detect", str(IMAGE), "--model", str(signed_model(many, scales)), "--out", str(folder / "a.jpg")],
        "model header of 10^12 elements": ["detect", str(IMAGE), "--model", str(huge_header(folder)), "--out", str(folder / "b.jpg")],
        "report, rows at frames 3e7 and 2^31-1": ["report", str(boxes), "--out", str(folder / "r.html")],
        "zip bomb (3 GiB member)": ["train", "--data-dir", str(zip_bomb(folder))],
        "mine-negatives --frames 0-50000000": ["mine-negatives", str(VIDEO), "--negative-region", "0,0,1280,720", "--frames",
                                               "0-50000000", "--out", str(folder / "neg"), "--no-progress"],
    }


def _hwm_mb(pid: int) -> float | None:
    """The process's peak resident memory so far (``VmHWM``, Linux), in MiB; None if unknown."""
    try:
        with open(f"/proc/{pid}/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        return None
    return None


def run(argv: list[str], timeout: float) -> tuple[int | None, float, float]:
    """Exit code (None: killed at the timeout), peak resident MiB and seconds of one CLI process.

    The peak is the process's own ``VmHWM``, read every 20 ms while it runs: ``ru_maxrss`` of a
    child counts the memory of the process that started it (the image it was forked from), so
    started from a large process (a test worker) it reads that process's peak.
    """
    t = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-m", "vehicle_detection.cli", *argv],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    peak = 0.0
    while proc.poll() is None and time.perf_counter() - t < timeout:
        peak = max(peak, _hwm_mb(proc.pid) or 0.0)
        time.sleep(0.02)
    if proc.poll() is None:
        proc.kill()
        proc.wait()
        return None, peak, time.perf_counter() - t
    return proc.returncode, peak, time.perf_counter() - t


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--limit-mb", type=float, default=1024)
    p.add_argument("--timeout", type=float, default=300)
    args = p.parse_args(argv)
    bad = 0
    print("| case | exit | peak MB | seconds |")
    print("| --- | --- | --- | --- |")
    with tempfile.TemporaryDirectory() as tmp:
        for name, cli in cases(Path(tmp)).items():
            code, mb, seconds = run(cli, args.timeout)
            over = code is None or mb >= args.limit_mb
            bad += over
            print(f"| {name} | {'killed' if code is None else code} | {mb:.0f}{' (over)' if over else ''} | {seconds:.1f} |", flush=True)
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
