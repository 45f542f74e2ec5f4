"""The training stage on tiny synthetic caches: resume, DDP equivalence, outputs."""
from __future__ import annotations

import json
import os
import socket
import subprocess
import sys

import pytest
import torch

from compact_perception.core.params import parse_params
from compact_perception.learning.schedule import EarlyStop, Plateau
from compact_perception.learning.training.train import selection_score, train_run

from repo_params import cap_epochs
from run_fixture import run_in
from synthetic import make_cache


def tiny_params(params_dict: dict, epochs: int = 3, batch: int = 2) -> object:
    cap_epochs(params_dict, epochs)
    params_dict["train"]["batch_size"] = batch
    params_dict["train"]["num_workers"] = 0
    params_dict["train"]["device"] = "cpu"
    for recipe in params_dict["train"]["models"].values():
        recipe.pop("max_epochs", None)
    return parse_params(params_dict)


def test_plateau_halves_after_patience_and_respects_min():
    p = Plateau(patience=4, factor=0.5, lr_min=0.02, rule="paper", threshold=1e-4)
    lr = 0.1
    assert p.step(1.0, lr) == (True, 0.1)
    for _ in range(3):
        improved, lr = p.step(1.0, lr)
        assert not improved and lr == 0.1
    _, lr = p.step(1.0, lr)          # 4th epoch without a drop: halve
    assert lr == 0.05
    for _ in range(8):
        _, lr = p.step(2.0, lr)
    assert lr == 0.02                 # clamped at lr_min


@pytest.mark.parametrize("scores", [
    [1.0] * 14,                                                  # never improves after epoch 1
    [1.0, 0.9, 0.95, 0.95, 0.95, 0.95, 0.95, 0.8, 0.8, 0.8],     # one halving, then a drop
    [1.0, 0.99995, 0.9999, 0.99989, 0.5, 0.50001, 0.49999] * 2,  # drops below the 1e-4 threshold
])
def test_torch_plateau_rule_is_reduce_lr_on_plateau(scores):
    """The 'torch' rule against PyTorch's own ReduceLROnPlateau (the authors' scheduler) with
    patience 4, factor 0.5, threshold 1e-4 (rel), min_lr 1e-5: the same lr after every epoch."""
    opt = torch.optim.SGD([torch.nn.Parameter(torch.zeros(1))], lr=0.1)
    ref = torch.optim.lr_scheduler.ReduceLROnPlateau(opt, mode="min", factor=0.5, patience=4, threshold=1e-4,
                                                     threshold_mode="rel", min_lr=1e-5)
    p = Plateau(patience=4, factor=0.5, lr_min=1e-5, rule="torch", threshold=1e-4)
    lr = 0.1
    for score in scores:
        ref.step(score)
        _, lr = p.step(score, lr)
        assert lr == pytest.approx(opt.param_groups[0]["lr"], rel=0, abs=1e-15)


def test_torch_rule_halves_after_the_fifth_bad_epoch_paper_rule_after_the_fourth():
    for rule, first_halving in (("paper", 5), ("torch", 6)):   # epoch 1 sets the best
        p, lr = Plateau(patience=4, factor=0.5, lr_min=1e-5, rule=rule, threshold=1e-4), 0.1
        lrs = []
        for _ in range(7):
            _, lr = p.step(1.0, lr)
            lrs.append(lr)
        assert lrs.index(0.05) + 1 == first_halving, rule


def test_smooth_l1_de_loss_is_torch_smooth_l1_with_beta_half():
    """``de_loss: smooth_l1`` = torch's smooth_l1_loss(beta=0.5) (the authors' DE loss) = 2 x eq. (2)."""
    from compact_perception.learning.losses import de_loss_factor, huber_loss, scale_de_loss

    g = torch.Generator().manual_seed(0)
    pred, target = torch.rand(2, 4, 1, 8, 8, generator=g) * 2, torch.rand(2, 4, 1, 8, 8, generator=g)
    ours = scale_de_loss({"de": huber_loss(pred, target, delta=0.5)}, de_loss_factor("smooth_l1"))["de"]
    ref = torch.nn.functional.smooth_l1_loss(pred, target, beta=0.5)
    assert float(ours) == pytest.approx(float(ref), rel=1e-6)
    assert de_loss_factor("huber") == 1.0 and de_loss_factor("smooth_l1") == 2.0
    # eq. (2) by hand at two points: |d| = 0.2 < delta -> 0.5 d^2; |d| = 1.0 -> delta (|d| - delta / 2)
    assert float(huber_loss(torch.tensor([0.2]), torch.tensor([0.0]))) == pytest.approx(0.02)
    assert float(huber_loss(torch.tensor([1.0]), torch.tensor([0.0]))) == pytest.approx(0.375)


