"""The loss-balancing study's weightings (uw, dwa, pcgrad, cagrad) against hand computations.

The hand references use closed-form gradients of tiny linear networks (no call into the
implementation's helpers): with ``x = (1, 0)``, ``a = W x`` (column 0 of the shared 2x2 W) and
``o_i = h_i . a``, a loss ``L_i = f(o_i)`` has ``dL_i/dW[:, 0] = f'(o_i) h_i``, ``dL_i/dW[:, 1] = 0``
and ``dL_i/dh_i = f'(o_i) a`` (the heads are task-specific).
"""
from __future__ import annotations

import copy
import math

import numpy as np
import pytest
import torch
from pydantic import ValidationError
from torch import nn

from compact_perception.learning.weighting import (
    WEIGHTINGS,
    CAGradParams,
    CAGradWeighting,
    DWAParams,
    DWAWeighting,
    GradNormParams,
    GradNormWeighting,
    MgnParams,
    MGNWeighting,
    NoWeighting,
    PCGradParams,
    PCGradWeighting,
    StaticWeighting,
    UncertaintyWeighting,
    UWParams,
    build_weighting,
)

from repo_params import section

D = torch.float64
PLATEAU = {"plateau_patience": 3, "plateau_factor": 0.5}
TASKS4 = ("de", "ss", "ls", "bevp")


class Lin(nn.Module):
    """Shared W (2x2), one head h_i (1x2) per task; o_i = h_i W x."""

    def __init__(self, W: list[list[float]], heads: list[list[float]]) -> None:
        super().__init__()
        self.W = nn.Parameter(torch.tensor(W, dtype=D))
        self.heads = nn.ParameterList([nn.Parameter(torch.tensor(h, dtype=D)) for h in heads])
        self.x = torch.tensor([1.0, 0.0], dtype=D)

    def outputs(self) -> list[torch.Tensor]:
        a = self.W @ self.x
        return [h @ a for h in self.heads]


def linear_losses(model: Lin, tasks: tuple[str, ...]) -> dict[str, torch.Tensor]:
    """L_i = o_i: dL_i/dW[:, 0] = h_i, dL_i/dh_i = W[:, 0]."""
    return dict(zip(tasks, model.outputs()))


def square_losses(model: Lin, tasks: tuple[str, ...], y: list[float]) -> dict[str, torch.Tensor]:
    """L_i = (o_i - y_i)^2 / 2: dL_i/dW[:, 0] = (o_i - y_i) h_i, dL_i/dh_i = (o_i - y_i) W[:, 0]."""
    return {t: 0.5 * (o - yi) ** 2 for t, o, yi in zip(tasks, model.outputs(), y)}


def col0(v) -> np.ndarray:
    """The expected W gradient: ``v`` in column 0, zeros in column 1."""
    return np.stack([np.asarray(v, dtype=float), np.zeros(2)], axis=1)


def grads(model: nn.Module) -> list[torch.Tensor]:
    return [p.grad.detach().clone() for p in model.parameters()]


class Tiny(nn.Module):
    """Nonlinear 4-task net: shared1 reached by every task, shared2 by bevp only."""

    def __init__(self) -> None:
        super().__init__()
        g = torch.Generator().manual_seed(0)
        self.shared1 = nn.Linear(3, 4).to(D)
        self.shared2 = nn.Linear(4, 4).to(D)
        self.heads = nn.ModuleDict({k: nn.Linear(4, 2).to(D) for k in TASKS4})
        with torch.no_grad():
            for p in self.parameters():
                p.copy_(torch.randn(p.shape, generator=g, dtype=D))

    def forward(self, x: torch.Tensor) -> dict[str, torch.Tensor]:
        h1 = torch.tanh(self.shared1(x))
        h2 = torch.tanh(self.shared2(h1))
        return {k: self.heads[k](h2 if k == "bevp" else h1) for k in TASKS4}


def tiny_losses(model: Tiny, seed: int) -> dict[str, torch.Tensor]:
    g = torch.Generator().manual_seed(seed)
    x = torch.randn(5, 3, generator=g, dtype=D)
    out = model(x)
    return {k: ((out[k] - torch.randn(5, 2, generator=g, dtype=D)) ** 2).mean() for k in TASKS4}


