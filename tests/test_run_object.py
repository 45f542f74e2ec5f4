"""One run object, planned once (``plan.PlannedRun``) and carried whole from the stage to its
worker processes, the training loop and the evaluation: the layers below the stages take it (and
the params) rather than loose values, re-read no params file and re-derive no recipe key, and
none of their public functions takes more than six parameters."""
from __future__ import annotations

import ast
import dataclasses
import importlib
import inspect
import pickle
import pkgutil
from pathlib import Path

import pytest

from compact_perception.core.params import parse_params
from compact_perception.core.layout import run_paths, study_arm, study_paths, study_run_name
from compact_perception.learning.plan import PlannedRun, dataset_runs, planned_run

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "src" / "compact_perception"
MAX_PARAMETERS = 6


def _modules_below_the_stages() -> list[str]:
    """``training`` and every module in it, and ``evaluate``."""
    import compact_perception.learning.training as training

    return ["compact_perception.learning.training", "compact_perception.evaluation.evaluate",
            *(f"compact_perception.learning.training.{m.name}" for m in pkgutil.iter_modules(training.__path__))]


def _public_callables(module_name: str) -> list[tuple[str, inspect.Signature, bool]]:
    """``(name, signature, is_method)`` of every public function the module defines and every public
    method (``__init__`` of a class that is not a dataclass included) of its public classes."""
    module = importlib.import_module(module_name)
    out = []
    for name, obj in vars(module).items():
        if name.startswith("_") or getattr(obj, "__module__", None) != module_name:
            continue
        if inspect.isfunction(obj):
            out.append((name, inspect.signature(obj), False))
        elif inspect.isclass(obj):
            for attr, member in vars(obj).items():
                init = attr == "__init__" and not dataclasses.is_dataclass(obj)
                if inspect.isfunction(member) and (init or not attr.startswith("_")):
                    out.append((f"{name}.{attr}", inspect.signature(member), True))
    return out


def _count(signature: inspect.Signature, is_method: bool) -> int:
    """The parameters a caller passes (``self`` not counted)."""
    return len(signature.parameters) - int(is_method)


@pytest.mark.parametrize("module_name", _modules_below_the_stages())
def test_no_public_function_below_the_stages_takes_more_than_six_parameters(module_name):
    found = _public_callables(module_name)
    too_many = [f"{module_name}.{name}{sig} ({_count(sig, m)} parameters)" for name, sig, m in found
                if _count(sig, m) > MAX_PARAMETERS]
    assert not too_many, "carry the run (plan.PlannedRun) or the params, not loose values:\n" + "\n".join(too_many)


def test_the_parameter_count_sees_what_it_bounds():
    """The checker itself: it finds the entry points and counts their parameters (``*`` markers
    not counted, every keyword-only one counted)."""
    found = {name: _count(sig, m) for name, sig, m in _public_callables("compact_perception.learning.training.train")}
    assert found["train_run"] == 5 and found["run_digest"] == 5
    found = {name: _count(sig, m) for name, sig, m in _public_callables("compact_perception.evaluation.evaluate")}
    assert found["evaluate_run"] == 3 and found["score_test_split"] == 6
    assert "ClassCounts.add" in found and "Scoring.__init__" not in found  # a dataclass's fields are its record


def _calls_and_imports(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ImportFrom):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.Name):
            names.add(node.id)
        elif isinstance(node, ast.Attribute):
            names.add(node.attr)
    return names


def _below_the_stages() -> list[Path]:
    return [PKG / "learning" / "plan.py", PKG / "evaluation" / "evaluate.py",
            *sorted((PKG / "learning" / "training").glob("*.py"))]


@pytest.mark.parametrize("path", _below_the_stages(), ids=lambda p: p.relative_to(PKG).as_posix())
def test_nothing_below_the_stages_reads_a_params_file(path):
    """A worker gets the stage's params (pickled to it), never a file to read again."""
    assert not {"load_params", "parse_params", "read_params"} & _calls_and_imports(path)


@pytest.mark.parametrize("path", [*_below_the_stages(), *sorted((ROOT / "pipeline").glob("*.py"))],
                         ids=lambda p: p.relative_to(ROOT).as_posix())
def test_a_recipe_key_is_spelled_where_params_are_read_only(path):
    """``train.models.<id>`` / ``study.arms.<arm>``: the recipe knows the key it was read from
    (core), the plan copies it into the run; nothing below or in a stage spells it again."""
    text = path.read_text()
    assert "train.models.{" not in text and "study.arms.{" not in text


