"""Training (paper section IV-D), one DVC dependency for the training stages
(``src/compact_perception/training``):

- ``train``        the training run: loop, validation, checkpoints, resume, dvclive logs
- ``schedule``     the learning-rate plateau rules and early stopping
- ``provenance``   the code fingerprint in a run's digest (no shortcut outlives a code change)
- ``precision``    mixed precision, channels-last and ``torch.compile`` (issue 15's fast path)
- ``distributed``  ``torchrun`` data parallelism (gloo on CPU, nccl on GPU; rank 0 writes)
"""
