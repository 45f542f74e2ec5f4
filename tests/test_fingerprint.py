"""benchmarks/fingerprint_kernels.py: the per-layer hashes are reproducible on one machine and
move from the first layer whose numbers change."""
from __future__ import annotations

import torch

from compact_perception.data.loader import make_loader, to_device
from compact_perception.learning.models import DATASET_SPECS, build_model

from scripts import load_script
from synthetic import make_cache


def _script(root, monkeypatch):
    monkeypatch.setenv("COMPACT_PERCEPTION_UNPINNED", "1")  # importing it must not pin this test process
    return load_script("fingerprint_kernels")


def test_fingerprint_is_stable_and_locates_a_change(root, tmp_path, monkeypatch):
    fp = _script(root, monkeypatch)
    cache = make_cache(tmp_path / "cache", "A", size=32, counts=(2, 1, 1))
    batch = to_device(next(iter(make_loader(cache, "train", batch_size=2))), "cpu", DATASET_SPECS["A"].n_seg)

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


def _mgn_run(fp, params, model_id: str, batch: dict, perturb: str | None = None) -> dict:
    """The ``mgn`` phase of ``model_id``'s recipe from seed 0, the weights of ``perturb`` 1 % larger."""
    from compact_perception.learning.losses import de_loss_factor
    from compact_perception.learning.weighting import build_weighting

    recipe = params.train.models[model_id]
    torch.manual_seed(0)
    model = build_model(model_id, "A")
    if perturb:
        with torch.no_grad():
            model.get_submodule(perturb).weight.mul_(1.01)
    weighting = build_weighting(recipe, model.tasks, model, plateau_patience=params.train.plateau_patience,
                                plateau_factor=params.train.plateau_factor)
    return fp.mgn_fingerprint(model, batch, weighting, de_loss_factor(recipe.de_loss))


def test_mgn_phase_records_the_authors_update_and_locates_a_change(root, tmp_path, monkeypatch):
    """The authors' form: exact G_i, dL_MGN/dw_i, w_i and the second-order .grad of every
    parameter, reproducible; a change in the LS head moves LS's entries but not DE's or SS's
    (their G_i never see that head); Algorithm 1 writes no .grad."""
    from compact_perception.core.params import load_params

    fp = _script(root, monkeypatch)
    params = load_params(root / "params.yaml")
    cache = make_cache(tmp_path / "cache", "A", size=16, counts=(2, 1, 1))
    batch = to_device(next(iter(make_loader(cache, "train", batch_size=2))), "cpu", DATASET_SPECS["A"].n_seg)

    a = _mgn_run(fp, params, "compact_15l_mgn_authors", batch)
    assert a == _mgn_run(fp, params, "compact_15l_mgn_authors", batch)
    assert {"G.ls", "grad_w.ls", "w.ls", "bottleneck1.conv1.weight", "enc_rgb.level0.0.conv1.weight"} <= set(a)
    c = _mgn_run(fp, params, "compact_15l_mgn_authors", batch, perturb="dec_ls.heads.0")
    assert c["G.ls"] != a["G.ls"] and c["grad_w.ls"] != a["grad_w.ls"]
    assert all(c[k] == a[k] for k in ("G.de", "G.ss", "grad_w.de", "grad_w.ss"))
    assert c["dec_ls.level0.0.conv1.weight"] != a["dec_ls.level0.0.conv1.weight"]

    alg1 = _mgn_run(fp, params, "compact_15l_mgn", batch)
    assert set(alg1) == {f"{k}.{t}" for k in ("G", "grad_w", "w") for t in ("de", "ss", "ls", "bevp")}


def test_differences_count_one_sided_entries_and_warn_on_other_code(root, monkeypatch):
    fp = _script(root, monkeypatch)
    mine = {"cpu": "here", "code": "c1", "models": {"m": {"grad": {"a": "1", "b": "2"}, "kernels": {"k1": "3"}}}}
    other = {"cpu": "there", "models": {"m": {"grad": {"a": "1", "b": "9"}, "kernels": {"k1": "3", "k2": "1"},
                                              "mgn": {"G.de": "0.5"}}}}
    lines = fp.differences(mine, other)
    assert any(line.startswith("warning: other code") for line in lines)
    by_phase = {line.split()[1].rstrip(":"): line for line in lines if line.strip().startswith("m ")}
    assert "1 of    2 differ; first at b" in by_phase["grad"]
    assert "1 of    2 differ; first at k2" in by_phase["kernels"]
    assert "not in this fingerprint" in by_phase["mgn"]
    same = fp.differences(mine, {**mine, "cpu": "twin"})
    assert not any("warning" in line for line in same) and all("identical" in line for line in same[2:])


def test_onednn_kernels_lists_the_primitives_and_keeps_stdout_clean(root, monkeypatch, capfd):
    fp = _script(root, monkeypatch)
    conv = torch.nn.Conv2d(8, 8, 3, padding=1)
    x = torch.randn(2, 8, 16, 16, requires_grad=True)
    out, kernels = fp.onednn_kernels(lambda: conv(x).sum().backward() or "done")
    assert out == "done"
    assert any(k.startswith("convolution,") and "backward_weights" in k for k in kernels)
    assert "onednn_verbose" not in capfd.readouterr().out
