"""Small helpers for the words the package prints (errors, summaries, figure titles)."""

from __future__ import annotations

__all__ = ["plural"]


def plural(n: int, word: str, many: str | None = None) -> str:
    """``n`` and ``word``, in the plural unless ``n`` is 1: ``plural(2, "box", "boxes")`` is ``"2 boxes"``.

    Parameters
    ----------
    n : int
    word : str
        The singular.
    many : str, optional
        The plural, where it is not ``word + "s"``.
    """
    return f"{n} {word}" if n == 1 else f"{n} {many or word + 's'}"
