"""What training at `full` or `paper` costs on one GPU, per dataset and in all, from a measured rate.

    .venv/bin/python benchmarks/gpu_cost.py [--params params.yaml] [--epochs 45]
        [--rate full=430 paper=400]

For each dataset of a scale it counts, from params.yaml at that scale, the runs a `train@<ds>` stage
trains (each compact model per training seed, the loss-balancing study's arms on a study dataset,
each baseline per baseline seed) and their training frames (the train split: a simulated set's
``split_ratio`` of its frames; the simulated nuScenes set's 3:1:1 split of its scenes, the
project's own split), and prints the samples one epoch of every run trains, the hours at
``--epochs`` epochs a run (default 45: the compact 15L network's count to its plateau at `full`
on set A, measured on a CPU) and at each run's epoch cap (the most early stopping allows), at
``--rate`` samples per second for the GPU (default: the first H200 measurement, 12 compact runs
sharing the GPU at batch 6 in fp32: about 430 together at 32 px, `full`'s size, about 400 at
128 px, `paper`'s; measured before the step lost its host reads and gained CUDA graphs).

The rate is a compact network's. The baselines' runs are counted apart: their rates on a GPU
have not been measured (GradNorm SegNet's four VGG16s cost about four compact runs on a CPU), so
their hours are printed at the compact rate and marked as such. Validation and the test split's
evaluation add a fraction of a training epoch's work and are left out.
"""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from flags import Parser, count  # noqa: E402

from compact_perception.core import catalog  # noqa: E402
from compact_perception.core.params import ParamsError, load_params  # noqa: E402
from compact_perception.data.nuscenes.split import split_sizes  # noqa: E402

#: samples/s of the first H200 measurement (12 compact runs sharing one GPU, batch 6, fp32)
MEASURED_RATE = {"full": 430.0, "paper": 400.0}
#: A rate past this is no GPU's (about 2000 times the measured one): a typo, refused.
MAX_RATE = 1.0e6


def parse_rates(items: list[str]) -> dict[str, float]:
    """``MEASURED_RATE`` with each ``SCALE=SAMPLES_PER_S`` of ``items`` in its place: ``ValueError``
    with one line for an unknown scale (``fulll``) or a rate that is not a finite number above 0."""
    rates = dict(MEASURED_RATE)
    for item in items:
        scale, _, value = item.partition("=")
        try:
            rate = float(value)
        except ValueError:
            raise ValueError(f"--rate {item!r}: expected SCALE=SAMPLES_PER_S, e.g. full=430") from None
        if scale not in MEASURED_RATE:
            raise ValueError(f"--rate {item!r}: unknown scale {scale!r} (expected {' or '.join(MEASURED_RATE)}), "
                             "e.g. full=430")
        if not (math.isfinite(rate) and 0 < rate <= MAX_RATE):
            raise ValueError(f"--rate {item!r}: expected samples/s above 0 and at most {MAX_RATE:g}, e.g. full=430")
        rates[scale] = rate
    return rates


def train_frames(params, dataset: str) -> int:
    """The training frames of ``dataset`` at the params' scale."""
    if dataset == "nuscenes":
        scenes = split_sizes(params.nuscenes_sim_scenes)[0]
        return scenes * params.datasets.nuscenes.sim_samples_per_scene
    return params.split_counts_of(dataset)["train"]


def runs_of(params, dataset: str) -> dict[str, list[tuple[str, int]]]:
    """``compact`` and ``baseline`` runs of the dataset's stage: (model or arm, epoch cap) each."""
    out: dict[str, list[tuple[str, int]]] = {"compact": [], "baseline": []}
    for model in params.model_ids:
        group = catalog.MODELS[model].group
        cap = params.max_epochs_of(params.train.models[model], dataset)
        out[group] += [(model, cap)] * len(params.seeds_of(group, dataset))
    if dataset in params.study_datasets:
        base = params.train.models[params.study.base_model]
        cap = params.max_epochs_of(base, dataset)
        out["compact"] += [(arm, cap) for arm in params.study.arm_ids] * len(params.seeds_of("compact", dataset))
    return out


def main() -> None:
    ap = Parser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--params", default=str(ROOT / "params.yaml"))
    ap.add_argument("--epochs", type=count(1, 10_000), default=45, help="epochs a run trains (early stopping ends it)")
    ap.add_argument("--rate", nargs="*", default=[], metavar="SCALE=SAMPLES_PER_S",
                    help="samples/s of the GPU at a scale (default: full=430 paper=400, the first H200 measurement)")
    args = ap.parse_args()
    try:
        rates = parse_rates(args.rate)
    except ValueError as err:
        sys.exit(f"error: {err}")
    try:
        base = load_params(Path(args.params))
    except ParamsError as err:
        sys.exit(f"error: {err}")
    for scale in ("full", "paper"):
        params = base.model_copy(update={"scale": scale})
        rate = rates[scale]
        print(f"\nscale {scale}: {params.resolution} px, {rate:.0f} samples/s, {args.epochs} epochs a run "
              "(at each run's cap in brackets)")
        print(f"{'dataset':<10s} {'train frames':>12s} {'compact runs':>12s} {'compact h':>16s} "
              f"{'baseline runs':>13s} {'baseline h (compact rate)':>26s}")
        total = {"compact": [0.0, 0.0], "baseline": [0.0, 0.0]}
        for ds in params.dataset_ids:
            frames = train_frames(params, ds)
            runs = runs_of(params, ds)
            cells = []
            for group in ("compact", "baseline"):
                at = sum(frames * min(args.epochs, cap) for _, cap in runs[group]) / rate / 3600
                top = sum(frames * cap for _, cap in runs[group]) / rate / 3600
                total[group][0] += at
                total[group][1] += top
                cells.append(f"{at:6.1f} [{top:7.1f}]")
            print(f"{ds:<10s} {frames:12d} {len(runs['compact']):12d} {cells[0]:>16s} "
                  f"{len(runs['baseline']):13d} {cells[1]:>26s}")
        c, b = total["compact"], total["baseline"]
        print(f"{'all':<10s} {'':12s} {'':12s} {c[0]:6.1f} [{c[1]:7.1f}] {'':13s} {b[0]:6.1f} [{b[1]:7.1f}]".rstrip())
        print(f"in all: {c[0] + b[0]:.1f} h at {args.epochs} epochs a run, {c[1] + b[1]:.1f} h at the caps "
              "(baselines at the compact rate: unmeasured)")


if __name__ == "__main__":
    main()
