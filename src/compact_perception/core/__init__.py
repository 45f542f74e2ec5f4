"""The infrastructure every stage shares (one DVC dependency, ``src/compact_perception/core``):

- ``params``       params.yaml: its typed schema (unknown keys and wrong types are errors), the
                   reading of the file, ``scale`` resolved once, the record of the keys a stage reads
- ``catalog``      the registries of tasks, scores, datasets, models and their groups, weighting
                   labels (ids, labels, metric keys, group rules)
- ``registry``     the small registry type the catalogs and ``weighting`` are built on
- ``classes``      the 23 CARLA tags, the 9 BEV classes, the 32 nuScenes-lidarseg classes
- ``cache``        the compact memory-mapped dataset cache (SPEC 4) and its checks
- ``layout``       where each run, result and report file lives
- ``io``           atomic, deterministic file writing
- ``errors``       the error classes a stage turns into a one-line message
- ``determinism``  the numeric-library pins that make results byte-identical across x86-64

Nothing here imports from the rest of the package, so importing ``core`` never pulls in torch.
"""
