"""The flexible joint (models/flexible_joint.xml): a link driven through a spring, a chain of r = 4 or 5.

A motor rotor (inertia J_m, hinge "motor") drives a link (inertia M_l about its axis, mass m, centre
of mass l_c from the axis, hinge "link", hanging down at q = 0) through a torsional spring of
stiffness K (a fixed tendon q - theta). With gear b, damping d_l (link) and d_m (rotor), the motor
torque b tau and a torque tau_d injected on the rotor (qfrc_applied), MuJoCo integrates

    M_l q'' = -c sin q - K (q - theta) - d_l q',        c = m g l_c
    J_m theta'' = b tau - K (theta - q) - d_m theta' + tau_d

The control enters the link's fourth derivative first: q'''' = ... + K b tau / (J_m M_l), so with
tau = g(t) u (a motor, ``integrating = false``) the link is a chain of r = 4 integrators, and with an
integrating actuator (MuJoCo dyntype "integrator": act' = g u, tau = act; ``integrating = true``) one
of r = 5. In chain units

    z = (q - ref, q', q'', q''' [, q''''])          (rad, rad/s, ...: the link's, never the rotor's)
    gamma = g K b / (J_m M_l),   phi = z_r' - gamma u

The constants c, K, b, J_m, M_l, d_l, d_m are read from the compiled model (mass matrix, tendon
stiffness, gravity torque, actuator gain and gear, dof damping), and z from its state (q, theta,
q', theta', act, tau_d) by the model's equations above and their exact time derivatives
(:func:`link_derivatives`), not finite differences: q'' equals MuJoCo's qacc of the link to 1e-12. tests/test_plants_flexible_joint.py checks them against MuJoCo's dynamics
(q'' against qacc; q''', q'''' and d q''''/du against trajectories integrated by MuJoCo). The
controller sees this exact z; a real joint would need a differentiator or an observer for it.

A user's MJCF of this form (a loop whose actuator reaches its joint through a spring tendon) is this
plant too (:meth:`FlexibleJointPlant.from_model`, built by plants/user.py): the same equations, its
own joint, actuator and tendon names, checked against MuJoCo's accelerations when it is built.

The disturbance is injected on the rotor, matched with the control: a torque tau_d = (J_m M_l / K)
phi_inj adds phi_inj to q'''' (r = 4); for r = 5 the injected torque's rate is that (tau_d(0) = 0).

Bounds (:meth:`FlexibleJointPlant.true_bounds`): phi is an explicit function of z (:func:`phi_of_z`:
for r = 4 without damping, of q, q', q'' only; damping adds q'''; r = 5 adds q''' and, with damping,
q''''), and its bound over the workspace q in [q_min, q_max], |q'| <= qd_max, |q''| <= qdd_max,
|q'''| <= qddd_max, |q''''| <= qdddd_max is an interval enclosure: the (q, q') rectangle is cut into
``cells`` x ``cells`` cells and phi evaluated in interval arithmetic on each (outward rounding, exact
ranges of sin and cos), the rest of the box as whole intervals. So phibar is guaranteed (an upper
bound of sup |phi| over the workspace), tight to O(1/cells); gamma's bounds are exact (gamma does
not depend on the state). The metrics check that a run stayed in the workspace (z_1, z_2, z_3 and
u); for r = 5, and r = 4 with damping, the bound also needs |q'''| <= qddd_max (and |q''''| <=
qdddd_max): the workspace states them (z4_abs_max, z5_abs_max) and the run's metrics check them.
"""

from __future__ import annotations

import mujoco
import numpy as np

from ftstab_mj.config.errors import ParameterError
from ftstab_mj.plants.base import Plant, check_keys, load_spec, number, register_plant
from ftstab_mj.plants.callback import control_callback