def adam(s: np.ndarray, g: np.ndarray, m: np.ndarray, v: np.ndarray, t: int, lr: float):
    """Adam (Kingma & Ba), PyTorch's defaults: betas 0.9 / 0.999, eps 1e-8."""
    b1, b2, eps = 0.9, 0.999, 1e-8
    m = b1 * m + (1 - b1) * g
    v = b2 * v + (1 - b2) * g * g
    s = s - lr / (1 - b1 ** t) * m / (np.sqrt(v) / math.sqrt(1 - b2 ** t) + eps)
    return s, m, v


# ----------------------------------------------------------------------------- registry / schema
def test_registry_has_the_study_ids_and_builds_them() -> None:
    assert {"uw", "dwa", "pcgrad", "cagrad"} <= set(WEIGHTINGS.keys())
    sections = {"uw": ({"lr": 0.05}, UncertaintyWeighting), "dwa": ({"temperature": 2.0}, DWAWeighting),
                "pcgrad": ({"seed": 3}, PCGradWeighting), "cagrad": ({"c": 0.4}, CAGradWeighting)}
    for key, (params, cls) in sections.items():
        recipe = section("train.models.compact_15l", weighting=key, **{key: params})
        w = build_weighting(recipe, TASKS4, None, **PLATEAU)
        assert type(w) is cls and w.plateau_patience == 3
        assert w.log_values().keys() >= {f"w_{t}" for t in TASKS4}
    assert build_weighting(section("train.models.compact_15l", weighting="cagrad", cagrad={"c": 0.25}),
                           TASKS4, None, **PLATEAU).c == 0.25
    with pytest.raises(ValueError, match="'uw' section"):
        build_weighting(section("train.models.compact_15l", weighting="uw"), TASKS4, None, **PLATEAU)


def test_every_class_exposes_label_and_params_model() -> None:
    expected = {StaticWeighting: None, NoWeighting: None, MGNWeighting: MgnParams,
                GradNormWeighting: GradNormParams, UncertaintyWeighting: UWParams, DWAWeighting: DWAParams,
                PCGradWeighting: PCGradParams, CAGradWeighting: CAGradParams}
    for cls, schema in expected.items():
        assert isinstance(cls.label, str) and cls.label, cls
        assert cls.params_model is schema, cls
    labels = [cls.label for cls in expected]
    assert len(set(labels)) == len(labels)


@pytest.mark.parametrize("schema,good,bad", [
    (UWParams, {"lr": 0.025}, [{"lr": 0.0}, {"lr": "0.1"}, {}, {"lr": 0.1, "x": 1}]),
    (DWAParams, {"temperature": 2}, [{"temperature": 0.0}, {"temperature": True}, {}]),
    (PCGradParams, {"seed": 0}, [{"seed": -1}, {"seed": 1.0}, {"seed": True}, {}]),
    (CAGradParams, {"c": 0.4}, [{"c": -0.1}, {"c": "0.4"}, {}]),
])
def test_params_schemas(schema, good, bad) -> None:
    schema.model_validate(good)
    for b in bad:
        with pytest.raises(ValidationError):
            schema.model_validate(b)


@pytest.mark.parametrize("where, value, message", [
    (("study", "arms", "uw", "uw", "lr"), "fast",
     "params.yaml: study.arms.uw.uw.lr: Input should be a valid number (got 'fast')"),
    (("study", "arms", "uw", "uw"), {}, "params.yaml: study.arms.uw.uw.lr: Field required"),
    (("train", "models", "compact_15l_mgn", "mgn", "lr_min"), 0.5,
     "params.yaml: train.models.compact_15l_mgn.mgn: Value error, lr_min (0.5) must not exceed lr (0.1)"),
    (("train", "models", "gradnorm_segnet", "gradnorm", "beta"), 1.0,
     "params.yaml: train.models.gradnorm_segnet.gradnorm.beta: unknown key (not in the schema)"),
    (("train", "models", "polarnet", "none"), {"x": 1},
     "params.yaml: train.models.polarnet.none: weighting 'none' takes no settings; remove the key"),
    (("train", "models", "polarnet", "weighting"), "unknown",
     "params.yaml: train.models.polarnet.weighting: unknown loss weighting 'unknown'; known: "),
])
def test_weighting_settings_are_checked_by_their_method_schema(params_dict, where, value, message) -> None:
    """A recipe's section passes the params schema (it is a mapping named after the weighting) and
    is checked by its method's own schema when a stage starts: one line naming the key."""
    from compact_perception.core.params import ParamsError, parse_params
    from compact_perception.learning.weighting import weighting_settings

    node = params_dict
    for key in where[:-1]:
        node = node[key]
    node[where[-1]] = value
    p = parse_params(params_dict)
    recipe = p.study_recipe(where[2]) if where[0] == "study" else p.train.models[where[2]]
    with pytest.raises(ParamsError) as exc:
        weighting_settings(recipe)
    assert str(exc.value).startswith(message) and "\n" not in str(exc.value), str(exc.value)


