"""Shared test fixtures. Tests never reach the network and keep DVC analytics off."""
from __future__ import annotations

import copy
import os
from pathlib import Path

import pytest
import yaml

os.environ["DVC_NO_ANALYTICS"] = "1"

ROOT = Path(__file__).resolve().parents[1]
# Collected first: under `pytest -n 2` (make test) one worker starts the tiny end-to-end pipeline,
# the longest module, at once while the other runs the rest (a stable sort keeps every other order).
FIRST_MODULES = ("test_pipeline_e2e.py",)


def pytest_collection_modifyitems(config, items):
    items.sort(key=lambda item: item.path.name not in FIRST_MODULES)


@pytest.fixture(scope="session")
def root() -> Path:
    return ROOT


@pytest.fixture()
def params_dict() -> dict:
    """A fresh, mutable copy of the committed params.yaml."""
    with (ROOT / "params.yaml").open() as fh:
        return copy.deepcopy(yaml.safe_load(fh))
