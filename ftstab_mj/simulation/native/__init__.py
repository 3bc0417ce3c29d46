"""The native (C) twin of the controller maths, loaded with ctypes, and the choice between the two.

The C kernel (kernel.c) is built by ``pip install`` as an optional extension. When it is missing
(no compiler at install time, or a source checkout never built: ``python setup.py build_ext
--inplace``), everything runs on the pure NumPy reference and :func:`use_native` says so once on
stderr. The NumPy code in ftstab_mj/control/ stays the reference: tests check that both agree.

Choice of path everywhere (``native=`` arguments): True (native, error if unavailable), False
(pure NumPy), "auto" (native when available, else pure).
"""

from __future__ import annotations

import ctypes
import importlib.util
import os
import sys

import numpy as np

from ftstab_mj.control.law import LawOutput
from ftstab_mj.config.errors import FtstabError, ParameterError

RMAX = 8  # longest chain the kernel handles (FT_RMAX in laws.h)
MAXSTATE = 4  # numbers of state a law may keep (FT_MAXSTATE)
NPAR = RMAX + RMAX * RMAX  # FT_NPAR
RK4_SUBSTEPS = 8  # advance_phi_hat's default number of sub-steps in the transition band

_dbl = ctypes.POINTER(ctypes.c_double)


class NativeUnavailable(FtstabError, RuntimeError):
    """native=True was asked for but the kernel is not built (or cannot take this law)."""


class FtLaw(ctypes.Structure):
    """Mirror of ft_law in laws.h (same field order and types)."""

    _fields_ = [
        ("r", ctypes.c_int32), ("simplified", ctypes.c_int32), ("law", ctypes.c_int32), ("substeps", ctypes.c_int32),
        ("gains", ctypes.c_double * RMAX), ("beta", ctypes.c_double * RMAX), ("expo", ctypes.c_double * RMAX),
        ("phibar", ctypes.c_double), ("gamma_m", ctypes.c_double),
        ("kappa", ctypes.c_double), ("delta", ctypes.c_double), ("rate", ctypes.c_double),
        ("eta", ctypes.c_double), ("eps", ctypes.c_double),
        ("nstate", ctypes.c_int32), ("implicit", ctypes.c_int32), ("period", ctypes.c_double),
        ("par", ctypes.c_double * NPAR),
    ]


class FtInput(ctypes.Structure):
    """Mirror of ft_input: a table of values (one per sub-step), or (values NULL) a state-dependent
    signal by its values for dV1/dz_r > 0, < 0 and = 0."""

    _fields_ = [("values", _dbl), ("if_pos", ctypes.c_double), ("if_neg", ctypes.c_double),
                ("if_zero", ctypes.c_double)]


def _find_library() -> tuple[ctypes.CDLL | None, str]:
    spec = importlib.util.find_spec("ftstab_mj.simulation.native._kernel")
    if spec is None or not spec.origin:
        return None, "the C kernel was not built at install time (no working C compiler?)"
    try:
        lib = ctypes.CDLL(spec.origin)
    except OSError as e:
        return None, f"the C kernel {spec.origin} cannot be loaded: {e}"
    if lib.ft_law_size() != ctypes.sizeof(FtLaw) or lib.ft_rmax() != RMAX:
        return None, f"the C kernel {spec.origin} does not match this ftstab_mj version (rebuild it)"
    p = ctypes.c_void_p
    lib.ft_law_output.argtypes = [p, ctypes.c_int64, p, p, p, p, p, p, p, p]
    lib.ft_law_output.restype = None
    lib.ft_advance_phi_hat.argtypes = [p, ctypes.c_int64, p, p, ctypes.c_double, p]
    lib.ft_advance_phi_hat.restype = None
    lib.ft_simulate_chain.argtypes = [p, ctypes.c_int64, p, p, ctypes.c_int64, ctypes.c_int32, ctypes.c_double,
                                      p, p, p, p, p, p, ctypes.c_int32]
    lib.ft_simulate_chain.restype = None
    lib.ft_law_sample.argtypes = [p, ctypes.c_int64, p, p, ctypes.c_double, p]
    lib.ft_law_sample.restype = None
    return lib, ""


LIB, UNAVAILABLE_REASON = _find_library()
_told = False


def available() -> bool:
    """True when the C kernel is built and loadable."""
    return LIB is not None


