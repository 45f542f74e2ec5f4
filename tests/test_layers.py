"""The package's layers import downward only.

Every module under ``src/compact_perception`` is parsed with :mod:`ast` (imports inside functions
included, relative imports resolved) and mapped to its layer by :data:`LAYERS`; an import of a
module in a higher layer fails, and so does an import across two subpackages of one layer that
:data:`SIBLINGS_APART` keeps apart.

The layer table (lowest first; a module may import its own layer's leaf modules and anything
below it):

0. ``core`` -- params, catalog, registries, io, errors: imports nothing of the project above it.
1. leaf modules -- one concern each, on top of ``core``: ``data``, ``models``, ``weighting``,
   ``geometry``, ``dvs``, ``lidar``, ``world``, ``nuscenes``, ``authors``, ``carla``,
   ``preprocess``, ``losses``, ``metrics``, ``floor``, ``plan``, ``schedule`` (the plateau rule
   shared by training and MGN), ``qualitative`` (the qualitative grid, drawn by the data stages
   and the report), ``figures_lidar``, ``efficiency`` (the model measurements of Table III),
   ``onnx_export`` (ONNX export of a network).
2. ``training``, ``evaluate`` and ``timing`` (the benchmark's inference variants, which use
   ``training.precision``) -- they run the networks of layer 1.
3. ``report`` and ``stats`` (the report's statistics) -- they read what layer 2 wrote.
4. ``pipeline`` -- the stage entry points (outside ``src``; may import everything).

The package's own ``__init__`` imports nothing of the project, so it is layer 0.
"""
from __future__ import annotations

import ast
from pathlib import Path

import pytest

from imports import import_targets

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "src" / "compact_perception"
TOP = "compact_perception"

CORE, LEAF, RUN, REPORT = 0, 1, 2, 3
LAYERS: dict[str, int] = {
    "": CORE, "core": CORE,
    **{name: LEAF for name in (
        "data", "models", "weighting", "geometry", "dvs", "lidar", "world", "nuscenes", "authors", "carla",
        "preprocess", "losses", "metrics", "floor", "plan", "schedule", "qualitative", "figures_lidar",
        "efficiency", "onnx_export")},
    "training": RUN, "evaluate": RUN, "timing": RUN,
    "report": REPORT, "stats": REPORT,
}
LAYER_NAMES = {CORE: "core", LEAF: "leaf modules", RUN: "training/evaluate", REPORT: "report"}

#: Subpackages of one layer that must not import each other (the trainable parts stay separate:
#: a network does not know its loss weighting, nor the weighting the network).
SIBLINGS_APART: frozenset[frozenset[str]] = frozenset({
    frozenset({"models", "weighting"}),
    frozenset({"training", "evaluate"}),
})


def _modules() -> dict[str, Path]:
    out = {}
    for path in sorted(PKG.rglob("*.py")):
        parts = list(path.relative_to(PKG.parent).with_suffix("").parts)
        if parts[-1] == "__init__":
            parts = parts[:-1]
        out[".".join(parts)] = path
    return out


def _imported(module: str, path: Path) -> list[tuple[int, str]]:
    """``(line, module)`` of every project module imported by ``module`` (lazy imports included)."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found = [(node.lineno, name) for node in ast.walk(ast.parse(path.read_text(), str(path)))
             for name in import_targets(node, package)]
    return [(line, name) for line, name in found if name == TOP or name.startswith(TOP + ".")]


def _top(module: str) -> str:
    """The first component below the package (``""`` for the package itself)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else ""


def _layer(module: str) -> int:
    top = _top(module)
    assert top in LAYERS, f"{module}: no layer in tests/test_layers.py's LAYERS; add {top!r} there"
    return LAYERS[top]


def _known(name: str, modules: dict[str, Path]) -> bool:
    return name in modules


def test_every_module_has_a_layer():
    for module in _modules():
        _layer(module)


def _violations() -> list[str]:
    modules = _modules()
    bad = []
    for module, path in modules.items():
        here, top = _layer(module), _top(module)
        for line, name in _imported(module, path):
            if not _known(name, modules):
                continue  # a name imported from a module, not a module
            there, other = _layer(name), _top(name)
            rel = f"{path.relative_to(ROOT)}:{line}: {module} imports {name}"
            if there > here:
                bad.append(f"{rel} ({LAYER_NAMES[here]} -> {LAYER_NAMES[there]}: upward)")
            elif other != top and frozenset({top, other}) in SIBLINGS_APART:
                bad.append(f"{rel} (sideways: {top} and {other} are kept apart)")
    return bad


def test_layers_import_downward_only():
    bad = _violations()
    assert not bad, "imports against the layer order:\n" + "\n".join(bad)


def test_checker_resolves_relative_and_lazy_imports(tmp_path):
    """The parser itself: a lazy relative import two levels up is found and resolved."""
    src = tmp_path / "x.py"
    src.write_text("def f():\n    from ..report.figures import save_figure\nimport os\n")
    found = _imported("compact_perception.weighting.mgn", src)
    assert (2, "compact_perception.report.figures") in found
    assert (2, "compact_perception.report.figures.save_figure") in found
    assert all(name != "os" for _, name in found)


@pytest.mark.parametrize("importer, imported, upward", [
    ("compact_perception.weighting.mgn", "compact_perception.training.schedule", True),
    ("compact_perception.authors", "compact_perception.report.qualitative", True),
    ("compact_perception.report.study", "compact_perception.weighting", False),
    ("compact_perception.training.train", "compact_perception.core.config", False),
])
def test_layer_order(importer, imported, upward):
    assert (_layer(imported) > _layer(importer)) is upward
