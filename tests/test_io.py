"""Atomic, deterministic writing."""
from __future__ import annotations

import numpy as np
import pytest

from compact_perception.core import io
from compact_perception.core.classes import CARLA_PALETTE, palette_to_index
from compact_perception.data.geometry import topview_center, topview_index


def test_npz_is_byte_identical_and_loadable(tmp_path):
    arrays = {"a": np.arange(10, dtype=np.int16), "b": np.ones((2, 3), np.float32)}
    io.write_npz(tmp_path / "x.npz", arrays)
    first = (tmp_path / "x.npz").read_bytes()
    io.write_npz(tmp_path / "x.npz", arrays)
    assert (tmp_path / "x.npz").read_bytes() == first
    with np.load(tmp_path / "x.npz") as z:
        np.testing.assert_array_equal(z["a"], arrays["a"])
        np.testing.assert_array_equal(z["b"], arrays["b"])


def test_atomic_path_leaves_nothing_on_error(tmp_path):
    target = tmp_path / "out.json"
    with pytest.raises(RuntimeError):
        with io.atomic_path(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("boom")
    assert not target.exists()
    assert list(tmp_path.iterdir()) == []


def test_a_kill_inside_atomic_path_leaves_a_temporary_that_remove_leftovers_clears(tmp_path):
    """A process killed between mkstemp and the rename (no exception handler runs) leaves
    ``.best.pt.<random>.tmp``; :func:`io.remove_leftovers` removes it and nothing else."""
    import subprocess
    import sys

    code = ("import os, sys; from compact_perception.core import io\n"
            "with io.atomic_path(sys.argv[1]) as tmp:\n    os.kill(os.getpid(), 9)\n")
    proc = subprocess.run([sys.executable, "-c", code, str(tmp_path / "best.pt")], capture_output=True)
    assert proc.returncode == -9
    (tmp_path / "last.pt").write_bytes(b"kept")
    left = [p.name for p in tmp_path.iterdir() if p.name.startswith(".best.pt.") and p.name.endswith(".tmp")]
    assert len(left) == 1
    assert [p.name for p in io.remove_leftovers(tmp_path)] == left
    assert sorted(p.name for p in tmp_path.iterdir()) == ["last.pt"]


def test_atomic_dir_swaps_only_on_success(tmp_path):
    target = tmp_path / "ds"
    with pytest.raises(KeyboardInterrupt):
        with io.atomic_dir(target) as tmp:
            (tmp / "f").write_text("x")
            raise KeyboardInterrupt
    assert not target.exists() and not any(tmp_path.iterdir())
    with io.atomic_dir(target) as tmp:
        (tmp / "f").write_text("x")
    assert (target / "f").read_text() == "x"


def test_palette_round_trip_and_unknown_colour():
    idx = np.arange(23, dtype=np.uint8).reshape(1, 23).repeat(2, 0)
    img = CARLA_PALETTE[idx]
    np.testing.assert_array_equal(palette_to_index(img, CARLA_PALETTE), idx)
    img[0, 0] = (1, 2, 3)
    with pytest.raises(ValueError, match=r"sem_f: colour \(1, 2, 3\)"):
        palette_to_index(img, CARLA_PALETTE, name="sem_f")


def test_topview_index_borders():
    # eq. (2)-(3): -32 -> 0, +32 -> 127, 0 -> rint(63.5) = 64 (half to even)
    np.testing.assert_array_equal(topview_index(np.array([-32.0, 32.0, 0.0]), 32.0, 128), [0, 127, 64])
    assert topview_center(128) == 64
    assert topview_index(np.array([32.3]), 32.0, 128)[0] == 128  # out of grid: caller drops it
