"""params.yaml schema: the committed file is valid; bad input names the key."""
from __future__ import annotations

import copy
import typing

import pytest
from pydantic import BaseModel

from compact_perception.core import params as config
from compact_perception.core import catalog
from compact_perception.core.params import ParamsError, load_params, parse_params
from repo_params import repo_params_dict


def test_committed_params_are_valid(root):
    p = load_params(root / "params.yaml")
    assert p.scale == "default"
    assert p.datasets.A.frames.at("paper") == 2000
    assert p.datasets.B.frames.at("paper") == 2000
    assert p.datasets.C.frames.at("paper") == 10000
    assert p.world.resolution.at("paper") == 128
    paper_models = {"compact_1l", "compact_15l", "compact_15l_mgn", "compact_15l_mgn_authors", "gradnorm_segnet",
                    "polarnet", "chen_bev"}
    assert paper_models <= set(p.train.models) == set(catalog.model_ids())


def test_unknown_key_is_named(params_dict):
    params_dict["world"]["lidar"]["chanels"] = 64
    with pytest.raises(ParamsError, match=r"world\.lidar\.chanels: unknown key"):
        parse_params(params_dict)


def test_wrong_type_is_named(params_dict):
    params_dict["train"]["batch_size"] = "six"
    with pytest.raises(ParamsError, match=r"train\.batch_size: .*integer.*'six'"):
        parse_params(params_dict)


@pytest.mark.parametrize(
    "path, value, fragment",
    [
        (("datasets", "A", "frames", "default"), -5, r"datasets\.A\.frames"),
        (("datasets", "C", "train_towns"), ["town09"], r"datasets\.C\.train_towns.*town09"),
        (("world", "camera", "fov_deg"), 200, r"world\.camera\.fov_deg"),
        (("scale",), "huge", r"scale"),
        (("world", "resolution", "default"), 100, r"world\.resolution"),
    ],
)
def test_impossible_values_are_named(params_dict, path, value, fragment):
    _assert_rejected(params_dict, path, value, fragment)


def test_unknown_model_id(params_dict):
    """A complete recipe under an id the model registry (core/catalog.py) does not know."""
    params_dict["train"]["models"]["resnet"] = copy.deepcopy(params_dict["train"]["models"]["polarnet"])
    with pytest.raises(ParamsError, match=r"train\.models: .*unknown model id\(s\) \['resnet'\]"):
        parse_params(params_dict)
    del params_dict["train"]["models"]["resnet"]
    parse_params(params_dict)


def test_missing_file(tmp_path):
    with pytest.raises(ParamsError, match="file not found"):
        load_params(tmp_path / "nope.yaml")


# ----------------------------------------------------------------------------- strict types, counts
@pytest.mark.parametrize(
    "path, value, fragment",
    [
        (("train", "batch_size"), True, r"train\.batch_size: .*integer.*True"),
        (("train", "batch_size"), "6", r"train\.batch_size: .*integer.*'6'"),
        (("train", "batch_size"), 6.0, r"train\.batch_size: .*integer"),
        (("train", "batch_size"), 0, r"train\.batch_size: .*greater than or equal to 1"),
        (("train", "channels_last"), "no", r"train\.channels_last: .*boolean"),
        (("train", "plateau_factor"), True, r"train\.plateau_factor: .*number"),
        (("seed",), "2022", r"seed: .*integer"),
        (("datasets", "A", "training", "max_epochs", "default"), 0,
         r"datasets\.A\.training\.max_epochs: .*default must be at least 1"),
        (("datasets", "B", "training", "max_epochs", "full"), -3,
         r"datasets\.B\.training\.max_epochs: .*full must be at least 1"),
        (("train", "models", "gradnorm_segnet", "max_epochs"), {"default": 0, "full": 100, "paper": 300},  # a model's override
         r"train\.models\.gradnorm_segnet\.max_epochs: .*at least 1"),
        (("datasets", "nuscenes", "sim_scenes", "default"), 2, r"datasets\.nuscenes\.sim_scenes: .*at least 3"),
        (("datasets", "nuscenes", "split_seed"), -1, r"datasets\.nuscenes\.split_seed"),
        (("world", "conditions", "times"), [], r"world\.conditions\.times"),
        (("evaluate", "save_predictions"), False, r"evaluate\.save_predictions: .*integer"),
    ],
)
def test_strict_types_and_counts(params_dict, path, value, fragment):
    _assert_rejected(params_dict, path, value, fragment)


