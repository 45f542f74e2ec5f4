"""The committed params.yaml as the tests' parameters: load it and override, never repeat values.

Every results-changing setting is required by the schema (core/params/), so a test that needs a
params object or one section of it starts from the repository's params.yaml:

    repo_params_dict()                                   # mutable dict of params.yaml
    section("preprocess", workers=1)                     # a validated PreprocessParams
    section("train.models.compact_1l", weighting="none") # a validated ModelRecipe
"""
from __future__ import annotations

import copy
from functools import lru_cache
from pathlib import Path
from typing import Any

import yaml

from compact_perception.core.params import Params, parse_params

ROOT = Path(__file__).resolve().parents[1]
PARAMS_YAML = ROOT / "params.yaml"


@lru_cache(maxsize=1)
def _committed() -> dict:
    with PARAMS_YAML.open() as fh:
        return yaml.safe_load(fh)


def repo_params_dict() -> dict:
    """A fresh, mutable copy of the committed params.yaml."""
    return copy.deepcopy(_committed())


def repo_params() -> Params:
    """The committed params.yaml, validated."""
    return parse_params(repo_params_dict(), str(PARAMS_YAML))


def section(path: str, **overrides: Any) -> Any:
    """The validated params section at dotted ``path`` with ``overrides`` applied (re-validated)."""
    obj: Any = repo_params()
    for key in path.split("."):
        obj = obj[key] if isinstance(obj, dict) else getattr(obj, key)
    return type(obj).model_validate({**obj.model_dump(), **overrides})


def scaled(value: Any) -> dict:
    """``{default: v, full: v, paper: v}``: a Scaled value equal at every scale."""
    from compact_perception.core.params import SCALES

    return {s: copy.deepcopy(value) for s in SCALES}


def cap_epochs(d: dict, epochs: int) -> dict:
    """Every run of params dict ``d`` capped at ``epochs``: each dataset's training cap and every
    recipe's own cap (the baselines'), at every scale. Returns ``d``."""
    for ds in d["datasets"].values():
        ds["training"]["max_epochs"] = scaled(epochs)
    for recipe in d["train"]["models"].values():
        if "max_epochs" in recipe:
            recipe["max_epochs"] = scaled(epochs)
    return d


def set_seeds(d: dict, seeds: list[int], baseline_seeds: list[int] | None = None) -> dict:
    """Every dataset's compact seeds (and the baselines') at every scale. Returns ``d``."""
    for ds in d["datasets"].values():
        ds["training"]["seeds"] = scaled(list(seeds))
    d["baseline_seeds"] = scaled(list(baseline_seeds if baseline_seeds is not None else seeds))
    return d


def docs_params_block(doc: str, contains: str) -> dict:
    """The first ```yaml block of ``docs/<doc>`` that contains ``contains``, parsed: a params
    snippet a page tells the user to write (the tests use it as written there)."""
    import re

    text = (ROOT / "docs" / doc).read_text()
    for block in re.findall(r"```yaml\n(.*?)```", text, flags=re.S):
        if contains in block:
            return yaml.safe_load(block)
    raise AssertionError(f"docs/{doc}: no yaml block with {contains!r}")


def carla_source(**changes: Any) -> dict:
    """``datasets.<ds>.source`` of a CARLA recording as docs/carla.md shows it, with ``changes``."""
    source = docs_params_block("carla.md", "id: carla")["datasets"]["A"]["source"]
    return {**source, **changes}
