"""The train stage: networks, their losses and metrics, loss weighting, and the training run.

- ``models`` (the compact network and the baselines, ``build_model``), ``losses`` and ``metrics``
  (section III-B), ``weighting`` (static, MGN, GradNorm, UW, DWA, PCGrad, CAGrad, single-task);
  ``models`` and ``weighting`` do not import each other.
- ``schedule``: the plateau rule of section IV-D, shared by the training loop and MGN.
- ``plan``: the runs a dataset's stages hold, each planned once as one ``PlannedRun``.
- ``training``: the run (``train_run(params, run)``), its epochs, checkpoints, precision, DDP and
  the stage's runs side by side; ``onnx_export``: a trained network as ONNX.
"""
