"""Implicit (backward Euler) discretization of discontinuous control terms (Acary & Brogliato 2010).

Plain NumPy, batched over leading axes (every argument broadcastable to the batch shape ``(...)``).

The explicit sampled law u_k = -K sign(sigma_k) switches at every period once sigma is O(h): this
is numerical chattering, of amplitude K whatever the period. Acary & Brogliato (Systems & Control
Letters 59:284, 2010, section 3) evaluate the set-valued sign at the *next* sample instead,
u_k in -K Sgn(sigma_{k+1}), with sigma_{k+1} predicted from the held-input model
sigma' = a + b u (a, b > 0 known; an unknown disturbance is left out of the prediction). For
sigma_{k+1} = sigma_k + h (a + b u_k) the inclusion has one solution in closed form,

    u_k = -proj_[-K, K]((sigma_k + h a) / (h b))       (:func:`sign_step`),

so sigma reaches a band of width h |unknown part| in finitely many steps and then u equals the
equivalent control (one period late) with no switching, whatever K and h. With an unknown
disturbance d and a gain b_true the one-step map is sigma_{k+1} = (1 - b_true / b) sigma_k + h d:
it contracts for 0 < b_true < 2 b.

Two uses here:

* the robust law (laws/paper.py, ``discretization = "implicit"``): the paper's robust law u = u0 / gamma_m - (phibar / gamma_m) sign(sigma)
  with sigma = z_r - v_{r-1}(z) (sign(u0) = -sign(sigma): u0 = -l_r sig(sig(z_r) - sig(v_{r-1}))),
  whose derivative is sigma' = phi + gamma u - d v_{r-1}/dt. The prediction keeps the known
  continuous part u0 / gamma_m and the nominal gain gamma_m, and leaves phi and d v_{r-1}/dt out:
  w = -proj_[-P, P]((sigma + h u0) / (h gamma_m)), P = phibar / gamma_m, u = u0 / gamma_m + w.
* super-twisting (Brogliato, Polyakov & Efimov 2020, IEEE TAC 65(8):3707): the pair
  s_{k+1} = s_k + h w, w = -k1 sig(s_{k+1}, 1/2) + v_{k+1}, v_{k+1} in v_k - h k2 Sgn(s_{k+1})
  solved exactly (:func:`super_twisting_step`).
"""

from __future__ import annotations

import numpy as np

from ftstab_mj.control.law import Param, one_of
from ftstab_mj.config.errors import ParameterError

DISCRETIZATIONS = ("explicit", "implicit")
DISCRETIZATION = Param("discretization", str, "discretization of the sign term: explicit sign(sigma_k) or "
                       "implicit (Acary-Brogliato: the sign at the predicted next sample)",
                       check=one_of(*DISCRETIZATIONS), default="explicit")


def check_discretization(d) -> str:
    if d not in DISCRETIZATIONS:
        raise ParameterError("discretization", "one of " + ", ".join(repr(x) for x in DISCRETIZATIONS), d)
    return d


def sign_step(sigma, a, K, h, b=1.0):
    """u in -K Sgn(sigma + h (a + b u)), solved: -clip((sigma + h a) / (h b), -K, K). Shapes broadcast."""
    K = np.asarray(K, dtype=float)
    return -np.clip((np.asarray(sigma, dtype=float) + h * np.asarray(a, dtype=float)) / (h * b), -K, K)


def super_twisting_step(s, v, k1, k2, h):
    """One implicit super-twisting period from (s_k, v_k): returns (w, v_{k+1}), shapes (...).

    With m = s_k + h v_k: if |m| <= h^2 k2 then s_{k+1} = 0 and v_{k+1} = -s_k / h; otherwise
    s_{k+1} = sign(m) y^2 with y = (-h k1 + sqrt(h^2 k1^2 + 4 (|m| - h^2 k2))) / 2 (the positive
    root of y^2 + h k1 y = |m| - h^2 k2) and v_{k+1} = v_k - h k2 sign(m). w = (s_{k+1} - s_k) / h.
    """
    s, v = np.broadcast_arrays(np.asarray(s, dtype=float), np.asarray(v, dtype=float))
    m = s + h * v
    excess = np.abs(m) - h * h * k2
    y = 0.5 * (-h * k1 + np.sqrt(h * h * k1 * k1 + 4.0 * np.maximum(excess, 0.0)))
    inside = excess <= 0.0
    s_next = np.where(inside, 0.0, np.sign(m) * y * y)
    v_next = np.where(inside, -s / h, v - h * k2 * np.sign(m))
    return (s_next - s) / h, v_next
