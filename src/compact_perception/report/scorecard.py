"""The claims scorecard's rows (:class:`ClaimRow`), their verdict counts and the scorecard's files:
``claims.md`` (Markdown) and ``claims.csv``. Which claims there are and how each row is decided
is :mod:`.claims`."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, Optional, Sequence

from ..stats import CONTRADICTED, INCONCLUSIVE, MIN_SEEDS, NOT_DECIDABLE, REPRODUCED
from .schema import DATASET_LABEL
from .tables.formats import csv_text, md_table

__all__ = ["ClaimRow", "FLOOR_NA", "EXACT_PREFIX", "COUNT_KEYS", "verdict_counts", "exact_counts", "claims_markdown",
           "claims_csv"]

#: ``above_floor`` of a row the gate does not apply to (the exact counts of Table III).
FLOOR_NA = "n/a"
#: The claims of Table III: exact counts (and FPS's timed range), reported apart.
EXACT_PREFIX = "efficiency/"


@dataclass(frozen=True)
class ClaimRow:
    """One line of the scorecard. ``model``: the model whose claim it is (the MGN form for the
    claims about 15L+MGN); ``variant``: the MGN form's label (empty for the other claims);
    ``mde``: the minimal detectable effect at 80% power of the row's design; ``above_floor``:
    ``yes``, ``no: <models and tasks>`` or ``n/a`` (exact counts); ``seeds_to_decide``: the seeds
    per model at which that MDE reaches the paper's effect (:func:`seeds_needed`)."""

    dataset: str
    claim: str
    statement: str
    paper: Optional[float]
    measured: Optional[float]
    ci_low: Optional[float]
    ci_high: Optional[float]
    n_seeds: Optional[int]
    n_test_frames: Optional[int]
    verdict: str
    margin: Optional[float] = None
    note: str = ""
    model: str = ""
    variant: str = ""
    seeds_per_model: tuple[int, ...] = ()
    mde: Optional[float] = None
    above_floor: str = FLOOR_NA
    seeds_to_decide: str = ""

    @property
    def exact(self) -> bool:
        """An exact count of Table III (reported apart from the claims judged on test scores)."""
        return self.claim.startswith(EXACT_PREFIX)


#: The keys of the verdict counts (``reports/metrics.json``): every verdict, spaces as underscores.
COUNT_KEYS: dict[str, str] = {v: v.replace(" ", "_") for v in (REPRODUCED, CONTRADICTED, INCONCLUSIVE, NOT_DECIDABLE)}


def _counts(rows: Sequence[ClaimRow]) -> dict[str, int]:
    out = {k: 0 for k in COUNT_KEYS.values()}
    for r in rows:
        out[COUNT_KEYS[r.verdict]] += 1
    return out


def verdict_counts(rows: Sequence[ClaimRow]) -> dict[str, int]:
    """The claims judged on test scores (not Table III's exact counts), per verdict: ``reproduced``,
    ``contradicted``, ``inconclusive`` (together: the rows the run can decide, learned models with
    enough seeds) and ``not_decidable``."""
    return _counts([r for r in rows if not r.exact])


def exact_counts(rows: Sequence[ClaimRow]) -> dict[str, int]:
    """Table III's exact counts (``efficiency/*``) per verdict, apart from :func:`verdict_counts`."""
    return _counts([r for r in rows if r.exact])


def _f(v: Optional[float], nd: int = 4) -> str:
    return "" if v is None else f"{v:+.{nd}f}"


def _seeds_text(r: ClaimRow) -> str:
    if not r.seeds_per_model:
        return "" if r.n_seeds is None else str(r.n_seeds)
    return " vs ".join(map(str, r.seeds_per_model))


def _md_row(r: ClaimRow) -> list[str]:
    ci = "" if r.ci_low is None or r.ci_high is None else f"[{r.ci_low:+.4f}, {r.ci_high:+.4f}]"
    stmt = r.statement + (f" (margin ±{r.margin:g})" if r.margin is not None else "")
    return [f"`{r.claim}`", DATASET_LABEL.get(r.dataset, r.dataset), r.variant, stmt,
            _f(r.paper, 3) if r.paper is not None else "not printed", _f(r.measured), ci,
            "" if r.mde is None else f"{r.mde:.4f}", r.seeds_to_decide, _seeds_text(r),
            "" if r.n_test_frames is None else str(r.n_test_frames), r.above_floor, f"**{r.verdict}**", r.note]


def _counts_text(counts: Mapping[str, int]) -> str:
    return ", ".join(f"{n} {k.replace('_', ' ')}" for k, n in counts.items())


def claims_markdown(rows: list[ClaimRow], coverage: str = "", rule: str = "") -> str:
    """The scorecard as Markdown: the verdict counts, the intervals' coverage line, the claims
    judged on test scores, Table III's exact counts apart, and the verdict rule (``rule``: its text,
    :data:`compact_perception.report.claims.RULE_TEXT`)."""
    head = ["Claim", "Dataset", "MGN form", "Statement", "Paper", "Measured", "95% CI", "MDE (80%)",
            "Seeds to decide", "Seeds", "Test frames", "Above floor", "Verdict", "Note"]
    align = ["---"] * 4 + ["---:"] * 7 + ["---"] * 3
    judged, exact = [r for r in rows if not r.exact], [r for r in rows if r.exact]
    counts = verdict_counts(rows)
    decided = sum(n for k, n in counts.items() if k != COUNT_KEYS[NOT_DECIDABLE])
    lines = ["# Claims scorecard", "",
             "The paper's claims (CLAIMS.md) tested on this run's test scores, over all training seeds; one row per "
             "claim and dataset, and for the claims about 15L+MGN one row per MGN form (`Alg. 1`: Algorithm 1 as "
             "printed, compact_15l_mgn; `authors' code`: compact_15l_mgn_authors).", "",
             f"**Verdicts** over the {decided} rows this run can decide (every model compared above the floor, at "
             f"least {MIN_SEEDS} seeds): {_counts_text({k: n for k, n in counts.items() if k != 'not_decidable'})}; "
             f"{counts['not_decidable']} rows not decidable. Table III's exact counts, apart: "
             f"{_counts_text(exact_counts(rows))}.", ""]
    if coverage:
        lines += [f"**Method and measured coverage**: {coverage}", ""]
    lines += [md_table(head, [_md_row(r) for r in judged], align)]
    if exact:
        lines += ["## Exact counts (Table III), apart", "", md_table(head, [_md_row(r) for r in exact], align)]
    lines += [rule, ""]
    return "\n".join(lines)


def claims_csv(rows: list[ClaimRow]) -> str:
    header = ["dataset", "claim", "model", "variant", "statement", "paper", "measured", "ci_low", "ci_high", "mde",
              "seeds_to_decide", "margin", "n_seeds", "seeds_per_model", "n_test_frames", "above_floor", "verdict",
              "note"]
    return csv_text(header, [[r.dataset, r.claim, r.model, r.variant, r.statement, r.paper, r.measured, r.ci_low,
                              r.ci_high, r.mde, r.seeds_to_decide, r.margin, r.n_seeds,
                              ";".join(map(str, r.seeds_per_model)),
                              r.n_test_frames, r.above_floor, r.verdict, r.note] for r in rows])
