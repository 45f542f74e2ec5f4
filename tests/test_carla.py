"""Recording from CARLA (compact_perception.data.carla, pipeline.collect_carla) without a server.

The conversions are checked against buffers built from CARLA's documented formats (BGRA
images, the 24-bit depth encoding, tags in red, packed DVS events, semantic LiDAR points in
CARLA's left-handed frame); the session runs against tests/carla_fake.py. The real client is
never needed (nor imported) here.
"""
from __future__ import annotations

import json
import re
import struct
import sys
from pathlib import Path

import numpy as np
import pytest
import yaml

import carla_fake
from compact_perception.data.carla import bev, convert
from compact_perception.data.carla.collector import CarlaError, SensorQueues, collect, connect, import_client
from compact_perception.data.carla.recording import Recording, check_recording, import_recording, plan_document
from compact_perception.data.carla.rig import sensor_specs
from compact_perception.core.classes import BEV_NAMES, CARLA_PALETTE, TAG
from compact_perception.core.params import ParamsError, load_params
from compact_perception.core.errors import RecordError
from compact_perception.data.geometry import topview_center, topview_index
from repo_params import carla_source
from compact_perception.data.preprocess import preprocess_sim

ROOT = Path(__file__).resolve().parents[1]


# ----------------------------------------------------------------------------- conversions
def _bgra(pixels: list[tuple[int, int, int, int]], w: int, h: int) -> bytes:
    return bytes(b for px in pixels for b in px)


def test_rgb_from_bgra_reorders_each_pixel():
    raw = _bgra([(1, 2, 3, 255), (10, 20, 30, 255), (0, 0, 255, 0), (255, 0, 0, 7)], 2, 2)
    rgb = convert.rgb_from_bgra(raw, 2, 2)
    assert rgb.dtype == np.uint8 and rgb.shape == (2, 2, 3)
    assert rgb.tolist() == [[[3, 2, 1], [30, 20, 10]], [[255, 0, 0], [0, 0, 255]]]
    with pytest.raises(convert.FormatError, match="2 x 2 x 4"):
        convert.rgb_from_bgra(raw[:-1], 2, 2)


