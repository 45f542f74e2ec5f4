"""What every report table shares: number formats (the paper's 3 decimals, its ``<0.001``
variances, ``mean ± sd`` over the seeds), how deep a row trained, the cell marks, and the
Markdown, LaTeX and CSV writers."""
from __future__ import annotations

import csv
import io as _io
import math
from pathlib import Path
from collections import Counter
from typing import Any, Iterable, Mapping, Optional, Sequence

from ...core import io
from ..collect import Cell

DECIMALS = 3
NOT_APPLICABLE = "-"
NOT_AVAILABLE = "n/a"
INCONCLUSIVE_MARK = "†"
#: Cell marks of the learnedness gate (:mod:`..gate`), Markdown and LaTeX: a value no better than
#: the floor's, and a better value whose margin's interval is not above 0 (or too few seeds).
BELOW_FLOOR_MARK, UNSHOWN_MARK = "↓", "°"
BELOW_FLOOR_TEX, UNSHOWN_TEX = "$^{\\downarrow}$", "$^{\\circ}$"


# ----------------------------------------------------------------------------- numbers
def fmt_num(x: Optional[float], decimals: int = DECIMALS) -> str:
    return "" if x is None else f"{x:.{decimals}f}"


def fmt_var(v: Optional[float], decimals: int = DECIMALS, latex: bool = False) -> str:
    """A variance as the paper prints it: ``<0.001`` when it rounds to zero."""
    if v is None:
        return ""
    if v < 0.5 * 10 ** (-decimals):
        return ("$<$" if latex else "<") + f"{10 ** (-decimals):.{decimals}f}"
    return f"{v:.{decimals}f}"


def fmt_seeds(cell: Optional[Cell], latex: bool = False, decimals: int = DECIMALS, *,
              no_sd: Optional[str] = None) -> str:
    """``mean ± sd`` over the seeds (sample sd); without an sd (a single seed) ``mean (n=1)``, or
    ``mean ± <no_sd>`` when ``no_sd`` is given (a table that keeps the sd column, e.g. ``—``)."""
    if cell is None:
        return NOT_APPLICABLE
    text = fmt_num(cell.mean, decimals)
    pm = " $\\pm$ " if latex else " ± "
    if cell.std is not None:
        return text + pm + fmt_num(cell.std, decimals)
    return text + (pm + no_sd if no_sd is not None else f" (n={cell.n_seeds})")


def join_values(values: Sequence[Any]) -> str:
    """One value if all are equal, else all of them joined by ``/`` (``?`` for a missing one)."""
    vals = ["?" if v is None else str(v) for v in values]
    return vals[0] if len(set(vals)) == 1 else "/".join(vals)


def training_text(facts: Sequence[Mapping[str, Any]]) -> str:
    """How deep a model's runs trained, from their ``summary.json`` facts (one per seed, in seed
    order): ``3 (best 2), max_epochs`` or ``12/15/9 (best 8/11/5), max_epochs x1, plateau x2``
    (why training stopped: the one reason of every run, or each reason with its count)."""
    if not facts:
        return ""
    text = (f"{join_values([f.get('epochs_run') for f in facts])} "
            f"(best {join_values([f.get('best_epoch') for f in facts])})")
    stops = Counter(str(f["stop_reason"]) for f in facts if f.get("stop_reason"))
    if len(stops) == 1 and sum(stops.values()) == len(facts):
        return f"{text}, {next(iter(stops))}"
    return text + "".join(f", {s} x{n}" for s, n in sorted(stops.items()))


def bold(text: str, latex: bool) -> str:
    return f"\\textbf{{{text}}}" if latex else f"**{text}**"


def and_list(words: Sequence[str]) -> str:
    """``a, b and c``."""
    return words[0] if len(words) == 1 else ", ".join(words[:-1]) + " and " + words[-1]


# ----------------------------------------------------------------------------- writers
def tex_escape(text: str) -> str:
    """Escape LaTeX specials in plain text."""
    out = text
    for a, b in (("\\", "\\textbackslash{}"), ("&", "\\&"), ("%", "\\%"), ("_", "\\_"), ("#", "\\#"),
                 ("$", "\\$"), ("{", "\\{"), ("}", "\\}")):
        out = out.replace(a, b)
    return out


def md_table(header: list[str], rows: list[list[str]], align: Optional[list[str]] = None) -> str:
    align = align or ["---"] * len(header)
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(align) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def booktabs(comments: Sequence[str], colspec: str, header: str, groups: Iterable[Sequence[str]]) -> list[str]:
    """The lines of a booktabs ``tabular`` (``\\usepackage{booktabs}``): each of ``comments`` as a
    ``% `` line, the column spec, the ``&``-joined ``header``, then each group of ``&``-joined body
    rows, the groups split by ``\\midrule``; the last line empty (the text ends with a line end)."""
    lines = [f"% {c}" for c in comments]
    lines += [f"\\begin{{tabular}}{{{colspec}}}", "\\toprule", header + " \\\\", "\\midrule"]
    for k, group in enumerate(groups):
        if k:
            lines.append("\\midrule")
        lines += [row + " \\\\" for row in group]
    return lines + ["\\bottomrule", "\\end{tabular}", ""]


def csv_text(header: Sequence[str], rows: Iterable[Sequence[Any]], float_format: Optional[str] = None) -> str:
    """CSV with ``\\n`` line ends; ``None`` is an empty cell, a float its ``repr`` (every digit), or
    ``float_format % v`` where given (then a NaN is an empty cell too: the study's ``%.10g``)."""
    buf = _io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(header)
    for r in rows:
        w.writerow(["" if v is None else (_csv_float(v, float_format) if isinstance(v, float) else v) for v in r])
    return buf.getvalue()


def _csv_float(v: float, float_format: Optional[str]) -> str:
    if float_format is None:
        return repr(v)
    return "" if math.isnan(v) else float_format % v


def table_files(stem: str, md: str, tex: str, csv_body: str) -> dict[str, str]:
    """A table's three files: ``<stem>.md``, ``.tex``, ``.csv`` (file name -> text)."""
    return {f"{stem}.md": md, f"{stem}.tex": tex, f"{stem}.csv": csv_body}


def write_files(out_dir: Path, files: Mapping[str, str]) -> list[Path]:
    """Write every ``file name: text`` under ``out_dir`` atomically; returns the paths in order."""
    paths = [Path(out_dir) / name for name in files]
    for path, text in zip(paths, files.values()):
        io.write_text(path, text)
    return paths
