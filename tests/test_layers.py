"""The package's layers, read from the source (the imports of every module, nothing executed).

Layers, lowest first; a module may import only from its own layer or lower ones:

0. **base**: the top-level ``errors``, ``geometry``, ``detections``, ``deprecation`` and
   ``_settings`` (the small settings' JSON round trip), and the package's own ``__init__`` (it
   defines ``__version__`` and hands every other name on lazily);
1. **io** (``vehicle_detection.io``) and **footage** (``vehicle_detection.footage``: the
   footage's horizon, exposure, cuts between shots, bars and overlays): side by side;
2. **core**: every other top-level module: the five stages (features, classifier, search,
   heatmap, tracker), and the config and detector that put them together;
3. **road**, **metrics**, **training**, **viz**: side by side;
4. **pipeline**;
5. **cli**.

A module's layer comes from the subpackage it lives in (top-level modules: base for those
named above, else core). The rules:

* no import cycle among the imports that run (``if TYPE_CHECKING:`` imports left out);
* no import from a higher layer (type-checking imports included);
* private names stay in their package: ``_name`` (a function, or a module ``_name.py``) is
  imported only by modules of the folder that holds it, or of a folder inside it (the top-level
  ``_settings`` serves ``footage/``; ``io/_files`` serves ``io/`` alone). A package hands on what
  others may use through its stub (``io/__init__.pyi``), so ``from ..io import atomic_output`` is fine.

Every import statement counts, at module level or inside a function; ``from pkg import name`` is
an edge to the module the package's stub says ``name`` comes from.
"""

from __future__ import annotations

import ast
import functools
import graphlib
import importlib
import sys
import tomllib
import warnings
from pathlib import Path

import pytest

import vehicle_detection as vd
from vehicle_detection import deprecation

PACKAGE = Path(vd.__file__).resolve().parent
NAME = "vehicle_detection"
BASE = {"errors", "geometry", "detections", "deprecation", "_settings", "__init__"}
LAYERS = {"base": 0, "io": 1, "footage": 1, "core": 2, "road": 3, "metrics": 3, "training": 3, "viz": 3, "pipeline": 4, "cli": 5}


def _module_name(path: Path) -> str:
    parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def _modules() -> dict[str, Path]:
    return {_module_name(p): p for p in sorted(PACKAGE.rglob("*.py"))}


MODULES = _modules()


def layer(module: str) -> str:
    parts = module.split(".")[1:]
    if not parts:
        return "base"  # the package's __init__
    if len(parts) == 1 and (PACKAGE / f"{parts[0]}.py").is_file():
        return "base" if parts[0] in BASE else "core"
    return parts[0]


def _is_package(module: str) -> bool:
    return MODULES.get(module, Path()).name == "__init__.py"


@functools.cache
def _stub_names(package: str) -> dict[str, str]:
    """name -> absolute module, from the package's ``__init__.pyi`` (empty without one)."""
    path = MODULES[package].with_suffix(".pyi")
    if not path.is_file():
        return {}
    out = {}
    for node in ast.parse(path.read_text()).body:
        if isinstance(node, ast.ImportFrom):
            base = f"{package}.{node.module}" if node.module else package
            for alias in node.names:
                out[alias.name] = f"{base}.{alias.name}" if f"{base}.{alias.name}" in MODULES else base
    return out


def _absolute(module: str, node: ast.ImportFrom) -> str:
    package = module if _is_package(module) else module.rpartition(".")[0]
    parts = package.split(".")
    if node.level > 1:
        parts = parts[: len(parts) - node.level + 1]
    return ".".join(parts + ([node.module] if node.module else []))


_BLOCKS = ("body", "orelse", "finalbody", "handlers", "cases")  # the fields that hold statements


def _import_statements(tree: ast.Module) -> list[tuple[ast.Import | ast.ImportFrom, bool]]:
    """Every import statement, at module level or nested in any block, with whether it runs
    (``False`` inside an ``if TYPE_CHECKING:`` body). Only statements are visited: imports are
    never inside expressions, and walking every expression node costs seconds over the package."""
    out, todo = [], [(stmt, True) for stmt in tree.body]
    while todo:
        node, runtime = todo.pop()
        if isinstance(node, (ast.Import, ast.ImportFrom)):
            out.append((node, runtime))
            continue
        typing_body = isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test)
        for field in _BLOCKS:
            for child in getattr(node, field, ()):
                todo.append((child, runtime and not (typing_body and field == "body")))
    return out


def imports(module: str) -> list[tuple[str, str | None, bool, bool]]:
    """``(target module, name taken or None, at run time, through a package's stub)`` of every
    import of the package in ``module``."""
    tree = ast.parse(MODULES[module].read_text())
    out = []
    for node, runtime in _import_statements(tree):
        if isinstance(node, ast.Import):
            out += [(a.name, None, runtime, False) for a in node.names if a.name.split(".")[0] == NAME]
        elif isinstance(node, ast.ImportFrom):
            target = _absolute(module, node) if node.level else node.module or ""
            if target.split(".")[0] != NAME:
                continue
            stub = _stub_names(target) if _is_package(target) else {}
            for alias in node.names:
                sub = f"{target}.{alias.name}"
                if sub in MODULES:
                    out.append((sub, None, runtime, False))
                else:
                    out.append((stub.get(alias.name, target), alias.name, runtime, alias.name in stub))
    return out


