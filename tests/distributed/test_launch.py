"""The distributed tests on 2 and 4 MPI ranks, from a plain ``python -m pytest``.

Runs ``mpirun -np N python -m pytest tests/distributed`` (CPU warp, ``--oversubscribe``:
CI machines have fewer cores than ranks) and passes when every rank passes. Skipped,
with the reason, only where mpirun or mpi4py is missing (``.ci/run`` installs both).
"""

import os
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
INSIDE_MPI = any(os.environ.get(k) for k in ("OMPI_COMM_WORLD_SIZE", "PMI_SIZE", "PMIX_RANK"))


@pytest.mark.skipif(INSIDE_MPI, reason="already running under mpirun")
@pytest.mark.parametrize("ranks", [2, 4])
def test_distributed_suite_on_mpi_ranks(ranks):
    if shutil.which("mpirun") is None:
        pytest.skip("mpirun not found: apt-get install openmpi-bin (.ci/run does)")
    try:
        import mpi4py  # noqa: F401
    except ImportError:
        pytest.skip("mpi4py not installed: pip install 'vtkillum[mpi]' (.ci/run does)")
    env = dict(os.environ, VTKILLUM_DEVICE="cpu", OMPI_MCA_rmaps_base_oversubscribe="1",
               PYTHONUNBUFFERED="1")
    if hasattr(os, "geteuid") and os.geteuid() == 0:
        env.update(OMPI_ALLOW_RUN_AS_ROOT="1", OMPI_ALLOW_RUN_AS_ROOT_CONFIRM="1")
    command = ["mpirun", "-np", str(ranks), sys.executable, "-m", "pytest", "-q", "-x",
               "-p", "no:cacheprovider", "--color=no", "tests/distributed",
               "--deselect", "tests/distributed/test_launch.py"]
    process = subprocess.Popen(command, cwd=ROOT, env=env, stdout=subprocess.PIPE,
                               stderr=subprocess.STDOUT, text=True, start_new_session=True)
    try:
        out, _ = process.communicate(timeout=900)
    except subprocess.TimeoutExpired:
        os.killpg(process.pid, signal.SIGKILL)  # the whole job: mpirun and its ranks
        out, _ = process.communicate()
        pytest.fail(f"{ranks} ranks did not finish in 900 s:\n{out[-4000:]}")
    assert process.returncode == 0, out[-6000:]
    assert out.count(" passed") >= ranks, out[-3000:]  # every rank ran its tests