def test_early_stop_after_patience():
    s = EarlyStop(patience=3)
    assert [s.step(v) for v in (1.0, 0.5, 0.6, 0.7, 0.8)] == [False, False, False, False, True]


def test_early_stop_at_its_edges():
    """An equal score is no improvement; a new best on the last allowed epoch resets the count;
    patience 1 stops at the first epoch without a new best; the state survives a round trip."""
    s = EarlyStop(patience=2)
    assert [s.step(v) for v in (1.0, 1.0, 1.0)] == [False, False, True]          # equal twice: stop
    s = EarlyStop(patience=2)
    assert [s.step(v) for v in (1.0, 1.1, 0.9, 1.2, 1.3)] == [False, False, False, False, True]
    s = EarlyStop(patience=1)
    assert [s.step(v) for v in (2.0, 1.0, 1.0)] == [False, False, True]
    s, t = EarlyStop(patience=3), EarlyStop(patience=3)
    for v in (1.0, 0.8, 0.9):
        s.step(v)
    t.load_state_dict(s.state_dict())
    assert [t.step(v) for v in (0.85, 0.95)] == [False, True] and t.since_best == 3


def _scripted_validation(monkeypatch, scores):
    """Validation returns TM = ``scores[i]`` at its i-th call (the first is the untrained net's)."""
    from compact_perception.learning.training import train as train_mod

    calls = iter(scores)

    def validate(run):
        tm = next(calls)
        return {"mae_de": tm - 3.0, "iou_ss": 0.0, "iou_ls": 0.0, "iou_bevp": 0.0}  # TM = mae + 3

    monkeypatch.setattr(train_mod, "validate", validate)


@pytest.mark.parametrize("scores, epochs_run, best_epoch, reason", [
    # untrained 9; best at epoch 1 (2.0); epochs 2, 3, 4 bring none: patience 3 stops after epoch 4
    ((9.0, 3.0, 2.0, 2.5, 2.0, 2.7, 1.0), 5, 1, "plateau"),
    # always improving: the cap (6 epochs) ends it
    ((9.0, 6.0, 5.0, 4.0, 3.5, 3.2, 3.1), 6, 5, "max_epochs"),
    # a new best on the last allowed epoch (4) resets the count; the cap ends it at 6
    ((9.0, 3.0, 2.0, 2.5, 2.6, 1.9, 2.0), 6, 4, "max_epochs"),
])
def test_a_run_stops_when_validation_stops_improving(tmp_path, params_dict, monkeypatch, scores, epochs_run,
                                                     best_epoch, reason):
    """summary.json records how long the run trained, its best epoch and why it stopped: early
    stopping (``plateau``, after ``train.early_stop_patience`` epochs without a new best; an equal
    score is none) or the cap (``max_epochs``)."""
    params_dict["train"]["early_stop_patience"] = {"default": 3, "full": 3, "paper": 3}
    params = tiny_params(params_dict, epochs=6)
    _scripted_validation(monkeypatch, scores)
    run = run_in(params, "compact_1l", make_cache(tmp_path / "cache", size=16), tmp_path / "run", export_onnx=False)
    summary = train_run(params, run)
    assert (summary["epochs_run"], summary["best_epoch"], summary["stop_reason"]) == (epochs_run, best_epoch, reason)
    assert summary["max_epochs"] == 6
    assert torch.load(tmp_path / "run" / "best.pt", weights_only=True)["epoch"] == best_epoch


def test_selection_score_is_tm_for_four_tasks():
    m = {"mae_de": 0.1, "iou_ss": 0.5, "iou_ls": 0.6, "iou_bevp": 0.7}
    assert selection_score(m) == pytest.approx(0.1 + 0.5 + 0.4 + 0.3)
    assert selection_score({"iou_ls": 0.75}) == pytest.approx(0.25)


