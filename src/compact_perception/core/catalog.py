"""The registries of what the pipeline knows: tasks, datasets and models (issue "one source of
truth"). Id lists, report labels, table columns and metric directions all derive from here;
``dvc.yaml``'s lists are checked against it (tests/test_registries.py). Loss-weighting methods
register their classes in :mod:`compact_perception.learning.weighting` (each with its params schema); their
report label and whether their weights adapt live here (:data:`WEIGHTING_METHODS`), so the report
reads them without importing torch, and a class registered under an id missing here fails.

This module imports nothing heavy (no torch), so the config and every stage can read it.

- a **task** (paper section III-B): its test metric (``metric``, a per-frame score key), the
  labels of task and metric, and whether lower or higher is better; which tasks are class maps
  (:data:`CLASS_MAP_TASKS`, also scored by the arg-max rule: :data:`ARGMAX_TASKS`);
- a **score** over the four task metrics (paper eq. 6-7: TM, MV): Table II's columns are the task
  metrics, then the scores (:func:`table2_columns`); each entry carries its formula
  (``of_terms``, :mod:`.scores`), which evaluation, the report and the statistics call (the four
  test-set means' scores: :func:`scores_from_means`);
- a **dataset**: its report label and whether the embedded world simulates it;
- a **model** (its one registration; nothing else gives it an id): what the report shows of it
  (its label, its row in the tables, ``table_order``, and the tasks it gives "the combination of
  baselines", ``combination``, section V-D: GradNorm's DE and SS, PolarNet's LS, Chen et al.'s
  BEVP) and what training needs (its group, the LiDAR channels it reads, its tasks, the network
  module of ``learning/models`` whose ``build`` makes it, and its epoch cost, which orders a stage's
  runs);
- a **model group** (:data:`GROUPS`): the rules its models share: which params key lists their
  training seeds, whether their recipe takes the paper's depth loss (``de_loss``), whether a
  finished run exports its network to ONNX (``compact``: the paper's network; ``baseline``:
  section V-D);
- a **loss-weighting method**: its report label and whether its weights change during training
  (``adaptive``: the report draws those).

A data source's registration (its settings, label and stage deps) is in
:mod:`compact_perception.core.params.sources`, beside the params section it validates.

Adding a model (docs/extending.md): the model's entry here, a network module in
``learning/models/`` defining ``build`` (or an existing one), and in params.yaml its recipe
(``train.models.<id>``) and its id in ``model_ids`` (the list the train and evaluate stages read;
its group's entry here decides its seeds, its depth loss and its ONNX export).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Literal, Mapping, Optional

from .registry import Registry
from .scores import metric_variance, total_metric

__all__ = [
    "TaskInfo", "DatasetInfo", "ModelInfo", "TASKS", "DATASETS", "MODELS",
    "task_ids", "dataset_ids", "sim_dataset_ids", "model_ids", "compact_model_ids",
    "metric_of", "metric_keys", "higher_is_better", "model_label", "table_model_ids", "combination_source",
    "STOP_PLATEAU", "STOP_CAP",
    "ScoreInfo", "SCORES", "table2_columns", "per_frame_scores", "per_frame_columns", "column_label", "lower_is_better",
    "score_terms", "scores_from_means", "CLASS_MAP_TASKS", "ARGMAX_TASKS",
    "WeightingInfo", "WEIGHTING_METHODS", "weighting_info", "GroupInfo", "GROUPS", "group_of",
]


@dataclass(frozen=True)
class TaskInfo:
    """One task of the multi-task network."""

    label: str                               # "DE"
    metric: str                              # per-frame score key: "mae_de"
    metric_label: str                        # "MAE_DE"
    direction: Literal["lower", "higher"]    # which way the metric is better


@dataclass(frozen=True)
class ScoreInfo:
    """A score of a run over its four task metrics (paper section III-B, eq. 6-7)."""

    label: str                               # "TM"
    direction: Literal["lower", "higher"]    # which way the score is better
    equation: str                            # the paper's equation number: "6"
    per_frame: bool                          # also a per-frame score (TM is, MV is one number per run)
    of_terms: Callable[..., Any]             # the score of the four task metrics (mae_de, iou_ss, iou_ls,
                                             # iou_bevp; numbers or arrays, element-wise): .scores


@dataclass(frozen=True)
class DatasetInfo:
    label: str                               # "Set A"
    simulated: bool                          # written by the embedded world (generate stage)


@dataclass(frozen=True)
class GroupInfo:
    """The rules every model of a group shares."""

    seeds: Literal["dataset", "baseline"]    # its training seeds: datasets.<ds>.training.seeds ("dataset")
                                             # or baseline_seeds ("baseline")
    de_loss: bool                            # its recipe names the depth loss (train.recipe.de_loss:
                                             # huber or smooth_l1); a group without keeps its own losses
    onnx: bool                               # a finished run exports best.pt to ONNX; Table III runs it


GROUPS: Registry[GroupInfo] = Registry("model group", ordered=True)
GROUPS.register("compact")(GroupInfo(seeds="dataset", de_loss=True, onnx=True))     # the paper's network
GROUPS.register("baseline")(GroupInfo(seeds="baseline", de_loss=False, onnx=False))  # section V-D


@dataclass(frozen=True)
class ModelInfo:
    label: str                               # report label: "15L+MGN (Alg. 1)"
    group: str                               # its GROUPS entry: "compact" or "baseline"
    lidar_channels: int                      # LiDAR input channels read (1 or 15, section IV-C)
    tasks: tuple[str, ...]                   # task ids it predicts
    network: str                             # the module of learning/models whose build() makes it
    table_order: int                         # its row in Tables II/III (the paper's order, baselines first)
    combination: tuple[str, ...] = ()        # the tasks it gives the combination of baselines (section V-D)
    epoch_cost: float = 1.0                  # CPU time of an epoch relative to the compact model's (measured at
                                             # 32 px: summary.json train_seconds / epochs_run); it only orders a
                                             # stage's runs, the longest first, so no core idles at the end

    def __post_init__(self) -> None:
        if self.group not in GROUPS:
            raise KeyError(f"model {self.label!r}: unknown group {self.group!r}; known: {list(GROUPS.keys())}")


TASKS: Registry[TaskInfo] = Registry("task", ordered=True)
TASKS.register("de")(TaskInfo("DE", "mae_de", "MAE_DE", "lower"))
TASKS.register("ss")(TaskInfo("SS", "iou_ss", "IoU_SS", "higher"))
TASKS.register("ls")(TaskInfo("LS", "iou_ls", "IoU_LS", "higher"))
TASKS.register("bevp")(TaskInfo("BEVP", "iou_bevp", "IoU_BEVP", "higher"))

#: The class-map tasks (one class per pixel or cell, one-hot): evaluation leaves their unlabelled
#: pixels out of eq. (5) (``metrics.labelled_only``) ...
CLASS_MAP_TASKS: tuple[str, ...] = ("ss", "ls")
#: ... and scores them by the arg-max rule as well, beside eq. (5) (``metrics.iou_argmax_per_sample``;
#: the report's extra-metrics table shows those scores).
ARGMAX_TASKS: tuple[str, ...] = CLASS_MAP_TASKS

SCORES: Registry[ScoreInfo] = Registry("score", ordered=True)
SCORES.register("tm")(ScoreInfo("TM", "lower", "6", per_frame=True, of_terms=total_metric))
SCORES.register("mv")(ScoreInfo("MV", "lower", "7", per_frame=False, of_terms=metric_variance))

DATASETS: Registry[DatasetInfo] = Registry("dataset", ordered=True)
DATASETS.register("A")(DatasetInfo("Set A", True))
DATASETS.register("B")(DatasetInfo("Set B", True))
DATASETS.register("C")(DatasetInfo("Set C", True))
DATASETS.register("nuscenes")(DatasetInfo("nuScenes", False))

_ALL = ("de", "ss", "ls", "bevp")
MODELS: Registry[ModelInfo] = Registry("model", ordered=True)
MODELS.register("compact_1l")(ModelInfo("1L", "compact", 1, _ALL, "compact", table_order=10))
MODELS.register("compact_15l")(ModelInfo("15L", "compact", 15, _ALL, "compact", table_order=11))
MODELS.register("compact_15l_mgn")(ModelInfo("15L+MGN (Alg. 1)", "compact", 15, _ALL, "compact", table_order=12))
MODELS.register("compact_15l_mgn_authors")(ModelInfo("15L+MGN (authors' code)", "compact", 15, _ALL, "compact",
                                                     table_order=13))
MODELS.register("gradnorm_segnet")(ModelInfo("GradNorm", "baseline", 15, ("de", "ss"), "segnet",
                                             table_order=2, combination=("de", "ss"), epoch_cost=5.5))
MODELS.register("polarnet")(ModelInfo("PolarNet", "baseline", 15, ("ls",), "polarnet", table_order=1,
                                      combination=("ls",), epoch_cost=1.0))
MODELS.register("chen_bev")(ModelInfo("Chen et al.", "baseline", 15, ("bevp",), "chen", table_order=0,
                                      combination=("bevp",), epoch_cost=0.35))



@dataclass(frozen=True)
class WeightingInfo:
    label: str                               # report label: "MGN (Algorithm 1)"
    adaptive: bool = True                    # its loss weights change during training


#: The loss-weighting methods (``ModelRecipe.weighting``); their classes are in
#: :mod:`compact_perception.learning.weighting`, which takes ``label`` and ``adaptive`` from here.
WEIGHTING_METHODS: Registry[WeightingInfo] = Registry("loss weighting")
WEIGHTING_METHODS.register("static")(WeightingInfo("Equal static weights", adaptive=False))
WEIGHTING_METHODS.register("none")(WeightingInfo("No weighting (plain sum)", adaptive=False))
WEIGHTING_METHODS.register("mgn")(WeightingInfo("MGN (Algorithm 1)"))
WEIGHTING_METHODS.register("gradnorm")(WeightingInfo("GradNorm (Chen et al. 2018)"))
WEIGHTING_METHODS.register("uw")(WeightingInfo("Uncertainty weighting (Kendall et al. 2018)"))
WEIGHTING_METHODS.register("dwa")(WeightingInfo("DWA (Liu et al. 2019)"))
WEIGHTING_METHODS.register("pcgrad")(WeightingInfo("PCGrad (Yu et al. 2020)"))
WEIGHTING_METHODS.register("cagrad")(WeightingInfo("CAGrad (Liu et al. 2021)"))
WEIGHTING_METHODS.register("single")(WeightingInfo("Single-task network", adaptive=False))

def task_ids() -> tuple[str, ...]:
    return tuple(TASKS.keys())


def dataset_ids() -> tuple[str, ...]:
    return tuple(DATASETS.keys())


def sim_dataset_ids() -> tuple[str, ...]:
    return tuple(k for k in DATASETS.keys() if DATASETS[k].simulated)


def model_ids() -> tuple[str, ...]:
    return tuple(MODELS.keys())


def compact_model_ids() -> tuple[str, ...]:
    return tuple(k for k in MODELS.keys() if MODELS[k].group == "compact")


def metric_of(task: str) -> str:
    """The per-frame test metric key of ``task`` (``de`` -> ``mae_de``)."""
    return TASKS[task].metric


def metric_keys() -> tuple[str, ...]:
    """The four task metrics in task order (the terms of TM, eq. 6)."""
    return tuple(TASKS[t].metric for t in TASKS.keys())


def higher_is_better(metric: str) -> bool:
    """Direction of a task metric key (``mae_de`` lower, ``iou_*`` higher)."""
    for t in TASKS.keys():
        if TASKS[t].metric == metric:
            return TASKS[t].direction == "higher"
    raise KeyError(f"unknown metric {metric!r}; known: {list(metric_keys())}")


def table2_columns() -> tuple[str, ...]:
    """Table II's columns: the task metrics in task order, then the scores over them (TM, MV)."""
    return metric_keys() + tuple(SCORES.keys())


