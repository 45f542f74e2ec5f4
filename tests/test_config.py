"""params.yaml schema: the committed file is valid; bad input names the key."""
from __future__ import annotations

import pytest

from compact_perception.config import ParamsError, load_params, parse_params


def test_committed_params_are_valid(root):
    p = load_params(root / "params.yaml")
    assert p.scale == "default"
    assert p.datasets.A.frames.at("paper") == 2000
    assert p.datasets.B.frames.at("paper") == 2000
    assert p.datasets.C.frames.at("paper") == 10000
    assert p.world.resolution.at("paper") == 128
    assert set(p.train.models) == {
        "compact_1l", "compact_15l", "compact_15l_mgn", "gradnorm_segnet", "polarnet", "chen_bev"
    }


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
    node = params_dict
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    with pytest.raises(ParamsError, match=fragment):
        parse_params(params_dict)


def test_unknown_model_id(params_dict):
    params_dict["train"]["models"]["resnet"] = {"optimizer": "sgd", "lr": 0.1}
    with pytest.raises(ParamsError, match=r"train\.models.*resnet"):
        parse_params(params_dict)


def test_missing_file(tmp_path):
    with pytest.raises(ParamsError, match="file not found"):
        load_params(tmp_path / "nope.yaml")
