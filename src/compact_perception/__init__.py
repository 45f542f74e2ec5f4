"""compact_perception: a reproducible pipeline for Natan & Miura (2022),
"Towards Compact Autonomous Driving Perception with Balanced Learning and
Multi-sensor Fusion" (IEEE T-ITS).

Package map (one concern per module):

- ``config``       typed schema of params.yaml (unknown keys and wrong types are errors)
- ``classes``      the 23 CARLA tags, the 9 BEV classes, the 32 nuScenes-lidarseg classes
- ``geometry``     frame conventions and the top-view grid of eq. (2)-(3)
- ``io``           atomic, deterministic file writing
- ``world``        the embedded procedural driving world (datasets A, B, C)
- ``dvs``/``lidar`` the paper's preprocessing, eq. (1) and eq. (2)-(5)
- ``cache``/``data`` the compact memory-mapped cache and the PyTorch loader
- ``models``       the compact model and the baselines, ``build_model(model_id, dataset_id)``
- ``losses``/``metrics`` section III-B
- ``weighting``    static weights, MGN (Algorithm 1), original GradNorm
"""

__version__ = "0.1.0"
