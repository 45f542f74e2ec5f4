"""benchmarks/fingerprint_kernels.py: the per-layer hashes are reproducible on one machine and
move from the first layer whose numbers change."""
from __future__ import annotations

import importlib.util

import torch

from compact_perception.data import make_loader, to_device
from compact_perception.models import DATASETS, build_model

from synthetic import make_cache


def _script(root, monkeypatch):
    monkeypatch.setenv("COMPACT_PERCEPTION_UNPINNED", "1")  # importing it must not pin this test process
    spec = importlib.util.spec_from_file_location("fingerprint_kernels", root / "benchmarks" / "fingerprint_kernels.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_fingerprint_is_stable_and_locates_a_change(root, tmp_path, monkeypatch):
    fp = _script(root, monkeypatch)
    cache = make_cache(tmp_path / "cache", "A", size=32, counts=(2, 1, 1))
    batch = to_device(next(iter(make_loader(cache, "train", batch_size=2))), "cpu", DATASETS["A"].n_seg)

    def run(perturb: bool) -> dict:
        torch.manual_seed(0)
        model = build_model("compact_15l", "A")
        if perturb:  # one weight of the LiDAR encoder's first conv changes by one float32 step
            w = model.get_submodule("enc_lidar.level0.0.conv1").weight
            with torch.no_grad():
                w.view(-1)[0] = torch.nextafter(w.view(-1)[0], torch.tensor(1.0))
        return fp.fingerprint(model, batch)

    a, b, c = run(False), run(False), run(True)
    assert a == b
    assert set(a) == {"forward", "grad", "grad2", "loss"} and len(a["forward"]) > 100
    changed = [k for k in a["forward"] if a["forward"][k] != c["forward"][k]]
    assert changed and changed[0].startswith("enc_lidar.level0.0.conv1#")
    assert all(a["forward"][k] == c["forward"][k] for k in a["forward"] if k.startswith("enc_rgb."))
