"""Table III (efficiency): per measured dataset, every model's parameters, state-dict size, peak
memory and batch-1 FPS / latency (PyTorch, and ONNX Runtime for the compact models), and the
combination of baselines as the sum of the models that give it; from
``results/benchmark/efficiency.json`` (``pipeline/benchmark.py``), as Markdown, LaTeX and CSV. Its
columns (headers, digits) are :data:`~..schema.TABLE3_COLUMNS`."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping, Optional

from ...core import catalog
from ..schema import (COMBINATION, COMBINATION_MODELS, COMPACT, DATASET_LABEL, ROW_LABEL, ROW_ORDER, TABLE3,
                      TABLE3_COLUMNS)
from .formats import NOT_AVAILABLE, booktabs, csv_text, md_table, table_files, tex_escape

#: How Table III names a row where the measured model differs from Table II's (GradNorm SegNet
#: runs once per camera view).
LABEL_NOTE: dict[str, str] = {"gradnorm_segnet": " (4 views)"}
COMBINATION_LABEL = "Combination (sum of the three)"


@dataclass
class Table3Row:
    """One row of Table III: its value in each column of :data:`~..schema.TABLE3_COLUMNS` that it
    has (``values``, by the column's key); ``available``: False where the row was not measured."""

    dataset: str
    row_id: str
    label: str
    values: dict[str, Any] = field(default_factory=dict)
    available: bool = True

    def value(self, key: str) -> Any:
        """The row's value in column ``key`` (``None`` where it has none)."""
        if key not in TABLE3:
            raise KeyError(f"unknown Table III column {key!r}; known: {list(TABLE3)}")
        return self.values.get(key)


#: The columns of table3.csv after the row's identity, in the table's order.
TABLE3_FIELDS: tuple[str, ...] = tuple(c.key for c in TABLE3_COLUMNS)


def _opt(m: Mapping[str, Any], key: str) -> Optional[float]:
    return None if m.get(key) is None else float(m[key])


def _combination_row(ds: str, models: Mapping[str, Any]) -> Table3Row:
    """The models of the combination run one after the other on the same frame: their parameters,
    sizes, peak memories and latencies add up; FPS = 1000 / the summed latency."""
    parts = [models.get(b) for b in COMBINATION_MODELS]
    if not all(parts):
        return Table3Row(ds, COMBINATION, COMBINATION_LABEL, available=False)
    lat = sum(p["latency_ms"] for p in parts)  # type: ignore[index]
    n = sum(int(p["params"]) for p in parts)  # type: ignore[index]
    size = sum(float(p["size_mb"]) for p in parts)  # type: ignore[index]
    return Table3Row(ds, COMBINATION, COMBINATION_LABEL, {
        "params": n, "total_params": n, "size_mb": size, "total_size_mb": size,
        "peak_memory_mb": sum(float(p["peak_memory_mb"]) for p in parts),  # type: ignore[index]
        "fps": 1e3 / lat if lat > 0 else None, "latency_ms": lat,
        "device": parts[0].get("device")})  # type: ignore[union-attr]


def _model_row(ds: str, rid: str, m: Optional[Mapping[str, Any]]) -> Table3Row:
    """A measured model (totals only for a compact model: a baseline's total is the combination's)."""
    label = ROW_LABEL[rid] + LABEL_NOTE.get(rid, "")
    if m is None:
        return Table3Row(ds, rid, label, available=False)
    own = rid in COMPACT
    return Table3Row(ds, rid, label, {
        "params": int(m["params"]), "total_params": int(m["params"]) if own else None,
        "size_mb": float(m["size_mb"]), "total_size_mb": float(m["size_mb"]) if own else None,
        "peak_memory_mb": float(m["peak_memory_mb"]), "fps": float(m["fps"]), "latency_ms": float(m["latency_ms"]),
        "device": m.get("device"), "onnx_fps": _opt(m, "onnx_fps"), "onnx_latency_ms": _opt(m, "onnx_latency_ms")})


def build_table3(efficiency: dict[str, Any]) -> dict[str, list[Table3Row]]:
    """Rows per measured dataset from ``efficiency.json`` (see ``pipeline/benchmark.py``), in
    :data:`~..schema.ROW_ORDER`. ONNX Runtime FPS / latency come from the ``onnx_*`` keys
    (compact models) where measured."""
    return {ds: [_combination_row(ds, models) if rid == COMBINATION else _model_row(ds, rid, models.get(rid))
                 for rid in ROW_ORDER]
            for ds, models in (efficiency.get("models") or {}).items()}


def _texts(r: Table3Row) -> list[str]:
    if not r.available:
        return [NOT_AVAILABLE] * len(TABLE3_COLUMNS)
    return [c.text(r.value(c.key)) for c in TABLE3_COLUMNS]


def _header(efficiency: dict[str, Any]) -> list[str]:
    gpu = bool(efficiency.get("is_gpu"))
    return ["Dataset", "Model", *(c.header_on(gpu) for c in TABLE3_COLUMNS)]


def _note(efficiency: dict[str, Any]) -> str:
    gpu = bool(efficiency.get("is_gpu"))
    s = (f"Batch 1 at {efficiency.get('resolution')}x{efficiency.get('resolution')} px; "
         f"{efficiency.get('warmup')} warm-up iterations excluded, median of {efficiency.get('runs')} timed runs"
         f"{', device synchronised before each clock read' if gpu else ''}. Size = serialised state_dict / 2^20. "
         f"Memory: {efficiency.get('memory_method', '')}.")
    if not gpu:
        s += (" **No GPU on this machine**: FPS and latency are CPU figures, not comparable with the paper's "
              "GPU (NVIDIA GTX 1080 Ti) numbers.")
    onnx = [m for models in (efficiency.get("models") or {}).values() for m in models.values()
            if isinstance(m, dict) and m.get("onnx_latency_ms") is not None]
    if onnx:
        worst = max(float(m.get("onnx_max_abs_diff") or 0.0) for m in onnx)
        s += (f" ONNX Runtime {onnx[0].get('onnxruntime', '')} (CPU execution provider, "
              f"{onnx[0].get('onnx_device', 'CPU')}, opset {onnx[0].get('onnx_opset', '')}): the compact models "
              f"exported to ONNX, same batch-1 protocol; largest |ONNX Runtime - PyTorch| output difference "
              f"{worst:.1e}.")
    return s


def _group_label(ds: str) -> str:
    """A simulated set stands for all of them (the same networks): the benchmark measures one."""
    return f"Simulation (measured on {ds})" if ds in catalog.sim_dataset_ids() else DATASET_LABEL.get(ds, ds)


def table3_markdown(tables: dict[str, list[Table3Row]], efficiency: dict[str, Any]) -> str:
    body = []
    for ds, rows in tables.items():
        for i, r in enumerate(rows):
            body.append([_group_label(ds) if i == 0 else "", r.label] + _texts(r))
    align = ["---", "---"] + ["---" if c.kind == "text" else "---:" for c in TABLE3_COLUMNS]
    return md_table(_header(efficiency), body, align) + "\n" + _note(efficiency) + "\n"


def table3_latex(tables: dict[str, list[Table3Row]], efficiency: dict[str, Any]) -> str:
    return "\n".join(booktabs(
        ["Table III (reproduced). Requires \\usepackage{booktabs}.", _note(efficiency).replace("**", "")],
        "ll" + "".join("l" if c.kind == "text" else "r" for c in TABLE3_COLUMNS),
        " & ".join(tex_escape(h) for h in _header(efficiency)),
        [[f"{tex_escape(_group_label(ds)) if i == 0 else ''} & {tex_escape(r.label)} & "
          + " & ".join(tex_escape(t) for t in _texts(r)) for i, r in enumerate(rows)] for ds, rows in tables.items()]))


def table3_csv(tables: dict[str, list[Table3Row]], efficiency: dict[str, Any]) -> str:
    header = ["dataset", "row_id", "label", "available", *TABLE3_FIELDS, "is_gpu", "resolution"]
    body = [[ds, r.row_id, r.label, int(r.available), *(r.value(f) for f in TABLE3_FIELDS),
             int(bool(efficiency.get("is_gpu"))), efficiency.get("resolution")]
            for ds, rows in tables.items() for r in rows]
    return csv_text(header, body)


def table3_files(tables: dict[str, list[Table3Row]], efficiency: dict[str, Any]) -> dict[str, str]:
    """``table3.{md,tex,csv}`` of the built table (file name -> text)."""
    return table_files("table3", table3_markdown(tables, efficiency), table3_latex(tables, efficiency),
                       table3_csv(tables, efficiency))
