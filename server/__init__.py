"""The forming preview service: FastAPI server, solver worker process, viewer and recordings."""

import sim  # noqa: F401  (first: it sets numpy's BLAS threads before numpy is loaded)