def test_yaml_int_passes_for_a_float(params_dict):
    params_dict["train"]["plateau_factor"] = 0.5
    params_dict["world"]["camera"]["fov_deg"] = 90  # YAML int where a float is expected
    assert parse_params(params_dict).world.camera.fov_deg == 90.0


def test_exponent_without_dot_gets_a_hint(params_dict):
    params_dict["train"]["models"]["polarnet"]["lr"] = "1e-3"  # what YAML 1.1 makes of `lr: 1e-3`
    with pytest.raises(ParamsError, match=r"train\.models\.polarnet\.lr: .*write e\.g\. 1\.0e-4"):
        parse_params(params_dict)


def test_momentum_only_with_sgd(params_dict):
    d = copy.deepcopy(params_dict)
    d["train"]["models"]["compact_1l"]["momentum"] = None  # null: the recipe drops the base's momentum
    with pytest.raises(ParamsError, match=r"train\.models\.compact_1l: .*momentum: required with optimizer 'sgd'"):
        parse_params(d)
    params_dict["train"]["models"]["polarnet"]["momentum"] = 0.9
    with pytest.raises(ParamsError, match=r"train\.models\.polarnet: .*momentum: not used by optimizer 'adam'"):
        parse_params(params_dict)


# ----------------------------------------------------------------------------- no hidden defaults
# The only fields with a default: optional sections/overrides whose absence means "not used"
# (no value hides behind them). Every setting, even one that cannot change a result (worker
# counts, the device), has its one default in params.yaml.
ABSENT_MEANS_UNUSED = {"ModelRecipe.momentum", "ModelRecipe.betas", "ModelRecipe.eps", "ModelRecipe.max_epochs",
                       "ModelRecipe.de_loss"}  # compact models only: train stops naming the key when absent


def _models(cls, seen=None):
    seen = {} if seen is None else seen
    if isinstance(cls, type) and issubclass(cls, BaseModel) and cls.__name__ not in seen:
        seen[cls.__name__] = cls
        for f in cls.model_fields.values():
            for arg in (f.annotation, *typing.get_args(f.annotation)):
                for inner in (arg, *typing.get_args(arg)):
                    _models(inner, seen)
    return seen


def test_every_results_changing_field_is_required():
    defaulted = {f"{name.split('[')[0]}.{fname}" for name, cls in _models(config.Params).items()
                 for fname, f in cls.model_fields.items() if not f.is_required()}
    assert defaulted == ABSENT_MEANS_UNUSED


def test_committed_params_spell_out_the_defaulted_settings(params_dict):
    assert params_dict["world"]["workers"] and params_dict["preprocess"]["workers"]
    assert "num_workers" in params_dict["train"] and "device" in params_dict["train"]


def test_missing_required_key_is_named(params_dict):
    """A key missing from the base recipe is named once, where it belongs (``train.recipe``), not
    once per model that inherits it; one a model removes (null) is named in that model."""
    del params_dict["train"]["recipe"]["weight_decay"]
    params_dict["train"]["models"]["polarnet"]["lr"] = None
    del params_dict["datasets"]["B"]["seed_offset"]
    with pytest.raises(ParamsError) as exc:
        parse_params(params_dict)
    msg = str(exc.value)
    assert msg.startswith("params.yaml: 3 invalid parameters: "), msg
    assert "train.recipe.weight_decay: Field required" in msg
    assert "train.models.polarnet.lr: Field required" in msg
    assert "datasets.B.seed_offset: Field required" in msg


