"""A small stand-in for the ``carla`` client module: only what a server would be needed for.

Sensor data is built in CARLA's documented buffer formats (BGRA images, 24-bit depth, tag in
red, packed 13-byte DVS events, 24-byte semantic LiDAR points), so the real conversions run on it.
A server that does not answer in time raises what the real client raises: a plain ``RuntimeError``
with the client's own message (:func:`timeout_error`). Every ``stop`` and ``destroy`` is logged
in ``World.log`` in call order.
"""
from __future__ import annotations

import fnmatch
import struct
import types
from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np


def timeout_error(client: "Client") -> RuntimeError:
    """The real client's exception for a server that does not answer within the client's time-out
    (LibCarla's ``rpc::timeout`` as the Python client raises it, e.g. from ``world.tick()``)."""
    client.gone = client.gone_after_timeout
    return RuntimeError(f"time-out of {int(round(client.timeout * 1000))}ms while waiting for the simulator, make sure "
                        f"the simulator is ready and connected to {client.host}:{client.port}")


@dataclass
class Location:
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0


@dataclass
class Rotation:
    pitch: float = 0.0
    yaw: float = 0.0
    roll: float = 0.0


@dataclass
class Transform:
    location: Location = field(default_factory=Location)
    rotation: Rotation = field(default_factory=Rotation)


@dataclass
class Vector3D:
    x: float = 0.0
    y: float = 0.0
    z: float = 0.0


@dataclass
class BoundingBox:
    location: Vector3D
    extent: Vector3D


@dataclass
class LaneMarking:
    type: str = "Solid"
    color: str = "White"


class Waypoint:
    def __init__(self, x: float, y: float, yaw: float = 0.0, lane_id: int = -1, width: float = 4.0,
                 left: LaneMarking | None = None, right: LaneMarking | None = None, left_lane: Any = None):
        self.transform = Transform(Location(x, y, 0.0), Rotation(yaw=yaw))
        self.lane_type, self.lane_width, self.lane_id = "Driving", width, lane_id
        self.left_lane_marking = left or LaneMarking()
        self.right_lane_marking = right or LaneMarking()
        self._left = left_lane

    def get_left_lane(self) -> Any:
        return self._left

    def get_right_lane(self) -> Any:
        return None


class Blueprint:
    def __init__(self, bp_id: str):
        self.id = bp_id
        self.attributes: dict[str, str] = {}

    def set_attribute(self, name: str, value: str) -> None:
        self.attributes[name] = value


class BlueprintLibrary:
    IDS = ("vehicle.lincoln.mkz_2017", "vehicle.audi.tt", "walker.pedestrian.0001", "controller.ai.walker",
           "sensor.camera.rgb", "sensor.camera.dvs", "sensor.camera.semantic_segmentation", "sensor.camera.depth",
           "sensor.lidar.ray_cast_semantic")

    def find(self, bp_id: str) -> Blueprint:
        if bp_id not in self.IDS:
            raise IndexError(bp_id)
        return Blueprint(bp_id)

    def filter(self, pattern: str) -> list[Blueprint]:
        return [Blueprint(i) for i in self.IDS if fnmatch.fnmatch(i, pattern)]


class ActorList(list):
    def filter(self, pattern: str) -> "ActorList":
        return ActorList(a for a in self if fnmatch.fnmatch(a.type_id, pattern))


class Actor:
    _next = 1

    def __init__(self, world: "World", bp: Blueprint, tr: Transform, parent: "Actor | None" = None):
        self.id, Actor._next = Actor._next, Actor._next + 1
        self.world, self.type_id, self.blueprint, self.parent = world, bp.id, bp, parent
        self._tr = tr
        self.bounding_box = BoundingBox(Vector3D(0.0, 0.0, 0.8), Vector3D(2.4, 1.0, 0.8))
        self.callback: Callable[[Any], None] | None = None
        self.destroyed = False

    def get_transform(self) -> Transform:
        if self.parent is None:
            return self._tr
        p = self.parent.get_transform()
        return Transform(Location(p.location.x + self._tr.location.x, p.location.y + self._tr.location.y,
                                  p.location.z + self._tr.location.z), Rotation(yaw=p.rotation.yaw + self._tr.rotation.yaw))

    def set_autopilot(self, on: bool, port: int) -> None:
        self.autopilot = (on, port)

    def listen(self, callback: Callable[[Any], None]) -> None:
        self.callback = callback

    def stop(self) -> None:
        if self.world.client.gone:
            raise timeout_error(self.world.client)
        self.callback = None
        self.world.log.append(("stop", self.type_id, self.id))

    def destroy(self) -> None:
        if self.world.client.gone:
            raise timeout_error(self.world.client)
        self.destroyed = True
        self.world.log.append(("destroy", self.type_id, self.id))
        self.world.actors.remove(self)

    def start(self) -> None:
        pass

    def go_to_location(self, loc: Any) -> None:
        if not isinstance(loc, Location):  # the real client: Boost.Python.ArgumentError, a TypeError
            raise TypeError(f"Python argument types in WalkerAIController.go_to_location did not match: {loc!r}")
        self.target = loc


