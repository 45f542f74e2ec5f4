"""docs/extending.md's additions, made as it says in a copy of the repository and run there: the
files it names are the only ones touched, and the addition works through the stage's own entry
point. (The test reads the checklist's file names from the page, so the page and the code cannot
drift apart.)"""
from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import yaml

from synthetic import make_cache

ROOT = Path(__file__).resolve().parents[1]
EXTENDING = ROOT / "docs" / "extending.md"

#: the toy network: LiDAR segmentation (LS) from one 1x1 convolution of the top view
TOY_NETWORK = '''"""A toy network: LS from one 1x1 convolution of the LiDAR top view."""
from __future__ import annotations

from torch import Tensor, nn

from .base import DatasetSpec


class Toy(nn.Module):
    tasks = ("ls",)
    argmax_tasks = ("ls",)

    def __init__(self, n_seg: int, in_ch: int) -> None:
        super().__init__()
        self.head = nn.Conv2d(in_ch, n_seg, 1)

    def forward(self, batch: dict[str, Tensor]) -> dict[str, Tensor]:
        return {"ls": self.head(batch["lidar"]).softmax(1)}

    def compute_losses(self, outputs: dict[str, Tensor], batch: dict[str, Tensor]) -> dict[str, Tensor]:
        return {"ls": -(batch["ls"] * outputs["ls"].clamp_min(1e-6).log()).sum(1).mean()}

    def shared_layers(self) -> dict[str, list[str]]:
        return {"ls": ["head"]}


def build(ds: DatasetSpec, info) -> Toy:
    return Toy(ds.n_seg, info.lidar_channels)
'''

TOY_ENTRY = ('MODELS.register("toy")(ModelInfo("Toy", "baseline", 15, ("ls",), "toy", table_order=20, '
             'epoch_cost=0.1))\n')


#: the toy source: random but valid raw records (the layout of docs/data-formats.md), seeded by
#: its one setting
TOY_SOURCE = '''"""A toy data source: random raw records, seeded by datasets.<ds>.source.seed."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ...core import io
from ...core.classes import BEV_NAMES, CARLA_NAMES, CARLA_PALETTE
from ...core.params import Params
from ..geometry import VIEWS
from ..record import SPLITS, load_manifest, load_record

cache = None  # the preprocess stage reads the raw records


def _record(rng: np.random.Generator, size: int) -> dict:
    rec = {}
    for v in VIEWS:
        rec[f"rgb_{v}"] = rng.integers(0, 256, (size, size, 3), dtype=np.uint8)
        rec[f"sem_{v}"] = CARLA_PALETTE[rng.integers(0, len(CARLA_PALETTE), (size, size))]
        rec[f"depth_{v}"] = rng.integers(0, 65536, (size, size), dtype=np.uint16)
        n = 40
        rec[f"dvs_{v}"] = np.stack([np.sort(rng.integers(0, 100_000, n)), rng.integers(0, size, n),
                                    rng.integers(0, size, n), rng.choice([-1, 1], n)], axis=1).astype(np.int64)
    n = 200
    rec["lidar"] = np.stack([rng.uniform(-30, 30, n), rng.uniform(-30, 30, n), rng.uniform(-2, 3, n),
                             rng.uniform(0, 1, n)], axis=1).astype(np.float32)
    rec["lidar_tag"] = rng.integers(0, len(CARLA_NAMES), n).astype(np.uint8)
    rec["bev"] = rng.integers(0, 2, (len(BEV_NAMES), size, size), dtype=np.uint8)
    rec["boxes"] = np.zeros((0, 8), dtype=np.float32)
    rec["ego_pose"] = np.zeros(3, dtype=np.float64)
    return rec


def write_raw(params: Params, dataset_id: str, out_dir: Path) -> None:
    rng = np.random.default_rng(params.dataset(dataset_id).source.seed)
    counts, size = params.split_counts_of(dataset_id), params.resolution
    splits, frames, k = {}, {}, 0
    with io.atomic_dir(out_dir) as tmp:
        for split in SPLITS:
            splits[split] = []
            for _ in range(counts[split]):
                fid = f"{dataset_id}_{k:05d}"
                io.write_npz(tmp / "frames" / f"{fid}.npz", _record(rng, size))
                splits[split].append(fid)
                frames[fid] = {"town": "town01", "episode": k // 2, "step": k % 2}
                k += 1
        io.write_json(tmp / "manifest.json", {"dataset": dataset_id, "source": "toy", "resolution": size,
                                              "views": list(VIEWS), "splits": splits, "frames": frames,
                                              "seg_classes": list(CARLA_NAMES), "bev_classes": list(BEV_NAMES)})


def draw_example(params: Params, dataset_id: str, raw_dir: Path, figure: Path) -> None:
    from ..figures_generate import save_frame_figure

    fid = load_manifest(raw_dir)["splits"]["test"][0]
    rec = load_record(Path(raw_dir) / "frames" / f"{fid}.npz", fid)
    save_frame_figure(rec, figure, params.world.lidar.range_m, title=f"dataset {dataset_id}: toy, frame {fid}")
'''

