"""Table III (efficiency): per measured dataset, every model's parameters, state-dict size, peak
memory and batch-1 FPS / latency (PyTorch, and ONNX Runtime for the compact models), and the
combination of baselines as the sum of the models that give it; from
``results/benchmark/efficiency.json`` (``pipeline/benchmark.py``), as Markdown, LaTeX and CSV."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Optional

from ...core import catalog
from ..schema import COMBINATION, COMBINATION_MODELS, COMPACT, DATASET_LABEL, ROW_LABEL, ROW_ORDER
from .formats import NOT_AVAILABLE, booktabs, csv_text, fmt_num, md_table, table_files, tex_escape

#: How Table III names a row where the measured model differs from Table II's (GradNorm SegNet
#: runs once per camera view).
LABEL_NOTE: dict[str, str] = {"gradnorm_segnet": " (4 views)"}
COMBINATION_LABEL = "Combination (sum of the three)"


@dataclass
class Table3Row:
    dataset: str
    row_id: str
    label: str
    params: Optional[int] = None
    total_params: Optional[int] = None
    size_mb: Optional[float] = None
    total_size_mb: Optional[float] = None
    peak_memory_mb: Optional[float] = None
    fps: Optional[float] = None
    latency_ms: Optional[float] = None
    device: Optional[str] = None
    available: bool = True
    onnx_fps: Optional[float] = None            # ONNX Runtime, batch 1, CPU (compact models; issue 15)
    onnx_latency_ms: Optional[float] = None


TABLE3_FIELDS: tuple[str, ...] = ("params", "total_params", "size_mb", "total_size_mb", "peak_memory_mb",
                                  "fps", "latency_ms", "onnx_fps", "onnx_latency_ms", "device")


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
    return Table3Row(ds, COMBINATION, COMBINATION_LABEL, n, n, size, size,
                     sum(float(p["peak_memory_mb"]) for p in parts),  # type: ignore[index]
                     1e3 / lat if lat > 0 else None, lat, parts[0].get("device"))  # type: ignore[union-attr]


def _model_row(ds: str, rid: str, m: Optional[Mapping[str, Any]]) -> Table3Row:
    """A measured model (totals only for a compact model: a baseline's total is the combination's)."""
    label = ROW_LABEL[rid] + LABEL_NOTE.get(rid, "")
    if m is None:
        return Table3Row(ds, rid, label, available=False)
    own = rid in COMPACT
    return Table3Row(ds, rid, label, int(m["params"]), int(m["params"]) if own else None,
                     float(m["size_mb"]), float(m["size_mb"]) if own else None,
                     float(m["peak_memory_mb"]), float(m["fps"]), float(m["latency_ms"]), m.get("device"),
                     onnx_fps=_opt(m, "onnx_fps"), onnx_latency_ms=_opt(m, "onnx_latency_ms"))


def build_table3(efficiency: dict[str, Any]) -> dict[str, list[Table3Row]]:
    """Rows per measured dataset from ``efficiency.json`` (see ``pipeline/benchmark.py``), in
    :data:`~..schema.ROW_ORDER`. ONNX Runtime FPS / latency come from the ``onnx_*`` keys
    (compact models) where measured."""
    return {ds: [_combination_row(ds, models) if rid == COMBINATION else _model_row(ds, rid, models.get(rid))
                 for rid in ROW_ORDER]
            for ds, models in (efficiency.get("models") or {}).items()}


def _texts(r: Table3Row) -> list[str]:
    if not r.available:
        return [NOT_AVAILABLE] * len(TABLE3_FIELDS)
    return [
        "" if r.params is None else f"{r.params:,}", "" if r.total_params is None else f"{r.total_params:,}",
        fmt_num(r.size_mb), fmt_num(r.total_size_mb), fmt_num(r.peak_memory_mb, 1), fmt_num(r.fps, 2),
        fmt_num(r.latency_ms, 2), fmt_num(r.onnx_fps, 2), fmt_num(r.onnx_latency_ms, 2), r.device or "",
    ]


def _header(efficiency: dict[str, Any]) -> list[str]:
    gpu = bool(efficiency.get("is_gpu"))
    mem = "GPU memory (MB)" if gpu else "Peak memory, CPU estimate (MB)"
    return ["Dataset", "Model", "Params", "Total params", "Size (MB)", "Total size (MB)", mem,
            "FPS" if gpu else "FPS (CPU)", "Latency (ms)", "ONNX Runtime FPS (CPU)", "ONNX Runtime latency (ms)",
            "Device"]


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
    align = ["---", "---"] + ["---:"] * 9 + ["---"]
    return md_table(_header(efficiency), body, align) + "\n" + _note(efficiency) + "\n"


def table3_latex(tables: dict[str, list[Table3Row]], efficiency: dict[str, Any]) -> str:
    return "\n".join(booktabs(
        ["Table III (reproduced). Requires \\usepackage{booktabs}.", _note(efficiency).replace("**", "")],
        "ll" + "r" * 9 + "l", " & ".join(tex_escape(h) for h in _header(efficiency)),
        [[f"{tex_escape(_group_label(ds)) if i == 0 else ''} & {tex_escape(r.label)} & "
          + " & ".join(tex_escape(t) for t in _texts(r)) for i, r in enumerate(rows)] for ds, rows in tables.items()]))


def table3_csv(tables: dict[str, list[Table3Row]], efficiency: dict[str, Any]) -> str:
    header = ["dataset", "row_id", "label", "available", *TABLE3_FIELDS, "is_gpu", "resolution"]
    body = [[ds, r.row_id, r.label, int(r.available), *(getattr(r, f) for f in TABLE3_FIELDS),
             int(bool(efficiency.get("is_gpu"))), efficiency.get("resolution")]
            for ds, rows in tables.items() for r in rows]
    return csv_text(header, body)


def table3_files(tables: dict[str, list[Table3Row]], efficiency: dict[str, Any]) -> dict[str, str]:
    """``table3.{md,tex,csv}`` of the built table (file name -> text)."""
    return table_files("table3", table3_markdown(tables, efficiency), table3_latex(tables, efficiency),
                       table3_csv(tables, efficiency))
