"""The Lyapunov certificate of Theorem 1 and the bounds of Theorem 3 (NOTES.md sections 5-6).

For the full form, V1 and dV1/dt are homogeneous, so their extreme values on the unit level
set {V1 = 1} give global constants. That set is sampled by dilating random states onto it
(seeded, so the result is deterministic), then the worst samples are refined by a local search
on the level set (the maximum of a continuous function over a compact set; sampling alone
under-estimates it).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from ftstab_mj.control.hong import HongController
from ftstab_mj.errors import ParameterError

DEFAULT_SAMPLES = 200_000
DEFAULT_SEED = 0


@dataclass(frozen=True)
class Certificate:
    """Constants of dV1/dt <= -c V1^alpha and |dV1/dz_r| <= c' V1^alpha' (full form).

    For the simplified form c and alpha are None (no homogeneous V1); ``region_max_dV1dt``
    reports the largest dV1/dt found on the sampled bounded region instead.
    """

    form: str
    c: float | None
    alpha: float | None
    c_prime: float | None
    alpha_prime: float | None
    certified: bool  # c > 0 (full form); always False for the simplified form (not global)
    samples: int
    seed: int
    region_radius: float | None = None  # simplified form: |z|_inf bound of the region checked
    region_max_dV1dt: float | None = None  # simplified form: max of dV1/dt over the region
    region_negative: bool | None = None  # simplified form: dV1/dt < 0 at every sample
    note: str = ""

    def to_dict(self) -> dict:
        return asdict(self)

    def time_bound(self, V1_0):
        """Theorem 1's bound on the convergence time from a state with V1 = V1_0: V1_0^(1-a)/(c(1-a)).

        Infinite when the certificate does not hold, and at k = 0 (alpha = 1: the linear law
        converges exponentially, not in finite time). V1_0 may be an array.
        """
        if not self.certified or self.alpha >= 1.0:
            return np.full(np.shape(V1_0), np.inf) if np.ndim(V1_0) else float("inf")
        a = self.alpha
        return np.asarray(V1_0, dtype=float) ** (1.0 - a) / (self.c * (1.0 - a))


def unit_level_set_points(hong: HongController, n: int, rng: np.random.Generator) -> np.ndarray:
    """n points with V1 = 1 (full form): random directions dilated onto the level set. Shape (n, r).

    Directions are drawn with log-uniform magnitudes per component so that states where one
    component dominates (where extremes of dV1/dt often sit) are well represented.
    """
    r = hong.r
    mags = 10.0 ** rng.uniform(-3.0, 1.0, size=(n, r))
    z = mags * rng.choice([-1.0, 1.0], size=(n, r))
    return _onto_unit_level(hong, z)


def _onto_unit_level(hong, z):
    V = hong.V1(z)
    lam = V ** (-1.0 / hong.degree_V1)
    return hong.dilate(z, lam)


def _refine_max(hong, f, z_best, rng, rounds=60, spread=0.2):
    """Local random search for max f on {V1 = 1}, started from the rows of z_best (m, r)."""
    z = z_best.copy()
    fz = f(z)
    scale = np.abs(z).mean(axis=0) + 1e-12
    for it in range(rounds):
        step = spread * (0.5 ** (it / 12.0))
        cand = _onto_unit_level(hong, z + step * scale * rng.standard_normal(z.shape))
        fc = f(cand)
        better = np.isfinite(fc) & (fc > fz)
        z[better], fz[better] = cand[better], fc[better]
    return float(np.nanmax(fz))


def certify(hong: HongController, samples: int = DEFAULT_SAMPLES, seed: int = DEFAULT_SEED,
            region_radius: float = 1.0) -> Certificate:
    """Compute the certificate of ``hong`` (see module docstring). Deterministic for a given seed."""
    if samples < 100:
        raise ParameterError("samples", "an integer >= 100", samples)
    rng = np.random.default_rng(seed)
    if hong.form == "simplified":
        return _certify_simplified(hong, samples, seed, rng, region_radius)
    z = unit_level_set_points(hong, samples, rng)
    dVdt = hong.closed_loop_dV1dt(z)
    dVr = np.abs(hong.dV1_dzr(z))
    top = min(64, samples)

    def best_rows(values):
        v = np.where(np.isfinite(values), values, -np.inf)
        return z[np.argpartition(v, -top)[-top:]]

    max_dVdt = max(float(np.nanmax(dVdt)), _refine_max(hong, hong.closed_loop_dV1dt, best_rows(dVdt), rng))
    c_prime = max(float(np.nanmax(dVr)),
                  _refine_max(hong, lambda x: np.abs(hong.dV1_dzr(x)), best_rows(dVr), rng))
    k = hong.k
    c = -max_dVdt
    return Certificate(
        form="full", c=c, alpha=(2.0 + 2.0 * k) / (2.0 + k), c_prime=c_prime,
        alpha_prime=1.0 - float(hong.p[hong.r - 1]) / (2.0 + k), certified=bool(c > 0.0),
        samples=samples, seed=seed,
        note=("max of dV1/dt on {V1 = 1} is >= 0: no finite-time certificate for these gains" if c <= 0 else
              "k = 0: linear law, exponential (not finite-time) convergence" if k == 0 else ""),
    )


def _certify_simplified(hong, samples, seed, rng, radius):
    """Simplified form: sample the box |z_i| <= radius and look at the sign of dV1/dt there."""
    z = rng.uniform(-radius, radius, size=(samples, hong.r))
    dVdt = hong.closed_loop_dV1dt(z)
    finite = np.isfinite(dVdt)
    mx = float(np.max(dVdt[finite]))
    return Certificate(
        form="simplified", c=None, alpha=None, c_prime=None, alpha_prime=None, certified=False,
        samples=samples, seed=seed, region_radius=radius, region_max_dV1dt=mx,
        region_negative=bool(mx < 0.0),
        note=("simplified form: V1 = sum (z_j - v_{j-1})^2/2 is not homogeneous, so this is a check of "
              "the sign of dV1/dt on the box |z_i| <= radius only, not a global certificate"),
    )


@dataclass(frozen=True)
class Theorem3Bounds:
    """Theorem 3's constants for the adaptive law, computed with the TRUE phibar and gamma_m."""

    Phibar: float
    Delta: float  # limsup V1 <= Delta
    phi_hat_limsup: float  # limsup phi_hat <= 2 Phibar + rate Delta^(1-alpha) / (c (1-alpha)); inf at k = 0


