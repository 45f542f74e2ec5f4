"""What README.md and docs/*.md tell a user to run exists, and the maps of the code match the code.

- Every shell command of the docs (a fenced ``bash``/``sh`` block, or an inline code span that
  starts with ``make``, ``bin/venv``, ``.venv/bin/``, ``python``, ``dvc`` or ``torchrun``) names
  only what exists: a make target of the Makefile, a stage of dvc.yaml (``train@A``), a params key
  of params.yaml (``-S train.recipe.lr=0.05``; ``-S '+key=...'`` adds a key, so its parent must
  exist), a module or script and every ``--flag`` it is given (the flag's string in that file).
- Every params key written in code in prose (``train.parallel_runs``,
  ``datasets.<ds>.training.seeds``: ``<...>`` stands for any key) exists.
- Every relative Markdown link of the docs points at a file or folder of the repository, and no
  doc names a path outside it.
- The package map in ``compact_perception/__init__.py`` and the module table of
  docs/ARCHITECTURE.md name every top-level module and subpackage, and only those; each
  subpackage's row of the table names each of its modules.
"""
from __future__ import annotations

import re
import shlex
from pathlib import Path
from typing import Any, Iterator, Optional

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
DOCS: tuple[Path, ...] = (ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")))
PKG = ROOT / "src" / "compact_perception"

FENCE = re.compile(r"^```(?P<lang>[\w-]*)\n(?P<body>.*?)^```", re.M | re.S)
INLINE = re.compile(r"(?<!`)`(?P<code>[^`]+)`(?!`)")
COMMAND_START = re.compile(r"^(make|bin/venv|\.venv/bin/|python3?|dvc|torchrun)\b")
PLACEHOLDER = re.compile(r"<[^<>\s]+>")
#: Top-level keys of params.yaml that prose names in dotted form.
PARAM_ROOTS = ("scale", "seed", "baseline_seeds", "sim_ids", "dataset_ids", "model_ids", "world", "datasets",
               "preprocess", "train", "study", "evaluate", "benchmark")
PARAM_IN_PROSE = re.compile(rf"^(?:{'|'.join(PARAM_ROOTS)})(?:\.[\w<>+-]+)+$")
FILE_SUFFIX = re.compile(r"\.(py|json|md|csv|yaml|yml|pt|png|tex|lock|npy|npz|onnx|txt)$")


# ----------------------------------------------------------------------------- the repository's facts
def make_targets() -> set[str]:
    return set(re.findall(r"^([A-Za-z][\w-]*)\s*:(?!=)", (ROOT / "Makefile").read_text(), re.M))


def params() -> dict[str, Any]:
    return yaml.safe_load((ROOT / "params.yaml").read_text())


def stage_names() -> set[str]:
    stages = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]
    p, names = params(), set()
    for name, body in stages.items():
        if "foreach" in body:
            items = p[re.fullmatch(r"\$\{(\w+)\}", body["foreach"])[1]]
            names |= {f"{name}@{item}" for item in items}
        else:
            names.add(name)
    return names


def key_exists(tree: Any, parts: list[str]) -> bool:
    """``parts`` is a path of ``tree``; a ``<...>`` part matches any key."""
    if not parts:
        return True
    if not isinstance(tree, dict):
        return False
    head, rest = parts[0], parts[1:]
    if PLACEHOLDER.fullmatch(head):
        return any(key_exists(v, rest) for v in tree.values())
    return head in tree and key_exists(tree[head], rest)


# ----------------------------------------------------------------------------- the docs' commands
def commands(text: str) -> Iterator[str]:
    """Every shell command of a Markdown text, continuation lines joined, comments dropped."""
    for m in FENCE.finditer(text):
        if m["lang"] not in ("bash", "sh", "shell", "console"):
            continue
        body = re.sub(r"\\\n\s*", " ", m["body"])
        for line in body.splitlines():
            line = re.sub(r"(^|\s)#.*$", "", line).strip().removeprefix("$ ")
            if line:
                yield line
    for m in INLINE.finditer(FENCE.sub("", text)):
        code = " ".join(m["code"].split())
        if COMMAND_START.match(code):
            yield code


