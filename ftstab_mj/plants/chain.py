"""Actuated hinge and slide joints of any MuJoCo model as perturbed chains of integrators.

One control loop per actuated joint (``ChainLoop``: the loop name, its joint, the actuator that
drives it, whether that actuator integrates). With M(q) the joint-space inertia (all nv dofs,
passive ones included), f(q, q') = qfrc_passive - qfrc_bias plus the forces of the actuators that
no loop drives, b_i = gain x gear of loop i's actuator, g_i(t) its gain factor (the LoopSpec's gamma
signal) and tau_d the injected disturbance (qfrc_applied on the loop's dof):

* force actuator (r = 2), z = (q_i - ref, q_i'):  M q'' = f + sum_j b_j g_j u_j e_dj + tau_d, so
      gamma_i = g_i b_i (M^-1)_ii,   phi_i = q_i'' - gamma_i u_i
  (phi collects gravity, Coriolis/centrifugal and passive forces, the other loops' torques and the
  passive joints' reaction through M^-1);
* integrating actuator (r = 3: MuJoCo dyntype "integrator", act' = ctrl = g u, torque b act),
  z = (q_i - ref, q_i', q_i''):  z_3' = d/dt [M^-1 (f + B act + tau_d)]_i, so the same gamma_i and
      phi_i = d/dt q_i'' - gamma_i u_i
  = [M^-1 (-M' q'' + f' + sum_{j != i} b_j g_j u_j e_dj + tau_d')]_i, the derivative terms that
  r = 3 brings (tau_d' is the injected force rate).

At run time (true_chain, the record of phi and gamma) q'' is MuJoCo's own smooth acceleration
(mj_fwdActuation + mj_fwdAcceleration on the state of the sample) and d/dt q'' its central
difference along the state's own derivative (q', q'', act', tau_d') over +-EPS seconds, evaluated
on a private MjData; (M^-1)_ii from mj_solveM. The controller sees only the sensors: z_1, z_2
from jointpos / jointvel sensors, z_3 from frame angular (hinge) or linear (slide) acceleration
sensors on the joint's body and its parent, projected on the joint axis; that needs an axis that
keeps its direction in the world (checked), or q'' is not a linear function of sensor readings.

What cannot be a chain is refused with a ParameterError naming the key (see :func:`check_model`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

from ftstab_mj.config.errors import ParameterError
from ftstab_mj.plants.base import Plant

TAU_STEP = 1e-3  # N m or N: half-width of the central difference of q'' in the loop's force (contacts)
EPS = 1e-6  # s: half-width of the central difference of q'' along the trajectory (r = 3)
SENSOR_PREFIX = "ftstab_"  # the sensors the plant adds to a model start with it
_HINGE, _SLIDE = int(mujoco.mjtJoint.mjJNT_HINGE), int(mujoco.mjtJoint.mjJNT_SLIDE)
_JOINT_TYPES = {int(mujoco.mjtJoint.mjJNT_FREE): "free", int(mujoco.mjtJoint.mjJNT_BALL): "ball",
                int(_HINGE): "hinge", int(_SLIDE): "slide"}


@dataclass(frozen=True)
class ChainLoop:
    """One loop: name, the joint (hinge or slide) and the actuator that drives it (joint transmission),
    integrating (the actuator integrates its input: r = 3), saturation (true: a ctrlrange/forcerange
    of the actuator is kept as the actuator's saturation; false: such a range is refused)."""

    name: str
    joint: str
    actuator: str
    integrating: bool = False
    saturation: bool = False


def _name(m, objtype, i) -> str:
    return mujoco.mj_id2name(m, objtype, i) or f"#{i}"


def _geom_name(m, g: int) -> str:
    """A geom as a note names it: its name, or (most models name few geoms) its number and its body's."""
    return mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, g) or (
        f"geom #{g} of body {_name(m, mujoco.mjtObj.mjOBJ_BODY, int(m.geom_bodyid[g]))}")


