"""The runs of one dataset (README "Scale"): what its ``train@<ds>`` stage trains and its
``evaluate@<ds>`` stage scores.

Every model of ``model_ids`` at its seeds (:meth:`~.core.config.Params.seeds_of`: the dataset's
``training.seeds`` for a compact model, ``baseline_seeds`` for a baseline) and, where the dataset
is one of ``study.datasets`` at this scale, every arm of the loss-balancing study at the seeds of
its base model (the compact 15L network with the arm's loss weighting; paper section III-C and
beyond). Each run's recipe is the model's (``train.models.<id>``) or the arm's
(:meth:`~.core.config.Params.study_recipe`), its epoch cap
:meth:`~.core.config.Params.max_epochs_of`, its folders :mod:`.core.layout`'s.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Optional

from .core import catalog
from .core.config import ModelRecipe
from .core.layout import STUDY_DIR, RunPaths, run_paths, study_paths

__all__ = ["PlannedRun", "dataset_runs", "recipe_of"]


@dataclass(frozen=True)
class PlannedRun:
    """One run of a dataset: a model at a seed, or a study arm (on its base model) at a seed."""

    dataset: str
    model: str                  # the network that is built (a study arm: study.base_model)
    seed: int                   # the training seed
    arm: Optional[str]          # the study arm, or None for the model's own recipe
    paths: RunPaths
    max_epochs: int             # its epoch cap

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

    @property
    def recipe_key(self) -> str:
        """The params key of its recipe: ``train.models.<id>`` or ``study.arms.<arm>``."""
        return f"study.arms.{self.arm}" if self.arm else f"train.models.{self.model}"


def recipe_of(params: Any, model: str, arm: Optional[str]) -> ModelRecipe:
    """The recipe of a run: the arm's (the base model's with its weighting replaced) or the model's."""
    return params.study_recipe(arm) if arm else params.train.models[model]


def dataset_runs(params: Any, dataset: str, root: Path | str = ".") -> list[PlannedRun]:
    """Every run of ``dataset`` in order: the models of ``model_ids`` (seed order), then the study's
    arms in ``study.arm_ids`` order when ``dataset`` is a study dataset at this scale."""
    out: list[PlannedRun] = []
    for m in params.model_ids:
        cap = params.max_epochs_of(params.train.models[m], dataset)
        for k in params.seeds_of(catalog.MODELS[m].group, dataset):
            out.append(PlannedRun(dataset, m, int(k), None, run_paths(dataset, m, k, root), cap))
    if dataset in params.study.datasets.at(params.scale):
        base = params.study.base_model
        for arm in params.study.arm_ids:
            cap = params.max_epochs_of(params.study_recipe(arm), dataset)
            for k in params.seeds_of(catalog.MODELS[base].group, dataset):
                out.append(PlannedRun(dataset, base, int(k), str(arm), study_paths(arm, k, dataset, root), cap))
    return out