def _depth_pixel(metres: float) -> tuple[int, int, int, int]:
    v = int(round(metres / 1000.0 * (256 ** 3 - 1)))
    return (v // 65536, (v // 256) % 256, v % 256, 255)  # B, G, R, A


def test_depth_decodes_the_24_bit_encoding_and_stores_carla_log_depth():
    metres = [10.0, 1000.0, 0.0, 3.0]
    raw = _bgra([_depth_pixel(m) for m in metres], 2, 2)
    d = convert.depth_metres_from_bgra(raw, 2, 2).ravel()
    np.testing.assert_allclose(d, metres, atol=1000.0 / 2 ** 24)
    log = convert.log_depth_u16_from_bgra(raw, 2, 2).ravel()
    # docs/ARCHITECTURE.md: clip(1 + ln(d / 1000) / 5.70378, 0, 1) x 65535; 0 below ~3.33 m
    assert abs(int(log[0]) - round((1 + np.log(0.01) / 5.70378) * 65535)) <= 1
    assert log[1] == 65535 and log[2] == 0 and log[3] == 0
    assert log.dtype == np.uint16


def test_semantic_tag_in_red_maps_to_the_palette_for_both_tag_numberings():
    old = convert.tag_table("0.9.10")
    raw = _bgra([(0, 0, 7, 255), (99, 99, 10, 255), (0, 0, 4, 0), (0, 0, 22, 255)], 2, 2)
    sem = convert.semantic_from_bgra(raw, 2, 2, old).reshape(-1, 3)
    assert [tuple(c) for c in sem] == [tuple(CARLA_PALETTE[TAG[n]]) for n in ("road", "vehicle", "pedestrian", "terrain")]
    new = convert.tag_table("0.9.16")  # Cityscapes numbering: 1 road, 13 rider, 14 car, 24 road line
    raw = _bgra([(0, 0, 1, 255), (0, 0, 13, 255), (0, 0, 14, 255), (0, 0, 24, 255)], 2, 2)
    sem = convert.semantic_from_bgra(raw, 2, 2, new).reshape(-1, 3)
    assert [tuple(c) for c in sem] == [tuple(CARLA_PALETTE[TAG[n]]) for n in ("road", "pedestrian", "vehicle", "road line")]


def test_dvs_events_from_the_packed_13_byte_array():
    raw = struct.pack("<HHq?", 3, 1, 5_000_000, True) + struct.pack("<HHq?", 0, 2, 7_000_999, False)
    assert convert.DVS_EVENT_DTYPE.itemsize == 13
    ev = convert.dvs_events_from_raw(raw, 4, 4)
    assert ev.dtype == np.int64 and ev.tolist() == [[5000, 3, 1, 1], [7000, 0, 2, -1]]  # t in microseconds
    assert convert.dvs_events_from_raw(b"", 4, 4).shape == (0, 4)
    with pytest.raises(convert.FormatError, match="13-byte"):
        convert.dvs_events_from_raw(raw[:-1], 4, 4)
    with pytest.raises(convert.FormatError, match="outside"):
        convert.dvs_events_from_raw(struct.pack("<HHq?", 4, 0, 0, True), 4, 4)


def test_semantic_lidar_points_to_the_ego_frame():
    # CARLA: x forward, y RIGHT, z up; the project: y LEFT
    raw = struct.pack("<ffffII", 5.0, 2.0, -1.5, -0.25, 17, 10) + struct.pack("<ffffII", 1.0, -3.0, 0.5, 0.75, 3, 4)
    assert convert.SEMANTIC_LIDAR_DTYPE.itemsize == 24
    pts, tags = convert.lidar_from_raw(raw, convert.tag_table("0.9.10"))
    np.testing.assert_array_equal(pts, np.array([[5, -2, -1.5, 0.25], [1, 3, 0.5, 0.75]], np.float32))
    assert tags.tolist() == [TAG["vehicle"], TAG["pedestrian"]] and tags.dtype == np.uint8
    _, tags = convert.lidar_from_raw(raw, convert.tag_table("0.9.16"))  # 10 terrain, 4 wall
    assert tags.tolist() == [TAG["terrain"], TAG["wall"]]
    with pytest.raises(convert.FormatError, match="24-byte"):
        convert.lidar_from_raw(raw[:-4], convert.tag_table("0.9.10"))


def test_right_handed_pose_and_versions():
    np.testing.assert_allclose(convert.right_handed_pose(1.0, 2.0, 90.0), [1.0, -2.0, -np.pi / 2])
    assert convert.parse_version("0.9.14-dirty") == (0, 9, 14)
    with pytest.raises(convert.FormatError):
        convert.parse_version("latest")


# ----------------------------------------------------------------------------- rig
def test_rig_uses_the_world_settings_and_carla_axes():
    p = load_params(ROOT / "params.yaml")
    specs = {s.key: s for s in sensor_specs(p.world, 128, 0.05)}
    assert len(specs) == 17
    left = specs["rgb_l"]
    assert left.location == pytest.approx((0.0, -p.world.camera.mount_offset_m, p.world.camera.height_m))  # left = -y
    assert left.rotation == (p.world.camera.pitch_deg, -90.0, 0.0)
    assert dict(specs["dvs_f"].attributes)["positive_threshold"] == "0.3"
    assert dict(specs["sem_r"].attributes) == {"image_size_x": "128", "image_size_y": "128", "fov": "90"}
    lid = dict(specs["lidar"].attributes)
    assert lid == {"channels": "64", "range": "32", "upper_fov": "20", "lower_fov": "-30",
                   "rotation_frequency": "20", "points_per_second": str(64 * 1024 * 20)}
    assert specs["lidar"].location == (0.0, 0.0, 2.0)


# ----------------------------------------------------------------------------- BEV
class _Car:
    def __init__(self, ident: int, x: float, y: float, yaw: float = 0.0):
        self.id = ident
        self._tr = carla_fake.Transform(carla_fake.Location(x, y, 0.0), carla_fake.Rotation(yaw=yaw))
        self.bounding_box = carla_fake.BoundingBox(carla_fake.Vector3D(0, 0, 0.8), carla_fake.Vector3D(2.0, 1.0, 0.8))

    def get_transform(self):
        return self._tr


def test_bev_from_actors_and_waypoints_in_the_ego_grid():
    S, R = 128, 32.0
    ego = _Car(1, 0.0, 0.0)
    right_car = _Car(2, 0.0, 10.0)  # CARLA y = +10: 10 m to the RIGHT -> ego y = -10
    ahead_walker = _Car(3, 10.0, 0.0)
    waypoints = [carla_fake.Waypoint(float(x), 0.0, left=carla_fake.LaneMarking("Solid", "Yellow"),
                                     right=carla_fake.LaneMarking("Broken", "White")) for x in range(-40, 41)]
    layers = bev.map_layers(waypoints, 1.0).merged(bev.actor_layers([ego, right_car], [ahead_walker], [], ego))
    m = bev.rasterise(layers, convert.right_handed_pose(0, 0, 0), R, S)
    c = topview_center(S)
    idx = lambda v: int(topview_index(v, R, S))  # noqa: E731
    B = {n: i for i, n in enumerate(BEV_NAMES)}
    assert m.shape == (9, S, S) and m.dtype == np.uint8
    assert m[B["other vehicles"], c, idx(-10.0)] == 1 and m[B["other vehicles"], c, idx(10.0)] == 0
    assert m[B["ego vehicle"], c, c] == 1 and m[B["other vehicles"], c, c] == 0
    assert m[B["pedestrian"], idx(10.0), c] == 1
    assert m[B["road"], c, c] == 1 and m[B["road"], c, idx(10.0)] == 0
    # lane going +x with a yellow marking on its left (CARLA y = -2 -> ego y = +2): the centreline
    assert m[B["road centreline"], c, idx(2.0)] == 1 and m[B["road centreline"], c, idx(-2.0)] == 0
    assert m[B["road lane"], c, idx(-2.0)] == 1
    # the same scene seen by an ego facing CARLA yaw +90 (towards +y): the right car is ahead
    m2 = bev.rasterise(layers, convert.right_handed_pose(0, 0, 90.0), R, S)
    assert m2[B["other vehicles"], idx(10.0), c] == 1


def test_traffic_light_states_mark_their_stop_waypoints():
    lights = [carla_fake.TrafficLight.__new__(carla_fake.TrafficLight) for _ in range(2)]
    for tl, (x, state) in zip(lights, ((8.0, "Red"), (-8.0, "Off"))):
        tl.state, tl.stops = state, [carla_fake.Waypoint(x, 0.0)]
    m = bev.rasterise(bev.actor_layers([], [], lights, _Car(1, 0, 0)), np.zeros(3), 32.0, 64)
    B = {n: i for i, n in enumerate(BEV_NAMES)}
    c = topview_center(64)
    assert m[B["red traffic light"], int(topview_index(8.0, 32.0, 64)), c] == 1
    assert m[B["green traffic light"]].sum() == 0 and m[B["red traffic light"], :c].sum() == 0


# ----------------------------------------------------------------------------- session
@pytest.fixture()
def small_params(tmp_path, params_dict):
    """params.yaml with a 5-frame set A recorded in episodes of 2 (3/1/1 split), a tiny traffic."""
    a = params_dict["datasets"]["A"]
    a["frames"]["default"] = 5
    a["split_ratio"]["default"] = {"train": 3, "val": 1, "test": 1}
    a["source"] = carla_source(root=str(tmp_path / "rec"), frames_per_episode=2, warmup_ticks=1, vehicles=2,
                               pedestrians=1, timeout_s=0.2)
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(params_dict))
    return path


