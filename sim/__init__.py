"""The solver: scenes, elements, energy terms, Newton, probes (imports without the server stack)."""

import os

# numpy's OpenBLAS threads busy-wait after each call (a norm, a dot of the Newton loop) and take
# the two cores from numba's parallel kernels that follow: a Q3T beam evaluation measured 13.2 ms
# after a norm against 6.7 ms with one BLAS thread. numpy's BLAS work here is vectors and 3x3
# batches, for which one thread is as fast; PARDISO's MKL threads are separate. Read when
# numpy is first imported, and inherited by the solver process the service spawns.
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
