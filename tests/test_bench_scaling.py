"""``benchmarks/bench_scaling.py --small`` runs on the CPU and prints its tables (shape only:
tests never assert on time)."""

import json
import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_small_run_prints_one_table_per_method(tmp_path):
    out = tmp_path / "rows.json"
    env = dict(os.environ, VTKILLUM_DEVICE="cpu")
    proc = subprocess.run(
        [sys.executable, str(ROOT / "benchmarks" / "bench_scaling.py"), "--small", "--device",
         "cpu", "--methods", "emission", "transmittance", "--json", str(out)],
        check=False, capture_output=True, text=True, timeout=600, env=env, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr[-2000:]
    text = proc.stdout
    for method in ("emission", "transmittance"):
        assert f"### {method} — cpu" in text
    rows = [line for line in text.splitlines() if line.startswith("| ") and "³ |" in line]
    steps = ("first image", "camera move", "TF edit", "light move")
    body = [r for r in rows if any(f"| {s} |" in r for s in steps)]
    assert len(body) == 2 * 3 * 4  # methods x sizes (16, 24, 32) x steps
    for r in body:
        cells = [c.strip() for c in r.strip("|").split("|")]
        assert len(cells) == 7
        assert cells[0] in ("16³", "24³", "32³")
        float(cells[2])  # whole call, ms
        float(cells[3])  # both methods report their device time
        assert float(cells[4]) >= 0 and float(cells[5]) > 0  # peak and estimate, MiB
    assert text.count("time ∝ voxels^") == 2
    assert "### largest volume on this device" in text
    assert "| transmittance |" in text.split("### largest volume")[1]
    data = json.loads(out.read_text())
    measured = [r for r in data["rows"] if "step" in r]
    assert len(measured) == 24
    assert all(r["peak_bytes"] is not None and r["estimate_bytes"] > 0 for r in measured)
