"""Optional dependencies, imported only when a feature that needs them is used.

The command-line install (``pip install vehicle-detection``) has no plotting library: matplotlib
comes with the ``report`` extra (the HTML report) and the ``notebooks`` extra (the figures),
scikit-image with the ``notebooks`` extra (HOG pictures only). :func:`require` imports such a
module, or raises :class:`~vehicle_detection.errors.MissingDependencyError` naming the extra.
"""

from __future__ import annotations

import importlib
from types import ModuleType

from .errors import MissingDependencyError

__all__ = ["require"]


def require(module: str, extra: str, feature: str) -> ModuleType:
    """Import ``module``, or say which extra installs it.

    Parameters
    ----------
    module : str
        Module to import (``"matplotlib.figure"``).
    extra : str
        The extra of ``vehicle-detection`` that installs it (``"report"``).
    feature : str
        What needs it, for the message (``"the HTML report"``).

    Returns
    -------
    module

    Raises
    ------
    MissingDependencyError
        If the module (or one it needs) cannot be imported; also an ``ImportError``.

    Examples
    --------
    >>> require("json", "report", "this example").__name__
    'json'
    """
    try:
        return importlib.import_module(module)
    except ImportError as exc:
        package = (exc.name or module).split(".")[0]
        raise MissingDependencyError(
            f"{feature} needs {package}, which is not installed: pip install \"vehicle-detection[{extra}]\""
        ) from None