def test_no_server_is_one_line_and_writes_nothing(small_params, monkeypatch, capsys):
    from pipeline import collect_carla

    monkeypatch.setitem(sys.modules, "carla", carla_fake.make_module(server=False))
    with pytest.raises(SystemExit) as err:
        collect_carla.main(["--dataset", "A", "--params", str(small_params), "--port", "2999"])
    assert err.value.code == "error: carla: no server at 127.0.0.1:2999 (connection timed out after 0.2 s)"
    assert not (small_params.parent / "rec").exists()


def test_missing_client_and_version_mismatch_and_missing_town(small_params, monkeypatch):
    monkeypatch.setitem(sys.modules, "carla", None)  # import fails as if not installed
    with pytest.raises(CarlaError, match=r"pip install -e '\.\[carla\]'"):
        import_client()
    p = load_params(small_params)
    mod = carla_fake.make_module(version="0.9.16")
    with pytest.raises(CarlaError, match=r"client 0\.9\.10 does not match server 0\.9\.16.*carla==0\.9\.16"):
        connect(mod, "127.0.0.1", 2000, 1.0)
    mod = carla_fake.make_module(maps=("Town01",))
    with pytest.raises(CarlaError, match=r"has no map Town02 \(it has Town01\)"):
        collect(mod, p, "A", p.datasets.A.source.root, "127.0.0.1", 2000)
    assert not Path(p.datasets.A.source.root).exists()


