"""The params audit (core/params_audit.py) records what a stage reads, including the base recipe
keys a merged recipe inherits (dvc.yaml must list ``train.recipe`` beside ``train.models.<id>``)."""
from __future__ import annotations

from compact_perception.core.config import parse_params
from compact_perception.core.params_audit import ParamsView, _Log, leaf_keys


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