def test_a_section_of_another_method_is_an_error_naming_the_key(params_dict) -> None:
    from compact_perception.core.params import ParamsError, parse_params

    params_dict["train"]["models"]["compact_15l_mgn"]["uw"] = {"lr": 0.025}
    with pytest.raises(ParamsError, match=r"^params\.yaml: train\.models\.compact_15l_mgn\.uw: unknown key"):
        parse_params(params_dict)


# ----------------------------------------------------------------------------- uncertainty weighting
def test_uw_total_network_grads_and_s_gradient_by_hand() -> None:
    tasks = ("de", "ss")
    W = [[0.5, 2.0], [-1.0, 3.0]]  # a = W x = (0.5, -1.0)
    H = [[1.0, 2.0], [-3.0, 1.0]]  # o = (-1.5, -2.5)
    y = [0.5, 1.0]
    a, o = np.array([0.5, -1.0]), np.array([-1.5, -2.5])
    r = o - np.array(y)                  # (-2, -3.5)
    L = 0.5 * r ** 2                     # (2, 6.125)
    model = Lin(W, H)
    lr = 0.1
    uw = UncertaintyWeighting(tasks, lr=lr, **PLATEAU)
    s, m, v = np.zeros(2), np.zeros(2), np.zeros(2)

    # step 1: s = 0, w = 1
    total = uw.backward(square_losses(model, tasks, y), model)
    assert float(total) == pytest.approx(L.sum() + s.sum(), abs=1e-12)
    np.testing.assert_allclose(model.W.grad.numpy(), col0(r[0] * np.array(H[0]) + r[1] * np.array(H[1])), atol=1e-12)
    for i in range(2):
        np.testing.assert_allclose(model.heads[i].grad.numpy(), r[i] * a, atol=1e-12)
    g = 1.0 - np.exp(-s) * L             # dL_UW/ds_i = 1 - exp(-s_i) L_i = (-1, -5.125)
    np.testing.assert_allclose(uw.last["grad_s"].numpy(), g, atol=1e-12)
    s, m, v = adam(s, g, m, v, 1, lr)
    np.testing.assert_allclose(uw.s.detach().numpy(), s, atol=1e-12)
    np.testing.assert_allclose(s, [lr, lr], atol=1e-8)  # Adam's first step: lr sign(-g)
    np.testing.assert_allclose(uw.w.numpy(), np.exp(-s), atol=1e-12)
    assert uw.log_values() == pytest.approx({"w_de": math.exp(-s[0]), "w_ss": math.exp(-s[1])})

    # step 2: same losses, weights exp(-s), grads accumulate into the existing .grad
    before_W = model.W.grad.clone()
    total = uw.backward(square_losses(model, tasks, y), model)
    w = np.exp(-s)
    assert float(total) == pytest.approx((w * L).sum() + s.sum(), abs=1e-12)
    dW = col0(w[0] * r[0] * np.array(H[0]) + w[1] * r[1] * np.array(H[1]))
    np.testing.assert_allclose((model.W.grad - before_W).numpy(), dW, atol=1e-12)
    g = 1.0 - np.exp(-s) * L
    np.testing.assert_allclose(uw.last["grad_s"].numpy(), g, atol=1e-12)
    s, m, v = adam(s, g, m, v, 2, lr)
    np.testing.assert_allclose(uw.s.detach().numpy(), s, atol=1e-12)


