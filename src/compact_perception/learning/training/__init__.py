"""Training (paper section IV-D), one DVC dependency for the training stages
(``src/compact_perception/learning/training``):

- ``train``        the training run (``train_run``) as named steps: setup, resume, epoch end,
                   checkpoint, finish; the run's seed and digest; the dvclive logs
- ``state``        ``RunSpec`` / ``RunState``: the one object the steps share
- ``epoch``        one epoch: the training steps (the weighting's step protocol) and validation
- ``checkpoint``   ``best.pt`` / ``last.pt``: atomic writes, reading back for a resume, restore
- ``provenance``   the code fingerprint in a run's digest (no shortcut outlives a code change)
- ``precision``    mixed precision, channels-last and ``torch.compile`` (issue 15's fast path)
- ``distributed``  ``torchrun`` data parallelism (gloo on CPU, nccl on GPU; rank 0 writes)

The plateau rules and early stopping are :mod:`compact_perception.learning.schedule` (a leaf module: MGN's
weight learning rate follows the same rule).
"""
