"""Every script of ``tools/`` that README.md, writeup.md or docs/ cites runs: with ``--help``, and on the
smallest real input that finishes in seconds (its own options, a few frames, a few images).

A script whose input is not on this machine (the mined negatives, a browser) is skipped with the
reason; its ``--help`` still runs. A newly cited script fails here until it has a tiny run below.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
TOOLS = REPO / "tools"
SHARED = Path(os.environ.get("VEHICLE_DETECTION_DATA", REPO.parent / "shared" / "data"))
CLIP_A = REPO / "dev_set" / "project_video_clip_A.mp4"
NEGATIVES = REPO / "data" / "negatives" / "non-vehicles"


def cited() -> list[str]:
    """The tools the README, the writeup and the documents of ``docs/`` name, ``tools/NAME.py``."""
    docs = [REPO / "README.md", REPO / "writeup.md", *sorted((REPO / "docs").glob("*.md"))]
    text = "".join(doc.read_text() for doc in docs if doc.is_file())
    return sorted(set(re.findall(r"tools/(\w+)\.py", text)))


def run(args: list[str], cwd: Path, timeout: int = 300) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(REPO), os.environ.get("PYTHONPATH", "")])}
    return subprocess.run([sys.executable, *args], cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)


def _needs(*paths: Path) -> str | None:
    missing = [str(p) for p in paths if not p.exists()]
    return f"needs {', '.join(missing)} (not on this machine)" if missing else None


def _highway_lanes(tmp: Path) -> list[str]:
    """A lanes table of the test video's first frames, as ``detect --lanes`` writes it."""
    out = run(["-m", "vehicle_detection.cli", "detect", str(REPO / "test_video.mp4"), "--lanes", "--lanes-csv", str(tmp / "L.csv"),
               "--boxes", str(tmp / "B.csv"), "--no-video", "--no-progress", "--frames", "0-4"], tmp)
    assert out.returncode == 0, out.stderr[-2000:]
    return ["tools/highway_lanes.py", str(tmp / "L.csv"), "--boxes", str(tmp / "B.csv")]


def _compare_road_estimate(tmp: Path) -> list[str]:
    """The chessboard calibration and the test video alone (the clips' folder left out)."""
    (tmp / "data").mkdir()
    for folder in ("camera_cal", "lanes"):
        (tmp / "data" / folder).symlink_to(SHARED / folder, target_is_directory=True)
    return ["tools/compare_road_estimate.py", "--data", str(tmp / "data")]


#: tool -> (the arguments of its tiny run, or a function of the run's folder giving them; what its
#: output must show; why it is skipped, None where it runs)
TINY = {
    "box_jitter": (["tools/box_jitter.py", str(REPO / "test_video.mp4"), "--frames", "12", "--rounds", "1"], r"test_video", None),
    "camera_transfer": (["tools/camera_transfer.py", "--variant", "default="], r"trained on",
                        _needs(NEGATIVES / "ProjectTune", NEGATIVES / "HighwayTune", SHARED / "vehicles.zip")),
    "compare_road_estimate": (_compare_road_estimate, r"(?s)calibrated: Camera.*== test_video\.mp4.*distances of tracked cars within", _needs(SHARED / "camera_cal", SHARED / "lanes")),
    "highway_lanes": (_highway_lanes, r"a lane drawn in \d+ of 5 frames", None),
    "horizon_sources": (["tools/horizon_sources.py", "--margins", "2"], r"test video +(none|\d\.\d{3})", _needs(CLIP_A)),
    "leave_one_camera_out": (["tools/leave_one_camera_out.py", "--classifier", "svm", "--cameras", "--pool", "--work", "."],
                             r"\| split \| camera \|", None),
    "model_variants": (["tools/model_variants.py", "embedded", "--group", "images", str(REPO / "dev_set" / "test_images.json")],
                       r"embedded +images +F1 ", None),
    "other_cameras": (["tools/other_cameras.py", ".", "--only", "tilted_down_960x540"], r"tilted_down_960x540", _needs(CLIP_A)),
    "plan_cost": (["tools/plan_cost.py", "--scales", "--rounds", "1", "--frames", "2"], r"\d", _needs(CLIP_A)),
    "pyramid_f1": (None, None, "no run of seconds: it runs the detector over every tune frame of both dev cameras (over 5 minutes here)"),
    "pyramid_margins": (["tools/pyramid_margins.py", str(REPO / "test_images" / "test1.jpg")], r"\d\.\d", None),
    "refine_transfer": (["tools/refine_transfer.py", "--alpha", "1e4"], r"alpha 10000: fitted on the project", _needs(CLIP_A)),
    "refine_windows": (None, None, "no run of seconds: its smallest run fits and scores four models on the dev set (minutes)"),
    "regenerate": (["tools/regenerate.py", "01", "--max-frames", "2", "--output-dir", "out", "--timeout", "300"],
                   r"01_data\.ipynb: [\d.]+ s", _needs(SHARED / "vehicles.zip")),
    "report_screenshot": (["tools/report_screenshot.py", "--out", "shot.png"], r"", None if shutil.which("chromium") or shutil.which(
        "chromium-browser") else "needs Chromium (headless) on the PATH (not on this machine)"),
    "self_training": (["tools/self_training.py", "--rounds", "40"], r"round 1",
                      _needs(NEGATIVES / "ProjectTune", SHARED / "videos" / "highway_dashcam_854x480.mp4")),
    "sweep_features": (["tools/sweep_features.py", "--data-dir", str(SHARED), "--subsample", "300", "--jobs", "1"], r"\d\.\d",
                       _needs(SHARED / "vehicles.zip", SHARED / "non-vehicles.zip")),
    "window_border": (["tools/window_border.py", "--rounds", "1"], r"frame", None),
}


