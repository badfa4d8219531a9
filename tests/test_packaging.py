"""The two packages install together; rigjax stays free of torch and learnstitch."""

from __future__ import annotations

import subprocess
import sys


def test_rigjax_never_imports_torch_or_learnstitch():
    code = "import sys, rigjax, rigjax.cli, rigjax.demo; print(sorted(m for m in sys.modules if m.split('.')[0] in ('torch', 'kornia', 'learnstitch')))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


def test_learnstitch_imports_with_its_dependencies():
    code = "import learnstitch, torch, kornia; print(learnstitch.__version__, torch.__version__)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.startswith("0.1.0 ")


def test_console_scripts_are_installed():
    from pathlib import Path

    bindir = Path(sys.executable).parent
    for name in ("rigjax", "learnstitch"):
        done = subprocess.run([str(bindir / name), "--help"], capture_output=True, text=True)
        assert done.returncode == 0 and "usage:" in done.stdout