def score_terms(scores: Mapping[str, Any]) -> Optional[tuple[Any, ...]]:
    """The four terms of TM / MV (eq. 6, 7) from ``scores``, in :func:`metric_keys` order (the
    arguments of every score's ``of_terms``); None if any is missing."""
    keys = metric_keys()
    if not all(k in scores for k in keys):
        return None
    return tuple(scores[k] for k in keys)


def scores_from_means(means: Mapping[str, float]) -> dict[str, float]:
    """TM (eq. 6) and MV (eq. 7) from the four **test-set means** ``mae_de``, ``iou_ss``,
    ``iou_ls``, ``iou_bevp`` (Table II's definition); empty if any of the four is missing."""
    terms = score_terms(means)
    if terms is None:
        return {}
    vals = [float(v) for v in terms]
    return {k: float(SCORES[k].of_terms(*vals)) for k in SCORES.keys()}


def per_frame_scores() -> tuple[str, ...]:
    """The scores that are also per-frame scores (TM), in registry order."""
    return tuple(k for k in SCORES.keys() if SCORES[k].per_frame)


def per_frame_columns() -> tuple[str, ...]:
    """The columns a run scores per test frame: the task metrics and the per-frame scores (TM)."""
    return metric_keys() + per_frame_scores()


def column_label(column: str) -> str:
    """The label of a Table II column: a task metric's (``mae_de`` -> ``MAE_DE``) or a score's (``TM``)."""
    if column in SCORES:
        return SCORES[column].label
    for t in TASKS.keys():
        if TASKS[t].metric == column:
            return TASKS[t].metric_label
    raise KeyError(f"unknown Table II column {column!r}; known: {list(table2_columns())}")