def test_collect_writes_a_raw_set_that_preprocess_reads(small_params, tmp_path):
    p = load_params(small_params)
    mod = carla_fake.make_module()
    root = Path(p.datasets.A.source.root)
    assert collect(mod, p, "A", str(root), "127.0.0.1", 2000) == 5
    man = json.loads((root / "manifest.json").read_text())
    assert {s: len(v) for s, v in man["splits"].items()} == {"train": 3, "val": 1, "test": 1}
    assert man["source"] == "carla" and man["carla"]["server_version"] == "0.9.10"
    assert mod.Client.instances[0].loads == ["Town01", "Town02"]  # grouped by town, each loaded once
    world = mod.Client.instances[0].world
    assert not world.settings.synchronous_mode  # restored
    assert [a.type_id for a in world.actors] == ["traffic.traffic_light"]  # everything spawned destroyed
    with np.load(root / "frames" / f"{man['splits']['train'][0]}.npz") as z:
        assert z["rgb_f"].shape == (32, 32, 3) and (z["sem_f"] == CARLA_PALETTE[TAG["road"]]).all()
        assert z["lidar"][0].tolist() == pytest.approx([5.0, -2.0, -1.9, 0.9])
        assert len(z["dvs_f"]) == 3 and z["bev"][BEV_NAMES.index("ego vehicle")].any()
    raw = tmp_path / "raw" / "A"
    import_recording(p, "A", root, raw)
    cache = preprocess_sim(raw, tmp_path / "cache" / "A", "A", p.preprocess)
    meta = json.loads((cache / "meta.json").read_text())
    assert meta["source"] == "carla"
    assert json.loads((cache / "test" / "frame_ids.json").read_text()) == man["splits"]["test"]
    # the collector has nothing more to do; a rerun says so
    assert collect(mod, p, "A", str(root), "127.0.0.1", 2000) == 0


def test_a_silent_sensor_fails_and_the_rerun_resumes(small_params):
    p = load_params(small_params)
    root = Path(p.datasets.A.source.root)
    mod = carla_fake.make_module(fail={"frame": 108, "sensor": "sensor.camera.rgb"})
    with pytest.raises(CarlaError, match=r"carla: sensor rgb_f delivered nothing for simulation frame \d+ within 0\.2 s"):
        collect(mod, p, "A", str(root), "127.0.0.1", 2000)
    assert not (root / "manifest.json").exists()
    done = sorted(f.name for f in (root / "episodes").iterdir())
    assert done and len(done) < 4
    ok = carla_fake.make_module()
    n = collect(ok, p, "A", str(root), "127.0.0.1", 2000)
    assert n == 5 - sum(len(json.loads((root / "episodes" / d).read_text())["frames"]) for d in done)
    assert (root / "manifest.json").exists() and len(list((root / "frames").glob("*.npz"))) == 5


