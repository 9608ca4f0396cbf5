"""The small frozen settings saved in model files (``SideFit``, ``ShotCuts``, ``Exposure``):
their plain-JSON round trip (one field, one key; pairs become lists) and their range checks."""

from __future__ import annotations

import dataclasses
import math
from typing import Any


def number_in(owner: object, name: str, low: float, high: float = math.inf, *, low_in: bool = False, high_in: bool = False) -> float:
    """``owner.name`` as a float, checked to be a finite number in the interval from ``low`` to
    ``high`` (each end included when ``low_in`` / ``high_in``).

    Raises
    ------
    ValueError
        Naming the class, the field and the interval.
    """
    v = getattr(owner, name)
    ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
    if not (ok and (low <= v if low_in else low < v) and (v <= high if high_in else v < high)):
        interval = f"{'[' if low_in else '('}{low:g}, {high:g}{']' if high_in else ')'}"
        raise ValueError(f"{type(owner).__name__}.{name} must be a number in {interval}; got {v!r}")
    return float(v)


class JsonSettings:
    """Mix into a frozen dataclass whose fields are numbers or tuples of numbers."""

    def to_dict(self) -> dict:
        """Plain JSON data."""
        return {f.name: list(v) if isinstance(v := getattr(self, f.name), tuple) else v for f in dataclasses.fields(self)}

    @classmethod
    def from_dict(cls, d: Any):
        """The inverse of :meth:`to_dict`.

        Raises
        ------
        ValueError
            If a key is missing or unknown, or a value is out of range.
        """
        keys = {f.name for f in dataclasses.fields(cls)}
        if not isinstance(d, dict) or set(d) != keys:
            raise ValueError(f"expected an object with exactly the keys {sorted(keys)}")
        return cls(**d)
