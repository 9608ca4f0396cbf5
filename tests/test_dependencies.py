"""The command-line install has no matplotlib and no scikit-image; what needs one names its extra."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PLOTTING = ("matplotlib", "skimage", "fontTools")


def run(code: str) -> str:
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300, cwd=REPO)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout.strip()


@pytest.fixture(scope="module")
def one_detect(tmp_path_factory):
    """One process detects in test1.jpg, through the Python API, then through the command line
    (``main``, as ``vehicle-detection detect`` runs it): the boxes it found, the run's folder,
    and the modules it imported by then (a module imported by either is there at the end)."""
    tmp_path = tmp_path_factory.mktemp("one_detect")
    code = (
        "import json, sys\n"
        "import vehicle_detection as vd\n"
        "found = vd.Detector().detect_image('test_images/test1.jpg')\n"
        "vd.write_boxes_csv(%r, found)\n"
        "from vehicle_detection.cli import main\n"
        "code = main(['detect', 'test_images/test1.jpg', '--out', %r, '--boxes', %r])\n"
        "assert code == 0, code\n"
        "print(len(found), json.dumps(sorted(m for m in %r if m in sys.modules)))\n"
    ) % (str(tmp_path / "a.csv"), str(tmp_path / "o.jpg"), str(tmp_path / "o.csv"), (*PLOTTING, "joblib", "sklearn"))
    n, loaded = run(code).splitlines()[-1].split(" ", 1)  # after the CLI's own lines
    return int(n), tmp_path, json.loads(loaded)


#: The tests of that one run: one worker makes it.
one_detect_group = pytest.mark.xdist_group(name="dependencies-one-detect")


@one_detect_group
def test_detecting_imports_no_plotting_library(one_detect):
    n, folder, loaded = one_detect
    assert n > 0 and (folder / "o.jpg").is_file()
    assert not set(loaded) & set(PLOTTING), loaded


#: library -> (code that needs it, the message naming its extra)
MISSING = {
    "matplotlib": ("import vehicle_detection.viz.plots",
                   'the figures (vehicle_detection.viz.plots) needs matplotlib, which is not installed: pip install "vehicle-detection[notebooks]"'),
    "skimage": ("import numpy as np\nfrom vehicle_detection.features import FeatureConfig, hog_image\n"
                "hog_image(np.zeros((64, 64), np.uint8), FeatureConfig())",
                'the HOG picture (hog_image) needs skimage, which is not installed: pip install "vehicle-detection[notebooks]"'),
    "pandas": ("from vehicle_detection.detections import Detections\nDetections([[0, 0, 9, 9]]).to_pandas()",
               'Detections.to_pandas() needs pandas, which is not installed: pip install "vehicle-detection[pandas]"'),
}  # fmt: skip


@pytest.fixture(scope="module")
def missing_messages() -> dict:
    """One process with none of the three (as on the command-line install) runs each code in turn:
    the message of the MissingDependencyError each raised, by library."""
    code = (f"import json, sys\nsys.modules.update(dict.fromkeys({list(MISSING)!r}))\n"  # None: their import fails
            "from vehicle_detection.errors import MissingDependencyError\nfound = {}\n")
    for blocked, (needs_it, _) in MISSING.items():
        code += ("try:\n" + "".join(f"    {line}\n" for line in needs_it.splitlines()) +
                 f"except MissingDependencyError as e:\n    found[{blocked!r}] = str(e)\n")
    return json.loads(run(code + "print(json.dumps(found))"))


@pytest.mark.xdist_group(name="dependencies-missing")  # one worker makes the run
@pytest.mark.parametrize("blocked", list(MISSING))
def test_a_missing_optional_library_names_its_extra(blocked, missing_messages):
    assert missing_messages.get(blocked) == MISSING[blocked][1]


def test_pyproject_extras():
    tomllib = pytest.importorskip("tomllib")
    project = tomllib.loads((REPO / "pyproject.toml").read_text())["project"]

    def names(reqs):
        return {r.split(">")[0].split("=")[0].split("[")[0].split("<")[0].strip().lower() for r in reqs}

    core = names(project["dependencies"])
    extras = {k: names(v) for k, v in project["optional-dependencies"].items()}
    assert not core & {"matplotlib", "scikit-image"}
    assert {"jupyterlab", "ipykernel", "ipywidgets", "matplotlib", "scikit-image"} <= extras["notebooks"]
    assert "jupyter" not in extras["notebooks"]
    assert extras["report"] == {"matplotlib"}
    # the README's test command installs what the tests import
    assert {"matplotlib", "scikit-image", "pandas"} <= extras["test"]


@one_detect_group
def test_one_input_starts_without_the_process_pool_or_the_learning_library(one_detect):
    """What a single ``detect`` pays at start-up: no joblib (the process pool of ``--jobs``),
    no scikit-learn (training only). Checked in the run above: a module not there after the API's
    detection and the command line's is not there after the command line's alone."""
    _, _, loaded = one_detect
    assert not set(loaded) & {"joblib", "sklearn"}, loaded
