"""Figures that README.md and docs/*.md quote from results equal the results they quote (issue 24:
stale figures).

A quoted result is written with its source right after the number, in an HTML comment Markdown
does not render: ``0.125<!-- quote e12ba38:results/C/gradnorm_segnet/seed0/metrics.json#iou_ss.mean -->``
(a commit's file, read with ``git show``) or ``26<!-- quote reports/metrics.json#claims.reproduced -->``
(the committed file in the working tree), or a cell of a committed CSV table:
``1.887<!-- quote reports/tables/table2.csv#dataset=A,row_id=compact_1l:tm -->`` (the ``tm`` column of
the one row whose ``dataset`` is ``A`` and ``row_id`` is ``compact_1l``). The number must equal the value at the key path
(``.``-separated) to the number's printed decimals. The scorecard's verdict counts may only be
quoted that way: a current figure is a pointer to the generated file or a checked quote.
"""
from __future__ import annotations

import csv
import hashlib
import io
import json
import re
import subprocess
from pathlib import Path
from typing import Any, Optional

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
DOCS: tuple[Path, ...] = (ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")))
#: The history the docs leave out: its quotes of earlier commits are checked like the docs' own.
CHANGELOG = ROOT / "CHANGELOG.md"
QUOTING: tuple[Path, ...] = (*DOCS, CHANGELOG)
#: The machine, software and wall time of the `make repro` behind the committed results.
REPRO_RECORD = ROOT / "benchmarks" / "records" / "default_repro.json"
QUOTE = re.compile(r"(?P<num>[-+]?\d+(?:\.\d+)?)<!-- quote (?:(?P<commit>[0-9a-f]{7,40}):)?(?P<path>[^#\s]+)"
                   r"#(?P<key>\S+) -->")
#: A verdict count in prose: the number, an optional quote marker, the verdict.
COUNT = re.compile(r"\b(?P<num>\d+)(?P<marker><!-- quote [^>]*-->)?\s+(?:reproduced|contradicted|inconclusive|"
                   r"not decidable)\b")


def _git_show(commit: str, path: str) -> Optional[str]:
    """The file at ``commit`` (``None`` where git or the commit is not available: a shallow clone)."""
    try:
        out = subprocess.run(["git", "-C", str(ROOT), "show", f"{commit}:{path}"], capture_output=True, text=True,
                             timeout=60)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return out.stdout if out.returncode == 0 else None


def _lookup_csv(text: str, key: str) -> Any:
    """``col=value,col=value:column`` of a CSV: the ``column`` of the one row whose columns
    have those values (``dataset=A,row_id=compact_1l:tm``)."""
    where, column = key.rsplit(":", 1)
    wanted = dict(part.split("=", 1) for part in where.split(","))
    rows = [r for r in csv.DictReader(io.StringIO(text)) if all(r.get(k) == v for k, v in wanted.items())]
    if len(rows) != 1:
        raise KeyError(f"{len(rows)} rows match {where}")
    return rows[0][column]


def _lookup(text: str, key: str, path: str = "") -> Any:
    if path.endswith(".csv"):
        return _lookup_csv(text, key)
    value: Any = json.loads(text)
    for part in key.split("."):
        value = value[int(part)] if isinstance(value, list) else value[part]
    return value


def check_quotes(text: str, root: Path = ROOT) -> tuple[list[str], int]:
    """Every quote of ``text`` against its source: the mismatches (one line each) and the number
    of quotes checked (quotes of an unavailable commit are skipped)."""
    problems, checked = [], 0
    for m in QUOTE.finditer(text):
        where = f"{m['commit'] + ':' if m['commit'] else ''}{m['path']}#{m['key']}"
        source = _git_show(m["commit"], m["path"]) if m["commit"] else (
            (root / m["path"]).read_text() if (root / m["path"]).is_file() else "")
        if source is None:
            continue
        try:
            value = float(_lookup(source, m["key"], m["path"]))
        except (ValueError, KeyError, TypeError):
            problems.append(f"{m['num']}: {where}: no number there")
            continue
        decimals = len(m["num"].split(".")[1]) if "." in m["num"] else 0
        if abs(value - float(m["num"])) > 0.5 * 10 ** -decimals + 1e-12:
            problems.append(f"{m['num']}: {where} is {value!r}")
        checked += 1
    return problems, checked


def unmarked_counts(text: str) -> list[str]:
    """Verdict counts written without their source."""
    return [m.group(0) for m in COUNT.finditer(text) if not m["marker"]]


@pytest.mark.parametrize("doc", QUOTING, ids=[p.name for p in QUOTING])
def test_every_quoted_result_equals_its_source(doc: Path) -> None:
    problems, _ = check_quotes(doc.read_text())
    assert not problems, f"{doc.name}: quoted results that differ from their source: {problems}"


@pytest.mark.parametrize("doc", QUOTING, ids=[p.name for p in QUOTING])
def test_verdict_counts_are_quoted_with_their_source(doc: Path) -> None:
    assert not unmarked_counts(doc.read_text()), f"{doc.name}: verdict counts without a source: " \
                                                  f"{unmarked_counts(doc.read_text())}"


def test_the_docs_quote_the_results_they_name() -> None:
    """The docs that quote results do so with sources (the quotes this test checks exist)."""
    if _git_show("e12ba38", "results/C/gradnorm_segnet/seed0/metrics.json") is None:
        pytest.skip("no git history here (shallow clone): the quotes of earlier commits cannot be read")
    counts = {doc.name: check_quotes(doc.read_text())[1] for doc in QUOTING}
    assert counts["README.md"] >= 40 and counts["results.md"] >= 20 and counts["CHANGELOG.md"] >= 10
    readme = (ROOT / "README.md").read_text()
    assert "0.104\n  here" not in readme and "26 reproduced" not in readme


def test_the_checker_fails_on_a_wrong_quote(tmp_path: Path) -> None:
    (tmp_path / "reports").mkdir()
    (tmp_path / "reports/metrics.json").write_text(json.dumps({"claims": {"reproduced": 7, "contradicted": 2},
                                                               "tm": {"A": 2.8123}}))
    right = ("7<!-- quote reports/metrics.json#claims.reproduced --> reproduced, "
             "2<!-- quote reports/metrics.json#claims.contradicted --> contradicted; TM "
             "2.81<!-- quote reports/metrics.json#tm.A -->")
    assert check_quotes(right, tmp_path) == ([], 3) and unmarked_counts(right) == []
    wrong = right.replace("7<!--", "26<!--").replace("2.81<!--", "2.82<!--")
    problems, checked = check_quotes(wrong, tmp_path)
    assert checked == 3 and problems == ["26: reports/metrics.json#claims.reproduced is 7.0",
                                         "2.82: reports/metrics.json#tm.A is 2.8123"]
    assert check_quotes("1<!-- quote reports/metrics.json#claims.missing -->", tmp_path)[0] == \
        ["1: reports/metrics.json#claims.missing: no number there"]
    assert unmarked_counts("the scorecard: 26 reproduced, 24 contradicted, 44\ninconclusive") == \
        ["26 reproduced", "24 contradicted", "44\ninconclusive"]


def test_a_csv_quote_is_checked_against_its_row_and_column(tmp_path: Path) -> None:
    (tmp_path / "t.csv").write_text("dataset,row_id,tm\nA,m1,1.8867\nA,m2,1.8470\nB,m1,3.2\n")
    assert check_quotes("1.887<!-- quote t.csv#dataset=A,row_id=m1:tm -->", tmp_path) == ([], 1)
    assert check_quotes("1.85<!-- quote t.csv#dataset=A,row_id=m2:tm -->", tmp_path) == ([], 1)
    assert check_quotes("1.88<!-- quote t.csv#dataset=A,row_id=m1:tm -->", tmp_path)[0] == \
        ["1.88: t.csv#dataset=A,row_id=m1:tm is 1.8867"]
    assert check_quotes("1.9<!-- quote t.csv#row_id=m1:tm -->", tmp_path)[0] == \
        ["1.9: t.csv#row_id=m1:tm: no number there"]


# ----------------------------------------------------------------------------- facts the docs state
def _section(text: str, heading: str) -> str:
    """The Markdown section under ``heading`` (to the next heading of the same or a higher level)."""
    level = heading.split(" ", 1)[0]
    body = text.split(heading + "\n", 1)[1]
    return re.split(rf"^#{{1,{len(level)}}} ", body, maxsplit=1, flags=re.M)[0]


def test_the_repro_record_is_that_of_the_committed_results() -> None:
    """The machine, software and wall time that the README and docs/results.md quote are those
    of the `make repro` that wrote the committed results: a commit of new results without a new
    record fails here (a timing of an earlier run no longer passes for the current one)."""
    record = json.loads(REPRO_RECORD.read_text())
    for path, digest in record["digests"].items():
        assert hashlib.sha256((ROOT / path).read_bytes()).hexdigest() == digest, \
            f"{path} is not the file the recorded run wrote: record the run that made it ({REPRO_RECORD.name})"
    efficiency = json.loads((ROOT / "results/benchmark/efficiency.json").read_text())
    pin = re.search(r"^torch==(\S+)", (ROOT / "requirements.txt").read_text(), re.M)[1]
    assert record["software"]["torch"] == efficiency["torch"] and efficiency["torch"].split("+")[0] == pin
    assert round(record["wall_s"] / 60, 1) == record["wall_min"]
    assert abs(sum(record["minutes"].values()) - record["wall_min"]) < 0.15, "the parts do not add up to the total"
    readme = (ROOT / "README.md").read_text()
    line = next(ln for ln in readme.split("\n\n") if ln.startswith("The committed results come from"))
    for fact in (f"Python {record['software']['python']}", f"torch {pin}", f"DVC {record['software']['dvc']}",
                 record["machine"]["os"], "Zen 5", f"{record['machine']['cores']}-core"):
        assert fact in line, f"the README's line on the committed results' machine does not say {fact!r}"
    table3 = next(p for p in readme.split("\n- ") if p.startswith("**Table III**"))
    assert f"measured on {efficiency['device']}" in table3 and "GTX 1080 Ti" in table3, \
        "the README's Table III line does not name the device of each measurement"


def test_the_python_and_systems_the_readme_names_are_the_tested_ones() -> None:
    """The README's requirements name the lowest Python the pinned packages install on (the same
    as pyproject.toml's requires-python), Linux on x86-64 as tested, and promise no macOS."""
    from importlib.metadata import PackageNotFoundError, metadata

    floors = []
    for name in re.findall(r"^([A-Za-z0-9_.-]+)==", (ROOT / "requirements.txt").read_text(), re.M):
        try:
            needs = metadata(name).get("Requires-Python") or ""
        except PackageNotFoundError:
            continue
        if m := re.search(r">=\s*3\.(\d+)", needs):
            floors.append(int(m[1]))
    lowest = f"3.{max(floors)}"
    pyproject = (ROOT / "pyproject.toml").read_text()
    assert f'requires-python = ">={lowest}"' in pyproject, f"pyproject.toml's requires-python is not >={lowest}"
    readme = (ROOT / "README.md").read_text()
    requirements = _section(readme, "## Requirements")
    assert f"Python {lowest}" in requirements and "Linux on x86-64" in requirements
    assert "macOS" not in readme, "the README names macOS, which no test or CI run covers"


def _output_sizes() -> tuple[float, float]:
    """GB of every output dvc.lock records, and of runs/ among them."""
    outs = [o for stage in yaml.safe_load((ROOT / "dvc.lock").read_text())["stages"].values()
            for o in stage.get("outs", [])]
    total = sum(o.get("size", 0) for o in outs)
    runs = sum(o.get("size", 0) for o in outs if o["path"].startswith("runs/"))
    return total / 1e9, runs / 1e9


def test_the_disk_figures_are_the_sizes_dvc_lock_records() -> None:
    total, runs = _output_sizes()
    sharing = (ROOT / "docs/sharing.md").read_text()
    for doc, text in (("README.md", (ROOT / "README.md").read_text()), ("sharing.md", sharing)):
        assert f"{total:.1f} GB" in text, f"{doc} does not give the outputs' size, {total:.1f} GB"
    assert f"{runs:.1f} GB" in sharing


def test_sharing_what_you_ran_commits_the_params_it_ran_with() -> None:
    """After ``dvc exp run -S`` params.yaml holds the values the runs were made with: "Share what you
    ran" commits it with dvc.lock (without it a colleague's clone saw train, evaluate and report
    changed and retrained), and the README and docs/sharing.md push the same way."""
    sharing = (ROOT / "docs/sharing.md").read_text().split("## Share what you ran", 1)[1].split("\n## ", 1)[0]
    git_add = next(line for line in sharing.splitlines() if line.startswith("git add"))
    assert {"params.yaml", "dvc.lock", "results", "reports"} <= set(git_add.split("&&")[0].split())
    readme = (ROOT / "README.md").read_text()
    readme_push = next(line for line in readme.splitlines() if line.startswith("bin/venv dvc push"))
    assert "params.yaml" in readme_push and "dvc.lock" in readme_push
    pushes = re.findall(r"dvc push[^\n#]*", sharing) + [readme_push.split("#")[0]]
    assert pushes and all("--run-cache" in p for p in pushes), pushes


def test_the_docs_say_what_full_makes_decidable_and_point_to_what_exists() -> None:
    """`scale: full` gives 3 seeds where set A's headline needs about 16: the README says it makes
    sets decidable, never that it decides them; Table III's claims are exact counts except FPS
    (docs/claims.md's exception), not all exact counts; the Makefile's first line names a README
    section that exists (it named "Quick start" after the section became "Reproduce")."""
    readme = (ROOT / "README.md").read_text()
    assert not re.search(r"`scale: full`\W{0,3}decides\b|full` decides", readme)
    assert not re.search(r"\bexact-count claims of Table III", readme)
    first = (ROOT / "Makefile").read_text().splitlines()[0]
    section = re.search(r'README "([^"]+)"', first)[1]
    assert re.search(rf"^#+ {re.escape(section)}$", readme, re.M), first


def test_every_byte_identity_promise_states_its_limits() -> None:
    """fp32 makes results byte-identical on x86-64 CPUs with AVX2, and not the runs of 15L+MGN
    (authors' code): a paragraph that promises it says both."""
    promise = re.compile(r"byte-identical|bit-for-bit|bit for bit|machine-independent")
    for doc in DOCS:
        for paragraph in re.split(r"\n\s*\n", doc.read_text()):
            if "fp32" in paragraph and promise.search(paragraph):
                assert "x86-64" in paragraph and "authors' code" in paragraph, \
                    f"{doc.name}: a promise of byte-identical fp32 results without its limits: {paragraph[:200]!r}"


def test_the_readme_names_where_a_table_ii_score_goes() -> None:
    """The README's Extend line for a Table II metric names the file that defines MV's formula and
    only files docs/extending.md's checklist names."""
    readme = (ROOT / "README.md").read_text()
    line = next(p for p in readme.split("\n\n") if "Table II\nmetric" in p or "Table II metric" in p)
    line = line[line.index("Table II"):].split(") and a dataset", 1)[0]
    named = set(re.findall(r"`([\w/]+\.py)`", line))
    defining = {str(p.relative_to(ROOT / "src/compact_perception")) for p in (ROOT / "src/compact_perception").rglob("*.py")
                if re.search(r"^def metric_variance\b", p.read_text(), re.M)}
    assert defining and defining <= named, f"the README does not name {defining}"
    checklist = _section((ROOT / "docs/extending.md").read_text(), "## A Table II metric")
    assert all(name in checklist for name in named), f"{named} against the checklist of docs/extending.md"


#: A commit hash: 7 to 40 hex digits with at least one letter and one digit, not inside a number or word.
COMMIT = re.compile(r"(?<![\w.])(?=[0-9a-f]*[a-f])(?=[0-9a-f]*\d)[0-9a-f]{7,40}(?![\w.])")
ISSUE = re.compile(r"\bissues? #?\d+|\(#\d+\)", re.I)
MONTHS = "January|February|March|April|May|June|July|August|September|October|November|December"
DATE = re.compile(rf"\b20\d\d-\d\d-\d\d\b|\b\d{{1,2}} (?:{MONTHS}) 20\d\d\b|\b(?:{MONTHS}) \d{{1,2}}, 20\d\d\b")


def history_in(text: str) -> list[str]:
    """Commit hashes, issue numbers and dates in ``text``: history, which belongs in CHANGELOG.md."""
    return [m.group(0) for pattern in (COMMIT, ISSUE, DATE) for m in pattern.finditer(text)]


@pytest.mark.parametrize("doc", DOCS, ids=[p.name for p in DOCS])
def test_the_docs_are_reference_not_history(doc: Path) -> None:
    """README.md and docs/ describe the project as it is; what changed when, with its commits,
    issues and dates, is CHANGELOG.md's. An all-digit hash is caught where git knows it."""
    text = doc.read_text()
    found = history_in(text)
    for token in set(re.findall(r"(?<![\w.,])\d{7,12}(?![\w.,])", text)):
        if _git_show(token, "dvc.yaml") is not None:
            found.append(token)
    assert not found, f"{doc.name}: history outside CHANGELOG.md: {found}"


def test_each_docs_page_opens_with_what_the_reader_gets() -> None:
    for doc in sorted((ROOT / "docs").glob("*.md")):
        lines = doc.read_text().splitlines()
        assert lines[0].startswith("# ") and lines[2].startswith("What you get here:"), doc.name


def test_the_history_checker_finds_hashes_issues_and_dates() -> None:
    assert history_in("the results of commit e12ba38 (issue 12, item 3), measured on 2026-12-02") == \
        ["e12ba38", "issue 12", "2026-12-02"]
    assert history_in("since Issues #24 and 4 December 2026; see a1f43b8d0") == ["a1f43b8d0", "Issues #24", "4 December 2026"]
    # numbers, words and decimals are not hashes
    assert history_in("5.278057624068129, 1000000 frames, 2521504 parameters, deadbeef, 0.2656729554137302") == []
    changelog = CHANGELOG.read_text()
    assert CHANGELOG.read_text().startswith("# Changelog") and "## [Unreleased]" in changelog
    assert len(set(COMMIT.findall(changelog))) >= 20, "CHANGELOG.md holds the history with its commits"


def test_the_readme_answers_each_question_in_under_40_lines() -> None:
    """A short guide: at most 200 lines, and the section that answers each of a new user's
    questions (how to reproduce and how long, what the default found, how to share runs, how to
    cite) under 40."""
    readme = (ROOT / "README.md").read_text()
    assert len(readme.splitlines()) <= 200
    for heading in ("## Reproduce", "## What the default run finds", "### Share runs with a colleague", "## Citation"):
        assert len(_section(readme, heading).strip().splitlines()) < 40, heading


def test_params_yaml_states_set_as_default_budget_as_its_values_make_it() -> None:
    """The comment on set A's default epoch cap gives the steps those values make (epochs x
    batches of the training split), and no other epoch count."""
    text = (ROOT / "params.yaml").read_text()
    p = yaml.safe_load(text)
    a = p["datasets"]["A"]
    ratio = a["split_ratio"]["default"]
    train_frames = a["frames"]["default"] * ratio["train"] // sum(ratio.values())
    batch = p["train"]["batch_size"]
    epochs = a["training"]["max_epochs"]["default"]
    steps = epochs * -(-train_frames // batch)
    line = next(ln for ln in text.splitlines() if ln.strip().startswith("max_epochs:") and "#" in ln)
    comment = line.split("#", 1)[1]
    assert f"{steps} steps" in comment and f"batch {batch}" in comment and f"{train_frames} training frames" in comment
    assert not re.search(r"\b\d+ epochs\b", comment), f"params.yaml: an epoch count that is not the cap: {comment!r}"


def test_every_carla_client_pin_the_docs_name_is_the_installable_one() -> None:
    """A concrete `carla==<version>` in the docs or pyproject.toml is the extra's pin (the package
    index has no client of most server versions: docs/carla.md says what to install instead)."""
    pyproject = (ROOT / "pyproject.toml").read_text()
    pin = re.search(r'carla = \["carla==([\d.]+)"\]', pyproject)[1]
    for doc in (*DOCS, ROOT / "pyproject.toml"):
        named = set(re.findall(r"carla==(\d[\d.]*\d)", doc.read_text()))
        assert named <= {pin}, f"{doc.name} pins a CARLA client the project does not install: {named - {pin}}"


def test_every_pointer_to_a_section_points_the_right_way() -> None:
    """`"<Section>" below` and `[<Section>](#anchor) above` name a heading of the same page on
    that side of the pointer."""
    for doc in DOCS:
        lines = doc.read_text().splitlines()
        headings = {re.sub(r"^#+ ", "", ln).strip(): i for i, ln in enumerate(lines) if ln.startswith("#")}
        anchors = {re.sub(r"[^\w\- ]", "", h).strip().lower().replace(" ", "-"): i for h, i in headings.items()}
        for i, line in enumerate(lines):
            for title, way in re.findall(r'"([^"]+)" (below|above)', line):
                if title in headings:
                    assert (headings[title] > i) == (way == "below"), f"{doc.name}:{i + 1}: {title!r} is not {way}"
            for anchor, way in re.findall(r"\]\(#([\w-]+)\) (below|above)", line):
                assert anchor in anchors, f"{doc.name}:{i + 1}: no section #{anchor}"
                assert (anchors[anchor] > i) == (way == "below"), f"{doc.name}:{i + 1}: #{anchor} is not {way}"


def test_the_readmes_full_scale_line_names_where_the_study_runs() -> None:
    """`scale=full` runs the loss-balancing study on the datasets params.yaml names, not everywhere."""
    study = yaml.safe_load((ROOT / "params.yaml").read_text())["study"]["datasets"]["full"]
    line = next(ln for ln in (ROOT / "README.md").read_text().splitlines() if "dvc exp run -S scale=full" in ln)
    assert f"the study on set {', '.join(study)}" in line, line
