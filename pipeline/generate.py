"""Stage generate@<ds>: render the simulated dataset A, B or C into data/raw/<ds>/ (SPEC 3.1).

Thin wrapper: parse args, load params, call compact_perception.world.generate_dataset, then
write the Fig. 1-like panel reports/figures/world_<ds>.png atomically. With ``source: authors``
it checks the authors' release; with ``source: carla`` it checks the recording at
``datasets.<ds>.carla.root`` (pipeline.collect_carla) and copies it into data/raw/<ds>.
"""
from __future__ import annotations

import argparse
import logging
import sys
from pathlib import Path

from compact_perception.core.catalog import sim_dataset_ids
from compact_perception.core.config import ParamsError
from compact_perception.core.errors import RunError, os_error_line

from ._common import start


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--dataset", required=True, choices=sim_dataset_ids())
    ap.add_argument("--params", default="params.yaml")
    ap.add_argument("--out", default="data/raw", help="parent of the dataset directory")
    ap.add_argument("--figure-dir", default="reports/figures")
    args = ap.parse_args(argv)
    params = start(args.params, workers=("world.workers",))
    dp = getattr(params.datasets, args.dataset)
    if dp.source == "authors":
        from compact_perception.authors import describe_authors_dataset
        from compact_perception.core.errors import RecordError

        try:
            describe_authors_dataset(dp.authors_root, dp.authors_splits, args.dataset, Path(args.out) / args.dataset,
                                     Path(args.figure_dir) / f"world_{args.dataset}.png",
                                     resolution=params.world.resolution.at(params.scale), workers=params.world.workers)
        except RecordError as err:
            sys.exit(f"error: {err}")
        except OSError as err:
            sys.exit(f"error: {os_error_line(err, Path(args.out) / args.dataset)}")
        return 0
    if dp.source == "carla":
        return _carla(params, args.dataset, Path(args.out) / args.dataset, Path(args.figure_dir) / f"world_{args.dataset}.png")
    from compact_perception.figures_generate import save_frame_figure
    from compact_perception.world.generate import generate_dataset, iter_episodes, render_episode

    try:
        out = generate_dataset(params, args.dataset, Path(args.out) / args.dataset)
    except (ParamsError, RunError) as err:  # RunError: the free disk cannot hold the dataset
        sys.exit(f"error: {err}")
    except OSError as err:  # a full disk: atomic_dir has removed the partial dataset
        sys.exit(f"error: {os_error_line(err, Path(args.out) / args.dataset)}")
    ep = next(e for e in iter_episodes(params, args.dataset) if e["split"] == "test")
    rec = None
    for rec in render_episode(params.world, ep["town"], ep["seed"], min(2, ep["frames"]),
                              params.world.resolution.at(params.scale), episode=ep["index"]):
        pass
    assert rec is not None
    figure = Path(args.figure_dir) / f"world_{args.dataset}.png"
    try:
        save_frame_figure(rec, figure, params.world.lidar.range_m, title=f"dataset {args.dataset}: {rec['meta']}")
    except OSError as err:
        sys.exit(f"error: {os_error_line(err, figure)}")
    logging.getLogger("generate").info("wrote %s and the figure", out)
    return 0


def _carla(params, dataset_id: str, out: Path, figure: Path) -> int:
    """source: carla: check the recording at datasets.<ds>.carla.root and copy it into ``out``."""
    from compact_perception.carla.recording import import_recording
    from compact_perception.core.errors import RecordError
    from compact_perception.record import load_record
    from compact_perception.figures_generate import save_frame_figure

    root = getattr(params.datasets, dataset_id).carla.root
    try:
        manifest = import_recording(params, dataset_id, root, out)
    except RecordError as err:
        sys.exit(f"error: {err}")
    except OSError as err:
        sys.exit(f"error: {os_error_line(err, out)}")
    fid = manifest["splits"]["test"][0]
    rec = load_record(out / "frames" / f"{fid}.npz", fid)
    try:
        save_frame_figure(rec, figure, params.world.lidar.range_m, title=f"dataset {dataset_id}: CARLA, test frame {fid}")
    except OSError as err:
        sys.exit(f"error: {os_error_line(err, figure)}")
    logging.getLogger("generate").info("copied the CARLA recording %s into %s", root, out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
