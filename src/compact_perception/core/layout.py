"""Where one training run's files live (each dataset's ``train@<ds>`` and ``evaluate@<ds>`` stages
write every run of that dataset):

- ``runs/<ds>/<model>/seed<k>/``          checkpoints, dvclive logs, ``summary.json`` (train)
- ``results/<ds>/<model>/seed<k>/metrics.json``  test scores (evaluate)
- ``data/eval/<ds>/<model>/seed<k>/``     per-frame scores and saved predictions (evaluate)
- ``data/cache/<ds>/``                    what it trains on and is scored on (preprocess writes it)

``k`` is one of the seeds ``Params.seeds_of`` gives (the dataset's ``training.seeds`` for a
compact model, ``baseline_seeds`` for a baseline). The loss-balancing study's runs live beside
them, under ``<...>/<ds>/study/<arm>/seed<k>/`` (:func:`study_paths`). Every stage and the report
build these paths here. The trivial predictors of the floor (:mod:`..floor`), fitted
once per dataset, have no seed: ``results/<ds>/<id>/metrics.json`` and ``data/eval/<ds>/<id>/``
(:func:`floor_paths`). :class:`RunPaths` holds them all, with the files of the run folder
(``last.pt``, ``best.pt``, ``summary.json``, ``live/``, ``model.onnx``) that training writes.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Optional

__all__ = ["RunPaths", "run_paths", "study_paths", "paths_of_run", "study_run_name", "study_arm", "floor_paths", "cache_dir",
           "evaluation_folders", "STUDY_DIR", "BEST_HASH_KEY"]

#: The folder of a dataset's study runs (not a model id: :mod:`.catalog` registers none by this name).
STUDY_DIR = "study"
#: The key of ``summary.json`` that records the SHA-256 of ``best.pt`` as the finished run left it
#: (training writes it; evaluation checks the checkpoint against it before it trusts it).
BEST_HASH_KEY = "best_sha256"
#: What a study run's name (:attr:`RunPaths.model`, a record's run) starts with: ``study:<arm>``.
_STUDY_PREFIX = "study:"


def study_run_name(arm: str) -> str:
    """The name of a run of study arm ``arm``: ``study:<arm>``, beside the model ids."""
    return f"{_STUDY_PREFIX}{arm}"


def study_arm(name: str) -> Optional[str]:
    """The study arm a run name (:func:`study_run_name`) belongs to; ``None`` for a model id."""
    return name[len(_STUDY_PREFIX):] if name.startswith(_STUDY_PREFIX) else None


@dataclass(frozen=True)
class RunPaths:
    """Every location of one run, relative to ``root``: its folders and the files of its run folder.
    A run trained or scored elsewhere (a test, ``--out``) is these with fields replaced
    (:func:`dataclasses.replace`)."""

    dataset: str
    model: str           # the model id, ``study:<arm>`` or a trivial predictor's id
    seed: int
    run_dir: Path        # runs/<ds>/<model>/seed<k>
    metrics_path: Path   # results/<ds>/<model>/seed<k>/metrics.json
    eval_dir: Path       # data/eval/<ds>/<model>/seed<k>
    cache_dir: Path      # data/cache/<ds>

    @property
    def last(self) -> Path:
        """Resumable state after the last finished epoch."""
        return self.run_dir / "last.pt"

    @property
    def best(self) -> Path:
        """The network at the best validation score (what evaluation scores)."""
        return self.run_dir / "best.pt"

    @property
    def summary(self) -> Path:
        """Written last: the run is complete."""
        return self.run_dir / "summary.json"

    @property
    def live(self) -> Path:
        """dvclive's logs, rebuilt from the checkpoint's history on every start."""
        return self.run_dir / "live"

    @property
    def onnx(self) -> Path:
        """The best network as ONNX (a compact model's own runs)."""
        return self.run_dir / "model.onnx"


def _paths(dataset: str, model: str, seed: int, root: Path | str, tail: Path) -> RunPaths:
    root = Path(root)
    return RunPaths(dataset, model, seed, root / "runs" / tail, root / "results" / tail / "metrics.json",
                    root / "data" / "eval" / tail, cache_dir(dataset, root))


#: Where the datasets' caches live, relative to the repository root (what preprocessing writes).
CACHE_ROOT = Path("data") / "cache"


def cache_dir(dataset: str, root: Path | str = ".") -> Path:
    """The cache of ``dataset`` under ``root``: ``data/cache/<ds>/`` (what preprocessing writes)."""
    return Path(root) / CACHE_ROOT / dataset


def run_paths(dataset: str, model: str, seed: int, root: Path | str = ".") -> RunPaths:
    """Paths of the run (``dataset``, ``model``, training seed ``seed``) under ``root``."""
    return _paths(dataset, model, seed, root, Path(dataset) / model / f"seed{seed}")


def study_paths(arm: str, seed: int, dataset: str, root: Path | str = ".") -> RunPaths:
    """Paths of one study run (arm ``arm`` of the loss-balancing study, training seed ``seed``, on
    ``dataset``): ``runs/<ds>/study/<arm>/seed<k>/``, ``results/<ds>/study/<arm>/seed<k>/metrics.json``,
    ``data/eval/<ds>/study/<arm>/seed<k>/``: inside the dataset's own folders, which its train and
    evaluate stages write."""
    return _paths(dataset, study_run_name(arm), seed, root, Path(dataset) / STUDY_DIR / arm / f"seed{seed}")


def paths_of_run(dataset: str, model: str, seed: int, arm: Optional[str] = None,
                 root: Path | str = ".") -> RunPaths:
    """Paths of a run of ``model`` or, with ``arm``, of that study arm (:func:`study_paths`; its model
    is the study's base model), at training seed ``seed`` on ``dataset``."""
    return study_paths(arm, seed, dataset, root) if arm is not None else run_paths(dataset, model, seed, root)


def floor_paths(dataset: str, trivial_id: str, root: Path | str = ".") -> RunPaths:
    """Paths of the evaluation of trivial predictor ``trivial_id`` (``floor_pixel``, ...) on
    ``dataset``: ``results/<ds>/<id>/metrics.json`` and ``data/eval/<ds>/<id>/``; it has no run
    folder (nothing is trained) and no seed (it is deterministic; ``seed`` is -1)."""
    return _paths(dataset, trivial_id, -1, root, Path(dataset) / trivial_id)


def evaluation_folders(paths: Iterable[RunPaths]) -> list[Path]:
    """The folders an evaluation of ``paths`` writes (each one's ``results/`` folder, then its
    ``data/eval/`` folder), once each: what the evaluate stage checks it can write before it writes."""
    paths = list(paths)
    found = [p.metrics_path.parent for p in paths] + [p.eval_dir for p in paths]
    return list(dict.fromkeys(found))
