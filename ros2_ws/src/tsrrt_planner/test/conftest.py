"""Small dense problems run fastest on one BLAS thread (SLSQP's QPs are tiny)."""

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")
