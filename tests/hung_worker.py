"""A Dask preload that never lets its worker finish starting (a worker process hung while it starts)."""

import threading


def dask_setup(worker) -> None:
    threading.Event().wait()  # for ever: only the nanny's timeout ends it (it kills the process)
