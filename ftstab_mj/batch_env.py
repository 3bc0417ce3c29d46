"""The environment of the processes that run many simulations: ``ftstab sweep``, ``compare``, ``montecarlo``.

They run one simulation per worker process and draw no 3-D scene, so their processes get, unless
the environment already sets them:

- ``OPENBLAS_NUM_THREADS=1``: their matrices are r x r with r <= 6, too small for BLAS to thread,
  and N workers with a BLAS thread per core each would oversubscribe the cores; OpenBLAS starting
  its threads costs ~0.05 s of CPU at ``import numpy``.
- ``MUJOCO_GL=disable``: ``import mujoco`` then does not load GLFW (~0.05 s of CPU).

Worker processes inherit both. They must be set before anything imports NumPy or MuJoCo (both
read them once, when they load): the process entry (``ftstab_mj.__main__``) does it first.
"""

import os

BATCH_VERBS = ("sweep", "compare", "montecarlo")
BATCH_ENVIRONMENT = {"OPENBLAS_NUM_THREADS": "1", "MUJOCO_GL": "disable"}


def batch_environment(environ=os.environ) -> dict:
    """``environ`` with the defaults of BATCH_ENVIRONMENT where it does not set them (in place; returned)."""
    for name, value in BATCH_ENVIRONMENT.items():
        environ.setdefault(name, value)
    return environ