def test_one_run_paths_class():
    defined = [p.relative_to(PKG).as_posix() for p in PKG.rglob("*.py")
               if any(isinstance(n, ast.ClassDef) and n.name == "RunPaths" for n in ast.walk(ast.parse(p.read_text())))]
    assert defined == ["core/layout.py"]


def test_a_study_run_name_is_spelt_in_one_place():
    """``study:<arm>`` names a study run beside the model ids (run folders, records, the report);
    only core/layout builds or parses it, and the two functions invert each other."""
    assert study_run_name("gradnorm") == "study:gradnorm" and study_arm("study:gradnorm") == "gradnorm"
    assert study_arm("compact_15l") is None and study_paths("uw", 1, "A").model == study_run_name("uw")
    spelt = [p.relative_to(PKG).as_posix() for p in PKG.rglob("*.py")
             if any(isinstance(n, ast.Constant) and isinstance(n.value, str) and n.value.startswith("study:")
                    for n in ast.walk(ast.parse(p.read_text())))]
    assert spelt == ["core/layout.py"]


@pytest.fixture()
def study_params(params_dict):
    params_dict["study"]["datasets"]["default"] = ["A"]
    return parse_params(params_dict)


def test_a_planned_run_holds_what_the_layers_below_need(study_params):
    params = study_params
    runs = {r.name: r for r in dataset_runs(params, "A")}
    own, arm = runs["A/compact_15l_mgn/seed0"], runs["A/study/gradnorm/seed0"]
    assert (own.dataset, own.model, own.seed, own.arm) == ("A", "compact_15l_mgn", 0, None)
    assert own.recipe == params.train.models["compact_15l_mgn"] and own.recipe_key == "train.models.compact_15l_mgn"
    assert own.paths == run_paths("A", "compact_15l_mgn", 0) and own.paths.cache_dir == Path("data/cache/A")
    assert own.paths.best == Path("runs/A/compact_15l_mgn/seed0/best.pt")
    assert own.max_epochs == params.max_epochs_of(own.recipe, "A") and own.export_onnx and own.save_predictions
    assert (arm.model, arm.arm) == (params.study.base_model, "gradnorm")
    assert arm.recipe == params.study_recipe("gradnorm") and arm.recipe_key == "study.arms.gradnorm"
    assert arm.paths == study_paths("gradnorm", 0, "A") and not arm.export_onnx and not arm.save_predictions
    assert arm.cost == arm.max_epochs * 1.0
    for run in runs.values():
        assert pickle.loads(pickle.dumps(run)) == run  # crosses to a stage's spawned workers


def test_a_study_arm_trains_the_base_model_only(study_params):
    with pytest.raises(ValueError, match="trains study.base_model"):
        planned_run(study_params, "A", "compact_1l", 0, "uw")


def test_a_moved_run_keeps_everything_but_the_paths_it_moves(study_params, tmp_path):
    run = planned_run(study_params, "A", "compact_1l", 0)
    moved = run.moved(run_dir=tmp_path / "r", cache_dir=str(tmp_path / "c"))
    assert moved.paths.run_dir == tmp_path / "r" and moved.paths.cache_dir == tmp_path / "c"
    assert moved.paths.metrics_path == run.paths.metrics_path and moved.paths.last == tmp_path / "r" / "last.pt"
    assert dataclasses.replace(moved, paths=run.paths) == run


@pytest.mark.parametrize("stage, worker", [("train", "train_one"), ("evaluate", "evaluate_one")])
def test_both_stages_hand_their_workers_the_params_and_the_run(stage, worker):
    """Both stages take ``Params`` the same way: the worker function's first two parameters."""
    fn = getattr(importlib.import_module(f"pipeline.{stage}"), worker)
    first = [p.annotation for p in inspect.signature(fn).parameters.values()][:2]
    assert first == ["Params", "PlannedRun"]
    for entry, name in (("compact_perception.learning.training.train", "train_run"), ("compact_perception.evaluation.evaluate",
                                                                             "evaluate_run")):
        params = list(inspect.signature(getattr(importlib.import_module(entry), name)).parameters.values())
        assert [p.annotation for p in params[:2]] == ["Params", "PlannedRun"], name
    assert PlannedRun.__dataclass_params__.frozen
