"""Shared fixtures: the warp ``device`` fixture and headless VTK.

Kernel tests take ``device``; they run on ``cpu`` everywhere and also on ``cuda``
where warp sees a GPU. Tests using the fixture are marked ``gpu`` so that the
device machine can run just those (``pytest -m gpu``).
"""

import os

# Headless VTK: must be set before vtk creates its first render window.
os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkOSOpenGLRenderWindow")

import pytest  # noqa: E402


def _devices():
    from vtkillum.core.device import available_devices

    names = available_devices()
    return ["cpu"] + (["cuda:0"] if "cuda:0" in names else [])


def pytest_generate_tests(metafunc):
    if "device" in metafunc.fixturenames:
        only = os.environ.get("VTKILLUM_TEST_DEVICES")
        devices = only.split(",") if only else _devices()
        metafunc.parametrize("device", devices)


def pytest_collection_modifyitems(items):
    for item in items:
        if "device" in getattr(item, "fixturenames", ()):
            item.add_marker(pytest.mark.gpu)


@pytest.fixture
def rng():
    """A seeded numpy generator (tests are deterministic)."""
    import numpy as np

    return np.random.default_rng(12345)