@functools.cache
def edges() -> dict[str, list[tuple[str, str | None, bool, bool]]]:
    """The imports of every module (parsed once, by the first test that asks: not at collection)."""
    return {m: imports(m) for m in MODULES}


def test_the_package_imports_no_old_module_path():
    """The old paths are for users' scripts, for one release; the package itself uses the new ones."""
    stale = sorted({(m, target) for m, edges in edges().items() for target, *_ in edges if target in deprecation.MOVED_MODULES})
    assert not stale, stale


def test_the_layers_are_those_of_the_issue():
    assert {layer(m) for m in MODULES} == set(LAYERS)
    for core in ("features", "classifier", "search", "heatmap", "tracker", "config", "detector"):
        assert layer(f"{NAME}.{core}") == "core", core
    for footage in ("horizon", "exposure", "shots", "overlays"):
        assert layer(f"{NAME}.footage.{footage}") == "footage", footage


def test_the_top_level_holds_the_stages_and_the_base_alone():
    """What reads the footage (rather than being a stage or the base) lives in footage/."""
    top = {m.rpartition(".")[2] for m in MODULES if m.count(".") == 1 and not _is_package(m)}
    stages = {"features", "classifier", "search", "heatmap", "tracker"}
    beside = {"config", "detector", "refine", "convnet", "warmup", "_jit"}  # put the stages together, or serve them
    assert top == (BASE - {"__init__"}) | stages | beside, sorted(top)


def _cycle(graph: dict[str, set[str]]) -> list[str] | None:
    try:
        tuple(graphlib.TopologicalSorter(graph).static_order())
    except graphlib.CycleError as exc:
        return exc.args[1]
    return None


@pytest.mark.parametrize("typing_too", [False, True], ids=["at-run-time", "type-checking-imports-too"])
def test_no_import_cycle(typing_too):
    """Not even through ``if TYPE_CHECKING:`` imports: a type the search takes from the classifier,
    whose config takes the search's plan, is a circle for every reader (the search names what it
    reads of a model in a protocol, ``search.WindowScorer``)."""
    graph = {m: {t for t, _, runtime, _ in edges()[m] if (runtime or typing_too) and t != m and t in MODULES} for m in MODULES}
    cycle = _cycle(graph)
    assert cycle is None, f"import cycle: {' -> '.join(cycle)}"
    assert _cycle({**graph, f"{NAME}.search": graph[f"{NAME}.search"] | {f"{NAME}.classifier"}})  # the old circle is seen


def test_no_import_from_a_higher_layer():
    upward = [
        f"{m} ({layer(m)}) imports {t} ({layer(t)})"
        for m in MODULES
        for t, _, _, _ in edges()[m]
        if t in MODULES and LAYERS[layer(t)] > LAYERS[layer(m)]
    ]
    assert not upward, "\n".join(upward)


def _folder(module: str) -> str:
    return module if _is_package(module) else module.rpartition(".")[0]


def _inside(module: str, folder: str) -> bool:
    """``module`` lives in ``folder`` or in a folder inside it."""
    return _folder(module) == folder or _folder(module).startswith(folder + ".")


def test_private_names_stay_in_their_package():
    leaks = []
    for m in MODULES:
        for target, name, _, via_stub in edges()[m]:
            if via_stub:
                continue  # a name the package hands on in its stub: public, wherever it is defined
            leaf = target.rpartition(".")[2]
            if leaf.startswith("_") and not leaf.startswith("__") and not _inside(m, _folder(target)):
                leaks.append(f"{m} imports the private module {target}")
            if name and name.startswith("_") and not name.startswith("__") and not _inside(m, _folder(target)):
                leaks.append(f"{m} imports the private name {target}.{name}")
    assert not leaks, "\n".join(leaks)


def test_the_rules_can_fail():
    """The readers above see what they must: an edge inside a function, through a stub, upward."""
    assert (f"{NAME}.io._files", "atomic_output", True, True) in edges()[f"{NAME}.classifier"]  # through io's stub
    assert layer(f"{NAME}.pipeline.inputs") == "pipeline" and layer(f"{NAME}.io._files") == "io"
    cli = {t for t, _, _, _ in edges()[f"{NAME}.cli.detect"]}
    assert f"{NAME}.pipeline.batch" in cli and LAYERS[layer(f"{NAME}.cli.detect")] > LAYERS["pipeline"]
    assert _inside(f"{NAME}.footage.shots", NAME) and not _inside(NAME + ".classifier", f"{NAME}.io")  # private: downward only
    assert (f"{NAME}._settings", "JsonSettings", True, False) in edges()[f"{NAME}.footage.shots"]
    assert layer(f"{NAME}.footage.shots") == "footage" and LAYERS["footage"] < LAYERS["core"]
    tree = ast.parse("def f():\n    from ..viz import drawing\n")
    node = tree.body[0].body[0]
    assert _absolute(f"{NAME}.metrics.reporting", node) == f"{NAME}.viz"


