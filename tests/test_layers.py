"""The package's layers import downward only.

Every module under ``src/compact_perception`` is parsed with :mod:`ast` (imports inside functions
included, relative imports resolved) and mapped to its place in :data:`LAYERS`; an import of a
module placed higher fails, and so does an import between two parts :data:`KEPT_APART` separates.

The layers are the package's folders, in the pipeline's order (lowest first); a module may import
its own layer and those below it, and inside a layer, its own tier and those below it:

0. ``core`` -- params (``scale`` resolved there), catalog, registries, io, errors, the facts the
   report shares with evaluation: imports nothing of the project above it.
1. ``execution`` -- where a stage's jobs run (the local pool, submitit): it knows jobs, not runs,
   so it imports nothing of ``learning`` or ``evaluation`` (nor does any file of it enter a run's
   digest).
2. ``data`` -- the generate and preprocess stages and the loader:
   (a) ``data.record``, the raw record contract: the sources write it, preprocessing reads it;
   (b) the sources' own code and the sensors' maths: ``world``, ``carla``, ``nuscenes``,
   ``authors``, ``geometry``, ``dvs``, ``lidar``, the stages' figures, ``qualitative``, ``loader``;
   (c) ``sources`` (the registry) and ``preprocess`` (which looks the source up): a source never
   imports its consumer.
3. ``learning`` -- the train stage: (a) ``models``, ``weighting`` (kept apart: a network does not
   know its loss weighting, nor the weighting the network), ``losses``, ``metrics``, ``schedule``,
   ``plan``, ``onnx_export``; (b) ``training``, which runs them.
4. ``evaluation`` -- the evaluate and benchmark stages: ``evaluate``, ``floor``, ``efficiency``,
   ``timing``.
5. ``report`` and ``stats`` (the report's statistics) -- they read what the stages below wrote.
6. ``pipeline`` -- the stage entry points (outside ``src``; may import everything).

The package's own ``__init__`` and each layer's ``__init__`` import nothing of the project.

The report needs no torch: nothing the report stage can import (``pipeline/report.py``, every
module of ``report/`` and ``stats/``, and everything they import, lazily too) imports torch or
the modules that compute a run's numbers (:data:`RUN_SIDE`); the facts it needs of them (score
formulas, metric and floor labels, the depth convention) are ``core``'s. Checked on the import
graph (naming the chain) and by importing the report in a fresh interpreter. No script of
``benchmarks/`` imports the report: the plateau record's writer and the report's reader of it
share its one definition, ``core/plateau_record``, and nothing else.
"""
from __future__ import annotations

import ast
import subprocess
import sys
from collections import deque
from pathlib import Path
from typing import Optional

import pytest

from imports import import_targets, module_file, module_imports

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "src" / "compact_perception"
TOP = "compact_perception"

CORE, EXECUTION, DATA, LEARNING, EVALUATION, REPORT = 0, 1, 2, 3, 4, 5
#: Where each part of the package sits: (layer, tier inside the layer). A module's place is that of
#: the longest entry its dotted name (below the package) starts with.
LAYERS: dict[str, tuple[int, int]] = {
    "": (CORE, 0), "core": (CORE, 0),
    "execution": (EXECUTION, 0),
    "data": (DATA, 0), "data.record": (DATA, 0),
    **{f"data.{name}": (DATA, 1) for name in (
        "world", "carla", "nuscenes", "authors", "geometry", "dvs", "lidar", "figures_generate",
        "figures_preprocess", "qualitative", "loader")},
    "data.sources": (DATA, 2), "data.preprocess": (DATA, 2),
    "learning": (LEARNING, 0),
    **{f"learning.{name}": (LEARNING, 0) for name in (
        "models", "weighting", "losses", "metrics", "schedule", "plan", "onnx_export")},
    "learning.training": (LEARNING, 1),
    "evaluation": (EVALUATION, 0),
    **{f"evaluation.{name}": (EVALUATION, 0) for name in ("evaluate", "floor", "efficiency", "timing")},
    "report": (REPORT, 0), "stats": (REPORT, 0),
}
LAYER_NAMES = {CORE: "core", EXECUTION: "execution", DATA: "data", LEARNING: "learning", EVALUATION: "evaluation", REPORT: "report"}

