"""Loss weighting: static, MGN (Algorithm 1, eq. 8-15) checked by hand in numpy, GradNorm."""
from __future__ import annotations

import copy

import numpy as np
import pytest
import torch
from torch import nn

from compact_perception.learning.weighting import (
    WEIGHTINGS,
    GradNormWeighting,
    MGNWeighting,
    NoWeighting,
    StaticWeighting,
    build_weighting,
)

from repo_params import section

D = torch.float64
TASKS = ("de", "ss", "ls", "bevp")
# Algorithm 1's settings (section IV-D: alpha 1.5, weight lr 0.1 halved on plateau down to 1e-4)
PLATEAU = {"plateau_patience": 4, "plateau_factor": 0.5, "plateau_rule": "paper"}
MGN_ARGS = {"alpha": 1.5, "lr": 0.1, "lr_min": 1e-4, **PLATEAU}


def make_mgn(model: nn.Module, **kw) -> MGNWeighting:
    """MGN on ``model``'s shared layers with Algorithm 1's settings, ``kw`` overriding them."""
    return MGNWeighting(TASKS, model.shared_layers(), **{**MGN_ARGS, **kw})


class Tiny(nn.Module):
    """x -> shared1 -> tanh -> h1 -> shared2 -> tanh -> h2; heads de/ss/ls on h1, bevp on h2."""

    def __init__(self, seed: int = 0) -> None:
        super().__init__()
        torch.manual_seed(seed)
        self.shared1 = nn.Linear(3, 4).to(D)
        self.shared2 = nn.Linear(4, 4).to(D)
        self.heads = nn.ModuleDict({k: nn.Linear(4, 2).to(D) for k in TASKS})

    def shared_layers(self) -> dict[str, list[str]]:
        return {"de": ["shared1"], "ss": ["shared1"], "ls": ["shared1"], "bevp": ["shared2"]}

    def forward(self, x: torch.Tensor) -> dict[str, torch.Tensor]:
        h1 = torch.tanh(self.shared1(x))
        h2 = torch.tanh(self.shared2(h1))
        return {k: self.heads[k](h2 if k == "bevp" else h1) for k in TASKS}


def make_batch(seed: int, scale: dict[str, float] | None = None) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(5, 3, generator=g, dtype=D)
    scale = scale or {}
    y = {k: torch.randn(5, 2, generator=g, dtype=D) * scale.get(k, 1.0) for k in TASKS}
    return x, y


def task_losses(model: Tiny, batch) -> dict[str, torch.Tensor]:
    x, y = batch
    out = model(x)
    return {k: ((out[k] - y[k]) ** 2).mean() for k in TASKS}


# ----------------------------------------------------------------------------- numpy reference
def np_losses_and_norms(model: Tiny, batch) -> tuple[np.ndarray, np.ndarray]:
    """Hand backprop of L_i = mean((y_i - t_i)^2) to W = shared1.weight (de/ss/ls), shared2.weight (bevp)."""
    x = batch[0].numpy()
    A1, b1 = model.shared1.weight.detach().numpy(), model.shared1.bias.detach().numpy()
    A2, b2 = model.shared2.weight.detach().numpy(), model.shared2.bias.detach().numpy()
    h1 = np.tanh(x @ A1.T + b1)
    h2 = np.tanh(h1 @ A2.T + b2)
    L, n = [], []
    for k in TASKS:
        Wk, bk = model.heads[k].weight.detach().numpy(), model.heads[k].bias.detach().numpy()
        h = h2 if k == "bevp" else h1
        yk = h @ Wk.T + bk
        r = yk - batch[1][k].numpy()
        L.append(np.mean(r ** 2))
        dy = 2 * r / r.size
        dh = dy @ Wk
        if k == "bevp":
            dpre2 = dh * (1 - h2 ** 2)
            dW = dpre2.T @ h1
        else:
            dpre1 = dh * (1 - h1 ** 2)
            dW = dpre1.T @ x
        n.append(np.sqrt(np.sum(dW ** 2)))
    return np.array(L), np.array(n)


