"""``vehicle-detection download``: the training archives into a data folder."""

from __future__ import annotations

from ..training.data import default_data_dir
from ..training.download import download_archives

__all__ = ["run"]


def run(args) -> int:
    paths = download_archives(default_data_dir(args.data_dir), progress=not args.no_progress)
    for name, path in paths.items():
        print(f"{name}: {path}")
    return 0