MODEL = "flexible_joint"
DEFAULTS = {
    "integrating": False,
    # a soft series-elastic joint: spring modes at sqrt(K/M_l + K/J_m) = 4.5 rad/s (0.7 Hz), slow
    # enough for the chain's phi (spring, gravity) to stay within what a 0.2 ms sampled law absorbs
    "motor_inertia": 0.1,       # kg m^2, J_m (rotor, with the gearbox's reflected inertia)
    "link_mass": 0.3,           # kg
    "link_com": 0.1,            # m, centre of mass from the axis (gravity torque c sin q, c = m g l_c)
    "link_inertia": 0.1,        # kg m^2, M_l about the link's axis (>= m l_c^2)
    "stiffness": 1.0,           # N m/rad, K
    "gear": 1.0,                # the motor torque is gear x tau
    "motor_damping": 0.0,       # N m s/rad, d_m (viscous, on the rotor)
    "link_damping": 0.0,        # N m s/rad, d_l
    # the workspace of the bounds (link): rad, rad/s, rad/s^2, rad/s^3, rad/s^4; u_max: N m (r = 5: N m/s)
    "q_min": -0.2, "q_max": 0.7, "qd_max": 1.5, "qdd_max": 1.5, "qddd_max": 4.0, "qdddd_max": 15.0,
    "u_max": None, "cells": 200,  # u_max: 5 N m (r = 4), 60 N m/s (r = 5); phi does not depend on u (one loop)
}
MAX_CELLS = 2000
SHIPPED = {"link": "link", "motor": "motor", "actuator": "motor", "spring": "spring"}  # names in the file


# -- the model's equations, on floats or on intervals ----------------------------------------------
class Interval:
    """Closed intervals [lo, hi] (numpy arrays), with outward-rounded arithmetic: every result
    contains the exact set of values of its operands' real numbers."""

    __slots__ = ("lo", "hi")

    def __init__(self, lo, hi=None):
        self.lo = np.asarray(lo, dtype=float)
        self.hi = self.lo if hi is None else np.asarray(hi, dtype=float)

    @staticmethod
    def _out(lo, hi):
        return Interval(np.nextafter(lo, -np.inf), np.nextafter(hi, np.inf))

    def __add__(self, o):
        o = _iv(o)
        return Interval._out(self.lo + o.lo, self.hi + o.hi)

    __radd__ = __add__

    def __neg__(self):
        return Interval(-self.hi, -self.lo)

    def __sub__(self, o):
        return self + (-_iv(o))

    def __rsub__(self, o):
        return _iv(o) + (-self)

    def __mul__(self, o):
        o = _iv(o)
        p = (self.lo * o.lo, self.lo * o.hi, self.hi * o.lo, self.hi * o.hi)
        return Interval._out(np.minimum.reduce(p), np.maximum.reduce(p))

    __rmul__ = __mul__

    def sq(self):
        """The exact range of x^2 (not x * x, which loses the dependency)."""
        a, b = self.lo * self.lo, self.hi * self.hi
        lo = np.where((self.lo <= 0) & (self.hi >= 0), 0.0, np.minimum(a, b))
        return Interval._out(lo, np.maximum(a, b))

    def cube(self):
        return Interval._out(self.lo ** 3, self.hi ** 3)  # x^3 is increasing

    def mag(self):
        """sup |x| over the interval."""
        return np.maximum(np.abs(self.lo), np.abs(self.hi))


def _iv(x) -> Interval:
    return x if isinstance(x, Interval) else Interval(x)


def _trig_range(lo, hi, f, top, bottom):
    """The range of f = np.sin or np.cos over [lo, hi] (arrays): the values at the ends, and 1 (-1) when
    a maximum point top + 2 k pi (a minimum point bottom + 2 k pi) lies in the interval (within a
    relative 1e-12: a point at the edge counts), widened by 4 eps and clipped to [-1, 1]."""
    a, b = f(lo), f(hi)
    slack = 1e-12 * (1.0 + np.abs(hi))

    def reached(point):
        first = np.ceil((lo - slack - point) / (2 * np.pi)) * 2 * np.pi + point  # the first such point >= lo
        return first <= hi + slack

    widen = 4 * np.finfo(float).eps
    s_hi = np.where(reached(top), 1.0, np.maximum(a, b) + widen)
    s_lo = np.where(reached(bottom), -1.0, np.minimum(a, b) - widen)
    return Interval(np.maximum(-1.0, s_lo), np.minimum(1.0, s_hi))


