"""compact_perception: a reproducible pipeline for Natan & Miura (2022),
"Towards Compact Autonomous Driving Perception with Balanced Learning and
Multi-sensor Fusion" (IEEE T-ITS).

Package map: the folders read as the pipeline, each importing only those above it in this list.

- ``core``        what every stage shares: the params schema (``config``; ``scale`` resolved where
                  params load), the registries of datasets, models, tasks and scores (``catalog``),
                  class tables, the dataset cache, file layout, atomic I/O, errors, the determinism
                  pins, the depth convention, the floor's rule, the plateau record (see its docstring)
- ``execution``   where a stage's jobs run: the local process pool (the default, its workers spread
                  over the visible GPUs) or SLURM through submitit, chosen by a setting no result
                  depends on (``cluster.yaml``, ``COMPACT_PERCEPTION_EXECUTOR``); nothing of it
                  enters a run's digest
- ``data``        the generate and preprocess stages and the loader: the raw record contract
                  (``record``), the data sources (``sources``: the embedded ``world``, the
                  ``authors``' release, ``carla`` recordings; ``nuscenes`` has its own stages),
                  the sensors' maths (``geometry``, ``dvs``, ``lidar``), ``preprocess``, each data
                  stage's figures, the qualitative grid and the PyTorch ``loader`` over the cache
- ``learning``    the train stage: the networks (``models``), their ``losses`` and ``metrics``
                  (section III-B), the loss ``weighting`` methods, the plateau rule (``schedule``),
                  which runs a stage holds (``plan``), the training run (``training``) and ONNX export
- ``evaluation``  the evaluate and benchmark stages: test scoring (``evaluate``), the
                  trivial-predictor ``floor``, Table III's measurements (``efficiency``, ``timing``)
- ``stats``       the claims' statistics (intervals with checked coverage, power, verdicts)
- ``report``      tables, figures, claims, the loss-balancing study's table, and the index

docs/ARCHITECTURE.md has the same map with each module's concern in more detail.
"""

__version__ = "0.1.0"
