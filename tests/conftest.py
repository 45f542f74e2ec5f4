"""Shared test fixtures. Tests never reach the network and keep DVC analytics off."""
from __future__ import annotations

import copy
import os
from pathlib import Path

import pytest
import yaml

os.environ["DVC_NO_ANALYTICS"] = "1"

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="session")
def root() -> Path:
    return ROOT


@pytest.fixture()
def params_dict() -> dict:
    """A fresh, mutable copy of the committed params.yaml."""
    with (ROOT / "params.yaml").open() as fh:
        return copy.deepcopy(yaml.safe_load(fh))
