"""A dataset recorded from CARLA: its plan, the frame writer that resumes, and the check that
brings a complete recording into ``data/raw/<ds>`` (the ``generate`` stage of a ``carla`` source).

The collector writes ``datasets.<ds>.source.root`` (never ``data/raw/<ds>``, a DVC output)::

    <root>/plan.json              written first: what is recorded (episodes, rig, settings)
    <root>/frames/<id>.npz        one raw record per frame (compact_perception.data.record), each atomically
    <root>/episodes/ep<k>.json    written once episode k's frames are all on disk: its frames' metadata
    <root>/manifest.json          written LAST, once every episode is complete

A killed collection leaves no manifest. The next run with the same plan keeps every complete
episode and records the others; frames of an episode that was cut short are removed and the
episode is driven again from its start (a drive cannot be continued once its server session
is gone, and an episode is one scene). ``--restart`` (or a plan that changed) starts the set
again: only the entries above are removed, nothing else in ``root``.

Frame ids are ``<town>_ep<k>_<step>`` as in the simulated sets; splits come from the dataset's
``split_ratio`` and towns (by town for A and B, by episode for C), so no episode is in two splits.
"""
from __future__ import annotations

import json
import logging
import shutil
import zlib
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Mapping

import numpy as np

from ...core import io
from ...core.classes import BEV_NAMES, CARLA_NAMES
from ...core.params import CarlaSource, Params, ParamsError
from ...core.errors import RecordError
from ..geometry import VIEWS
from ..record import SPLITS, RecordSpec, load_record, validate_record
from .conditions import draw_condition
from .rig import sensor_specs

log = logging.getLogger(__name__)

RECORD_KEYS = tuple(f"{k}_{v}" for v in VIEWS for k in ("rgb", "dvs", "sem", "depth")) + (
    "lidar", "lidar_tag", "bev", "boxes", "ego_pose")


@dataclass(frozen=True)
class EpisodePlan:
    split: str
    town: str  # the project's name (town01)
    map: str  # CARLA's map (Town01)
    index: int
    frames: int
    seed: int
    time_of_day: str
    weather: str
    intensity: float

    def frame_id(self, step: int) -> str:
        return f"{self.town}_ep{self.index:04d}_{step:03d}"


def carla_map(town: str) -> str:
    """The CARLA map of a project town name: town01 -> Town01."""
    return "Town" + town[len("town"):]


def carla_settings(params: Params, dataset_id: str) -> CarlaSource:
    """``datasets.<ds>.source`` of a dataset recorded from CARLA; a set of another source is one line."""
    settings = params.dataset(dataset_id).source
    if settings.id != "carla":
        raise ParamsError(f"datasets.{dataset_id}.source.id is {settings.id!r}: recording from CARLA needs "
                          "datasets.<ds>.source: {id: carla, root: ..., host: ..., ...} (docs/carla.md)")
    return settings


def ticks_per_frame(params: Params, dataset_id: str) -> int:
    """Simulation steps between two recorded frames: ``world.dvs.step_s`` / ``fixed_delta_s`` (at least 1)."""
    cs = carla_settings(params, dataset_id)
    return max(1, int(round(params.world.dvs.step_s / cs.fixed_delta_s)))


def plan_recording(params: Params, dataset_id: str) -> list[EpisodePlan]:
    """The episodes of a recorded dataset: its frames at ``scale`` split by ``split_ratio``,
    ``carla.frames_per_episode`` per episode, towns as the simulated sets use them."""
    dp = params.dataset(dataset_id)
    cs = carla_settings(params, dataset_id)
    n = params.split_counts_of(dataset_id)
    towns = dp.towns_by_split()
    plan, index = [], 0
    for split in SPLITS:
        left, k = n[split], 0
        while left > 0:
            m = min(cs.frames_per_episode, left)
            tl = towns[split]
            town = tl[(k + (1 if split == "test" else 0)) % len(tl)]
            seq = np.random.SeedSequence([params.seed, dp.seed_offset, zlib.crc32(dataset_id.encode()), index, 0xCA])
            seed = int(seq.generate_state(1, np.uint32)[0])
            time, weather, intensity = draw_condition(cs.times, cs.weathers, seed)
            plan.append(EpisodePlan(split, town, carla_map(town), index, m, seed, time, weather, intensity))
            index, left, k = index + 1, left - m, k + 1
    return plan


