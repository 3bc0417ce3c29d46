"""The run loop: a plant under the paper's controllers, the controller in MuJoCo's control callback.

    plant = make_plant("cart", {"mass": 2.0})
    loops = [LoopSpec("cart", z0=(1.0, 0.0), controller=RobustLaw(hong, phibar=0.5, gamma_m=0.8),
                      disturbance=Signal("sine", amplitude=0.5, freq=1.0), gain=Signal("constant", 1.0))]
    result = simulate(plant, loops, duration=5.0, period=0.01, physics_step=0.001)  # RunResult

The direction is one way: :class:`Simulation` steps the plant and records samples, :class:`Run`
cuts a run into batches and ends it with a status, ``simulate`` collects them. Sinks and metrics
belong to whoever drives the run (ftstab_mj.scenario.run.record), never to this module.

Timing. The control period is N physics steps (N integer, checked). Sample k is taken at
t_k = k * period from the state at the start of the step that opens period k: the run loop sets a
"sample pending" flag before that ``mj_step``, and the first callback call of the step (the one of
its first forward pass, where position and velocity sensors are fresh) evaluates the law once,
writes the control and records the sample. Every other callback call (the rest of the steps, the
RK4 stages, stray forward passes) returns at once, so the control is held over the period whatever
the integrator. The per-step inputs (gain factor, injected disturbance; plants/base.py) are written
by the loop before each step.

The per-sample pipeline is :meth:`Simulation._sample`: read z (``_read_z``: the plant's sensors
minus the set points) -> ``_sense`` (a loop's sensor and observer: what its law sees) -> every
loop's law (``law.evaluate``, state advanced with ``law.advance``) -> u -> ``_actuate`` (a loop's
actuator model: what the plant receives at each physics step) -> inject (``_inject``: ctrl = gain
u, the disturbance force). The stages are ftstab_mj/loop_stages (LoopStages, built from the
LoopSpec's sensor, observer and actuator tables); a loop without them, or with every stage at its
identity, skips both steps and runs exactly as before they existed.

Native path (``native=True | "auto"``, the default "auto"): the same per-sample and per-step work
done by a C callback (ftstab_mj/simulation/native/run.py, kernel.c) so that a whole batch runs in one
``mj_step(m, d, nstep)``; it records the same samples (to rounding: tests/test_native_sim.py).
"auto" uses it when the kernel is built and the simulation is one it handles (Euler or
implicitfast, a plant with a native sensor map, laws with a ``native_code``), and Python otherwise.

State. Each law's own state (``law.state_size`` numbers: the adaptive law's phi_hat, none for the
others) is advanced exactly once per period (``law.advance``, z held) and lives in MuJoCo's
``userdata`` (loop i at ``Simulation.state_slices[i]``), followed by each loop's stage state (the
sensor's delay line, the differentiator, the actuator's lag: ``Simulation.stage_slices[i]``), so
``mj_getState(mjSTATE_INTEGRATION)`` (which also holds qpos, qvel, act, ctrl, qfrc_applied and
time) saves the whole run state.

Outcomes. A run ends "completed", "diverged" (NaN or |z| beyond ``divergence_limit`` at a sample,
a MuJoCo warning), or "interrupted" (Ctrl-C: :meth:`Run.interrupted` keeps the samples of the
batch cut short); :class:`RunResult` holds every sample when the Run keeps them (``keep_samples``:
``simulate`` does, the scenario runner only when asked). An exception inside the callback comes out
as :class:`CallbackError`. The callback that was installed before the run is always put back
(:func:`control_callback`).
"""

from __future__ import annotations

import math
from contextlib import contextmanager
from dataclasses import dataclass

import mujoco
import numpy as np

from ftstab_mj.simulation import native as native_path
from ftstab_mj.plants.callback import control_callback, holds_slot, timer_off
from ftstab_mj.simulation.interrupts import Interrupted, critical, interruption
from ftstab_mj.config.errors import CallbackError, ParameterError
from ftstab_mj.config.limits import MUJOCO_MAXVAL
from ftstab_mj.simulation.stages.pipeline import build_stages, describe_stages
from ftstab_mj.simulation.native import run as native_run
from ftstab_mj.plants.base import Plant, release_data
from ftstab_mj.simulation.records import (COMPLETED, DIVERGED, INTERRUPTED, LOOP_FIELDS, LoopInfo,
                               MetricSettings, RunInfo, SampleBatch)
from ftstab_mj.config.validate import whole_steps

# MuJoCo warnings that mean the simulation blew up (MuJoCo resets the data when they fire).
_DIVERGENCE_WARNINGS = (mujoco.mjtWarning.mjWARN_BADQPOS, mujoco.mjtWarning.mjWARN_BADQVEL,
                        mujoco.mjtWarning.mjWARN_BADQACC, mujoco.mjtWarning.mjWARN_BADCTRL)
_SCALARS = tuple(f for f in LOOP_FIELDS if f not in ("t", "z"))
# where the Python callback finds a sample's fields in its record block (Simulation._rec_block, one
# row per field of _SCALARS): the law's outputs u .. gamma_hat, then the true phi and gamma
_OUTPUTS, _PHI, _GAMMA = slice(0, _SCALARS.index("gamma_hat") + 1), _SCALARS.index("phi"), _SCALARS.index("gamma")
# What the loop reads of a loop description: ftstab_mj.scenario.LoopSpec has them (the scenario layer
# sits above this one, so the loop asks for the fields instead of the class).
_LOOP_FIELDS = ("name", "z0", "law", "disturbance", "gain", "ref", "sensor", "observer", "actuator")


