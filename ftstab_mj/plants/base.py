"""What every plant gives the run loop: a compiled MuJoCo model, how to read z, how inputs map to it.

A plant has ``n`` control loops (one per actuated joint), all with the same chain length ``r``.
The loops' joints are dofs ``dof_ids`` and their actuators ``actuator_ids`` (None: ``0..n-1``, as
the carts are written; a ChainPlant maps any model's joints, plants/chain.py).

Input mapping, per loop i, with the signals of its :class:`ftstab_mj.simulation.run_loop.LoopSpec`:

* control: ``ctrl[i] = gain(t) * u`` (gain = the LoopSpec's ``gamma`` signal). The actuator's own
  gain ``gainprm`` is fixed by the plant (the cart: its mass, so that ``gamma`` is in chain units).
  For an integrating actuator MuJoCo has no gain on ``act'`` = ctrl, so writing the gain into ctrl is
  how a gain on the actuator's input is modelled; for force actuators it is the same product.
* injected disturbance: the generalized force ``qfrc_applied[i] = dist_scale[i] * phi(t)``
  (r = 2), or its rate ``d/dt qfrc_applied[i] = dist_scale[i] * phi(t)`` (r = 3, so the force has
  a bounded derivative and phi is that derivative in chain units).

MuJoCo's ``userdata`` holds the controller state that must survive a save/restore of the
simulation state (``mjSTATE_INTEGRATION`` includes it): the run loop asks :meth:`Plant.compile` for
as many slots as its laws have state (ftstab_mj.simulation.run_loop).
"""

from __future__ import annotations

import re
import threading
from dataclasses import dataclass
from typing import Callable

import mujoco
import numpy as np

from ftstab_mj.plants.callback import control_callback
from ftstab_mj.config.errors import ParameterError
from ftstab_mj.config.resources import data_dir
from ftstab_mj.config.validate import number_problem

MODELS_DIR = data_dir("models")


def quiet_mujoco_log() -> None:
    """Turn off MuJoCo's default log handler's outputs, the console line and ``MUJOCO_LOG.TXT`` in the
    working directory, for the whole process (MuJoCo 4.0's mju_setLogConfig).

    Why here, and process-wide: a run reads MuJoCo's warnings from its own MjData's counters
    (d.warning, per run, so per thread of the batch engine) and says them in its own words (a diverged
    run names mjWARN_BADCTRL and its count); MuJoCo's handler printed the first of each beside that and
    left a file in the user's folder. Its configuration is one static struct that the handler reads: set
    once, at the import of the plants (before any model is compiled or stepped), with no Python callback
    called from the simulation threads (mujoco.set_mju_user_warning's would be, under the GIL, and could
    not tell which run warned). MuJoCo's errors are unchanged: the bindings raise them as exceptions."""
    config = mujoco.MjLogConfig.get()
    if config.logto_console or config.logto_file:
        config.logto_console = config.logto_file = False
        config.set()


quiet_mujoco_log()

COMPILED_MODELS = 8  # compiled models kept per process, by MJCF text (Plant.compile)
_COMPILED: dict[str, mujoco.MjModel] = {}
_TEXTS: dict[tuple, str] = {}  # {(plant class, Plant.spec_key, step, integrator, nuserdata): MJCF text}
SPARE_DATA = 4  # finished runs' MjData kept per compiled model for the next runs (release_data)
_SPARE: dict[int, tuple] = {}  # {id(model): (model, [MjData reset])} for the models in _COMPILED
_SPARE_LOCK = threading.Lock()  # the batch engine's threads compile and release at once
# an attribute naming a file the compiler reads: a mesh's, height field's or skin's file, a texture's
# file, fileright, ..., fileback (an attribute value cannot hold a '"': the writer escapes it)
_FILE_ATTRIBUTE = re.compile(r'\sfile[a-z]*="')