def np_mgn_step(w, L0, L, n, alpha, lr, floor_ratio=1e-3):
    T = len(w)
    G = w * n  # eq. 9: ||grad_W (w_i L_i)|| = w_i ||grad_W L_i||
    G_avg = G.mean()  # eq. 10
    ratio = L / L0  # eq. 11
    r = ratio / ratio.mean()  # eq. 12
    target = G_avg * r ** alpha  # eq. 14 (constant)
    grad = -np.sign(target - G) * n  # d/dw_i sum_j |target_j - G_j|
    w_new = w - lr * grad
    w_new = np.maximum(w_new, floor_ratio * T)
    return w_new * T / w_new.sum(), dict(G=G, r=r, target=target, grad=grad)


# ----------------------------------------------------------------------------- MGN
def test_mgn_one_update_matches_hand_computation() -> None:
    model = Tiny()
    b0, b1 = make_batch(1), make_batch(2, {"ss": 3.0, "bevp": 0.2})
    mgn = make_mgn(model, alpha=1.5, lr=0.1)
    L0, _ = np_losses_and_norms(model, b0)
    mgn.before_backward(0, 2, task_losses(model, b0), model)
    mgn.after_backward()
    assert np.allclose(mgn.w.numpy(), 1.0)  # step 0 only records L_i(0)
    np.testing.assert_allclose(mgn.L0.numpy(), L0, atol=1e-12)
    L1, n1 = np_losses_and_norms(model, b1)
    mgn.before_backward(1, 2, task_losses(model, b1), model)
    mgn.after_backward()
    w_ref, ref = np_mgn_step(np.ones(4), L0, L1, n1, 1.5, 0.1)
    np.testing.assert_allclose(mgn.last["norms"].numpy(), n1, atol=1e-10)
    np.testing.assert_allclose(mgn.last["r"].numpy(), ref["r"], atol=1e-10)
    np.testing.assert_allclose(mgn.last["target"].numpy(), ref["target"], atol=1e-10)
    np.testing.assert_allclose(mgn.last["grad_w"].numpy(), ref["grad"], atol=1e-10)
    np.testing.assert_allclose(mgn.w.numpy(), w_ref, atol=1e-6)
    assert float(mgn.w.sum()) == pytest.approx(4.0, abs=1e-12)
    assert not np.allclose(w_ref, 1.0)  # the case is not trivial


def test_mgn_leaves_network_and_grads_untouched_and_graph_alive() -> None:
    model = Tiny()
    for p in model.parameters():
        p.grad = torch.full_like(p, 0.123)
    before = {k: (p.detach().clone(), p.grad.clone()) for k, p in model.named_parameters()}
    mgn = make_mgn(model)
    losses = task_losses(model, make_batch(3))
    mgn.before_backward(0, 1, losses, model)  # n_steps == 1: record and update on the same step
    mgn.after_backward()
    assert mgn.n_updates == 1
    for k, p in model.named_parameters():
        assert torch.equal(p, before[k][0]) and torch.equal(p.grad, before[k][1]), k
    mgn.total(losses).backward()  # forward graph kept (retain_graph)
    assert all(not torch.equal(p.grad, before[k][1]) for k, p in model.named_parameters())
    assert mgn.w.grad is None and not mgn.w.requires_grad


def test_mgn_sum_stays_T_over_epochs_and_total() -> None:
    model = Tiny()
    opt = torch.optim.SGD(model.parameters(), lr=0.05)
    mgn = make_mgn(model, lr=0.5)
    history = []
    for epoch in range(4):
        for step in range(3):
            losses = task_losses(model, make_batch(10 * epoch + step, {"ls": 4.0}))
            mgn.before_backward(step, 3, losses, model)
            mgn.after_backward()
            opt.zero_grad()
            mgn.total(losses).backward()
            opt.step()
        history.append(mgn.w.clone())
        assert float(mgn.w.sum()) == pytest.approx(4.0, abs=1e-12)
        assert bool((mgn.w > 0).all())
    assert mgn.n_updates == 4
    assert not torch.allclose(history[0], history[-1])
    # total: weighted tasks + aux with weight 1
    losses = {k: torch.tensor(1.0 + i, dtype=D) for i, k in enumerate(TASKS)}
    losses["aux_kl"] = torch.tensor(10.0, dtype=D)
    expected = sum(mgn.weights[k] * (1.0 + i) for i, k in enumerate(TASKS)) + 10.0
    assert float(mgn.total(losses)) == pytest.approx(expected)


