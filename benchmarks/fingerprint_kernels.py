"""Which kernel makes two machines disagree? A per-layer fingerprint of one training step.

    .venv/bin/python benchmarks/fingerprint_kernels.py [--cache data/cache/A] \
        [--models compact_15l compact_15l_mgn_authors polarnet gradnorm_segnet chen_bev] \
        [--weights runs/A/compact_15l/seed0/last.pt] [--out /tmp/fp.json] \
        [--compare benchmarks/fingerprints/amd_epyc_2core.json]

With the numeric libraries pinned exactly as every stage pins them
(``determinism.pin_numeric_libraries``, ``train.num_threads`` from params.yaml, PyTorch's
deterministic mode as in training), one training batch of the cache (the first of the
unshuffled train split, ``train.batch_size`` frames) goes through each model, with its training
losses (the recipe's DE loss form). Phases, each a dict of hashes (SHA-256, 16 hex):

* ``forward``: every leaf module's output, in call order;
* ``grad``: every parameter's gradient after ``backward`` of the summed task losses;
* ``grad2`` (models with shared layers): every gradient of a second-order step, the norm of the
  first shared layer's gradient (taken with ``create_graph=True``) backpropagated;
* ``mgn`` (recipes with ``weighting: mgn``): one real MGN update (eq. 9-15) by the weighting
  registry's own class, as step 0 of a one-step epoch (L_i(0) = L_i): the exact G_i, dL_MGN/dw_i
  and new w_i (float reprs), and, in the authors' form (section III-C as their code does it), the
  second-order terms that update writes into every parameter's ``.grad``;
* ``kernels``: the oneDNN primitives the step executed (implementation, propagation kind,
  memory formats, shape) and how often, read from oneDNN's verbose log.

``--weights`` loads a training checkpoint's model state first: the authors' form parts two
machines only after some training (docs/reproducibility.md), so fingerprint both machines from a
checkpoint both have byte-identical (one of a model whose results agree, e.g. compact_15l).
``--compare`` prints, per model and phase, how many entries differ from a fingerprint recorded
on another machine (entries missing on either side count) and the first one (in call order for
``forward``, parameter order otherwise), and warns when the two were taken from different code
(``code``: the training provenance's source fingerprint), whose hashes differ for that reason.
``benchmarks/fingerprints/`` holds the ones recorded so far (the cache bytes are
machine-independent: the data stages' hashes agree).
"""
from __future__ import annotations

from compact_perception.core.determinism import pin_numeric_libraries

pin_numeric_libraries()  # before numpy/torch run anything, as every stage does

import argparse  # noqa: E402
import ctypes  # noqa: E402
import hashlib  # noqa: E402
import json  # noqa: E402
import os  # noqa: E402
import pickle  # noqa: E402
import sys  # noqa: E402
import tempfile  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402
from typing import Any, Callable  # noqa: E402

import torch  # noqa: E402
from torch import Tensor, nn  # noqa: E402

from compact_perception.core.catalog import dataset_ids, model_ids  # noqa: E402
from compact_perception.core.params import load_params  # noqa: E402
from compact_perception.core.determinism import set_threads  # noqa: E402
from compact_perception.core.machine import cpu_name  # noqa: E402
from compact_perception.data.loader import make_loader, to_device  # noqa: E402
from compact_perception.learning.losses import de_loss_factor, scale_de_loss  # noqa: E402
from compact_perception.learning.models import DATASET_SPECS, build_model, lidar_channels  # noqa: E402
from compact_perception.learning.training.provenance import source_fingerprint  # noqa: E402
from compact_perception.learning.weighting import LossWeighting, build_weighting  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
from flags import Parser  # noqa: E402

DEFAULT_MODELS = ["compact_15l", "compact_15l_mgn_authors", "polarnet", "gradnorm_segnet", "chen_bev"]


def _hash(t: Tensor) -> str:
    return hashlib.sha256(t.detach().contiguous().cpu().numpy().tobytes()).hexdigest()[:16]


def _losses(model: nn.Module, batch: dict[str, Tensor], de_factor: float) -> dict[str, Tensor]:
    """The training losses: the model's task losses, DE in the recipe's form (``scale_de_loss``)."""
    return scale_de_loss(model.compute_losses(model(batch), batch), de_factor)


