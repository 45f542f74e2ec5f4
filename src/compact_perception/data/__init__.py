"""The data side: what the generate and preprocess stages do, and the loader the training reads with.

- ``record``: the raw record contract of ``data/raw/<ds>/`` (manifest, frame npz), written by
  every source and read by ``preprocess``; it imports no other module of this package.
- the sources: one module each in ``sources/``, named after its ``datasets.<ds>.source.id``
  (``sim``: the embedded world, ``world/``; ``authors``: the authors' released CARLA dataset,
  ``authors``; ``carla``: a recording from a CARLA server, ``carla/``), each registered with its
  settings in :mod:`compact_perception.core.params.sources`; ``nuscenes`` (the nuScenes-format
  export and the devkit ingest) has stages of its own.
- the sensors' maths: ``geometry`` (frames and the top-view grid of eq. (2)-(3)), ``dvs`` (eq. 1),
  ``lidar`` (eq. (2)-(5)).
- ``preprocess``: raw records -> the cache (:mod:`compact_perception.core.cache`).
- figures: ``figures_generate`` and ``figures_preprocess`` (one module per stage), ``qualitative``
  (the grid of one test frame, drawn by the generate stage and the report).
- ``loader``: the PyTorch loader over the cache and the batch on the device.
"""
