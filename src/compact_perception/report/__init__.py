"""Reports (SPEC 8): Table II / III, paper-vs-reproduced table, claims scorecard, figures, the
plots' CSV files, the headline metrics and ``reports/index.md``, over every training seed.

- ``schema``      the tables' rows and columns, labels and MGN forms, derived from the registries
- ``collect``     reading the pipeline's outputs; :func:`~.collect.list_runs`, the one place that
                  knows which runs (seeds) of a (dataset, model) exist; means and sds over seeds
- ``paper``       the paper's published numbers (``paper_numbers.yaml``) and their loader
- ``tables``      one module per table: ``table2`` (the floor's rows first), ``table3``, ``comparison``
                  (paper vs reproduced), ``extra`` (metrics beyond the paper's, the arg-max rule
                  among them), and their shared ``formats``
- ``gate``        the learnedness gate: each row's margin over the trivial-predictor floor and
                  whether its interval lies above 0 (nothing below the floor is bolded, judged or
                  given a Δm)
- ``claims``      the claims (CLAIMS.md; both MGN forms), each row decided (``not decidable`` with the
                  reason)
- ``scorecard``   the claim rows, their verdict counts and the scorecard's ``claims.{md,csv}``
- ``figures``     loss-weight plots (Fig. 8), validation curves, qualitative grids (Fig. 6/7, drawn by
                  the leaf module :mod:`compact_perception.data.qualitative`)
- ``plots``       every run's validation TM and loss weights as long CSVs for ``dvc plots``
- ``study``       the loss-balancing study (beyond the paper): ``weighting.{md,csv}`` (four metrics,
                  TM, MV, Δm against single-task networks, time per epoch) and every method's loss weights
- ``index``       ``reports/index.md`` and ``reports/metrics.json`` tying everything together
"""
