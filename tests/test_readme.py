"""The README's ```bash blocks, replayed in order in a fresh copy of the repository; its ```python
blocks, run as pasted, in order, in one fresh Python process.

A copy of the tracked files (``git ls-files``) stands in for a fresh clone, with the shared data
reachable as ``../shared/data`` (as beside the checkout). Every command runs as written, in
order, with ``vehicle-detection`` running the copy's package; a command that fails fails the
test. The commands that cannot run here are skipped, each for a stated reason (installs, the
test suite itself, servers, minutes of training); everything else runs, so a new block runs too.
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
SHARED = REPO.parent / "shared"

#: (pattern at the start of a command, reason it is not run here). Checked in order.
SKIPPED = [
    (r"(python -m )?pip install\b", "an install: it would change the environment running the tests (the copy's package runs in place)"),
    (r"python -m pytest\b", "the test suite itself"),
    (r"dask (scheduler|worker)\b", "a dask cluster's long-running servers (tests/test_batch.py runs the batch on a LocalCluster)"),
    (r"vehicle-detection detect \S+ .*--scheduler tcp://HOST", "needs the cluster above"),
    (r"git show ", "rebuilding the embedded model: needs the git history, then minutes of mining and training "
                   "(tests/test_mining.py and tests/test_cli.py run both on small inputs)"),
    (r"vehicle-detection \S+ .*\bmy_(tune|heldout|camera)\b", "your own camera's footage and labelled frames (\"Your own camera\")"),
    (r"vehicle-detection (mine-negatives|train)\b", "rebuilding the embedded model: minutes of mining and training"),
    (r"jupyter lab\b", "an interactive server"),
    (r"python tools/regenerate\.py", "re-runs the notebooks, minutes (tests/test_notebooks.py executes them)"),
]
#: An install before ``&&``: the copy's package is used in place (PYTHONPATH), so only the rest runs.
INSTALL = re.compile(r"^python -m pip install [^&]*&&\s*")
#: Seconds a command may take (the slowest here, a batch with --jobs 2, takes well under a minute).
TIMEOUT = 600


#: Runs the ```python blocks given as a JSON list on standard input, in order, in one namespace, as
#: pasted into one interpreter; on an exception, prints the traceback and the block's number, exits 1.
PYTHON_RUNNER = """
import json, sys, traceback
namespace = {"__name__": "__main__"}
for number, code in enumerate(json.load(sys.stdin), 1):
    try:
        exec(compile(code, f"<README python block {number}>", "exec"), namespace)
    except BaseException:
        traceback.print_exc()
        sys.stderr.write(f"README python block {number} failed\\n")
        sys.exit(1)
