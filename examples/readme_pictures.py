"""Render the README's VTK and pyvista pictures off screen, with the README's own code.

    python examples/readme_pictures.py [--out docs/images]

Runs, in a temporary directory and without a display, the README's
``vtkillum export ... -o head.vti`` command and its two Python blocks that
write ``vtk.png`` (the VTK section: a smoke plume lit by a
``ConvectionDiffusionLightFilter`` through :class:`vtkillum.mappers.IlluminatedVolume`)
and ``pyvista.png`` (the pyvista section: the CT head phantom lit by
``grid.illum.transmittance`` and shown with ``add_illuminated_volume``), exactly as the
README has them (``tests/test_readme.py`` runs every block the same way), and copies
the pictures to ``<out>/readme_vtk.png`` and ``<out>/readme_pyvista.png``.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
#: README picture -> the file it is copied to.
PICTURES = {"vtk.png": "readme_vtk.png", "pyvista.png": "readme_pyvista.png"}


def readme_blocks() -> list[tuple[str, str]]:
    """``(language, code)`` of the README's fenced blocks, in order."""
    text = (ROOT / "README.md").read_text()
    return [(m.group(1), m.group(2)) for m in
            re.finditer(r"^```(\w*)\n(.*?)^```", text, flags=re.DOTALL | re.MULTILINE)]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default=str(ROOT / "docs" / "images"),
                        help="directory for the pictures (default docs/images)")
    opts = parser.parse_args(argv)
    out = Path(opts.out)
    out.mkdir(parents=True, exist_ok=True)
    env = dict(os.environ, VTK_DEFAULT_OPENGL_WINDOW="vtkOSOpenGLRenderWindow",
               PYVISTA_OFF_SCREEN="true",
               PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    env.pop("DISPLAY", None)
    with tempfile.TemporaryDirectory() as tmp:
        bin_dir = Path(tmp) / "bin"  # `vtkillum` is this checkout's command line
        bin_dir.mkdir()
        (bin_dir / "vtkillum").write_text(f'#!/bin/sh\nexec "{sys.executable}" -m vtkillum.cli "$@"\n')
        (bin_dir / "vtkillum").chmod(0o755)
        env["PATH"] = f"{bin_dir}{os.pathsep}{env.get('PATH', '')}"
        for language, code in readme_blocks():
            if language == "bash" and "vtkillum export" in code and "head.vti" in code:
                subprocess.run(["bash", "-euo", "pipefail", "-c", code], cwd=tmp, env=env,
                               check=True)
        for language, code in readme_blocks():
            if language != "python" or not any(f'"{name}"' in code for name in PICTURES):
                continue
            script = Path(tmp) / "block.py"
            script.write_text(code)
            subprocess.run([sys.executable, str(script)], cwd=tmp, env=env, check=True)
        for name, target in PICTURES.items():
            source = Path(tmp) / name
            if not source.exists():
                print(f"the README's code did not write {name}", file=sys.stderr)
                return 1
            shutil.copyfile(source, out / target)
            print(f"wrote {out / target}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