def check_model(m: mujoco.MjModel, loops, key: str = "params.loops", constraints_key: str = "params",
                joint_ranges: dict | None = None) -> list[str]:
    """Refuse what cannot be a loop (ParameterError naming ``key``.<loop>.<field>); return the notes
    to show the user (saturations honoured). Checks, in order: each loop's joint exists and is hinge
    or slide, its actuator exists, drives that joint through a joint transmission with a fixed gain
    > 0, has the dynamics the loop says (none, or integrator), has no range that would clamp the
    control silently. What the rest of the model adds (contacts, limits, a floating base) is not
    refused: :func:`beyond_chain` says what it is. Returns (notes, the loops' actuator ids)."""
    notes, actuator_ids = [], []
    seen = {}
    for L in loops:
        p = f"{key}.{L.name}"
        j = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, L.joint)
        if j < 0:
            raise ParameterError(f"{p}.joint", "a joint of the model with an actuator (" + (_names(
                {_name(m, mujoco.mjtObj.mjOBJ_JOINT, int(m.actuator_trnid[a, 0])) for a in range(m.nu)
                 if m.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT}, 12) or "the model has none") + ")", L.joint)
        if m.jnt_type[j] not in (_HINGE, _SLIDE):
            raise _refusal(f"{p}.joint", "a hinge or slide joint (one dof, a chain of integrators)",
                                 f"{L.joint!r}, a {_JOINT_TYPES[int(m.jnt_type[j])]} joint")
        if L.joint in seen:
            raise _refusal(f"{p}.joint", "a joint no other loop drives", f"{L.joint!r}, also loop {seen[L.joint]!r}")
        seen[L.joint] = L.name
        driver_ids = [a for a in range(m.nu)
                      if m.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT and m.actuator_trnid[a, 0] == j]
        drivers = [_name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a) for a in driver_ids]
        if not L.actuator:  # omitted: the one actuator driving the joint (it may have no name)
            if len(driver_ids) != 1:
                raise _refusal(f"{p}.actuator", f"the actuator that drives joint {L.joint!r}",
                                     f"none: joint {L.joint!r} is unactuated (no actuator drives it)"
                                     if not drivers else f"none, and joint {L.joint!r} is driven by {', '.join(drivers)}")
            a = driver_ids[0]
        else:
            a = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, L.actuator)
        if a < 0:
            raise ParameterError(f"{p}.actuator", "an actuator of the model (" + (_names(
                [_name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a) for a in range(m.nu)], 12) or "the model has none") + ")", L.actuator)
        named = L.actuator or mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_ACTUATOR, a)
        actuator = f"actuator {named!r}" if named else f"actuator #{a} (unnamed, counted from 0)"  # as the lines below say it
        if m.actuator_trntype[a] != mujoco.mjtTrn.mjTRN_JOINT or m.actuator_trnid[a, 0] != j:
            target = (f"joint {_name(m, mujoco.mjtObj.mjOBJ_JOINT, int(m.actuator_trnid[a, 0]))!r}"
                      if m.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT else "no joint directly (a tendon or site)")
            spring = (spring_between(m, j, int(m.actuator_trnid[a, 0]))
                      if m.actuator_trntype[a] == mujoco.mjtTrn.mjTRN_JOINT else "")
            if spring:  # a flexible joint: relative degree 4 (5 with an integrating actuator), not r = 2 or 3
                raise _refusal(f"{p}.actuator", f"an actuator driving joint {L.joint!r} directly (a user model's "
                                     "loops are r = 2 or 3; through a spring the relative degree is 4, 5 with an "
                                     "integrating actuator: the shipped model 'flexible_joint')",
                                     f"{actuator}, which reaches it through the spring {spring!r}")
            raise _refusal(f"{p}.actuator", f"an actuator driving joint {L.joint!r}"
                                 + (f" ({', '.join(drivers)})" if drivers else " (the model has none: an unactuated joint)"),
                                 f"{actuator}, which drives {target}")
        if m.actuator_gaintype[a] != mujoco.mjtGain.mjGAIN_FIXED:
            raise _refusal(f"{p}.actuator", "an actuator with a fixed gain (gamma from the model)",
                                 f"{actuator} with gaintype {mujoco.mjtGain(m.actuator_gaintype[a]).name[7:].lower()}")
        if not m.actuator_gainprm[a, 0] * m.actuator_gear[a, 0] > 0:
            raise _refusal(f"{p}.actuator", "an actuator with gain x gear > 0 (gamma > 0)",
                                 f"{actuator} with gain {m.actuator_gainprm[a, 0]:g}, gear {m.actuator_gear[a, 0]:g}")
        dyn = mujoco.mjtDyn(m.actuator_dyntype[a])
        want = mujoco.mjtDyn.mjDYN_INTEGRATOR if L.integrating else mujoco.mjtDyn.mjDYN_NONE
        if dyn != want:
            raise _refusal(f"{p}.integrating", f"{str(L.integrating).lower()} only for an actuator with dyntype "
                                 f"{'integrator' if L.integrating else 'none'}", f"{actuator} with dyntype {dyn.name[6:].lower()}")
        ranges = []
        if m.actuator_ctrllimited[a]:
            ranges.append(f"ctrlrange {m.actuator_ctrlrange[a].tolist()}")
        if m.actuator_forcelimited[a]:
            ranges.append(f"forcerange {m.actuator_forcerange[a].tolist()}")
        if m.actuator_actlimited[a]:
            ranges.append(f"actrange {m.actuator_actrange[a].tolist()}")
        if m.jnt_actfrclimited[j]:
            ranges.append(f"joint actuatorfrcrange {m.jnt_actfrcrange[j].tolist()}")
        if ranges and not L.saturation:
            raise _refusal(f"{p}.saturation", "true to keep the actuator's range as its saturation (a "
                                 "discontinuous law must not be clamped silently), or a model without it",
                                 f"{actuator} with {', '.join(ranges)}")
        actuator_ids.append(a)
        if ranges:
            notes.append(f"loop {L.name!r}: {', '.join(ranges)} of {actuator} kept as its saturation: "
                         "the log records the control applied (u_applied) beside the law's u")
    return notes, np.array(actuator_ids, dtype=np.int32)