def lower_is_better(column: str) -> bool:
    """Direction of a Table II column: a task metric (:func:`higher_is_better`) or a score."""
    return SCORES[column].direction == "lower" if column in SCORES else not higher_is_better(column)


def model_label(model_id: str) -> str:
    return MODELS[model_id].label


def table_model_ids() -> tuple[str, ...]:
    """Every model in the order of the report's tables (:attr:`ModelInfo.table_order`)."""
    return tuple(sorted(MODELS.keys(), key=lambda m: MODELS[m].table_order))


def combination_source() -> dict[str, str]:
    """The combination of baselines (section V-D, SPEC 6): task metric -> the model it comes from,
    in task order; each task must be given by exactly one model."""
    out: dict[str, str] = {}
    for t in TASKS.keys():
        givers = [m for m in MODELS.keys() if t in MODELS[m].combination]
        if len(givers) != 1:
            raise KeyError(f"task {t!r}: the combination needs exactly one model giving it, got {givers}")
        out[TASKS[t].metric] = givers[0]
    return out


def group_of(model_id: str) -> GroupInfo:
    """The rules of ``model_id``'s group (its seeds key, depth loss, ONNX export)."""
    return GROUPS[MODELS[model_id].group]


def weighting_info(key: str) -> WeightingInfo:
    """The report label and ``adaptive`` flag of the loss weighting ``key`` (no torch import)."""
    return WEIGHTING_METHODS[key]


#: A run's ``summary.json`` ``stop_reason`` (written by training, read by the report): early
#: stopping ended the run (``train.early_stop_patience`` epochs without a new best validation
#: score: learning stopped, the run converged) ...
STOP_PLATEAU = "plateau"
#: ... or the epoch cap did (``datasets.<ds>.training.max_epochs`` or the recipe's).
STOP_CAP = "max_epochs"
