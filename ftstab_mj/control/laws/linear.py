"""Linear state feedback with given closed-loop poles, registered as "linear" (the engineer's baseline).

u = -(a_r z_1 + a_{r-1} z_2 + ... + a_1 z_r), where y^r + a_1 y^(r-1) + ... + a_r = prod_i (y - p_i) is
the monic polynomial of the poles p_i (real, < 0, in 1/s): on the nominal chain z_r' = u the closed
loop z' = A z (companion matrix) has exactly these poles. It is Hong's controller at k = 0 with the
gains ``gains_for_polynomial(np.poly(poles))`` (control/hong.py: at k = 0 Hong's law is the linear
backstepping law whose polynomial is the nested one). Convergence is exponential, not in finite time,
so no time bound applies. Lyapunov function: V1 = z^T P z with A^T P + P A = -I (logged with
dV1/dz_r = 2 (P z)_r); on the nominal chain V1' = -|z|^2 <= -V1 / lambda_max(P).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ftstab_mj.control.law import Law, LawOutput, Param, register_law
from ftstab_mj.config.errors import ParameterError


def _poles(v):
    return None if all(p < 0 for p in v) else "real closed-loop poles < 0 (1/s), one per integrator"


def lyapunov_matrix(A):
    """P with A^T P + P A = -I for a Hurwitz A (n, n), from the Kronecker form (n is small)."""
    n = A.shape[0]
    eye = np.eye(n)
    M = np.kron(eye, A.T) + np.kron(A.T, eye)
    P = np.linalg.solve(M, -eye.reshape(-1)).reshape(n, n)
    return 0.5 * (P + P.T)


@register_law
@dataclass(frozen=True)
class LinearLaw(Law):
    """u = -K z with closed-loop poles ``poles`` on the nominal chain; K = (a_r, ..., a_1)."""

    poles: tuple
    name = "linear"
    summary = "linear state feedback u = -K z placing the closed-loop poles (Hong's law at k = 0)"
    params = (Param("poles", tuple[float, ...], "closed-loop poles, real, one per integrator", "1/s", _poles),)
    lyapunov = True
    u_continuous = True
    native_code = 5
    K: np.ndarray = field(init=False, repr=False, compare=False)
    P: np.ndarray = field(init=False, repr=False, compare=False)

    def __post_init__(self):
        poles = tuple(self.poles)
        if not poles:
            raise ParameterError("poles", "one closed-loop pole per integrator", poles)
        for i, p in enumerate(poles):
            if isinstance(p, bool) or not isinstance(p, (int, float, np.integer, np.floating)) or not (np.isfinite(p) and p < 0):
                raise ParameterError(f"poles[{i}]", "a finite real number < 0 (1/s)", p)
        object.__setattr__(self, "poles", tuple(float(p) for p in poles))
        K = np.real(np.poly(self.poles))[1:][::-1].copy()  # (a_r, ..., a_1): the weight of z_1 first
        r = len(poles)
        A = np.eye(r, k=1)
        A[-1] = -K
        for name, arr in (("K", K), ("P", lyapunov_matrix(A))):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @property
    def r(self) -> int:
        return len(self.poles)

    @classmethod
    def from_params(cls, r, values):
        law = cls(values["poles"])
        if law.r != r:
            raise ParameterError("poles", f"{r} poles (one per integrator, r = {r})", law.poles)
        return law

    def native_params(self) -> dict:
        return {"par": (*self.K, *self.P.ravel())}  # K (r,), P (r, r) row-major

    def evaluate(self, z, state=None) -> LawOutput:
        z = np.asarray(z, dtype=float)
        if z.shape[-1:] != (self.r,):
            raise ParameterError("z", f"an array whose last axis has length r = {self.r}", z.shape)
        u = -(z @ self.K)
        Pz = z @ self.P
        one = np.ones(np.shape(u))
        return LawOutput(u, u, np.sum(z * Pz, axis=-1), 2.0 * Pz[..., -1], one, 0.0 * one)
