"""The benchmark stage times the models of ``model_ids`` only, as every other stage runs them
(issue 56, item 10), with efficiency.json's keys as the committed file has them; the report
reads a Table III that lacks some models (``n/a`` rows, the efficiency claims not decidable)."""
from __future__ import annotations

import csv
import json
from pathlib import Path

import pytest
import yaml

from compact_perception.core.catalog import model_ids
from report_fixture import MODELS, SEEDS, build_tree, seed_map

ROOT = Path(__file__).resolve().parents[1]
#: The committed efficiency.json (all seven models at the default): its keys, datasets and models.
COMMITTED = json.loads((ROOT / "results" / "benchmark" / "efficiency.json").read_text())
KEYS = list(COMMITTED)


@pytest.fixture()
def timed(monkeypatch) -> list[tuple[str, str]]:
    """The stage's measurements stubbed: (dataset, model) of each network it would time."""
    import pipeline.benchmark as bench

    seen: list[tuple[str, str]] = []
    monkeypatch.setattr(bench, "build_model", lambda m, ds: seen.append((ds, m)) or object())
    monkeypatch.setattr(bench, "dummy_batch", lambda model, **kw: {})
    monkeypatch.setattr(bench, "measure_model", lambda model, batch, device, warmup, runs: {"fps": 1.0, "latency_ms": 1.0})
    monkeypatch.setattr(bench, "measure_onnx", lambda *a, **kw: {"onnx_fps": 2.0})
    return seen


def _run(tmp_path, params_dict, selected=None, *extra: str) -> dict:
    from pipeline.benchmark import main

    if selected is not None:
        params_dict["model_ids"] = selected
    params_dict["train"]["device"] = "cpu"
    params = tmp_path / "params.yaml"
    params.write_text(yaml.safe_dump(params_dict))
    out = tmp_path / "efficiency.json"
    main(["--params", str(params), "--out", str(out), *extra])
    return json.loads(out.read_text())


def test_the_benchmark_times_the_selected_models_only(tmp_path, params_dict, timed):
    got = _run(tmp_path, params_dict, ["chen_bev", "compact_1l"])
    assert list(got) == KEYS
    assert {ds: list(m) for ds, m in got["models"].items()} == {"A": ["chen_bev", "compact_1l"],
                                                                "nuscenes": ["chen_bev", "compact_1l"]}
    assert timed == [("A", "compact_1l"), ("A", "chen_bev"), ("nuscenes", "compact_1l"), ("nuscenes", "chen_bev")]


def test_at_the_default_every_model_as_the_committed_file_has_them(tmp_path, params_dict, timed):
    got = _run(tmp_path, params_dict)
    assert list(got) == KEYS
    assert {ds: list(m) for ds, m in got["models"].items()} == {ds: list(m) for ds, m in COMMITTED["models"].items()}
    assert [m for ds, m in timed if ds == "A"] == list(model_ids()) == params_dict["model_ids"]  # as before
    timed.clear()
    assert list(_run(tmp_path, params_dict, None, "--models", "polarnet", "--datasets", "A")["models"]["A"]) == \
        ["polarnet"]


def test_the_stage_declares_model_ids():
    stage = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]["benchmark"]
    assert "model_ids" in stage["params"]


def test_the_report_reads_a_table_iii_without_some_models(tmp_path):
    """Set A's compact models and one baseline benchmarked: the combination's row and the rows of
    what was not benchmarked say n/a, the efficiency claims are not decidable, and the report builds."""
    from compact_perception.report.index import build_reports

    chosen = ["compact_1l", "compact_15l", "polarnet"]
    build_tree(tmp_path, ("A",), efficiency=True, models=[m for m in MODELS if m in chosen])
    build_reports(tmp_path, tmp_path / "reports", datasets=("A",), models=chosen, scale_name="default",
                  seeds=seed_map(SEEDS, SEEDS))
    rows = {r["row_id"]: r for r in csv.DictReader((tmp_path / "reports/tables/table3.csv").open())}
    assert rows["compact_1l"]["params"] and rows["polarnet"]["params"]
    assert not rows["combination"]["params"] and not rows["chen_bev"]["params"]
    claims = [r for r in csv.DictReader((tmp_path / "reports/tables/claims.csv").open())
              if r["claim"].startswith("efficiency/")]
    assert len(claims) == 4 and {r["verdict"] for r in claims} == {"not decidable"}
    assert all("no benchmark of 15L+MGN or of all three baselines" in r["note"] for r in claims), claims
