"""MuJoCo's control callback slot (one per process): install a callback and always put back the previous one.

Fact (MuJoCo 4.0, checked): while a Python control callback is installed, compiling a model
(MjModel.from_xml_*, MjSpec.compile, MjSpec.to_xml) fails with "engine error: Python exception raised" because the
compiler runs a forward pass that calls it. Compile under ``control_callback(None)``.
"""

from __future__ import annotations

from contextlib import contextmanager

import mujoco


@contextmanager
def control_callback(callback):
    """Install ``callback`` (a Python callable (m, d), a ctypes function pointer or None) as MuJoCo's
    control callback for the duration of the block; the previous one is restored even on error."""
    previous = mujoco.get_mjcb_control()
    mujoco.set_mjcb_control(callback)
    try:
        yield
    finally:
        mujoco.set_mjcb_control(previous)
