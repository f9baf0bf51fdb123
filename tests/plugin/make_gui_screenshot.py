"""Regenerate ``docs/images/pv_gui.png``: the ParaView GUI with a vtkIllum filter.

Runs the GUI session of ``test_gui.py`` (Debian's ParaView under ``xvfb-run``) and
keeps its last window grab: a CT-like phantom lit by vtkIllum Light Transmittance,
the filter's Properties panel on the left. Usage, from the project's environment::

    python tests/plugin/make_gui_screenshot.py [OUT_PNG]
"""

import sys
import tempfile
from pathlib import Path

from PIL import Image

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import test_gui


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    target = Path(argv[0]) if argv else HERE.parents[1] / "docs" / "images" / "pv_gui.png"
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "gui"
        out.mkdir()
        status, log = test_gui.run_gui(out, Path(tmp) / "shim")
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
