"""Execute every notebook headless, top to bottom, rebuilding the figures and videos in output_images/.

    python tools/regenerate.py                    # all notebooks, in order
    python tools/regenerate.py 03 05              # only those whose name starts with 03 or 05
    python tools/regenerate.py --max-frames 40    # only the first 40 frames of the project clip

Each notebook runs in a fresh ``python3`` kernel with ``notebooks/`` as its working directory
(nbclient), a time limit per cell, and these environment variables:

* ``VEHICLE_DETECTION_DATA``: kept if set, else ``../shared/data`` beside the checkout when it
  exists, else the repository's ``data/``;
* ``VD_OUTPUT_DIR``: ``--output-dir`` if given (default: the notebooks' own default,
  ``output_images/``);
* ``VD_MAX_FRAMES``: ``--max-frames`` if given;
* ``PYTHONPATH``: this checkout first, so that the kernels import its ``vehicle_detection``
  whatever copy is installed (an editable install may point at another checkout).

The notebooks on disk are not modified (they are committed without outputs; see
``tools/make_notebooks.py``); ``--executed DIR`` saves the executed copies there. Prints each
notebook and its time; exits 1 and prints the failing cell's error if a cell fails.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
NOTEBOOK_DIR = REPO / "notebooks"


def data_dir() -> Path:
    """The data folder the notebooks will use (see module docstring)."""
    env = os.environ.get("VEHICLE_DETECTION_DATA")
    if env:
        return Path(env).resolve()
    shared = REPO.parent / "shared" / "data"
    return shared if shared.is_dir() else REPO / "data"


def run_notebook(path: Path, *, timeout: int = 1200, env: dict[str, str] | None = None, executed: Path | None = None) -> float:
    """Execute one notebook in its folder; return the seconds taken.

    Raises
    ------
    nbclient.exceptions.CellExecutionError
        If a cell raises (the message holds the cell's source and traceback).
    """
    import nbformat
    from nbclient import NotebookClient

    saved = dict(os.environ)
    os.environ.update(env or {})
    os.environ["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), os.environ.get("PYTHONPATH", "")) if p)
    try:
        nb = nbformat.read(path, as_version=4)
        client = NotebookClient(
            nb,
            timeout=timeout,
            kernel_name="python3",
            resources={"metadata": {"path": str(path.parent)}},
        )
        t = time.perf_counter()
        try:
            client.execute()
        finally:
            if executed is not None:
                executed.mkdir(parents=True, exist_ok=True)
                nbformat.write(nb, executed / path.name)
        return time.perf_counter() - t
    finally:
        os.environ.clear()
        os.environ.update(saved)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("only", nargs="*", help="run only notebooks whose name starts with one of these")
    ap.add_argument("--timeout", type=int, default=1200, help="seconds per cell (default %(default)s)")
    ap.add_argument("--max-frames", type=int, default=None, help="frames of the project clip to process (default: all)")
    ap.add_argument("--output-dir", default=None, help="where figures go (default: output_images/)")
    ap.add_argument("--executed", default=None, help="also save the executed notebooks in this folder")
    args = ap.parse_args(argv)

    from nbclient.exceptions import CellExecutionError

    notebooks = sorted(NOTEBOOK_DIR.glob("[0-9][0-9]_*.ipynb"))
    if args.only:
        notebooks = [p for p in notebooks if p.name.startswith(tuple(args.only))]
    if not notebooks:
        print(f"no notebooks to run in {NOTEBOOK_DIR}", file=sys.stderr)
        return 1
    env = {"VEHICLE_DETECTION_DATA": str(data_dir())}
    if args.output_dir:
        env["VD_OUTPUT_DIR"] = str(Path(args.output_dir).resolve())
    if args.max_frames:
        env["VD_MAX_FRAMES"] = str(args.max_frames)
    out = env.get("VD_OUTPUT_DIR", str(REPO / "output_images"))
    print(f"data: {env['VEHICLE_DETECTION_DATA']}\noutput: {out}", flush=True)
    total = time.perf_counter()
    for path in notebooks:
        print(f"running {path.name}", flush=True)
        try:
            seconds = run_notebook(path, timeout=args.timeout, env=env, executed=Path(args.executed) if args.executed else None)
        except CellExecutionError as exc:
            print(f"FAILED: {path.name}", flush=True)
            print(re.sub(r"\x1b\[[0-9;]*m", "", str(exc)), file=sys.stderr)  # without the terminal colours
            return 1
        print(f"{path.name}: {seconds:.1f} s", flush=True)
    print(f"all {len(notebooks)} notebooks in {time.perf_counter() - total:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
