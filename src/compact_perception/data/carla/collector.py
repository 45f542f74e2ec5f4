"""The CARLA server session: connect, load each town, drive the ego on the autopilot among
traffic, step the simulation synchronously and turn each recorded step into a raw record.

``carla`` (the official client module) is passed in, never imported at module level: the
project runs and tests without it (tests pass a small fake with the same names).

Per episode (:class:`~compact_perception.data.carla.recording.EpisodePlan`): the town is loaded if
it is not the current map; synchronous mode with ``fixed_delta_s`` is set (and the traffic
manager's too); the weather of the episode is applied; the ego (role ``hero``) and
``vehicles`` other vehicles are spawned at seeded spawn points on the traffic manager's
autopilot, ``pedestrians`` walkers with AI controllers going to random places; the rig of
:mod:`.rig` is attached to the ego. After ``warmup_ticks``, every ``ticks_per_frame``-th step
is recorded: each sensor's data of that step (a sensor that delivers nothing within
``timeout_s`` is an error), the DVS events of all steps since the previous frame (a DVS camera
sends only when events fire, so it is read without waiting), the BEV from the map and actors.
Everything spawned is destroyed (a walker's AI controller stopped first) and the server's
settings restored when an episode ends or fails. Recordings are not byte-reproducible: the
server's physics and pedestrians are not.

The client answers a server that does not reply in time (and most other server-side failures)
with a plain ``RuntimeError`` ("time-out of 10000ms while waiting for the simulator, ..."); every
such error becomes a :class:`CarlaError` naming the step (``load_world Town03``, ``tick``,
``spawn_actor``), the host and the port (:func:`server_step`). Loading a map runs under its own,
longer time-out (``carla.load_world_timeout_s``): a large town takes longer than a tick. A
session's first town is always loaded afresh, which clears whatever a session cut short left on
the server (its actors keep running otherwise).
"""
from __future__ import annotations

import contextlib
import logging
import queue
from typing import Any, Callable, Iterator, Mapping

import numpy as np

from ...core.classes import TAG
from ...core.errors import RecordError
from ...core.params.errors import cut
from ..geometry import VIEWS
from . import bev, convert
from .conditions import weather_parameters
from .recording import EpisodePlan, Recording
from .rig import SensorSpec, blueprint, transform

log = logging.getLogger(__name__)

#: waypoint spacing (m) of the map layers of the BEV
WAYPOINT_SPACING_M = 1.0
TRAFFIC_MANAGER_PORT = 8000
EGO_BLUEPRINTS = ("vehicle.lincoln.mkz_2017", "vehicle.lincoln.mkz2017", "vehicle.tesla.model3")


class CarlaError(RuntimeError):
    """The server cannot serve the recording (no server, wrong version, missing town, a silent sensor)."""


@contextlib.contextmanager
def server_step(step: str, where: str, hint: str = "") -> Iterator[None]:
    """A client ``RuntimeError`` raised inside (a time-out, a lost connection, a refused spawn) as
    one :class:`CarlaError` line naming ``step`` and the server ``where`` (``host:port``);
    ``hint`` says what to do about it."""
    try:
        yield
    except CarlaError:
        raise
    except RuntimeError as err:
        raise CarlaError(f"carla: {step} at {where}: {cut(str(err) or type(err).__name__)}"
                         + (f"; {hint}" if hint else "")) from None


def import_client() -> Any:
    """The ``carla`` module, or a one-line error naming the extra to install."""
    try:
        import carla
    except ImportError:
        raise CarlaError("carla: the client is not installed; pip install -e '.[carla]' "
                         "(or pip install carla==<your server's version>)") from None
    return carla


def connect(carla: Any, host: str, port: int, timeout_s: float) -> tuple[Any, str]:
    """(client, server version) of the server at host:port; its version must equal the client's."""
    client = carla.Client(host, int(port))
    client.set_timeout(float(timeout_s))
    try:
        server = str(client.get_server_version())
    except RuntimeError:
        raise CarlaError(f"carla: no server at {host}:{port} (connection timed out after {timeout_s:g} s)") from None
    mine = str(client.get_client_version())
    try:
        same = convert.parse_version(server) == convert.parse_version(mine)
    except convert.FormatError as err:
        raise CarlaError(f"carla: {err}") from None
    if not same:
        raise CarlaError(f"carla: client {mine} does not match server {server} at {host}:{port}; "
                         f"install the client of the server's version (pip install carla=={server.split('-')[0]})")
    return client, server


def _map_name(path: str) -> str:
    return str(path).replace("\\", "/").rsplit("/", 1)[-1]


