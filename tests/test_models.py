"""Models (SPEC 5, paper III-A / V-D): exact parameter counts, shapes, ranges, losses, overfit.

Kept small for a shared 2-core machine: S = 32, batch 1, single-threaded torch; the large
GradNorm SegNet is built at most once per class count.
"""
from __future__ import annotations

import pytest
import torch
import torch.nn.functional as F
from torch import nn

from compact_perception.core.catalog import dataset_ids, model_ids
from compact_perception.learning.models import DATASET_SPECS, MODELS, build_model, count_parameters
from compact_perception.learning.models.polarnet import PolarNet, RingConv2d

torch.set_num_threads(1)

S = 32
DATASET_IDS = dataset_ids()
RANGES = {"de": "relu", "ss": "prob", "ls": "prob", "bevp": "prob"}


_BY_SPEC: dict[tuple[str, object], nn.Module] = {}


def _model(model_id: str, dataset_id: str) -> nn.Module:
    """One cached build per (model, dataset spec): A, B and C share a spec."""
    key = (model_id, DATASET_SPECS[dataset_id])
    if key not in _BY_SPEC:
        torch.manual_seed(0)
        _BY_SPEC[key] = build_model(model_id, dataset_id)
    return _BY_SPEC[key]


def make_batch(dataset_id: str, lidar_channels: int, s: int = S, b: int = 1, seed: int = 0) -> dict:
    """A random batch following ARCHITECTURE.md (one-hot targets, some unlabelled LS cells)."""
    spec = DATASET_SPECS[dataset_id]
    g = torch.Generator().manual_seed(seed)
    c, cb, v = spec.n_seg, spec.n_bev, spec.n_views

    def onehot(shape: tuple[int, ...], n: int) -> torch.Tensor:
        idx = torch.randint(0, n, shape, generator=g)
        return F.one_hot(idx, n).movedim(-1, -3).float()

    ls = onehot((b, s, s), c)
    ls[..., : s // 4, :] = 0.0  # cells with no LiDAR point: all-zero one-hot
    batch = {
        "rgb": torch.rand(b, v, 3, s, s, generator=g),
        "lidar": torch.rand(b, lidar_channels, s, s, generator=g),
        "de": torch.rand(b, v, 1, s, s, generator=g),
        "ss": onehot((b, v, s, s), c),
        "ls": ls,
        "bevp": (torch.rand(b, cb, s, s, generator=g) > 0.7).float(),
    }
    if spec.has_dvs:
        batch["dvs"] = torch.rand(b, v, 2, s, s, generator=g)
    return batch


def _lidar_ch(model_id: str) -> int:
    return 1 if model_id == "compact_1l" else 15


# ---------------------------------------------------------------- parameter counts
@pytest.mark.parametrize(
    "model_id,dataset_id,expected",
    [
        *[("compact_1l", d, 2_519_488) for d in "ABC"],
        *[("compact_15l", d, 2_521_504) for d in "ABC"],
        *[("compact_15l_mgn", d, 2_521_504) for d in "ABC"],
        ("compact_1l", "nuscenes", 2_275_604),
        ("compact_15l", "nuscenes", 2_277_620),
        ("compact_15l_mgn", "nuscenes", 2_277_620),
        *[("polarnet", d, 13_403_701) for d in "ABC"],
        ("polarnet", "nuscenes", 13_404_286),
    ],
)
def test_exact_parameter_counts(model_id: str, dataset_id: str, expected: int) -> None:
    assert count_parameters(build_model(model_id, dataset_id)) == expected


@pytest.mark.parametrize(
    "model_id,dataset_id,paper,ours",
    [
        ("gradnorm_segnet", "A", 28_239_960, 29_456_856),
        ("gradnorm_segnet", "nuscenes", 28_245_153, 29_462_049),
        ("chen_bev", "A", 10_365_211, 10_928_101),
        ("chen_bev", "nuscenes", 10_372_539, 10_962_403),
    ],
)
def test_baseline_counts_within_10_percent(model_id: str, dataset_id: str, paper: int, ours: int) -> None:
    model = _model(model_id, dataset_id)
    if model_id == "gradnorm_segnet":  # the paper counts one of the 4 per-view models
        assert len(model.views) == 4
        per_view = {count_parameters(v) for v in model.views}
        assert per_view == {ours}
        assert count_parameters(model) == 4 * ours
    else:
        assert count_parameters(model) == ours
    assert abs(ours - paper) / paper < 0.10


def test_chen_count_independent_of_resolution() -> None:
    """Chen's size adaptation changes no weight shape: the 128-input count holds at 32/64."""
    model = _model("chen_bev", "A")
    for s in (32, 64, 128):
        out = model.eval()(make_batch("A", 15, s=s))
        assert out["bevp"].shape == (1, 9, s, s)
    assert count_parameters(model) == 10_928_101


# ---------------------------------------------------------------- single-task networks
# Per-module counts of the 15L network on A (the compact.py arithmetic, block(i, o) = 9io + 9o^2 + 6o):
# the encoders 178,368 (RGB) + 177,792 (DVS) + 74,256 (LiDAR, 15 channels) + bottleneck 1 369,408 = 799,824.
@pytest.mark.parametrize("tasks,expected", [
    (("de",), 799_824 + 296_516),
    (("ss",), 799_824 + 298_012),
    (("ls",), 799_824 + 157_735),
    (("bevp",), 2_521_504),          # BEVP's second stage reads the DE, SS and LS outputs: the whole network
])
def test_single_task_compact_network_counts(tasks: tuple[str, ...], expected: int) -> None:
    model = build_model("compact_15l", "A", tasks)
    assert model.tasks == tasks
    assert count_parameters(model) == expected


@pytest.mark.parametrize("task", ["de", "ss", "ls"])
def test_single_task_network_is_the_full_networks_branch(task: str) -> None:
    """Given the full network's weights, the one-task network computes exactly that task's output."""
    full = _model("compact_15l", "A").eval()
    one = build_model("compact_15l", "A", (task,)).eval()
    missing, unexpected = one.load_state_dict(full.state_dict(), strict=False)
    assert not missing and unexpected  # every weight of the branch comes from the full net; the rest is absent
    batch = make_batch("A", 15)
    with torch.no_grad():
        out = one(batch)
        assert set(out) == {task} and set(one.compute_losses(out, batch)) == {task}
        assert torch.equal(out[task], full(batch)[task])
    assert set(one.shared_layers()) == {task}


def test_only_the_compact_network_has_task_subsets() -> None:
    assert build_model("polarnet", "A", ("ls",)).tasks == ("ls",)  # its own tasks: the plain build
    with pytest.raises(ValueError, match="gradnorm_segnet is built for all of its tasks"):
        build_model("gradnorm_segnet", "A", ("de",))
    with pytest.raises(ValueError, match="non-empty subset"):
        build_model("compact_15l", "A", ("depth",))


# ---------------------------------------------------------------- forward contract
@pytest.mark.parametrize("dataset_id", DATASET_IDS)
@pytest.mark.parametrize("model_id", model_ids())
def test_forward_shapes_ranges_losses(model_id: str, dataset_id: str) -> None:
    model = _model(model_id, dataset_id).train()
    batch = make_batch(dataset_id, _lidar_ch(model_id))
    out = model(batch)
    assert set(out) == set(model.tasks)
    for task, pred in out.items():
        assert pred.shape == batch[task].shape, task
        assert torch.isfinite(pred).all()
        assert pred.min() >= 0.0
        if RANGES[task] == "prob":
            assert pred.max() <= 1.0
    losses = model.compute_losses(out, batch)
    assert set(losses) == set(model.tasks)
    for task, loss in losses.items():
        assert loss.dim() == 0 and torch.isfinite(loss), task
        assert loss.requires_grad


@pytest.mark.parametrize("model_id", model_ids())
def test_shared_layers_resolve_to_convs(model_id: str) -> None:
    model = _model(model_id, "A")
    shared = model.shared_layers()
    assert set(shared) <= set(model.tasks)
    for names in shared.values():
        assert names
        for name in names:
            assert isinstance(model.get_submodule(name), nn.Conv2d), name
    if model_id.startswith("compact"):
        assert shared["bevp"] == ["bottleneck2.conv1"]
        assert all(shared[t] == ["bottleneck1.conv1"] for t in ("de", "ss", "ls"))
    if model_id == "gradnorm_segnet":
        assert shared["de"] == shared["ss"] and len(shared["de"]) == 4


def test_compact_1l_reads_channel_14_of_15() -> None:
    model = _model("compact_1l", "A").eval()
    batch = make_batch("A", 15)
    with torch.no_grad():
        full = model(batch)["ls"]
        batch["lidar"] = batch["lidar"][:, 14:15]
        one = model(batch)["ls"]
    assert torch.allclose(full, one)


def test_build_model_unknown_ids() -> None:
    with pytest.raises(KeyError, match="unknown model 'nope'"):
        build_model("nope", "A")
    with pytest.raises(KeyError, match="unknown dataset 'Z'"):
        build_model("polarnet", "Z")
    assert set(MODELS.keys()) == set(model_ids())


# ---------------------------------------------------------------- PolarNet ring padding
def test_ring_conv_wraps_last_axis_only() -> None:
    conv = RingConv2d(1, 1)
    with torch.no_grad():
        conv.weight.fill_(1.0)
        conv.bias.zero_()
    h = w = 8
    x = torch.zeros(1, 1, h, w)
    x[0, 0, 3, 0] = 1.0  # left edge of the angular (last) axis
    y = conv(x)
    assert y[0, 0, 3, w - 1] > 0  # wraps to the right edge
    x = torch.zeros(1, 1, h, w)
    x[0, 0, 0, 3] = 1.0  # top edge of the other axis
    y = conv(x)
    assert y[0, 0, h - 1, 3] == 0  # no wrap along the rows
    assert y[0, 0, 1, 3] > 0


def test_polarnet_uses_ring_convs() -> None:
    model = _model("polarnet", "A")
    convs3 = [m for m in model.modules() if isinstance(m, nn.Conv2d) and m.kernel_size == (3, 3)]
    assert convs3 and all(isinstance(m, RingConv2d) for m in convs3)
    assert isinstance(model, PolarNet)


# ---------------------------------------------------------------- tiny overfit
@pytest.mark.parametrize("model_id", ["compact_1l", "compact_15l", "gradnorm_segnet", "polarnet", "chen_bev"])
def test_tiny_overfit(model_id: str) -> None:
    """A few Adam steps on one fixed S = 32 batch lower the summed task losses."""
    torch.manual_seed(1)
    if model_id == "gradnorm_segnet":
        # one view keeps the step cheap; the 4 per-view networks are identical in structure
        from compact_perception.learning.models.segnet import GradNormSegNet

        model = GradNormSegNet(DATASET_SPECS["A"].n_seg, n_views=1)
    else:
        model = build_model(model_id, "A")
    model.train()
    for m in model.modules():  # deterministic comparison: no dropout noise
        if isinstance(m, nn.Dropout):
            m.eval()
    batch = make_batch("A", _lidar_ch(model_id), seed=3)
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    history = []
    for _ in range(6):
        opt.zero_grad()
        loss = sum(model.compute_losses(model(batch), batch).values())
        loss.backward()
        opt.step()
        history.append(loss.item())
    assert history[-1] < history[0], history


def test_network_missing_a_contract_member_fails_when_found():
    """``network_factory`` checks a network module's ``build`` against ``PerceptionNet``: a class
    without ``shared_layers`` (or a ``build`` without a return annotation, or a module without
    ``build``) never reaches training."""
    import types

    from torch import nn

    from compact_perception.learning.models.base import PerceptionNet, contract_gaps, network_factory

    class Partial(nn.Module):
        tasks = ("de",)
        argmax_tasks = ()

        def forward(self, batch):
            return {}

        def compute_losses(self, outputs, batch):
            return {}

    def build(ds, info):
        return Partial()

    build.__annotations__["return"] = Partial  # a local class: the annotation itself, not its name
    module = types.ModuleType("compact_perception.learning.models.partial")
    module.build = build
    with pytest.raises(TypeError, match=r"network 'partial': Partial does not meet the PerceptionNet contract "
                                        r"\(models/base.py\); it lacks: method shared_layers\(\)"):
        network_factory(module)

    def unannotated(ds, info):
        return Partial()

    module.build = unannotated
    with pytest.raises(TypeError, match="must annotate its return with the network class"):
        network_factory(module)
    with pytest.raises(TypeError, match=r"network 'empty': its module defines no build\(spec, info\) function"):
        network_factory(types.ModuleType("compact_perception.learning.models.empty"))
    assert contract_gaps(nn.Module) == ["class attribute 'tasks'", "class attribute 'argmax_tasks'", "method forward()",
                                        "method compute_losses()", "method shared_layers()"]
    assert PerceptionNet.__doc__


def test_every_network_meets_the_contract():
    from compact_perception.learning.models import NETWORKS
    from compact_perception.learning.models.base import contract_gaps

    assert sorted(NETWORKS) == ["chen", "compact", "polarnet", "segnet"]
    for key, factory in NETWORKS.items():
        cls = factory.__annotations__["return"]
        cls = factory.__globals__[cls] if isinstance(cls, str) else cls
        assert contract_gaps(cls) == [], key
