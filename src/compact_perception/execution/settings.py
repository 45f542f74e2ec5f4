"""Which executor runs a stage's jobs, and the cluster's settings, in one place.

No result depends on them, so they are neither params (``params.yaml``) nor DVC params of any
stage nor part of any run's digest: switching the executor reruns no stage and restarts no run.
Two sources, the environment first:

- ``COMPACT_PERCEPTION_EXECUTOR``: ``pool`` (the default: the local process pool), ``slurm``,
  ``local`` or ``debug`` (submitit's local executors, for tests and a dry run);
- the cluster file, ``cluster.yaml`` in the working directory (``COMPACT_PERCEPTION_CLUSTER``
  names another; none: every default below). docs/cluster.md has a commented example.

A key not listed, a value of the wrong type or range, or an executor named that is not one is
a :class:`SettingsError` of one line naming the file (or variable) and the key.
"""
from __future__ import annotations

import os
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any, Mapping, Optional

import yaml

from ..core.params.file import DuplicateKeyError, ExpansionError, UniqueKeyLoader

__all__ = ["CLUSTER_FILE", "CLUSTER_FILE_ENV", "EXECUTORS", "EXECUTOR_ENV", "ClusterSettings", "SettingsError",
           "read_settings"]

EXECUTOR_ENV = "COMPACT_PERCEPTION_EXECUTOR"
CLUSTER_FILE_ENV = "COMPACT_PERCEPTION_CLUSTER"
CLUSTER_FILE = Path("cluster.yaml")
#: ``pool``: this machine's process pool; the others are submitit's executors of those names.
EXECUTORS = ("pool", "slurm", "local", "debug")
#: A cluster file is a few hundred bytes.
MAX_BYTES = 1 << 16


class SettingsError(ValueError):
    """A cluster setting that cannot be used: one line naming the file or variable and the key."""


@dataclass(frozen=True)
class ClusterSettings:
    """How a stage's jobs are executed (docs/cluster.md); every field has a default."""

    executor: str = "pool"            # pool | slurm | local | debug
    folder: str = ".submitit"         # submitit's job files and logs: on a filesystem every node shares
    partition: Optional[str] = None   # sbatch --partition
    account: Optional[str] = None     # sbatch --account
    qos: Optional[str] = None         # sbatch --qos
    time_min: int = 1440              # one job's time limit; a job past it is requeued and resumes
    cpus_per_task: Optional[int] = None   # sbatch --cpus-per-task (train.num_threads + loader workers)
    gpus_per_task: int = 0            # GPUs of one job (one run)
    mem_gb: Optional[float] = None    # sbatch --mem
    array_parallelism: int = 256      # jobs of one array running at once
    max_requeues: int = 3             # times a job may time out and be requeued
    setup: tuple[str, ...] = ()       # shell lines run before each job (module load, venv activate)
    poll_s: float = 5.0               # how often the stage looks at its jobs
    extra: Mapping[str, Any] = field(default_factory=dict)  # other sbatch options, as submitit names them

    @property
    def submitted(self) -> bool:
        """Whether the jobs go to submitit (anything but the local pool)."""
        return self.executor != "pool"


_INT_KEYS = {"time_min": 1, "cpus_per_task": 1, "gpus_per_task": 0, "array_parallelism": 1, "max_requeues": 0}
_FLOAT_KEYS = {"mem_gb": 0.0, "poll_s": 0.0}
_STR_KEYS = ("folder", "partition", "account", "qos")
_KEYS = tuple(f.name for f in fields(ClusterSettings))


def _checked(key: str, value: Any, where: str) -> Any:
    """``value`` of ``key`` as the settings hold it; :class:`SettingsError` naming ``where`` and the key."""
    optional = ClusterSettings.__dataclass_fields__[key].default is None
    if value is None and optional:
        return None
    if key == "executor":
        if value not in EXECUTORS:
            raise SettingsError(f"{where}: executor: expected one of {', '.join(EXECUTORS)}, got {str(value)[:40]!r}")
        return value
    if key in _INT_KEYS:
        if type(value) is not int or value < _INT_KEYS[key]:
            raise SettingsError(f"{where}: {key}: expected an integer >= {_INT_KEYS[key]}, got {str(value)[:40]!r}")
        return value
    if key in _FLOAT_KEYS:
        if type(value) not in (int, float) or not value > _FLOAT_KEYS[key]:
            raise SettingsError(f"{where}: {key}: expected a number > {_FLOAT_KEYS[key]:g}, got {str(value)[:40]!r}")
        return float(value)
    if key in _STR_KEYS:
        if not isinstance(value, str) or not value.strip():
            raise SettingsError(f"{where}: {key}: expected a non-empty string, got {str(value)[:40]!r}")
        return value
    if key == "setup":
        if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
            raise SettingsError(f"{where}: setup: expected a list of shell lines (strings)")
        return tuple(value)
    if not isinstance(value, dict) or not all(isinstance(k, str) for k in value):  # extra
        raise SettingsError(f"{where}: extra: expected a mapping of sbatch options (submitit's names)")
    return dict(value)


def _file_values(path: Path) -> dict[str, Any]:
    """The settings a cluster file writes (none when there is no file)."""
    try:
        if not path.is_file():
            return {}
        raw = path.read_bytes()[:MAX_BYTES + 1]
    except OSError as err:
        raise SettingsError(f"{path}: could not read ({err.strerror or err})") from None
    if len(raw) > MAX_BYTES:
        raise SettingsError(f"{path}: too large for a cluster file (at most {MAX_BYTES} bytes)")
    try:
        data = yaml.load(raw.decode("utf-8"), Loader=UniqueKeyLoader)
    except UnicodeDecodeError:
        raise SettingsError(f"{path}: not UTF-8 text") from None
    except (DuplicateKeyError, ExpansionError) as err:
        raise SettingsError(f"{path}: {err}") from None
    except yaml.YAMLError as err:
        raise SettingsError(f"{path}: not valid YAML: {' '.join(str(err).split())[:200]}") from None
    if data is None:
        return {}
    if not isinstance(data, dict):
        raise SettingsError(f"{path}: expected a mapping of cluster settings, got a {type(data).__name__}")
    unknown = [str(k) for k in data if k not in _KEYS]
    if unknown:
        raise SettingsError(f"{path}: {unknown[0][:40]}: not a cluster setting (expected one of {', '.join(_KEYS)})")
    return {k: _checked(k, v, str(path)) for k, v in data.items()}


def read_settings(environ: Optional[Mapping[str, str]] = None) -> ClusterSettings:
    """The settings of this stage: the cluster file's (:data:`CLUSTER_FILE`, or the file
    :data:`CLUSTER_FILE_ENV` names), the executor :data:`EXECUTOR_ENV` names over the file's."""
    env = os.environ if environ is None else environ
    named = env.get(CLUSTER_FILE_ENV)
    path = Path(named) if named else CLUSTER_FILE
    if named and not path.is_file():
        raise SettingsError(f"{CLUSTER_FILE_ENV}: {named}: file not found")
    values = _file_values(path)
    chosen = env.get(EXECUTOR_ENV)
    if chosen:
        if chosen.strip() not in EXECUTORS:
            raise SettingsError(f"{EXECUTOR_ENV}: expected one of {', '.join(EXECUTORS)}, got {chosen[:40]!r}")
        values["executor"] = chosen.strip()
    return ClusterSettings(**values)