def check_towns(client: Any, maps: list[str], where: str) -> None:
    """Every map in ``maps`` is one the server has."""
    with server_step("get_available_maps", where):
        have = sorted({_map_name(m) for m in client.get_available_maps()})
    missing = [m for m in dict.fromkeys(maps) if m not in have]
    if missing:
        raise CarlaError(f"carla: the server at {where} has no map {', '.join(missing)} (it has {', '.join(have) or 'none'})")


def load_town(client: Any, name: str, where: str, timeout_s: float, load_timeout_s: float, fresh: bool = False,
              timeout_key: str = "datasets.<ds>.source.load_world_timeout_s") -> Any:
    """The world with map ``name``, loaded if it is not the current one (or ``fresh``: always,
    which clears the actors a session cut short left behind). The load runs under the client
    time-out ``load_timeout_s`` (the params key ``timeout_key``); ``timeout_s`` is restored afterwards."""
    with server_step("get_world", where):
        world = client.get_world()
        current = _map_name(world.get_map().name)
    if fresh or current != name:
        client.set_timeout(float(load_timeout_s))
        try:
            with server_step(f"load_world {name} (time-out {load_timeout_s:g} s)", where,
                             f"a map that loads slower needs a longer {timeout_key}"):
                world = client.load_world(name)
        finally:
            client.set_timeout(float(timeout_s))
    return world


class SensorQueues:
    """One queue per sensor; :meth:`tick` steps the world and collects that step's data."""

    def __init__(self, timeout_s: float):
        self.timeout_s = float(timeout_s)
        self.queues: dict[str, queue.Queue] = {}
        self.events: dict[str, list[np.ndarray]] = {}

    def listen(self, key: str, sensor: Any) -> None:
        q: queue.Queue = queue.Queue()
        self.queues[key] = q
        if key.startswith("dvs_"):
            self.events[key] = []
        sensor.listen(q.put)

    def _drain_events(self, key: str, frame: int) -> None:
        q = self.queues[key]
        while True:
            try:
                data = q.get_nowait()
            except queue.Empty:
                return
            self.events[key].append(convert.dvs_events_from_raw(data.raw_data, data.width, data.height))
            if data.frame >= frame:
                return

    def tick(self, world: Any) -> tuple[int, dict[str, Any]]:
        """Step the world once; (frame number, {key: that frame's data}) of every non-DVS sensor."""
        frame = int(world.tick(self.timeout_s))
        out: dict[str, Any] = {}
        for key, q in self.queues.items():
            if key in self.events:
                continue
            while True:
                try:
                    data = q.get(timeout=self.timeout_s)
                except queue.Empty:
                    raise CarlaError(f"carla: sensor {key} delivered nothing for simulation frame {frame} "
                                     f"within {self.timeout_s:g} s") from None
                if int(data.frame) >= frame:
                    out[key] = data
                    break
        for key in self.events:
            self._drain_events(key, frame)
        return frame, out

    def take_events(self, key: str) -> np.ndarray:
        """The DVS events of ``key`` since the last call, sorted by t, y, x."""
        parts, self.events[key] = self.events[key], []
        ev = np.concatenate(parts) if parts else np.zeros((0, 4), np.int64)
        return ev[np.lexsort((ev[:, 1], ev[:, 2], ev[:, 0]))] if len(ev) else ev


def frame_record(data: Mapping[str, Any], queues: SensorQueues, table: np.ndarray, layers: bev.Layers,
                 actors: Mapping[str, list[Any]], ego: Any, range_m: float, size: int) -> dict[str, np.ndarray]:
    """The raw record (docs/ARCHITECTURE.md) of one recorded step."""
    rec: dict[str, np.ndarray] = {}
    for v in VIEWS:
        img = data[f"rgb_{v}"]
        rec[f"rgb_{v}"] = convert.rgb_from_bgra(img.raw_data, img.width, img.height)
        img = data[f"sem_{v}"]
        rec[f"sem_{v}"] = convert.semantic_from_bgra(img.raw_data, img.width, img.height, table)
        img = data[f"depth_{v}"]
        rec[f"depth_{v}"] = convert.log_depth_u16_from_bgra(img.raw_data, img.width, img.height)
        rec[f"dvs_{v}"] = queues.take_events(f"dvs_{v}")
    lidar = data["lidar"]
    rec["lidar"], rec["lidar_tag"] = convert.lidar_from_raw(lidar.raw_data, table)
    loc, rot = lidar.transform.location, lidar.transform.rotation
    pose = convert.right_handed_pose(loc.x, loc.y, rot.yaw)
    frame_layers = layers.merged(bev.actor_layers(actors["vehicles"], actors["walkers"], actors["lights"], ego))
    rec["bev"] = bev.rasterise(frame_layers, pose, range_m, size)
    rec["boxes"] = bev.boxes_in_ego(actors["vehicles"], actors["walkers"], ego, pose, float(loc.z), range_m,
                                    (TAG["vehicle"], TAG["pedestrian"]))
    rec["ego_pose"] = pose
    return rec


