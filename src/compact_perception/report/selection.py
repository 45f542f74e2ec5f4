"""What the report shows: the datasets and models the params selected, nothing else.

``dataset_ids`` and ``model_ids`` (params.yaml) choose what the train and evaluate stages run;
the report reads the same lists (in the registry's order, so a full selection gives the report
it always gave), the seeds of each, the study's arms on the study datasets among them, and the
benchmark's figures of the selected models only. A dataset or model left out is never read:
``results/`` files that git tracks from another run (the last default run's sets B, C, nuScenes)
do not fill a table, a figure or the headline of this one.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Optional

from ..core.catalog import MODELS, dataset_ids, model_ids, sim_dataset_ids
from .study import StudySpec

__all__ = ["ReportSelection", "select", "selected_efficiency"]


@dataclass(frozen=True)
class ReportSelection:
    """The report's datasets and models (registry order), their seeds, and the study (``None``
    where params give none)."""

    datasets: tuple[str, ...]
    models: tuple[str, ...]
    seeds: dict[str, dict[str, list[int]]]
    study: Optional[StudySpec]


def select(params: Any) -> ReportSelection:
    """The selection of validated params: ``dataset_ids``, ``model_ids`` (each model's seeds on
    each dataset: ``Params.seeds_of``) and ``study.datasets`` at the scale, within ``dataset_ids``."""
    datasets = tuple(d for d in dataset_ids() if d in params.dataset_ids)
    models = tuple(m for m in model_ids() if m in params.model_ids)
    seeds = {ds: {m: [int(k) for k in params.seeds_of(MODELS[m].group, ds)] for m in models} for ds in datasets}
    spec = StudySpec.from_params(params)
    study = dataclasses.replace(spec, datasets=tuple(d for d in spec.datasets if d in datasets),
                                seeds={d: s for d, s in spec.seeds.items() if d in datasets})
    return ReportSelection(datasets, models, seeds, study)


def selected_efficiency(efficiency: Optional[dict], datasets: tuple[str, ...] | list[str],
                        models: tuple[str, ...] | list[str]) -> Optional[dict]:
    """``results/benchmark/efficiency.json`` cut to the selected models, and to the networks of the
    selected datasets (the benchmark measures one simulated set for all of them, and nuScenes):
    a benchmarked dataset is kept where a selected dataset shares its networks."""
    if efficiency is None or not isinstance(efficiency.get("models"), dict):
        return efficiency
    sims = set(sim_dataset_ids())
    wanted = set(datasets)
    keep = {}
    for ds, per_model in efficiency["models"].items():
        if not (ds in wanted or (ds in sims and wanted & sims)):
            continue
        keep[ds] = {m: v for m, v in per_model.items() if m in models} if isinstance(per_model, dict) else per_model
    return {**efficiency, "models": keep}
