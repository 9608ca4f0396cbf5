"""The doctests of ``vehicle_detection/`` read the repository's files by relative path
(``test_images/test1.jpg``): each runs from the repository's root, whatever folder the tests
before it in the same worker left as the current one (``tests/conftest.py`` runs each test in a
temporary folder)."""

from pathlib import Path

import pytest
from _pytest.doctest import DoctestItem

ROOT = Path(__file__).resolve().parent


@pytest.fixture(autouse=True)
def _doctests_run_from_the_root(request, monkeypatch):
    if isinstance(request.node, DoctestItem):
        monkeypatch.chdir(ROOT)
