"""Static import closure of the project's modules (for the dvc.yaml dependency checks).

Follows every ``import``/``from ... import`` statement, including those inside functions,
from a stage's entry module through ``pipeline`` and ``compact_perception``; third-party
modules are ignored (requirements.txt pins them).
"""
from __future__ import annotations

import ast
from pathlib import Path

PROJECT_PACKAGES = ("pipeline", "compact_perception")


def module_file(root: Path, module: str) -> Path | None:
    """The source file of a project module (``pkg/__init__.py`` for a package), or None."""
    parts = module.split(".")
    if parts[0] not in PROJECT_PACKAGES:
        return None
    base = root / ("src" if parts[0] == "compact_perception" else "") / Path(*parts)
    for cand in (base.with_suffix(".py"), base / "__init__.py"):
        if cand.is_file():
            return cand
    return None


def import_targets(node: ast.AST, package: str) -> list[str]:
    """The modules one import statement names: ``a.b`` of ``import a.b``; ``base`` and each
    ``base.name`` of ``from base import name`` (a name may be a submodule), a relative ``base``
    resolved against ``package``; nothing for any other node."""
    if isinstance(node, ast.Import):
        return [alias.name for alias in node.names]
    if not isinstance(node, ast.ImportFrom):
        return []
    if node.level:
        parts = package.split(".")
        base = ".".join(parts[: len(parts) - (node.level - 1)] + ([node.module] if node.module else []))
    else:
        base = node.module or ""
    return [base] + [f"{base}.{alias.name}" for alias in node.names]


def _module_name(root: Path, path: Path) -> str:
    rel = path.relative_to(root / "src" if path.is_relative_to(root / "src") else root).with_suffix("")
    parts = list(rel.parts)
    if parts[-1] == "__init__":
        parts = parts[:-1]
    return ".".join(parts)


def module_imports(root: Path, path: Path) -> set[str]:
    """Every module importing the file at ``path`` runs (lazy imports included; a third-party
    module by its name too), each with the packages above it (``a.b.c`` runs ``a`` and ``a.b``);
    a package that calls ``import_submodules`` (the model networks, the data sources, the
    weighting methods) runs every module in its folder."""
    name = _module_name(root, path)
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        found.update(import_targets(node, package))
        if (path.name == "__init__.py" and isinstance(node, ast.Call) and isinstance(node.func, ast.Name)
                and node.func.id == "import_submodules"):
            found.update(f"{name}.{p.stem}" for p in path.parent.glob("*.py") if p.name != "__init__.py")
    out: set[str] = set()
    for mod in found:
        parts = mod.split(".")
        for i in range(1, len(parts) + 1):  # importing a.b.c runs a/__init__ and a/b/__init__ too
            out.add(".".join(parts[:i]))
    return out


def import_closure(root: Path, entry: Path) -> set[Path]:
    """Every project source file that running ``entry`` can import."""
    seen: set[Path] = set()
    todo = [entry]
    parent = entry.parent  # `python -m pkg.mod` runs pkg/__init__.py first
    while (parent / "__init__.py").is_file():
        todo.append(parent / "__init__.py")
        parent = parent.parent
    while todo:
        path = todo.pop()
        if path in seen:
            continue
        seen.add(path)
        for mod in module_imports(root, path):
            f = module_file(root, mod)
            if f is not None and f not in seen:
                todo.append(f)
    return seen