#: its registration, placed where docs/extending.md says (above the union of the sources' settings)
TOY_REGISTRATION = '''@register_source("toy", label="toy records")
class ToySource(Strict):
    """Random raw records."""

    id: Literal["toy"]
    seed: int = Field(ge=0)


'''
SOURCES_ANCHOR = "#: ``datasets.<ds>.source``: one of the registered settings models"


def _section(title: str) -> str:
    text = EXTENDING.read_text()
    start = text.index(f"\n## {title}\n")
    end = text.find("\n## ", start + 1)
    return text[start:end if end > 0 else None]


def _named_files(section: str) -> set[str]:
    """The repository files a checklist names (``src/...``, ``params.yaml``, ``dvc.yaml``)."""
    return {m.rstrip(".,") for m in re.findall(r"`((?:src/[\w/.]+)|params\.yaml|dvc\.yaml)`", section)}


def _copy_repo(dst: Path) -> None:
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc")
    for name in ("src", "pipeline"):
        shutil.copytree(ROOT / name, dst / name, ignore=ignore)
    shutil.copy(ROOT / "params.yaml", dst / "params.yaml")


def _changed(dst: Path) -> set[str]:
    """The files of the copy that differ from (or are not in) the repository."""
    out = set()
    for path in dst.rglob("*"):
        if path.is_file() and "__pycache__" not in path.parts and path.suffix != ".pyc":
            rel = path.relative_to(dst).as_posix()
            if rel.startswith(("src/", "pipeline/")) or rel == "params.yaml":
                orig = ROOT / rel
                if not orig.is_file() or orig.read_bytes() != path.read_bytes():
                    out.add(rel)
    return out


def _add_as_documented(tmp_path: Path, section: str, module: str, module_text: str, registry: str, anchor: str,
                       registration: str, edit_params) -> tuple[Path, dict, dict]:
    """A copy of the repository with an addition made as docs/extending.md's ``section`` says: the
    new ``module``, its ``registration`` placed before ``anchor`` in ``registry``, params.yaml edited
    by ``edit_params``; checks that only those files changed and that the section names them.
    Returns the copy, its params and the environment that runs its code."""
    repo = tmp_path / "repo"
    _copy_repo(repo)
    (repo / module).write_text(module_text)
    text = (repo / registry).read_text()
    assert text.count(anchor) == 1
    (repo / registry).write_text(text.replace(anchor, registration + anchor))
    params = yaml.safe_load((repo / "params.yaml").read_text())
    edit_params(params)
    (repo / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))
    named = _named_files(_section(section))
    assert _changed(repo) == {module, registry, "params.yaml"}
    assert {registry, "params.yaml"} <= named and module.rpartition("/")[0] + "/" in named, named
    return repo, params, {**os.environ, "PYTHONPATH": os.pathsep.join([str(repo / "src"), str(repo)])}