def test_mgn_non_positive_weight_is_floored() -> None:
    model = Tiny()
    b0, b1 = make_batch(1), make_batch(2, {"ss": 3.0, "bevp": 0.2})
    mgn = make_mgn(model, lr=100.0)  # a huge step drives weights negative
    mgn.before_backward(0, 2, task_losses(model, b0), model)
    mgn.after_backward()
    L0, _ = np_losses_and_norms(model, b0)
    L1, n1 = np_losses_and_norms(model, b1)
    mgn.before_backward(1, 2, task_losses(model, b1), model)
    mgn.after_backward()
    raw = 1.0 - 100.0 * np_mgn_step(np.ones(4), L0, L1, n1, 1.5, 100.0)[1]["grad"]
    assert (raw <= 0).any()
    w_ref = np.maximum(raw, 4e-3)
    w_ref = w_ref * 4 / w_ref.sum()
    np.testing.assert_allclose(mgn.w.numpy(), w_ref, atol=1e-12)
    assert bool((mgn.w > 0).all()) and float(mgn.w.sum()) == pytest.approx(4.0)


def test_mgn_plateau_and_state_round_trip() -> None:
    mgn = make_mgn(Tiny(), lr=0.1, lr_min=0.03, plateau_patience=2)
    for improved, lr in [(False, 0.1), (False, 0.05), (True, 0.05), (False, 0.05), (False, 0.03), (False, 0.03), (False, 0.03)]:
        mgn.on_epoch_end(improved)
        assert mgn.lr == pytest.approx(lr)
    assert mgn.log_values()["lr_w"] == pytest.approx(0.03)

    model = Tiny()
    a = make_mgn(model, lr=0.3)
    a.before_backward(0, 2, task_losses(model, make_batch(1)), model)
    a.after_backward()
    a.before_backward(1, 2, task_losses(model, make_batch(2, {"ss": 2.0})), model)
    a.after_backward()
    a.on_epoch_end(False)
    a.before_backward(0, 2, task_losses(model, make_batch(5)), model)  # interrupted mid-epoch
    a.after_backward()
    b = make_mgn(model)
    b.load_state_dict(copy.deepcopy(a.state_dict()))
    assert b.state_dict() == a.state_dict()
    last = task_losses(model, make_batch(6, {"bevp": 3.0}))
    a.before_backward(1, 2, last, model)
    a.after_backward()
    b.before_backward(1, 2, last, model)
    b.after_backward()
    assert torch.equal(a.w, b.w) and a.log_values() == b.log_values()


def test_authors_mode_changes_network_grads() -> None:
    grads, last = {}, {}
    for mode in (False, True):
        model = Tiny()
        mgn = make_mgn(model, authors_mode=mode)
        b0, b1 = make_batch(1), make_batch(2, {"ss": 3.0, "bevp": 0.2})
        mgn.before_backward(0, 2, task_losses(model, b0), model)
        mgn.after_backward()
        losses = task_losses(model, b1)
        model.zero_grad()
        mgn.before_backward(1, 2, losses, model)
        if mode:  # second-order terms of L_MGN already reached the network
            assert any(p.grad is not None and bool(p.grad.abs().sum() > 0) for p in model.parameters())
        else:
            assert all(p.grad is None for p in model.parameters())
        mgn.total(losses).backward()
        mgn.after_backward()
        grads[mode] = torch.cat([p.grad.flatten() for p in model.parameters()])
        last[mode] = mgn.last
        assert float(mgn.w.sum()) == pytest.approx(4.0)
    assert not torch.allclose(grads[False], grads[True])
    # same G_i; w's gradient gains dL_total/dw_i = L_i
    torch.testing.assert_close(last[True]["G"], last[False]["G"], rtol=0, atol=1e-10)
    torch.testing.assert_close(last[True]["grad_w"], last[False]["grad_w"] + last[False]["L"], rtol=0, atol=1e-10)


