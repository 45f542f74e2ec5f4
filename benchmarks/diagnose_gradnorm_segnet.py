"""Why does GradNorm SegNet score IoU_SS ~ 0 at the default scale? (issue 12, item 3)

    .venv/bin/python benchmarks/diagnose_gradnorm_segnet.py --dataset A --epochs 3 \
        [--cache data/cache/A] [--out /tmp/gns/diag] [--arms gradnorm static] [--json /tmp/gns/diag.json]

Prints, for the test split of one dataset (the figures docs/gradnorm_segnet.md is based on):

1. a scoring check without training: the test ground truth fed back as the SS prediction (IoU 1
   expected), and the same class map as a softmax whose arg-max is right but whose top
   probability is 0.45 (what eq. (5)'s ``p > 0.5`` makes of a correct but unconfident softmax);
2. for the untrained network (the run's own initialisation) and for each trained arm
   (``gradnorm`` = the params.yaml recipe; ``static`` = the same recipe with equal static
   weights): IoU_SS as the pipeline scores it (eq. (5): softmax probabilities > 0.5, per
   frame, mean over the test frames = ``evaluate_run``'s ``iou_ss``), IoU_SS of the arg-max
   class map scored by the same eq. (5), the mIoU of the arg-max map, the mean top softmax
   probability and the share of pixels whose top probability exceeds 0.5, and MAE_DE;
3. the GradNorm weights w_de, w_ss at every training step (and the per-step SS / DE losses).

Runs write under ``--out`` (never in the repository). The cache can be made outside the
repository: ``python -m pipeline.generate --dataset A --out /tmp/gns/raw --figure-dir /tmp/gns/fig``
then ``python -m pipeline.preprocess --dataset A --raw-root /tmp/gns/raw --cache-root /tmp/gns/cache
--figures /tmp/gns/fig``.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import sys
import time
from pathlib import Path

import torch

from compact_perception.core.catalog import dataset_ids
from compact_perception.core.params import Scaled, load_params
from compact_perception.data.loader import make_loader, to_device
from compact_perception.core.determinism import set_threads
from compact_perception.learning.metrics import class_confusion, class_iou, compute_metrics_per_sample, mean_iou
from compact_perception.learning.models import build_model
from compact_perception.learning.plan import planned_run
from compact_perception.learning.training.train import run_seed, seed_everything, train_run
from compact_perception.learning.weighting.gradnorm import GradNormWeighting

sys.path.insert(0, str(Path(__file__).resolve().parent))
from flags import MAX_WORKERS, Parser, count  # noqa: E402

log = logging.getLogger("diagnose_gradnorm_segnet")
MODEL = "gradnorm_segnet"


def unconfident_softmax(target: torch.Tensor, top: float = 0.45) -> torch.Tensor:
    """A softmax whose arg-max is the ground-truth class with probability ``top`` (< 0.5) and
    the rest spread evenly over the other classes."""
    n = target.shape[2]
    return target * top + (1 - target) * (1 - top) / (n - 1)


@torch.no_grad()
def score(model: torch.nn.Module | None, cache: Path, n_cls: int, batch: int = 10) -> dict[str, float]:
    """Test-split SS/DE diagnostics of ``model`` (None: the scoring checks on the ground truth)."""
    loader = make_loader(cache, "test", 15, batch, shuffle=False, seed=0, num_workers=0, drop_last=False)
    dev = torch.device("cpu")
    acc: dict[str, list[torch.Tensor]] = {}
    tp = fp = fn = None
    for raw in loader:
        b = to_device(raw, dev, n_cls)
        gt = b["ss"]
        if model is None:
            variants = {"gt_as_prediction": gt, "unconfident_correct_softmax": unconfident_softmax(gt)}
            for k, p in variants.items():
                for how, tasks in (("eq5_probs", ()), ("argmax", ("ss",))):
                    acc.setdefault(f"iou_ss_{k}_{how}", []).append(
                        compute_metrics_per_sample({"ss": p}, b, argmax_tasks=tasks)["iou_ss"])
            continue
        out = model(b)
        prob = out["ss"]
        top = prob.amax(dim=2)
        per = compute_metrics_per_sample(out, b, argmax_tasks=())  # eq. (5) on the probabilities (the old scoring)
        per_arg = compute_metrics_per_sample(out, b, argmax_tasks=("ss",))  # the pipeline's scoring now
        for k, v in {"iou_ss_eq5_probs": per["iou_ss"], "iou_ss_eq5_argmax": per_arg["iou_ss"],
                     "mae_de": per["mae_de"], "top_prob_mean": top.double().mean(dim=(1, 2, 3)),
                     "share_top_prob_gt_0.5": (top > 0.5).double().mean(dim=(1, 2, 3))}.items():
            acc.setdefault(k, []).append(v)
        c = class_confusion(prob, gt)
        tp, fp, fn = c if tp is None else (tp + c[0], fp + c[1], fn + c[2])
    out_d = {k: float(torch.cat(v).mean()) for k, v in acc.items()}
    if tp is not None:
        out_d["miou_argmax"] = float(mean_iou(class_iou(tp.numpy(), fp.numpy(), fn.numpy())))
    return out_d


def load_best(model_id: str, ds: str, run_dir: Path) -> torch.nn.Module:
    m = build_model(model_id, ds)
    m.load_state_dict(torch.load(run_dir / "best.pt", map_location="cpu", weights_only=True)["model"])
    return m.eval()


def main(argv: list[str] | None = None) -> int:
    ap = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--dataset", default="A", choices=dataset_ids())
    ap.add_argument("--params", default="params.yaml")
    ap.add_argument("--cache", default=None, help="cache of the dataset (default data/cache/<dataset>)")
    ap.add_argument("--out", default="/tmp/gns/diag", help="run folders (outside the repository)")
    ap.add_argument("--epochs", type=count(1, 10_000), default=None,
                    help="epochs per arm (default: the gradnorm_segnet recipe's cap at params' scale)")
    ap.add_argument("--seed", type=count(0, 1_000_000), default=0, help="training seed")
    ap.add_argument("--arms", nargs="+", default=["gradnorm", "static"], choices=["gradnorm", "static"])
    ap.add_argument("--threads", type=count(1, MAX_WORKERS), default=2)
    ap.add_argument("--json", default=None, help="also write every figure to this JSON file")
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    set_threads(args.threads)
    params = load_params(args.params)
    cache = Path(args.cache or f"data/cache/{args.dataset}")
    meta = json.loads((cache / "meta.json").read_text())
    n_cls = len(meta["seg_classes"])
    base = params.train.models[MODEL]
    epochs = args.epochs or params.max_epochs_of(base, args.dataset)
    report: dict = {"dataset": args.dataset, "epochs": epochs, "n_classes": n_cls, "seed": args.seed}

    log.info("scoring check on the ground truth (no model)")
    report["scoring_check"] = score(None, cache, n_cls)

    log.info("untrained network (the runs' initialisation)")
    seed_everything(run_seed(params, args.dataset, args.seed))
    report["untrained"] = score(build_model(MODEL, args.dataset).eval(), cache, n_cls)

    steps: list[dict[str, float]] = []
    orig = GradNormWeighting.before_backward

    def recording(self, step, n_steps, losses, model):  # the w of every step, after its update
        orig(self, step, n_steps, losses, model)
        new = self._pending if self._pending is not None else self.w   # taken after the step's backward
        steps.append({"w_" + t: float(w) for t, w in zip(self.tasks, new)}
                     | {"loss_" + t: float(losses[t].detach()) for t in self.tasks})

    GradNormWeighting.before_backward = recording
    try:
        for arm in args.arms:
            upd: dict = {"max_epochs": Scaled[int](default=epochs, full=epochs, paper=epochs)}
            if arm == "static":
                upd |= {"weighting": "static", "gradnorm": None}
            recipe = base.model_copy(update=upd)
            run_dir = Path(args.out) / args.dataset / arm
            steps.clear()
            log.info("training %s (%s weighting, %d epochs) into %s", MODEL, recipe.weighting, epochs, run_dir)
            t0 = time.perf_counter()
            run = dataclasses.replace(planned_run(params, args.dataset, MODEL, args.seed), recipe=recipe,
                                      recipe_key=f"diagnose.{arm}",
                                      max_epochs=params.max_epochs_of(recipe, args.dataset))
            summary = train_run(params, run.moved(cache_dir=cache, run_dir=run_dir))
            res = {"train_seconds": round(time.perf_counter() - t0, 1), "best_epoch": summary["best_epoch"],
                   **score(load_best(MODEL, args.dataset, run_dir), cache, n_cls)}
            if arm == "gradnorm":
                res["steps"] = list(steps)
            report[arm] = res
    finally:
        GradNormWeighting.before_backward = orig

    print(f"\nGradNorm SegNet, dataset {args.dataset}, {epochs} epochs, seed {args.seed}, {n_cls} SS classes")
    print("scoring check (eq. 5, test GT): " + ", ".join(f"{k} {v:.4f}" for k, v in report["scoring_check"].items()))
    cols = ["iou_ss_eq5_probs", "iou_ss_eq5_argmax", "miou_argmax", "top_prob_mean", "share_top_prob_gt_0.5",
            "mae_de"]
    print(f"{'network':<12}" + "".join(f"{c:>24}" for c in cols))
    for name in ["untrained", *args.arms]:
        print(f"{name:<12}" + "".join(f"{report[name][c]:>24.4f}" for c in cols))
    if "gradnorm" in report:
        print("\nGradNorm per step: step  w_de  w_ss  loss_de  loss_ss")
        for i, s in enumerate(report["gradnorm"]["steps"]):
            print(f"  {i:4d}  {s['w_de']:.4f}  {s['w_ss']:.4f}  {s['loss_de']:.4f}  {s['loss_ss']:.4f}")
    if args.json:
        Path(args.json).parent.mkdir(parents=True, exist_ok=True)
        Path(args.json).write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