def _simple_commands(line: str) -> Iterator[list[str]]:
    lex = shlex.shlex(line, posix=True, punctuation_chars=";&|")
    lex.whitespace_split = True
    words: list[str] = []
    for tok in lex:
        if tok and set(tok) <= set(";&|"):
            if words:
                yield words
            words = []
        else:
            words.append(tok)
    if words:
        yield words


def _unwrap(words: list[str]) -> list[str]:
    """The command itself: ``bin/venv``, ``.venv/bin/`` and ``time`` prefixes removed."""
    while words:
        if words[0] in ("bin/venv", "time", "/usr/bin/time", "-v", "env"):
            words = words[1:]
        elif words[0].startswith(".venv/bin/"):
            words = [words[0].removeprefix(".venv/bin/"), *words[1:]]
        elif re.fullmatch(r"[A-Z_]+=\S*", words[0]):
            words = words[1:]
        else:
            return words
    return words


def _check_flags(source: Path, args: list[str], what: str) -> list[str]:
    if not source.is_file():
        return [f"{what}: no file {source.relative_to(ROOT)}"]
    text = source.read_text()
    return [f"{what}: {source.relative_to(ROOT)} has no flag {a.split('=')[0]}" for a in args
            if a.startswith("--") and f'"{a.split("=")[0]}"' not in text]


def _check_python(args: list[str], what: str) -> list[str]:
    """``python -m pkg.mod ...`` or ``python path.py ...``."""
    if not args:
        return []
    if args[0] == "-m":
        module, rest = args[1], args[2:]
        if module == "pytest":
            return [f"{what}: no test file {a}" for a in rest
                    if a.startswith("tests/") and not (ROOT / a.split("::")[0]).exists()]
        if module.split(".")[0] not in ("pipeline", "benchmarks"):
            return []
        return _check_flags(ROOT / (module.replace(".", "/") + ".py"), rest, what)
    if args[0].endswith(".py"):
        return _check_flags(ROOT / args[0], args[1:], what)
    return []


def _check_set_param(value: str, what: str) -> list[str]:
    key = value.split("=", 1)[0]
    if key.startswith(("+", "~")):
        parts = key.lstrip("+~").split(".")[:-1]
    else:
        parts = key.split(".")
    return [] if key_exists(params(), parts) else [f"{what}: params.yaml has no key {key.lstrip('+~')}"]


def _check_stage(name: str, what: str) -> list[str]:
    names = stage_names()
    if PLACEHOLDER.search(name):
        pattern = re.compile(PLACEHOLDER.sub(r"[^@]+", re.escape(name).replace(r"\<", "<").replace(r"\>", ">")))
        ok = any(pattern.fullmatch(n) for n in names)
    else:
        ok = name in names
    return [] if ok else [f"{what}: dvc.yaml has no stage {name}"]


def check_command(line: str) -> list[str]:
    """What ``line`` names that does not exist (one line each)."""
    problems: list[str] = []
    try:
        simple = list(_simple_commands(line))
    except ValueError as e:
        return [f"{line}: unparsable ({e})"]
    for words in simple:
        words = _unwrap(words)
        if not words:
            continue
        head, args = words[0], words[1:]
        if head == "make":
            problems += [f"{line}: the Makefile has no target {a}" for a in args
                         if not a.startswith("-") and "=" not in a and a not in make_targets()]
        elif head in ("python", "python3"):
            problems += _check_python(args, line)
        elif head == "torchrun":
            if "-m" in args:
                problems += _check_python(args[args.index("-m"):], line)
        elif head == "dvc":
            if args[:1] == ["repro"]:
                problems += [p for a in args[1:] if not a.startswith("-") for p in _check_stage(a, line)]
            for i, a in enumerate(args):
                if a in ("-S", "--set-param") and i + 1 < len(args):
                    problems += _check_set_param(args[i + 1], line)
    return problems


def _is_code_name(dotted: str) -> bool:
    """``evaluate.evaluate_run``, ``train.train_run``: a module's function or class, not a params key
    (a module of the package named like the first part defines the second)."""
    module, name = dotted.split(".")[:2]
    return any(re.search(rf"^(?:def|class) {re.escape(name)}\b|^{re.escape(name)}\s*[:=]", f.read_text(), re.M)
               for f in PKG.rglob(f"{module}.py"))


