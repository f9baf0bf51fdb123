"""The README's pvpython block runs as written under pvbatch (Debian's ParaView 5.11).

As the README says: from the repository's root (here: a temporary directory holding a
link to ``paraview_plugin``), with the ``head.vti`` of the README's ``vtkillum export``
command. The block ends in ``SaveScreenshot("paraview.png")``: a lit volume, not blank.
"""

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "paraview_plugin"))
sys.path.insert(0, str(ROOT / "tests"))
import pvbatch_env
from test_readme import blocks


def test_readme_pvpython_block_runs_as_written(tmp_path):
    text = (ROOT / "README.md").read_text()
    code = [c for lang, c in blocks(text) if lang == "python" and "LoadPlugin(" in c]
    export = [c for lang, c in blocks(text)
              if lang == "bash" and "vtkillum export" in c and "head.vti" in c]
    assert len(code) == 1 and len(export) == 1
    (tmp_path / "paraview_plugin").symlink_to(ROOT / "paraview_plugin")
    command = export[0].strip().replace("vtkillum ", f"{sys.executable} -m vtkillum.cli ", 1)
    subprocess.run(command, shell=True, cwd=tmp_path, check=True, capture_output=True,
                   env={**os.environ, "PYTHONPATH": str(ROOT)})
    script = tmp_path / "readme_block.py"
    script.write_text(code[0])
    proc = pvbatch_env.run_pvbatch(script, shim_dir=tmp_path / "shim", timeout=300,
                                   capture_output=True, text=True, cwd=tmp_path)
    log = proc.stdout + proc.stderr
    assert proc.returncode == 0 and "Traceback" not in log, log[-4000:]
    from PIL import Image

    rgb = np.asarray(Image.open(tmp_path / "paraview.png").convert("RGB")).astype(int)
    assert (np.abs(rgb - rgb[0, 0]).max(-1) > 10).mean() > 0.02, "paraview.png is blank"