def test_resume_removes_frames_of_an_unfinished_episode_and_a_changed_plan_needs_restart(small_params):
    p = load_params(small_params)
    root = Path(p.datasets.A.source.root)
    rec = Recording(root, "A", plan_document(p, "A"))
    assert len(rec.open()) == 4
    (root / "frames").mkdir()
    (root / "frames" / "town01_ep0000_000.npz").write_bytes(b"partial")
    (root / "frames" / ".town01_ep0000_001.npz.x.tmp").write_bytes(b"")
    assert len(rec.open()) == 4 and not list((root / "frames").iterdir())
    other = dict(plan_document(p, "A"), resolution=64)
    with pytest.raises(RecordError, match="resolution differs from params.yaml.*--restart"):
        Recording(root, "A", other).open()
    assert len(Recording(root, "A", other).open(restart=True)) == 4
    with pytest.raises(RecordError, match="episode 0 is not recorded; no manifest"):
        rec.finalize({})


def test_generate_checks_the_recording(small_params, tmp_path):
    p = load_params(small_params)
    root = Path(p.datasets.A.source.root)
    with pytest.raises(RecordError, match="not a directory.*collect_carla --dataset A"):
        check_recording(p, "A", root)
    root.mkdir()
    with pytest.raises(RecordError, match=r"incomplete \(no manifest.json\)"):
        check_recording(p, "A", root)
    collect(carla_fake.make_module(), p, "A", str(root), "127.0.0.1", 2000)
    q = load_params(small_params).model_copy(deep=True)
    d = yaml.safe_load(small_params.read_text())
    d["datasets"]["A"]["source"]["vehicles"] = 3
    other = tmp_path / "other.yaml"
    other.write_text(yaml.safe_dump(d))
    with pytest.raises(RecordError, match="settings.vehicles differs"):
        check_recording(load_params(other), "A", root)
    fid = json.loads((root / "manifest.json").read_text())["splits"]["val"][0]
    (root / "frames" / f"{fid}.npz").write_bytes(b"truncated")
    with pytest.raises(RecordError, match=f"frame {fid}"):
        import_recording(q, "A", root, tmp_path / "raw" / "A")
    assert not (tmp_path / "raw" / "A").exists()


def test_sensor_queues_collect_dvs_events_without_waiting():
    q = SensorQueues(0.1)

    class _S:
        def listen(self, cb):
            self.cb = cb

    s = _S()
    q.listen("dvs_f", s)
    s.cb(carla_fake.SensorData(5, carla_fake.dvs_bytes(5), 8, 8, None))
    s.cb(carla_fake.SensorData(7, carla_fake.dvs_bytes(7), 8, 8, None))
    q._drain_events("dvs_f", 7)
    ev = q.take_events("dvs_f")
    assert len(ev) == 6 and (np.diff(ev[:, 0]) >= 0).all()
    assert q.take_events("dvs_f").shape == (0, 4)