def test_every_cited_tool_has_a_tiny_run():
    names = cited()
    assert len(names) >= 10, names  # the citations are found
    assert not set(names) - set(TINY), f"cited tools without a tiny run here: {sorted(set(names) - set(TINY))}"
    assert all((TOOLS / f"{name}.py").is_file() for name in TINY)


#: ``python tools/NAME.py --help`` for each path given, each in a process of its own forked from
#: this one once it has imported what nearly every tool imports first (0.2 s to 1 s a tool less):
#: NAME -> [exit code, stdout, stderr].
HELP_RUNNER = """
import io, json, os, runpy, sys, traceback
import cv2, numpy, vehicle_detection, vehicle_detection.detector
results = {}
for path in sys.argv[1:]:
    read, write = os.pipe()
    if os.fork() == 0:  # the tool's process: python tools/NAME.py --help
        sys.argv, sys.path[0] = [path, "--help"], os.path.dirname(path)
        sys.stdout, sys.stderr = io.StringIO(), io.StringIO()
        try:
            runpy.run_path(path, run_name="__main__")
            code = 0
        except SystemExit as e:
            code = e.code if isinstance(e.code, int) else int(e.code is not None)
        except BaseException:
            traceback.print_exc()
            code = 1
        os.write(write, json.dumps([code, sys.stdout.getvalue(), sys.stderr.getvalue()]).encode())
        os._exit(0)
    os.close(write)
    with os.fdopen(read, "rb") as f:
        results[os.path.basename(path)[:-3]] = json.loads(f.read() or b"[-1, '', 'no result']")
    os.wait()
print(json.dumps(results))
"""


@pytest.fixture(scope="module")
def helps(tmp_path_factory) -> dict:
    out = run(["-c", HELP_RUNNER, *(str(TOOLS / f"{name}.py") for name in sorted(TINY))], tmp_path_factory.mktemp("help"))
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout)


@pytest.mark.xdist_group(name="tools-help")  # one worker makes the runs
@pytest.mark.parametrize("name", sorted(TINY))
def test_help(name, helps):
    code, stdout, stderr = helps[name]
    assert code == 0, stderr[-2000:]
    assert stdout.startswith("usage:") and f"{name}.py" in stdout.splitlines()[0], stdout[:500]


@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(TINY))
def test_tiny_run(name, tmp_path):
    args, expected, skip = TINY[name]
    if skip:
        pytest.skip(f"{name}: {skip}")
    args = args(tmp_path) if callable(args) else args
    out = run([str(REPO / args[0]), *args[1:]], tmp_path)
    assert out.returncode == 0, f"{name}: exit {out.returncode}\n{out.stdout[-1500:]}\n{out.stderr[-2500:]}"
    assert re.search(expected, out.stdout), f"{name}: {expected!r} not in\n{out.stdout[-2000:]}"


def test_a_failing_tool_fails_here(tmp_path):
    """The runner sees a tool's failure: a tool given a file that is not there exits non-zero."""
    out = run([str(TOOLS / "highway_lanes.py"), str(tmp_path / "no_such.csv")], tmp_path)
    assert out.returncode != 0
    assert not re.search(TINY["model_variants"][1], "embedded images nothing")