def reads_files(xml: str) -> bool:
    """Whether compiling the MJCF text ``xml`` reads files (meshes, height fields, skins, textures):
    then the text alone does not determine the model (the same text in another folder, or after a
    mesh was edited, compiles to another one)."""
    return _FILE_ATTRIBUTE.search(xml) is not None


def model_bytes(m: mujoco.MjModel) -> bytes:
    """The compiled model as MuJoCo's binary MJB (deterministic: equal models, equal bytes)."""
    buf = np.zeros(mujoco.mj_sizeModel(m), dtype=np.uint8)
    mujoco.mj_saveModel(m, None, buf)
    return buf.tobytes()

INTEGRATORS = {"euler": mujoco.mjtIntegrator.mjINT_EULER, "rk4": mujoco.mjtIntegrator.mjINT_RK4,
               "implicitfast": mujoco.mjtIntegrator.mjINT_IMPLICITFAST}


def number(params: dict, key: str, default: float, *, positive=False, nonneg=False) -> float:
    """params[key] (or default) as a finite float, checked; ParameterError names ``params.key``."""
    v = params.get(key, default)
    ok = number_problem(v) is None
    if ok and positive:
        ok = v > 0
    if ok and nonneg:
        ok = v >= 0
    if not ok:
        what = "a finite number" + (" > 0" if positive else " >= 0" if nonneg else "")
        raise ParameterError(f"params.{key}", what, v)
    return float(v)


def check_keys(model: str, params: dict, allowed) -> None:
    """Reject a parameter the model does not know, naming it and listing the known ones."""
    if not isinstance(params, dict):
        raise ParameterError("params", "a table of plant parameters", params)
    for key in params:
        if key not in allowed:
            raise ParameterError(f"params.{key}", f"a parameter of model {model!r} (one of {', '.join(sorted(allowed))})",
                                 key)


def _new_data(model) -> mujoco.MjData:
    """A fresh MjData of ``model``: a finished run's (:func:`release_data`) where one is spare, else a new one."""
    with _SPARE_LOCK:
        entry = _SPARE.get(id(model))
        if entry is not None and entry[0] is model and entry[1]:
            return entry[1].pop()
    return mujoco.MjData(model)


def release_data(model, data) -> None:
    """Give a finished run's MjData of ``model`` (from :meth:`Plant.compile`) to the next run of that model,
    reset to the model's initial state by mj_resetData, which is what a new MjData is made with: the
    same run follows, bit for bit. Why: a new MjData allocates and clears MuJoCo's arena (13.6 MB by
    default, ~0.4 ms: 40 % of the set-up of a sweep row on the cart), a reset does not touch it (2 us).
    The caller must not use ``data`` afterwards."""
    with _SPARE_LOCK:
        entry = _SPARE.get(id(model))
        if entry is None or entry[0] is not model or len(entry[1]) >= SPARE_DATA or any(d is data for d in entry[1]):
            return
        mujoco.mj_resetData(model, data)
        entry[1].append(data)