def test_params_carla_source(params_dict, tmp_path):
    """docs/carla.md's source section loads as written; a recording folder inside data/raw, or a key
    of another source, is one line naming the key; a sim set is not recorded."""
    params_dict["datasets"]["B"]["source"] = carla_source(root="data/raw/B")
    path = tmp_path / "p.yaml"
    path.write_text(yaml.safe_dump(params_dict))
    with pytest.raises(ParamsError, match=r"datasets\.B\.source\.root: Value error, 'data/raw/B' is inside data/raw"):
        load_params(path)
    params_dict["datasets"]["B"]["source"] = carla_source(root="recordings/B", splits={"train": "Tr1"})
    path.write_text(yaml.safe_dump(params_dict))
    with pytest.raises(ParamsError, match=r"datasets\.B\.source\.splits: unknown key"):
        load_params(path)
    params_dict["datasets"]["B"]["source"] = carla_source(root="recordings/B")
    path.write_text(yaml.safe_dump(params_dict))
    p = load_params(path)
    assert p.datasets.B.source.id == "carla" and p.datasets.B.source.root == "recordings/B"
    assert set(plan_document(p, "B")["settings"]) == {"fixed_delta_s", "frames_per_episode", "warmup_ticks",
                                                      "vehicles", "pedestrians", "times", "weathers"}
    from compact_perception.data.carla.recording import carla_settings
    with pytest.raises(ParamsError, match=r"^datasets\.A\.source\.id is 'sim': recording from CARLA needs "):
        carla_settings(p, "A")


def test_generate_stage_with_source_carla(small_params, tmp_path):
    from pipeline import generate

    p = load_params(small_params)
    collect(carla_fake.make_module(), p, "A", p.datasets.A.source.root, "127.0.0.1", 2000)
    out, figures = tmp_path / "raw", tmp_path / "figures"
    assert generate.main(["--dataset", "A", "--params", str(small_params), "--out", str(out),
                          "--figure-dir", str(figures)]) == 0
    assert json.loads((out / "A" / "manifest.json").read_text())["source"] == "carla"
    assert len(list((out / "A" / "frames").glob("*.npz"))) == 5 and (figures / "world_A.png").is_file()
    (Path(p.datasets.A.source.root) / "manifest.json").unlink()
    with pytest.raises(SystemExit, match=r"^error: .*incomplete \(no manifest.json\)"):
        generate.main(["--dataset", "A", "--params", str(small_params), "--out", str(out), "--figure-dir", str(figures)])


# ----------------------------------------------------------------------------- a server that times out
def _run_collector(params: Path, mod) -> str | None:
    """pipeline.collect_carla against the stand-in ``mod``: its exit message (None on success)."""
    from pipeline import collect_carla

    sys.modules["carla"] = mod
    try:
        collect_carla.main(["--dataset", "A", "--params", str(params)])
    except SystemExit as exc:
        assert isinstance(exc.code, str) and "\n" not in exc.code and "Traceback" not in exc.code, exc.code
        return exc.code
    finally:
        del sys.modules["carla"]
    return None


def _stopped_before_destroyed(world) -> None:
    """Every walker's AI controller was stopped before it was destroyed, and every actor spawned is gone."""
    for kind, type_id, ident in world.log:
        if kind == "destroy" and type_id == "controller.ai.walker":
            assert ("stop", type_id, ident) in world.log[:world.log.index((kind, type_id, ident))], world.log
    assert any(t == "controller.ai.walker" for _, t, _ in world.log)
    assert [a.type_id for a in world.actors] == ["traffic.traffic_light"]