def test_lr_floor_not_above_lr(params_dict):
    d = copy.deepcopy(params_dict)
    d["train"]["models"]["polarnet"]["lr_min"] = 0.01
    with pytest.raises(ParamsError, match=r"train\.models\.polarnet: .*lr_min \(0\.01\) must not exceed lr"):
        parse_params(d)
    params_dict["train"]["recipe"]["lr_min"] = 0.5  # above every inheriting SGD recipe's lr 0.1
    with pytest.raises(ParamsError, match=r"train\.models\.compact_1l: .*lr_min \(0\.5\) must not exceed lr"):
        parse_params(params_dict)


def test_optimizer_settings_belong_to_their_optimizer(params_dict):
    """Adam's betas/eps are required with adam and refused with sgd (no hidden torch defaults)."""
    from compact_perception.core.params import ParamsError, parse_params

    adam = params_dict["train"]["models"]["polarnet"]
    del adam["betas"]
    with pytest.raises(ParamsError, match="betas and eps: required"):
        parse_params(params_dict)
    adam["betas"] = [0.9, 0.999]
    params_dict["train"]["models"]["compact_1l"]["eps"] = 1e-8
    with pytest.raises(ParamsError, match="not used by optimizer 'sgd'"):
        parse_params(params_dict)


def _assert_rejected(params_dict, path, value, fragment):
    """Set ``path`` to ``value``; validation must fail with a message matching ``fragment``."""
    node = params_dict
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    with pytest.raises(ParamsError, match=fragment):
        parse_params(params_dict)


@pytest.mark.parametrize(
    "path, value, fragment",
    [
        (("dataset_ids",), ["A", "no_such_set"], r"dataset_ids: .*unknown dataset\(s\) \['no_such_set'\]"),
        (("sim_ids",), ["A", "A"], r"sim_ids: .*distinct ids"),
        (("model_ids",), ["compact_1l", "resnet"], r"model_ids: .*unknown model\(s\) \['resnet'\]"),
        (("model_ids",), ["compact_1l", "compact_1l"], r"model_ids: .*distinct ids"),
    ],
)
def test_run_lists_are_checked(params_dict, path, value, fragment):
    """The matrices' id lists (what dvc.yaml iterates over) fail with the key named."""
    _assert_rejected(params_dict, path, value, fragment)


def test_a_model_listed_without_a_recipe_is_named(params_dict):
    del params_dict["train"]["models"]["polarnet"]
    with pytest.raises(ParamsError, match=r"model_ids: no recipe train\.models\.<id> for \['polarnet'\]"):
        parse_params(params_dict)


def test_scale_is_resolved_once_when_params_load():
    """``Params`` resolves every per-scale value at its ``scale`` once, when it loads, with the one
    resolver (``resolve_scale``, which the record's settings use too); a copy that changes the
    scale resolves again."""
    from compact_perception.core.params.base import resolve_scale

    d = repo_params_dict()
    d["datasets"]["B"]["frames"] = {"default": 40, "full": 500, "paper": 10000}
    d["world"]["resolution"] = {"default": 32, "full": 64, "paper": 128}
    p = config.parse_params(d)
    assert (p.scale, p.resolution, p.frames_of("B")) == ("default", 32, 40)
    assert p._at_scale == resolve_scale(p.model_dump(mode="python"), "default")
    assert p.split_counts_of("B") == {"train": 12, "val": 8, "test": 20}      # 3:2:5 of 40, by hand
    full = p.model_copy(update={"scale": "full"})
    assert (full.resolution, full.frames_of("B")) == (64, 500)
    assert full.split_counts_of("B") == {"train": 300, "val": 50, "test": 150}  # 6:1:3 of 500
    assert full.seeds_of("compact", "A") == p.seeds_of("compact", "A", "full")
    assert resolve_scale({"a": [{"default": 1, "full": 2, "paper": 3}], "b": {"default": 0}}, "full") == \
        {"a": [2], "b": {"default": 0}}
