"""Thin DVC stage entry points: parse args, load params, call compact_perception, write outputs.

Importing this package
- puts this checkout's ``src/`` first on ``sys.path``, so a stage runs the library code that
  ``dvc.yaml`` lists as its dependencies (also in a ``dvc exp`` copy of the repository, where
  an editable install would point at the original checkout);
- pins every numeric library to the same kernels on any x86-64 machine
  (:mod:`compact_perception.core.determinism`) before numpy or torch compute anything.
"""
import sys
from pathlib import Path

_SRC = str(Path(__file__).resolve().parents[1] / "src")
if Path(_SRC, "compact_perception").is_dir() and sys.path[:1] != [_SRC]:
    sys.path.insert(0, _SRC)

from compact_perception.core.determinism import pin_numeric_libraries, pin_opencv  # noqa: E402

pin_numeric_libraries()
pin_opencv()
