"""Training-stage input and write errors: one line naming the file or key, exit status 1,
nothing half-written (dvclive folders included)."""
from __future__ import annotations

import errno

import pytest
import torch
import yaml

from repo_params import cap_epochs
from synthetic import make_cache


def _params_file(tmp_path, params_dict, *, epochs=2, batch=2):
    cap_epochs(params_dict, epochs)
    params_dict["train"]["batch_size"] = batch
    params_dict["train"]["num_workers"] = 0
    params_dict["train"]["device"] = "cpu"
    params_dict["train"]["models"]["compact_1l"].pop("max_epochs", None)
    path = tmp_path / "params.yaml"
    path.write_text(yaml.safe_dump(params_dict))
    return path


def _train(tmp_path, params_path, cache):
    from pipeline.train import main

    with pytest.raises(SystemExit) as exc:
        main(["--dataset", "A", "--model", "compact_1l", "--seed", "0", "--params", str(params_path), "--cache", str(cache),
              "--out", str(tmp_path / "run")])
    return str(exc.value.code)


def test_batch_larger_than_the_train_split(tmp_path, params_dict):
    cache = make_cache(tmp_path / "cache", counts=(3, 2, 2))
    msg = _train(tmp_path, _params_file(tmp_path, params_dict, batch=4), cache)
    assert msg.startswith("error: train.batch_size: 4 needs at least 4 training frames") and "\n" not in msg
    assert str(cache / "train") in msg
    assert not (tmp_path / "run").exists() or not any((tmp_path / "run").iterdir())


@pytest.mark.parametrize("fail_at_save,torch_error", [(1, False), (3, False), (1, True)])
def test_disk_full_leaves_no_half_written_epoch(tmp_path, params_dict, monkeypatch, fail_at_save, torch_error):
    """The n-th checkpoint write fails with ENOSPC: one line naming the file; the dvclive logs
    hold exactly the epochs the checkpoint holds (none when the first write failed)."""
    cache = make_cache(tmp_path / "cache", counts=(4, 2, 2))
    params_path = _params_file(tmp_path, params_dict, epochs=3)
    real_save, calls = torch.save, {"n": 0}

    def failing_save(obj, f, *args, **kwargs):
        calls["n"] += 1
        if calls["n"] >= fail_at_save:
            if torch_error:  # what torch.save really raises on a full disk
                raise RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 4224 vs 4120")
            raise OSError(errno.ENOSPC, "No space left on device", str(f))
        return real_save(obj, f, *args, **kwargs)

    monkeypatch.setattr(torch, "save", failing_save)
    if torch_error:
        import shutil
        from collections import namedtuple

        usage = namedtuple("usage", "total used free")
        monkeypatch.setattr(shutil, "disk_usage", lambda p: usage(1 << 30, 1 << 30, 1 << 10))
    msg = _train(tmp_path, params_path, cache)
    assert "No space left on device" in msg and "\n" not in msg and msg.startswith("error: ")
    assert ("last.pt" in msg or "best.pt" in msg) and ".tmp" not in msg
    run = tmp_path / "run"
    assert not (run / "summary.json").exists()
    if fail_at_save == 1:  # nothing was ever saved: nothing is left
        assert not (run / "live").exists() and not (run / "last.pt").exists()
    else:
        saved = torch.load(run / "last.pt", weights_only=True)["epoch"]
        logged = (run / "live" / "plots" / "metrics" / "lr.tsv").read_text().split()[2::2]
        assert logged == [str(e) for e in range(saved + 1)]


def test_checkpoint_bytes_do_not_depend_on_the_temporary_name(tmp_path):
    """Checkpoints are written under a random temporary name and renamed (nothing half-written);
    torch.save given a path names the archive's root folder after the file, so the bytes must
    be written through an open file to be the same on every run."""
    from compact_perception.core import io
    from compact_perception.learning.training.checkpoint import save

    state = {"model": {"w": torch.arange(6.0).reshape(2, 3)}, "epoch": 1}
    written = []
    for name in ("a", "b"):
        final = tmp_path / name / "best.pt"
        final.parent.mkdir()
        with io.atomic_path(final) as tmp:
            assert tmp.name != final.name
            save(state, tmp, final)
        written.append(final.read_bytes())
    assert written[0] == written[1]
    assert torch.equal(torch.load(tmp_path / "a" / "best.pt")["model"]["w"], state["model"]["w"])


def _files(folder):
    return {p.relative_to(folder): (p.read_bytes(), p.stat().st_mtime_ns) for p in folder.rglob("*") if p.is_file()}


def test_out_refuses_a_folder_holding_a_finished_run_of_another_model_or_seed(tmp_path, params_dict):
    """``train --model compact_1l --seed 0 --out runs/A/compact_15l/seed0`` (issue 56): one line naming
    the folder and the run it holds, exit 1, not a byte of it changed; its own run there is reused."""
    from pipeline.train import main

    cache = make_cache(tmp_path / "cache", counts=(4, 2, 2))
    params_path = _params_file(tmp_path, params_dict, epochs=1)
    out = tmp_path / "runs" / "A" / "compact_15l" / "seed0"

    def train(model, seed):
        try:
            main(["--dataset", "A", "--model", model, "--seed", str(seed), "--params", str(params_path),
                  "--cache", str(cache), "--out", str(out)])
        except SystemExit as exc:
            return str(exc.code)
        return None

    assert train("compact_15l", 0) is None and (out / "summary.json").is_file()
    before = _files(out)
    for model, seed, held in (("compact_1l", 0, "A/compact_15l/seed0"), ("compact_15l", 1, "A/compact_15l/seed0")):
        msg = train(model, seed)
        assert msg == (f"error: {out}: holds a finished run of {held} (its summary.json), not of A/{model}/seed{seed}; "
                       "give --out an empty folder or this run's own"), msg
        assert _files(out) == before
    assert train("compact_15l", 0) is None and _files(out) == before  # its own: already complete
    (out / "summary.json").write_text("[" * 100_000)
    msg = train("compact_1l", 0)
    assert msg.startswith(f"error: {out}: its summary.json does not read as a run's summary") and "\n" not in msg