def _run(repo: Path, env: dict, *argv: str) -> str:
    """``python <argv>`` in the copy; its stdout (it must exit 0)."""
    proc = subprocess.run([sys.executable, *argv], cwd=repo, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, (argv, proc.stderr[-2000:])
    return proc.stdout


def test_a_model_added_as_extending_md_says_trains_one_epoch(tmp_path):
    """A toy model (a new network module, its catalog entry, its recipe and id in params.yaml)
    trains one epoch through ``python -m pipeline.train`` at tiny scale, with no other file edited."""
    def edit(params: dict) -> None:
        params["model_ids"].append("toy")
        params["train"]["models"]["toy"] = {"optimizer": "adam", "de_loss": None, "momentum": None,
                                            "betas": [0.9, 0.999], "eps": 1.0e-8, "lr": 1.0e-2, "weight_decay": 0.0,
                                            "weighting": "none", "max_epochs": {"default": 1, "full": 1, "paper": 1}}
        params["train"].update(batch_size=2, num_workers=0, device="cpu", parallel_runs=1)

    repo, params, env = _add_as_documented(
        tmp_path, "A model", "src/compact_perception/learning/models/toy.py", TOY_NETWORK,
        "src/compact_perception/core/catalog.py", "\n\n@dataclass(frozen=True)\nclass WeightingInfo", TOY_ENTRY, edit)
    make_cache(repo / "data" / "cache" / "A", "A", size=params["world"]["resolution"]["default"])
    _run(repo, env, "-m", "pipeline.train", "--dataset", "A", "--model", "toy", "--seed", "0")
    summary = json.loads((repo / "runs/A/toy/seed0/summary.json").read_text())
    assert summary["epochs_run"] == 1 and summary["model"] == "toy"
    assert (repo / "runs/A/toy/seed0/best.pt").is_file()
    # the toy module is the copy's, not the repository's: the run's code fingerprint holds it
    files = _run(repo, env, "-c", "from compact_perception.learning.training.provenance import "
                 "fingerprinted_files as f; print('\\n'.join(f()))").split()
    assert "compact_perception/learning/models/toy.py" in files


def test_a_data_source_added_as_extending_md_says_runs_generate_and_preprocess(tmp_path):
    """A toy source (its module in data/sources, its registration in core/params/sources.py) runs
    through ``python -m pipeline.generate`` and ``python -m pipeline.preprocess`` at tiny scale,
    with no other file edited; the cache records it and the report names it by its label."""
    def edit(params: dict) -> None:
        a = params["datasets"]["A"]
        a["source"] = {"id": "toy", "seed": 3}
        a["frames"]["default"] = 10
        a["split_ratio"]["default"] = {"train": 6, "val": 2, "test": 2}
        params["world"]["workers"] = params["preprocess"]["workers"] = 1

    repo, params, env = _add_as_documented(
        tmp_path, "A data source", "src/compact_perception/data/sources/toy.py", TOY_SOURCE,
        "src/compact_perception/core/params/sources.py", SOURCES_ANCHOR, TOY_REGISTRATION, edit)
    _run(repo, env, "-m", "pipeline.generate", "--dataset", "A")
    _run(repo, env, "-m", "pipeline.preprocess", "--dataset", "A")
    meta = json.loads((repo / "data/cache/A/meta.json").read_text())
    assert meta["source"] == "toy" and meta["resolution"] == params["world"]["resolution"]["default"]
    assert (repo / "reports/figures/world_A.png").is_file()
    assert (repo / "reports/figures/lidar_preprocessing_A.png").is_file()
    label = _run(repo, env, "-c", "from compact_perception.core.params import source_label; print(source_label('toy'))")
    assert label.strip() == "toy records"
