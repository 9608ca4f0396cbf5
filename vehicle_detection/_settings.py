"""Plain-JSON round trips of the small frozen settings saved in model files (``SideFit``,
``ShotCuts``, ``Exposure``): one field, one key; pairs become lists."""

from __future__ import annotations

import dataclasses
from typing import Any


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