@pytest.mark.parametrize("knobs, step", [
    ({"tick_timeout": 110}, r"episode 1 \(Town01\): tick \(frame town01_ep0001_000\)"),
    ({"tick_timeout": 102}, r"episode 0 \(Town01\): tick \(warm-up\)"),
    ({"spawn_timeout": "sensor.lidar.ray_cast_semantic"}, r"episode 0 \(Town01\): spawn_actor \(sensor lidar\)"),
])
def test_a_client_time_out_is_one_line_naming_step_host_and_port_and_the_rerun_resumes(small_params, knobs, step):
    """The client's RuntimeError ("time-out of 10000ms while waiting for the simulator ...") from
    tick or spawn_actor was a traceback. Now: one line naming the step, host and port, exit
    status 1; the cut episode's walkers stopped before destroyed, everything spawned destroyed and
    synchronous mode off; on disk what the documented resume expects (the plan, the complete
    episodes, no manifest), and the same command completes the set."""
    p = load_params(small_params)
    root = Path(p.datasets.A.source.root)
    mod = carla_fake.make_module(**knobs)
    msg = _run_collector(small_params, mod)
    assert re.fullmatch(rf"error: carla: {step} at 127\.0\.0\.1:2000: time-out of 200ms while waiting for the "
                        r"simulator, make sure the simulator is ready and connected to 127\.0\.0\.1:2000; complete "
                        r"episodes are kept: rerun the same command to resume", msg), msg
    world = mod.Client.instances[0].world
    _stopped_before_destroyed(world)
    assert not world.settings.synchronous_mode
    assert (root / "plan.json").is_file() and not (root / "manifest.json").exists()
    done = sorted(f.name for f in (root / "episodes").glob("*.json")) if (root / "episodes").exists() else []
    kept = {fid for d in done for fid in json.loads((root / "episodes" / d).read_text())["frames"]}
    assert len(done) == (1 if "frame town01_ep0001" in step else 0)
    assert Recording(root, "A", plan_document(p, "A")).open() and {
        f.stem for f in (root / "frames").glob("*.npz")} == kept      # the cut episode's frames are dropped
    ok = carla_fake.make_module()
    assert _run_collector(small_params, ok) is None
    assert json.loads((root / "manifest.json").read_text())["splits"]["train"]
    assert len(list((root / "frames").glob("*.npz"))) == 5
    _stopped_before_destroyed(ok.Client.instances[0].world)


def test_load_world_runs_under_its_own_longer_time_out(small_params, tmp_path):
    """``load_world`` ran under the client's 10 s time-out; a map load often takes longer. It now
    runs under ``carla.load_world_timeout_s`` (the tick's time-out restored after), and one that
    times out anyway names the step, the server and the param."""
    slow = carla_fake.make_module(load_seconds=1.0)                   # a town that takes 1 s to load
    assert _run_collector(small_params, slow) is None
    assert slow.Client.instances[0].load_timeouts == [120.0, 120.0]  # Town01, then Town02
    assert slow.Client.instances[0].timeout == 0.2                    # the tick's own time-out again
    d = yaml.safe_load(small_params.read_text())
    d["datasets"]["A"]["source"].update(root=str(tmp_path / "rec2"), load_world_timeout_s=0.5)
    small_params.write_text(yaml.safe_dump(d))
    msg = _run_collector(small_params, carla_fake.make_module(load_seconds=1.0))
    assert msg == ("error: carla: load_world Town01 (time-out 0.5 s) at 127.0.0.1:2000: time-out of 500ms while "
                   "waiting for the simulator, make sure the simulator is ready and connected to 127.0.0.1:2000; a "
                   "map that loads slower needs a longer datasets.A.source.load_world_timeout_s")
    assert not (tmp_path / "rec2" / "manifest.json").exists()


def test_a_server_gone_is_not_asked_to_clean_up_call_after_call(small_params, caplog):
    """A server that stopped answering: each clean-up call would wait its full time-out. The first
    one that fails ends the clean-up with one warning; the error is still the step's one line."""
    mod = carla_fake.make_module(tick_timeout=102, gone_after_timeout=True)
    msg = _run_collector(small_params, mod)
    assert msg.startswith("error: carla: episode 0 (Town01): tick (warm-up) at 127.0.0.1:2000: time-out of 200ms")
    assert mod.Client.instances[0].world.log == []                    # nothing more was asked of it
    warnings = [r.getMessage() for r in caplog.records if r.levelname == "WARNING"]
    assert len(warnings) == 1 and "did not answer while cleaning up" in warnings[0], warnings


def test_a_walker_the_navigation_mesh_gives_no_place_to_go_stands(small_params):
    """``get_random_location_from_navigation()`` may return None: the walker's controller was
    sent to None (the real client's ArgumentError); now it stands where it was spawned."""
    p = load_params(small_params)
    mod = carla_fake.make_module(navigation_none=2)                   # every second call: no place
    assert collect(mod, p, "A", p.datasets.A.source.root, "127.0.0.1", 2000) == 5
    _stopped_before_destroyed(mod.Client.instances[0].world)
