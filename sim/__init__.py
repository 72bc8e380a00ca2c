"""The solver: scenes, elements, energy terms, Newton, probes (imports without the server stack)."""

import hashlib
import os
import shutil
from pathlib import Path

# numpy's OpenBLAS threads busy-wait after each call (a norm, a dot of the Newton loop) and take
# the two cores from numba's parallel kernels that follow (a Q3T beam evaluation after a norm
# took twice as long as with one BLAS thread). numpy's BLAS work here is vectors and 3x3
# batches, for which one thread is as fast; PARDISO's MKL threads are separate. Read when
# numpy is first imported, and inherited by the solver process the service spawns.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def numba_cache_dir(src: Path) -> str:
    """numba keys a cached kernel on its own file's time stamp only, so a kernel that calls or
    inlines a helper from another module (the elastic kernel inlines the material laws) would
    keep the old helper after an edit, silently. The cache lives in a folder named by a hash of
    every source of the solver instead (sim/apps, which no kernel can reach, left out): any edit
    starts a fresh one. The newest few stay, so a suite still running on the code before an edit
    keeps its kernels; older ones go."""
    h = hashlib.sha1()
    for p in sorted(src.rglob("*.py")):
        rel = p.relative_to(src)
        if rel.parts[0] == "apps":
            continue
        h.update(str(rel).encode())
        h.update(p.read_bytes())
    root = src.parent / ".numba-cache"
    here = root / h.hexdigest()[:12]
    if root.is_dir():
        others = sorted((d for d in root.iterdir() if d != here),
                        key=lambda d: d.stat().st_mtime, reverse=True)
        for old in others[KEEP_CACHES - 1:]:
            shutil.rmtree(old, ignore_errors=True)
    return str(here)


KEEP_CACHES = 3  # this one and the two before it


# an explicit NUMBA_CACHE_DIR wins (q3t bench-service times a cold start in an empty one)
if "NUMBA_CACHE_DIR" not in os.environ:
    try:
        os.environ["NUMBA_CACHE_DIR"] = numba_cache_dir(Path(__file__).resolve().parent)
    except OSError:  # a read-only install: numba's own default (__pycache__) then
        pass