@dataclass
class RunResult:
    """What a run produced. loops: {loop name: {field: array}} (LOOP_FIELDS, and STAGE_FIELDS for a loop
    with stages; z (n, r), z_measured (n, m), z_hat (n, r), others (n,));
    body_pos (n, nbody, 3), body_quat (n, nbody, 4): the same arrays the sinks received. loops,
    body_pos and body_quat are None for a run that did not keep its samples (``Run(keep_samples=False)``)."""

    status: str
    message: str
    info: RunInfo
    loops: dict | None
    body_pos: np.ndarray | None
    body_quat: np.ndarray | None
    n_samples: int


def steps_per_period(period: float, physics_step: float) -> int:
    """N with period = N * physics_step; ParameterError quoting both numbers otherwise."""
    for name, v in (("physics_step", physics_step), ("period", period)):
        if isinstance(v, bool) or not isinstance(v, (int, float, np.integer, np.floating)) or not (np.isfinite(v) and v > 0):
            raise ParameterError(name, "a finite number > 0 (s)", v)
    n = whole_steps(period, physics_step)
    if n is None:
        raise ParameterError("period", f"an integer multiple of the physics step {physics_step:g} s", period)
    return n


class Simulation:
    """A plant under control, advanced batch by batch with :meth:`advance` while :meth:`installed`.

    Between two batches the state can be saved and restored (:meth:`get_state`, :meth:`set_state`).
    """

    def __init__(self, plant: Plant, loops, period: float, physics_step: float, integrator: str = "euler",
                 divergence_limit: float = 1e6, native="auto"):
        self.N = steps_per_period(period, physics_step)
        self.period, self.physics_step = float(period), float(physics_step)
        if not (isinstance(divergence_limit, (int, float)) and divergence_limit > 0):
            raise ParameterError("divergence_limit", "a number > 0", divergence_limit)
        self.divergence_limit = float(divergence_limit)
        self.plant = plant
        self.loops, laws = self._check_loops(plant, loops)
        self.laws = tuple(law.for_period(self.period) for law in laws)  # implicit discretizations need h
        n, r = plant.n, plant.r
        # each loop's sensor, observer and actuator (None: the loop reads z and applies u exactly)
        self.stages = tuple(build_stages(L.sensor, L.observer, L.actuator, r, self.period, self.N, stream=i)
                            for i, L in enumerate(self.loops))
        self._staged = any(st is not None for st in self.stages)
        # loops whose actuator MuJoCo clamps (a user model's ctrlrange/forcerange kept as its saturation):
        # they record u_applied, the control the plant received, and the true phi is taken with it
        clamps = getattr(plant, "clamps", None)
        self._clamped = tuple(i for i in range(plant.n) if clamps is not None and clamps[i])
        # userdata: each law's state (loop i at state_slices[i]), then each loop's stage state
        # (stage_slices[i]), so that mjSTATE_INTEGRATION saves and restores both
        sizes = [law.state_size for law in self.laws] + [st.state_size if st else 0 for st in self.stages]
        ends = np.cumsum([0] + sizes)
        slices = tuple(slice(int(a), int(b)) for a, b in zip(ends[:-1], ends[1:]))
        self.state_slices, self.stage_slices = slices[:n], slices[n:]
        self.model, self.data, self.model_xml = plant.compile(physics_step, integrator, nuserdata=int(ends[-1]))
        self.integrator = integrator
        # the references: a set point (``ref``, or a constant [reference]) or ref(t) to track
        self.references = tuple(getattr(L, "reference", None) for L in self.loops)
        self.refs = np.array([float(L.ref) if ref is None or not ref.constant else float(ref.value)
                              for L, ref in zip(self.loops, self.references)])
        self._tracking = any(ref is not None and not ref.constant for ref in self.references)
        self._R = None  # per batch: the references' table (advance)
        self._set_initial()
        self._body_ids = np.array([mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, b)
                                   for b in plant.body_names], dtype=int)
        self._z = np.empty((n, r))
        # the loops' dofs (qfrc_applied) and actuators (ctrl): 0..n-1 unless the plant says otherwise
        self._dof = np.arange(n) if plant.dof_ids is None else np.asarray(plant.dof_ids)
        self._act = np.arange(n) if plant.actuator_ids is None else np.asarray(plant.actuator_ids)
        self._u = np.zeros(n)  # control held over the period, chain units
        self._u_applied = np.zeros(n)  # what the plant receives at the sample (the actuator's output)
        self._u_steps = np.zeros((self.N, n))  # ... and at each physics step of the period
        # generalized force per unit of injected phi: a force, or (integrating plants) its increment per step
        self._force_factor = plant.dist_scale * (self.physics_step if plant.integrating else 1.0)
        self._pending = False
        self.stop_reason = ""  # set when the run diverged
        self._rec = None
        self._row = -1
        self._warnings = [self.data.warning[int(k)] for k in _DIVERGENCE_WARNINGS]  # live views of d.warning
        # the laws with a state (a stateless law's advance is not called: it would write nothing)
        self._stateful = tuple(sl.stop > sl.start for sl in self.state_slices)
        self._native = self._native_run(native)
        # one object, so "is it installed" is an identity test
        self.callback = self._control if self._native is None else self._native.callback

    def _set_initial(self) -> None:
        """The state at t = 0 on a fresh (or reset) MjData: each law's initial state in userdata (the stages'
        state starts at sample 0), the plant at the loops' z0 (a tracked reference: q^(j)(0) = ref^(j)(0) + z0_(j+1))."""
        for law, sl in zip(self.laws, self.state_slices):
            self.data.userdata[sl] = law.initial_state()
        z0 = np.array([L.z0 if len(L.z0) else np.zeros(self.plant.r) for L in self.loops], dtype=float)
        if self._tracking:
            R0 = self._reference_table(np.zeros(1))[0]
            self.plant.set_initial(self.model, self.data, R0[:, 0] + z0[:, 0], z0 + R0[:, :self.plant.r])
        else:
            self.plant.set_initial(self.model, self.data, self.refs + z0[:, 0], z0)

    def reset(self, z0) -> None:
        """Start again at t = 0 from the loops' initial states ``z0`` (n, r), each loop's z0 replaced: the
        run that follows is that of a new Simulation of these loops with those z0, bit for bit (the MjData
        reset as a new one is made, plants.base.release_data; the stages' state restarts at sample 0).
        For the native kernel only (a Monte Carlo's states; the Python path keeps more per-run state)."""
        from dataclasses import replace

        if self._native is None:
            raise RuntimeError("Simulation.reset: the Python control path cannot be reset; make a new Simulation")
        z0 = np.asarray(z0, dtype=float)
        if z0.shape != (self.plant.n, self.plant.r) or not np.all(np.isfinite(z0)):
            raise ParameterError("z0", f"{self.plant.n} x {self.plant.r} finite numbers", z0)
        mujoco.mj_resetData(self.model, self.data)
        self.loops = tuple(replace(L, z0=tuple(float(x) for x in z)) for L, z in zip(self.loops, z0))
        self._set_initial()
        self._rec, self._row, self._pending, self.stop_reason = None, -1, False, ""

    def release(self) -> None:
        """Done with this simulation: its MjData serves the next simulation of the same model
        (plants.base.release_data); nothing may use this one afterwards (its ``data`` is None)."""
        data, self.data = self.data, None
        if data is not None:
            release_data(self.model, data)

    def _reference_table(self, t) -> np.ndarray:
        """(len(t), n, r + 1): ref^(j)(t) of every loop, j = 0..r (a set point: ref, then zeros)."""
        r = self.plant.r
        out = np.zeros((len(t), self.plant.n, r + 1))
        for i, ref in enumerate(self.references):
            if ref is None or ref.constant:
                out[:, i, 0] = self.refs[i]
            else:
                out[:, i, :] = ref.derivatives(t, r)
        return out

    def _native_run(self, native):
        """The native callback (ftstab_mj/simulation/native/run.py) when ``native`` (True | False | "auto") asks
        for it and it can run this simulation; None for the Python callback :meth:`_control`."""
        if not native_path.use_native(native):
            return None
        why = native_run.unsupported(self.plant, self.laws, self.loops, self.integrator)
        if why:
            if native is True:
                raise native_path.NativeUnavailable(f"native=True but {why}")
            return None
        run = native_run.NativeRun(self.model, self.data, self.plant, self.loops, self.laws, self.state_slices,
                                   self.refs, self._force_factor, self._body_ids, self.period, self.physics_step, self.N,
                                   self.divergence_limit)
        run.use_stages(self.stages, self.stage_slices, self.physics_step)
        return run

    @staticmethod
    def _check_loops(plant: Plant, loops) -> tuple[tuple, tuple]:
        """(loops, laws) in the plant's loop order; ParameterError naming the loop otherwise."""
        loops = tuple(loops)
        by_name, laws = {}, {}
        for L in loops:
            if not all(hasattr(L, a) for a in _LOOP_FIELDS):
                raise ParameterError("loops", "LoopSpec entries", L)
            if L.name not in plant.loop_names:
                raise ParameterError("loops.name", f"a loop of {plant.model_name!r} ({', '.join(plant.loop_names)})", L.name)
            if L.name in by_name:
                raise ParameterError(f"loops.{L.name}", "one LoopSpec per loop", "a duplicate")
            law = L.law(plant.r)
            if getattr(law, "r", None) != plant.r:
                raise ParameterError(f"loops.{L.name}.controller", f"a law for chain length r = {plant.r}",
                                     getattr(law, "r", law))
            if len(L.z0) not in (0, plant.r) or not np.all(np.isfinite(np.asarray(L.z0, dtype=float))):
                raise ParameterError(f"loops.{L.name}.z0", f"{plant.r} finite numbers", L.z0)
            if L.gain.state_dependent:
                raise ParameterError(f"loops.{L.name}.gain", "a signal that is not state dependent", L.gain.kind)
            by_name[L.name], laws[L.name] = L, law
        missing = [name for name in plant.loop_names if name not in by_name]
        if missing:
            raise ParameterError("loops", f"a LoopSpec for every loop of {plant.model_name!r}", f"none for {missing}")
        return tuple(by_name[name] for name in plant.loop_names), tuple(laws[name] for name in plant.loop_names)

    # -- description ------------------------------------------------------------------------------
    def run_info(self, scenario: dict | None = None, metric_settings: MetricSettings | None = None,
                 duration: float | None = None) -> RunInfo:
        """The run's description; ``duration`` (s): the horizon over which a tracked reference's
        derivatives are bounded (its ref^(r) is part of phi: true_phibar includes max |ref^(r)|)."""
        phibar, gm, gM = self.plant.true_bounds([L.disturbance.bounds() for L in self.loops],
                                                [L.gain.bounds() for L in self.loops])
        metric_settings = metric_settings or MetricSettings()
        infos = []
        for i, (L, law) in enumerate(zip(self.loops, self.laws)):
            ref = self.references[i]
            if ref is not None and not ref.constant:
                described = ref.describe(law.r, duration if duration is not None else 0.0)
                infos.append(LoopInfo(name=L.name, r=law.r, law=law.name, hong=law.base_info(),
                                      law_params=law.param_values(),
                                      true_phibar=float(phibar[i]) + described["max_abs"][law.r],
                                      true_gamma_m=float(gm[i]), true_gamma_M=float(gM[i]),
                                      workspace=self._tracking_workspace(i, ref, described["max_abs"], duration),
                                      stages=None if self.stages[i] is None else describe_stages(
                                          self.stages[i], law, L.z0 if len(L.z0) else np.zeros(law.r)),
                                      certificate_boxes=metric_settings.certificate_boxes,
                                      clamp=self.plant.clamp_texts[i] if i in self._clamped else None,
                                      reference=described))
                continue
            infos.append(LoopInfo(name=L.name, r=law.r, law=law.name, hong=law.base_info(),
                                  law_params=law.param_values(), true_phibar=float(phibar[i]),
                                  true_gamma_m=float(gm[i]), true_gamma_M=float(gM[i]),
                                  workspace=self.plant.loop_workspace(i, float(L.ref)),
                                  stages=None if self.stages[i] is None else describe_stages(
                                      self.stages[i], law, L.z0 if len(L.z0) else np.zeros(law.r)),
                                  certificate_boxes=metric_settings.certificate_boxes,
                                  clamp=self.plant.clamp_texts[i] if i in self._clamped else None))
        return RunInfo(scenario=dict(scenario or {}), loops=tuple(infos), period=self.period,
                       physics_step=self.physics_step, metric_settings=metric_settings,
                       model_xml=self.model_xml, body_names=tuple(self.plant.body_names),
                       kernel="python" if self._native is None else "native")

    def _tracking_workspace(self, i: int, ref, max_abs, duration) -> dict | None:
        """Where loop i's bounds hold, in the error chain of a tracked reference: q = z_1 + ref(t) stays in
        [q_min, q_max] for every ref(t) when z_1 is in [q_min - ref_min, q_max - ref_max], and
        |q^(j)| <= its bound when |z_(j+1)| <= the bound - max |ref^(j)| (0 when the reference alone
        exceeds it: the run then leaves the workspace at once)."""
        t = np.linspace(0.0, duration or 0.0, 2001)
        q = ref.derivatives(t, 0)[:, 0]
        lo, hi = self.plant.loop_workspace(i, float(q.min())), self.plant.loop_workspace(i, float(q.max()))
        if lo is None or hi is None:
            return None
        out = dict(lo)
        out["z1_max"] = hi["z1_max"]
        for key, v in lo.items():
            if key.startswith("z") and key.endswith("_abs_max"):
                j = int(key[1:key.index("_")]) - 1  # z_(j+1) = q^(j) - ref^(j)
                out[key] = max(0.0, float(v) - (max_abs[j] if j < len(max_abs) else 0.0))
        return out

    # -- state ------------------------------------------------------------------------------------
    @property
    def time(self) -> float:
        return float(self.data.time)

    def get_state(self) -> np.ndarray:
        """The full integration state (qpos, qvel, act, ctrl, qfrc_applied, userdata = the laws' states, time)."""
        spec = mujoco.mjtState.mjSTATE_INTEGRATION
        state = np.empty(mujoco.mj_stateSize(self.model, spec))
        mujoco.mj_getState(self.model, self.data, state, spec)
        return state

    def set_state(self, state: np.ndarray) -> None:
        mujoco.mj_setState(self.model, self.data, np.asarray(state, dtype=float), mujoco.mjtState.mjSTATE_INTEGRATION)
        self.stop_reason = ""

    @contextmanager
    def installed(self):
        """Context manager installing this simulation's control callback (previous one restored),
        with MuJoCo's profiling timer off meanwhile (callback.timer_off: half of a bare step)."""
        # the native callback finds its run from the MjData: runs in other threads share it
        with control_callback(self.callback, owner=self, shared=self._native is not None), timer_off():
            yield

    # -- running ----------------------------------------------------------------------------------
    def advance(self, n_samples: int) -> SampleBatch:
        """Run n_samples control periods (fewer if the run diverges: see ``stop_reason``) and return
        their samples. Must be called between samples, with the callback installed."""
        if not holds_slot(self) or mujoco.get_mjcb_control() is not self.callback:
            raise RuntimeError("Simulation.advance needs its control callback installed (use `with sim.installed():`)")
        m, d, N, n = self.model, self.data, self.N, self.plant.n
        # d.time is a running float sum of steps, so it drifts from k * period (1e-10 s after 369,000
        # steps of 1e-4 s). Calls only ever happen at step boundaries, and a boundary inside a period
        # is a whole step away from every sample instant: half a step tells them apart.
        k0 = self._k0 = int(round(d.time / self.period))
        if abs(d.time - k0 * self.period) > 0.5 * self.physics_step:
            raise RuntimeError(f"advance called between samples (t = {d.time!r}, period {self.period!r})")
        # Sample and step times as the ideal chain computes them (t_k + s * period / N).
        self._t = (k0 + np.arange(n_samples)) * self.period
        ts = (self._t[:, None] + np.arange(N) * (self.period / N)).ravel()
        self._inj = np.empty((n_samples * N, n))  # injected phi at each step (state-dependent: filled at samples)
        self._gain = np.empty((n_samples * N, n))
        for i, L in enumerate(self.loops):
            if not L.disturbance.state_dependent:
                self._inj[:, i] = L.disturbance(ts)
            self._gain[:, i] = L.gain(ts)
        # Per step, what the loop writes: the generalized force (r = 2) or its increment over the
        # step (integrating plants: F_d' = scale phi held over the step), and ctrl (filled at samples).
        self._force = self._inj * self._force_factor
        self._ctrl = np.zeros((n_samples * N, n))
        # a tracked reference: ref^(j)(t_k), j = 0..r, of every loop at every sample (None: set points)
        self._R = np.ascontiguousarray(self._reference_table(self._t)) if self._tracking else None
        self._start_batch(n_samples)
        warn0 = self._warning_count()
        if self._native is None:
            self._step_batch(n_samples, warn0)
        else:  # the same work, in C, inside one mj_step(nstep) call
            self._native.clear_rows()  # before the try: the finally below must never see the last batch's count
            self._native.stage_batch(k0, self._rec)
            self._native.record_applied(self._rec)
            self._native.reference_batch(self._R)
            try:
                self._native.run_batch(m, d, self._t, self._inj, self._gain, self._force, self._ctrl, self._rec_t,
                                       self._rec_z, [self._rec_scalars[f] for f in _SCALARS], self._pos, self._quat)
            finally:  # a Ctrl-C comes out right after mj_step: keep what the batch recorded
                self._row = self._native.rows - 1
            self.stop_reason = self._native.stop_reason([L.name for L in self.loops], self.divergence_limit)
        if self._warning_count() != warn0:  # the root cause
            if self._native is not None:  # the kernel steps on past a refused control: keep what the Python path keeps
                self._row = min(self._row, self._first_refused_row())
            t_last = self._t[self._row] if self._row >= 0 else self._t[0] - self.period
            # a bad state makes MuJoCo reset the data (and d.time); a bad control only goes unapplied
            refused = not any(w.number for w in self._warnings[:-1])  # mjWARN_BADCTRL (the last) alone
            self.stop_reason = (f"diverged after the sample at t = {t_last:.6g} s: MuJoCo reported a bad state "
                                f"({self._warning_text()}) and "
                                + ("did not apply the control (NaN or beyond 1e10)" if refused else
                                   "reset the simulation"))
        return self.take_batch()

    def _step_batch(self, n_samples: int, warn0: int) -> None:
        """The Python path of :meth:`advance`: one mj_step per physics step, the per-step inputs
        written here, the law evaluated by :meth:`_control` at the first step of each period."""
        m, d, N = self.model, self.data, self.N
        force, ctrl_steps = self._force, self._ctrl
        ctrl, qfrc = d.ctrl, d.qfrc_applied
        integrating, refresh = self.plant.integrating, self.plant.refresh_before_sample
        step = self.plant.step  # mujoco.mj_step, unless the plant integrates itself (plants/base.py)
        dof, act = self._dof, self._act
        self._python_batch(d)
        # MuJoCo's warning counts: a live view, read as one list a sample (a tenth of the four counters'
        # attributes); any change is looked at, a divergence warning stops the batch
        numbers, divergence = d.warning.number, [int(k) for k in _DIVERGENCE_WARNINGS]
        seen = numbers.tolist()
        for k in range(n_samples):
            base = k * N
            now = numbers.tolist()
            if now != seen:
                if sum(now[i] for i in divergence) != warn0:
                    break
                seen = now
            if refresh:
                mujoco.mj_forward(m, d)
            self._s = base
            self._pending = True
            step(m, d)  # the callback evaluates the law, writes ctrl (and the r = 2 force) and records
            if self.stop_reason:
                break
            if integrating:
                qfrc[dof] += force[base]
            for s in range(base + 1, base + N) if N > 1 else ():
                ctrl[act] = ctrl_steps[s]
                if integrating:
                    step(m, d)
                    qfrc[dof] += force[s]
                else:
                    qfrc[dof] = force[s]
                    step(m, d)

    def _python_batch(self, d) -> None:
        """What the Python callback reuses at every sample of this batch, so that a sample allocates
        nothing it can avoid: views of MjData's arrays and of the records (their memory does not
        move), each loop's (index, law, loop, phi state dependent, law state view, stateful, its
        records of u .. gamma_hat), the sample times recorded in one write (t_k does not depend on
        the run), and the per-step gain and force as Python floats (on a few numbers a float
        product costs a tenth of NumPy's call and rounds the same: IEEE double either way)."""
        self._rec_t[:] = self._t
        self._d_ctrl, self._d_qfrc, self._d_xpos, self._d_xquat = d.ctrl, d.qfrc_applied, d.xpos, d.xquat
        self._z_rows = tuple(self._z)  # loop i's z (r,), a view of self._z
        self._z_flat = self._z.reshape(-1)
        # z_1 - ref: the set points in column 0, 0.0 elsewhere (x - 0.0 is x, bit for bit); none when
        # every set point is +0.0 (x - +0.0 is x: nothing to do)
        self._z_ref = np.zeros_like(self._z)
        self._z_ref[:, 0] = self.refs
        self._ref_zero = self._R is None and not (np.any(self.refs) or np.any(np.signbit(self.refs)))
        # flat: step s, loop i at s n + i (one list of floats is ten times quicker to make than rows)
        self._gain_f, self._force_f = self._gain.ravel().tolist(), self._force.ravel().tolist()
        self._u_f = [0.0] * len(self.loops)
        self._act_f, self._dof_f = tuple(enumerate(self._act.tolist())), tuple(enumerate(self._dof.tolist()))
        self._rec_phi, self._rec_gamma = self._rec_block[_PHI], self._rec_block[_GAMMA]
        self._rec_z_rows = self._rec_z.transpose(1, 0, 2)  # (n_samples, n_loops, r): sample k's z at [k]
        # the recorded bodies' poses: views of xpos, xquat when the bodies are consecutive (a plain copy)
        ids = self._body_ids
        consecutive = len(ids) > 0 and np.array_equal(ids, np.arange(ids[0], ids[0] + len(ids)))
        self._body_rows = (d.xpos[ids[0]:ids[0] + len(ids)], d.xquat[ids[0]:ids[0] + len(ids)]) if consecutive else None
        self._py_loops = tuple((i, law, L, L.disturbance.state_dependent, d.userdata[sl], stateful,
                                tuple(self._rec_block[_OUTPUTS, i]))
                               for i, (law, L, sl, stateful) in enumerate(zip(self.laws, self.loops,
                                                                              self.state_slices, self._stateful)))

    def _first_refused_row(self) -> int:
        """The first sample of this batch whose control MuJoCo refuses (mjWARN_BADCTRL: a ctrl NaN or
        beyond mjMAXVAL = 1e10), else the last row recorded."""
        bad = np.flatnonzero(~(np.abs(self._ctrl[:(self._row + 1) * self.N]) <= MUJOCO_MAXVAL).all(axis=1))
        return int(bad[0]) // self.N if len(bad) else self._row

    def _warning_count(self) -> int:
        return sum([w.number for w in self._warnings])

    def _warning_text(self) -> str:
        return ", ".join(f"{k.name} x{w.number}" for k, w in zip(_DIVERGENCE_WARNINGS, self._warnings) if w.number)

    def _start_batch(self, n_samples: int) -> None:
        # No row recorded yet, set before the new (uninitialised) arrays exist, and _rec last: a
        # Ctrl-C anywhere in here leaves take_batch either the old state taken (None) or 0 rows.
        self._rec = None
        self._row = -1
        n_body, n_loops = len(self._body_ids), len(self.loops)
        # One array per field for all loops (the native callback writes them); each loop's record
        # is a view of its row.
        self._rec_t = np.empty(n_samples)
        self._rec_z = np.empty((n_loops, n_samples, self.plant.r))
        # one block, a contiguous (n_loops, n_samples) array per field (the native callback writes them so)
        self._rec_block = np.empty((len(_SCALARS), n_loops, n_samples))
        self._rec_scalars = dict(zip(_SCALARS, self._rec_block))
        self._pos = np.empty((n_samples, n_body, 3))
        self._quat = np.empty((n_samples, n_body, 4))
        recs = [{"t": self._rec_t, "z": self._rec_z[i], **{f: a[i] for f, a in self._rec_scalars.items()}}
                for i in range(n_loops)]
        for rec, st in zip(recs, self.stages):  # a loop with stages also records what its law saw
            if st is not None:
                rec.update(z_measured=np.empty((n_samples, st.channels)), z_hat=np.empty((n_samples, st.r)),
                           u_applied=np.empty(n_samples))
        for i in self._clamped:  # ... and a loop whose actuator clamps, what the plant received
            recs[i].setdefault("u_applied", np.empty(n_samples))
        self._rec = recs

    def take_batch(self) -> SampleBatch:
        """The samples recorded since the batch started (all of them after a normal advance, the
        completed ones after an interruption), as a SampleBatch of copies; empty when taken twice."""
        if self._rec is None:  # nothing recorded since the last take
            self._start_batch(0)
        k = self._row + 1
        loops = {L.name: {f: a[:k].copy() for f, a in rec.items()} for L, rec in zip(self.loops, self._rec)}
        batch = SampleBatch(loops=loops, body_pos=self._pos[:k].copy(), body_quat=self._quat[:k].copy())
        self._rec = None
        return batch

    # -- the control callback ---------------------------------------------------------------------
    def _control(self, m, d) -> None:
        """MuJoCo's control callback: evaluates the law once per period, returns at once otherwise."""
        if not self._pending:
            return
        self._pending = False
        try:
            self._sample(m, d)
        except Exception as exc:
            raise CallbackError(f"control callback failed at t = {d.time:.6g} s: {type(exc).__name__}: {exc}") from exc

    def _sample(self, m, d) -> None:
        """One control sample, the per-sample pipeline: read z -> each loop's law -> u -> inject, record.
        A stage acting on z (sensor, observer) or on u (actuator) goes between two of these steps.
        It reuses what :meth:`_python_batch` prepared, so that it allocates little beyond what the laws
        and the plant's sense and true_chain do (benchmarks/law_costs.py, column "x hand")."""
        row = self._row + 1
        z = self._read_z(d, row)
        # max |z| <= limit, NaN failing it; on a few floats, Python's abs and compare beat np.abs(z).max()
        if not all(map(self.divergence_limit.__ge__, map(abs, self._z_flat.tolist()))):
            zmax = float(np.abs(z).max())
            self._stop(d, f"diverged at t = {self._t[row]:.6g} s: max |z| = {zmax:.3g} is beyond the divergence "
                          f"limit {self.divergence_limit:g}")
            return
        z_law = self._sense(d, z, row) if self._staged else z
        if not self._control_laws(d, z, row, z_law):
            return
        if self._staged:
            self._actuate(d, row)
        self._inject(m, d, row)

    def _read_z(self, d, row: int) -> np.ndarray:
        """The chain states (n, r) the laws see: the plant's sensors, z_1 relative to the set point (a
        tracked reference: z_i = q^(i-1) - ref^(i-1)(t) at this sample)."""
        z = self._z
        self.plant.sense(d, z)
        if not self._ref_zero:
            np.subtract(z, self._z_ref if self._R is None else self._R[row, :, :-1], out=z)
        return z

    def _sense(self, d, z, row: int) -> np.ndarray:
        """What the laws see (a simulation with stages): z itself, or for a loop with stages its sensor's
        reading through its observer (loop_stages.LoopStages.measure; z_measured and z_hat recorded)."""
        z_law, k, ud = z.copy(), self._k0 + row, d.userdata
        for i, (st, sl, rec) in enumerate(zip(self.stages, self.stage_slices, self._rec)):
            if st is not None:
                z_meas, z_law[i] = st.measure(z[i], k, ud[sl])
                rec["z_measured"][row] = z_meas
                rec["z_hat"][row] = z_law[i]
        return z_law

    def _control_laws(self, d, z, row: int, z_law) -> bool:
        """Evaluate every loop's law at z_law (what it sees), record its outputs with the true z,
        advance its state; u -> self._u. False (and the run stopped) when a control is not finite."""
        self._rec_z_rows[row] = z  # every loop's z record is a row of it (a sample is kept when _inject ends)
        rows = self._z_rows if z_law is z else z_law
        for i, law, L, state_dependent, state, stateful, recs in self._py_loops:
            out = law.evaluate(rows[i], state)
            if state_dependent:  # worst case: held over the period with this sample's dV1/dz_r
                s, t = self._s, self._t[row]
                value = float(L.disturbance(t, out.dV1_dzr))
                self._inj[s:s + self.N, i] = value
                self._force[s:s + self.N, i] = value * self._force_factor[i]
                self._force_f[s * len(self.loops) + i] = float(self._force[s, i])
            u = float(out.u)
            if not math.isfinite(u):
                self._stop(d, f"diverged at t = {self._t[row]:.6g} s: the control of loop {L.name!r} is {u}")
                return False
            self._u[i] = self._u_f[i] = u
            # phi_hat: the law's (robust: phibar / gamma_m), as the ideal chain logs it
            rec_u, rec_u0, rec_V1, rec_dV1, rec_phi_hat, rec_gamma_hat = recs
            rec_u[row] = u
            rec_u0[row] = out.u0
            rec_V1[row] = out.V1
            rec_dV1[row] = out.dV1_dzr
            rec_phi_hat[row] = out.phi_hat
            rec_gamma_hat[row] = out.gamma_hat
            if stateful:
                state[:] = law.advance(rows[i], state, out, self.period)
        return True

    def _actuate(self, d, row: int) -> None:
        """What the plant receives over the period (a simulation with stages): u held, or for a loop with
        an actuator model its output at each physics step (loop_stages.LoopStages.actuate; u_applied
        recorded)."""
        k, ud = self._k0 + row, d.userdata
        self._u_applied[:] = self._u
        self._u_steps[:] = self._u
        for i, (st, sl, rec) in enumerate(zip(self.stages, self.stage_slices, self._rec)):
            if st is not None:
                self._u_applied[i], self._u_steps[:, i] = st.actuate(self._u[i], k, ud[sl], self.physics_step)
                rec["u_applied"][row] = self._u_applied[i]

    def _inject(self, m, d, row: int) -> None:
        """Write the held control (ctrl = gain u) and the disturbance force; record the true phi,
        gamma and the body poses of this sample."""
        s, N = self._s, self.N
        u, u_steps = (self._u_applied, self._u_steps) if self._staged else (self._u, self._u)
        at = s * len(self._u_f)  # step s in the flat lists
        if N == 1 and not self._staged:  # the sample's step only: ctrl = gain u, float by float
            d_ctrl, gain_f, u_f = self._d_ctrl, self._gain_f, self._u_f
            for i, a in self._act_f:
                d_ctrl[a] = gain_f[at + i] * u_f[i]
        else:  # held u times each step's gain; _step_batch writes the other steps' ctrl
            ctrl = self._ctrl[s:s + N]
            np.multiply(self._gain[s:s + N], u_steps, out=ctrl)
            self._d_ctrl[self._act] = ctrl[0]
        if not self.plant.integrating:
            d_qfrc, force_f = self._d_qfrc, self._force_f
            for i, f in self._dof_f:
                d_qfrc[f] = force_f[at + i]
        gain = self._gain[s]
        if self._clamped:  # what MuJoCo's actuator applies (its ctrlrange, forcerange): the phi of the chain
            u = self.plant.applied(u, gain)  # is the rest of q^(r) (h (phi + gamma u_applied) per period)
            for i in self._clamped:
                self._rec[i]["u_applied"][row] = u[i]
        phi, gamma = self.plant.true_chain(m, d, u, gain, self._inj[s])
        if self._R is not None:  # the error chain's: z_r' = q^(r) - ref^(r)
            phi = phi - self._R[row, :, -1]
        self._rec_phi[:, row] = phi  # every loop's at once
        self._rec_gamma[:, row] = gamma
        if self._body_rows is None:
            self._d_xpos.take(self._body_ids, axis=0, out=self._pos[row])
            self._d_xquat.take(self._body_ids, axis=0, out=self._quat[row])
        else:
            self._pos[row], self._quat[row] = self._body_rows
        self._row = row

    def _stop(self, d, reason: str) -> None:
        """Stop the run at this sample (diverged): no control, nothing recorded."""
        self.stop_reason = reason
        d.ctrl[self._act] = 0.0


