"""Tests that drive Debian's ParaView (pvbatch under xvfb-run): each is marked ``plugin``
and skipped, with the reason, where pvbatch or xvfb-run is missing."""

import json
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


@pytest.fixture(scope="session")
def pvbatch_summary(tmp_path_factory):
    """``run(script, name, summary="summary.json", **options)``: run a pvbatch script once
    into a fresh directory (``pvbatch_env.run_pvbatch_logged`` with ``options``), check that
    it ended well and wrote ``summary``; returns ``(directory, summary dict, log)``."""
    def run(script, name, summary="summary.json", **options):
        out = tmp_path_factory.mktemp(name)
        shim = tmp_path_factory.mktemp("pvshim")
        proc, log = pvbatch_env.run_pvbatch_logged(script, out, shim_dir=shim, **options)
        assert proc.returncode == 0 and (out / summary).exists(), log[-4000:]
        return out, json.loads((out / summary).read_text()), log
    return run
