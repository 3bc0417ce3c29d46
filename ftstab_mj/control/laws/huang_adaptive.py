"""Adaptive sliding mode with a gain that never decreases, registered as "huang_adaptive".

Huang, Kuo and Chang, "Adaptive sliding-mode control for nonlinear systems with uncertain parameters",
IEEE Trans. Systems, Man, and Cybernetics B 38(2):534-539, 2008 (their adaptive switching gain; equation
numbers not quoted here). On the surface
s = z_r + sum_{i<r} c_i z_i (the known drift a(z) = sum c_i z_{i+1} cancelled, as for the other
surface laws):

    u = -a(z) - K sign(s),      K' = Kbar |s|,      K(0) = K0 >= 0

K grows as long as s != 0 and never decreases: it stops growing only on an ideal sliding mode
s = 0. Sampled, |s| stays O(h) after the reaching phase, so K keeps growing (at about Kbar times the
mean |s|): the over-estimation that Plestan et al. 2010 ("plestan_adaptive") and the paper's adaptive
law correct by letting the gain decrease inside a band. The Lyapunov argument (V = s^2/2 +
(K - K*)^2 / (2 Kbar) with K* > |phi|) gives s -> 0 and K bounded in continuous time only.

State (K,), K(0) = ``K0``; phi_hat = K is logged (the disturbance-bound estimate, as
"plestan_adaptive"), gamma_hat = 1; no Lyapunov function is logged. K' is held over the period
(explicit Euler, exact with s held).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ftstab_mj.control.law import Law, LawOutput, Param, non_negative, register_law
from ftstab_mj.control.laws.adaptive_super_twisting import sliding_variable
from ftstab_mj.control.laws.sliding_surface import SURFACE, PlestanAdaptive, surface_coefficients
from ftstab_mj.control.laws.terminal import positive_number
from ftstab_mj.config.errors import ParameterError

KBAR = next(p for p in PlestanAdaptive.params if p.name == "Kbar")  # one key, one meaning


@register_law
@dataclass(frozen=True)
class HuangAdaptive(Law):
    """u = -a(z) - K sign s, K' = Kbar |s| (module docstring). State (K,)."""

    r: int
    surface: tuple
    Kbar: float
    K0: float = 0.0
    name = "huang_adaptive"
    native_code = 13
    summary = ("adaptive sliding mode whose gain never decreases, u = -K sign s, K' = Kbar |s| "
               "(Huang, Kuo, Chang 2008, IEEE TSMC-B 38:534)")
    params = (
        SURFACE,
        KBAR,
        Param("K0", float, "K(0), the initial switching gain", "chain units, m/s^r or rad/s^r", non_negative, default=0.0),
    )

    def __post_init__(self):
        object.__setattr__(self, "surface", surface_coefficients(self.surface, self.r))
        object.__setattr__(self, "Kbar", positive_number("Kbar", self.Kbar))
        K0 = self.K0
        if isinstance(K0, bool) or not isinstance(K0, (int, float, np.integer, np.floating)) or not (
                np.isfinite(K0) and K0 >= 0):
            raise ParameterError("K0", "a finite number >= 0", K0)
        object.__setattr__(self, "K0", float(K0))

    @classmethod
    def from_params(cls, r, values):
        return cls(r, values["surface"], values["Kbar"], values["K0"])

    @property
    def state_size(self) -> int:
        return 1

    def initial_state(self):
        return np.array([self.K0])

    def evaluate(self, z, state) -> LawOutput:
        K = np.asarray(state, dtype=float)[..., 0]
        s, a = sliding_variable(self.surface, z)
        u = -a - K * np.sign(s)
        nan = np.full(np.shape(u), np.nan)
        return LawOutput(u, nan, nan, nan, np.ones(np.shape(u)), K + 0.0 * u)

    def state_derivative(self, z, state, out):
        s, _ = sliding_variable(self.surface, z)
        return (self.Kbar * np.abs(s))[..., None]

    def param_values(self) -> dict:
        return {"surface": list(self.surface), "Kbar": self.Kbar, "K0": self.K0}

    def native_params(self) -> dict:
        return {"par": (self.Kbar, *self.surface)}