# --- the faces: the package's and each subpackage's names --------------------------------------------


SUBPACKAGES = sorted(m for m in MODULES if _is_package(m) and m != NAME)


@pytest.mark.parametrize("package", [NAME, *SUBPACKAGES])
def test_every_stub_name_is_its_modules_object(package):
    pkg = importlib.import_module(package)
    names = _stub_names(package)
    if package != f"{NAME}.cli":
        assert names, f"{package}: no __init__.pyi"
        assert set(pkg.__all__) >= set(names)
    for name, module in names.items():
        value = importlib.import_module(module) if f"{module}" == f"{package}.{name}" else getattr(importlib.import_module(module), name)
        assert getattr(pkg, name) is value, f"{package}.{name}"


def test_the_top_level_keeps_every_name_of_the_flat_api():
    flat = {
        "Detections", "box_iou", "match_boxes", "Detector", "DetectorConfig", "FeatureConfig", "extract_features",
        "SearchPlan", "SearchScale", "estimate_horizon", "vanishing_row", "active_area", "static_mask", "find_overlays",
        "Tracker", "TrackerConfig", "process_video", "detect_many", "InputResult", "MoviepyAdapter", "Camera", "calibrate",
        "BirdsEye", "birds_eye_from_straight", "lane_binary", "find_lane_pixels", "fit_lanes", "Lane", "LaneTracker",
        "DistanceTracker", "draw_lane", "VehicleClassifier", "load_model", "load_default_model", "train", "sweep",
        "sweep_configs", "split_indices", "load_dataset", "find_duplicates", "MiningSource", "mine_negatives",
        "write_negatives", "read_image", "write_image", "list_images", "read_frames", "probe_video", "VideoWriter",
        "read_boxes_csv", "write_boxes_csv", "write_mot", "write_coco", "write_parquet", "read_parquet", "write_lanes_csv",
        "draw_boxes", "draw_detections", "Annotations", "FrameLabels", "load_annotations", "evaluate_detections",
        "evaluation_report", "average_precision", "match_frame", "tracking_scores",
    }  # fmt: skip
    assert flat <= set(vd.__all__) and flat <= set(dir(vd))
    assert "__version__" in vd.__all__


def test_subpackage_faces_import_nothing_but_the_lazy_loader():
    for package in SUBPACKAGES:
        if package == f"{NAME}.cli":
            continue  # the command line's face is its main (a script needs it at once)
        tree = ast.parse(MODULES[package].read_text())
        modules = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
        modules |= {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
        assert modules <= {"lazy_loader", "__future__"}, (package, modules)


def test_the_console_script_is_the_cli_main():
    """The console script runs ``main`` and exits with its code (``run``), as ``python -m`` does."""
    scripts = tomllib.loads((PACKAGE.parent / "pyproject.toml").read_text())["project"]["scripts"]
    module, _, func = scripts["vehicle-detection"].partition(":")
    assert module == f"{NAME}.cli.main"
    assert getattr(importlib.import_module(module), func) is vd.cli.run
    assert "run()" in (PACKAGE / "cli" / "__main__.py").read_text()


# --- the old paths, for one release ------------------------------------------------------------------


@pytest.mark.parametrize("old", sorted(deprecation.MOVED_MODULES))
def test_an_old_module_path_imports_with_a_warning(old):
    sys.modules.pop(old, None)
    with pytest.warns(DeprecationWarning, match=deprecation.MOVED_MODULES[old].replace(".", r"\.")):
        module = importlib.import_module(old)
    new = importlib.import_module(deprecation.MOVED_MODULES[old])
    for name in new.__all__:
        assert getattr(module, name) is getattr(new, name), f"{old}.{name}"
    sys.modules.pop(old, None)


@pytest.mark.parametrize("old,name", sorted((m, n) for m, names in deprecation.MOVED_NAMES.items() for n in names))
def test_a_moved_name_is_still_there_with_a_warning(old, name):
    new = importlib.import_module(deprecation.MOVED_NAMES[old][name])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)  # importing an old module path warns too
        module = importlib.import_module(old)
    if old in deprecation.MOVED_MODULES:  # a stand-in: hands the name on quietly (its import warned)
        assert getattr(module, name) is getattr(new, name)
    else:
        with pytest.warns(DeprecationWarning, match=f"{old}.{name}"):
            assert getattr(module, name) is getattr(new, name)
    with pytest.raises(AttributeError):
        getattr(module, "no_such_name")


def test_the_warning_points_at_the_import():
    sys.modules.pop(f"{NAME}.batch", None)
    with pytest.warns(DeprecationWarning) as record:
        import vehicle_detection.batch  # noqa: F401
    assert record[0].filename == __file__
    sys.modules.pop(f"{NAME}.batch", None)
