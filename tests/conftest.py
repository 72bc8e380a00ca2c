import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))
os.environ.setdefault("XDG_CONFIG_HOME", "/tmp/q3t-test-config")

import sim  # noqa: E402,F401  (before numpy: the BLAS thread setting of sim/__init__.py)
