"""dvc.yaml records every input of a result: each stage depends on every project module its
entry module can import (statically, lazy imports included), on no code it cannot import (so
editing a loss reruns no report), and on nothing that is missing.

The params side (every key a stage reads is listed under its ``params:``) is checked by the
end-to-end test, which runs the real stages with the params audit on.
"""
from __future__ import annotations

import re
from pathlib import Path

import pytest
import yaml

from imports import import_closure

ROOT = Path(__file__).resolve().parents[1]


def _stages() -> dict[str, dict]:
    stages = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]
    out = {}
    for name, stage in stages.items():
        out[name] = stage.get("do", stage)
    return out


def _code_deps(stage: dict) -> list[str]:
    deps = []
    for dep in stage.get("deps", []):
        path = dep if isinstance(dep, str) else next(iter(dep))
        if "${" not in path and not path.startswith(("data/", "runs", "results")):
            deps.append(path)
    return deps


def _covered(path: Path, deps: list[str]) -> bool:
    rel = path.relative_to(ROOT).as_posix()
    return any(rel == d or rel.startswith(d.rstrip("/") + "/") for d in deps)


@pytest.mark.parametrize("name", sorted(_stages()))
def test_stage_depends_on_every_module_it_imports(name):
    stage = _stages()[name]
    module = re.search(r"-m (pipeline\.\w+)", stage["cmd"]).group(1)
    entry = ROOT / (module.replace(".", "/") + ".py")
    deps = _code_deps(stage)
    missing = sorted(p.relative_to(ROOT).as_posix() for p in import_closure(ROOT, entry) if not _covered(p, deps))
    assert not missing, f"stage {name} imports these but does not depend on them: {missing}"


@pytest.mark.parametrize("name", sorted(_stages()))
def test_stage_depends_on_no_code_it_does_not_import(name):
    """Every Python file or folder of code a stage depends on holds a module its entry can import:
    a module the stage does not run would rerun it for nothing (data files, such as the paper's
    numbers, are inputs of their own)."""
    stage = _stages()[name]
    module = re.search(r"-m (pipeline\.\w+)", stage["cmd"]).group(1)
    closure = import_closure(ROOT, ROOT / (module.replace(".", "/") + ".py"))
    code = [d for d in _code_deps(stage)   # a folder of data (benchmarks/records/full) is an input, not code
            if d.endswith(".py") or ((ROOT / d).is_dir() and any((ROOT / d).rglob("*.py")))]
    unused = [d for d in code if not any(_covered(p, [d]) for p in closure)]
    assert not unused, f"stage {name} depends on code it does not import: {unused}"


def test_the_report_reruns_for_no_loss_metric_or_floor():
    """The report reads what evaluation wrote: the modules that compute it are no dependency."""
    deps = _code_deps(_stages()["report"])
    for module in ("losses.py", "metrics.py", "floor.py"):
        assert f"src/compact_perception/{module}" not in deps


@pytest.mark.parametrize("name", sorted(_stages()))
def test_stage_code_deps_exist(name):
    for dep in _code_deps(_stages()[name]):
        assert (ROOT / dep).exists(), f"stage {name}: dependency {dep} does not exist"


def test_closure_follows_lazy_and_relative_imports(tmp_path):
    """The checker itself: a lazy import inside a function and a relative import are found."""
    (tmp_path / "pipeline").mkdir()
    pkg = tmp_path / "src" / "compact_perception"
    (pkg / "sub").mkdir(parents=True)
    (tmp_path / "pipeline" / "__init__.py").write_text("")
    (tmp_path / "pipeline" / "stage.py").write_text("def main():\n    from compact_perception.sub import thing\n")
    (pkg / "__init__.py").write_text("")
    (pkg / "sub" / "__init__.py").write_text("from .thing import f\n")
    (pkg / "sub" / "thing.py").write_text("from .. import leaf\n")
    (pkg / "leaf.py").write_text("import numpy\n")
    (pkg / "unused.py").write_text("")
    found = {p.relative_to(tmp_path).as_posix() for p in import_closure(tmp_path, tmp_path / "pipeline/stage.py")}
    assert found == {"pipeline/__init__.py", "pipeline/stage.py", "src/compact_perception/__init__.py",
                     "src/compact_perception/sub/__init__.py", "src/compact_perception/sub/thing.py",
                     "src/compact_perception/leaf.py"}


def test_each_data_source_registration_names_its_stage_deps():
    """A data source's registration (core/params/sources.py) names the code its module runs beyond
    the shared data modules: the generate and preprocess stages list each of those and the
    data/sources folder, and the source's module does import each (the registration is true)."""
    from compact_perception.core.params import SOURCES

    stages = _stages()
    for key in SOURCES.keys():
        module = ROOT / "src" / "compact_perception" / "data" / "sources" / f"{key}.py"
        closure = import_closure(ROOT, module)
        for dep in SOURCES[key].deps:
            assert (ROOT / dep).exists(), f"source {key}: dep {dep} does not exist"
            assert any(_covered(p, [dep]) for p in closure), f"source {key}: its module does not import {dep}"
            for stage in ("generate", "preprocess"):
                assert dep in _code_deps(stages[stage]), f"stage {stage} does not list source {key}'s dep {dep}"
    for stage in ("generate", "preprocess"):
        assert "src/compact_perception/data/sources" in _code_deps(stages[stage])
