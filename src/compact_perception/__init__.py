"""compact_perception: a reproducible pipeline for Natan & Miura (2022),
"Towards Compact Autonomous Driving Perception with Balanced Learning and
Multi-sensor Fusion" (IEEE T-ITS).

Package map (one concern per module):

- ``core``         what every stage shares: the params schema (``config``), the registries of
                   datasets, models and tasks (``catalog``), class tables, the dataset cache,
                   file layout, atomic I/O, errors and the determinism pins (see its docstring)
- ``geometry``     frame conventions and the top-view grid of eq. (2)-(3)
- ``world``        the embedded procedural driving world (datasets A, B, C)
- ``nuscenes``     the nuScenes-format export of the world and the nuScenes-lidarseg ingest
- ``authors``      reading the authors' released CARLA dataset
- ``carla``        recording sets from a CARLA server (optional ``carla`` client): the sensor rig,
                   the sensors' buffer formats, BEV ground truth from the map, the resumable writer
- ``record``       the raw record contract of data/raw/<ds>/ (manifest, frame npz): the sources
                   write it, ``preprocess`` reads it
- ``sources``      the data sources by ``datasets.<ds>.source`` (sim, authors, carla), each with its
                   raw records, example frame and cache, looked up by the generate and preprocess stages
- ``dvs``/``lidar``/``preprocess`` the paper's preprocessing, eq. (1) and eq. (2)-(5)
- ``figures_generate`` the generate stage's figure: one example frame of a source (Fig. 1-like)
- ``figures_preprocess`` the preprocess stage's figure: the LiDAR preprocessing (Fig. 5-like)
- ``qualitative``  the qualitative grid of one test frame (Fig. 6/7), drawn by the generate stage
                   (authors' source) and the report
- ``data``         the PyTorch loader over the cache
- ``models``       the compact model and the baselines, ``build_model(model_id, dataset_id)``
- ``losses``/``metrics`` section III-B
- ``weighting``    loss weighting: static, none, MGN (Algorithm 1), GradNorm, UW, DWA, PCGrad,
                   CAGrad, single-task
- ``schedule``     the plateau rule of section IV-D (lr halving, early stop), shared by training
                   and MGN's weight learning rate
- ``training``     the training run (section IV-D): loop, checkpoints, provenance, precision, DDP,
                   a stage's runs side by side
- ``plan``         which runs a dataset's stages hold (each model at its seeds, the study's arms)
- ``floor``        the trivial-predictor floor: input-blind predictors fitted on the train split
- ``stats``        the claims' statistics: distributions (t and normal quantiles, scipy), comparison,
                   variance (the linearised contrast's parts), power (MDE, decidability),
                   intervals (seed-cluster-t), verdicts, coverage (the check by simulation)
- ``evaluate``     test scoring (floors, eq. (5) and arg-max scores, margins over the floor)
- ``onnx_export`` ONNX export of a trained network and its check against PyTorch
- ``efficiency``   the model measurements of Table III: parameters, size, peak memory, FPS
- ``timing``       batch-1 inference timing of the benchmark's variants
- ``report``       tables, figures, claims, the loss-balancing study's table, and the index

docs/ARCHITECTURE.md has the same map with each module's concern in more detail.
"""

__version__ = "0.1.0"
