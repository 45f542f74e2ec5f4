"""Recording the paper's datasets from a CARLA server (a ``carla`` source; docs/carla.md).

| module | concern |
|---|---|
| ``convert`` | CARLA's documented sensor buffers (BGRA images, 24-bit depth, semantic tags, DVS events, semantic LiDAR) -> raw-record arrays |
| ``rig`` | the paper's sensor rig as blueprints and mounts, from ``world.camera``/``lidar``/``dvs`` |
| ``conditions`` | an episode's time of day and weather as ``carla.WeatherParameters`` |
| ``bev`` | the 9 BEV masks from the map's waypoints and the actors, on the LiDAR's top-view grid |
| ``collector`` | the server session: connect, towns, traffic, synchronous stepping, one record per frame |
| ``recording`` | the plan, the resuming frame writer, the manifest, and generate@<ds>'s check and import |

Nothing here imports the ``carla`` client at module level; :func:`collector.import_client` does,
when a collection starts. The client is an optional extra (``pip install -e .[carla]``).
"""
