"""What ``dvc exp run -S key=value`` writes, the stages read (issue 56, item 3).

DVC writes params.yaml through its own writer (``dvc.utils.hydra.apply_overrides``: Hydra's
override grammar, ruamel.yaml, YAML 1.2) and records in dvc.lock what ruamel reads back; the stages
read the file with PyYAML (YAML 1.1), where an unquoted ``off``, ``on``, ``yes`` or ``no`` is a
boolean. Every ``-S`` the docs show (README.md, docs/*.md, params.yaml's comments), and every enum
value of the schema that YAML 1.1 reads as something else, goes through DVC's writer on a copy of
params.yaml and is loaded by the project's loader: it must give the value DVC recorded.
"""
from __future__ import annotations

import re
import shlex
import shutil
import typing
from pathlib import Path
from typing import Any, Iterator

import pytest
import yaml
from pydantic import BaseModel

from compact_perception.core.params import ParamsError, load_params
from compact_perception.core.params.schema import Params

ROOT = Path(__file__).resolve().parents[1]
DOCS: tuple[Path, ...] = (ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")), ROOT / "params.yaml")
SET_PARAM = re.compile(r"(?:^|[\s`(])-S\s+('[^']*'|\"[^\"]*\"|[^\s`)]+)")
#: The enum values YAML 1.1 reads as booleans, each accepted as its key's value (core/params/schema.py).
BOOLEAN_WORDS = {("train.cuda_graphs", "off")}
#: Documented on purpose as what a stage refuses (docs/design.md: a typo'd new key).
REFUSED = {"+train.recipe.lrr=0.1": "train.recipe.lrr: unknown key"}


def documented_overrides() -> list[str]:
    """Every ``-S`` value README.md, docs/*.md and params.yaml's comments show, once each."""
    found: dict[str, None] = {}
    for doc in DOCS:
        for m in SET_PARAM.finditer(doc.read_text()):
            found[shlex.split(m[1])[0]] = None
    return list(found)


def set_params(tmp_path: Path, overrides: list[str]) -> Path:
    """A copy of params.yaml with ``overrides`` applied as ``dvc exp run -S`` applies them."""
    from dvc.utils.cli_parse import to_path_overrides
    from dvc.utils.hydra import apply_overrides

    path = tmp_path / "params.yaml"
    shutil.copy(ROOT / "params.yaml", path)
    grouped = to_path_overrides(overrides)
    assert list(grouped) == ["params.yaml"], grouped
    apply_overrides(path, grouped["params.yaml"])
    return path


def dvc_reads(path: Path) -> dict:
    """params.yaml as DVC reads it (what dvc.lock records)."""
    from dvc.utils.serialize import load_yaml

    return load_yaml(path)


def at(data: Any, key: str) -> Any:
    for part in key.lstrip("+").split("."):
        data = data[part]
    return data


def enum_values(model: type[BaseModel], prefix: str = "") -> Iterator[tuple[str, str]]:
    """(params key, value) for every enum (``Literal``) value of the schema under ``model``."""
    for name, field in model.model_fields.items():
        yield from _values(field.annotation, f"{prefix}{name}")


def _values(annotation: Any, key: str) -> Iterator[tuple[str, str]]:
    origin = typing.get_origin(annotation)
    if origin is typing.Literal:
        yield from ((key, v) for v in typing.get_args(annotation) if isinstance(v, str))
    elif isinstance(annotation, type) and issubclass(annotation, BaseModel):
        yield from enum_values(annotation, f"{key}.")
    elif origin is dict:
        yield from _values(typing.get_args(annotation)[1], f"{key}.<id>")
    else:
        for arg in typing.get_args(annotation):
            yield from _values(arg, key)


def test_the_docs_show_set_params_and_the_schema_names_its_boolean_words():
    shown = documented_overrides()
    assert {"scale=full", "train.recipe.lr=0.05", "+train.models.compact_1l.lr=0.05", "dataset_ids=[A]",
            "train.parallel_runs=auto"} <= set(shown), shown
    values = list(enum_values(Params))
    assert ("train.cuda_graphs", "auto") in values and ("train.device", "cuda") in values
    assert ("train.models.<id>.plateau_rule", "torch") in values  # a recipe's enums too
    misread = {(k, v) for k, v in values if yaml.safe_load(v) != v}
    assert misread == BOOLEAN_WORDS, "an enum value YAML 1.1 does not read as text: accept it in core/params/schema.py"


@pytest.mark.parametrize("override", documented_overrides())
def test_every_documented_set_param_loads_as_dvc_records_it(tmp_path, override):
    path = set_params(tmp_path, [override])
    if override in REFUSED:
        with pytest.raises(ParamsError, match=re.escape(REFUSED[override])):
            load_params(path)
        return
    key = override.split("=", 1)[0]
    loaded = load_params(path).model_dump(mode="json")
    assert at(loaded, key) == at(dvc_reads(path), key)


@pytest.mark.parametrize("key,value", sorted(BOOLEAN_WORDS) + [("train.cuda_graphs", "auto")])
def test_an_enum_word_yaml_reads_as_a_boolean_loads_as_the_word(tmp_path, key, value):
    """``dvc exp run -S train.cuda_graphs=off`` (docs/gpu.md: ``off`` steps eagerly) writes ``off``
    unquoted; the stages read the value DVC records, not a refusal of ``False``."""
    path = set_params(tmp_path, [f"{key}={value}"])
    assert re.search(rf"^\s+{key.rsplit('.', 1)[1]}: {value}\b", path.read_text(), re.M)  # unquoted
    assert at(dvc_reads(path), key) == value
    assert at(load_params(path).model_dump(mode="json"), key) == value


def test_a_yaml_true_is_still_refused_where_off_is_accepted(tmp_path):
    path = set_params(tmp_path, ["train.cuda_graphs=on"])
    with pytest.raises(ParamsError, match=r"train\.cuda_graphs: .*'auto'.*'off'.*\(got True\)"):
        load_params(path)