def plan_document(params: Params, dataset_id: str) -> dict[str, Any]:
    """What a recording is made of; two recordings with equal documents are interchangeable."""
    cs = carla_settings(params, dataset_id)
    size = params.resolution
    return {
        "dataset": dataset_id, "resolution": size, "views": list(VIEWS),
        "episodes": [asdict(e) for e in plan_recording(params, dataset_id)],
        "rig": [asdict(s) for s in sensor_specs(params.world, size, cs.fixed_delta_s)],
        "lidar_range_m": params.world.lidar.range_m,
        "ticks_per_frame": ticks_per_frame(params, dataset_id),
        # what shapes the data (a recording made before the source had an id compares equal)
        "settings": cs.model_dump(mode="json",
                                  exclude={"id", "root", "host", "port", "timeout_s", "load_world_timeout_s"}),
    }


def _plain(obj: Any) -> Any:
    return json.loads(json.dumps(obj))


def first_difference(a: Any, b: Any, path: str = "") -> str | None:
    """The dotted path of the first place two JSON values differ (None if equal)."""
    if isinstance(a, dict) and isinstance(b, dict):
        for k in sorted(set(a) | set(b)):
            if k not in a or k not in b:
                return f"{path}.{k}".lstrip(".")
            d = first_difference(a[k], b[k], f"{path}.{k}")
            if d:
                return d
        return None
    if isinstance(a, list) and isinstance(b, list):
        if len(a) != len(b):
            return f"{path} (length {len(a)} vs {len(b)})".lstrip(".")
        for i, (x, y) in enumerate(zip(a, b)):
            d = first_difference(x, y, f"{path}[{i}]")
            if d:
                return d
        return None
    return None if a == b else (path.lstrip(".") or "<value>")


def _read_json(path: Path) -> Any:
    try:
        return json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise RecordError(f"{path}: unreadable ({type(err).__name__}: {err})") from None


class Recording:
    """The collector's folder: resume, frame writer, manifest (see the module docstring)."""

    def __init__(self, root: str | Path, dataset_id: str, plan: Mapping[str, Any]):
        self.root = Path(root)
        self.dataset_id = dataset_id
        self.plan = _plain(plan)
        self.spec = RecordSpec(views=VIEWS, size=int(plan["resolution"]), has_dvs=True, n_bev=len(BEV_NAMES))

    @property
    def manifest_path(self) -> Path:
        return self.root / "manifest.json"

    def _episode_path(self, index: int) -> Path:
        return self.root / "episodes" / f"ep{index:04d}.json"

    def clear(self) -> None:
        """Remove the recording's own entries (nothing else in ``root``); the manifest first."""
        for name in ("manifest.json", "plan.json"):
            (self.root / name).unlink(missing_ok=True)
        for name in ("episodes", "frames"):
            shutil.rmtree(self.root / name, ignore_errors=True)

    def open(self, restart: bool = False) -> list[dict[str, Any]]:
        """Prepare ``root`` and return the planned episodes still to record ([] if complete)."""
        plan_file = self.root / "plan.json"
        if plan_file.exists() and not restart:
            where = first_difference(_read_json(plan_file), self.plan)
            if where:
                raise RecordError(f"{self.root}: recorded with other settings ({where} differs from params.yaml); "
                                  f"rerun with --restart to record it again")
        if restart:
            self.clear()
        if self.manifest_path.exists():
            return []
        self.root.mkdir(parents=True, exist_ok=True)
        if not plan_file.exists():
            io.write_json(plan_file, self.plan)
        todo = [e for e in self.plan["episodes"] if not self._episode_path(e["index"]).exists()]
        done_ids = {fid for e in self.plan["episodes"] if e not in todo
                    for fid in _read_json(self._episode_path(e["index"]))["frames"]}
        frames = self.root / "frames"
        if frames.is_dir():  # frames of an episode cut short: it is recorded again from its start
            for f in frames.iterdir():
                if f.name.endswith(".npz") and f.name[:-4] in done_ids:
                    continue
                f.unlink()
        io.remove_leftovers(self.root)
        io.remove_leftovers(self.root / "episodes")
        return todo

    def write_frame(self, frame_id: str, arrays: Mapping[str, np.ndarray]) -> None:
        """Check one frame against the raw layout, then write it atomically."""
        missing = [k for k in RECORD_KEYS if k not in arrays]
        if missing:
            raise RecordError(f"frame {frame_id}: missing key(s) {', '.join(missing)}")
        validate_record(arrays, self.spec, f"frame {frame_id}")
        io.write_npz(self.root / "frames" / f"{frame_id}.npz", {k: arrays[k] for k in RECORD_KEYS})

    def finish_episode(self, episode: Mapping[str, Any], metas: Mapping[str, Mapping[str, Any]]) -> None:
        """Mark an episode complete once its frames are written (``metas``: frame id -> metadata)."""
        for fid in metas:
            if not (self.root / "frames" / f"{fid}.npz").is_file():
                raise RecordError(f"frame {fid}: not written; episode {episode['index']} is incomplete")
        io.write_json(self._episode_path(int(episode["index"])),
                      {"episode": _plain(dict(episode)), "frames": _plain(dict(metas))})

    def finalize(self, extra: Mapping[str, Any]) -> Path:
        """Write ``manifest.json`` (last) from the completed episodes; an episode missing is an error."""
        splits: dict[str, list[str]] = {s: [] for s in SPLITS}
        frames: dict[str, Any] = {}
        for e in self.plan["episodes"]:
            path = self._episode_path(e["index"])
            if not path.exists():
                raise RecordError(f"{self.root}: episode {e['index']} is not recorded; no manifest written")
            metas = _read_json(path)["frames"]
            splits[e["split"]] += list(metas)
            frames.update(metas)
        manifest = {
            "dataset": self.dataset_id, "source": "carla", "resolution": self.plan["resolution"],
            "views": list(VIEWS), "splits": splits, "frames": frames, "seg_classes": list(CARLA_NAMES),
            "bev_classes": list(BEV_NAMES), "params": {"plan": self.plan}, "carla": _plain(dict(extra)),
        }
        io.write_json(self.manifest_path, manifest)
        return self.manifest_path