class Plant:
    """Base of the plants. Subclasses fill the attributes in ``__init__`` and implement the hooks.

    Attributes:
      model_name: the name given to make_plant; params: resolved parameters (defaults filled in).
      loop_names: one name per loop ("cart", or "joint0", "joint1", ...); r: chain length.
      dist_scale: (n,) generalized force per unit of the LoopSpec's phi signal.
      integrating: True when the actuators integrate (r = 3: the disturbance enters as a force rate).
      refresh_before_sample: True when a sensor read by :meth:`sense` is computed after the control
        callback in MuJoCo's forward pass (acceleration stage): the run loop then calls mj_forward
        once before each control sample so that the sensor is not one physics step old.
      body_names: bodies whose poses are recorded (world excluded).
      phi_units, gamma_units: what the LoopSpec's phi and gamma signals mean for this plant
        (chain units for the carts; a joint torque and a motor gain factor for the arm).
      exact_chain_twin: True when the plant's loop is exactly the ideal chain z_r' = phi + gamma u
        (no friction, damping or coupling): ``ftstab montecarlo --on chain`` may run it there.
    """

    model_name: str
    params: dict
    loop_names: tuple[str, ...]
    r: int
    dist_scale: np.ndarray
    integrating: bool = False
    refresh_before_sample: bool = False
    body_names: tuple[str, ...] = ()
    phi_units: str = ""
    gamma_units: str = ""
    dof_ids: np.ndarray | None = None  # (n,) dof of each loop's joint; None: 0..n-1
    actuator_ids: np.ndarray | None = None  # (n,) actuator of each loop; None: 0..n-1
    notes: tuple | list = ()  # lines to show the user about the model (a saturation kept, ...)
    integrators: tuple = tuple(INTEGRATORS)  # the sim.integrator values this plant runs with
    exact_chain_twin: bool = False
    # what determines the spec whole, hashable (a package model file and the parameters that edit it),
    # or None (the spec's text is the key): lets :meth:`compile` skip writing the text of a spec seen before
    spec_key: tuple | None = None

    def __init__(self, spec: mujoco.MjSpec):
        self._spec = spec

    @property
    def n(self) -> int:
        return len(self.loop_names)

    def compile(self, physics_step: float, integrator: str = "euler", nuserdata: int = 0):
        """(MjModel, MjData, MJCF text) for this physics step and integrator, with ``nuserdata``
        userdata slots (the controllers' state); the plant's parameters are unchanged."""
        if integrator not in self.integrators:
            raise ParameterError("integrator", "one of " + ", ".join(self.integrators)
                                 + ("" if self.integrators == tuple(INTEGRATORS) else f" for {self.model_name!r}"), integrator)
        key = None if self.spec_key is None else (type(self), self.spec_key, float(physics_step), integrator,
                                                  int(nuserdata))
        xml = _TEXTS.get(key) if key is not None else None
        with _SPARE_LOCK:
            model = _COMPILED.pop(xml, None) if xml is not None else None
            if model is not None:  # the text of this very spec, 0.4 ms on the cart (a sweep row's largest set-up)
                _COMPILED[xml] = model  # the most recent last
        if model is not None:
            self.bind(model)
            return model, _new_data(model), xml
        spec = self._spec.copy()
        spec.option.timestep = float(physics_step)
        spec.option.integrator = INTEGRATORS[integrator]
        spec.nuserdata = int(nuserdata)
        # the MJCF text is the whole spec (options and userdata size included), so two specs with
        # the same text compile to the same model: a sweep's rows, which differ in initial states
        # and signals, compile their plant once per process (0.14 ms for the text against 0.5 ms
        # for a compile of the cart). Nothing writes into a compiled MjModel; each run has its MjData.
        # Not so for a text that names files (a user model's meshes): those are read at each compile.
        with control_callback(None):  # compiling runs a forward pass that would call it (callback.py),
            xml = spec.to_xml()  # and so may writing the text of a spec not compiled yet
            model = _COMPILED.pop(xml, None)
            if model is None:
                model = spec.compile()
        if not reads_files(xml):
            with _SPARE_LOCK:
                _COMPILED[xml] = model  # the most recent last
                _SPARE.setdefault(id(model), (model, []))
                while len(_COMPILED) > COMPILED_MODELS:
                    _SPARE.pop(id(_COMPILED.pop(next(iter(_COMPILED)))), None)
                if key is not None:
                    if len(_TEXTS) >= 4 * COMPILED_MODELS:
                        _TEXTS.clear()
                    _TEXTS[key] = xml
        self.bind(model)
        return model, _new_data(model), xml

    def bind(self, m) -> None:
        """Read what the hooks below need from a compiled model (sensor addresses). :meth:`compile`
        calls it, so a plant is compiled only when a run (or a question about the model) needs it."""

    # -- hooks used by the run loop ---------------------------------------------------------------
    # One physics step of (m, d): MuJoCo's own for every plant that is a mechanism. A plant whose
    # dynamics MuJoCo cannot express (plants/ideal.py) overrides it; the run loop then uses the
    # Python callback (the native one steps with mj_step in C).
    step = staticmethod(mujoco.mj_step)

    def set_initial(self, m, d, q0: np.ndarray, z0: np.ndarray) -> None:
        """Put the plant at joint positions q0 (n,) and chain state z0 (n, r) (z0[:, 0] is ignored)."""
        raise NotImplementedError

    def sense(self, d, z: np.ndarray) -> None:
        """Write the sensed chain state into z (n, r), z[:, 0] being the joint position (set point not
        subtracted). Called inside the control callback: position/velocity sensors are fresh there."""
        raise NotImplementedError

    def true_chain(self, m, d, u: np.ndarray, gain: np.ndarray, phi_inj: np.ndarray):
        """(phi (n,), gamma (n,)): the true disturbance and gain in chain units at the sample,
        given the controls u, the gain factors and the injected signal values. Never shown to the
        controller."""
        raise NotImplementedError

    def true_bounds(self, phi_bounds, gamma_bounds):
        """(phibar (n,), gamma_m (n,), gamma_M (n,)) in chain units for injected signals within
        phi_bounds[i] = (lo, hi) and gain factors within gamma_bounds[i]."""
        raise NotImplementedError

    def native_sensing(self, m):
        """What the native control callback (ftstab_mj/simulation/native/run.py) needs to replace :meth:`sense`
        and :meth:`true_chain`, or None when they are not of this form (the run then uses Python):
        (adr (n, r) indices into sensordata with z[i, j] = sensordata[adr[i, j]], damping (n,),
        mass (n,)) such that the recorded phi is phi_inj - damping * qvel[i] / mass and gamma the
        gain factor. ``m`` may be None (a question about the plant only)."""
        return None

    def loop_workspace(self, i: int, ref: float) -> dict | None:
        """Where loop i's true bounds hold, in chain units (z_1 = q - ref) and control units:
        {"z1_min", "z1_max", "z2_abs_max", "u_abs_max"}; None when they hold everywhere (the carts).
        Written into LoopInfo so that metrics (live and replay) can tell whether a run stayed there."""
        return None

    def sensor_block(self, m, name: str) -> slice:
        """Slice of d.sensordata holding sensor ``name``."""
        i = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_SENSOR, name)
        adr, dim = int(m.sensor_adr[i]), int(m.sensor_dim[i])
        return slice(adr, adr + dim)