def use_native(native, law=None) -> bool:
    """Resolve a ``native=`` choice (True | False | "auto") for ``law`` (None: any law).

    "auto" falls back to the pure path when the kernel is missing (one line on stderr, once per
    process) or cannot take the law (r > RMAX, a law type it does not know). True raises
    :class:`NativeUnavailable` in those cases.
    """
    global _told
    if native is False:
        return False
    if native not in (True, "auto"):
        raise ParameterError("native", 'True, False or "auto"', native)
    reason = UNAVAILABLE_REASON if LIB is None else (_unsupported(law) if law is not None else "")
    if not reason:
        return True
    if native is True:
        raise NativeUnavailable(f"native controller requested but {reason}")
    if LIB is None and not _told:
        _told = True
        print(f"ftstab: {reason}; using the pure NumPy controller (slower)", file=sys.stderr)
    return False


def _unsupported(law) -> str:
    # the class itself must declare its twin: a subclass overriding the maths is not the C code's
    if type(law).__dict__.get("native_code") is None:
        return f"the C kernel does not know the law type {type(law).__name__}"
    if law.r > RMAX:
        return f"the C kernel handles r <= {RMAX}, got r = {law.r}"
    if law.state_size > MAXSTATE:
        return f"the C kernel keeps at most {MAXSTATE} numbers of state per law, {law.name!r} has {law.state_size}"
    return ""


_ARRAYS = {name for name, kind in FtLaw._fields_ if issubclass(kind, ctypes.Array)}


def pack_law(law, substeps: int = RK4_SUBSTEPS) -> FtLaw:
    """The kernel's copy of ``law``: its declared ``native_code`` and ``native_params()`` (FtLaw fields
    by name, numbers computed once in Python, so both paths share them: Hong's exponents, Levant's)."""
    why = _unsupported(law)
    if why:
        raise NativeUnavailable(why)
    p = FtLaw(r=law.r, law=law.native_code, substeps=substeps, nstate=law.state_size,
              implicit=int(getattr(law, "discretization", "explicit") == "implicit"),
              period=getattr(law, "period", None) or 0.0)
    for name, value in law.native_params().items():
        if name not in FtLaw.__dict__:  # a ctypes Structure would silently keep an unknown attribute
            raise NativeUnavailable(f"the C kernel's law record has no field {name!r} (law {law.name!r})")
        if name in _ARRAYS:
            values = [float(v) for v in np.ravel(value)]
            if len(values) > len(getattr(p, name)):
                raise NativeUnavailable(f"law {law.name!r}: {len(values)} numbers for the kernel's {name!r}, "
                                        f"which holds {len(getattr(p, name))}")
            getattr(p, name)[: len(values)] = values
        else:
            setattr(p, name, value)
    if p.implicit and not p.period > 0.0:
        raise NativeUnavailable(f"law {law.name!r}: the implicit discretization needs the control period "
                                "(law.for_period(h))")
    return p


def _require():
    if LIB is None:
        raise NativeUnavailable(f"native controller requested but {UNAVAILABLE_REASON}")
    return LIB


def _c(a: np.ndarray) -> int:
    return a.ctypes.data


def law_output(law, z, phi_hat=0.0) -> LawOutput:
    """Native ``law.output(z, phi_hat)``: z (..., r), phi_hat broadcastable to (...). Fields (...)."""
    lib = _require()
    z = np.ascontiguousarray(z, dtype=float)
    if z.shape[-1:] != (law.hong.r,):
        raise ParameterError("z", f"an array whose last axis has length r = {law.hong.r}", z.shape)
    batch = z.shape[:-1]
    ph = np.ascontiguousarray(np.broadcast_to(np.asarray(phi_hat, dtype=float), batch))
    out = [np.empty(batch) for _ in LawOutput._fields]
    p = pack_law(law)
    lib.ft_law_output(ctypes.byref(p), int(np.prod(batch, dtype=np.int64)), _c(z), _c(ph), *map(_c, out))
    return LawOutput(*out)


def law_sample(law, z, state, h: float) -> tuple[LawOutput, np.ndarray]:
    """Native ``law.evaluate(z, state)`` and ``law.advance(z, state, out, h)`` for a batch: z (n, r),
    state (n, state_size). Returns (LawOutput with fields (n,), the state one period h later (n, state_size))."""
    lib = _require()
    p = pack_law(law)
    z = np.ascontiguousarray(z, dtype=float)
    n = len(z)
    if z.shape != (n, law.r):
        raise ParameterError("z", f"an array (n, r = {law.r})", z.shape)
    state = np.array(np.broadcast_to(np.asarray(state, dtype=float), (n, law.state_size)), dtype=float, order="C")
    out = [np.empty(n) for _ in LawOutput._fields]
    ptrs = (ctypes.c_void_p * 6)(*map(_c, out))
    lib.ft_law_sample(ctypes.byref(p), n, _c(z), _c(state), float(h), ptrs)
    return LawOutput(*out), state


