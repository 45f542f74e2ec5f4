"""The report's tables, one module per table, each written as Markdown, LaTeX (booktabs) and/or
CSV; their rows and columns come from :mod:`..schema` (the registries).

- ``table2``      Table II, the test comparison (mean ± sd over the seeds, the paper's per-frame
                  variance; bold where the row is above the floor and the 95% interval of its
                  difference from the runner-up, seed-cluster-t by default, lies above 0)
- ``table3``      Table III, efficiency (parameters, size, memory, FPS; the combination as a sum)
- ``comparison``  the paper's published numbers beside this run's, and this run's scale
- ``extra``       metrics beyond the paper's: per-class IoU / mIoU, depth errors on metric depth
- ``formats``     what they share: number formats, cell marks, the Markdown / LaTeX / CSV writers
"""