def _ego_blueprint(library: Any) -> Any:
    for name in EGO_BLUEPRINTS:
        found = list(library.filter(name))
        if found:
            return found[0]
    return list(library.filter("vehicle.*"))[0]


def _spawn_traffic(carla: Any, world: Any, library: Any, tm_port: int, ep: EpisodePlan, vehicles: int,
                   pedestrians: int, rng: np.random.Generator, spawned: list[Any], controllers: list[Any]) -> Any:
    """Spawn the ego and the traffic (appended to ``spawned``, the walkers' AI controllers to
    ``controllers`` too); returns the ego. A walker the navigation mesh gives no place (``None``)
    to stand on is not spawned; one it gives no place to go stands where it is."""
    points = list(world.get_map().get_spawn_points())
    order = [int(k) for k in rng.permutation(len(points))]
    ego_bp = _ego_blueprint(library)
    if hasattr(ego_bp, "set_attribute"):
        ego_bp.set_attribute("role_name", "hero")
    ego = None
    while order and ego is None:
        ego = world.try_spawn_actor(ego_bp, points[order.pop(0)])
    if ego is None:
        raise CarlaError(f"carla: no free spawn point for the ego vehicle in {ep.map}")
    spawned.append(ego)
    ego.set_autopilot(True, tm_port)
    car_bps = list(library.filter("vehicle.*"))
    n = 0
    while order and n < vehicles:
        actor = world.try_spawn_actor(car_bps[int(rng.integers(len(car_bps)))], points[order.pop(0)])
        if actor is not None:
            spawned.append(actor)
            actor.set_autopilot(True, tm_port)
            n += 1
    walker_bps = list(library.filter("walker.pedestrian.*"))
    for _ in range(pedestrians if walker_bps else 0):
        loc = world.get_random_location_from_navigation()
        if loc is None:
            continue
        walker = world.try_spawn_actor(walker_bps[int(rng.integers(len(walker_bps)))], carla.Transform(loc))
        if walker is None:
            continue
        spawned.append(walker)
        ctrl = world.spawn_actor(library.find("controller.ai.walker"), carla.Transform(), attach_to=walker)
        spawned.append(ctrl)
        controllers.append(ctrl)
    world.tick()
    standing = 0
    for ctrl in controllers:
        ctrl.start()
        target = world.get_random_location_from_navigation()
        if target is None:
            standing += 1
        else:
            ctrl.go_to_location(target)
    log.info("%s: ego and %d vehicles, %d pedestrians (%d without a place to go)", ep.map, n, len(controllers),
             standing)
    return ego


def _clean_up(world: Any, tm: Any, original: Any, sensors: list[Any], controllers: list[Any], spawned: list[Any],
              where: str) -> None:
    """End an episode on the server: sensors stopped, walkers' controllers stopped, everything
    destroyed (the latest first), synchronous mode off and the settings as they were. A server
    that does not answer one of these calls is not asked the rest (each would wait its full
    time-out): the next session's fresh map load clears what is left."""
    calls = [*(s.stop for s in sensors), *(c.stop for c in controllers),
             *(a.destroy for a in reversed(sensors + spawned)),
             lambda: tm.set_synchronous_mode(False), lambda: world.apply_settings(original)]
    for i, call in enumerate(calls):
        try:
            call()
        except RuntimeError as err:
            log.warning("carla: the server at %s did not answer while cleaning up (%s); %d call(s) skipped, the "
                        "next session's map load clears what is left", where, cut(str(err), 120), len(calls) - i - 1)
            return