class TrafficLight(Actor):
    def __init__(self, world: "World", x: float, y: float, state: str):
        super().__init__(world, Blueprint("traffic.traffic_light"), Transform(Location(x, y, 0.0)))
        self.state, self.stops = state, [Waypoint(x, y)]

    def get_state(self) -> str:
        return self.state

    def get_stop_waypoints(self) -> list[Waypoint]:
        return self.stops


@dataclass
class SensorData:
    frame: int
    raw_data: bytes
    width: int
    height: int
    transform: Transform


@dataclass
class Settings:
    synchronous_mode: bool = False
    fixed_delta_seconds: float | None = None


class Map:
    def __init__(self, name: str):
        self.name = f"Carla/Maps/{name}"

    def get_spawn_points(self) -> list[Transform]:
        return [Transform(Location(float(10 * k), 0.0, 0.3)) for k in range(6)]

    def generate_waypoints(self, distance: float) -> list[Waypoint]:
        return [Waypoint(float(x), 0.0, left=LaneMarking("Solid", "Yellow")) for x in np.arange(-40, 100, distance)]


# --- sensor buffers in CARLA's formats --------------------------------------------------
SEM_TAG = 7  # road in CARLA 0.9.10 numbering
DEPTH_24 = 167772  # ~10 m


def camera_bytes(kind: str, w: int, h: int, frame: int) -> bytes:
    img = np.zeros((h, w, 4), np.uint8)
    img[..., 3] = 255
    if kind == "sensor.camera.rgb":
        img[..., 0], img[..., 1], img[..., 2] = 30, 20, (10 + frame) % 256  # B, G, R
    elif kind == "sensor.camera.semantic_segmentation":
        img[..., 2] = SEM_TAG
    elif kind == "sensor.camera.depth":
        img[..., 2], img[..., 1], img[..., 0] = DEPTH_24 % 256, (DEPTH_24 // 256) % 256, DEPTH_24 // 65536
    return img.tobytes()


def dvs_bytes(frame: int) -> bytes:
    return b"".join(struct.pack("<HHq?", 3, 4, frame * 50_000_000 + k, bool(k % 2)) for k in range(3))


def lidar_bytes() -> bytes:
    pts = [(5.0, 2.0, -1.9, 0.9, 0, SEM_TAG), (-3.0, -4.0, 0.5, -0.5, 9, 10)]
    return b"".join(struct.pack("<ffffII", *p) for p in pts)


class World:
    def __init__(self, client: "Client", name: str):
        self.client, self.map = client, Map(name)
        self.frame = 100
        self.actors: ActorList = ActorList()
        self.settings = Settings()
        self.weather = None
        self.log: list[tuple[str, str, int]] = []
        self.navigation_calls = 0
        self.actors.append(TrafficLight(self, 20.0, 0.0, "Red"))

    def get_map(self) -> Map:
        return self.map

    def get_settings(self) -> Settings:
        return Settings(self.settings.synchronous_mode, self.settings.fixed_delta_seconds)

    def apply_settings(self, s: Settings) -> None:
        if self.client.gone:
            raise timeout_error(self.client)
        self.settings = s

    def set_weather(self, w: Any) -> None:
        self.weather = w

    def get_blueprint_library(self) -> BlueprintLibrary:
        return BlueprintLibrary()

    def get_actors(self) -> ActorList:
        return ActorList(self.actors)

    def get_random_location_from_navigation(self) -> Location | None:
        """A place on the sidewalks; ``None`` (as the real one may give) every ``Client.navigation_none``-th call."""
        self.navigation_calls += 1
        every = self.client.navigation_none
        return None if every and self.navigation_calls % every == 0 else Location(5.0, 8.0, 0.5)

    def try_spawn_actor(self, bp: Blueprint, tr: Transform, attach_to: Actor | None = None) -> Actor | None:
        if attach_to is None and any(a.parent is None and a.get_transform().location == tr.location
                                     and not a.type_id.startswith("walker") for a in self.actors):
            return None
        a = Actor(self, bp, tr, attach_to)
        self.actors.append(a)
        return a

    def spawn_actor(self, bp: Blueprint, tr: Transform, attach_to: Actor | None = None) -> Actor:
        if self.client.spawn_timeout == bp.id:
            raise timeout_error(self.client)
        a = self.try_spawn_actor(bp, tr, attach_to)
        assert a is not None
        return a

    def tick(self, timeout: float = 10.0) -> int:
        if self.client.tick_timeout is not None and self.frame + 1 == self.client.tick_timeout:
            raise timeout_error(self.client)
        if self.client.gone:
            raise timeout_error(self.client)
        self.frame += 1
        fails = self.client.fail
        for a in list(self.actors):
            if a.callback is None:
                continue
            if fails and fails["frame"] <= self.frame and a.type_id == fails["sensor"]:
                continue  # the sensor stopped delivering
            w = int(a.blueprint.attributes.get("image_size_x", 0))
            if a.type_id == "sensor.camera.dvs":
                if self.frame % 2 == 0:  # a DVS camera sends only when events fire
                    a.callback(SensorData(self.frame, dvs_bytes(self.frame), w, w, a.get_transform()))
            elif a.type_id.startswith("sensor.camera"):
                a.callback(SensorData(self.frame, camera_bytes(a.type_id, w, w, self.frame), w, w, a.get_transform()))
            elif a.type_id.startswith("sensor.lidar"):
                a.callback(SensorData(self.frame, lidar_bytes(), 0, 0, a.get_transform()))
        for a in self.actors:  # everything on the road drives forward 1 m per tick
            if a.parent is None and a.type_id.startswith("vehicle"):
                a._tr = Transform(Location(a._tr.location.x + 1.0, a._tr.location.y, a._tr.location.z), a._tr.rotation)
        return self.frame


class TrafficManager:
    def get_port(self) -> int:
        return 8000

    def set_synchronous_mode(self, on: bool) -> None:
        self.sync = on

    def set_random_device_seed(self, seed: int) -> None:
        self.seed = seed


class Client:
    #: class-level knobs a test sets: is there a server, its version, its maps, a sensor that stops;
    #: the simulation frame whose tick times out, the blueprint whose spawn_actor times out, how
    #: many seconds a map takes to load (a load under a shorter time-out times out), every how
    #: many calls the navigation mesh has no place (None); ``gone``: after the first time-out the
    #: server answers nothing more
    server: bool = True
    version: str = "0.9.10"
    maps: tuple[str, ...] = ("Town01", "Town02", "Town03", "Town04", "Town05")
    fail: dict | None = None
    tick_timeout: int | None = None
    spawn_timeout: str | None = None
    load_seconds: float = 0.0
    navigation_none: int = 0
    gone_after_timeout: bool = False
    instances: list["Client"] = []

    def __init__(self, host: str, port: int):
        self.host, self.port, self.timeout = host, port, None
        self.world: World | None = None
        self.loads: list[str] = []
        self.load_timeouts: list[float] = []
        self.gone = False
        type(self).instances.append(self)

    def set_timeout(self, seconds: float) -> None:
        self.timeout = seconds

    def get_server_version(self) -> str:
        if not self.server:
            raise RuntimeError(f"time-out of {int(self.timeout * 1000)}ms while waiting for the simulator")
        return self.version

    def get_client_version(self) -> str:
        return "0.9.10"

    def get_available_maps(self) -> list[str]:
        return [f"/Game/Carla/Maps/{m}" for m in self.maps]

    def get_world(self) -> World:
        if self.world is None:
            self.world = World(self, "Town10HD")
        return self.world

    def load_world(self, name: str) -> World:
        self.load_timeouts.append(self.timeout)
        if self.timeout < self.load_seconds:
            raise timeout_error(self)
        self.loads.append(name)
        self.world = World(self, name)
        return self.world

    def get_trafficmanager(self, port: int = 8000) -> TrafficManager:
        return TrafficManager()


def make_module(**knobs: Any) -> types.ModuleType:
    """A fresh ``carla`` stand-in; ``knobs`` set :class:`Client`'s class attributes."""
    client = type("Client", (Client,), {"instances": [], **knobs})
    mod = types.ModuleType("carla")
    mod.Client, mod.Transform, mod.Location, mod.Rotation = client, Transform, Location, Rotation
    mod.WeatherParameters = lambda **kw: dict(kw)
    return mod
