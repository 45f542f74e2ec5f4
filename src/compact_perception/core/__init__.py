"""The infrastructure every stage shares (one DVC dependency, ``src/compact_perception/core``):

- ``config``       typed schema of params.yaml (unknown keys and wrong types are errors)
- ``catalog``      the registries of datasets, models and tasks (ids, labels, metric keys)
- ``registry``     the small registry type the catalogs and ``weighting`` are built on
- ``classes``      the 23 CARLA tags, the 9 BEV classes, the 32 nuScenes-lidarseg classes
- ``cache``        the compact memory-mapped dataset cache (SPEC 4) and its checks
- ``layout``       where each run, result and report file lives
- ``io``           atomic, deterministic file writing
- ``errors``       the error classes a stage turns into a one-line message
- ``determinism``  the numeric-library pins that make results byte-identical across x86-64
- ``params_audit`` the record of which params keys a stage reads (checked against dvc.yaml)

Nothing here imports from the rest of the package, so importing ``core`` never pulls in torch.
"""
