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


def test_a_model_added_as_extending_md_says_trains_one_epoch(tmp_path):
    """A toy model (a new network module, its catalog entry, its recipe and id in params.yaml)
    trains one epoch through ``python -m pipeline.train`` at tiny scale, with no other file edited."""
    named = _named_files(_section("A model"))
    repo = tmp_path / "repo"
    _copy_repo(repo)
    (repo / "src/compact_perception/learning/models/toy.py").write_text(TOY_NETWORK)
    catalog = repo / "src/compact_perception/core/catalog.py"
    text = catalog.read_text()
    anchor = "\n\n\n@dataclass(frozen=True)\nclass WeightingInfo"
    assert anchor in text
    catalog.write_text(text.replace(anchor, "\n" + TOY_ENTRY + anchor, 1))
    params = yaml.safe_load((repo / "params.yaml").read_text())
    params["model_ids"].append("toy")
    params["train"]["models"]["toy"] = {"optimizer": "adam", "de_loss": None, "momentum": None,
                                        "betas": [0.9, 0.999], "eps": 1.0e-8, "lr": 1.0e-2, "weight_decay": 0.0,
                                        "weighting": "none", "max_epochs": {"default": 1, "full": 1, "paper": 1}}
    params["train"].update(batch_size=2, num_workers=0, device="cpu", parallel_runs=1)
    (repo / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False))

    changed = _changed(repo)
    assert changed == {"src/compact_perception/learning/models/toy.py", "src/compact_perception/core/catalog.py",
                       "params.yaml"}
    assert changed - {"src/compact_perception/learning/models/toy.py"} <= named, named
    assert "src/compact_perception/learning/models/" in " ".join(named)

    make_cache(repo / "data" / "cache" / "A", "A", size=params["world"]["resolution"]["default"])
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(repo / "src"), str(repo)])}
    proc = subprocess.run([sys.executable, "-m", "pipeline.train", "--dataset", "A", "--model", "toy", "--seed", "0"],
                          cwd=repo, env=env, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    summary = json.loads((repo / "runs/A/toy/seed0/summary.json").read_text())
    assert summary["epochs_run"] == 1 and summary["model"] == "toy"
    assert (repo / "runs/A/toy/seed0/best.pt").is_file()
    # the toy module is the copy's, not the repository's: the run's code fingerprint holds it
    probe = subprocess.run([sys.executable, "-c", "from compact_perception.learning.training.provenance import "
                            "fingerprinted_files as f; print('\\n'.join(f()))"], cwd=repo, env=env,
                           capture_output=True, text=True, check=True)
    assert "compact_perception/learning/models/toy.py" in probe.stdout.split()
