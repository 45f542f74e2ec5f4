"""The loss-balancing study (beyond the paper): one arm = the compact 15L network trained with one
loss-weighting method, at one seed, on every dataset of ``study.datasets`` (set A at the default
scale, all four at the paper's), then scored on the test split like any run.

The arms come from params.yaml (``study.arms``: the weighting id and its settings); the recipe is
``study.base_model``'s with the weighting replaced (:meth:`~compact_perception.core.config.Params.study_recipe`),
so every arm differs from the others in the weighting only. The paper's own forms (static weights,
MGN as printed, MGN as the authors ran it) are the main runs of compact_15l, compact_15l_mgn and
compact_15l_mgn_authors, not repeated here.
"""
from __future__ import annotations

import logging
from pathlib import Path

from .core.config import Params
from .evaluate import evaluate_run
from .core.layout import study_paths
from .training.train import train_run

log = logging.getLogger(__name__)

__all__ = ["run_arm"]


def run_arm(params: Params, arm: str, seed: int, root: Path | str = ".") -> list[dict]:
    """Train and evaluate study arm ``arm`` at training seed ``seed`` on each study dataset;
    returns the test results (one dict per dataset)."""
    recipe = params.study_recipe(arm)
    base = params.study.base_model
    results = []
    for ds in params.study.datasets.at(params.scale):
        paths = study_paths(arm, seed, ds, root)
        cache = Path(root) / "data" / "cache" / ds
        log.info("study arm %s (weighting %s), seed %d, dataset %s", arm, recipe.weighting, seed, ds)
        train_run(params, ds, base, seed, cache, paths.run_dir, recipe=recipe, recipe_key=f"study.arms.{arm}",
                  export_onnx=False)
        results.append(evaluate_run(ds, base, cache, paths.run_dir, paths.metrics_path, paths.eval_dir,
                                    device_pref=params.train.device, save_predictions=0,
                                    num_threads=params.train.num_threads))
    return results
