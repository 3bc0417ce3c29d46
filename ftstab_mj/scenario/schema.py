"""The scenario schema: frozen typed dataclasses, one per TOML table, units in the field comments.

A scenario file (``scenarios/*.toml``) maps onto :class:`Scenario`::

    name, description, seed            -> Scenario
    [plant]   model + physical params  -> PlantSpec   (params go to ftstab_mj.plants.make_plant)
    [sim]                              -> SimSpec
    [metrics]                          -> records.MetricSettings
    [loops.<name>]                     -> LoopSpec    (one per actuated joint of the plant)
    [loops.<name>.controller]          -> ControllerSpec  (law + that law's declared parameters)
    [loops.<name>.disturbance]         -> disturbances.Signal (the injected disturbance)
    [loops.<name>.gain]                -> disturbances.Signal (the actuator gain factor)
    [loops.<name>.reference]           -> reference.Reference (ref(t) to track; default: the set point ref)
    [loops.<name>.sensor]              -> SensorSpec    (what the controller reads; default: the exact z)
    [loops.<name>.observer]            -> ObserverSpec  (Levant's differentiator; default: none)
    [loops.<name>.actuator]            -> ActuatorSpec  (what the plant receives; default: the law's u)

Chain units: for a loop of chain length r, z = (z_1, ..., z_r) are the
position error (m or rad) and its r - 1 derivatives; phi is in m/s^r (rad/s^r) and gamma in
(m/s^r) per unit of control. The signals are in the plant's units (ftstab_mj.plants): for the cart
they are phi and gamma in chain units; for the arm a torque (N m) and a dimensionless gain factor,
which the arm's inertia turns into its phi and gamma. Each field's metadata holds ``doc`` (what, with units) and an
optional ``check`` (value -> None when fine, else a text saying what is allowed) used by the loader.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from ftstab_mj.control.law import Law, law_class
from ftstab_mj.plants.disturbances import Signal
from ftstab_mj.plants.reference import Reference
from ftstab_mj.simulation.records import MetricSettings
from ftstab_mj.config.validate import box_count, fraction, identifier, non_negative, one_line, one_of, positive, state_limit, time_step

INTEGRATORS = ("euler", "implicitfast", "rk4")


def meta(doc, check=None):
    return {"doc": doc, "check": check}


# -- the schema ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class PlantSpec:
    """The simulated plant: a model name and its physical parameters (units: see ftstab_mj.plants)."""

    model: str = field(metadata=meta("the plant model name (a registered plant: see `ftstab list`)"))
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
    """One loop's control law: ``law`` (a registered law's name) and that law's parameters.

    ``params``: (name, value) of every parameter the law declares (its ``Param``s), defaults filled
    in, in declaration order; the loader reads them against the law's declarations, so a key of
    another law is an error, not silently ignored. Read one as ``spec.params_dict["k"]`` or ``spec.k``.
    A robust bound may be the word "computed": the loader replaces it by the plant's bound for the
    scenario's signals.
    """

    law: str
    params: tuple[tuple[str, object], ...] = ()

    @classmethod
    def of(cls, law: str, **values) -> "ControllerSpec":
        """The spec of ``law`` with ``values``, defaults filled in (ParameterError for an unknown law;
        the loader is the one that checks the values themselves)."""
        declared = law_class(law).all_params()
        return cls(law, tuple((p.name, values.get(p.name, None if p.required else p.default)) for p in declared))

    @property
    def params_dict(self) -> dict:
        return dict(self.params)

    def __getattr__(self, name):  # spec.k, spec.gains: the law's parameters as attributes
        if name.startswith("__"):
            raise AttributeError(name)
        for key, value in object.__getattribute__(self, "params"):
            if key == name:
                return value
        raise AttributeError(f"the {self.law} law has no parameter {name!r}")

    def values(self) -> dict:
        """{param: value} of every parameter of this law (defaults filled in)."""
        return dict(self.params)

    def with_values(self, **values) -> "ControllerSpec":
        """A copy with some parameters replaced (the loader's "computed" bounds)."""
        return ControllerSpec(self.law, tuple((k, values.get(k, v)) for k, v in self.params))

    def build(self, r: int):
        """The control law (a registered ftstab_mj.control.Law) for chain length r."""
        return law_class(self.law).from_params(r, self.values())


# -- the loop stages (ftstab_mj/loop_stages): sensor, observer, actuator ---------------------------
def whole_periods(v):
    from ftstab_mj.config.limits import MAX_DELAY_SAMPLES

    return (None if 0 <= v <= MAX_DELAY_SAMPLES and float(v).is_integer() else
            f"a whole number of control periods in [0, {MAX_DELAY_SAMPLES:.0e}] (a limit: the delay line holds "
            f"every delayed sample)".replace("e+0", "e"))


def channel_values(v):
    vals = v if isinstance(v, tuple) else (v,)
    return None if all(math.isfinite(x) and x >= 0 for x in vals) else "finite numbers >= 0"


@dataclass(frozen=True)
class SensorSpec:
    """What the controller reads of z (ftstab_mj/simulation/stages/sensor.py). A number for noise or
    quantum applies to every measured channel; an array gives one value per channel."""

    measured: str = field(default="state", metadata=meta(
        'the components read: "state" (z_1..z_r) or "position" (z_1 only; needs an observer)',
        one_of("state", "position")))
    noise: float | tuple[float, ...] = field(default=0.0, metadata=meta(
        "additive noise amplitude per measured channel (chain units; uniform: half-width, gaussian: std)",
        channel_values))
    noise_kind: str = field(default="uniform", metadata=meta("noise distribution", one_of("uniform", "gaussian")))
    quantum: float | tuple[float, ...] = field(default=0.0, metadata=meta(
        "quantization step per measured channel (chain units; 0: none)", channel_values))
    delay: float = field(default=0, metadata=meta("delay of the readings (control periods)", whole_periods))
    seed: int = 0  # derived from Scenario.seed by the loader (SIGNAL_DERIVED), never set in a file


OBSERVER_KINDS = ("levant", "levant_filtering")


@dataclass(frozen=True)
class ObserverSpec:
    """Levant's robust exact differentiator rebuilding z_2..z_r from the measured z_1
    (ftstab_mj/simulation/stages/differentiator.py); ``levant_filtering`` is its filtering variant."""

    kind: str = field(metadata=meta("the observer", one_of(*OBSERVER_KINDS)))
    L: float | str = field(metadata=meta(
        'bound on |z_1^(order+1)| (chain units: m/s^(order+1)), or "computed": the rule phibar + gamma_M u_max '
        "from the plant's true bounds and the actuator's saturation (order r - 1; needs actuator.u_max)",
        lambda v: None if v == "computed" or (not isinstance(v, str) and v > 0) else 'a number > 0 or "computed"'))
    order: int | None = field(default=None, metadata=meta(
        "differentiation order n >= r - 1 (default r - 1)", non_negative))
    filter_order: int | None = field(default=None, metadata=meta(
        "levant_filtering: filtering order n_f >= 1 (default 1)", positive))


@dataclass(frozen=True)
class ActuatorSpec:
    """What the plant receives when the law asks for u (ftstab_mj/simulation/stages/actuator.py), chain units."""

    u_max: float | None = field(default=None, metadata=meta("saturation |u| <= u_max (default: none)", positive))
    rate_max: float | None = field(default=None, metadata=meta(
        "rate limit |du/dt| <= rate_max (per s; default: none)", positive))
    tau: float = field(default=0.0, metadata=meta("first-order lag time constant (s; 0: none)", non_negative))
    dead_zone: float = field(default=0.0, metadata=meta("dead-zone half-width (0: none)", non_negative))
    lag_order: int | None = field(default=None, metadata=meta(
        "1: one lag 1/(tau s + 1) (default); 2: two in cascade, a second-order actuator", one_of(1, 2)))


@dataclass(frozen=True)
class LoopSpec:
    """One control loop (one actuated joint): initial state, controller, phi(t), gamma(t).

    The one loop description of the project: the scenario loader builds it from [loops.<name>]
    (controller: a ControllerSpec) and ftstab_mj.simulation.run_loop runs it (controller: a ControllerSpec, built
    for the plant's r, or a law object following ftstab_mj.control.Law).
    """

    name: str = field(metadata=meta("loop name (the key of [loops.<name>]; the plant names its loops)"))
    z0: tuple[float, ...] = field(metadata=meta("initial state z_1..z_r (chain units: m or rad, then derivatives)"))
    controller: ControllerSpec | Law = field(metadata=meta("the control law"))
    disturbance: Signal = field(default=Signal("constant", 0.0), metadata=meta(
        "injected disturbance (cart: phi in m/s^r; arm: torque in N m); default none"))
    gain: Signal = field(default=Signal("constant", 1.0), metadata=meta(
        "actuator gain factor (cart: gamma in chain units; arm: dimensionless); default 1"))
    ref: float = field(default=0.0, metadata=meta("set point of the joint position (m or rad): z_1 = q - ref"))
    reference: Reference | None = field(default=None, metadata=meta(
        "a reference to track instead of ref: kind constant | sine | polynomial | min_jerk | file; "
        "z_i = q^(i-1) - ref^(i-1)(t)"))
    sensor: SensorSpec | None = field(default=None, metadata=meta("the sensor model; default: the exact z"))
    observer: ObserverSpec | None = field(default=None, metadata=meta("the observer; default: none"))
    actuator: ActuatorSpec | None = field(default=None, metadata=meta("the actuator model; default: ideal"))

    def law(self, r: int):
        """The control law object of this loop for chain length r."""
        c = self.controller
        return c.build(r) if isinstance(c, ControllerSpec) else c


@dataclass(frozen=True)
class Scenario:
    """Everything needed to reproduce a run. ``seed`` is the only source of randomness of the run."""

    name: str = field(metadata=meta("scenario name (names the log files DIR/<name>.mcap, .rrd)", identifier))
    description: str = field(metadata=meta("one-line description of what the run shows", one_line))
    plant: PlantSpec = field(metadata=meta("the plant"))
    sim: SimSpec = field(metadata=meta("time discretisation"))
    loops: tuple[LoopSpec, ...] = field(metadata=meta("the control loops, one table per loop name"))
    seed: int = field(default=0, metadata=meta("seed of every random signal of the run", non_negative))
    plugins: tuple[str, ...] = field(default=(), metadata=meta(
        "Python files (relative to the scenario file) or importable modules that register laws and plants, "
        "imported before the rest is read; the resolved scenario pins each by its sha256"))
    metrics: MetricSettings = field(default_factory=MetricSettings, metadata=meta("how metrics read the run"))


# Range checks of classes defined elsewhere (their own constructors check the rest).
def frequency_band(v):
    ok = len(v) == 2 and 0 <= v[0] < v[1]
    return None if ok else "two frequencies [low, high] in Hz with 0 <= low < high"


EXTERNAL_CHECKS = {
    MetricSettings: {"settle_level": positive, "final_fraction": fraction, "chatter_band": frequency_band,
                      "settle_z1": positive, "final_window_max": positive, "certificate_boxes": box_count},
}
# Fields of Signal and SensorSpec that a scenario does not set: the seed is derived from Scenario.seed.
SIGNAL_DERIVED = ("seed",)

