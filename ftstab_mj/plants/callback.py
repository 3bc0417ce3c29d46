"""MuJoCo's control callback slot (one per process): install a callback and always put back the previous one.

The slot is global. A Python callback serves one run only: two simulations stepping at once in one
process (threads, a multi-threaded Dask worker) would each run with the other's callback and record
a wrong trajectory without any error. So :func:`control_callback` claims the slot for the run that
installs its callback, and refuses with :class:`CallbackBusy` to install another run's callback while
one is installed, or to clear the slot from another thread while a run steps.

A *shared* callback (the native kernel's: one C function that finds each call's run from the MjData
it is called with) serves any number of runs: runs installing the same shared callback hold the slot
together, in any threads, and clearing the slot to compile a model is then needless (the C callback
ignores an MjData no run is stepping) and leaves it in place. Code that runs many simulations of
the Python path in one process (the sweep engines) waits for :data:`ONE_RUN` first.

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

_claim = threading.Condition()  # guards the three below; notified when a claim leaves
_owners: list[tuple[object, threading.Thread]] = []  # the runs whose callback is installed, in claim order
_shared = False  # the installed callback serves several runs (the native kernel's)
_previous = None  # the callback installed before the first claim, put back when the last one leaves
_compilers: list[tuple] = []  # (thread, whether it cleared the slot) of each compile block (control_callback(None))


class CallbackBusy(FtstabError, RuntimeError):
    """Another simulation's control callback is installed in this process (one slot per process)."""


_waiting = threading.local()  # .on: this thread waits for the slot instead of being refused
_exclusive_waiters = 0  # threads waiting for the slot to themselves: later shared claims queue behind them


@contextmanager
def waiting_for_slot():
    """In the block, this thread's :func:`control_callback` waits until the slot can be had (the runs
    holding it have left) instead of raising :class:`CallbackBusy`: what an engine running rows on
    several threads of one process uses, so that native runs step at once and a Python-path run
    (or a compile) waits for the slot to itself."""
    before = getattr(_waiting, "on", False)
    _waiting.on = True
    try:
        yield
    finally:
        _waiting.on = before


def slot_owner():
    """The first run (the ``owner`` given to :func:`control_callback`) whose callback is installed, or None."""
    owners = _owners
    return owners[0][0] if owners else None


def holds_slot(run) -> bool:
    """True when ``run``'s callback is installed (alone, or shared with other runs)."""
    return any(o is run for o, _ in list(_owners))


def _busy(what: str, claim) -> CallbackBusy:
    run, thread = claim
    return CallbackBusy(f"cannot {what}: MuJoCo's control callback is one slot per process and another simulation "
                        f"holds it ({type(run).__name__} {id(run):#x}, thread {thread.name!r}); a simulation on the "
                        "Python control path (a law or integrator without a C version, e.g. RK4) needs the slot to "
                        "itself: start it once the other has finished, or in another process (ftstab sweep --engine "
                        "batch or processes does either for you); simulations on the native kernel share the slot")


@contextmanager
def control_callback(callback, owner=None, shared: bool = False):
    """Install ``callback`` (a Python callable (m, d), a ctypes function pointer or None) as MuJoCo's
    control callback for the duration of the block; the previous one is restored even on error.

    ``owner`` (a run, e.g. the Simulation) claims the slot for the block. While a run holds it,
    installing any other callback raises :class:`CallbackBusy` (in any thread), and so does clearing
    the slot (None, to compile a model) from another thread; the run's own thread may clear it.
    ``shared``: ``callback`` serves several runs at once (it finds each call's run itself), so runs
    installing the same shared callback hold the slot together, and clearing it is a no-op meanwhile.
    While another thread compiles (a None block), a Python callback is not installed either.
    """
    global _shared, _previous, _exclusive_waiters
    me = threading.current_thread()
    wait = getattr(_waiting, "on", False)
    compiling = callback is None and owner is None
    with _claim:
        while True:
            install, refusal = _admit(callback, owner, shared, me)
            fair = not (wait and shared and _exclusive_waiters and _owners)  # shared runs queue behind a Python one
            if refusal is None and fair:
                break
            if not wait:
                raise refusal
            exclusive = not shared and not compiling
            _exclusive_waiters += exclusive
            try:
                _claim.wait()
            finally:
                _exclusive_waiters -= exclusive
        if install and owner is not None:
            _previous = mujoco.get_mjcb_control()
            _shared = shared
        if owner is not None:
            _owners.append((owner, me))
        if compiling:
            entry = (me, install)
            _compilers.append(entry)
    try:
        if not install:
            yield
            return
        previous = mujoco.get_mjcb_control()
        mujoco.set_mjcb_control(callback)
        try:
            yield
        finally:
            if owner is None:
                mujoco.set_mjcb_control(previous)
    finally:
        with _claim:
            if owner is not None:
                _owners[:] = [c for c in _owners if c[0] is not owner]
                if not _owners:  # the last run of the slot puts back what was there before the first
                    mujoco.set_mjcb_control(_previous)
                    _previous, _shared = None, False
            if compiling:
                _compilers.remove(entry)
            _claim.notify_all()


def _admit(callback, owner, shared: bool, me) -> tuple[bool, CallbackBusy | None]:
    """(whether to set the slot, the refusal or None) for a claim, under _claim."""
    if callback is None and owner is None:  # a compile
        if _owners and _shared:
            return False, None  # the shared C callback ignores a compile's forward pass: leave it
        if any(t is not me for _, t in _owners):
            return True, _busy("clear the control callback (to compile a model) while another thread's "
                               "simulation runs", _owners[0])
        return mujoco.get_mjcb_control() is not None, None  # an empty slot needs no clearing
    if shared and owner is not None:
        if not _owners:
            if any(t is not me for t, cleared in _compilers if cleared):  # its exit would put back what it cleared
                return True, CallbackBusy("cannot install the native control callback while another thread has "
                                          "cleared MuJoCo's control callback slot to compile a model")
            return True, None
        if _shared and mujoco.get_mjcb_control() is callback:
            return False, None  # another run of the same shared callback
        return True, _busy("install a second simulation's control callback", _owners[0])
    if _owners:
        return True, _busy("install a second simulation's control callback", _owners[0])
    others = [t for t, _ in _compilers if t is not me]
    if others:  # it would be called by the other thread's compile
        return True, CallbackBusy(f"cannot install a control callback: thread {others[0].name!r} is compiling a model "
                                  "with MuJoCo's control callback slot cleared; run one simulation of the Python "
                                  "control path at a time per process")
    return True, None


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


_timer_lock = threading.Lock()
_timer_users = 0  # blocks inside timer_off, in any thread
_timer_previous = None


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
    global _timer_users, _timer_previous
    slot = _timer_slot()
    if slot is None:
        yield
        return
    with _timer_lock:  # counted: runs in several threads overlap, the last one out puts the timer back
        if _timer_users == 0:
            _timer_previous = slot.value
            slot.value = None
        _timer_users += 1
    try:
        yield
    finally:
        with _timer_lock:
            _timer_users -= 1
            if _timer_users == 0:
                slot.value = _timer_previous
