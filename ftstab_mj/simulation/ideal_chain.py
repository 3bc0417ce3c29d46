"""The ideal plant: the perturbed chain z_i' = z_{i+1}, z_r' = phi(t) + gamma(t) u, integrated exactly.

The control u is computed from the sampled state and held over each control period (zero-order
hold). phi and gamma are held over each of ``substeps`` equal sub-intervals of the period (a
MuJoCo plant with Euler holds them over each physics step; matching substeps to the number of
physics steps per period makes the two comparable). With its input piecewise constant the chain
is a linear system, so z(t + h) = Phi(h) z(t) + G(h) w is exact: Phi is the upper-triangular
matrix with entries h^(j-i)/(j-i)! and G_i = h^(r-i+1)/(r-i+1)!.

This is the reference the MuJoCo plants are checked against.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ftstab_mj.simulation import native as native_path
from ftstab_mj.control.laws import advance_phi_hat
from ftstab_mj.plants.disturbances import Signal
from ftstab_mj.config.errors import ParameterError
from ftstab_mj.control.chain import chain_transition


@dataclass
class ChainRun:
    """Samples of a run, one row per control sample k (t_k = k * period).

    Shapes: t (N,); z (N, ..., r) the sampled state; the others (N, ...). ``z_final`` is the
    state after the last period, (..., r).
    """

    t: np.ndarray
    z: np.ndarray
    u: np.ndarray
    u0: np.ndarray
    V1: np.ndarray
    dV1_dzr: np.ndarray
    phi_hat: np.ndarray
    gamma_hat: np.ndarray
    phi: np.ndarray  # true disturbance at the sample instant, chain units
    gamma: np.ndarray  # true gain at the sample instant
    z_final: np.ndarray


def simulate_chain(law, z0, period: float, duration: float, phi: Signal | None = None,
                   gamma: Signal | None = None, substeps: int = 1, phi_hat0=0.0, native=False) -> ChainRun:
    """Run ``law`` on the ideal chain from z0 (r,) or a batch (n, r) for ``duration`` seconds.

    period: control period (s); substeps: sub-intervals per period over which phi and gamma are
    held (>= 1). phi defaults to 0 and gamma to 1. A state-dependent phi (worst case) is evaluated
    with the controller's dV1/dz_r of the current sample.
    native: False runs this NumPy loop (the reference); True | "auto" runs the same computation in
    the C kernel (ftstab_mj.simulation.native), which agrees with it to rounding (a large batch is split over
    the CPUs: native.chain_threads).
    """
    (run,) = simulate_chain_segments(law, z0, period, duration, phi, gamma, substeps, phi_hat0, native, segment=None)
    return run


def simulate_chain_segments(law, z0, period: float, duration: float, phi: Signal | None = None,
                            gamma: Signal | None = None, substeps: int = 1, phi_hat0=0.0, native=False,
                            segment: int | None = 1000):
    """:func:`simulate_chain` as consecutive pieces of at most ``segment`` samples each (None: one piece),
    yielded as ChainRun whose t, z, ... are those samples of the whole run (the same bits), and whose
    z_final is the state after the piece: a caller that reduces each piece as it comes keeps memory
    flat in the duration."""
    if not (period > 0 and np.isfinite(period)):
        raise ParameterError("period", "a finite number > 0 (s)", period)
    if isinstance(substeps, bool) or not isinstance(substeps, (int, np.integer)) or substeps < 1:
        raise ParameterError("substeps", "an integer >= 1", substeps)
    phi = phi or Signal("constant", 0.0)
    gamma = gamma or Signal("constant", 1.0)
    z = np.array(z0, dtype=float)
    n = int(round(duration / period))
    Phi, G = chain_transition(law.hong.r, period / substeps)
    ph = np.broadcast_to(np.asarray(phi_hat0, dtype=float), z.shape[:-1]).copy()
    run_piece = _simulate_chain_native if native_path.use_native(native, law) else _simulate_chain_numpy
    step = max(1, n if segment is None else int(segment))
    for a in range(0, max(n, 1), step):
        t = np.arange(a, min(n, a + step)) * period  # the instants k * period of the whole run, bit for bit
        run, ph = run_piece(law, z, ph, t, period, substeps, Phi, G, phi, gamma)
        z = run.z_final
        yield run


def _simulate_chain_numpy(law, z, ph, t, period, substeps, Phi, G, phi, gamma) -> tuple[ChainRun, np.ndarray]:
    """(the samples at the instants t (n,), phi_hat after them) from state z (..., r), phi_hat ph (...)."""
    n, batch, dt = len(t), z.shape[:-1], period / substeps
    names = ("u", "u0", "V1", "dV1_dzr", "phi_hat", "gamma_hat", "phi", "gamma")
    rec = {k: np.empty((n,) + batch) for k in names}
    zs = np.empty((n,) + z.shape)
    for k in range(n):
        out = law.output(z, ph)
        zs[k] = z
        for name in ("u", "u0", "V1", "dV1_dzr", "phi_hat", "gamma_hat"):
            rec[name][k] = getattr(out, name)
        for s in range(substeps):
            ts = t[k] + s * dt
            w_phi = phi(ts, out.dV1_dzr) if phi.state_dependent else phi(ts)
            w_gam = gamma(ts, out.dV1_dzr) if gamma.state_dependent else gamma(ts)
            if s == 0:
                rec["phi"][k], rec["gamma"][k] = w_phi, w_gam
            z = z @ Phi.T + (w_phi + w_gam * out.u)[..., None] * G
        ph = advance_phi_hat(law, out.V1, ph, period)
    return ChainRun(t=t, z=zs, z_final=z, **rec), ph


def _simulate_chain_native(law, z, ph, t, period, substeps, Phi, G, phi, gamma) -> tuple[ChainRun, np.ndarray]:
    """simulate_chain's loop in the C kernel: same inputs (phi and gamma tabulated at the same
    sub-step instants t_k + s dt), same outputs."""
    batch, r, n = z.shape[:-1], z.shape[-1], len(t)
    t_sub = t[:, None] + np.arange(substeps) * (period / substeps)  # (n, substeps): t[k] + s * dt
    phi_in, phi_table = native_path.chain_input(phi, t_sub)  # the tables must outlive the call
    gam_in, gam_table = native_path.chain_input(gamma, t_sub)
    zf = np.ascontiguousarray(z.reshape(-1, r))
    phf = np.ascontiguousarray(ph.reshape(-1))
    zs, rec = native_path.simulate_chain_kernel(law, zf, phf, n, substeps, period, Phi, G, phi_in, gam_in,
                                                native_path.chain_threads(len(zf)))
    return ChainRun(t=t, z=zs.reshape((n,) + batch + (r,)), z_final=zf.reshape(batch + (r,)),
                    **{k: v.reshape((n,) + batch) for k, v in rec.items()}), phf.reshape(batch)
