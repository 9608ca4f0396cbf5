"""Hypothesis strategies shared by the tests."""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st


@st.composite
def box_sets(draw, max_boxes=6, max_coord=60, max_size=40):
    """``(n, 4)`` int64 boxes with x2 > x1 and y2 > y1, up to ``max_boxes`` of them."""
    n = draw(st.integers(0, max_boxes))
    out = []
    for _ in range(n):
        x1 = draw(st.integers(0, max_coord))
        y1 = draw(st.integers(0, max_coord))
        out.append([x1, y1, x1 + draw(st.integers(1, max_size)), y1 + draw(st.integers(1, max_size))])
    return np.array(out, dtype=np.int64).reshape(-1, 4)
