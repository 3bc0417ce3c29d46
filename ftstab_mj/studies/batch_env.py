"""The environment of the processes that run many simulations: ``ftstab sweep``, ``compare``, ``montecarlo``.

They run one simulation per worker process and draw no 3-D scene, so their processes get, unless
the environment already sets them:

- ``OPENBLAS_NUM_THREADS=1``: their matrices are r x r with r <= 6, too small for BLAS to thread,
  and N workers with a BLAS thread per core each would oversubscribe the cores; OpenBLAS starting
  its threads costs ~0.05 s of CPU at ``import numpy``.
- ``MUJOCO_GL=disable``: ``import mujoco`` then does not load GLFW (~0.05 s of CPU).

Worker processes inherit both. They must be set before anything imports NumPy or MuJoCo (both
read them once, when they load): the process entry (``ftstab_mj.__main__``) does it first.

A local Dask cluster's workers come from a forkserver that imported what they run once
(:func:`start_forkserver`; why that is safe: ftstab_mj.studies.sweep.engine.local_worker_method). This module
imports nothing heavy, so ``ftstab sweep`` can start the forkserver before its own imports.
"""

import os

# what a worker process runs a row with (MuJoCo, the run loop, the metrics; ftstab_mj.simulation.native loads the
# C kernel), and what a local cluster's worker runs in (distributed; the task's module)
WORKER_MODULES = ("ftstab_mj.metrics.run_metrics", "ftstab_mj.scenario.run", "ftstab_mj.simulation.run_loop", "ftstab_mj.simulation.native")
FORKSERVER_PRELOAD = ("distributed", "ftstab_mj.studies.sweep.row", *WORKER_MODULES)

BATCH_VERBS = ("sweep", "compare", "montecarlo")
BATCH_ENVIRONMENT = {"OPENBLAS_NUM_THREADS": "1", "MUJOCO_GL": "disable"}


def batch_environment(environ=os.environ) -> dict:
    """``environ`` with the defaults of BATCH_ENVIRONMENT where it does not set them (in place; returned)."""
    for name, value in BATCH_ENVIRONMENT.items():
        environ.setdefault(name, value)
    return environ


def start_forkserver() -> bool:
    """Start this process's multiprocessing forkserver with FORKSERVER_PRELOAD imported in it (it imports
    them in its own process, beside this one); False where the platform has no forkserver. A forkserver
    already running is used as it is (Python keeps one per process, and it exits after the process)."""
    import multiprocessing

    if "forkserver" not in multiprocessing.get_all_start_methods():
        return False
    from multiprocessing import forkserver

    multiprocessing.get_context("forkserver").set_forkserver_preload(list(FORKSERVER_PRELOAD))
    forkserver.ensure_running()
    return True