# ----------------------------------------------------------------------------- generate@<ds>
def check_recording(params: Params, dataset_id: str, root: str | Path) -> dict[str, Any]:
    """The manifest of a complete recording made with the current params; every frame is read
    and checked against the raw layout. Any problem is a one-line :class:`RecordError`."""
    root = Path(root)
    hint = f"record it with: python -m pipeline.collect_carla --dataset {dataset_id} (docs/carla.md)"
    if not root.is_dir():
        raise RecordError(f"datasets.{dataset_id}.source.root: {str(root)!r} is not a directory; {hint}")
    path = root / "manifest.json"
    if not path.is_file():
        raise RecordError(f"{root}: recording incomplete (no manifest.json); {hint}")
    manifest = _read_json(path)
    if not isinstance(manifest, dict) or manifest.get("source") != "carla" or manifest.get("dataset") != dataset_id:
        raise RecordError(f"{path}: not a CARLA recording of dataset {dataset_id}")
    where = first_difference(manifest.get("params", {}).get("plan"), _plain(plan_document(params, dataset_id)))
    if where:
        raise RecordError(f"{path}: recorded with other settings ({where} differs from params.yaml); "
                          f"record it again (collect_carla --restart) or restore the settings")
    spec = RecordSpec(views=VIEWS, size=int(manifest["resolution"]), has_dvs=True, n_bev=len(BEV_NAMES))
    for split in SPLITS:
        ids = manifest.get("splits", {}).get(split) or []
        if not ids:
            raise RecordError(f"{path}: split {split!r} is empty")
        for fid in ids:
            frame = root / "frames" / f"{fid}.npz"
            validate_record(load_record(frame, fid), spec, f"frame {fid}: {frame}")
    return manifest


def import_recording(params: Params, dataset_id: str, root: str | Path, out_dir: str | Path) -> dict[str, Any]:
    """Check the recording at ``root`` and copy it into ``out_dir`` (= data/raw/<ds>) atomically."""
    manifest = check_recording(params, dataset_id, root)
    root = Path(root)
    with io.atomic_dir(out_dir) as tmp:
        (tmp / "frames").mkdir()
        for split in SPLITS:
            for fid in manifest["splits"][split]:
                shutil.copyfile(root / "frames" / f"{fid}.npz", tmp / "frames" / f"{fid}.npz")
        io.write_json(tmp / "manifest.json", dict(manifest, carla_root=str(root.resolve())))
    return manifest