class Finding(str):
    """A finding the plant wrote itself (a sentence, not a value the user typed): the loader shows it
    whole, never cut to a value's length."""


def _refusal(key: str, allowed: str, given) -> ParameterError:
    """A ParameterError whose finding (a text the plant wrote) is shown whole."""
    return ParameterError(key, allowed, Finding(given) if isinstance(given, str) else given)


def _names(items, most: int = 6) -> str:
    items = list(items)
    head = ", ".join(repr(x) for x in items[:most])
    return head + (f" and {len(items) - most} more" if len(items) > most else "")


def beyond_chain(m: mujoco.MjModel, joint_ranges: dict | None = None) -> tuple[list[str], list[str]]:
    """What of the model lies outside the guarantee of a perturbed chain, and why computed bounds cannot
    be offered: (items, refusals). items: one phrase per kind of thing MuJoCo may add to the joints'
    dynamics beyond M(q) q'' = f(q, q') + actuators (contacts that can happen, joint limits, equality
    constraints, tendon limits, free or ball joints); each is simulated and enters the recorded phi and
    gamma (the full dynamics, plants/chain.py), but no bound the model states covers it. refusals: the
    reasons ``phibar = "computed"`` is refused (a joint limit inside the workspace of the bounds is
    no reason: ``joint_ranges`` {joint: (q_min, q_max)})."""
    items, refusals = [], []
    balls = [(_name(m, mujoco.mjtObj.mjOBJ_JOINT, j), _JOINT_TYPES[int(m.jnt_type[j])])
             for j in range(m.njnt) if m.jnt_type[j] not in (_HINGE, _SLIDE)]
    if balls:
        items.append("a floating base or ball joints (" + ", ".join(f"{n!r} {k}" for n, k in balls[:6])
                     + (f" and {len(balls) - 6} more" if len(balls) > 6 else "") + ")")
        refusals.append("free or ball joints (the bounds' grid covers hinge and slide joints only)")
    if m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CONSTRAINT:
        return items, refusals
    ranges = joint_ranges or {}
    if not m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_LIMIT:
        limited, reached = [], []
        for j in range(m.njnt):
            if m.jnt_limited[j]:
                name = _name(m, mujoco.mjtObj.mjOBJ_JOINT, j)
                limited.append(name)
                lo, hi = m.jnt_range[j] + np.array([1.0, -1.0]) * m.jnt_margin[j]  # the limit acts within its margin
                if not (name in ranges and lo < ranges[name][0] and ranges[name][1] < hi):
                    reached.append(f"{name!r} [{m.jnt_range[j][0]:.4g}, {m.jnt_range[j][1]:.4g}]")
        if limited:
            items.append(f"joint limits ({_names(limited)})")
        if reached:
            refusals.append("joint limits the workspace reaches or that have no workspace: " + ", ".join(reached[:6])
                            + (f" and {len(reached) - 6} more" if len(reached) > 6 else "")
                            + " (a [plant.workspace.<joint>] q strictly inside each limit removes this)")
        if m.ntendon and np.any(m.tendon_limited):
            items.append("tendon limits")
            refusals.append("tendon limits (a limit force has no bound the model states)")
    if m.neq and not m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_EQUALITY:
        items.append(f"{m.neq} equality constraint(s)")
        refusals.append("equality constraints (their forces have no bound the model states)")
    pairs = _contact_pairs(m)
    if pairs:
        items.append(f"contacts that can happen ({_names(pairs, 3)})")
        refusals.append("contacts can happen (a contact force depends on the ground and the impact, not on the "
                        "joints' state alone, so no bound over a joint workspace covers it)")
    return items, refusals


