"""Training recipes: ``train.recipe`` (the base) merged with ``train.models.<id>`` (what a model
changes) in the schema, and a study arm merged onto its base model's recipe. The merged recipes
must be exactly the recipes params.yaml spelled out per model before the base existed."""
from __future__ import annotations

import pytest

from compact_perception.core.params import ParamsError, merge_recipe, parse_params

# The recipes as params.yaml wrote them out in full (git show b6a4d10:params.yaml, train.models),
# before the base recipe: the merged recipes must equal them, key for key.
SGD = {"optimizer": "sgd", "de_loss": "huber", "plateau_rule": "paper", "lr": 0.1, "lr_min": 1.0e-5,
       "momentum": 0.9, "weight_decay": 1.0e-4}
WRITTEN_OUT = {
    "compact_1l": {**SGD, "weighting": "static"},
    "compact_15l": {**SGD, "weighting": "static"},
    "compact_15l_mgn": {**SGD, "weighting": "mgn",
                        "mgn": {"alpha": 1.5, "lr": 0.1, "lr_min": 1.0e-4, "authors_mode": False}},
    "compact_15l_mgn_authors": {"optimizer": "sgd", "de_loss": "smooth_l1", "plateau_rule": "torch", "lr": 0.1,
                                "lr_min": 1.0e-5, "momentum": 0.9, "weight_decay": 1.0e-4, "weighting": "mgn",
                                "mgn": {"alpha": 1.5, "lr": 0.1, "lr_min": 1.0e-4, "authors_mode": True}},
    "gradnorm_segnet": {"optimizer": "adam", "plateau_rule": "paper", "betas": [0.9, 0.999], "eps": 1.0e-8,
                        "lr": 1.0e-4, "lr_min": 1.0e-5, "weight_decay": 1.0e-4, "weighting": "gradnorm",
                        "gradnorm": {"alpha": 1.5, "lr": 0.025}},
    "polarnet": {"optimizer": "adam", "plateau_rule": "paper", "betas": [0.9, 0.999], "eps": 1.0e-8, "lr": 1.0e-3,
                 "lr_min": 1.0e-5, "weight_decay": 0.0, "weighting": "none"},
    "chen_bev": {"optimizer": "adam", "plateau_rule": "paper", "betas": [0.9, 0.999], "eps": 1.0e-8, "lr": 1.0e-4,
                 "lr_min": 1.0e-5, "weight_decay": 0.0, "weighting": "none"},
}
# Since issue 23 the baselines cap their own training (the default scale trains them 1 epoch).
CAP = {"max_epochs": {"default": 1, "full": 100, "paper": 300}}
for _m in ("gradnorm_segnet", "polarnet", "chen_bev"):
    WRITTEN_OUT[_m] = {**WRITTEN_OUT[_m], **CAP}
# Each study arm: compact_15l's recipe with the arm's weighting and its section (Params.study_recipe).
ARMS = {
    "gradnorm": {"weighting": "gradnorm", "gradnorm": {"alpha": 1.5, "lr": 0.025}},
    "uw": {"weighting": "uw", "uw": {"lr": 0.025}},
    "dwa": {"weighting": "dwa", "dwa": {"temperature": 2.0}},
    "pcgrad": {"weighting": "pcgrad", "pcgrad": {"seed": 0}},
    "cagrad": {"weighting": "cagrad", "cagrad": {"c": 0.4}},
    "single_de": {"weighting": "single", "single": {"task": "de"}},
    "single_ss": {"weighting": "single", "single": {"task": "ss"}},
    "single_ls": {"weighting": "single", "single": {"task": "ls"}},
    "single_bevp": {"weighting": "single", "single": {"task": "bevp"}},
}


def test_merged_recipes_equal_the_recipes_written_out_before(params_dict):
    p = parse_params(params_dict)
    assert [m for m in p.train.models if m in WRITTEN_OUT] == list(WRITTEN_OUT)   # a later model may follow
    for model_id, expected in WRITTEN_OUT.items():
        assert p.train.models[model_id].model_dump(exclude_none=True) == expected, model_id
    assert [a for a in p.study.arm_ids if a in ARMS] == list(ARMS)                # a later arm may join
    for arm in p.study.arm_ids:          # every arm: the base model's recipe with its weighting replaced
        spec = ARMS.get(arm, params_dict["study"]["arms"][arm])
        assert p.study_recipe(arm).model_dump(exclude_none=True) == {**WRITTEN_OUT["compact_15l"], **spec}, arm


def test_the_base_reaches_every_model_that_does_not_change_the_key(params_dict):
    params_dict["train"]["recipe"]["weight_decay"] = 5.0e-4
    models = parse_params(params_dict).train.models
    changed = {m for m, r in models.items() if r.weight_decay == 5.0e-4}
    inherits = {m for m, diff in params_dict["train"]["models"].items() if "weight_decay" not in (diff or {})}
    assert changed == inherits
    assert {"compact_1l", "compact_15l", "compact_15l_mgn", "compact_15l_mgn_authors", "gradnorm_segnet"} <= changed
    assert models["polarnet"].weight_decay == 0.0


def test_merge_rules():
    base = {"optimizer": "sgd", "momentum": 0.9, "weighting": "mgn", "mgn": {"alpha": 1.5}}
    assert merge_recipe(base, {}) == base
    assert merge_recipe(base, {"momentum": None}) == {"optimizer": "sgd", "weighting": "mgn", "mgn": {"alpha": 1.5}}
    # a new weighting drops the section of the one it replaces; the same weighting keeps it
    assert merge_recipe(base, {"weighting": "uw", "uw": {"lr": 0.1}}) == {
        "optimizer": "sgd", "momentum": 0.9, "weighting": "uw", "uw": {"lr": 0.1}}
    assert merge_recipe(base, {"weighting": "mgn"})["mgn"] == {"alpha": 1.5}
    assert base["mgn"] == {"alpha": 1.5} and "uw" not in base  # the base itself is left as it is


def test_a_recipe_knows_where_each_value_is_written(params_dict):
    p = parse_params(params_dict)
    mgn = p.train.models["compact_15l_mgn"]
    assert mgn.key_of("lr") == "train.recipe.lr"
    assert mgn.key_of("weighting") == "train.models.compact_15l_mgn.weighting"
    assert mgn.key_of("mgn") == "train.models.compact_15l_mgn.mgn"
    uw = p.study_recipe("uw")
    assert uw.key_of("uw") == "study.arms.uw.uw" and uw.key_of("lr") == "train.recipe.lr"


def test_a_bad_inherited_value_is_named_once_at_the_base(params_dict):
    params_dict["train"]["recipe"]["lr"] = "fast"
    params_dict["train"]["recipe"]["lr_mn"] = 1.0e-5  # a typo: no such key
    with pytest.raises(ParamsError) as exc:
        parse_params(params_dict)
    msg = str(exc.value)
    assert msg.count("train.recipe.lr: Input should be a valid number (got 'fast')") == 1, msg
    assert msg.count("train.recipe.lr_mn: unknown key") == 1, msg
    assert "train.models" not in msg, msg


def test_a_study_arm_error_names_the_arm_key(params_dict):
    params_dict["study"]["arms"]["uw"] = {"weighting": "uw", "uw": 0.025}
    p = parse_params(params_dict)
    with pytest.raises(ParamsError, match=r"^params\.yaml: study\.arms\.uw\.uw: expected a mapping .*\(got 0\.025\)"):
        p.study_recipe("uw")
