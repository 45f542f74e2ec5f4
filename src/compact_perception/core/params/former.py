"""Params written before a change of layout, read in today's: the one list of those changes.

A run recorded at ``scale: full`` names the commit it ran at, and re-creating it (the command
its record gives, ``benchmarks/record_full.py --commit <that commit> ...``) or recording a part
resumed in a clone at that commit reads that commit's params.yaml with today's code. Each change
of layout since records were first made is one entry here, used two ways: :func:`upgrade_params`
rewrites a params document of the former layout into today's (what ``load_params(path,
former=True)`` does before validating), and a record's settings are compared with today's under
today's names (:data:`RENAMED_KEYS`, :data:`UNRECORDED_VALUES`; ``plateau_record.changed_keys``).

- ``datasets.<ds>.source`` was the source's id, a string, with the authors' release in
  ``authors_root``/``authors_splits`` and a CARLA server's settings in ``carla`` beside it, on
  every set whatever its source; it is now a section ``{id, <that source's settings>}``
  (``.sources``): ``{id: sim}``, ``{id: authors, root, splits}``, ``{id: carla, <carla>}``.
  The settings of the sources a set did not use did nothing and are dropped.
- ``evaluate.batch_size`` did not exist: evaluation scored one frame at a time.

Nothing else is guessed: a key this list does not name is validated as written.
"""
from __future__ import annotations

import copy
from typing import Any

__all__ = ["RENAMED_KEYS", "UNRECORDED_VALUES", "upgrade_params"]

#: Keys added after runs were recorded, each with the value that does what the code did before
#: the key existed: a record or params file without the key was made at that value.
UNRECORDED_VALUES: dict[str, Any] = {"evaluate.batch_size": 1}
#: Keys renamed after runs were recorded, as (pattern of the former key, today's key): the value
#: means the same under either name (``datasets.<ds>.source`` held the source's id before the
#: section held the source's own settings).
RENAMED_KEYS: tuple[tuple[str, str], ...] = ((r"^datasets\.([^.]+)\.source$", r"datasets.\1.source.id"),)
#: The former keys beside ``datasets.<ds>.source``, by the source whose settings they were.
_FORMER_SOURCE_KEYS = {"authors_root": "authors", "authors_splits": "authors", "carla": "carla"}


def _source_section(dataset: dict) -> list[str]:
    """Rewrite one dataset's former source keys into today's section, in place; what it did."""
    source = dataset["source"]
    former = {k: dataset.pop(k) for k in list(_FORMER_SOURCE_KEYS) if k in dataset}
    section: dict[str, Any] = {"id": source}
    if source == "authors":
        section.update({k: v for k, v in (("root", former.get("authors_root")),
                                          ("splits", former.get("authors_splits"))) if v is not None})
    elif source == "carla" and isinstance(former.get("carla"), dict):
        section.update(former["carla"])
    dataset["source"] = section
    dropped = sorted(k for k in former if _FORMER_SOURCE_KEYS[k] != source)
    return [f"source: {source!r} -> {{id: {source}, ...}}" + (f" (dropped {', '.join(dropped)})" if dropped else "")]


def upgrade_params(data: Any) -> tuple[Any, list[str]]:
    """``data`` (a parsed params document) with every former layout of this module's list
    rewritten in today's, as a new document, and one line per change made (empty: nothing was in
    a former layout). What is not a mapping where the layout expects one is left for the schema
    to refuse."""
    if not isinstance(data, dict):
        return data, []
    data = copy.deepcopy(data)
    changes: list[str] = []
    datasets = data.get("datasets")
    for ds, section in datasets.items() if isinstance(datasets, dict) else ():
        if isinstance(section, dict) and isinstance(section.get("source"), str):
            changes += [f"datasets.{ds}.{c}" for c in _source_section(section)]
    for key, value in UNRECORDED_VALUES.items():
        *parents, leaf = key.split(".")
        node = data
        for p in parents:
            node = node.get(p) if isinstance(node, dict) else None
        if isinstance(node, dict) and leaf not in node:
            node[leaf] = value
            changes.append(f"{key}: absent -> {value!r} (what the code did before the key)")
    return data, changes
