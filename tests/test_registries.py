"""The registries are the single source of truth: params.yaml's id lists (which dvc.yaml's
matrices read) equal them, every loss weighting declares its label and params schema, and the package has no import
cycles."""
from __future__ import annotations

import ast
from pathlib import Path

import pytest
import yaml

from compact_perception.core import catalog
from compact_perception.core.params import DatasetsParams, ParamsError, load_params

from repo_params import repo_params_dict
from compact_perception.learning.weighting import WEIGHTINGS, weighting_class, weighting_settings

from imports import import_targets, module_file

ROOT = Path(__file__).resolve().parents[1]


def test_the_run_lists_equal_the_registries():
    """dvc.yaml's matrices iterate over params.yaml's id lists, which must equal the registries."""
    p = load_params(ROOT / "params.yaml")
    assert p.sim_ids == list(catalog.sim_dataset_ids())
    assert p.dataset_ids == list(catalog.dataset_ids())
    assert p.model_ids == list(catalog.model_ids())


def test_dvc_yaml_reads_its_lists_from_params():
    """No second copy of the lists: dvc.yaml has no ``vars`` of its own, and its matrices name
    params.yaml's lists."""
    text = (ROOT / "dvc.yaml").read_text()
    assert "vars" not in yaml.safe_load(text)
    for key in ("sim_ids", "dataset_ids"):
        assert "${" + key + "}" in text, key


def test_params_yaml_follows_the_registries():
    p = load_params(ROOT / "params.yaml")
    assert list(p.train.models) == list(catalog.model_ids())
    assert list(DatasetsParams.model_fields) == list(catalog.dataset_ids())
    used = {r.weighting for r in p.train.models.values()} | {a["weighting"] for a in p.study.arms.values()}
    assert used <= set(WEIGHTINGS.keys()), used - set(WEIGHTINGS.keys())
    # every registered method is studied or trained somewhere (a new method = file + params entry)
    assert set(WEIGHTINGS.keys()) - {"none"} <= used, set(WEIGHTINGS.keys()) - used
    # every recipe's and every arm's settings pass its method's own schema (what the stages check first)
    for recipe in [*p.train.models.values(), *(p.study_recipe(arm) for arm in p.study.arm_ids)]:
        settings = weighting_settings(recipe)
        schema = weighting_class(recipe.weighting).params_model
        assert (settings is None) == (schema is None) and (schema is None or isinstance(settings, schema))


def test_the_data_sources_equal_the_schema():
    """``datasets.<ds>.source`` is the union of the registered sources' settings, chosen by ``id``;
    each registered source has its module in data/sources and each module its registration, each
    module says what it does in each data stage, and no stage branches on the source by hand."""
    import typing

    from compact_perception.core.params import SOURCES, parse_params
    from compact_perception.core.params.schema import SimDatasetParams
    from compact_perception.data.sources import MODULES, data_source

    field = SimDatasetParams.model_fields["source"]
    union = typing.get_args(field.annotation)
    assert field.discriminator == "id"
    assert [typing.get_args(m.model_fields["id"].annotation) for m in union] == [(k,) for k in SOURCES.keys()]
    assert set(MODULES) == set(SOURCES.keys())
    for key in SOURCES.keys():
        source = data_source(key)
        assert callable(source.write_raw) and callable(source.draw_example), key
        assert source.cache is None or callable(source.cache), key
        assert SOURCES[key].label, key
    for stage in (ROOT / "pipeline" / "generate.py", ROOT / "src" / "compact_perception" / "data" / "preprocess.py"):
        text = stage.read_text()
        assert "source ==" not in text and "source in (" not in text and "source.id ==" not in text, stage
    # the discriminator: an id no source registers is one line naming the registered ones
    d = repo_params_dict()
    d["datasets"]["B"]["source"] = {"id": "lidar-only"}
    with pytest.raises(ParamsError, match=r"datasets\.B\.source: .*'sim', 'authors', 'carla'"):
        parse_params(d)


def test_every_weighting_declares_label_and_schema():
    for key in WEIGHTINGS.keys():
        cls = weighting_class(key)
        assert isinstance(cls.label, str) and cls.label, key
        assert hasattr(cls, "params_model"), key


def test_weighting_labels_live_in_the_catalog():
    """The report reads a method's label and ``adaptive`` from ``core.catalog`` (no torch): the same
    methods as the classes registered, and a class registered under an id the catalog lacks fails."""
    from compact_perception.learning.weighting.base import LossWeighting, register

    assert set(catalog.WEIGHTING_METHODS.keys()) == set(WEIGHTINGS.keys())
    for key in WEIGHTINGS.keys():
        info = catalog.weighting_info(key)
        assert (weighting_class(key).label, weighting_class(key).adaptive) == (info.label, info.adaptive)
    with pytest.raises(KeyError, match="unknown loss weighting 'nope'"):
        register("nope")(type("Nope", (LossWeighting,), {"params_model": None}))
    assert "nope" not in WEIGHTINGS


def test_every_weighting_class_in_the_package_is_registered():
    """A new method is one file: its class registers itself and the package finds the module."""
    import inspect
    import pkgutil

    import compact_perception.learning.weighting as pkg
    from compact_perception.learning.weighting.base import LossWeighting

    registered = {weighting_class(k) for k in WEIGHTINGS.keys()}
    for info in pkgutil.iter_modules(pkg.__path__):
        module = __import__(f"{pkg.__name__}.{info.name}", fromlist=["_"])
        for _, cls in inspect.getmembers(module, inspect.isclass):
            if issubclass(cls, LossWeighting) and cls.__module__ == module.__name__ and "params_model" in vars(cls):
                assert cls in registered, f"{cls.__name__} ({info.name}.py) declares a schema but is not registered"