def spring_between(m, j1: int, j2: int) -> str:
    """The name of a fixed tendon with stiffness > 0 whose joints include j1 and j2 (a spring coupling
    them), "" when there is none."""
    for t in range(m.ntendon):
        adr, num = int(m.tendon_adr[t]), int(m.tendon_num[t])
        joints = {int(m.wrap_objid[w]) for w in range(adr, adr + num) if m.wrap_type[w] == mujoco.mjtWrap.mjWRAP_JOINT}
        if {j1, j2} <= joints and np.any(np.asarray(m.tendon_stiffness[t]) > 0):
            return _name(m, mujoco.mjtObj.mjOBJ_TENDON, t)
    return ""


def _contact_pairs(m, most: int = 1000) -> list[str]:
    """The geom pairs that can touch, "a - b" (MuJoCo's filters: contype/conaffinity, same or welded
    bodies, parent-child, <exclude>, explicit <pair>); at most ``most`` of them, [] when none can."""
    if m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_CONTACT:
        return []
    out = [f"{_geom_name(m, int(a))} - {_geom_name(m, int(b))}" for a, b in zip(m.pair_geom1, m.pair_geom2)]
    excluded = {tuple(sorted((int(b1), int(b2)))) for b1, b2 in zip(m.exclude_signature >> 16, m.exclude_signature & 0xFFFF)}
    filter_parent = not m.opt.disableflags & mujoco.mjtDisableBit.mjDSBL_FILTERPARENT
    weld = m.body_weldid
    for g1 in range(m.ngeom):
        for g2 in range(g1 + 1, m.ngeom):
            if not (m.geom_contype[g1] & m.geom_conaffinity[g2] or m.geom_contype[g2] & m.geom_conaffinity[g1]):
                continue
            b1, b2 = int(m.geom_bodyid[g1]), int(m.geom_bodyid[g2])
            w1, w2 = int(weld[b1]), int(weld[b2])
            if w1 == w2 or tuple(sorted((b1, b2))) in excluded:
                continue
            if filter_parent and w1 and w2 and (int(weld[m.body_parentid[w1]]) == w2 or int(weld[m.body_parentid[w2]]) == w1):
                continue
            out.append(f"{_geom_name(m, g1)} - {_geom_name(m, g2)}")
            if len(out) >= most:
                return out
    return out


