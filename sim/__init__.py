"""The solver: scenes, elements, energy terms, Newton, probes (imports without the server stack)."""

import hashlib
import os
import shutil
from pathlib import Path

# numpy's OpenBLAS threads busy-wait after each call (a norm, a dot of the Newton loop) and take
# the two cores from numba's parallel kernels that follow: a Q3T beam evaluation measured 13.2 ms
# after a norm against 6.7 ms with one BLAS thread. numpy's BLAS work here is vectors and 3x3
# batches, for which one thread is as fast; PARDISO's MKL threads are separate. Read when
# numpy is first imported, and inherited by the solver process the service spawns.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def _numba_cache_dir() -> str:
    """numba keys a cached kernel on its own file's time stamp only, so a kernel that calls or
    inlines a helper from another module (the elastic kernel inlines the material laws) would
    keep the old helper after an edit, silently. The cache lives in a folder named by a hash of
    every source of this package instead: any edit starts a fresh one, and the stale ones go."""
    src = Path(__file__).resolve().parent
    h = hashlib.sha1()
    for p in sorted(src.rglob("*.py")):
        h.update(str(p.relative_to(src)).encode())
        h.update(p.read_bytes())
    root = src.parent / ".numba-cache"
    here = root / h.hexdigest()[:12]
    if root.is_dir():
        for old in root.iterdir():
            if old != here:
                shutil.rmtree(old, ignore_errors=True)
    return str(here)


# an explicit NUMBA_CACHE_DIR wins (q3t bench-service times a cold start in an empty one)
if "NUMBA_CACHE_DIR" not in os.environ:
    try:
        os.environ["NUMBA_CACHE_DIR"] = _numba_cache_dir()
    except OSError:  # a read-only install: numba's own default (__pycache__) then
        pass