def record_episode(carla: Any, client: Any, world: Any, ep: EpisodePlan, specs: list[SensorSpec], settings: Any,
                   ticks: int, table: np.ndarray, layers: bev.Layers, range_m: float, size: int,
                   write: Callable[[str, dict[str, np.ndarray]], None], where: str) -> dict[str, dict[str, Any]]:
    """Drive one episode and hand each frame to ``write(frame_id, record)``; returns the frames'
    metadata. A client error names the step and the server ``where`` (:func:`server_step`)."""
    episode = f"episode {ep.index} ({ep.map})"
    resume = "complete episodes are kept: rerun the same command to resume"
    with server_step(f"{episode}: get_settings", where, resume):
        original = world.get_settings()
        new = world.get_settings()
        tm = client.get_trafficmanager(TRAFFIC_MANAGER_PORT)
    new.synchronous_mode = True
    new.fixed_delta_seconds = float(settings.fixed_delta_s)
    spawned: list[Any] = []
    controllers: list[Any] = []
    sensors: list[Any] = []
    metas: dict[str, dict[str, Any]] = {}
    try:
        with server_step(f"{episode}: apply_settings (synchronous mode, traffic manager, weather)", where, resume):
            world.apply_settings(new)
            tm.set_synchronous_mode(True)
            tm.set_random_device_seed(int(ep.seed))
            world.set_weather(carla.WeatherParameters(**weather_parameters(ep.time_of_day, ep.weather, ep.intensity)))
            library = world.get_blueprint_library()
        rng = np.random.default_rng([int(ep.seed), 1])
        with server_step(f"{episode}: spawn_actor (ego and traffic)", where, resume):
            ego = _spawn_traffic(carla, world, library, tm.get_port(), ep, settings.vehicles, settings.pedestrians,
                                 rng, spawned, controllers)
        queues = SensorQueues(settings.timeout_s)
        for spec in specs:
            with server_step(f"{episode}: spawn_actor (sensor {spec.key})", where, resume):
                sensor = world.spawn_actor(blueprint(library, spec), transform(carla, spec), attach_to=ego)
                sensors.append(sensor)
                queues.listen(spec.key, sensor)
        with server_step(f"{episode}: tick (warm-up)", where, resume):
            for _ in range(settings.warmup_ticks):
                queues.tick(world)
            for key in queues.events:  # a frame's DVS holds the events of its own ticks only
                queues.take_events(key)
            lights = list(world.get_actors().filter("traffic.traffic_light*"))
        for step in range(ep.frames):
            fid = ep.frame_id(step)
            with server_step(f"{episode}: tick (frame {fid})", where, resume):
                for _ in range(ticks):
                    _, data = queues.tick(world)
                actors = world.get_actors()
                groups = {"vehicles": list(actors.filter("vehicle.*")),
                          "walkers": list(actors.filter("walker.pedestrian.*")), "lights": lights}
                try:
                    rec = frame_record(data, queues, table, layers, groups, ego, range_m, size)
                except convert.FormatError as err:
                    raise RecordError(f"frame {fid}: {err}") from None
            write(fid, rec)
            metas[fid] = {"town": ep.town, "episode": ep.index, "step": step, "time_of_day": ep.time_of_day,
                          "weather": {ep.weather: ep.intensity}}
    finally:
        _clean_up(world, tm, original, sensors, controllers, spawned, where)
    return metas


def collect(carla: Any, params: Any, dataset_id: str, root: str, host: str, port: int, restart: bool = False) -> int:
    """Record dataset ``dataset_id`` into ``root`` (resuming); returns the number of frames recorded now.

    Nothing is written before the server has answered and has every town the dataset needs.
    """
    from .recording import carla_settings, plan_document, ticks_per_frame
    from .rig import sensor_specs

    cs = carla_settings(params, dataset_id)
    where = f"{host}:{port}"
    client, server = connect(carla, host, port, cs.timeout_s)
    doc = plan_document(params, dataset_id)
    episodes = [EpisodePlan(**e) for e in doc["episodes"]]
    check_towns(client, [e.map for e in episodes], where)
    rec = Recording(root, dataset_id, doc)
    todo = {e["index"] for e in rec.open(restart)}
    if not todo and rec.manifest_path.exists():
        log.info("%s: already complete (%s)", root, rec.manifest_path)
        return 0
    size = int(doc["resolution"])
    specs = sensor_specs(params.world, size, cs.fixed_delta_s)
    table = convert.tag_table(server)
    ticks = ticks_per_frame(params, dataset_id)
    recorded = 0
    layers_of: dict[str, bev.Layers] = {}
    for ep in sorted((e for e in episodes if e.index in todo), key=lambda e: (e.map, e.index)):
        world = load_town(client, ep.map, where, cs.timeout_s, cs.load_world_timeout_s, fresh=not layers_of,
                          timeout_key=f"datasets.{dataset_id}.source.load_world_timeout_s")
        if ep.map not in layers_of:
            with server_step(f"generate_waypoints ({ep.map})", where):
                layers_of = {ep.map: bev.map_layers(world.get_map().generate_waypoints(WAYPOINT_SPACING_M),
                                                    WAYPOINT_SPACING_M)}
        log.info("episode %d (%s, %s, %s %s): %d frames", ep.index, ep.split, ep.map, ep.time_of_day, ep.weather,
                 ep.frames)
        metas = record_episode(carla, client, world, ep, specs, cs, ticks, table, layers_of[ep.map],
                               params.world.lidar.range_m, size, rec.write_frame, where)
        rec.finish_episode({k: v for k, v in ep.__dict__.items()}, metas)
        recorded += len(metas)
    rec.finalize({"server_version": server, "client_version": str(client.get_client_version()),
                  "host": host, "port": int(port)})
    return recorded