class ChainPlant(Plant):
    """A MuJoCo model (MjSpec) whose loops (ChainLoop, all with the same ``integrating``) are its actuated
    hinge/slide joints. Subclasses (the arm) or plants.user build the spec; the workspace of the
    bounds is set with :meth:`set_workspace`."""

    def __init__(self, model_name: str, spec: mujoco.MjSpec, loops, key: str = "params.loops",
                 joint_ranges: dict | None = None):
        loops = tuple(loops)
        if not loops:
            raise ParameterError(key, "at least one loop [plant.loops.<name>]", "none")
        kinds = {L.integrating for L in loops}
        if len(kinds) > 1:
            raise ParameterError(f"{key}.{loops[0].name}.integrating", "the same value for every loop (one chain "
                                 "length r per plant)", "a mix of true and false")
        self.integrating = kinds.pop()
        self.r = 3 if self.integrating else 2
        with_sensors = spec.copy()
        m = _compile(spec)
        self.notes, self.actuator_ids = check_model(m, loops, key)
        # what MuJoCo adds beyond the chain (contacts, limits, equality constraints, a floating base):
        # simulated, and part of the recorded phi and gamma (true_chain: the full dynamics), but no
        # computed bound covers it (bounds_refusals)
        self.beyond, self.bounds_refusals = beyond_chain(m, joint_ranges)
        self.constrained = any(not x.startswith("a floating base") for x in self.beyond)
        if self.beyond:
            if self.integrating:
                raise ParameterError(f"{key}.{loops[0].name}.integrating", "false for a model with " + ", ".join(
                    self.beyond) + " (r = 3 needs the derivative of q'', which a contact or limit force does not have)",
                    Finding("true"))
            if self.bounds_refusals:
                self.notes.append(f"model {Path(model_name).name!r} has " + "; ".join(self.beyond) + ": simulated by "
                                  "MuJoCo and part of the recorded phi and gamma (its full dynamics), but not covered "
                                  "by any bound: give phibar and gamma_m by hand, or use a law that needs none (adaptive)")
            else:  # joint limits only, the workspace inside every one
                self.notes.append(f"model {Path(model_name).name!r} has " + "; ".join(self.beyond) + ": simulated by "
                                  "MuJoCo; the workspace of the bounds lies inside every limit, so the computed bounds "
                                  "hold while every joint stays in it (metrics: workspace_left for the loops' joints, and the "
                                  "logged true phi and gamma against the law's bounds: bound_applies_reason)")
        self.chain_loops = loops
        self.loop_names = tuple(L.name for L in loops)
        self.joint_ids = np.array([mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, L.joint) for L in loops])
        self.dof_ids = m.jnt_dofadr[self.joint_ids].astype(np.int32)
        self.qpos_ids = m.jnt_qposadr[self.joint_ids].astype(np.int32)
        # generalized force per unit of ctrl (r = 2) or of act (r = 3): gain x gear
        self.b = m.actuator_gainprm[self.actuator_ids, 0] * m.actuator_gear[self.actuator_ids, 0]
        # what MuJoCo clamps (saturation = true): ctrl to ctrlrange, then (r = 2) the force to forcerange
        a = self.actuator_ids
        inf = np.full(len(a), np.inf)
        on = m.actuator_ctrllimited[a].astype(bool)
        self.ctrl_lo, self.ctrl_hi = np.where(on, m.actuator_ctrlrange[a, 0], -inf), np.where(on, m.actuator_ctrlrange[a, 1], inf)
        fon = m.actuator_forcelimited[a].astype(bool) & (not self.integrating)
        self.force_lo, self.force_hi = np.where(fon, m.actuator_forcerange[a, 0], -inf), np.where(fon, m.actuator_forcerange[a, 1], inf)
        self.gainprm = m.actuator_gainprm[a, 0].copy()
        self.clamps = on | fon  # per loop: the plant may receive another control than the law's u
        self.clamp_texts = tuple(
            ", ".join([f"ctrlrange [{lo:g}, {hi:g}]" for lo, hi, c in [(self.ctrl_lo[i], self.ctrl_hi[i], on[i])] if c]
                      + [f"forcerange [{lo:g}, {hi:g}]" for lo, hi, c in [(self.force_lo[i], self.force_hi[i], fon[i])] if c])
            or None for i in range(len(a)))
        self._readout = _add_sensors(with_sensors, m, loops, self.r, key)
        super().__init__(with_sensors)
        self.model_name = model_name
        self.refresh_before_sample = self.integrating  # z_3 comes from acceleration sensors
        self.dist_scale = np.ones(len(loops))
        self.body_names = tuple(_name(m, mujoco.mjtObj.mjOBJ_BODY, b) for b in range(1, m.nbody))
        self.phi_units = "N m or N (injected joint torque or force" + (" rate, per s)" if self.integrating else ")")
        self.gamma_units = "actuator gain factor (dimensionless, nominal 1; chain gamma = factor x gain x gear x (M^-1)_ii)"
        self._scratch = {}  # id(model) -> (model, private MjData) for the central difference (r = 3)
        self.workspace = None

    def applied(self, u: np.ndarray, gain: np.ndarray) -> np.ndarray:
        """The control each loop's actuator applies for the law's u (chain units) and gain factors: MuJoCo
        clamps ctrl = gain u to the ctrlrange and (r = 2) the force gainprm ctrl to the forcerange; u
        itself, bit for bit, where nothing clamps (the C twin: kernel.c chain_applied). A joint's
        actuatorfrcrange and an actrange are not in it (a note says so)."""
        c = gain * u
        cc = np.minimum(np.maximum(c, self.ctrl_lo), self.ctrl_hi)
        f = self.gainprm * cc
        fc = np.minimum(np.maximum(f, self.force_lo), self.force_hi)
        return np.where(fc != f, fc / (self.gainprm * gain), np.where(cc != c, cc / gain, u))

    def bind(self, m):
        """The sensor readout of z in m's sensordata (plants/base.py: compile calls it)."""
        self._adr, self._w = _readout_arrays(m, self._readout, self.r)

    # -- hooks of the run loop --------------------------------------------------------------------
    def set_initial(self, m, d, q0, z0):
        d.qpos[self.qpos_ids] = q0
        d.qvel[self.dof_ids] = z0[:, 1]
        if self.integrating:  # the actuator states that give q''(0) = z0[:, 2] on the loop joints
            d.act[:] = 0.0
            _smooth_acc(m, d, position=True)
            acc0 = d.qacc_smooth[self.dof_ids].copy()
            A = _minv_cols(m, d, self.dof_ids)[self.dof_ids] * self.b  # d q''_loops / d act
            d.act[m.actuator_actadr[self.actuator_ids]] = np.linalg.solve(A, z0[:, 2] - acc0)

    def sense(self, d, z):
        s = d.sensordata
        for i in range(self.n):
            for j in range(self.r):
                acc = 0.0
                for adr, w in zip(self._adr[i, j], self._w[i, j]):
                    if adr >= 0:
                        acc = acc + w * s[adr]
                z[i, j] = acc

    def true_chain(self, m, d, u, gain, phi_inj):
        """Inside the callback, after ctrl (and the r = 2 disturbance) of the sample were written.
        ``u``: the control the plant receives (u_applied)."""
        if self.constrained:
            return self._full_chain(m, d, u, gain)
        _smooth_acc(m, d)
        minv = _minv_cols(m, d, self.dof_ids)
        gamma = np.empty(self.n)
        for i in range(self.n):
            gamma[i] = gain[i] * (self.b[i] * minv[self.dof_ids[i], i])
        if not self.integrating:
            return d.qacc_smooth[self.dof_ids] - gamma * u, gamma
        s = self._scratch_data(m)
        rate = np.zeros(m.nv)
        rate[self.dof_ids] = self.dist_scale * phi_inj  # d/dt qfrc_applied (the injected force rate)
        qacc = d.qacc_smooth.copy()
        acc = []
        for sign in (1.0, -1.0):
            h = sign * EPS
            s.qpos[:] = d.qpos + h * d.qvel
            s.qvel[:] = d.qvel + h * qacc
            s.act[:] = d.act + h * d.act_dot
            s.qfrc_applied[:] = d.qfrc_applied + h * rate
            s.ctrl[:] = d.ctrl
            _smooth_acc(m, s, position=True)
            acc.append(s.qacc_smooth[self.dof_ids].copy())
        return (acc[0] - acc[1]) / (2.0 * EPS) - gamma * u, gamma

    def _full_chain(self, m, d, u, gain):
        """phi and gamma from MuJoCo's full dynamics (contact, limit and equality forces included), on a
        private MjData holding d's state: q'' = qacc after the constraint solver, gamma_i = g_i b_i
        d q''_i / d tau_i (the constraints included) by a central difference of a generalized force
        on the loop's dof (+-TAU_STEP, the active constraints held: the constraint solver's answer is
        piecewise linear in it), and phi_i = q''_i - gamma_i u_i. d itself is not touched (its own
        solver starts from its warmstart as without this)."""
        s = self._scratch_data(m)
        for name in ("qpos", "qvel", "qfrc_applied", "act", "ctrl"):
            getattr(s, name)[:] = getattr(d, name)
        warm = d.qacc_warmstart.copy()
        mujoco.mj_fwdPosition(m, s)
        mujoco.mj_fwdVelocity(m, s)

        def acc():
            s.qacc_warmstart[:] = warm
            mujoco.mj_fwdActuation(m, s)
            mujoco.mj_fwdAcceleration(m, s)
            mujoco.mj_fwdConstraint(m, s)
            return s.qacc[self.dof_ids].copy()

        qacc = acc()
        gamma = np.empty(self.n)
        for i in range(self.n):
            dof = self.dof_ids[i]
            base = s.qfrc_applied[dof]
            s.qfrc_applied[dof] = base + TAU_STEP
            plus = acc()[i]
            s.qfrc_applied[dof] = base - TAU_STEP
            minus = acc()[i]
            s.qfrc_applied[dof] = base
            gamma[i] = gain[i] * self.b[i] * (plus - minus) / (2.0 * TAU_STEP)
        return qacc - gamma * u, gamma

    def _scratch_data(self, m):
        entry = self._scratch.get(id(m))
        if entry is None or entry[0] is not m:
            self._scratch = {id(m): (m, mujoco.MjData(m))}
            entry = self._scratch[id(m)]
        return entry[1]

    def native_chain(self, m):
        """What the native callback needs to replace sense and true_chain (native/run.py): the sensor
        readout (adr, w: (n, r, K) indices into sensordata, -1 unused, and weights) and the chain map
        (dof ids, qpos ids, actuator ids, b). ``m`` may be None (a question about the plant only)."""
        return {"adr": self._adr, "w": self._w, "dof": self.dof_ids, "act": self.actuator_ids, "b": self.b,
                "clamp": {"on": self.clamps, "ctrl": (self.ctrl_lo, self.ctrl_hi), "force": (self.force_lo, self.force_hi),
                          "gainprm": self.gainprm}}

    def loop_workspace(self, i: int, ref: float) -> dict | None:
        ws = self.workspace
        if ws is None:
            return None
        dof = int(self.dof_ids[i])
        out = {"z1_min": float(ws.q_min[dof] - ref), "z1_max": float(ws.q_max[dof] - ref),
               "z2_abs_max": float(ws.qd_max[dof]), "u_abs_max": float(ws.u_max[i])}
        if self.r == 3:
            out["z3_abs_max"] = float(ws.qdd_max[dof])
        return out

    @property
    def unbounded_reason(self) -> str:
        """Why the bounds are infinite ("" when they are not known to be), every reason in one line."""
        reasons = list(self.bounds_refusals)
        if self.workspace is None:
            reasons.append(self.missing_workspace())
        elif self.integrating and np.any(self._friction(None) > 0):
            reasons.append("dry friction: its rate jumps, so phi of r = 3 has no finite bound")
        return "; ".join(reasons)

    def missing_workspace(self) -> str:
        """What the workspace of the bounds lacks (the arm's is built in: never missing)."""
        return ("no workspace for the bounds: [plant.workspace.<joint>] q, qd_max"
                + (", qdd_max" if self.integrating else "") + " for every joint and u_max in every [plant.loops.<name>]")

    def _friction(self, m):
        m = m if m is not None else self.compile(0.001)[0]
        return np.asarray(m.dof_frictionloss, dtype=float)

    def true_bounds(self, phi_bounds, gamma_bounds):
        from ftstab_mj.plants.chain_bounds import chain_bounds

        n = self.n
        if self.workspace is None or self.bounds_refusals:
            return np.full(n, np.inf), np.zeros(n), np.full(n, np.inf)
        return chain_bounds(self, phi_bounds, gamma_bounds)


