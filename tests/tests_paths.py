"""Paths the end-to-end tests share (the ccl executable of this environment)."""

import shutil
import sys
from pathlib import Path

CCL = shutil.which("ccl") or str(Path(sys.executable).parent / "ccl")
