"""The paper's published numbers (Tables II and III), kept as data in ``paper_numbers.yaml``.

The YAML is package data (``compact_perception/paper_numbers.yaml``); this module parses it
into small typed records. A Table II task cell is a :class:`PaperCell` (mean and the variance
over test frames; the paper prints ``<0.001`` for variances under its precision, kept as
``var_below=True``). Anything the paper leaves blank is ``None``. TM and MV of the paper's
rows are recomputed (tests, claims) with :mod:`compact_perception.core.scores`, the project's one
implementation of eq. (6)-(7).
"""
from __future__ import annotations

import functools
import logging
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any, Optional

import yaml

from ..core import catalog
from .schema import ROW_ORDER, TABLE2_COLUMNS, TABLE3, TABLE3_COLUMNS, TASK_COLUMNS

log = logging.getLogger(__name__)

#: Table III group of every dataset id: the paper measures the simulated sets once ("simulation").
TABLE3_GROUP: dict[str, str] = {d: "simulation" if catalog.DATASETS[d].simulated else d for d in catalog.dataset_ids()}


class PaperNumbersError(ValueError):
    """paper_numbers.yaml is malformed; the message names the entry."""


@dataclass(frozen=True)
class PaperCell:
    """A printed ``mean ± variance`` cell; ``var_below``: the paper printed ``<var``."""

    mean: float
    var: float
    var_below: bool = False

    def var_text(self) -> str:
        return f"<{self.var:.3f}" if self.var_below else f"{self.var:.3f}"

    def text(self) -> str:
        return f"{self.mean:.3f} ± {self.var_text()}"


@dataclass(frozen=True)
class PrintedTable2Row:
    """One printed row of Table II (``combination`` carries only tm and mv)."""

    row_id: str
    label: str
    cells: dict[str, Optional[PaperCell]]
    tm: Optional[float]
    mv: Optional[float]
    bold: tuple[str, ...] = ()
    bold_label: bool = False
    printed_on: Optional[str] = None

    def value(self, column: str) -> Optional[float]:
        """Mean of a task column, or tm / mv; ``None`` where the paper prints nothing."""
        if column == "tm":
            return self.tm
        if column == "mv":
            return self.mv
        cell = self.cells.get(column)
        return None if cell is None else cell.mean


@dataclass(frozen=True)
class PrintedTable3Row:
    """One printed row of Table III (sizes and memory in MB): ``printed``, what it prints, by the
    key of the column of :data:`~.schema.TABLE3_COLUMNS` (a per-copy number as printed, for one copy
    of the ``copies`` the row runs)."""

    row_id: str
    label: str
    printed: dict[str, float] = field(default_factory=dict)
    copies: int = 1
    printed_on: Optional[str] = None

    def value(self, key: str) -> Optional[float]:
        """The row's value in Table III's column ``key``, as a reproduced row holds it: a number
        printed per copy times the row's copies (a row printing only its total gives that);
        ``None`` where the paper prints nothing."""
        column = TABLE3[key]
        if column.per_copy and key in self.printed:
            return self.printed[key] * self.copies
        if column.per_copy and column.total is not None:
            return self.printed.get(column.total)
        return self.printed.get(key)


@dataclass(frozen=True)
class PaperNumbers:
    """Everything transcribed from the paper."""

    table2: dict[str, dict[str, PrintedTable2Row]]   # dataset -> row id -> row
    table2_labels: dict[str, str]                    # dataset -> printed label
    table3: dict[str, dict[str, PrintedTable3Row]]   # group -> row id -> row
    table3_labels: dict[str, str]
    table3_device: str
    raw: dict[str, Any] = field(repr=False, default_factory=dict)

    def table2_row(self, dataset: str, row_id: str) -> Optional[PrintedTable2Row]:
        return self.table2.get(dataset, {}).get(row_id)

    def table3_row(self, dataset: str, row_id: str) -> Optional[PrintedTable3Row]:
        """Table III row for a dataset (A, B, C share the simulation group)."""
        return self.table3.get(TABLE3_GROUP.get(dataset, dataset), {}).get(row_id)


