"""Tests that drive Debian's ParaView (pvbatch under xvfb-run): each is marked ``plugin``
and skipped, with the reason, where pvbatch or xvfb-run is missing."""

import sys
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parents[1] / "paraview_plugin"))
import pvbatch_env


def pytest_collection_modifyitems(config, items):
    missing = pvbatch_env.missing_tools()
    for item in items:
        if HERE in Path(str(item.fspath)).resolve().parents:
            item.add_marker(pytest.mark.plugin)
            if missing:
                item.add_marker(pytest.mark.skip(
                    reason=f"{', '.join(missing)} not found: the plugin tests need Debian's "
                           "ParaView (pvbatch) and xvfb-run"))