def fingerprint(model: nn.Module, batch: dict[str, Tensor], de_factor: float = 1.0) -> dict[str, dict[str, str]]:
    """Forward outputs, first-order and (with shared layers) second-order gradients, hashed."""
    forward: dict[str, str] = {}
    calls: dict[str, int] = {}

    def hook(name: str):
        def record(_mod: nn.Module, _inp: object, out: object) -> None:
            outs = out if isinstance(out, (tuple, list)) else [out]
            k = calls[name] = calls.get(name, -1) + 1
            for i, o in enumerate(outs):
                if isinstance(o, Tensor):
                    forward[f"{name}#{k}.{i}"] = _hash(o)
        return record

    handles = [m.register_forward_hook(hook(n)) for n, m in model.named_modules() if not list(m.children())]
    model.train()
    losses = _losses(model, batch, de_factor)
    for h in handles:
        h.remove()
    total = sum(losses.values())
    params = dict(model.named_parameters())
    grads = torch.autograd.grad(total, list(params.values()), retain_graph=True, allow_unused=True)
    first = {n: _hash(g) for (n, _), g in zip(params.items(), grads) if g is not None}
    out = {"forward": forward, "grad": first, "loss": {k: repr(float(v.detach())) for k, v in losses.items()}}
    shared = [name for names in model.shared_layers().values() for name in names]
    if shared:
        w = model.get_submodule(shared[0]).weight
        (g,) = torch.autograd.grad(total, [w], create_graph=True)
        grads2 = torch.autograd.grad(g.norm(), list(params.values()), allow_unused=True)
        out["grad2"] = {n: _hash(g2) for (n, _), g2 in zip(params.items(), grads2) if g2 is not None}
    return out


def mgn_fingerprint(model: nn.Module, batch: dict[str, Tensor], weighting: LossWeighting,
                    de_factor: float = 1.0) -> dict[str, str]:
    """One MGN update (Algorithm 1, or the authors' form with its second-order ``.grad``) as
    step 0 of a one-step epoch: exact G_i, dL_MGN/dw_i and updated w_i, and the hash of every
    ``.grad`` it wrote (none in Algorithm 1's network-isolated mode)."""
    model.train()
    for p in model.parameters():
        p.grad = None
    weighting.before_backward(0, 1, _losses(model, batch, de_factor), model)
    out = {n: _hash(p.grad) for n, p in model.named_parameters() if p.grad is not None}
    for i, t in enumerate(weighting.tasks):
        out[f"G.{t}"] = repr(float(weighting.last["G"][i]))
        out[f"grad_w.{t}"] = repr(float(weighting.last["grad_w"][i]))
        out[f"w.{t}"] = repr(float(weighting.w[i]))
    return out


def onednn_kernels(fn: Callable[[], Any]) -> tuple[Any, dict[str, str]]:
    """``fn()`` and the oneDNN primitives it executed: ``{"kind,impl,prop,formats,attrs,alg,shape":
    count}``, read from oneDNN's verbose log (file descriptor 1 goes to a scratch file meanwhile)."""
    libc = ctypes.CDLL(None)
    sys.stdout.flush()
    libc.fflush(None)
    saved = os.dup(1)
    with tempfile.TemporaryFile(mode="w+b") as log:
        os.dup2(log.fileno(), 1)
        try:
            with torch.backends.mkldnn.verbose(torch.backends.mkldnn.VERBOSE_ON):
                result = fn()
        finally:
            libc.fflush(None)
            os.dup2(saved, 1)
            os.close(saved)
        log.seek(0)
        lines = log.read().decode(errors="replace").splitlines()
    counts: dict[str, int] = {}
    for line in lines:
        fields = line.split(",")
        if line.startswith("onednn_verbose") and "exec" in fields:
            key = ",".join(fields[fields.index("exec") + 2:-1])  # from the kind on, without the time
            counts[key] = counts.get(key, 0) + 1
    return result, {k: str(v) for k, v in sorted(counts.items())}


def differences(mine: dict, other: dict) -> list[str]:
    """Per model and phase: how many entries differ (or exist on one side only) and the first;
    a phase or model one side lacks is named as such."""
    lines = [f"this machine: {mine['cpu']}", f"other:        {other['cpu']}"]
    if mine.get("code") != other.get("code"):
        lines.append(f"warning: other code ({other.get('code', 'not recorded')} vs {mine.get('code')}): "
                     "hashes may differ because of the code, not the machine")
    for model, phases in mine["models"].items():
        theirs = other["models"].get(model)
        if theirs is None:
            lines.append(f"{model}: not in the other fingerprint")
            continue
        for phase in list(phases) + [p for p in theirs if p not in phases]:
            if phase not in phases or phase not in theirs:
                side = "the other" if phase in phases else "this"
                lines.append(f"{model:>24} {phase:>7}: not in {side} fingerprint")
                continue
            a, b = phases[phase], theirs[phase]
            keys = list(a) + [k for k in b if k not in a]
            diff = [k for k in keys if a.get(k) != b.get(k)]
            where = f"first at {diff[0]}" if diff else "identical"
            lines.append(f"{model:>24} {phase:>7}: {len(diff):4d} of {len(keys):4d} differ; {where}")
    return lines