# -- helpers ---------------------------------------------------------------------------------------
def _compile(spec):
    from ftstab_mj.plants.callback import control_callback

    with control_callback(None):  # compiling runs a forward pass that would call it
        return spec.copy().compile()


def _smooth_acc(m, d, position: bool = False) -> None:
    """qacc_smooth = M^-1 (passive - bias + applied + actuator) of d's state; the position and velocity
    stages are recomputed when ``position`` (a private MjData), else taken as fresh (the callback)."""
    if position:
        mujoco.mj_fwdPosition(m, d)
        mujoco.mj_fwdVelocity(m, d)
    mujoco.mj_fwdActuation(m, d)
    mujoco.mj_fwdAcceleration(m, d)


def _minv_cols(m, d, dofs) -> np.ndarray:
    """(nv, len(dofs)): the columns ``dofs`` of M^-1 (mj_solveM on unit vectors; M factored in d)."""
    e = np.zeros((len(dofs), m.nv))
    e[np.arange(len(dofs)), dofs] = 1.0
    x = np.empty_like(e)
    mujoco.mj_solveM(m, d, x, e)
    return x.T


def _axis_is_fixed(m, j) -> bool:
    """True when joint j's axis keeps its world direction (and, for a slide, its body does not turn)
    in every configuration: checked at a few random configurations of all joints."""
    d = mujoco.MjData(m)
    rng = np.random.default_rng(0)
    b = m.jnt_bodyid[j]
    axes, quats = [], []
    for _ in range(4):
        d.qpos[:] = rng.uniform(-np.pi, np.pi, size=m.nq)
        mujoco.mj_kinematics(m, d)
        axes.append(d.xaxis[j].copy())
        quats.append(np.concatenate([d.xquat[b], d.xquat[m.body_parentid[b]]]))
    if not np.allclose(axes, axes[0], atol=1e-9):
        return False
    return m.jnt_type[j] == _HINGE or all(np.allclose(np.abs(q), np.abs(quats[0]), atol=1e-9) for q in quats)