@pytest.mark.slow
def test_interrupted_run_resumes_to_the_same_result(tmp_path, params_dict):
    params = tiny_params(params_dict, epochs=3)
    cache = make_cache(tmp_path / "cache")
    full = train_run(params, run_in(params, "compact_15l_mgn", cache, tmp_path / "full"))
    with pytest.raises(InterruptedError):
        train_run(params, run_in(params, "compact_15l_mgn", cache, tmp_path / "cut"), stop_after_epochs=1)
    assert not (tmp_path / "cut" / "summary.json").exists()
    assert torch.load(tmp_path / "cut" / "last.pt", weights_only=True)["epoch"] == 0
    resumed = train_run(params, run_in(params, "compact_15l_mgn", cache, tmp_path / "cut"))
    assert resumed["epochs_run"] == full["epochs_run"] == 3
    assert resumed["untrained_val_score"] == pytest.approx(full["untrained_val_score"], abs=1e-9)
    assert 0.0 < full["untrained_val_score"] < 4.0  # TM of the Kaiming-initialised network, recorded once
    assert resumed["best_val_score"] == pytest.approx(full["best_val_score"], abs=1e-6)
    assert resumed["final_weights"] == pytest.approx(full["final_weights"], abs=1e-6)
    # every epoch logged once, in order, for every task loss, metric, lr and weight
    tsv = (tmp_path / "cut" / "live" / "plots" / "metrics" / "w_bevp.tsv").read_text().splitlines()
    assert [line.split("\t")[0] for line in tsv[1:]] == ["0", "1", "2"]
    for name in ("train/loss_de", "train/loss_bevp", "val/iou_ss", "val/mae_de", "lr", "w_de"):
        assert (tmp_path / "cut" / "live" / "plots" / "metrics" / f"{name}.tsv").is_file(), name
    # a completed run with the same configuration is not retrained
    again = train_run(params, run_in(params, "compact_15l_mgn", cache, tmp_path / "cut"))
    assert again["train_seconds"] == resumed["train_seconds"]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.mark.slow
def test_two_process_gloo_matches_one_process(tmp_path, params_dict, root):
    """Same global batch (4): 1 process x 4 vs 2 processes x 2 under torchrun (gloo), with MGN.

    BatchNorm statistics are per process (as with DDP), so the runs agree within a
    tolerance rather than exactly: validation scores within 5 % relative after 2 epochs.
    """
    import yaml

    cap_epochs(params_dict, 2)
    params_dict["train"]["batch_size"] = 4
    params_dict["train"]["num_workers"] = 0
    params_dict["train"]["device"] = "cpu"
    (tmp_path / "params.yaml").write_text(yaml.safe_dump(params_dict))
    cache = make_cache(tmp_path / "cache", counts=(8, 4, 2))
    env = {**os.environ, "PYTHONPATH": str(root), "OMP_NUM_THREADS": "1"}
    common = ["-m", "pipeline.train", "--dataset", "A", "--model", "compact_15l_mgn", "--seed", "0",
              "--params", str(tmp_path / "params.yaml"), "--cache", str(cache)]
    subprocess.run([sys.executable, *common, "--out", str(tmp_path / "one")], check=True, env=env, cwd=root)
    subprocess.run([sys.executable, "-m", "torch.distributed.run", "--nnodes=1", "--nproc_per_node=2",
                    f"--master_port={_free_port()}", *common, "--out", str(tmp_path / "two")],
                   check=True, env=env, cwd=root)
    one = json.loads((tmp_path / "one" / "summary.json").read_text())
    two = json.loads((tmp_path / "two" / "summary.json").read_text())
    assert two["world_size"] == 2 and one["world_size"] == 1
    assert two["epochs_run"] == one["epochs_run"] == 2
    assert two["best_val_score"] == pytest.approx(one["best_val_score"], rel=0.05)
    # MGN weights are averaged across ranks after every update: one set, summing to T = 4
    assert sum(two["final_weights"].values()) == pytest.approx(4.0)
    assert two["final_weights"] == pytest.approx(one["final_weights"], rel=0.05)


def test_single_task_arm_trains_and_scores_a_one_task_network(tmp_path, params_dict):
    """A study arm with ``single`` weighting trains the network built for its task alone (the
    checkpoint says which), and the test scores are that task's only."""
    from compact_perception.evaluation.evaluate import evaluate_run
    from compact_perception.learning.weighting import network_tasks

    params = tiny_params(params_dict, epochs=1)
    recipe = params.study_recipe("single_ls")
    assert network_tasks(recipe, ("de", "ss", "ls", "bevp")) == ("ls",)
    assert network_tasks(params.study_recipe("uw"), ("de", "ss", "ls", "bevp")) == ("de", "ss", "ls", "bevp")
    cache = make_cache(tmp_path / "cache")
    run = tmp_path / "run"
    planned = run_in(params, "compact_15l", cache, run, arm="single_ls")
    assert planned.recipe == recipe and planned.recipe_key == "study.arms.single_ls" and not planned.export_onnx
    summary = train_run(params, planned)
    best = torch.load(run / "best.pt", weights_only=True)
    assert best["tasks"] == ["ls"] and not any(k.startswith(("dec_de", "dec_bevp", "enc_ss")) for k in best["model"])
    assert summary["final_weights"] == {"w_ls": 1.0}
    assert not (run / "model.onnx").exists()
    result = evaluate_run(params, planned)
    assert "iou_ls" in result and not {"mae_de", "iou_ss", "iou_bevp", "tm"} & set(result)
    assert result == json.loads(planned.paths.metrics_path.read_text())
