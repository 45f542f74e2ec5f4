"""Params files of an earlier commit (core/params/former.py): a run recorded at ``scale: full``
is re-created at its own commit, whose params.yaml may be in a layout since replaced. The former
layouts below are written as those commits wrote them (each set carried ``source: <id>``,
``authors_root``, ``authors_splits`` and a ``carla`` section; ``evaluate.batch_size`` did not
exist), not produced by the code under test."""
from __future__ import annotations

import copy
from pathlib import Path

import pytest
import yaml

from compact_perception.core.params import ParamsError, load_params, parse_params
from compact_perception.core.params.former import upgrade_params
from compact_perception.core.plateau_record import changed_keys
from repo_params import carla_source, repo_params_dict

# As the commits before the source section wrote set B (its CARLA keys as docs/carla.md gives them).
FORMER_B = """
source: {source}
authors_root: {root}
authors_splits: {{train: Tr2, val: Va1, test: Te1}}
carla:
  root: data/carla/B
  host: 127.0.0.1
  port: 2000
  timeout_s: 10.0
  load_world_timeout_s: 120.0
  fixed_delta_s: 0.05
  frames_per_episode: 10
  warmup_ticks: 40
  vehicles: 30
  pedestrians: 30
  times: [morning, noon, evening, night]
  weathers: [sunny, cloudy, rainy, foggy]
"""


def _former(source: str = "sim", root: str = "null") -> dict:
    """Today's params.yaml with every set's source written in the former layout and no
    ``evaluate.batch_size``."""
    data = repo_params_dict()
    for ds, section in data["datasets"].items():
        if isinstance(section, dict) and "source" in section:
            section.pop("source")
            section.update(yaml.safe_load(FORMER_B.format(source=source if ds == "B" else "sim", root=root)))
    del data["evaluate"]["batch_size"]
    return data


def test_a_former_file_is_refused_as_written_and_read_as_todays_when_asked(tmp_path: Path) -> None:
    data = _former()
    with pytest.raises(ParamsError, match=r"datasets\.A\.source: expected a section"):
        parse_params(copy.deepcopy(data))
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    with pytest.raises(ParamsError):
        load_params(path)
    today = parse_params(repo_params_dict())
    assert today.evaluate.batch_size == 1  # the value evaluation had before the key; else the next line cannot hold
    assert load_params(path, former=True).model_dump() == today.model_dump()


def test_the_former_source_keys_become_the_section_of_the_source_used() -> None:
    up, changes = upgrade_params(_former("authors", "/data/release/dataset"))
    assert up["datasets"]["B"]["source"] == {"id": "authors", "root": "/data/release/dataset",
                                              "splits": {"train": "Tr2", "val": "Va1", "test": "Te1"}}
    assert "datasets.B.source: 'authors' -> {id: authors, ...} (dropped carla)" in changes
    assert "evaluate.batch_size: absent -> 1 (what the code did before the key)" in changes
    assert parse_params(up).dataset("B").source.root == "/data/release/dataset"

    up, _ = upgrade_params(_former("carla"))
    assert up["datasets"]["B"]["source"] == carla_source(root="data/carla/B")
    assert up["datasets"]["A"]["source"] == {"id": "sim"}
    parse_params(up)


def test_a_former_file_missing_what_its_source_needs_is_refused_naming_the_key() -> None:
    up, _ = upgrade_params(_former("authors", "null"))
    with pytest.raises(ParamsError, match=r"datasets\.B\.source\.root"):
        parse_params(up)


def test_todays_file_and_what_is_not_a_params_document_are_left_as_they_are() -> None:
    today = repo_params_dict()
    assert upgrade_params(today) == (today, [])
    for odd in (None, [], "text", {"datasets": [1]}, {"datasets": {"A": "sim"}}, {"evaluate": 3}):
        assert upgrade_params(odd) == (odd, [])


def test_a_setting_recorded_under_its_former_name_is_compared_under_todays() -> None:
    assert changed_keys({"datasets.B.source": "sim"}, {"datasets.B.source.id": "sim"}, "cpu") == []
    assert changed_keys({"datasets.B.source": "sim"}, {"datasets.B.source.id": "authors"}, "cpu") == [
        "datasets.B.source.id"]
    assert changed_keys({}, {"evaluate.batch_size": 1}, "cpu") == []
    assert changed_keys({}, {"evaluate.batch_size": 8}, "cpu") == ["evaluate.batch_size"]