def test_uw_scale_aux_and_fixed_point() -> None:
    tasks = ("de", "ss")
    model = Lin([[1.0, 0.0], [2.0, 1.0]], [[1.0, 1.0], [0.5, -1.0]])  # a = (1, 2), o = (3, -1.5)
    uw = UncertaintyWeighting(tasks, lr=0.01, **PLATEAU)
    losses = square_losses(model, tasks, [1.0, -0.5])  # L = (2, 0.5), r = (2, -1)
    losses["aux_reg"] = 0.25 * (model.W ** 2).sum()     # weight 1: d/dW = W / 2
    uw.backward(losses, model, lambda t: t * 4.0)       # a loss scaler's factor 4 reaches .grad only
    expected = col0(2.0 * np.array([1.0, 1.0]) - 1.0 * np.array([0.5, -1.0])) + 0.5 * model.W.detach().numpy()
    np.testing.assert_allclose(model.W.grad.numpy(), 4.0 * expected, atol=1e-12)
    np.testing.assert_allclose(uw.last["grad_s"].numpy(), [1 - 2.0, 1 - 0.5], atol=1e-12)
    # the optimum of exp(-s) L + s is s = log L: there the s-gradient vanishes
    uw2 = UncertaintyWeighting(tasks, lr=0.01, **PLATEAU)
    uw2.set_weights(torch.tensor([1 / 2.0, 1 / 0.5], dtype=D))
    np.testing.assert_allclose(uw2.s.detach().numpy(), np.log([2.0, 0.5]), atol=1e-15)
    uw2.backward(square_losses(model, tasks, [1.0, -0.5]), model)
    np.testing.assert_allclose(uw2.last["grad_s"].numpy(), [0.0, 0.0], atol=1e-15)


