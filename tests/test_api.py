"""The public API: ``import vehicle_detection as vd`` is light, and every ``vd.`` name is what its module defines."""

from __future__ import annotations

import importlib
import pkgutil
import subprocess
import sys

import vehicle_detection as vd


def test_import_is_lazy():
    code = (
        "import sys, vehicle_detection as vd\n"
        "heavy = [m for m in ('numba', 'cv2', 'scipy', 'sklearn', 'av', 'PIL') if m in sys.modules]\n"
        "print(heavy)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, check=True)
    assert out.stdout.strip() == "[]"


def test_no_public_name_is_a_module_name():
    modules = {m.name for m in pkgutil.iter_modules(vd.__path__)}
    assert not modules & set(vd._API)


def test_every_name_is_its_modules_object_even_after_every_module_is_imported():
    for m in pkgutil.iter_modules(vd.__path__):
        if m.name not in ("__main__", "cli"):
            importlib.import_module(f"vehicle_detection.{m.name}")
    for name, module in vd._API.items():
        assert getattr(vd, name) is getattr(importlib.import_module(f"vehicle_detection.{module}"), name), name
    assert set(vd._API) <= set(dir(vd))


def test_unknown_name_is_an_attribute_error():
    try:
        vd.no_such_name  # noqa: B018
    except AttributeError as e:
        assert "no_such_name" in str(e)
    else:
        raise AssertionError("vd.no_such_name did not raise")