def sin(x):
    return _trig_range(x.lo, x.hi, np.sin, np.pi / 2, -np.pi / 2) if isinstance(x, Interval) else np.sin(x)


def cos(x):
    return _trig_range(x.lo, x.hi, np.cos, 0.0, np.pi) if isinstance(x, Interval) else np.cos(x)


def sq(x):
    return x.sq() if isinstance(x, Interval) else x * x


def cube(x):
    return x.cube() if isinstance(x, Interval) else x * x * x


def link_derivatives(k: dict, q, th, v, w, tau, tau_rate=0.0, taud=0.0, taud_rate=0.0, n: int = 5):
    """The link's (q, q', ..., q^(n-1)) at the state (link angle q, rotor angle th, their rates v, w),
    motor torque ``tau`` (gear included) and its rate, injected rotor torque ``taud`` and its rate:
    the model's equations (module docstring) and their exact time derivatives. ``k``: the constants
    (c, K, M, J, dl, dm) of :meth:`FlexibleJointPlant.constants`. n <= 6."""
    c, K, M, J, dl, dm = k["c"], k["K"], k["M"], k["J"], k["dl"], k["dm"]
    sq_, cq = np.sin(q), np.cos(q)
    a = (-c * sq_ - K * (q - th) - dl * v) / M
    th2 = (tau - K * (th - q) - dm * w + taud) / J
    j = (-c * cq * v - K * (v - w) - dl * a) / M
    s = (c * (sq_ * v * v - cq * a) - K * (a - th2) - dl * j) / M
    th3 = (tau_rate - K * (w - v) - dm * th2 + taud_rate) / J
    p = (c * (cq * v ** 3 + 3 * sq_ * v * a - cq * j) - K * (j - th3) - dl * s) / M
    return (q, v, a, j, s, p)[:n]


def phi_of_z(k: dict, r: int, z):
    """phi = z_r' - gamma u as a function of the link's z = (q, q', q'', q''' [, q'''']) (absolute q),
    without the injected part (which adds phi_inj): floats or :class:`Interval` s. The rotor's state
    is eliminated with the model's equations (module docstring)."""
    c, K, M, J, dl, dm = k["c"], k["K"], k["M"], k["J"], k["dl"], k["dm"]
    q, v, a, j = z[0], z[1], z[2], z[3]
    s_, c_ = sin(q), cos(q)
    MJ = M * J
    if r == 4:
        return ((c / M) * (s_ * sq(v)) - (K * (dl + dm) / MJ) * v - (dm * c / MJ) * (c_ * v) - (c / M) * (c_ * a)
                - (K / M + K / J + dm * dl / MJ) * a - (dl / M + dm / J) * j - (K * c / MJ) * s_)
    s = z[4]
    return ((c / M) * (c_ * cube(v)) + (3 * c / M) * (s_ * (v * a)) + (dm * c / MJ) * (s_ * sq(v))
            - (K * c / MJ) * (c_ * v) - (c / M) * (c_ * j) - (K / M + K / J + dm * dl / MJ) * j
            - (K * (dl + dm) / MJ) * a - (dm * c / MJ) * (c_ * a) - (dl / M + dm / J) * s)


