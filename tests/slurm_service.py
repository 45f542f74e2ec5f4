"""A real single-node SLURM on the loopback for the tests: the ``slurm_service``
fixture starts ``tests/services/slurm.sh`` in a fresh folder once per session and stops exactly the
processes it started (their pid files) at the end.

It skips, saying why, where it cannot run: not root, or SLURM and munge not installed (CI installs
nothing extra by default; ``bash tests/services/slurm.sh install`` does, on Debian 12). Installed
but not starting is a failure, with the script's line.

No accounting storage: the service runs no slurmdbd, so ``sacct`` answers "Slurm accounting storage
is disabled" (exit 1). What submitit 1.5.4 does then (``submitit/core/core.py``, ``InfoWatcher``):
each poll of a job with no result file yet calls ``sacct`` (at 0, 2, 4, 8 ... s after the last
submission), logs "Bypassing sacct error ..., status may be inaccurate." at WARNING and keeps the
job's state UNKNOWN, which counts as not finished. A job that ends with a result is still seen to
finish: ``Job.done()`` looks for the job's result file first, and the stage's executor returns every
outcome through that file (a failing run included: :class:`RunTask` catches its error). A job that
dies without writing one (killed, out of memory, cancelled outside the stage) would stay UNKNOWN;
the executor asks the controller itself (``squeue``, ``QueueWatch`` in
``execution/submitit_backend.py``), which needs no accounting, and fails the stage with the job's
state and log (``test_a_job_that_dies_without_a_result_fails_the_stage_with_its_log``).
"""
from __future__ import annotations

import os
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import pytest

SCRIPT = Path(__file__).resolve().parent / "services" / "slurm.sh"
NEEDED = ("munged", "slurmctld", "slurmd", "sinfo", "sbatch", "srun", "scontrol")


@dataclass(frozen=True)
class SlurmService:
    folder: Path   # slurm.conf, the daemons' pid and log files, munged's socket
    conf: str      # SLURM_CONF for every SLURM command (sbatch, scontrol) and job


def why_not() -> str | None:
    """Why the service cannot start on this machine (``None``: it can)."""
    if os.geteuid() != 0:
        return "a SLURM test service runs as root (SlurmUser=root); not root here"
    missing = [c for c in NEEDED if shutil.which(c) is None]
    if missing:
        return f"SLURM or munge not installed ({', '.join(missing)} not found): bash tests/services/slurm.sh install"
    return None


def _script(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(["bash", str(SCRIPT), *args], capture_output=True, text=True, timeout=180,
                          stdin=subprocess.DEVNULL)


@pytest.fixture(scope="session")
def slurm_service():
    """The running service; stopped at the session's end (by the pids it recorded)."""
    reason = why_not()
    if reason:
        pytest.skip(reason)
    # In /tmp, not pytest's tmp_path: munged's socket needs every folder above it searchable by all.
    folder = Path(tempfile.mkdtemp(prefix="slurm-service-", dir="/tmp"))
    started = _script("start", str(folder))
    if started.returncode != 0:
        _script("stop", str(folder))   # whatever did start; the folder stays for its logs
        pytest.fail(f"the SLURM test service did not start: {started.stderr.strip()[-600:]}", pytrace=False)
    try:
        line = started.stdout.strip().splitlines()[-1]
        yield SlurmService(folder, line.removeprefix("export SLURM_CONF="))
    finally:
        _script("stop", str(folder))
        shutil.rmtree(folder, ignore_errors=True)
