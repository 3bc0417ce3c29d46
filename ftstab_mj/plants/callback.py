"""MuJoCo's control callback slot (one per process): install a callback and always put back the previous one.

One run at a time. The slot is global (so is the native kernel's active run): two simulations
stepping at once in one process (threads, a multi-threaded Dask worker) would each run with the
other's callback and record a wrong trajectory without any error. So :func:`control_callback`
claims the slot for the run that installs its callback, and refuses with :class:`CallbackBusy`
to install another run's callback while one is installed, or to clear the slot from another
thread while a run steps. Code that must run many simulations in one process (the sweep engines)
waits for :data:`ONE_RUN` first.

Fact (MuJoCo 4.0, checked): while a Python control callback is installed, compiling a model
(MjModel.from_xml_*, MjSpec.compile, MjSpec.to_xml) fails with "engine error: Python exception raised" because the
compiler runs a forward pass that calls it. Compile under ``control_callback(None)``.
"""

from __future__ import annotations

import functools
import threading
from contextlib import contextmanager

import mujoco

from ftstab_mj.config.errors import FtstabError

# Held for a whole run by the code that runs several simulations in one process (sweep engines), so
# that a second thread waits for the first run instead of being refused.
ONE_RUN = threading.RLock()

_claim = threading.Lock()  # guards _owner
_owner: tuple[object, threading.Thread] | None = None  # (run, thread) whose callback is installed


class CallbackBusy(FtstabError, RuntimeError):
    """Another simulation's control callback is installed in this process (one slot per process)."""


def slot_owner():
    """The run (the ``owner`` given to :func:`control_callback`) whose callback is installed, or None."""
    claim = _owner
    return None if claim is None else claim[0]


def _busy(what: str, claim) -> CallbackBusy:
    run, thread = claim
    return CallbackBusy(f"cannot {what}: MuJoCo's control callback is one slot per process and the callback of "
                        f"{type(run).__name__} {id(run):#x} (thread {thread.name!r}) is installed; run one "
                        "simulation at a time per process (threads share the slot: use processes, or Dask "
                        "workers with --nthreads 1)")


@contextmanager
def control_callback(callback, owner=None):
    """Install ``callback`` (a Python callable (m, d), a ctypes function pointer or None) as MuJoCo's
    control callback for the duration of the block; the previous one is restored even on error.

    ``owner`` (a run, e.g. the Simulation) claims the slot for the block. While a run holds it,
    installing any other callback raises :class:`CallbackBusy` (in any thread), and so does clearing
    the slot (None, to compile a model) from another thread; the run's own thread may clear it.
    """
    global _owner
    me = threading.current_thread()
    with _claim:
        claim = _owner
        if claim is not None and (callback is not None or claim[1] is not me):
            raise _busy("install a second simulation's control callback" if callback is not None else
                        "clear the control callback (to compile a model) while another thread's simulation runs",
                        claim)
        if owner is not None:
            _owner = (owner, me)
    try:
        previous = mujoco.get_mjcb_control()
        mujoco.set_mjcb_control(callback)
        try:
            yield
        finally:
            mujoco.set_mjcb_control(previous)
    finally:
        if owner is not None:
            with _claim:
                _owner = None


@functools.lru_cache(maxsize=None)
def _timer_slot():
    """ctypes view of MuJoCo's global ``mjcb_time`` pointer (in the library the bindings loaded);
    found once per process (the glob and the library look-up cost ~0.4 ms)."""
    import ctypes
    import glob
    import os

    libs = sorted(glob.glob(os.path.join(os.path.dirname(mujoco.__file__), "libmujoco.so*")) +
                  glob.glob(os.path.join(os.path.dirname(mujoco.__file__), "libmujoco*.dylib")))
    if not libs:
        return None
    try:
        return ctypes.c_void_p.in_dll(ctypes.CDLL(libs[0]), "mjcb_time")
    except (OSError, ValueError):
        return None


@contextmanager
def timer_off():
    """No profiling timer for the block: MuJoCo's ``mjcb_time`` is NULL, and put back afterwards.

    Fact (MuJoCo 4.0 Python bindings, checked): importing ``mujoco`` installs a C timer in
    ``mjcb_time`` that every step calls 30-odd times to fill ``d.timer``; it costs half of a bare
    step of the cart (1.26 -> 0.64 us). ``mujoco.set_mjcb_time(None)`` does not remove it (it puts
    the bindings' default back) and ``get_mjcb_time()`` returns None while it is installed, so the
    pointer is set through ctypes. ftstab never reads ``d.timer``. Where the library cannot be
    found, nothing changes (the run is only slower).
    """
    slot = _timer_slot()
    if slot is None:
        yield
        return
    previous = slot.value
    slot.value = None
    try:
        yield
    finally:
        slot.value = previous
