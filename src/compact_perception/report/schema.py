"""What the report's tables are made of, derived from the registries
(:mod:`compact_perception.core.catalog`); no report module lists a model, dataset, metric or
label of its own.

- **rows**: every model in its ``table_order`` (the paper's order, baselines first), with the
  combination of baselines (section V-D, SPEC 6) right after the last model that gives it a
  task (:attr:`~compact_perception.core.catalog.ModelInfo.combination`); the trivial predictors
  of the floor (SPEC 8, :data:`compact_perception.core.floor_rule.FLOOR_PREDICTORS`) with their labels;
- **columns** of Table II: the task metrics in task order, then TM and MV (eq. 6-7), with their
  labels, directions, the statistic their interval uses (:mod:`compact_perception.stats`) and the
  contrast "row a beats row b" (:func:`beats`);
- **columns** of Table III (:data:`TABLE3_COLUMNS`): what a reproduced row holds, its header and
  digits, and the paper's printed field it is compared with;
- the two **MGN forms** (Algorithm 1 as printed, the authors' code) and the paper's row each
  is compared with (the paper prints one 15L+MGN row);
- the **loss-weight names** a weighted run logs (``w_<task>``, dvclive and ``summary.json``).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable, Literal, Optional

import numpy as np

from ..core import catalog
from ..core.floor_rule import FLOOR_PREDICTORS
from ..stats import STATISTICS, stat_mean

__all__ = [
    "COMBINATION", "COMBINATION_MODELS", "COMBINATION_SOURCE", "COMPACT", "ROW_ORDER", "ROW_LABEL", "DATASET_LABEL",
    "TASK_COLUMNS", "TABLE2_COLUMNS", "PER_FRAME_COLUMNS", "LOWER_IS_BETTER", "COLUMN_MD", "COLUMN_TEX",
    "column_stat", "stat_columns", "MGN_FORMS", "PAPER_MGN", "paper_row", "WEIGHT_KEYS", "WEIGHT_LABEL",
    "weight_key", "weight_task", "row_ids", "combination_models", "WEIGHT_PREFIX", "FLOOR_IDS", "FLOOR_LABEL",
    "METRIC_TASK", "beats", "Table3Column", "TABLE3_COLUMNS", "TABLE3",
]

# ----------------------------------------------------------------------------- rows
#: The row id of the combination of baselines.
COMBINATION = "combination"


def combination_models() -> tuple[str, ...]:
    """The models that give the combination its tasks (:attr:`~..core.catalog.ModelInfo.combination`),
    in table order."""
    return tuple(m for m in catalog.table_model_ids() if catalog.MODELS[m].combination)


def row_ids() -> tuple[str, ...]:
    """Every model in table order, the combination right after the last model that gives it a task."""
    models = catalog.table_model_ids()
    at = max(models.index(m) for m in combination_models()) + 1
    return models[:at] + (COMBINATION,) + models[at:]


COMBINATION_MODELS: tuple[str, ...] = combination_models()
#: Task metric -> the model it comes from in the combination.
COMBINATION_SOURCE: dict[str, str] = catalog.combination_source()
COMPACT: tuple[str, ...] = catalog.compact_model_ids()
ROW_ORDER: tuple[str, ...] = row_ids()
ROW_LABEL: dict[str, str] = {**{m: catalog.model_label(m) for m in catalog.model_ids()}, COMBINATION: "Combination"}
DATASET_LABEL: dict[str, str] = {d: catalog.DATASETS[d].label for d in catalog.dataset_ids()}
#: The trivial predictors of the floor, in the order of their rows (first in every dataset's block).
FLOOR_IDS: tuple[str, ...] = tuple(FLOOR_PREDICTORS.keys())
FLOOR_LABEL: dict[str, str] = {t: FLOOR_PREDICTORS[t] for t in FLOOR_IDS}

# ----------------------------------------------------------------------------- columns
TASK_COLUMNS: tuple[str, ...] = catalog.metric_keys()
TABLE2_COLUMNS: tuple[str, ...] = catalog.table2_columns()
#: The columns a ``per_frame.csv`` holds per test frame (the task metrics and TM).
PER_FRAME_COLUMNS: tuple[str, ...] = catalog.per_frame_columns()
LOWER_IS_BETTER: frozenset[str] = frozenset(c for c in TABLE2_COLUMNS if catalog.lower_is_better(c))
COLUMN_MD: dict[str, str] = {c: catalog.column_label(c) for c in TABLE2_COLUMNS}
#: Task metric -> its task's short label (``iou_ls`` -> ``LS``).
METRIC_TASK: dict[str, str] = {catalog.metric_of(t): catalog.TASKS[t].label for t in catalog.task_ids()}


def _tex_label(label: str) -> str:
    """``MAE_DE`` -> ``$MAE_{DE}$``, ``TM`` -> ``$TM$``."""
    head, _, sub = label.partition("_")
    return f"${head}_{{{sub}}}$" if sub else f"${head}$"


COLUMN_TEX: dict[str, str] = {c: _tex_label(COLUMN_MD[c]) for c in TABLE2_COLUMNS}


def column_stat(col: str) -> Callable[[np.ndarray], np.ndarray]:
    """The interval's statistic (:func:`compact_perception.stats.interval`) of a Table II column:
    the mean of a task metric, or a score's formula of the four task means (TM, eq. 6; MV, eq. 7:
    its entry in ``catalog.SCORES``, :data:`~compact_perception.stats.STATISTICS`); it reads the
    columns :func:`stat_columns` gives."""
    return stat_mean if col in TASK_COLUMNS else STATISTICS[col]


def stat_columns(col: str) -> list[str]:
    """The per-frame columns :func:`column_stat` of ``col`` reads: the metric itself, or every task
    metric (TM and MV): also the metrics on which a row must be above the floor for ``col``."""
    return [col] if col in TASK_COLUMNS else list(TASK_COLUMNS)


def beats(col: str) -> Callable[[np.ndarray], np.ndarray]:
    """The contrast "row 0 beats row 1 on ``col``" of two rows' values (``v[..., 0]``, ``v[..., 1]``),
    positive when it does: ``v1 - v0`` where lower is better, ``v0 - v1`` otherwise."""
    if col in LOWER_IS_BETTER:
        return lambda v: v[..., 1] - v[..., 0]
    return lambda v: v[..., 0] - v[..., 1]


# ----------------------------------------------------------------------------- Table III's columns
@dataclass(frozen=True)
class Table3Column:
    """A column of Table III: the one definition the reproduced table (:mod:`.tables.table3`), the
    paper's printed rows (:mod:`.paper`), their comparison (:mod:`.tables.comparison`) and the
    efficiency claims (:mod:`.claims`) read.

    ``key``: what a reproduced row holds (efficiency.json's key, table3.csv's column); ``header``:
    its header on a CPU host, ``gpu_header`` on a GPU host where that differs; ``kind``: a
    ``count`` (printed whole, with thousands separators), a ``number`` (``decimals`` digits) or a
    ``text``; ``paper``: the field of paper_numbers.yaml's ``table3`` rows that prints it
    (``None``: the paper prints none), ``per_copy``: printed per copy of a model the row runs
    ``copies`` times (the row's value is that times its copies; a row that prints only its total,
    the combination, gives ``total``'s); ``compared``: its name in ``paper_vs_reproduced``
    (``None``: not compared there)."""

    key: str
    header: str
    kind: Literal["count", "number", "text"]
    decimals: int = 0
    paper: Optional[str] = None
    gpu_header: Optional[str] = None
    per_copy: bool = False
    total: Optional[str] = None
    compared: Optional[str] = None

    def header_on(self, gpu: bool) -> str:
        return self.gpu_header if gpu and self.gpu_header is not None else self.header

    def text(self, value: Any) -> str:
        """``value`` as the tables print it (empty where there is none)."""
        if value is None:
            return ""
        if self.kind == "count":
            return f"{int(round(value)):,}"
        if self.kind == "text":
            return str(value)
        return f"{value:.{self.decimals}f}"


#: Table III's columns, in the table's order.
TABLE3_COLUMNS: tuple[Table3Column, ...] = (
    Table3Column("params", "Params", "count", paper="params", per_copy=True, total="total_params", compared="params"),
    Table3Column("total_params", "Total params", "count", paper="total_params"),
    Table3Column("size_mb", "Size (MB)", "number", 3, paper="size_mb", per_copy=True, total="total_size_mb",
                 compared="size_mb"),
    Table3Column("total_size_mb", "Total size (MB)", "number", 3, paper="total_size_mb"),
    Table3Column("peak_memory_mb", "Peak memory, CPU estimate (MB)", "number", 1, paper="gpu_memory_mb",
                 gpu_header="GPU memory (MB)", compared="memory_mb"),
    Table3Column("fps", "FPS (CPU)", "number", 2, paper="fps", gpu_header="FPS", compared="fps"),
    Table3Column("latency_ms", "Latency (ms)", "number", 2),
    Table3Column("onnx_fps", "ONNX Runtime FPS (CPU)", "number", 2),
    Table3Column("onnx_latency_ms", "ONNX Runtime latency (ms)", "number", 2),
    Table3Column("device", "Device", "text"),
)
TABLE3: dict[str, Table3Column] = {c.key: c for c in TABLE3_COLUMNS}


# ----------------------------------------------------------------------------- the two MGN forms
#: The MGN forms each tested by the claims about 15L+MGN: model id -> variant label.
MGN_FORMS: dict[str, str] = {m: v for m, v in (("compact_15l_mgn", "Alg. 1"),
                                               ("compact_15l_mgn_authors", "authors' code")) if m in catalog.MODELS}
#: The paper's one 15L+MGN row of Table II (it came from the authors' code); both forms are compared with it.
PAPER_MGN = "compact_15l_mgn"


def paper_row(row_id: str) -> str:
    """The paper's row a row of this run is compared with (both MGN forms: :data:`PAPER_MGN`)."""
    return PAPER_MGN if row_id in MGN_FORMS else row_id


# ----------------------------------------------------------------------------- loss weights
WEIGHT_PREFIX = "w_"


def weight_key(task: str) -> str:
    """The name a run logs the loss weight of ``task`` under: ``de`` -> ``w_de``."""
    return WEIGHT_PREFIX + task


def weight_task(name: str) -> str:
    """The task of a logged loss-weight name: ``w_de`` -> ``de``."""
    return name[len(WEIGHT_PREFIX):]


#: Every task's loss-weight name, in task order.
WEIGHT_KEYS: tuple[str, ...] = tuple(weight_key(t) for t in catalog.task_ids())
WEIGHT_LABEL: dict[str, str] = {weight_key(t): catalog.TASKS[t].label for t in catalog.task_ids()}