def prose_param_keys(text: str) -> Iterator[str]:
    for m in INLINE.finditer(FENCE.sub("", text)):
        code = m["code"].strip()
        if PARAM_IN_PROSE.match(code) and not FILE_SUFFIX.search(code) and not _is_code_name(code):
            yield code


@pytest.mark.parametrize("doc", DOCS, ids=[p.name for p in DOCS])
def test_every_command_of_the_docs_names_what_exists(doc: Path) -> None:
    problems = [p for line in commands(doc.read_text()) for p in check_command(line)]
    assert not problems, f"{doc.name}: commands naming what does not exist:\n" + "\n".join(problems)


def source_setting(parts: list[str]) -> bool:
    """``datasets.<ds>.source.<key>...`` where ``<key>`` is a setting of some registered data source
    (params.yaml holds the settings of each set's own source only)."""
    from compact_perception.core.params import SOURCES

    fields = {f for k in SOURCES.keys() for f in SOURCES[k].settings.model_fields}
    return len(parts) >= 4 and parts[0] == "datasets" and parts[2] == "source" and parts[3] in fields


@pytest.mark.parametrize("doc", DOCS, ids=[p.name for p in DOCS])
def test_every_params_key_the_prose_names_exists(doc: Path) -> None:
    missing = sorted({k for k in prose_param_keys(doc.read_text())
                      if not key_exists(params(), k.lstrip("+").split(".")) and not source_setting(k.split("."))})
    assert not missing, f"{doc.name}: params keys that params.yaml does not have: {missing}"


def paper_links() -> set[str]:
    """The two links that may leave the repository: the paper's DOI and the authors' code, as
    CITATION.cff names them."""
    paper = yaml.safe_load((ROOT / "CITATION.cff").read_text())["references"][0]
    return {f"https://doi.org/{paper['doi']}", paper["repository-code"]}


@pytest.mark.parametrize("doc", DOCS, ids=[p.name for p in DOCS])
def test_links_stay_inside_the_repository(doc: Path) -> None:
    text = doc.read_text()
    links = re.findall(r"\]\(([^)\s]+)\)", text)
    external = [t for t in links if re.match(r"[a-z]+:", t) and t not in paper_links()]
    assert not external, f"{doc.name}: links that leave the repository (only the paper's and its code's may): {external}"
    broken = [t for t in links if not t.startswith("#") and t not in paper_links()
              and not (doc.parent / t.split("#")[0]).exists()]
    assert not broken, f"{doc.name}: links to nothing in the repository: {broken}"
    outside = [line for line in text.splitlines() if re.search(r"\.\./shared|/work/|/home/|/tmp/|\bSPEC\b", line)]
    assert not outside, f"{doc.name}: lines naming a path outside the repository or the specification: {outside}"


def test_the_checker_catches_what_does_not_exist() -> None:
    assert check_command("make repro") == [] and check_command("make test-fast") == []
    assert check_command("make reproduce") == ["make reproduce: the Makefile has no target reproduce"]
    assert check_command("bin/venv dvc repro train@A evaluate@<ds>") == []
    assert check_command("bin/venv dvc repro train@D") == ["bin/venv dvc repro train@D: dvc.yaml has no stage train@D"]
    assert check_command("bin/venv dvc exp run -S 'dataset_ids=[A]' -S 'sim_ids=[A]'") == []
    assert check_command("bin/venv dvc exp run -S '+train.models.compact_1l.lr=0.05'") == []
    assert check_command("bin/venv dvc exp run -S train.parallel=4") == \
        ["bin/venv dvc exp run -S train.parallel=4: params.yaml has no key train.parallel"]
    assert check_command("bin/venv python -m pipeline.train --dataset A --seed 0") == []
    assert check_command(".venv/bin/python benchmarks/bench_gpu.py --device cuda --fast") == \
        [".venv/bin/python benchmarks/bench_gpu.py --device cuda --fast: benchmarks/bench_gpu.py has no flag --fast"]
    assert check_command("bin/venv python -m pipeline.nothing") == \
        ["bin/venv python -m pipeline.nothing: no file pipeline/nothing.py"]
    assert list(prose_param_keys("set `train.parallel_runs` and `datasets.<ds>.training.seeds`, see `train.py`")) == \
        ["train.parallel_runs", "datasets.<ds>.training.seeds"]
    assert not key_exists(params(), ["train", "parallel"])


