"""Where a stage's runs execute: one seam between a stage's planned work and the engine that runs it.

A stage (``pipeline/train.py``, ``pipeline/evaluate.py``) plans its runs, decides which are
already complete, and hands the rest, with the worker function they are given to, to an
executor; the executor returns their results in the order given, or the first failure as one
line. Nothing here knows what a run is: this layer imports ``core`` only, never ``learning`` or
``evaluation``, and no file of it enters a run's digest (``learning/training/provenance``), so
adding or changing an executor restarts no run.

- ``jobs``              a job (one input of the worker function, with its name and cost), the
                        one-line job error, the worker-side call that turns an expected error
                        into its line
- ``pool``              the local process pool (the default; the former ``learning/training/parallel``
                        pool, unchanged), its workers spread over the visible GPUs
- ``settings``          which executor, and the cluster's settings: ``cluster.yaml`` and
                        ``COMPACT_PERCEPTION_EXECUTOR`` (no result depends on them; docs/cluster.md)
- ``submitit_backend``  SLURM through submitit (and submitit's ``local`` and ``debug`` executors),
                        requeued jobs resuming their runs
- ``executor``          the seam: the ``Executor`` protocol, the chosen executor, ``run_jobs``
"""
