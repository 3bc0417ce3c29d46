"""The scenario schema: frozen typed dataclasses, one per TOML table, units in the field comments.

A scenario file (``scenarios/*.toml``) maps onto :class:`Scenario`::

    name, description, seed            -> Scenario
    [plant]   model + physical params  -> PlantSpec   (params go to ftstab_mj.plants.make_plant)
    [sim]                              -> SimSpec
    [metrics]                          -> records.MetricSettings
    [loops.<name>]                     -> LoopSpec    (one per actuated joint of the plant)
    [loops.<name>.controller]          -> ControllerSpec
    [loops.<name>.disturbance]         -> disturbances.Signal (the injected disturbance)
    [loops.<name>.gain]                -> disturbances.Signal (the actuator gain factor)

Chain units (NOTES.md section 7): for a loop of chain length r, z = (z_1, ..., z_r) are the
position error (m or rad) and its r - 1 derivatives; phi is in m/s^r (rad/s^r) and gamma in
(m/s^r) per unit of control. The signals are in the plant's units (ftstab_mj.plants): for the cart
they are phi and gamma in chain units; for the arm a torque (N m) and a dimensionless gain factor,
which the arm's inertia turns into its phi and gamma. Each field's metadata holds ``doc`` (what, with units) and an
optional ``check`` (value -> None when fine, else a text saying what is allowed) used by the loader.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from ftstab_mj.disturbances import Signal
from ftstab_mj.records import MetricSettings

LAWS = ("nominal", "robust", "adaptive")
INTEGRATORS = ("euler", "implicitfast", "rk4")
ROBUST_PARAMS = ("phibar", "gamma_m")
ADAPTIVE_PARAMS = ("kappa", "delta", "rate", "eta", "eps")


# -- field checks: value -> None if allowed, else the text of what is allowed --------------------
def positive(v):
    return None if v > 0 else "a number > 0"


def non_negative(v):
    return None if v >= 0 else "a number >= 0"


def one_of(*allowed):
    def check(v):
        return None if v in allowed else "one of " + ", ".join(repr(a) for a in allowed)
    return check


def open_unit_interval(v):
    return None if 0 < v < 1 else "a number in the open interval (0, 1)"


def time_step(v):
    # 1e-7 s is 10 million steps per simulated second; below it a run is an error, not a study.
    return None if v >= 1e-7 else "a time step >= 1e-7 s"


def state_limit(v):
    # MuJoCo resets a state beyond 1e10 on its own (a warning, zeros): our limit must fire first.
    return None if 0 < v <= 1e9 else "a number in (0, 1e9] (MuJoCo resets states beyond 1e10)"


def fraction(v):
    return None if 0 < v <= 1 else "a number in (0, 1]"


def identifier(v):
    ok = v != "" and all(c.isalnum() or c in "_-" for c in v)
    return None if ok else "a non-empty name of letters, digits, '_' and '-' (it names the log files)"


def one_line(v):
    return None if v.strip() and "\n" not in v else "one non-empty line"


COMPUTED = "computed"


def bound(check):
    """A robust bound: a number passing ``check``, or the word "computed"."""
    def check_bound(v):
        if isinstance(v, str):
            return None if v == COMPUTED else f'a number or "{COMPUTED}"'
        return check(v)
    return check_bound


def meta(doc, check=None):
    return {"doc": doc, "check": check}


# -- the schema ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PlantSpec:
    """The simulated plant: a model name and its physical parameters (units: see ftstab_mj.plants)."""

    model: str = field(metadata=meta("the plant model name (see `ftstab_mj.plants.MODELS`)"))
    # mass (kg), friction, damping, link sizes...: passed to make_plant, which validates them
    params: dict = field(default_factory=dict, metadata=meta("physical parameters of the model"))


@dataclass(frozen=True)
class SimSpec:
    """Time discretisation of the run."""

    duration: float = field(metadata=meta("run length (s)", positive))
    physics_step: float = field(default=1e-3, metadata=meta("MuJoCo timestep (s)", time_step))
    period: float = field(default=1e-3, metadata=meta(
        "control period (s), an integer multiple of physics_step; u is held over it", positive))
    integrator: str = field(default="euler", metadata=meta("MuJoCo integrator", one_of(*INTEGRATORS)))
    divergence_limit: float = field(default=1e3, metadata=meta(
        "the run stops as diverged when some |z_i| exceeds it (chain units)", state_limit))


@dataclass(frozen=True)
class ControllerSpec:
    """One loop's control law (NOTES.md sections 2-6). Hong's part: form, k, gains; then the law's own.

    robust needs phibar, gamma_m (the bounds it assumes, or "computed" to take the plant's bounds: the
    loader replaces the word by the numbers); adaptive needs kappa, delta, rate, eta, eps;
    nominal needs none. A parameter of another law is an error, not silently ignored.
    """

    law: str = field(metadata=meta("the control law", one_of(*LAWS)))
    k: float = field(metadata=meta("homogeneity degree, -1/r < k <= 0 (full form)"))
    gains: tuple[float, ...] = field(metadata=meta("Hong's gains l_1..l_r > 0 (Hurwitz nested polynomial)"))
    form: str = field(default="full", metadata=meta("Hong's controller form", one_of("full", "simplified")))
    # robust bounds: a number, or "computed": the plant's bound for this scenario's signals
    # (Plant.true_bounds: the cart from the signal ranges, the arm from its model over its workspace)
    phibar: float | str | None = field(default=None, metadata=meta(
        "robust: assumed bound on |phi| (chain units, m/s^r or rad/s^2), or \"computed\"", bound(non_negative)))
    gamma_m: float | str | None = field(default=None, metadata=meta(
        "robust: assumed lower bound on gamma (chain units), or \"computed\"", bound(positive)))
    kappa: float | None = field(default=None, metadata=meta("adaptive: gamma_hat = kappa + delta |u0|", positive))
    delta: float | None = field(default=None, metadata=meta("adaptive: gamma_hat = kappa + delta |u0|", positive))
    rate: float | None = field(default=None, metadata=meta(
        "adaptive: growth rate of phi_hat (chain units per s; the paper's 'k')", positive))
    eta: float | None = field(default=None, metadata=meta(
        "adaptive: decay exponent of phi_hat", open_unit_interval))
    eps: float | None = field(default=None, metadata=meta(
        "adaptive: V1 level below which phi_hat decays", positive))

    def law_params(self) -> dict:
        """The parameters of this law only: robust {phibar, gamma_m}, adaptive {kappa, ...}, nominal {}."""
        names = {"robust": ROBUST_PARAMS, "adaptive": ADAPTIVE_PARAMS}.get(self.law, ())
        return {n: getattr(self, n) for n in names}


@dataclass(frozen=True)
class LoopSpec:
    """One control loop (one actuated joint): initial state, controller, phi(t), gamma(t)."""

    name: str = field(metadata=meta("loop name (the key of [loops.<name>]; the plant names its loops)"))
    z0: tuple[float, ...] = field(metadata=meta("initial state z_1..z_r (chain units: m or rad, then derivatives)"))
    controller: ControllerSpec = field(metadata=meta("the control law"))
    disturbance: Signal = field(default=Signal("constant", 0.0), metadata=meta(
        "injected disturbance (cart: phi in m/s^r; arm: torque in N m); default none"))
    gain: Signal = field(default=Signal("constant", 1.0), metadata=meta(
        "actuator gain factor (cart: gamma in chain units; arm: dimensionless); default 1"))
    ref: float = field(default=0.0, metadata=meta("set point of the joint position (m or rad): z_1 = q - ref"))


@dataclass(frozen=True)
class Scenario:
    """Everything needed to reproduce a run. ``seed`` is the only source of randomness of the run."""

    name: str = field(metadata=meta("scenario name (names the log files DIR/<name>.mcap, .rrd)", identifier))
    description: str = field(metadata=meta("one-line description of what the run shows", one_line))
    plant: PlantSpec = field(metadata=meta("the plant"))
    sim: SimSpec = field(metadata=meta("time discretisation"))
    loops: tuple[LoopSpec, ...] = field(metadata=meta("the control loops, one table per loop name"))
    seed: int = field(default=0, metadata=meta("seed of every random signal of the run", non_negative))
    metrics: MetricSettings = field(default_factory=MetricSettings, metadata=meta("how metrics read the run"))


# Range checks of classes defined elsewhere (their own constructors check the rest).
EXTERNAL_CHECKS = {
    MetricSettings: {"settle_level": positive, "final_fraction": fraction},
}
# Fields of Signal that a scenario does not set: the seed is derived from Scenario.seed.
SIGNAL_DERIVED = ("seed",)


def period_is_multiple(period: float, step: float) -> bool:
    """True when period / step is an integer (to 1e-9 relative), as MuJoCo can only hold u over whole steps."""
    n = round(period / step)
    return n >= 1 and math.isclose(n * step, period, rel_tol=1e-9, abs_tol=0.0)