# -- the plant -------------------------------------------------------------------------------------
class FlexibleJointPlant(Plant):
    """The flexible joint, one loop "link" (module docstring); ``params["integrating"]`` selects r = 5."""

    def __init__(self, model_name: str, params: dict):
        check_keys(model_name, params, DEFAULTS)
        integrating = params.get("integrating", DEFAULTS["integrating"])
        if not isinstance(integrating, bool):
            raise ParameterError("params.integrating", "true or false", integrating)
        defaults = dict(DEFAULTS, u_max=60.0 if integrating else 5.0)
        p = {key: number(params, key, defaults[key], positive=key in ("motor_inertia", "link_mass", "link_inertia",
                                                                         "stiffness", "gear"),
                         nonneg=key in ("link_com", "motor_damping", "link_damping", "qd_max", "qdd_max",
                                        "qddd_max", "qdddd_max", "u_max"))
             for key in DEFAULTS if key not in ("integrating", "cells")}
        cells = params.get("cells", DEFAULTS["cells"])
        if isinstance(cells, bool) or not isinstance(cells, int) or not 1 <= cells <= MAX_CELLS:
            raise ParameterError("params.cells", f"an integer in [1, {MAX_CELLS}] (cells per axis of the bounds)", cells)
        if p["q_min"] >= p["q_max"]:
            raise ParameterError("params.q_max", "a number above q_min", p["q_max"])
        own = p["link_inertia"] - p["link_mass"] * p["link_com"] ** 2  # about the centre of mass
        if not own > 1e-9:
            raise ParameterError("params.link_inertia", f"more than link_mass x link_com^2 = "
                                 f"{p['link_mass'] * p['link_com'] ** 2:.6g} kg m^2 (the inertia about the axis)",
                                 p["link_inertia"])
        spec = load_spec("flexible_joint.xml")
        rotor = spec.body("rotor")
        rotor.inertia = [p["motor_inertia"]] * 3
        link = spec.body("link")
        link.mass = p["link_mass"]
        link.ipos = [0.0, 0.0, -p["link_com"]]
        link.inertia = [own] * 3
        spec.tendon("spring").stiffness = [p["stiffness"], 0.0, 0.0]
        spec.joint("motor").damping = [p["motor_damping"], 0.0, 0.0]
        spec.joint("link").damping = [p["link_damping"], 0.0, 0.0]
        actuator = spec.actuator("motor")
        actuator.gear = [p["gear"], 0, 0, 0, 0, 0]
        if integrating:  # act' = ctrl (the torque rate), torque = gear x act
            actuator.dyntype = mujoco.mjtDyn.mjDYN_INTEGRATOR
        self._setup(spec, model_name, {"integrating": integrating, **p, "cells": cells}, "link", SHIPPED)

    def _setup(self, spec, model_name: str, params: dict, loop: str, names: dict, key: str = "params") -> None:
        """Attributes from the (edited) spec whose joints, actuator and spring tendon ``names`` gives
        ({"link", "motor", "actuator", "spring"}); ``params`` holds integrating, cells and the workspace
        (q_min, ..., u_max; q_min None: no bounds); ``key`` names the structure in a refusal."""
        Plant.__init__(self, spec)
        self.model_name = model_name
        self.params = self.ws = params  # ws: the workspace of the bounds (from_model: params are the user's)
        self.integrating = integrating = params["integrating"]
        self.r = 5 if integrating else 4
        self.loop_names = (loop,)
        self.names = names
        self.cells = params["cells"]
        self.k = self.constants(key)
        m = self.compile(0.001)[0]
        self.body_names = tuple(mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_BODY, b) or f"#{b}" for b in range(1, m.nbody))
        K, M, J, b = self.k["K"], self.k["M"], self.k["J"], self.k["b"]
        self.gamma_nominal = K * b / (J * M)  # chain gamma per unit gain factor: d z_r' / d u
        self.dist_scale = np.array([J * M / K])  # rotor torque (N m; r = 5: N m/s) per unit of phi_inj
        self.dof_ids = np.array([self._motor_dof], dtype=np.int32)  # phi is injected on the rotor (matched)
        self.actuator_ids = np.array([self._actuator], dtype=np.int32)
        units = "rad/s^5" if integrating else "rad/s^4"
        self.phi_units = f"{units} (chain units: the link's z_{self.r}' = phi + gamma u; injected on the rotor)"
        self.gamma_units = (f"{units} per unit u (chain gamma = gain factor x K gear / (J_m M_l) = factor x "
                            f"{self.gamma_nominal:.6g}; u is the motor torque{' rate' if integrating else ''})")
        self._bound_cache = {}

    @classmethod
    def from_model(cls, spec, path: str, params: dict, loop: str, names: dict, workspace: dict, key: str):
        """The plant of a user's model (plants/user.py): ``spec`` its MjSpec, ``params`` the user's
        (recorded, so that the same call rebuilds it), ``names`` as in :meth:`_setup`, ``workspace``
        integrating, cells, q_min, ..., u_max (q_min None: no bounds)."""
        plant = cls.__new__(cls)
        plant._setup(spec, path, workspace, loop, names, key)
        plant.params = params
        return plant

    def constants(self, key: str = "params") -> dict:
        """c, K, M (= M_l), J (= J_m), dl, dm, b (= gear x gain) read from the compiled model, which is
        checked to be this mechanism (else ParameterError naming ``key``): two hinges with a constant
        diagonal mass matrix, coupled only by the spring, whose accelerations at random states and
        controls are the module docstring's equations, so that d q''/du = d q'''/du = 0 and
        d q''''/du = K b / (J_m M_l) > 0: a chain of r = 4 (5 integrating)."""
        m, d, _ = self.compile(0.001)
        # its forward passes call MuJoCo's control callback: a Python-path run stepping in another thread
        # (the batch engine's, a Dask worker's) would take the call for its own and sample this MjData
        with control_callback(None):  # so they wait for the slot, as a compile does (callback.py)
            return self._read_constants(m, d, key)

    def _read_constants(self, m, d, key: str) -> dict:
        """:meth:`constants` of the compiled (m, d), with MuJoCo's control callback slot cleared."""
        jid = {name: mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, self.names[name]) for name in ("link", "motor")}
        self._link_dof, self._motor_dof = (int(m.jnt_dofadr[jid[name]]) for name in ("link", "motor"))
        self._actuator = a = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, self.names["actuator"])
        spring = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_TENDON, self.names["spring"])
        L, R = self._link_dof, self._motor_dof
        expected = ("a flexible joint (r = 4): a rotor hinge and a link hinge coupled only by a spring, "
                    "M_l q'' = -c sin q - K (q - theta) - d_l q', J_m theta'' = gear u - K (theta - q) - d_m theta'")
        if m.nv != 2 or m.nu != 1:
            raise ParameterError(key, expected, f"a model of {m.nv} degrees of freedom and {m.nu} actuators")
        d.qpos[:] = 0.0
        d.qvel[:] = 0.0
        d.qpos[L] = np.pi / 2  # the gravity torque's amplitude: qfrc_bias = c sin q at rest
        mujoco.mj_forward(m, d)
        M = np.empty((m.nv, m.nv))
        mujoco.mj_fullM(m, d, M)
        if M[L, R] != 0.0 or M[R, L] != 0.0:
            raise ParameterError(key, expected, f"rotor and link inertias coupled (M_12 = {M[L, R]:.6g} kg m^2)")
        k = {"c": float(d.qfrc_bias[L]), "K": float(m.tendon_stiffness[spring]), "M": float(M[L, L]),
             "J": float(M[R, R]), "dl": float(m.dof_damping[L]), "dm": float(m.dof_damping[R]),
             "b": float(m.actuator_gainprm[a, 0] * m.actuator_gear[a, 0])}
        if not (k["K"] > 0 and k["b"] > 0):
            raise ParameterError(key, expected, f"K = {k['K']:.6g} N m/rad, gear x gain = {k['b']:.6g} (both > 0)")
        # MuJoCo's accelerations against the equations at a few states and torques drawn once (a
        # user's model: the spring's coefficients, gravity's zero angle, stray forces would show here)
        rng = np.random.default_rng(0)
        for _ in range(8):
            d.qpos[L], d.qpos[R], d.qvel[L], d.qvel[R] = rng.uniform(-2.0, 2.0, 4)
            tau = float(rng.uniform(-1.0, 1.0))
            d.ctrl[:] = 0.0
            if self.integrating:
                d.act[0] = tau
            else:
                d.ctrl[a] = tau
            mujoco.mj_forward(m, d)
            q, th, v, w = d.qpos[L], d.qpos[R], d.qvel[L], d.qvel[R]
            acc = link_derivatives(k, q, th, v, w, k["b"] * tau, n=3)[2]
            th2 = (k["b"] * tau - k["K"] * (th - q) - k["dm"] * w) / k["J"]
            scale = abs(k["c"]) + 4.0 * k["K"] + k["b"] + 2.0 * (k["dl"] + k["dm"])  # the forces' size here
            err = max(abs(d.qacc[L] - acc) * k["M"], abs(d.qacc[R] - th2) * k["J"]) / scale
            if not err <= 1e-9:
                raise ParameterError(key, expected, f"MuJoCo's torques off these equations by {err:.2g} (relative) "
                                     f"at q = {q:.3g}, theta = {th:.3g} rad")
        return k

    # -- the state ---------------------------------------------------------------------------------
    def derivatives(self, m, d, control: float = 0.0, taud_rate: float = 0.0, n: int | None = None):
        """The link's (q, q', ..., q^(n-1)) (n: r + 1 by default) at d's state: torque (r = 4: gear x
        ctrl, r = 5: gear x act) and injected torque from d, ``control`` the torque rate (r = 5)."""
        k, L, R = self.k, self._link_dof, self._motor_dof
        if self.integrating:
            tau, rate = k["b"] * d.act[0], k["b"] * control
        else:
            tau, rate = k["b"] * d.ctrl[0], 0.0
        return link_derivatives(k, d.qpos[L], d.qpos[R], d.qvel[L], d.qvel[R], tau, rate, d.qfrc_applied[R],
                                taud_rate, self.r + 1 if n is None else n)

    def set_initial(self, m, d, q0, z0):
        k, L, R = self.k, self._link_dof, self._motor_dof
        c, K, M, J, dl, dm = k["c"], k["K"], k["M"], k["J"], k["dl"], k["dm"]
        q, v, a, j = float(q0[0]), *(float(x) for x in z0[0, 1:4])
        th = q + (M * a + c * np.sin(q) + dl * v) / K
        w = v + (M * j + c * np.cos(q) * v + dl * a) / K
        d.qpos[L], d.qpos[R], d.qvel[L], d.qvel[R] = q, th, v, w
        if self.integrating:  # the torque that gives q''''(0) = z0[0, 4], with tau_d(0) = 0
            s = float(z0[0, 4])
            th2 = (M * s - c * np.sin(q) * v * v + c * np.cos(q) * a + K * a + dl * j) / K
            d.act[0] = (J * th2 + K * (th - q) + dm * w) / k["b"]

    def sense(self, d, z):
        z[0, :] = self.derivatives(None, d, n=self.r)

    def true_chain(self, m, d, u, gain, phi_inj):
        """phi = z_r' - gamma u from the state, the injected torque (r = 4) or its rate (r = 5)."""
        gamma = gain * self.gamma_nominal
        if self.integrating:  # q^(5) with act' = 0 and the injected torque's rate
            phi = self.derivatives(m, d, 0.0, float(self.dist_scale[0] * phi_inj[0]))[5]
        else:  # q'''' with no motor torque
            k = self.k
            phi = link_derivatives(k, d.qpos[self._link_dof], d.qpos[self._motor_dof], d.qvel[self._link_dof],
                                   d.qvel[self._motor_dof], 0.0, 0.0, d.qfrc_applied[self._motor_dof])[4]
        return np.array([phi]), np.asarray(gamma, dtype=float).copy()

    # -- bounds ------------------------------------------------------------------------------------
    def _needs(self) -> int:
        """How many entries of z phi depends on: 3 (q, q', q''), 4 (and q''') or 5 (and q'''')."""
        damped = self.k["dl"] > 0 or self.k["dm"] > 0
        return (5 if damped else 4) if self.integrating else (4 if damped else 3)

    def workspace_box(self):
        """The workspace as the box of z (absolute q): [(lo, hi)] * r."""
        p = self.ws
        box = [(p["q_min"], p["q_max"]), (-p["qd_max"], p["qd_max"]), (-p["qdd_max"], p["qdd_max"]),
               (-p["qddd_max"], p["qddd_max"]), (-p["qdddd_max"], p["qdddd_max"])]
        return box[:self.r]

    def phi_state_bound(self) -> float:
        """sup |phi_of_z| over the workspace, guaranteed: interval enclosures on cells x cells cells of
        the (q, q') rectangle, the other entries whole (module docstring); cached."""
        if self.ws["q_min"] is None:  # a user's model without a workspace
            return np.inf
        if "state" not in self._bound_cache:
            box, n = self.workspace_box(), self.cells
            (q0, q1), (v0, v1) = box[0], box[1]
            qe, ve = np.linspace(q0, q1, n + 1), np.linspace(v0, v1, n + 1)
            lo_q, lo_v = np.meshgrid(qe[:-1], ve[:-1], indexing="ij")
            hi_q, hi_v = np.meshgrid(qe[1:], ve[1:], indexing="ij")
            Q, V = Interval(lo_q, hi_q), Interval(lo_v, hi_v)
            z = [Q, V] + [Interval(np.full(Q.lo.shape, lo), np.full(Q.lo.shape, hi)) for lo, hi in box[2:]]
            while len(z) < 5:
                z.append(Interval(0.0))
            self._bound_cache["state"] = float(phi_of_z(self.k, self.r, z).mag().max())
        return self._bound_cache["state"]

    def true_bounds(self, phi_bounds, gamma_bounds):
        (plo, phi_hi), = phi_bounds
        (glo, ghi), = gamma_bounds
        if not glo > 0:
            raise ParameterError("gamma", "gain factors > 0 for the bounds", glo)
        # the injected phi_inj adds to phi with coefficient 1; one more relative 1e-12 for the rounding
        # of the constants and of this sum
        phibar = (self.phi_state_bound() + max(abs(plo), abs(phi_hi))) * (1 + 1e-12)
        return np.array([phibar]), np.array([glo * self.gamma_nominal]), np.array([ghi * self.gamma_nominal])

    @property
    def unbounded_reason(self) -> str:
        """Why the bounds are infinite: "" when a workspace is stated."""
        if self.ws["q_min"] is not None:
            return ""
        need = ("q, qd_max, qdd_max" + (", qddd_max" if self._needs() >= 4 else "")
                + (", qdddd_max" if self._needs() >= 5 else ""))
        return (f"no workspace for the bounds: add [plant.workspace.{self.names['link']}] {need} and u_max in "
                f"[plant.loops.{self.loop_names[0]}]")

    def loop_workspace(self, i: int, ref: float) -> dict | None:
        p = self.ws
        if p["q_min"] is None:
            return None
        out = {"z1_min": p["q_min"] - ref, "z1_max": p["q_max"] - ref, "z2_abs_max": p["qd_max"],
               "z3_abs_max": p["qdd_max"], "u_abs_max": p["u_max"]}
        if self._needs() >= 4:
            out["z4_abs_max"] = p["qddd_max"]
        if self._needs() >= 5:
            out["z5_abs_max"] = p["qdddd_max"]
        return out


register_plant(MODEL, FlexibleJointPlant,
               "r = 4, one loop 'link': a link under gravity driven through a spring by a motor rotor (flexible "
               "joint); integrating = true: the motor's torque rate is the control, r = 5 (params: motor_inertia, "
               "link_mass, link_com, link_inertia, stiffness, gear, motor_damping, link_damping; bounds' "
               "workspace: q_min, q_max, qd_max, qdd_max, qddd_max, qdddd_max, u_max, cells)")
