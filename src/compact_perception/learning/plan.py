"""The runs of one dataset (README "Scale"): what its ``train@<ds>`` stage trains and its
``evaluate@<ds>`` stage scores.

Every model of ``model_ids`` at its seeds (:meth:`~.core.params.Params.seeds_of`: the dataset's
``training.seeds`` for a compact model, ``baseline_seeds`` for a baseline) and, where the dataset
is one of ``study.datasets`` at this scale, every arm of the loss-balancing study at the seeds of
its base model (the compact 15L network with the arm's loss weighting; paper section III-C and
beyond).

Each run is planned here once, as one :class:`PlannedRun`: its ids, its recipe (the model's
``train.models.<id>`` or the arm's, :meth:`~.core.params.Params.study_recipe`) and that recipe's
params key, its epoch cap (:meth:`~.core.params.Params.max_epochs_of`), every path
(:class:`.core.layout.RunPaths`) and what it writes besides its scores (ONNX, saved predictions).
The stages hand it whole to their worker processes, the training loop and the evaluation
(``training.train.train_run``, ``evaluate.evaluate_run``); nothing below re-derives any of it.
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Optional

from ..core import catalog
from ..core.params import ModelRecipe
from ..core.layout import STUDY_DIR, RunPaths, paths_of_run

__all__ = ["PlannedRun", "dataset_runs", "planned_run", "recipe_of"]


@dataclass(frozen=True)
class PlannedRun:
    """One run of a dataset: a model at a seed, or a study arm (on its base model) at a seed.
    Plain data (it is pickled to a stage's worker processes)."""

    dataset: str
    model: str                  # the network that is built (a study arm: study.base_model)
    seed: int                   # the training seed
    arm: Optional[str]          # the study arm, or None for the model's own recipe
    recipe: ModelRecipe         # the model's recipe, or the arm's
    recipe_key: str             # its params key (train.models.<id>, study.arms.<arm>): messages name it
    paths: RunPaths             # every folder and file of the run, the cache it reads included
    max_epochs: int             # its epoch cap
    export_onnx: bool           # write the best network as ONNX too (a deployable model, not a study arm)
    save_predictions: bool      # save its first test frames' predictions for the figures (not a study arm)

    @property
    def cost(self) -> float:
        """Its expected CPU time, relative: the epoch cap times the model's ``epoch_cost``
        (the stage starts the longest runs first)."""
        return self.max_epochs * catalog.MODELS[self.model].epoch_cost

    @property
    def name(self) -> str:
        """``A/compact_15l/seed0`` or ``A/study/uw/seed0`` (progress, errors)."""
        what = f"{STUDY_DIR}/{self.arm}" if self.arm else self.model
        return f"{self.dataset}/{what}/seed{self.seed}"

    def moved(self, **paths: Path) -> "PlannedRun":
        """This run with some of its paths elsewhere (``run_dir=``, ``cache_dir=``, ...: the
        fields of :class:`RunPaths`): a stage's ``--out`` and ``--cache``, a test's folders."""
        return replace(self, paths=replace(self.paths, **{k: Path(v) for k, v in paths.items()}))


def recipe_of(params: Any, model: str, arm: Optional[str]) -> ModelRecipe:
    """The recipe of a run: the arm's (the base model's with its weighting replaced) or the model's."""
    return params.study_recipe(arm) if arm else params.train.models[model]


def planned_run(params: Any, dataset: str, model: str, seed: int, arm: Optional[str] = None,
                root: Path | str = ".") -> PlannedRun:
    """The run of ``model`` at training seed ``seed`` on ``dataset`` with its own recipe, or with
    study arm ``arm``'s (``model`` is then ``study.base_model``), its folders under ``root``."""
    if arm is not None and model != params.study.base_model:
        raise ValueError(f"study arm {arm}: trains study.base_model ({params.study.base_model}), not {model}")
    recipe = recipe_of(params, model, arm)
    paths = paths_of_run(dataset, model, seed, arm, root)
    return PlannedRun(dataset, model, int(seed), arm, recipe, recipe.key, paths,
                      max_epochs=params.max_epochs_of(recipe, dataset), export_onnx=arm is None,
                      save_predictions=arm is None)


def dataset_runs(params: Any, dataset: str, root: Path | str = ".") -> list[PlannedRun]:
    """Every run of ``dataset`` in order: the models of ``model_ids`` (seed order), then the study's
    arms in ``study.arm_ids`` order when ``dataset`` is a study dataset at this scale."""
    out = [planned_run(params, dataset, m, k, None, root)
           for m in params.model_ids for k in params.seeds_of(catalog.MODELS[m].group, dataset)]
    if dataset in params.study_datasets:
        base = params.study.base_model
        out += [planned_run(params, dataset, base, k, str(arm), root)
                for arm in params.study.arm_ids for k in params.seeds_of(catalog.MODELS[base].group, dataset)]
    return out
