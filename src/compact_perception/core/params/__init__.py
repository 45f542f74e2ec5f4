"""Typed schema of params.yaml (SPEC 9): unknown keys and wrong types are errors
whose message names the offending key.

Types are strict: a bool or a string never passes as a number (``batch_size: true`` is an
error, not 1), a YAML int passes where a float is expected. Every setting that can change a
result is required, so params.yaml spells out every value a result depends on and no default
hides in code; only settings that cannot change a result (worker counts, the device
preference) have defaults. An optional override (a model's ``max_epochs``, an optimiser's own
settings) is absent when not used.

A model's training recipe is ``train.recipe`` (the base every model shares) merged with
``train.models.<id>`` (what that model changes): :func:`merge_recipe`, applied by the schema, so
``Params.train.models[id]`` is the whole recipe. A recipe's loss-weighting settings sit in a
section named after its weighting (``mgn: {...}``), validated by that method's own schema
(``compact_perception.learning.weighting``), which this module does not import (no torch here).

``scale`` is the one switch (README "Scale"): ``default`` (a 2-core CPU, under an hour for the
whole pipeline: set A's main ablation trained deep, the rest shallow), ``full`` (the same data,
every dataset, model, seed and the study trained to the plateau: hours on a CPU) and ``paper``
(the paper's frames, resolution and schedule: a GPU). Every value that differs between them is
written as ``{default: ..., full: ..., paper: ...}`` (a :class:`Scaled`), resolved once when the
params load (``Params``' accessors; :func:`.base.resolve_scale` is the one resolver).

How deep a run trains is its dataset's ``training`` (:class:`TrainingBudget`: the compact
models' seeds and the epoch cap; a recipe's own ``max_epochs`` overrides the cap): early stopping
(``train.early_stop_patience``) ends a run when validation stops improving, the cap only bounds it.

This package holds the params, one module per concern, and this module is its one import point
(callers import from here): :mod:`.base` (``Strict``, ``Scaled`` and the one resolver of
``scale``, the count bounds), :mod:`.recipe` (a model's recipe and its merging), :mod:`.schema`
(the sections and ``Params``), :mod:`.errors` (``ParamsError`` and its one-line messages),
:mod:`.file` (reading the file), :mod:`.audit` (which keys a stage reads), :mod:`.sources`
(the data sources' registrations: each one's settings section, label and stage deps) and
:mod:`.former` (the layouts params were written in before, read in today's).
"""
from __future__ import annotations

from .base import (MAX_BATCH, MAX_FRAMES, MAX_SAVED_PREDICTIONS, MAX_SCENES, MAX_WORKERS, SCALES, ScaleName, Scaled,
                   Strict, resolve_scale)
from .errors import ParamsError, format_error
from .file import MAX_PARAMS_BYTES, MAX_PARAMS_VALUES, DuplicateKeyError, ExpansionError, UniqueKeyLoader, load_params
from .schema import (DATASET_IDS, TOWNS, BenchmarkParams, CameraParams, ConditionParams, DatasetsParams, DvsParams,
                     EvalParams, LidarParams, NuScenesParams, Params, PreprocessParams, SimDatasetParams, SplitRatio, StudyParams, TrainingBudget, TrainParams, WorldParams, parse_params)
from .recipe import ModelRecipe, check_lr_floor, merge_recipe
from .sources import SOURCES, AuthorsSource, AuthorsSplits, CarlaSource, SimSource, SourceSettings, source_label

__all__ = [
    "Strict", "Scaled", "ScaleName", "SCALES", "MAX_FRAMES", "MAX_SCENES", "MAX_WORKERS", "MAX_BATCH",
    "MAX_SAVED_PREDICTIONS", "resolve_scale", "ParamsError", "format_error", "load_params", "parse_params",
    "UniqueKeyLoader",
    "DuplicateKeyError", "ExpansionError", "MAX_PARAMS_BYTES", "MAX_PARAMS_VALUES", "DATASET_IDS", "TOWNS",
    "AuthorsSplits", "BenchmarkParams",
    "CameraParams", "CarlaSource", "ConditionParams", "DatasetsParams", "DvsParams", "EvalParams", "LidarParams",
    "NuScenesParams", "Params", "PreprocessParams", "SimDatasetParams", "SplitRatio", "StudyParams",
    "TrainingBudget", "TrainParams", "WorldParams", "ModelRecipe", "check_lr_floor", "merge_recipe",
    "SOURCES", "AuthorsSource", "SimSource", "SourceSettings", "source_label",
]