# ----------------------------------------------------------------------------- the maps of the code
def top_level_modules() -> set[str]:
    mods = {p.stem for p in PKG.glob("*.py") if p.stem != "__init__"}
    return mods | {p.name for p in PKG.iterdir() if (p / "__init__.py").is_file()}


def package_map_names(doc: Optional[str]) -> set[str]:
    """The names of the package map's entries: the ````name```` at the start of each ``- `` line."""
    names: set[str] = set()
    for line in (doc or "").splitlines():
        m = re.match(r"\s*- ((?:``\w+``/?)+)", line)
        if m:
            names |= set(re.findall(r"``(\w+)``", m[1]))
    return names


def architecture_rows() -> dict[str, str]:
    """docs/ARCHITECTURE.md's module table: each first-column name -> its row."""
    rows: dict[str, str] = {}
    text = (ROOT / "docs" / "ARCHITECTURE.md").read_text()
    table = text.split("| module | concern |", 1)[1].split("\n\n", 1)[0]
    for line in table.splitlines():
        m = re.match(r"\| ((?:`[\w/]+`(?:, )?)+) \|(.*)\|\s*$", line)
        if m:
            for name in re.findall(r"`(\w+)/?`", m[1]):
                rows[name] = m[2]
    return rows


def test_the_package_map_names_every_module_and_only_those() -> None:
    import compact_perception
    named = package_map_names(compact_perception.__doc__)
    assert named, "no package map in compact_perception/__init__.py"
    assert named - top_level_modules() == set(), f"the package map names modules that do not exist: " \
                                                 f"{sorted(named - top_level_modules())}"
    assert top_level_modules() - named == set(), f"modules the package map leaves out: " \
                                                 f"{sorted(top_level_modules() - named)}"


def test_the_architecture_module_table_matches_the_files() -> None:
    rows = architecture_rows()
    assert set(rows) - top_level_modules() == set(), f"docs/ARCHITECTURE.md names modules that do not exist: " \
                                                     f"{sorted(set(rows) - top_level_modules())}"
    assert top_level_modules() - set(rows) == set(), f"modules docs/ARCHITECTURE.md leaves out: " \
                                                     f"{sorted(top_level_modules() - set(rows))}"
    for sub in sorted(n for n in rows if (PKG / n).is_dir()):
        files = {p.stem for p in (PKG / sub).glob("*.py") if p.stem != "__init__"}
        files |= {p.name for p in (PKG / sub).iterdir() if (p / "__init__.py").is_file()}
        missing = sorted(f for f in files if not re.search(rf"`{f}\b", rows[sub]))
        assert not missing, f"docs/ARCHITECTURE.md's `{sub}/` row leaves out {missing}"


def test_the_readme_links_the_paper_and_the_authors_code() -> None:
    """A reader finds the paper (its DOI) and the authors' code from the README's first lines."""
    head = "\n".join((ROOT / "README.md").read_text().splitlines()[:12])
    linked = set(re.findall(r"\]\(([^)\s]+)\)", head))
    assert paper_links() <= linked, f"the README's opening does not link {sorted(paper_links() - linked)}"


def test_license_and_citation_match_the_readme() -> None:
    """LICENSE is MIT, and the README's citation block names what CITATION.cff names."""
    assert (ROOT / "LICENSE").read_text().startswith("MIT License")
    cff = yaml.safe_load((ROOT / "CITATION.cff").read_text())
    readme = (ROOT / "README.md").read_text()
    block = readme.split("## Citation", 1)[1].split("## ", 1)[0]
    assert cff["license"] == "MIT" and "license = {MIT}" in block
    assert f"title   = {{{cff['title']}}}" in block and f"version = {{{cff['version']}}}" in block
    paper = cff["references"][0]
    assert f"title   = {{{paper['title']}}}" in block and f"doi     = {{{paper['doi']}}}" in block
    assert all(a["family-names"] in block for a in paper["authors"])
    import compact_perception
    assert str(cff["version"]) == compact_perception.__version__
