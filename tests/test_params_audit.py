"""The params audit (core/params/audit.py) records what a stage reads, including the base recipe
keys a merged recipe inherits (dvc.yaml must list ``train.recipe`` beside ``train.models.<id>``)."""
from __future__ import annotations

import json
from functools import partial

from compact_perception.core.params import parse_params
from compact_perception.core.params.audit import ENV_VAR, ParamsView, _Log, leaf_keys
from compact_perception.learning.plan import planned_run
from compact_perception.learning.training.parallel import Job, run_jobs


def _view(params_dict: dict) -> tuple[ParamsView, _Log]:
    log = _Log()
    return ParamsView(parse_params(params_dict), "", log), log


def test_an_inherited_recipe_key_records_the_base_key(params_dict):
    view, log = _view(params_dict)
    recipe = view.train.models["compact_15l_mgn"]
    assert recipe.lr == 0.1 and recipe.weighting == "mgn"
    assert leaf_keys(log.keys) == {"train.models.compact_15l_mgn.lr", "train.recipe.lr",
                                   "train.models.compact_15l_mgn.weighting"}


def test_a_dump_records_every_key_and_where_it_is_written(params_dict):
    view, log = _view(params_dict)
    view.train.models["gradnorm_segnet"].model_dump()
    keys = leaf_keys(log.keys)
    assert {"train.models.gradnorm_segnet.gradnorm", "train.models.gradnorm_segnet.lr",
            "train.recipe.plateau_rule", "train.recipe.lr_min", "train.recipe.weight_decay"} <= keys
    assert "train.recipe.lr" not in keys  # the model sets its own lr


def test_a_method_runs_on_the_view(params_dict):
    """``Params.study_recipe`` reads the base model's recipe and the arm: all of it is recorded."""
    view, log = _view(params_dict)
    assert view.study_recipe("uw").weighting == "uw"
    keys = {k.split(".")[0] + "." + k.split(".")[1] for k in leaf_keys(log.keys)}
    assert keys == {"study.arms", "study.base_model", "train.models", "train.recipe"}
    assert "study.arms.uw" in {".".join(k.split(".")[:3]) for k in log.keys}
    assert "train.recipe.lr" in log.keys and "study.arms.dwa" not in log.keys


def test_a_value_at_the_files_scale_records_its_key_and_scale(params_dict):
    """``scale`` is resolved once, when params load; reading a value at it (``resolution``,
    ``frames_of``, ``split_counts_of``, ``seeds_of``) still records that key and ``scale``, and a
    value asked at another scale records its key only."""
    view, log = _view(params_dict)
    assert view.resolution == 32 and view.frames_of("B") == params_dict["datasets"]["B"]["frames"]["default"]
    assert leaf_keys(log.keys) == {"scale", "world.resolution", "datasets.B.frames"}
    view, log = _view(params_dict)
    assert sum(view.split_counts_of("C").values()) == params_dict["datasets"]["C"]["frames"]["default"]
    keys = leaf_keys(log.keys)
    assert {"scale", "datasets.C.frames"} <= keys and any(k.startswith("datasets.C.split_ratio.") for k in keys)
    view, log = _view(params_dict)
    view.seeds_of("baseline", "A", "full")
    assert leaf_keys(log.keys) == {"baseline_seeds.full"}   # no "scale": not read at the file's scale


def _worker_reads(params, run) -> float:
    """What a stage's worker reads: a setting of the params and a value of the run's recipe."""
    return params.train.num_threads * run.recipe.lr


def test_a_workers_reads_are_recorded_in_its_own_line(params_dict, tmp_path, monkeypatch):
    """The stage hands its (audited) params and planned runs to spawned worker processes pickled;
    each worker records what it reads, recipe keys included, and appends its line at exit."""
    target = tmp_path / "audit.jsonl"
    monkeypatch.setenv(ENV_VAR, str(target))  # inherited by the workers
    view, log = _view(params_dict)
    runs = [planned_run(view, "A", m, 0) for m in ("compact_15l_mgn", "compact_1l")]
    assert run_jobs(partial(_worker_reads, view), [Job(r.name, r) for r in runs], 2, desc="audit") == \
        [view.train.num_threads * r.recipe.lr for r in runs]
    lines = [json.loads(line) for line in target.read_text().splitlines()]
    worker_keys = set().union(*(line["keys"] for line in lines))
    assert {"train.num_threads", "train.models.compact_15l_mgn.lr", "train.models.compact_1l.lr",
            "train.recipe.lr"} <= worker_keys
    assert all(k.startswith(("train.num_threads", "train.models.", "train.recipe.")) for k in worker_keys)
