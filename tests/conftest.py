"""Shared test fixtures. Tests never reach the network and keep DVC analytics off."""
from __future__ import annotations

import copy
import os
from pathlib import Path

import pytest
import yaml

os.environ["DVC_NO_ANALYTICS"] = "1"

# The test process computes as the stages do: the same numeric pins (compact_perception.core.determinism),
# set before any test imports numpy or runs a tensor op. Without them a run trained in the test process
# (MKL, OpenBLAS, oneDNN on the machine's own code paths) and one trained by a stage in a subprocess (pinned)
# differ in the last bits, and whether the pins were set depended on which test module imported `pipeline` first.
from compact_perception.core.determinism import pin_numeric_libraries  # noqa: E402

pin_numeric_libraries()

ROOT = Path(__file__).resolve().parents[1]
# Collected first: under `pytest -n 2` (make test) one worker starts the tiny end-to-end pipeline,
# the longest module, at once and the other the DVC-remote runs, the second longest, before the
# rest (a stable sort keeps every other order).
FIRST_MODULES = ("test_pipeline_e2e.py", "test_remote.py")


def pytest_collection_modifyitems(config, items):
    items.sort(key=lambda item: FIRST_MODULES.index(item.path.name) if item.path.name in FIRST_MODULES
               else len(FIRST_MODULES))


@pytest.fixture(scope="session")
def root() -> Path:
    return ROOT


@pytest.fixture()
def params_dict() -> dict:
    """A fresh, mutable copy of the committed params.yaml."""
    with (ROOT / "params.yaml").open() as fh:
        return copy.deepcopy(yaml.safe_load(fh))


@pytest.fixture()
def stand_in_pinning(monkeypatch) -> set:
    """The CPU build cannot pin memory: a stand-in accelerator and ``Tensor.pin_memory`` (a pinned
    copy, its ``id`` kept in the returned set), so a test sees what a pinning loader pins."""
    import torch

    pinned: set[int] = set()

    def pin(self, *_a, **_k):
        out = self.clone()
        pinned.add(id(out))
        return out

    monkeypatch.setattr(torch.Tensor, "pin_memory", pin)
    monkeypatch.setattr(torch.accelerator, "is_available", lambda: True)
    monkeypatch.setattr(torch.accelerator, "current_accelerator", lambda *a, **k: torch.device("cpu"))
    return pinned