def _model(model_id: str, dataset_id: str, weights: Path | None) -> nn.Module:
    """The model as every fingerprint starts it: built under seed 0, then ``weights`` if given."""
    torch.manual_seed(0)
    model = build_model(model_id, dataset_id)
    if weights is not None:
        try:  # weights_only: a crafted checkpoint cannot run code (runs/ can come from a shared DVC cache)
            state = torch.load(weights, map_location="cpu", weights_only=True)
            model.load_state_dict(state["model"] if isinstance(state, dict) and "model" in state else state)
        except (RuntimeError, KeyError, TypeError, EOFError, pickle.UnpicklingError) as err:
            raise SystemExit(f"error: {weights}: expected a training checkpoint of {model_id} "
                             f"({str(err).splitlines()[0]})") from None
        torch.manual_seed(0)  # the same dropout draws as without --weights
    return model


def fingerprint_model(model_id: str, args: argparse.Namespace, params: Any) -> dict[str, dict[str, str]]:
    """Every phase of one model (module doc)."""
    recipe = params.train.models[model_id]
    de_factor = de_loss_factor(recipe.de_loss) if recipe.de_loss is not None else 1.0
    loader = make_loader(args.cache, "train", lidar_channels=lidar_channels(model_id),
                         batch_size=params.train.batch_size)
    batch = to_device(next(iter(loader)), "cpu", DATASET_SPECS[args.dataset].n_seg)
    model = _model(model_id, args.dataset, args.weights)
    phases, kernels = onednn_kernels(lambda: fingerprint(model, batch, de_factor))
    phases["kernels"] = kernels
    if recipe.weighting == "mgn":
        model = _model(model_id, args.dataset, args.weights)
        weighting = build_weighting(recipe, model.tasks, model, plateau_patience=params.train.plateau_patience,
                                    plateau_factor=params.train.plateau_factor)
        phases["mgn"] = mgn_fingerprint(model, batch, weighting, de_factor)
    return phases


def main() -> None:
    ap = Parser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--cache", default="data/cache/A")
    ap.add_argument("--dataset", default="A", choices=dataset_ids(), help="the dataset id of --cache (class counts)")
    ap.add_argument("--models", nargs="+", default=DEFAULT_MODELS, choices=model_ids())
    ap.add_argument("--weights", type=Path, default=None, help="a training checkpoint (best.pt/last.pt) to start from")
    ap.add_argument("--out", type=Path, default=None, help="write the fingerprint as JSON here")
    ap.add_argument("--compare", type=Path, default=None, help="a fingerprint recorded on another machine")
    args = ap.parse_args()

    if not (Path(args.cache) / "meta.json").is_file():
        raise SystemExit(f"error: {args.cache}: no cache (meta.json) there; build it with "
                         f"`bin/venv dvc repro preprocess@{args.dataset}` or pass --cache")
    for path, what in ((args.compare, "a JSON written by --out"), (args.weights, "a training checkpoint")):
        if path is not None and not path.is_file():
            raise SystemExit(f"error: {path}: file not found ({what})")
    params = load_params()
    unknown = [m for m in args.models if m not in params.train.models]
    if unknown:
        raise SystemExit(f"error: --models: {unknown} have no train.models recipe in params.yaml")
    set_threads(params.train.num_threads)
    torch.use_deterministic_algorithms(True, warn_only=True)  # as training runs
    warnings.filterwarnings("ignore", message=".*does not have a deterministic implementation")
    result = {"cpu": cpu_name(), "torch": torch.__version__, "threads": params.train.num_threads,
              "code": source_fingerprint(), "weights": str(args.weights) if args.weights else None,
              "models": {m: fingerprint_model(m, args, params) for m in args.models}}
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(result, indent=1, sort_keys=True) + "\n")
    if args.compare:
        print("\n".join(differences(result, json.loads(args.compare.read_text()))))
    else:
        for model_id, phases in result["models"].items():
            print(model_id, {p: len(v) for p, v in phases.items()})


if __name__ == "__main__":
    main()