_PARSED: dict[str, mujoco.MjSpec] = {}  # models/<filename> parsed once per process (package data: never changes)


def load_spec(filename: str) -> mujoco.MjSpec:
    """A fresh MjSpec of models/<filename> (the caller may edit it): a copy of the file parsed once per
    process (a copy costs 5 us, parsing 140 us, and every scenario check and run builds a plant)."""
    if filename not in _PARSED:
        _PARSED[filename] = mujoco.MjSpec.from_file(str(MODELS_DIR / filename))
    return _PARSED[filename].copy()


# -- the plant registry ----------------------------------------------------------------------------
@dataclass(frozen=True)
class PlantEntry:
    """A registered plant: ``build(name, params)`` returns the Plant; ``summary`` is one line for
    ``ftstab list`` (chain length, loops, parameters)."""

    name: str
    build: Callable[[str, dict], Plant]
    summary: str


PLANTS: dict[str, PlantEntry] = {}


def register_plant(name: str, build: Callable[[str, dict], Plant], summary: str) -> None:
    """Make ``name`` a model of ``make_plant`` and of the scenario's ``plant.model`` (ftstab_mj.plants)."""
    if name in PLANTS and PLANTS[name].build is not build:
        raise TypeError(f"a plant named {name!r} is already registered")
    PLANTS[name] = PlantEntry(name, build, summary)