def test_authors_mode_update_matches_hand_computation() -> None:
    """The authors' form (compact_15l_mgn_authors): w <- renorm(w - lr (dL_MGN/dw + L_i)) by hand."""
    model = Tiny()
    b0, b1 = make_batch(1), make_batch(2, {"ss": 3.0, "bevp": 0.2})
    mgn = make_mgn(model, alpha=1.5, lr=0.1, authors_mode=True)
    L0, _ = np_losses_and_norms(model, b0)
    mgn.before_backward(0, 2, task_losses(model, b0), model)
    mgn.after_backward()
    L1, n1 = np_losses_and_norms(model, b1)
    mgn.before_backward(1, 2, task_losses(model, b1), model)
    mgn.after_backward()
    _, ref = np_mgn_step(np.ones(4), L0, L1, n1, 1.5, 0.1)
    w_hand = np.maximum(1.0 - 0.1 * (ref["grad"] + L1), 1e-3 * 4)
    w_hand = w_hand * 4 / w_hand.sum()
    np.testing.assert_allclose(mgn.last["grad_w"].numpy(), ref["grad"] + L1, atol=1e-6)
    np.testing.assert_allclose(mgn.w.numpy(), w_hand, atol=1e-6)


@pytest.mark.parametrize("authors_mode", [False, True])
def test_the_updating_step_backpropagates_with_the_weights_it_started_with(authors_mode) -> None:
    """Issue 23 item 7, by hand: at an epoch's last step MGN computes w(t+1), but that step's
    network gradient is the one of sum_i w_i(t) L_i (Algorithm 1 and the authors' train.py: the
    total loss is backpropagated before w is updated); w(t+1) is in place after the step.
    Reference: w(t) = (0.5, 1.5, 1.0, 1.0), set before the epoch; the gradient of
    sum_i w_i(t) L_i taken by autograd on a copy of the network; w(t+1) by numpy (np_mgn_step);
    in the authors' form the second-order terms of L_MGN are added to the network's gradient
    before the total loss is, so the reference there is the default form's gradient plus them."""
    model = Tiny()
    w_t = torch.tensor([0.5, 1.5, 1.0, 1.0], dtype=D)
    b = make_batch(2, {"ss": 3.0, "bevp": 0.2})
    ref_model = copy.deepcopy(model)
    ref_losses = task_losses(ref_model, b)
    sum(w * ref_losses[k] for w, k in zip(w_t, TASKS)).backward()
    ref_grad = torch.cat([p.grad.flatten() for p in ref_model.parameters()])
    L, n = np_losses_and_norms(model, b)

    mgn = make_mgn(model, authors_mode=authors_mode)
    mgn.set_weights(w_t)
    losses = task_losses(model, b)
    mgn.before_backward(0, 1, losses, model)            # one step per epoch: L(0) = L, then the update
    second_order = [None if p.grad is None else p.grad.clone() for p in model.parameters()]
    assert torch.equal(mgn.w, w_t)                      # not yet taken
    mgn.backward(losses, model)
    mgn.after_backward()
    got = torch.cat([(p.grad - (0 if s is None else s)).flatten() for p, s in zip(model.parameters(), second_order)])
    torch.testing.assert_close(got, ref_grad, rtol=0, atol=1e-12)
    w_next, ref = np_mgn_step(w_t.numpy(), L, L, n, MGN_ARGS["alpha"], MGN_ARGS["lr"])
    if authors_mode:  # w's gradient also gets dL_total/dw_i = L_i
        w_next = np.maximum(w_t.numpy() - MGN_ARGS["lr"] * (ref["grad"] + L), 4e-3)
        w_next = w_next * 4 / w_next.sum()
    np.testing.assert_allclose(mgn.w.numpy(), w_next, atol=1e-9)
    assert not np.allclose(w_next, w_t.numpy())         # the update is not trivial