def _cell(v: Any, where: str) -> Optional[PaperCell]:
    if v is None:
        return None
    if not isinstance(v, dict) or set(v) != {"mean", "var"}:
        raise PaperNumbersError(f"{where}: expected {{mean, var}} or null, got {v!r}")
    var = v["var"]
    below = isinstance(var, str)
    if below:
        if not var.startswith("<"):
            raise PaperNumbersError(f"{where}.var: a string variance must look like '<0.001', got {var!r}")
        var = float(var[1:])
    return PaperCell(float(v["mean"]), float(var), below)


def _opt_float(v: Any, where: str) -> Optional[float]:
    if v is None:
        return None
    if not isinstance(v, (int, float)):
        raise PaperNumbersError(f"{where}: expected a number or null, got {v!r}")
    return float(v)


#: The paper's field -> the Table III column it prints (paper_numbers.yaml ``table3`` rows).
_PRINTED_AS: dict[str, str] = {c.paper: c.key for c in TABLE3_COLUMNS if c.paper is not None}
_ROW_KEYS3 = ("label", "copies", "printed_on")


def _table3_row(rid: str, r: dict[str, Any], where: str) -> PrintedTable3Row:
    unknown = set(r) - set(_PRINTED_AS) - set(_ROW_KEYS3)
    if unknown:
        raise PaperNumbersError(f"{where}: unknown key(s) {sorted(unknown)}")
    printed = {_PRINTED_AS[k]: v for k, v in r.items() if k in _PRINTED_AS and v is not None}
    return PrintedTable3Row(rid, str(r.get("label", rid)), printed, r.get("copies", 1), r.get("printed_on"))


def parse_paper_numbers(data: dict[str, Any], source: str = "paper_numbers.yaml") -> PaperNumbers:
    """Validate and convert the YAML mapping."""
    try:
        t2_raw, t3_raw = data["table2"]["datasets"], data["table3"]["groups"]
    except (KeyError, TypeError) as err:
        raise PaperNumbersError(f"{source}: missing section {err}") from None
    table2: dict[str, dict[str, PrintedTable2Row]] = {}
    labels2: dict[str, str] = {}
    for ds, block in t2_raw.items():
        labels2[ds] = str(block.get("label", ds))
        rows: dict[str, PrintedTable2Row] = {}
        for rid, r in block["rows"].items():
            where = f"{source}: table2.datasets.{ds}.rows.{rid}"
            if rid not in ROW_ORDER:   # a row of the report's tables (the catalog's models, the combination)
                raise PaperNumbersError(f"{where}: unknown row id (known: {list(ROW_ORDER)})")
            unknown = set(r) - set(TABLE2_COLUMNS) - {"label", "bold", "bold_label", "printed_on"}
            if unknown:
                raise PaperNumbersError(f"{where}: unknown key(s) {sorted(unknown)}")
            rows[rid] = PrintedTable2Row(
                row_id=rid, label=str(r.get("label", rid)),
                cells={c: _cell(r.get(c), f"{where}.{c}") for c in TASK_COLUMNS},
                tm=_opt_float(r.get("tm"), f"{where}.tm"), mv=_opt_float(r.get("mv"), f"{where}.mv"),
                bold=tuple(r.get("bold") or ()), bold_label=bool(r.get("bold_label", False)),
                printed_on=r.get("printed_on"),
            )
        table2[ds] = rows
    table3: dict[str, dict[str, PrintedTable3Row]] = {}
    labels3: dict[str, str] = {}
    for grp, block in t3_raw.items():
        labels3[grp] = str(block.get("label", grp))
        table3[grp] = {rid: _table3_row(rid, r, f"{source}: table3.groups.{grp}.rows.{rid}")
                       for rid, r in block["rows"].items()}
    return PaperNumbers(table2, labels2, table3, labels3, str(data["table3"].get("device", "")), data)


@functools.lru_cache(maxsize=4)
def _load_cached(path: Optional[str]) -> PaperNumbers:
    if path is None:
        text = resources.files("compact_perception").joinpath("paper_numbers.yaml").read_text()
        source = "compact_perception/paper_numbers.yaml"
    else:
        text, source = Path(path).read_text(), path
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise PaperNumbersError(f"{source}: not valid YAML: {err}") from None
    return parse_paper_numbers(data, source)


def load_paper_numbers(path: str | Path | None = None) -> PaperNumbers:
    """Load the paper's numbers (the packaged YAML unless ``path`` is given)."""
    return _load_cached(None if path is None else str(path))
