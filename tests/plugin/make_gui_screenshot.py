"""Regenerate ``docs/images/pv_gui.png`` (or ``pv_gui_<version>.png``): the ParaView GUI
with a vtkIllum filter.

Runs the GUI session of ``test_gui.py`` (Debian's ParaView under ``xvfb-run``) and
keeps its last window grab: a CT-like phantom lit by vtkIllum Light Transmittance,
the filter's Properties panel on the left. Usage, from the project's environment::

    python tests/plugin/make_gui_screenshot.py [OUT_PNG]
    python tests/plugin/make_gui_screenshot.py --version   # docs/images/pv_gui_5.11.png

``--version`` runs only the CT part of the session (about a minute, no menu clicks) and
names the picture after the ParaView that ``pvpython --version`` reports: the pictures of
``docs/images/pv_gui_<major>.<minor>.png`` come from the host's ParaView 5.11 and from
``.ci/paraview-chroot.sh forky|trixie --run python tests/plugin/make_gui_screenshot.py
--version`` (6.1, 5.13), then copied out of the chroot's checkout.
"""

import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

from PIL import Image

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import test_gui

IMAGES = HERE.parents[1] / "docs" / "images"


def paraview_version() -> str:
    """``major.minor`` of the ParaView on PATH (``pvpython --version``: the GUI's own
    ``--version`` needs an X server)."""
    text = subprocess.run(["pvpython", "--version"], capture_output=True, text=True,
                          timeout=120).stdout
    match = re.search(r"version (\d+)\.(\d+)", text)
    if match is None:
        raise RuntimeError(f"pvpython --version said {text!r}")
    return f"{match[1]}.{match[2]}"


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    only_ct = "--version" in argv
    argv = [a for a in argv if a != "--version"]
    if argv:
        target = Path(argv[0])
    elif only_ct:
        target = IMAGES / f"pv_gui_{paraview_version()}.png"
    else:
        target = IMAGES / "pv_gui.png"
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "gui"
        out.mkdir()
        if only_ct:
            os.environ["VTKILLUM_GUI_ONLY_CT"] = "1"
        status, log = test_gui.run_gui(out, Path(tmp) / "shim",
                                       test_script=None if only_ct else test_gui.MENU_CLICKS)
        grab = out / "window_ct.png"
        if status != 0 or not grab.exists():
            print(log[-3000:])
            return 1
        image = Image.open(grab).convert("RGB")
        width, height = image.size
        image.resize((width * 3 // 4, height * 3 // 4), Image.LANCZOS).save(target, optimize=True)
    print(f"wrote {target}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