print(f"{number} blocks ran")
"""


def python_blocks(text: str) -> list[str]:
    """The code of each ```python block, in order, as written."""
    return re.findall(r"^```python\n(.*?)^```", text, flags=re.S | re.M)


def run_python_blocks(blocks: list[str], cwd: Path, env: dict | None = None) -> subprocess.CompletedProcess:
    """The blocks, run as pasted into one fresh interpreter started in ``cwd``."""
    return subprocess.run([sys.executable, "-c", PYTHON_RUNNER], input=json.dumps(blocks), cwd=cwd, env=env,
                          capture_output=True, text=True, timeout=TIMEOUT)


def bash_blocks(text: str) -> list[list[str]]:
    """The commands of each ```bash block, in order (blank and comment lines left out)."""
    blocks = re.findall(r"^```bash\n(.*?)^```", text, flags=re.S | re.M)
    return [[line.strip() for line in b.splitlines() if line.strip() and not line.strip().startswith("#")] for b in blocks]


def plan(commands: list[str]) -> list[tuple[str, str | None]]:
    """Each command as it runs here, or with the reason it does not."""
    out = []
    for command in commands:
        command = INSTALL.sub("", command)
        reason = next((why for pattern, why in SKIPPED if re.match(pattern, command)), None)
        out.append((command, reason))
    return out


def test_the_readme_blocks_are_found_and_their_skips_are_few():
    blocks = bash_blocks((REPO / "README.md").read_text())
    planned = plan([c for b in blocks for c in b])
    run = [c for c, why in planned if why is None]
    assert len(blocks) >= 5 and len(run) >= 5, planned
    assert run[0] == "vehicle-detection detect test_video.mp4"  # the main job, after the install
    assert all("pip install" not in c for c in run), run  # never an install on the environment running the tests
    assert any("pip install" in c and why for c, why in planned)  # an install command is there, skipped


@pytest.fixture(scope="module")
def clone(tmp_path_factory) -> Path:
    """One fresh copy for the module: the bash and the python blocks run in it, as a user who
    clones once and follows the README would (each block's outputs are named apart). A fresh
    copy's first run compiles the kernels into a cache folder of its own (seconds): once, not once
    a test. Its tests share one xdist group, so one worker makes it."""
    tmp_path = tmp_path_factory.mktemp("readme")
    if shutil.which("git") is None or not (REPO / ".git").exists():
        pytest.skip("not a git checkout: the tracked files are unknown")
    if not (SHARED / "data").is_dir():
        pytest.skip(f"{SHARED / 'data'} not found: the README's commands read ../shared/data")
    files = subprocess.run(["git", "ls-files", "-z"], cwd=REPO, capture_output=True, check=True).stdout.decode().split("\0")
    root = tmp_path / "clone"
    for name in filter(None, files):
        src = REPO / name
        if src.is_file():
            (root / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(src, root / name)
    (tmp_path / "shared").symlink_to(SHARED, target_is_directory=True)
    return root


def copy_cache_home(clone: Path) -> dict[str, str]:
    """The copy's per-user cache folder (its compiled kernels) inside the test's temporary folder:
    the kernels are cached per package location, so each run's fresh copy would otherwise leave a
    folder of its own in ``~/.cache/vehicle-detection`` (a megabyte a run)."""
    env = {"XDG_CACHE_HOME": str(clone.parent / "cache")}
    if "NUMBA_CACHE_DIR" in os.environ:  # the user's own setting would win over XDG_CACHE_HOME
        env["NUMBA_CACHE_DIR"] = str(clone.parent / "cache" / "numba")
    return env


@pytest.mark.xdist_group(name="readme-clone")
def test_every_readme_bash_block_runs_as_written_in_order(clone, tmp_path):
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    shim = bin_dir / "vehicle-detection"  # the command, running the copy's package
    shim.write_text(f'#!/bin/sh\nexec "{sys.executable}" -m vehicle_detection.cli "$@"\n')
    shim.chmod(0o755)
    env = {**os.environ, "PYTHONPATH": str(clone), "PATH": f"{bin_dir}{os.pathsep}{os.environ.get('PATH', '')}"}
    env["PIP_REQUIRE_VIRTUALENV"] = "1"  # a pip install that slips through is refused, never run on this environment
    env.update(copy_cache_home(clone))
    env.pop("VEHICLE_DETECTION_DATA", None)
    ran, skipped = [], []
    for command, why in plan([c for b in bash_blocks((clone / "README.md").read_text()) for c in b]):
        if why is not None:
            skipped.append((command, why))
            continue
        proc = subprocess.run(["bash", "-c", command], cwd=clone, env=env, capture_output=True, text=True, timeout=TIMEOUT)
        assert proc.returncode == 0, f"README command failed (exit {proc.returncode}): {command}\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}"
        ran.append(command)
    # What the commands promise is there.
    assert (clone / "test_video_detected.mp4").is_file() and (clone / "test_video_boxes.csv").is_file()
    assert (clone / "camera.json").is_file() and (clone / "test_video_lanes.csv").is_file()
    assert {"test_video_boxes.csv", "test_images_detected"} <= {p.name for p in (clone / "out").iterdir()}
    assert (clone / "out" / "test1_boxes.csv").is_file() and (clone / "test_video_report.html").is_file()
    assert len(ran) >= 5, (ran, skipped)


def test_the_readme_python_blocks_are_found():
    blocks = python_blocks((REPO / "README.md").read_text())
    assert len(blocks) >= 3, blocks
    assert blocks[0].lstrip().startswith("import vehicle_detection as vd")
    text = "".join(blocks)
    for name in ("vd.Detector(", "detect_image(", ".track(", "vd.process_video(", "vd.evaluation_report("):
        assert name in text, name


@pytest.mark.xdist_group(name="readme-clone")
def test_every_readme_python_block_runs_as_pasted_in_order(clone):
    env = {**os.environ, "PYTHONPATH": str(clone), **copy_cache_home(clone)}  # the copy's package, as an install of the clone would give
    env.pop("VEHICLE_DETECTION_DATA", None)
    blocks = python_blocks((clone / "README.md").read_text())
    proc = run_python_blocks(blocks, clone, env)
    assert proc.returncode == 0, f"a README python block failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}"
    assert proc.stdout.splitlines()[-1] == f"{len(blocks)} blocks ran"
    assert (clone / "test1_boxes.jpg").is_file() and (clone / "test_video_python.csv").is_file()


def test_a_python_block_with_a_bad_name_fails(tmp_path):
    """The check can fail: a name that does not exist, or a method called on the class, stops the
    run at its block, which is named; names carry over between blocks, as when pasted."""
    # The good blocks use the package's name only: a second of imports less in each of the four runs.
    ok = ["import vehicle_detection as vd\nfound = 1", "assert found == 1\nprint(vd.__name__)"]
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    proc = run_python_blocks(ok, tmp_path, env)
    assert proc.returncode == 0 and proc.stdout.splitlines()[-1] == "2 blocks ran", proc.stderr
    for bad, error in [("vd.no_such_name", "AttributeError"), ('vd.Road.for_footage("test_video.mp4")', "TypeError"),
                       ("print(undefined)", "NameError")]:
        proc = run_python_blocks([*ok, bad, "print('never')"], tmp_path, env)
        assert proc.returncode == 1, (bad, proc.stdout, proc.stderr)
        assert "README python block 3 failed" in proc.stderr and error in proc.stderr, (bad, proc.stderr)
        assert "never" not in proc.stdout
