"""A progress bar on the terminal (or in a notebook), and nothing elsewhere; counted words for what is printed."""

from __future__ import annotations

import sys
from collections.abc import Iterator
from contextlib import contextmanager

__all__ = ["progress_bar", "in_notebook", "plural"]


def in_notebook() -> bool:
    """True inside a Jupyter kernel, where ``tqdm.auto`` draws a widget (stderr is no terminal there)."""
    shell = sys.modules.get("IPython")
    try:
        return shell is not None and type(shell.get_ipython()).__name__ == "ZMQInteractiveShell"
    except Exception:
        return False


@contextmanager
def progress_bar(total: int | None, desc: str, *, enabled: bool = True) -> Iterator:
    """A ``tqdm`` bar of ``total`` frames on stderr when ``enabled`` and stderr is a terminal (or in
    a notebook), else None; the bar is removed at the end of the block."""
    if not (enabled and (sys.stderr.isatty() or in_notebook())):
        yield None
        return
    from tqdm.auto import tqdm  # only when a bar is drawn (it looks for Jupyter's widgets)

    with tqdm(total=total, unit="frame", desc=desc, leave=False) as bar:
        yield bar


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
