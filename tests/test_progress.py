"""Tests of vehicle_detection.io.progress.plural: the counted words the package prints."""

from __future__ import annotations

import pytest

from vehicle_detection.io import plural


@pytest.mark.parametrize(
    "n, word, many, expected",
    [
        (0, "frame", None, "0 frames"),
        (1, "frame", None, "1 frame"),
        (2, "vehicle", None, "2 vehicles"),
        (1, "box", "boxes", "1 box"),
        (5, "box", "boxes", "5 boxes"),
        (1, "false positive", None, "1 false positive"),
    ],
)
def test_plural(n, word, many, expected):
    assert plural(n, word, many) == expected
