"""The public API: ``import vehicle_detection as vd`` is light, and every ``vd.`` name is what its module defines."""

from __future__ import annotations

import importlib
import pkgutil
import subprocess
import sys
from pathlib import Path

import pytest

import vehicle_detection as vd


def test_import_is_lazy():
    code = (
        "import sys, vehicle_detection as vd\n"
        "heavy = [m for m in ('numba', 'cv2', 'scipy', 'sklearn', 'av', 'PIL') if m in sys.modules]\n"
        "print(heavy)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    assert out.stdout.strip() == "[]"


PACKAGES = ["vehicle_detection", *sorted(m.name for m in pkgutil.walk_packages(vd.__path__, "vehicle_detection.") if m.ispkg)]


@pytest.mark.parametrize("package", PACKAGES)
def test_no_public_name_is_a_module_name(package):
    """A name equal to a module's would be rebound to the module when the package imports it."""
    pkg = importlib.import_module(package)
    modules = {m.name for m in pkgutil.iter_modules(pkg.__path__)}
    clashes = set(getattr(pkg, "__all__", ())) & modules
    for name in clashes:
        value, module = getattr(pkg, name), importlib.import_module(f"{package}.{name}")
        if value is module:
            continue  # the module itself is the name (vd.io, vd.viz.plots)
        # cli's main(): its __init__ imports cli.main first, then binds the name, so it stays the function
        assert value.__module__ == module.__name__ and not Path(pkg.__file__).with_suffix(".pyi").exists(), (package, name)
        assert getattr(importlib.import_module(package), name) is value


def test_every_name_is_its_modules_object_even_after_every_module_is_imported():
    for m in pkgutil.walk_packages(vd.__path__, "vehicle_detection."):
        if not m.name.endswith("__main__"):
            importlib.import_module(m.name)
    for package in PACKAGES:
        pkg = importlib.import_module(package)
        for name in getattr(pkg, "__all__", ()):
            if name == "__version__":
                continue
            value = getattr(pkg, name)
            module = getattr(value, "__module__", None) if not isinstance(value, type(vd)) else value.__name__
            assert module is None or module.startswith("vehicle_detection"), (package, name, module)
            if isinstance(value, type(vd)):
                assert value is importlib.import_module(f"{package}.{name}")
            assert name in dir(pkg), (package, name)


def test_unknown_name_is_an_attribute_error():
    try:
        vd.no_such_name  # noqa: B018
    except AttributeError as e:
        assert "no_such_name" in str(e)
    else:
        raise AssertionError("vd.no_such_name did not raise")
