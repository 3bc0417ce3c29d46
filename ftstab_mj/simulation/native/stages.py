"""The kernel's copy of a loop's stages (kernel.c ft_stage) and the batched test entry points.

:func:`pack_stages` turns a :class:`~ftstab_mj.simulation.stages.pipeline.LoopStages` into the C struct
(the differentiator's gains and exponents and the lag's decay are computed here, once, so both
paths use the same numbers); :func:`noise_table` draws a batch's sensor noise with the NumPy
sensor model, so the C path reads exactly the noise the Python path draws.
"""

from __future__ import annotations

import ctypes
import math

import numpy as np

from ftstab_mj.simulation import native
from ftstab_mj.simulation.stages.pipeline import LoopStages

OBSMAX = 6  # FT_OBSMAX in kernel.c
_d = ctypes.c_double
_i32 = ctypes.c_int32


class FtStage(ctypes.Structure):
    """Mirror of ft_stage in kernel.c (same field order and types)."""

    _fields_ = [
        ("r", _i32), ("m", _i32), ("delay", _i32), ("observer", _i32), ("order", _i32), ("nf", _i32),
        ("N", _i32), ("pad", _i32),
        ("noise_amp", _d * native.RMAX), ("quantum", _d * native.RMAX),
        ("z_gain", _d * OBSMAX), ("z_pow", _d * OBSMAX), ("w_gain", _d * OBSMAX), ("w_pow", _d * OBSMAX),
        ("u_max", _d), ("rate_max", _d), ("tau", _d), ("dead_zone", _d), ("decay", _d), ("mean", _d), ("h", _d), ("h_tau", _d), ("c_a", _d), ("c_b", _d),
        ("lag_order", _i32), ("pad2", _i32), ("period", _d),
        ("noisy", _i32), ("quantized", _i32), ("noise", ctypes.c_void_p),
    ]


def _lib():
    lib = native.LIB
    if lib is None:
        raise native.NativeUnavailable(f"native stages requested but {native.UNAVAILABLE_REASON}")
    if not hasattr(lib, "_ft_stage_ready"):
        if lib.ft_stage_size() != ctypes.sizeof(FtStage):
            raise native.NativeUnavailable("the C kernel does not match this ftstab_mj version (rebuild it)")
        p = ctypes.c_void_p
        lib.ft_stage_measure.argtypes = [p, ctypes.c_int64, ctypes.c_int64, p, p, p, p]
        lib.ft_stage_measure.restype = None
        lib.ft_stage_actuate.argtypes = [p, ctypes.c_int64, ctypes.c_int64, p, p, p]
        lib.ft_stage_actuate.restype = None
        lib._ft_stage_ready = True
    return lib


def pack_stages(st: LoopStages, physics_step: float) -> FtStage:
    """The kernel's copy of ``st`` for physics steps of ``physics_step`` s (noise table: set per batch)."""
    s, o, a = st.sensor, st.observer, st.actuator
    p = FtStage(r=st.r, m=st.channels, delay=s.delay, observer=int(o is not None), N=st.N, period=st.period)
    p.noisy, p.quantized = int(any(s.noise)), int(any(s.quantum))
    p.noise_amp[:len(s.noise)] = s.noise
    p.quantum[:len(s.quantum)] = s.quantum
    if o is not None:
        p.order, p.nf = o.order, o.filter_order
        p.z_gain[:o.order + 1], p.z_pow[:o.order + 1] = o._z_gain.tolist(), o._z_pow.tolist()
        p.w_gain[:o.filter_order], p.w_pow[:o.filter_order] = o._w_gain.tolist(), o._w_pow.tolist()
    p.u_max, p.rate_max, p.tau, p.dead_zone = a.u_max, a.rate_max, a.tau, a.dead_zone
    p.decay = math.exp(-physics_step / a.tau) if a.tau else 0.0
    if a.tau:  # the constants of ActuatorModel.steps, computed as it computes them
        h = physics_step
        p.mean = a.tau / h * (1.0 - p.decay)
        p.h, p.h_tau, p.c_a, p.c_b = h, h / a.tau, a.tau * (1.0 - p.decay), a.tau * (1.0 - p.decay) - h * p.decay
    p.lag_order = a.lag_order
    return p


def noise_table(st: LoopStages, k0: int, n: int) -> np.ndarray:
    """(n, m) unit noise of samples k0..k0+n-1 of the loop (zeros when the sensor is noiseless)."""
    m = st.channels
    if not any(st.sensor.noise):
        return np.zeros((n, m))
    return st.sensor.noise_table(k0, n, m, st.stream)


def measure(st: LoopStages, k0: int, z: np.ndarray, state: np.ndarray):
    """Native LoopStages.measure over samples k0..k0+n-1 of true states z (n, r); state updated in
    place. Returns (z_measured (n, m), z_hat (n, r))."""
    lib = _lib()
    z = np.ascontiguousarray(z, dtype=float)
    n = len(z)
    p = pack_stages(st, 1.0)
    table = np.ascontiguousarray(noise_table(st, k0, n))
    p.noise = table.ctypes.data
    if state.dtype != np.float64 or not state.flags.c_contiguous or state.size < st.state_size:
        raise ValueError(f"state: expected a contiguous float64 array of {st.state_size}, got {state.shape}")
    zm, zh = np.empty((n, st.channels)), np.empty((n, st.r))
    lib.ft_stage_measure(ctypes.byref(p), int(k0), n, z.ctypes.data, state.ctypes.data, zm.ctypes.data,
                         zh.ctypes.data)
    return zm, zh


def actuate(st: LoopStages, k0: int, u: np.ndarray, state: np.ndarray, physics_step: float) -> np.ndarray:
    """Native LoopStages.actuate over samples k0..: u (n,) -> the plant's input per step (n, N)."""
    lib = _lib()
    u = np.ascontiguousarray(u, dtype=float)
    p = pack_stages(st, physics_step)
    if state.dtype != np.float64 or not state.flags.c_contiguous or state.size < st.state_size:
        raise ValueError(f"state: expected a contiguous float64 array of {st.state_size}, got {state.shape}")
    steps = np.empty((len(u), st.N))
    lib.ft_stage_actuate(ctypes.byref(p), int(k0), len(u), u.ctypes.data, state.ctypes.data, steps.ctypes.data)
    return steps