# ----------------------------------------------------------------------------- DWA
def test_dwa_weights_after_three_epochs_by_hand() -> None:
    tasks = ("de", "ss", "ls")
    dwa = DWAWeighting(tasks, temperature=2.0, **PLATEAU)
    model = nn.Linear(1, 1)
    # per-step losses of each epoch; epoch means: (2, 4, 1), (1, 3, 1), (0.5, 3, 2)
    epochs = [
        [(1.0, 5.0, 1.0), (3.0, 3.0, 1.0)],
        [(1.0, 2.0, 0.5), (1.0, 4.0, 1.5)],
        [(0.25, 3.0, 2.0), (0.75, 3.0, 2.0)],
    ]
    seen = []
    for e, steps in enumerate(epochs):
        for k, vals in enumerate(steps):
            dwa.before_backward(k, len(steps), {t: torch.tensor(v) for t, v in zip(tasks, vals)}, model)
            dwa.after_backward()
            seen.append(dwa.w.tolist())
        dwa.on_epoch_end(False)
    assert all(w == [1.0, 1.0, 1.0] for w in seen[:4])  # epochs 0 and 1: w = 1
    # epoch 2 used r = L(1) / L(0) = (1/2, 3/4, 1); temperature 2
    e2 = [math.exp(0.5 / 2), math.exp(0.75 / 2), math.exp(1.0 / 2)]
    np.testing.assert_allclose(seen[4], [3 * x / sum(e2) for x in e2], atol=1e-14)
    # after epoch 2: r = L(2) / L(1) = (1/2, 1, 2)
    e3 = [math.exp(0.25), math.exp(0.5), math.exp(1.0)]
    np.testing.assert_allclose(dwa.w.numpy(), [3 * x / sum(e3) for x in e3], atol=1e-14)
    assert float(dwa.w.sum()) == pytest.approx(3.0, abs=1e-14)
    assert dwa.log_values()["w_ls"] == pytest.approx(3 * math.e / sum(e3))
    # the weights enter the default backward (eq. 8)
    lin = Lin([[1.0, 0.0], [0.0, 1.0]], [[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])  # o = (1, 0, 1)
    total = dwa.backward(linear_losses(lin, tasks), lin)
    w = dwa.w.numpy()
    assert float(total) == pytest.approx(w[0] + w[2], abs=1e-12)
    np.testing.assert_allclose(lin.W.grad.numpy(), col0(w[0] * np.array([1, 0]) + w[1] * np.array([0, 1])
                                                        + w[2] * np.array([1, 1])), atol=1e-12)


def test_dwa_state_round_trip_mid_epoch_and_non_finite_steps() -> None:
    tasks = ("de", "ss")
    model = nn.Linear(1, 1)
    a = DWAWeighting(tasks, temperature=1.5, **PLATEAU)
    vals = [[(1.0, 2.0), (3.0, 1.0)], [(2.0, 2.0), (float("inf"), 1.0), (1.0, 3.0)], [(0.5, 1.0)]]
    for steps in vals[:2]:
        for k, v in enumerate(steps):
            a.before_backward(k, len(steps), dict(zip(tasks, map(torch.tensor, v))), model)
            a.after_backward()
        a.on_epoch_end(True)
    # the inf step is left out of de's mean: L(1) = (1.5, 2)
    assert a.history == [[2.0, 1.5], [1.5, 2.0]]
    a.before_backward(0, 2, dict(zip(tasks, map(torch.tensor, vals[2][0]))), model)
    a.after_backward()
    b = DWAWeighting(tasks, temperature=1.5, **PLATEAU)
    b.load_state_dict(copy.deepcopy(a.state_dict()))
    for x in (a, b):
        x.before_backward(1, 2, dict(zip(tasks, map(torch.tensor, (1.0, 2.0)))), model)
        x.after_backward()
        x.on_epoch_end(False)
    assert torch.equal(a.w, b.w) and a.history == b.history == [[1.5, 2.0], [0.75, 1.5]]
    r = [0.75 / 1.5, 1.5 / 2.0]
    e = [math.exp(x / 1.5) for x in r]
    np.testing.assert_allclose(a.w.numpy(), [2 * x / sum(e) for x in e], atol=1e-14)


# ----------------------------------------------------------------------------- PCGrad
def np_pcgrad(gs: list[np.ndarray], orders: list[list[int]]) -> np.ndarray:
    """Algorithm 1 on explicit vectors: g_i projected against the original g_j in ``orders[i]``."""
    out = np.zeros_like(gs[0])
    for i, g in enumerate(gs):
        gi = g.astype(float).copy()
        for j in orders[i]:
            if j != i and gi @ gs[j] < 0:
                gi = gi - (gi @ gs[j]) / (gs[j] @ gs[j]) * gs[j]
        out += gi
    return out


def test_pcgrad_two_conflicting_gradients_by_hand() -> None:
    tasks = ("de", "ss")
    W = [[2.0, 5.0], [-1.0, 7.0]]  # a = (2, -1)
    model = Lin(W, [[1.0, 0.0], [-1.0, 1.0]])  # g1 = (1, 0), g2 = (-1, 1): g1.g2 = -1 < 0
    pc = PCGradWeighting(tasks, seed=0, **PLATEAU)
    total = pc.backward(linear_losses(model, tasks), model)
    # g1 - (-1/2) g2 = (0.5, 0.5); g2 - (-1/1) g1 = (0, 1); sum (0.5, 1.5)
    np.testing.assert_allclose(model.W.grad.numpy(), col0([0.5, 1.5]), atol=1e-15)
    for h in model.heads:  # task-specific: the plain task gradient a
        np.testing.assert_allclose(h.grad.numpy(), [2.0, -1.0], atol=1e-15)
    assert float(total) == pytest.approx(2.0 + (-3.0))  # unweighted sum of o = (2, -3)
    assert pc.last["conflicts"] == 2
    pc.on_epoch_end(False)
    assert pc.log_values() == {"w_de": 1.0, "w_ss": 1.0, "conflicts": 2.0}
    assert pc.total(linear_losses(model, tasks)).item() == pytest.approx(-1.0)


def test_pcgrad_non_conflicting_unchanged_accumulates_scale_and_aux() -> None:
    tasks = ("de", "ss")
    model = Lin([[1.0, 0.0], [1.0, 0.0]], [[1.0, 0.0], [1.0, 1.0]])  # g1.g2 = 1 > 0
    for p in model.parameters():
        p.grad = torch.full_like(p, 0.5)  # e.g. MGN authors_mode's pre-filled .grad
    pc = PCGradWeighting(tasks, seed=0, **PLATEAU)
    losses = linear_losses(model, tasks)
    losses["aux_x"] = 3.0 * model.W[1, 1]  # weight 1, not projected
    pc.backward(losses, model, lambda t: t * 8.0)
    exp_W = col0([2.0, 1.0])
    exp_W[1, 1] += 3.0
    np.testing.assert_allclose(model.W.grad.numpy(), 0.5 + 8.0 * exp_W, atol=1e-12)
    np.testing.assert_allclose(model.heads[0].grad.numpy(), 0.5 + 8.0 * np.array([1.0, 1.0]), atol=1e-12)
    assert pc.last["conflicts"] == 0


def test_pcgrad_random_order_three_tasks_by_hand() -> None:
    tasks = ("de", "ss", "ls")
    H = [[1.0, 0.0], [-1.0, 1.0], [-2.0, -1.0]]
    gs = [np.array(h) for h in H]
    # the order matters here: g1 against (g2, g3) gives (-0.1, 0.2), against (g3, g2) (-0.1, -0.1)
    np.testing.assert_allclose(np_pcgrad(gs, [[1, 2], [], []]) - gs[1] - gs[2], [-0.1, 0.2], atol=1e-12)
    np.testing.assert_allclose(np_pcgrad(gs, [[2, 1], [], []]) - gs[1] - gs[2], [-0.1, -0.1], atol=1e-12)
    seed = 5
    gen = torch.Generator().manual_seed(seed)  # documented protocol: one randperm(T) per task i
    results = []
    pc = PCGradWeighting(tasks, seed=seed, **PLATEAU)
    for step in range(4):
        orders = [torch.randperm(3, generator=gen).tolist() for _ in range(3)]
        model = Lin([[1.0, 0.0], [1.0, 0.0]], H)
        pc.backward(linear_losses(model, tasks), model)
        np.testing.assert_allclose(model.W.grad.numpy(), col0(np_pcgrad(gs, orders)), atol=1e-12)
        results.append(model.W.grad[:, 0].tolist())
    assert len({tuple(np.round(r, 9)) for r in results}) > 1  # the draws differ between steps


def test_pcgrad_shared_means_reached_by_two_tasks() -> None:
    model = Tiny()
    losses = tiny_losses(model, 1)
    plain = {t: torch.autograd.grad(losses[t], list(model.parameters()), retain_graph=True, allow_unused=True)
             for t in TASKS4}
    pc = PCGradWeighting(TASKS4, seed=0, **PLATEAU)
    pc.backward(losses, model)
    names = [n for n, _ in model.named_parameters()]
    for k, (n, p) in enumerate(model.named_parameters()):
        if n.startswith("shared1"):
            continue  # all four tasks: projected
        # shared2 (bevp only) and every head: the plain gradient of the one task reaching it
        reach = [t for t in TASKS4 if plain[t][k] is not None]
        assert len(reach) == 1, n
        assert torch.equal(p.grad, plain[reach[0]][k]), n
    assert "shared2.weight" in names


# ----------------------------------------------------------------------------- CAGrad
def test_cagrad_c0_is_the_mean_gradient() -> None:
    tasks = ("de", "ss", "ls")
    H = [[1.0, 0.0], [-1.0, 1.0], [3.0, -2.0]]
    model = Lin([[1.0, 0.0], [2.0, 0.0]], H)  # a = (1, 2)
    cg = CAGradWeighting(tasks, c=0.0, **PLATEAU)
    total = cg.backward(linear_losses(model, tasks), model)
    np.testing.assert_allclose(model.W.grad.numpy(), col0(np.mean(H, axis=0)), atol=1e-14)
    for h in model.heads:  # task-specific parameters: weight 1
        np.testing.assert_allclose(h.grad.numpy(), [1.0, 2.0], atol=1e-15)
    np.testing.assert_allclose(cg.w.numpy(), [1 / 3] * 3, atol=1e-15)
    assert float(total) == pytest.approx(1.0 + 1.0 - 1.0)


def test_cagrad_orthogonal_equal_norms_symmetric_solution() -> None:
    tasks = ("de", "ss")
    c = 0.4
    model = Lin([[1.0, 0.0], [1.0, 0.0]], [[1.0, 0.0], [0.0, 1.0]])
    cg = CAGradWeighting(tasks, c=c, **PLATEAU)
    cg.backward(linear_losses(model, tasks), model)
    # w* = (1/2, 1/2) by symmetry, g_w* = g0, ||g_w*|| = ||g0||: d = (1 + c) g0
    np.testing.assert_allclose(cg.last["w_star"].numpy(), [0.5, 0.5], atol=1e-12)
    np.testing.assert_allclose(model.W.grad.numpy(), col0([(1 + c) / 2, (1 + c) / 2]), atol=1e-12)
    np.testing.assert_allclose(cg.w.numpy(), [(1 + c) / 2] * 2, atol=1e-12)


def test_cagrad_two_tasks_against_golden_section_search() -> None:
    tasks = ("de", "ss")
    c = 0.4
    g1, g2 = np.array([1.0, 0.0]), np.array([-0.8, 0.9])
    g0 = (g1 + g2) / 2
    lam = c * np.linalg.norm(g0)

    def F(t: float) -> float:  # w = (t, 1 - t)
        gw = t * g1 + (1 - t) * g2
        return gw @ g0 + lam * np.linalg.norm(gw)

    lo, hi = 0.0, 1.0
    phi = (math.sqrt(5) - 1) / 2
    for _ in range(200):
        m1, m2 = hi - phi * (hi - lo), lo + phi * (hi - lo)
        lo, hi = (lo, m2) if F(m1) < F(m2) else (m1, hi)
    t = (lo + hi) / 2
    gw = t * g1 + (1 - t) * g2
    d = g0 + lam / np.linalg.norm(gw) * gw
    assert 0.01 < t < 0.99  # an interior solution: the case is not trivial
    model = Lin([[1.0, 0.0], [1.0, 0.0]], [g1.tolist(), g2.tolist()])
    cg = CAGradWeighting(tasks, c=c, **PLATEAU)
    cg.backward(linear_losses(model, tasks), model, lambda x: x * 8.0)
    np.testing.assert_allclose(cg.last["w_star"].numpy(), [t, 1 - t], atol=1e-7)
    np.testing.assert_allclose(model.W.grad.numpy(), 8.0 * col0(d), atol=1e-7)
    # d = sum_i (1/T + lam w_i / ||g_w||) g_i
    np.testing.assert_allclose(cg.w.numpy(), [0.5 + lam * t / np.linalg.norm(gw),
                                              0.5 + lam * (1 - t) / np.linalg.norm(gw)], atol=1e-7)
    # CAGrad's guarantee: d's worst task improvement beats the mean gradient's
    assert min(g1 @ d, g2 @ d) > min(g1 @ g0, g2 @ g0)


@pytest.mark.parametrize("dim,c", [(50, 0.4), (2, 0.4), (3, 0.9), (50, 1.5)])
def test_cagrad_four_tasks_satisfies_the_optimality_conditions(dim: int, c: float) -> None:
    """For the convex F on the simplex, w* is optimal iff grad F(w*)_i = min_j grad F(w*)_j on the
    support of w* and >= elsewhere; checked with F's gradient written out by hand."""
    rng = np.random.default_rng(dim)
    G = rng.normal(size=(4, dim)) * np.array([[1.0], [5.0], [0.3], [2.0]])
    G[1] -= 1.5 * G[0]  # a conflict
    model = nn.Module()
    model.theta = nn.Parameter(torch.zeros(dim, dtype=D))
    model.heads = nn.ParameterList([nn.Parameter(torch.zeros((), dtype=D)) for _ in TASKS4])  # one per task
    losses = {t: torch.tensor(G[i], dtype=D) @ model.theta + model.heads[i] for i, t in enumerate(TASKS4)}
    cg = CAGradWeighting(TASKS4, c=c, **PLATEAU)
    cg.backward(losses, model)
    w = cg.last["w_star"].numpy()
    Q = G @ G.T
    g0 = G.mean(axis=0)
    lam = c * np.linalg.norm(g0)
    gw = w @ G
    grad = G @ g0 + lam * (G @ gw) / np.linalg.norm(gw)
    assert w.min() >= 0 and w.sum() == pytest.approx(1.0, abs=1e-12)
    scale = np.abs(Q).max()
    mu = grad.min()
    assert np.all(np.abs(grad[w > 1e-9] - mu) <= 1e-8 * scale), (w, grad)
    coeffs = 0.25 + lam * w / np.linalg.norm(gw)
    np.testing.assert_allclose(model.theta.grad.numpy(), coeffs @ G, atol=1e-9 * scale)
    assert [float(h.grad) for h in model.heads] == [1.0] * 4
    np.testing.assert_allclose(Q, cg.last["gram"].numpy(), atol=1e-12 * scale)


def test_cagrad_logs_epoch_mean_of_effective_weights() -> None:
    tasks = ("de", "ss")
    cg = CAGradWeighting(tasks, c=0.4, **PLATEAU)
    assert cg.log_values() == pytest.approx({"w_de": 0.5, "w_ss": 0.5})
    seen = []
    for H in ([[1.0, 0.0], [0.0, 1.0]], [[1.0, 0.0], [-1.0, 3.0]]):
        model = Lin([[1.0, 0.0], [1.0, 0.0]], H)
        cg.backward(linear_losses(model, tasks), model)
        seen.append(cg.w.numpy().copy())
    cg.on_epoch_end(False)
    assert cg.log_values() == pytest.approx(dict(zip(("w_de", "w_ss"), np.mean(seen, axis=0))))


# ----------------------------------------------------------------------------- resume
def _make(kind: str):
    if kind == "uw":
        return UncertaintyWeighting(TASKS4, lr=0.05, **PLATEAU)
    if kind == "dwa":
        return DWAWeighting(TASKS4, temperature=2.0, **PLATEAU)
    if kind == "pcgrad":
        return PCGradWeighting(TASKS4, seed=11, **PLATEAU)
    return CAGradWeighting(TASKS4, c=0.4, **PLATEAU)


def _train_step(weighting, model: Tiny, opt: torch.optim.Optimizer, step: int, n_steps: int, seed: int) -> None:
    opt.zero_grad(set_to_none=True)
    losses = tiny_losses(model, seed)
    weighting.before_backward(step, n_steps, losses, model)
    weighting.after_backward()
    weighting.backward(losses, model)
    opt.step()


@pytest.mark.parametrize("kind", ["uw", "dwa", "pcgrad", "cagrad"])
def test_state_round_trip_gives_identical_updates(kind: str) -> None:
    model = Tiny()
    opt = torch.optim.SGD(model.parameters(), lr=0.01)
    a = _make(kind)
    seed = 0
    for epoch in range(3):  # DWA needs three epochs to move its weights
        for step in range(2):
            _train_step(a, model, opt, step, 2, seed)
            seed += 1
        a.on_epoch_end(epoch == 0)
    _train_step(a, model, opt, 0, 2, seed)  # mid-epoch
    seed += 1
    state = copy.deepcopy(a.state_dict())
    model_b = copy.deepcopy(model)
    opt_b = torch.optim.SGD(model_b.parameters(), lr=0.01)
    opt_b.load_state_dict(copy.deepcopy(opt.state_dict()))
    b = _make(kind)
    b.load_state_dict(state)
    assert torch.equal(a.w, b.w)
    if kind != "pcgrad":
        assert not np.allclose(a.w.numpy(), a.w.numpy()[0])  # the weights have moved: a real check
    for step in range(1, 2):
        _train_step(a, model, opt, step, 2, seed)
        _train_step(b, model_b, opt_b, step, 2, seed)
    a.on_epoch_end(False)
    b.on_epoch_end(False)
    for k in range(3):
        _train_step(a, model, opt, k, 3, seed + 1 + k)
        _train_step(b, model_b, opt_b, k, 3, seed + 1 + k)
        assert all(torch.equal(x, y) for x, y in zip(grads(model), grads(model_b)))
    assert torch.equal(a.w, b.w) and a.log_values() == b.log_values()
    assert all(torch.equal(x, y) for x, y in zip(model.parameters(), model_b.parameters()))


def test_pcgrad_seed_changes_the_orders_and_resume_restores_the_generator() -> None:
    tasks = ("de", "ss", "ls")
    H = [[1.0, 0.0], [-1.0, 1.0], [-2.0, -1.0]]

    def run(pc: PCGradWeighting, n: int) -> list[list[float]]:
        out = []
        for _ in range(n):
            model = Lin([[1.0, 0.0], [1.0, 0.0]], H)
            pc.backward(linear_losses(model, tasks), model)
            out.append(model.W.grad[:, 0].tolist())
        return out

    ref = run(PCGradWeighting(tasks, seed=1, **PLATEAU), 8)
    assert run(PCGradWeighting(tasks, seed=1, **PLATEAU), 8) == ref  # same seed, same bytes
    assert run(PCGradWeighting(tasks, seed=2, **PLATEAU), 8) != ref
    a = PCGradWeighting(tasks, seed=1, **PLATEAU)
    run(a, 3)
    b = PCGradWeighting(tasks, seed=1, **PLATEAU)
    b.load_state_dict(copy.deepcopy(a.state_dict()))
    assert run(b, 5) == ref[3:]
    with pytest.raises(ValueError, match="seed"):
        PCGradWeighting(tasks, seed=2, **PLATEAU).load_state_dict(a.state_dict())