def test_task_registry_directions():
    assert catalog.metric_keys() == ("mae_de", "iou_ss", "iou_ls", "iou_bevp")
    assert not catalog.higher_is_better("mae_de")
    assert all(catalog.higher_is_better(m) for m in ("iou_ss", "iou_ls", "iou_bevp"))
    for m in catalog.model_ids():
        info = catalog.MODELS[m]
        assert set(info.tasks) <= set(catalog.task_ids()) and info.group in ("compact", "baseline")


def test_a_score_is_computed_through_its_catalog_entry():
    """A Table II score is its SCORES entry: evaluation (scores_from_means, per-frame scores), the
    statistics and the report's interval statistic all call the entry's formula (of_terms)."""
    import numpy as np

    from compact_perception.evaluation.evaluate import frame_scores
    from compact_perception.learning.metrics import scores_from_means
    from compact_perception.report.schema import column_stat
    from compact_perception.stats import STATISTICS

    means = {"mae_de": 0.1, "iou_ss": 0.8, "iou_ls": 0.6, "iou_bevp": 0.9}
    terms = np.array(list(means.values()))
    by_entry = {k: float(catalog.SCORES[k].of_terms(*terms)) for k in catalog.SCORES.keys()}
    assert by_entry["tm"] == pytest.approx(0.8) and by_entry["mv"] == pytest.approx(0.015)
    assert scores_from_means(means) == by_entry
    assert frame_scores(means) == {**means, **{k: by_entry[k] for k in catalog.per_frame_scores()}}
    assert catalog.per_frame_scores() == ("tm",)
    for k in catalog.SCORES.keys():
        assert column_stat(k) is STATISTICS[k] and float(column_stat(k)(terms)) == by_entry[k]


def _top_level_imports(path: Path, module: str) -> set[str]:
    """Project modules imported at module level (what runs on import), without the module's own
    parent packages (importing a submodule while its package is being imported is no cycle)."""
    package = module if path.name == "__init__.py" else module.rpartition(".")[0]
    found: set[str] = set()
    for node in ast.parse(path.read_text()).body:
        found.update(name for name in import_targets(node, package) if module_file(ROOT, name) is not None)
    ancestors = {".".join(module.split(".")[:i]) for i in range(1, len(module.split(".")))}
    return {m for m in found if m not in ancestors and m != module}


def test_no_import_cycles():
    files = sorted((ROOT / "src" / "compact_perception").rglob("*.py"))
    graph: dict[str, set[str]] = {}
    for f in files:
        rel = f.relative_to(ROOT / "src").with_suffix("")
        parts = list(rel.parts[:-1]) if rel.name == "__init__" else list(rel.parts)
        mod = ".".join(parts)
        graph[mod] = set()
        for name in _top_level_imports(f, mod):
            target = module_file(ROOT, name)
            tr = target.relative_to(ROOT / "src").with_suffix("")
            tparts = list(tr.parts[:-1]) if tr.name == "__init__" else list(tr.parts)
            graph[mod].add(".".join(tparts))
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> None:
        state[m] = 1
        stack.append(m)
        for n in sorted(graph.get(m, ())):
            if n == m:
                continue
            if state.get(n) == 1:
                cycle = stack[stack.index(n):] + [n]
                pytest.fail(f"import cycle: {' -> '.join(cycle)}")
            if n not in state:
                visit(n)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)


def test_every_network_is_found_by_its_module():
    """A new network is one file: the models package finds every module with a ``build`` (no
    second registration, no second id); every model names such a module, every network serves
    some model, and the code fingerprint counts each network module."""
    from compact_perception.learning.models import NETWORKS, build_model
    from compact_perception.learning.training.provenance import fingerprinted_files

    networks = {catalog.MODELS[m].network for m in catalog.model_ids()}
    assert networks == set(NETWORKS.keys())
    assert {f"compact_perception/learning/models/{n}.py" for n in networks} <= set(fingerprinted_files())
    for m in catalog.model_ids():
        assert set(build_model(m, catalog.dataset_ids()[0]).tasks) == set(catalog.MODELS[m].tasks), m


def test_depth_metrics_derive_from_their_registry():
    """A new depth metric is one entry of core.depth_metrics.DEPTH_METRICS (the one evaluation's
    metrics module computes with): evaluation computes and summarises it, the report's
    extra-metrics table gets its columns, label and decimals."""
    import torch

    from compact_perception.evaluation import evaluate
    from compact_perception.learning import metrics
    from compact_perception.core.depth_metrics import DEPTH_METRICS
    from compact_perception.learning.metrics import depth_errors_per_sample
    from compact_perception.report.tables import extra

    assert metrics.DEPTH_METRICS is DEPTH_METRICS

    keys = tuple(DEPTH_METRICS.keys())
    assert evaluate.DEPTH_COLUMNS == keys and extra.EXTRA_DEPTH == keys
    for k in keys:
        assert DEPTH_METRICS[k].definition in evaluate.depth_definition(80.0)
        assert extra.EXTRA_MD[k] == DEPTH_METRICS[k].label
        assert f"{k}_mean" in extra.extra_csv([]).splitlines()[0]
    x = torch.full((1, 4, 1, 2, 2), 0.5, dtype=torch.float64)
    assert set(depth_errors_per_sample(x, x)) == set(keys) | {"n_valid"}