def theorem3_bounds(cert: Certificate, phibar: float, gamma_m: float, kappa: float, delta: float,
                    rate: float, eps: float) -> Theorem3Bounds:
    """Phibar, Delta and the limsup bound on phi_hat (NOTES.md section 6). Needs a full-form certificate."""
    if not cert.certified:
        raise ParameterError("certificate", "a full-form certificate with c > 0", cert.c)
    for name, val in (("phibar", phibar), ("gamma_m", gamma_m), ("kappa", kappa), ("delta", delta),
                      ("rate", rate), ("eps", eps)):
        if not (np.isfinite(val) and (val > 0 or (name == "phibar" and val == 0))):
            raise ParameterError(name, "a finite number > 0" + (" (or 0)" if name == "phibar" else ""), val)
    # float64 arithmetic: a bound beyond the largest float is infinite (an honest "no finite bound"),
    # where Python's float ** would raise OverflowError (e.g. a gain offset of 1.8e308); the inputs are
    # finite, so a NaN can only come from inf / inf of such an overflow and is infinite too
    phibar, gamma_m, kappa, delta, rate, eps = map(np.float64, (phibar, gamma_m, kappa, delta, rate, eps))
    with np.errstate(over="ignore", invalid="ignore"):
        Phibar = (phibar + (kappa * gamma_m - 1.0) ** 2 / (4.0 * gamma_m * delta)) / gamma_m
        ap = cert.alpha_prime
        Delta = (eps ** (1.0 - ap) + cert.c_prime * (1.0 - ap) * gamma_m * Phibar ** 2 / (2.0 * rate)) ** (1.0 / (1.0 - ap))
        a = cert.alpha
        # At k = 0 (alpha = 1) V1 decays exponentially, never reaching 0 in finite time: the proof's
        # last phase has no end, so the bound on phi_hat is infinite.
        limsup = 2.0 * Phibar + rate * Delta ** (1.0 - a) / (cert.c * (1.0 - a)) if a < 1.0 else float("inf")
    def bound(x):
        return float(x) if np.isfinite(x) else float("inf")

    return Theorem3Bounds(Phibar=bound(Phibar), Delta=bound(Delta), phi_hat_limsup=bound(limsup))