def sample_count(duration: float, period: float) -> int:
    """Number of control samples of a run (as the ideal chain counts them)."""
    if isinstance(duration, bool) or not isinstance(duration, (int, float, np.integer, np.floating)) or not (
            np.isfinite(duration) and duration > 0):
        raise ParameterError("duration", "a finite number > 0 (s)", duration)
    return max(1, int(round(duration / period)))


class Run:
    """One run of a Simulation, batch by batch, in one direction: the run produces samples and ends
    with a status; whoever drives it (``simulate``, the scenario runner with its sinks) consumes them.

        run = Run(sim, duration=5.0)
        with sim.installed():
            while not run.finished:
                batch = run.step()         # KeyboardInterrupt / an error: batch = run.stop(...)
        result = run.result()              # RunResult: status, message, info, every sample

    ``info`` (RunInfo) describes the run before the first sample. ``step`` advances one batch and
    ends the run "completed" after the last one or "diverged" when the simulation stopped;
    ``stop(status, message)`` ends it early (interrupted, failed) and returns the samples the
    interrupted batch had recorded. With ``keep_samples`` every batch returned is also kept for
    :meth:`result`; without, the run holds no sample once its batch is handed on (flat memory: the
    consumer streams them, e.g. to the logs and ftstab_mj.metrics.run_metrics.MetricsStream).
    """

    def __init__(self, sim: Simulation, duration: float, batch_size: int = 1000, scenario_dict: dict | None = None,
                 metric_settings: MetricSettings | None = None, keep_samples: bool = False):
        if isinstance(batch_size, bool) or not isinstance(batch_size, (int, np.integer)) or batch_size < 1:
            raise ParameterError("batch_size", "an integer >= 1", batch_size)
        self.sim, self.batch_size = sim, int(batch_size)
        self.n_total = sample_count(duration, sim.period)
        self.info = sim.run_info(scenario_dict, metric_settings, duration=self.n_total * sim.period)
        self.status: str | None = None  # None while running
        self.message = ""
        self.done = 0
        self.keep_samples = bool(keep_samples)
        self._batches: list[SampleBatch] = []

    @property
    def finished(self) -> bool:
        return self.status is not None

    def step(self, emit=None) -> SampleBatch:
        """The next batch of samples (the callback installed: ``with run.sim.installed()``).

        emit: called with the batch as it is kept (the sinks' writes): the two happen in one
        :func:`ftstab_mj.simulation.interrupts.critical` block, so a signal never leaves a batch kept for the
        metrics but missing from a log (it stops the run before or after both)."""
        if self.finished:
            raise RuntimeError(f"the run has ended ({self.status})")
        sim = self.sim
        batch = self._keep(sim.advance(min(self.batch_size, self.n_total - self.done)), emit)
        if sim.stop_reason:
            self.status, self.message = DIVERGED, sim.stop_reason
        elif self.done >= self.n_total:
            self.status = COMPLETED
        return batch

    def stop(self, status: str, message: str, emit=None) -> SampleBatch:
        """End the run with ``status`` (INTERRUPTED, FAILED), also after its last batch (a Ctrl-C while
        that batch is being recorded); returns the samples recorded since the last batch (those of a
        batch cut short), empty when there are none. emit: as for :meth:`step`."""
        self.status, self.message = status, message
        return self._keep(self.sim.take_batch(), emit)

    def interrupted(self, stop: Interrupted | None = None, emit=None) -> SampleBatch:
        """:meth:`stop` for a signal (``stop``; None: a Ctrl-C), the message naming it and the
        simulated time it came at ("interrupted (SIGTERM) at t = 1.2 s")."""
        label = (stop or Interrupted()).label
        return self.stop(INTERRUPTED, f"{label} at t = {self.sim.time:.6g} s", emit)

    def _keep(self, batch: SampleBatch, emit=None) -> SampleBatch:
        with critical():
            if self.keep_samples:
                self._batches.append(batch)
            self.done += len(batch)
            if emit is not None:
                emit(batch)
        return batch

    def result(self) -> RunResult:
        """Every sample of the finished run (None without keep_samples), with its status and message."""
        if not self.finished:
            raise RuntimeError("the run has not ended: step it until run.finished, or stop it")
        if not self.keep_samples:
            return RunResult(status=self.status, message=self.message, info=self.info, loops=None,
                             body_pos=None, body_quat=None, n_samples=self.done)
        batches = [b for b in self._batches if len(b)] or [self.sim.take_batch()]
        loops = {name: {f: np.concatenate([b.loops[name][f] for b in batches]) for f in fields}
                 for name, fields in batches[0].loops.items()}
        return RunResult(status=self.status, message=self.message, info=self.info, loops=loops,
                         body_pos=np.concatenate([b.body_pos for b in batches]),
                         body_quat=np.concatenate([b.body_quat for b in batches]), n_samples=self.done)


def simulate(plant: Plant, loops, duration: float, period: float, physics_step: float, integrator: str = "euler",
             batch_size: int = 1000, divergence_limit: float = 1e6, native="auto") -> RunResult:
    """Run ``loops`` (LoopSpec, one per plant loop) on ``plant`` for ``duration`` seconds; the samples
    and the status (completed, diverged or interrupted by Ctrl-C) in a RunResult.

    period: control period (s), an integer multiple of physics_step (s); integrator: "euler"
    (default), "rk4" or "implicitfast"; native: True | False | "auto": the controller in the C
    callback or in Python (see Simulation). Raises CallbackError when the controller raised. To
    record a run (sinks, metrics), drive a :class:`Run` (ftstab_mj.scenario.run.record).
    """
    sim = Simulation(plant, loops, period, physics_step, integrator, divergence_limit, native)
    run = Run(sim, duration, batch_size, keep_samples=True)
    with sim.installed():
        try:
            while not run.finished:
                run.step()
        except KeyboardInterrupt as exc:
            run.interrupted(interruption(exc))
    return run.result()
