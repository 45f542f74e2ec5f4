"""The step census (training/census.py) counts what it says: aten ops, and every way the host reads
a device value, once each; the step counters PyTorch keeps on the host are not reads."""
from __future__ import annotations

import math

import torch

from compact_perception.training.census import Census, optimizer_step_counters


def test_every_kind_of_host_read_counts_once():
    x = torch.arange(6.0).reshape(2, 3)
    with Census("cpu") as c:
        s = x.sum()
        s.item()
        float(s)
        bool(s > 0)
        int(s)
        math.isfinite(s)
        x.tolist()
        x.numpy()
        x.cpu()
        x[x > 2]                       # boolean mask: nonzero underneath
        torch.nonzero(x)
    assert c.syncs == 10
    assert sum(c.sites.values()) == 10
    assert all(s.endswith("at (outside the package)") for s in c.sites)  # a site is code of the package
    assert c.ops > 5


def test_device_work_alone_is_no_sync():
    x = torch.randn(4, 4, requires_grad=True)
    acc = torch.zeros((), dtype=torch.float64)
    with Census("cpu") as c:
        y = (x @ x).relu().sum()
        y.backward()
        acc = acc + y.detach().double() * 3
        ok = torch.isfinite(acc)
        torch.where(ok, acc, torch.zeros_like(acc))
    assert c.syncs == 0 and c.ops > 5


def test_adam_step_counters_are_host_side():
    """A non-fused Adam reads its step counter with ``.item()``; PyTorch keeps that counter on the
    host in a GPU run too, so it is no device read. A fused Adam keeps it on the device and never
    reads it."""
    p = torch.nn.Parameter(torch.ones(3, dtype=torch.float64))
    opt = torch.optim.Adam([p], lr=0.1)
    p.grad = torch.ones(3, dtype=torch.float64)
    opt.step()
    with Census("cpu") as plain:
        opt.step()
    with Census("cpu", optimizer_step_counters(opt)) as exempt:
        opt.step()
    assert plain.syncs >= 1 and exempt.syncs == 0

    class Holder:  # a loss weighting holding its own optimiser
        def __init__(self) -> None:
            self.opt = opt

    with Census("cpu", optimizer_step_counters(Holder())) as held:
        opt.step()
    assert held.syncs == 0