def advance_phi_hat(law, V1, phi_hat, h: float, substeps: int = RK4_SUBSTEPS) -> np.ndarray:
    """Native :func:`ftstab_mj.control.advance_phi_hat`; shapes (...) broadcast together."""
    lib = _require()
    V1, ph = (np.ascontiguousarray(a, dtype=float) for a in np.broadcast_arrays(V1, phi_hat))
    out = np.empty(V1.shape)
    p = pack_law(law, substeps)
    lib.ft_advance_phi_hat(ctypes.byref(p), V1.size, _c(V1), _c(ph), float(h), _c(out))
    return out


def chain_input(signal, t_sub: np.ndarray) -> tuple[FtInput, np.ndarray | None]:
    """The kernel's view of a Signal over the sub-step instants t_sub (nsteps, substeps): a table of
    its values, or for a state-dependent signal (a function of sign(dV1/dz_r) only) its three
    values. Returns the struct and the array it points into (keep it alive while the struct is used)."""
    if signal.state_dependent:
        return FtInput(None, *(float(signal(0.0, s)) for s in (1.0, -1.0, 0.0))), None
    values = np.ascontiguousarray(signal(t_sub), dtype=float)
    return FtInput(values.ctypes.data_as(_dbl), 0.0, 0.0), values


def chain_threads(n_traj: int) -> int:
    """Threads for a batch of n_traj trajectories: the CPUs this process may use, one per 64
    trajectories at most (a thread costs ~50 us to start). The result does not depend on it."""
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        cpus = os.cpu_count() or 1
    return max(1, min(cpus, n_traj // 64))


def require_buffer(name: str, a, shape: tuple) -> None:
    """The C side writes ``a`` as a C-contiguous float64 block of ``shape``: anything else is a
    ValueError here (a raised check, kept under ``python -O``), never a write out of bounds."""
    if not isinstance(a, np.ndarray) or a.dtype != np.float64 or not a.flags.c_contiguous or not a.flags.writeable:
        what = type(a).__name__ if not isinstance(a, np.ndarray) else (
            f"{a.dtype}, {'C-contiguous' if a.flags.c_contiguous else 'not C-contiguous'}"
            f"{'' if a.flags.writeable else ', read-only'}")
        raise ValueError(f"native buffer {name}: expected a writable C-contiguous float64 array, got {what}")
    if a.shape != tuple(shape):
        raise ValueError(f"native buffer {name}: expected shape {tuple(shape)}, got {a.shape}")


def simulate_chain_kernel(law, z: np.ndarray, phi_hat: np.ndarray, nsteps: int, substeps: int, period: float,
                          Phi: np.ndarray, G: np.ndarray, phi_in: FtInput, gam_in: FtInput, threads: int = 1):
    """Run the ideal chain in C (see ideal_chain.simulate_chain, which prepares the arguments).

    z (n, r) and phi_hat (n,) are advanced in place to the final state. Returns (zs (nsteps, n, r),
    {field: (nsteps, n)}) for the fields u, u0, V1, dV1_dzr, phi_hat, gamma_hat, phi, gamma.
    threads: trajectories are split over that many threads (POSIX; the result is the same).
    """
    lib = _require()

    n, r = z.shape
    require_buffer("z", z, (n, law.r))  # advanced in place by the C code
    require_buffer("phi_hat", phi_hat, (n,))
    zs = np.empty((nsteps, n, r))
    names = ("u", "u0", "V1", "dV1_dzr", "phi_hat", "gamma_hat", "phi", "gamma")
    rec = {k: np.empty((nsteps, n)) for k in names}
    ptrs = (ctypes.c_void_p * 8)(*(_c(rec[k]) for k in names))
    p = pack_law(law)
    Phi, G = np.ascontiguousarray(Phi, dtype=float), np.ascontiguousarray(G, dtype=float)
    lib.ft_simulate_chain(ctypes.byref(p), n, _c(z), _c(phi_hat), nsteps, substeps, float(period), _c(Phi),
                          _c(G), ctypes.byref(phi_in), ctypes.byref(gam_in), _c(zs), ptrs, int(threads))
    return zs, rec