def _add_sensors(spec, m, loops, r, key):
    """Add the sensors z is read from to ``spec`` (unless a recorded model already has them) and
    return, per loop and chain entry, the list of (sensor name, component, weight) summed."""
    existing = {s.name for s in spec.sensors}

    def add(name, kind, objtype, objname):
        if name not in existing:
            s = spec.add_sensor()
            s.name, s.type, s.objtype, s.objname = name, kind, objtype, objname
            existing.add(name)
        return name

    readout = []
    for L in loops:
        j = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, L.joint)
        q = add(f"{SENSOR_PREFIX}{L.name}_q", mujoco.mjtSensor.mjSENS_JOINTPOS, mujoco.mjtObj.mjOBJ_JOINT, L.joint)
        qd = add(f"{SENSOR_PREFIX}{L.name}_qd", mujoco.mjtSensor.mjSENS_JOINTVEL, mujoco.mjtObj.mjOBJ_JOINT, L.joint)
        entries = [[(q, 0, 1.0)], [(qd, 0, 1.0)]]
        if r == 3:
            if not _axis_is_fixed(m, j):
                raise ParameterError(f"{key}.{L.name}.integrating", "true only for a joint whose axis keeps its "
                                     "direction in the world (q'' is then read from acceleration sensors)",
                                     f"joint {L.joint!r}, whose axis turns with the joints above it")
            kind = mujoco.mjtSensor.mjSENS_FRAMEANGACC if m.jnt_type[j] == _HINGE else mujoco.mjtSensor.mjSENS_FRAMELINACC
            body = int(m.jnt_bodyid[j])
            child = add(f"{SENSOR_PREFIX}{L.name}_acc", kind, mujoco.mjtObj.mjOBJ_BODY, _name(m, mujoco.mjtObj.mjOBJ_BODY, body))
            parent = add(f"{SENSOR_PREFIX}{L.name}_acc_parent", kind, mujoco.mjtObj.mjOBJ_BODY,
                         _name(m, mujoco.mjtObj.mjOBJ_BODY, int(m.body_parentid[body])))
            d = mujoco.MjData(m)
            mujoco.mj_kinematics(m, d)
            axis = d.xaxis[j].copy()
            entries.append([(child, c, float(axis[c])) for c in range(3) if axis[c] != 0.0]
                           + [(parent, c, -float(axis[c])) for c in range(3) if axis[c] != 0.0])
        readout.append(entries)
    return readout


def _readout_arrays(m, readout, r):
    """(adr, w) (n, r, K): z[i, j] = sum_k w[i, j, k] sensordata[adr[i, j, k]] (adr -1: unused)."""
    K = max(len(e) for loop in readout for e in loop)
    adr = np.full((len(readout), r, K), -1, dtype=np.int32)
    w = np.zeros((len(readout), r, K))
    for i, loop in enumerate(readout):
        for j, entry in enumerate(loop):
            for k, (name, comp, weight) in enumerate(entry):
                sid = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SENSOR, name)
                adr[i, j, k] = m.sensor_adr[sid] + comp
                w[i, j, k] = weight
    return adr, w
