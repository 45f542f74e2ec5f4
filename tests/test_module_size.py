"""One concern per module: no module under src/ is over :data:`MAX_LINES` lines."""
from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
MAX_LINES = 600
#: Modules over the limit while their split is under way elsewhere (remove the entry with the split).
PENDING_SPLIT = {"src/compact_perception/stats.py"}


def test_no_module_over_the_limit():
    long = {p.relative_to(ROOT).as_posix(): n for p in sorted((ROOT / "src").rglob("*.py"))
            if (n := len(p.read_text().splitlines())) > MAX_LINES}
    over = {p: n for p, n in long.items() if p not in PENDING_SPLIT}
    assert not over, f"modules over {MAX_LINES} lines (split them by concern): {over}"