#: Parts that must not import each other, whatever their places: the trainable parts stay
#: separate (a network does not know its loss weighting, nor the weighting the network), and
#: scoring a run does not reach into how it was trained.
KEPT_APART: frozenset[frozenset[str]] = frozenset({
    frozenset({"learning.models", "learning.weighting"}),
    frozenset({"learning.training", "evaluation.evaluate"}),
})


def _modules() -> dict[str, Path]:
    out = {}
    for path in sorted(PKG.rglob("*.py")):
        parts = list(path.relative_to(PKG.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def _imported(module: str, path: Path) -> list[tuple[int, str]]:
    """``(line, module)`` of every project module imported by ``module`` (lazy imports included)."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = [(node.lineno, name) for node in ast.walk(ast.parse(path.read_text(), str(path)))
             for name in import_targets(node, package)]
    return [(line, name) for line, name in found if name == TOP or name.startswith(TOP + ".")]


def _part(module: str) -> str:
    """The :data:`LAYERS` entry ``module`` belongs to: the longest one its name below the package
    starts with (``""`` for the package itself)."""
    below = module.split(".", 1)[1] if "." in module else ""
    parts = below.split(".") if below else []
    for n in range(len(parts), -1, -1):
        key = ".".join(parts[:n])
        if key in LAYERS:
            return key
    raise AssertionError(f"{module}: no place in tests/test_layers.py's LAYERS; add {below!r} there")


def _layer(module: str) -> tuple[int, int]:
    return LAYERS[_part(module)]


def _where(module: str) -> str:
    layer, tier = _layer(module)
    return f"{LAYER_NAMES[layer]}/{_part(module) or 'package'} (tier {tier})"


def _known(name: str, modules: dict[str, Path]) -> bool:
    return name in modules


def test_every_module_has_a_layer():
    for module in _modules():
        _layer(module)


def _violations() -> list[str]:
    modules = _modules()
    bad = []
    for module, path in modules.items():
        here, part = _layer(module), _part(module)
        for line, name in _imported(module, path):
            if not _known(name, modules):
                continue  # a name imported from a module, not a module
            there, other = _layer(name), _part(name)
            rel = f"{path.relative_to(ROOT)}:{line}: {module} imports {name}"
            if there > here:
                bad.append(f"{rel} ({_where(module)} -> {_where(name)}: upward)")
            elif other != part and frozenset({part, other}) in KEPT_APART:
                bad.append(f"{rel} (sideways: {part} and {other} are kept apart)")
    return bad


def test_the_top_level_reads_as_the_pipeline():
    """The package's folders are its layers, in the pipeline's order; no loose module at the top."""
    top = sorted(p.name for p in PKG.iterdir() if p.suffix == ".py" or (p.is_dir() and (p / "__init__.py").exists()))
    assert top == ["__init__.py", "core", "data", "evaluation", "execution", "learning", "report", "stats"]
    assert sorted({key.split(".")[0] for key in LAYERS if key}) == top[1:]


def test_the_executor_layer_knows_jobs_not_runs():
    """``execution/`` imports nothing of ``learning/`` or ``evaluation/`` (nor anything above them):
    a stage hands it its planned runs and worker function, whole."""
    modules = _modules()
    reached = sorted(f"{m} imports {name}" for m, path in modules.items() if _part(m) == "execution"
                     for _, name in _imported(m, path) if _known(name, modules) and _layer(name)[0] > EXECUTION)
    assert not reached, reached
    assert any(_part(m) == "execution" for m in modules)


def test_layers_import_downward_only():
    bad = _violations()
    assert not bad, "imports against the layer order:\n" + "\n".join(bad)


def test_checker_resolves_relative_and_lazy_imports(tmp_path):
    """The parser itself: a lazy relative import two levels up is found and resolved."""
    src = tmp_path / "x.py"
    src.write_text("def f():\n    from ...report.figures import save_figure\nimport os\n")
    found = _imported("compact_perception.learning.weighting.mgn", src)
    assert (2, "compact_perception.report.figures") in found
    assert (2, "compact_perception.report.figures.save_figure") in found
    assert all(name != "os" for _, name in found)


@pytest.mark.parametrize("importer, imported, upward", [
    ("compact_perception.learning.weighting.mgn", "compact_perception.learning.training.train", True),
    ("compact_perception.learning.weighting.mgn", "compact_perception.learning.schedule", False),
    ("compact_perception.data.authors", "compact_perception.report.figures", True),
    ("compact_perception.data.loader", "compact_perception.learning.losses", True),
    ("compact_perception.learning.training.train", "compact_perception.evaluation.evaluate", True),
    ("compact_perception.evaluation.evaluate", "compact_perception.learning.metrics", False),
    ("compact_perception.report.study", "compact_perception.learning.weighting", False),
    ("compact_perception.learning.training.train", "compact_perception.core.params", False),
    ("compact_perception.data.carla.recording", "compact_perception.data.preprocess", True),  # a source, its consumer
    ("compact_perception.data.carla.recording", "compact_perception.data.record", False),
    ("compact_perception.data.preprocess", "compact_perception.data.sources", False),
    ("compact_perception.execution.pool", "compact_perception.learning.training.train", True),
    ("compact_perception.execution.executor", "compact_perception.evaluation.evaluate", True),
    ("compact_perception.learning.training.parallel", "compact_perception.execution.pool", False),
    ("compact_perception.execution.settings", "compact_perception.core.params.file", False),
])
def test_layer_order(importer, imported, upward):
    assert (_layer(imported) > _layer(importer)) is upward


# ----------------------------------------------------------------------------- the report needs no torch
#: The modules that compute a run's numbers (evaluation's metrics and floor, training's losses):
#: the report reads what they wrote, never them, so editing one reruns nothing of the report.
RUN_SIDE: tuple[str, ...] = (f"{TOP}.learning.metrics", f"{TOP}.learning.losses", f"{TOP}.evaluation.floor")
#: What no module of the report stage may import, directly or through others, lazily too.
NOT_IN_REPORT: tuple[str, ...] = ("torch", *RUN_SIDE)


#: The modules of every stage's start-up (``pipeline/__init__``, ``pipeline/_common``) whose
#: functions for the torch stages import torch: the numeric pins (``set_threads``,
#: ``set_determinism``) and the device check (``device_problem``, a stage that runs on
#: ``train.device``). They import torch inside those functions only
#: (:func:`test_the_start_up_imports_torch_only_in_the_torch_stages_helpers`), and the report stage,
#: run whole, loads no torch (:func:`test_the_report_stage_runs_without_torch`).
TORCH_ONLY_WHEN_CALLED: frozenset[str] = frozenset({f"src/{TOP}/core/determinism.py", f"src/{TOP}/core/machine.py"})


def test_the_run_side_names_modules_that_exist():
    """The forbidden modules are real ones: a move cannot make the torch-free check vacuous."""
    modules = _modules()
    assert [name for name in RUN_SIDE if name not in modules] == []


def _report_entries() -> list[Path]:
    """Every module the report stage runs: its entry point and each module of ``report/`` and ``stats/``."""
    return [ROOT / "pipeline" / "report.py", *sorted((PKG / "report").rglob("*.py")),
            *sorted((PKG / "stats").rglob("*.py"))]


def _forbidden(name: str) -> bool:
    return any(name == bad or name.startswith(bad + ".") for bad in NOT_IN_REPORT)


def _chain_to_forbidden(entry: Path) -> Optional[list[str]]:
    """The import chain (files, then the module) from ``entry`` to a module of :data:`NOT_IN_REPORT`,
    breadth first (the shortest); ``None`` when there is none."""
    todo: deque[tuple[Path, list[str]]] = deque([(entry, [entry.relative_to(ROOT).as_posix()])])
    seen = {entry}
    while todo:
        path, chain = todo.popleft()
        torch_when_called = path.relative_to(ROOT).as_posix() in TORCH_ONLY_WHEN_CALLED
        for name in sorted(module_imports(ROOT, path)):
            if _forbidden(name) and not (torch_when_called and name.split(".")[0] == "torch"):
                return chain + [name]
            found = module_file(ROOT, name)
            if found is not None and found not in seen:
                seen.add(found)
                todo.append((found, chain + [found.relative_to(ROOT).as_posix()]))
    return None


@pytest.mark.parametrize("entry", _report_entries(), ids=lambda p: p.relative_to(ROOT).as_posix())
def test_no_report_module_reaches_torch_or_the_run_side(entry: Path):
    chain = _chain_to_forbidden(entry)
    assert chain is None, "the report must not import torch or " + ", ".join(RUN_SIDE) + ": " + " -> ".join(chain)


def _chain_to_report(entry: Path) -> Optional[list[str]]:
    """The import chain (files) from ``entry`` to a module of ``report/``, breadth first; ``None`` when there is none."""
    todo: deque[tuple[Path, list[str]]] = deque([(entry, [entry.relative_to(ROOT).as_posix()])])
    seen = {entry}
    while todo:
        path, chain = todo.popleft()
        for name in sorted(module_imports(ROOT, path)):
            found = module_file(ROOT, name)
            if found is None or found in seen:
                continue
            if (PKG / "report") in found.parents:
                return chain + [found.relative_to(ROOT).as_posix()]
            seen.add(found)
            todo.append((found, chain + [found.relative_to(ROOT).as_posix()]))
    return None


@pytest.mark.parametrize("script", sorted((ROOT / "benchmarks").glob("*.py")), ids=lambda p: p.name)
def test_no_benchmark_script_imports_the_report(script: Path):
    """The scripts write what the report reads (``benchmarks/record_full.py`` the plateau record,
    whose one definition is ``core/plateau_record``, read by ``report/plateau``): none imports the
    report, so the writer and its reader share only what is below both."""
    chain = _chain_to_report(script)
    assert chain is None, "a benchmark script must not import the report: " + " -> ".join(chain)


def test_the_plateau_records_writer_and_reader_share_its_one_definition():
    record = f"{TOP}.core.plateau_record"
    for user in (ROOT / "benchmarks" / "record_full.py", PKG / "report" / "plateau.py"):
        assert record in module_imports(ROOT, user), f"{user.relative_to(ROOT)} does not read with {record}"


def test_the_checker_finds_a_lazy_import_two_modules_down(tmp_path, monkeypatch):
    """The chain search itself: a report module importing a core module that lazily imports the
    metrics module is caught, and the chain names both files."""
    pkg = tmp_path / "src" / TOP
    for sub in ("report", "core", "learning"):
        (pkg / sub).mkdir(parents=True)
        (pkg / sub / "__init__.py").write_text("")
    (pkg / "__init__.py").write_text("")
    (pkg / "learning" / "metrics.py").write_text("import torch\n")
    (pkg / "core" / "facts.py").write_text("def f():\n    from ..learning.metrics import mae\n")
    (pkg / "report" / "table.py").write_text("from ..core import facts\n")
    (pkg / "report" / "clean.py").write_text("from ..core import catalog\nimport numpy\n")
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    assert _chain_to_forbidden(pkg / "report" / "table.py") == [
        f"src/{TOP}/report/table.py", f"src/{TOP}/core/facts.py", f"{TOP}.learning.metrics"]
    assert _chain_to_forbidden(pkg / "report" / "clean.py") is None


def test_the_start_up_imports_torch_only_in_the_torch_stages_helpers():
    """The exemption holds: a module of :data:`TORCH_ONLY_WHEN_CALLED` imports torch inside its
    functions only, never when it is imported (``if TYPE_CHECKING:`` aside)."""
    def on_import(nodes: list[ast.stmt]) -> set[str]:
        names: set[str] = set()
        for node in nodes:
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            if isinstance(node, ast.If) and isinstance(node.test, ast.Name) and node.test.id == "TYPE_CHECKING":
                names |= on_import(node.orelse)
                continue
            names.update(import_targets(node, f"{TOP}.core"))
            names |= on_import([c for c in ast.iter_child_nodes(node) if isinstance(c, ast.stmt)])
        return names

    for rel in sorted(TORCH_ONLY_WHEN_CALLED):
        tree = ast.parse((ROOT / rel).read_text())
        assert not any(n.split(".")[0] == "torch" for n in on_import(tree.body)), f"{rel} imports torch on import"


def _in_fresh_interpreter(code: str) -> list[str]:
    """Run ``code`` in a fresh interpreter at the repository root; the modules of
    :data:`NOT_IN_REPORT` it left loaded."""
    code += f"\nimport sys\nprint(sorted(m for m in sys.modules if any(m == b or m.startswith(b + '.') for b in {NOT_IN_REPORT!r})))"
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=300)
    assert done.returncode == 0, done.stderr
    return ast.literal_eval(done.stdout.strip().splitlines()[-1])


def test_importing_the_report_loads_no_torch():
    """In a fresh interpreter, every report module and the stage's entry point import without
    torch (nor a third-party module that pulls it in) and without the run side's modules."""
    modules = [".".join(p.relative_to(PKG.parent if p.is_relative_to(PKG) else ROOT).with_suffix("").parts)
               for p in _report_entries()]
    modules = [m.removesuffix(".__init__") for m in modules]
    code = f"import importlib\nfor m in {modules!r}:\n    importlib.import_module(m)"
    assert _in_fresh_interpreter(code) == []


def test_the_report_stage_runs_without_torch(tmp_path):
    """The stage itself, lazy imports in the functions it calls included: ``python -m
    pipeline.report`` with the repository's params (its start-up, the plateau record, the whole
    report: tables, claims, figures, plots) over a tree of every selected dataset's runs, in a
    fresh interpreter, leaves no torch loaded."""
    from report_fixture import build_tree

    build_tree(tmp_path / "tree", ("A", "B", "C", "nuscenes"), n_frames=20, seeds=(0, 1, 2, 3), baseline_seeds=(0,),
               predictions=True, efficiency=True)
    argv = ["pipeline.report", "--root", str(tmp_path / "tree"), "--out", str(tmp_path / "reports")]
    code = f"import runpy, sys\nsys.argv = {argv!r}\nrunpy.run_module('pipeline.report', run_name='__main__')"
    assert _in_fresh_interpreter(code) == []
    for name in ("index.md", "tables/table2.md", "tables/claims.md", "figures/report/qualitative_A.png"):
        assert (tmp_path / "reports" / name).is_file(), name


# ----------------------------------------------------------------------------- scale, resolved once
#: The one module that resolves a per-scale value at the params' own ``scale``: ``Params``'
#: accessors (``resolution``, ``frames_of``, ``split_counts_of``, ``study_datasets``, ...).
SCALE_RESOLVED_IN = PKG / "core" / "params" / "schema.py"


def _scale_lookups(path: Path) -> list[str]:
    """``file:line: code`` of every ``<value>.at(<x>.scale)`` call in ``path`` (a ``Scaled`` read
    at the params' own scale), whatever ``<x>`` is named."""
    tree = ast.parse(path.read_text(), str(path))
    return [f"{path.name}:{node.lineno}: {ast.unparse(node)}" for node in ast.walk(tree)
            if isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute) and node.func.attr == "at"
            and any(isinstance(a, ast.Attribute) and a.attr == "scale" for a in node.args)]


def test_scale_is_resolved_where_params_load():
    """No module below the params schema, no stage and no benchmark reads ``.at(params.scale)``:
    they ask ``Params`` for the value at its scale, so the scale is chosen in one place."""
    files = [p for d in (PKG, ROOT / "pipeline", ROOT / "benchmarks") for p in sorted(d.rglob("*.py"))]
    found = [hit for p in files if p != SCALE_RESOLVED_IN for hit in _scale_lookups(p)]
    assert not found, "a per-scale value resolved outside core/params/schema.py:\n" + "\n".join(found)
    assert _scale_lookups(SCALE_RESOLVED_IN), "the checker finds nothing where the scale is resolved"


def test_the_scale_checker_finds_any_spelling(tmp_path):
    src = tmp_path / "x.py"
    src.write_text("def f(p, spec):\n    a = p.world.resolution.at(p.scale)\n    b = spec.x.at(spec.params.scale)\n"
                   "    c = p.world.resolution.at('full')\n")
    hits = _scale_lookups(src)
    assert [h.split(": ", 1)[1] for h in hits] == ["p.world.resolution.at(p.scale)", "spec.x.at(spec.params.scale)"]
