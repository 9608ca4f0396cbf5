"""What a new user hit, following the README (issue 21, section 4): each a run as the user made it."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
TEST_VIDEO = REPO / "test_video.mp4"
TEST_IMAGES = REPO / "test_images"

pytestmark = pytest.mark.skipif(
    not (TEST_VIDEO.is_file() and (TEST_IMAGES / "test1.jpg").is_file()), reason="test_video.mp4 or test_images/ not in the checkout"
)


def _env() -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), *filter(None, [env.get("PYTHONPATH")])])
    return env


def test_detect_many_with_jobs_in_a_plain_script_without_a_main_guard(tmp_path):
    # A script as a user writes it: no ``if __name__ == "__main__":``. Worker processes must not
    # re-run it (each input came back "worker failed: BrokenProcessPool" with multiprocessing's spawn).
    for name in ("test1.jpg", "test3.jpg"):
        shutil.copy(TEST_IMAGES / name, tmp_path / name)
    script = tmp_path / "plain.py"
    script.write_text(textwrap.dedent("""
        import vehicle_detection as vd
        print("script started")
        results = vd.detect_many(["test1.jpg", "test3.jpg"], "out", vd.InputOptions(video=False), jobs=2)
        for r in results:
            print(r.path, r.n_boxes, r.error)
    """))
    proc = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=_env(), capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.splitlines()
    assert lines.count("script started") == 1  # the workers did not run the script again
    rows = [line.split() for line in lines[1:]]
    assert [r[0] for r in rows] == ["test1.jpg", "test3.jpg"]
    assert all(r[2] == "None" and int(r[1]) >= 1 for r in rows), lines  # no error, cars found in both
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["test1_boxes.csv", "test3_boxes.csv"]