def test_gradnorm_backpropagates_each_step_with_the_weights_it_started_with() -> None:
    """Chen et al. (2018): each step's network update uses w(t); w(t+1) comes after it."""
    model = Tiny()
    gn = GradNormWeighting(TASKS, model.shared_layers(), alpha=1.5, lr=0.05, **PLATEAU)
    gn.set_weights(torch.tensor([0.5, 1.5, 1.0, 1.0], dtype=D))
    w_t = gn.w.clone()
    b = make_batch(4, {"ls": 4.0})
    ref_model = copy.deepcopy(model)
    ref_losses = task_losses(ref_model, b)
    sum(w * ref_losses[k] for w, k in zip(w_t, TASKS)).backward()
    losses = task_losses(model, b)
    gn.before_backward(0, 3, losses, model)
    assert torch.equal(gn.w, w_t)
    gn.backward(losses, model)
    gn.after_backward()
    for p, q in zip(model.parameters(), ref_model.parameters()):
        torch.testing.assert_close(p.grad, q.grad, rtol=0, atol=1e-12)
    assert not torch.equal(gn.w, w_t) and float(gn.w.sum()) == pytest.approx(4.0, abs=1e-12)


# ----------------------------------------------------------------------------- GradNorm
def test_gradnorm_updates_every_step_and_keeps_sum() -> None:
    model = Tiny()
    opt = torch.optim.SGD(model.parameters(), lr=0.05)
    gn = GradNormWeighting(TASKS, model.shared_layers(), alpha=1.5, lr=0.05, **PLATEAU)
    prev = gn.w.clone()
    first_L0 = None
    for epoch in range(2):
        for step in range(3):
            losses = task_losses(model, make_batch(10 * epoch + step, {"ls": 4.0}))
            gn.before_backward(step, 3, losses, model)
            opt.zero_grad()
            gn.total(losses).backward()       # the step's backward: with w(t)
            gn.after_backward()               # then w(t+1)
            if first_L0 is None:
                first_L0 = gn.L0.clone()
            assert torch.equal(gn.L0, first_L0)  # L_i(0) from the very first step only
            assert not torch.equal(gn.w, prev)
            prev = gn.w.clone()
            assert float(gn.w.sum()) == pytest.approx(4.0, abs=1e-12)
            opt.step()
        gn.on_epoch_end(False)
    assert gn.n_updates == 6 and gn.log_values()["lr_w"] == pytest.approx(0.05)
    gn2 = GradNormWeighting(TASKS, model.shared_layers(), alpha=1.5, lr=0.05, **PLATEAU)
    gn2.load_state_dict(copy.deepcopy(gn.state_dict()))
    losses = task_losses(model, make_batch(99))
    gn.before_backward(0, 3, losses, model)
    gn.after_backward()
    gn2.before_backward(0, 3, losses, model)
    gn2.after_backward()
    assert torch.equal(gn.w, gn2.w)


# ----------------------------------------------------------------------------- registry / factory
def test_registry_and_factory() -> None:
    assert {"cagrad", "dwa", "gradnorm", "mgn", "none", "pcgrad", "single", "static", "uw"} <= set(WEIGHTINGS.keys())
    model = Tiny()
    kinds = {
        "static": (section("train.models.compact_1l", weighting="static"), StaticWeighting),
        "none": (section("train.models.compact_1l", weighting="none"), NoWeighting),
        "mgn": (section("train.models.compact_15l_mgn"), MGNWeighting),
        "gradnorm": (section("train.models.gradnorm_segnet", lr=1e-3), GradNormWeighting),
    }
    for key, (recipe, cls) in kinds.items():
        w = build_weighting(recipe, TASKS, model, plateau_patience=3, plateau_factor=0.5)
        assert type(w) is cls and w.plateau_patience == 3
        assert w.log_values()["w_de"] == 1.0
        losses = task_losses(model, make_batch(0))
        w.before_backward(0, 1, losses, model)
        w.after_backward()
        assert float(w.w.sum()) == pytest.approx(4.0)
    assert build_weighting(kinds["mgn"][0], TASKS, model, plateau_patience=4, plateau_factor=0.5).lr == pytest.approx(0.1)
    with pytest.raises(KeyError):
        StaticWeighting(TASKS, plateau_patience=4, plateau_factor=0.5).total({"de": torch.tensor(1.0)})
