"""Reports (SPEC 8): Table II / III, paper-vs-reproduced table, figures, ``reports/index.md``.

- ``paper``       the paper's published numbers (``paper_numbers.yaml``) and their loader
- ``tables``      Table II, Table III and the paper-vs-reproduced table (Markdown, LaTeX, CSV)
- ``figures``     loss-weight plots (Fig. 8), validation curves, qualitative grids (Fig. 6/7)
- ``efficiency``  parameter count, state-dict size, peak memory and FPS of a model
- ``index``       ``reports/index.md`` tying everything together
"""
