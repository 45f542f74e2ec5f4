"""The evaluate and benchmark stages: scoring trained runs on the test split and measuring them.

- ``evaluate``: a run's test scores (eq. (5) and arg-max scores, per frame and per test set),
  ``evaluate_run(params, run, floor)``; ``floor``: the trivial-predictor floor every network must
  beat.
- ``efficiency`` (Table III: parameters, size, peak memory, FPS) and ``timing`` (batch-1
  inference variants for the GPU benchmark).
"""
