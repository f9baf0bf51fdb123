"""Device choice: explicit argument, then VTKILLUM_DEVICE, then CUDA when present."""

import numpy as np
import pytest
import warp as wp

from vtkillum.core.device import available_devices, resolve_device
from vtkillum.core.warp_common import to_device


def test_explicit_cpu_and_auto(monkeypatch):
    monkeypatch.delenv("VTKILLUM_DEVICE", raising=False)
    assert resolve_device("cpu") == "cpu"
    expected = "cuda:0" if "cuda:0" in available_devices() else "cpu"
    assert resolve_device(None) == expected == resolve_device("auto")


def test_environment_variable_overrides_default(monkeypatch):
    monkeypatch.setenv("VTKILLUM_DEVICE", "cpu")
    assert resolve_device() == "cpu"
    monkeypatch.setenv("VTKILLUM_DEVICE", "tpu")
    with pytest.raises(ValueError, match="VTKILLUM_DEVICE"):
        resolve_device()


def test_unknown_device_names_what_exists():
    with pytest.raises(ValueError, match="not available"):
        resolve_device("cuda:7")


def test_allocation_failure_says_what_to_do(monkeypatch):
    def fail(*args, **kwargs):
        raise RuntimeError("Failed to allocate")

    monkeypatch.setattr(wp, "array", fail)
    with pytest.raises(MemoryError, match="downsample"):
        to_device(np.zeros((4, 4, 4), np.float32), wp.float32, "cpu")


@pytest.mark.parametrize("value", ["", "  ", "auto", "AUTO"])
def test_empty_environment_variable_means_automatic(monkeypatch, value):
    """Issue 15 row 10: ``VTKILLUM_DEVICE=`` failed with "device '' is not available"."""
    monkeypatch.setenv("VTKILLUM_DEVICE", value)
    expected = "cuda:0" if "cuda:0" in available_devices() else "cpu"
    assert resolve_device() == expected == resolve_device("")


def test_available_memory_reports_the_address_space_limit():
    """The CLI's memory check: ``ulimit -v`` is seen (Linux)."""
    import subprocess
    import sys

    if not sys.platform.startswith("linux"):
        pytest.skip("Linux /proc")
    from vtkillum.core.device import available_memory

    host, gpu = available_memory("cpu")
    assert gpu is None and (host is None or host > 0)
    code = ("from vtkillum.core.device import _host_available as h; print(h())")
    import os
    from pathlib import Path

    root = str(Path(__file__).resolve().parents[2])
    env = dict(os.environ, PYTHONPATH=root + os.pathsep + os.environ.get("PYTHONPATH", ""),
               CUDA_VISIBLE_DEVICES="")
    out = subprocess.run(["bash", "-c", f"ulimit -v 3000000; exec {sys.executable} -c '{code}'"],
                         capture_output=True, text=True, timeout=60, env=env)
    assert 0 < int(out.stdout.split()[-1]) < 3000000 * 1024
