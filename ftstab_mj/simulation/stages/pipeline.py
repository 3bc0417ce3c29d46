"""One loop's stages put together, as the run loop calls them once per control sample.

    stages = LoopStages(sensor, observer, actuator, r=2, period=0.01, physics_step=0.001, stream=0)
    z_measured, z_hat = stages.measure(z_true, k, state)     # before the law
    u_applied, per_step = stages.actuate(u, state)           # after the law: the plant's input per physics step

``state`` is the loop's flat stage state (``state_size`` floats, updated in place), which the run
loop keeps in MuJoCo's ``userdata`` so that a saved and restored run goes on exactly. Layout:
the sensor's delay line, then the observer's state, then the actuator's (2). At sample k = 0 the
delay line and the observer start from the first reading (whatever the state held), so a run
restored to its start begins the same way.

The observer runs at the control rate, and the law at sample k uses its estimate at t_k, which
depends on the readings up to sample k - 1 (Livne & Levant's discrete differentiator predicts
z(t_(k+1)) from z(t_k) and the reading at t_k). Without an observer the law uses the reading.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ftstab_mj.config.errors import ParameterError
from ftstab_mj.simulation.stages.actuator import STATE_SIZE as ACTUATOR_STATE, ActuatorModel
from ftstab_mj.simulation.stages.differentiator import LevantDifferentiator
from ftstab_mj.simulation.stages.sensor import SensorModel


@dataclass(frozen=True)
class LoopStages:
    """sensor, observer (LevantDifferentiator or None), actuator of a loop of chain length r.

    period: control period (s); N: physics steps per period; stream: the loop's noise stream.
    """

    sensor: SensorModel
    observer: LevantDifferentiator | None
    actuator: ActuatorModel
    r: int
    period: float
    N: int
    stream: int = 0

    def __post_init__(self):
        self.sensor.check(self.r)
        if self.observer is None and self.sensor.measured != "state":
            raise ParameterError("observer", 'an observer when the sensor measures only the position', None)
        if self.observer is not None:
            if self.sensor.measured != "position":
                raise ParameterError("sensor.measured", '"position" with an observer (it rebuilds z_2..z_r)',
                                     self.sensor.measured)
            if self.observer.order < self.r - 1:
                raise ParameterError("observer.order", f"an order >= r - 1 = {self.r - 1}", self.observer.order)
        m = self.sensor.channels(self.r)
        d = self.sensor.state_size(self.r)
        o = self.observer.state_size if self.observer else 0
        object.__setattr__(self, "_m", m)
        object.__setattr__(self, "_slices", (slice(0, d), slice(d, d + o), slice(d + o, d + o + ACTUATOR_STATE)))

    @property
    def ideal(self) -> bool:
        """True when every stage is the identity: the run loop then skips them (today's runs)."""
        return self.sensor.ideal and self.observer is None and self.actuator.ideal

    @property
    def state_size(self) -> int:
        return self._slices[2].stop

    @property
    def channels(self) -> int:
        return self._m

    def measure(self, z_true, k: int, state) -> tuple[np.ndarray, np.ndarray]:
        """(z_measured (m,), z_hat (r,)) at sample k from the true z (r,); advances the delay line
        and the observer in ``state``."""
        line, obs, _ = self._slices
        y = self.sensor.reading(z_true, k, self.stream)
        if k == 0:
            state[line] = self.sensor.initial_state(y)
        z_meas, state[line] = self.sensor.delayed(state[line], y)
        if self.observer is None:
            return z_meas, z_meas
        if k == 0:
            state[obs] = self.observer.initial_state(z_meas[0])
        z_hat = self.observer.estimate(state[obs])[:self.r].copy()
        state[obs] = self.observer.step(state[obs], z_meas[0], self.period)
        return z_meas, z_hat

    def actuate(self, u: float, k: int, state, physics_step: float) -> tuple[float, np.ndarray]:
        """(u_applied, the plant's input at each of the N physics steps (N,)) for the law's u at
        sample k; advances the actuator's state (at rest, 0, before sample 0)."""
        act = self._slices[2]
        if k == 0:
            state[act] = self.actuator.initial_state()
        u_c = self.actuator.command(u, state[act], self.period)
        steps, state[act] = self.actuator.steps(u_c, state[act], physics_step, self.N)
        return float(steps[0]), steps


def build_stages(sensor, observer, actuator, r: int, period: float, N: int, stream: int = 0) -> LoopStages | None:
    """The stages of a loop from its scenario tables (scenario/schema.py SensorSpec, ObserverSpec,
    ActuatorSpec, each None when absent), or None when every stage is the identity (the run loop
    then runs the loop exactly as without stages). ParameterError names the stage's key."""
    if sensor is None and observer is None and actuator is None:
        return None
    sens = SensorModel()
    if sensor is not None:
        m = r if sensor.measured == "state" else 1

        def per_channel(v):
            v = tuple(v) if isinstance(v, (tuple, list)) else (float(v),) * m
            return () if not any(v) else v

        sens = SensorModel(measured=sensor.measured, noise=per_channel(sensor.noise), noise_kind=sensor.noise_kind,
                           quantum=per_channel(sensor.quantum), delay=int(sensor.delay), seed=int(sensor.seed))
    obs = None
    if observer is not None:
        nf = (1 if observer.filter_order is None else observer.filter_order) if observer.kind == "levant_filtering" else 0
        obs = LevantDifferentiator(r - 1 if observer.order is None else observer.order, observer.L, nf)
    act = ActuatorModel()
    if actuator is not None:
        inf = float("inf")
        act = ActuatorModel(u_max=inf if actuator.u_max is None else actuator.u_max,
                            rate_max=inf if actuator.rate_max is None else actuator.rate_max,
                            tau=actuator.tau, dead_zone=actuator.dead_zone,
                            lag_order=1 if actuator.lag_order is None else actuator.lag_order)
    stages = LoopStages(sens, obs, act, r=r, period=period, N=N, stream=stream)
    return None if stages.ideal else stages


def describe_stages(stages: LoopStages, law, z0) -> dict:
    """The stages of a loop as plain JSON-able data (records.LoopInfo.stages), with what the law's
    guarantee needs of the actuator (actuator.control_needed)."""
    from ftstab_mj.simulation.stages.actuator import control_needed

    s, o, a = stages.sensor, stages.observer, stages.actuator

    def finite(x):
        return None if x == float("inf") else x

    need, note = control_needed(law, z0)
    return {
        "sensor": {"measured": s.measured, "noise": list(s.noise), "noise_kind": s.noise_kind,
                   "quantum": list(s.quantum), "delay": s.delay},
        "observer": None if o is None else {
            "kind": "levant_filtering" if o.filter_order else "levant", "order": o.order, "L": o.L,
            "filter_order": o.filter_order},
        "actuator": {"u_max": finite(a.u_max), "rate_max": finite(a.rate_max), "tau": a.tau,
                     "lag_order": a.lag_order, "dead_zone": a.dead_zone},
        "u_needed": need, "u_needed_note": note,
    }
