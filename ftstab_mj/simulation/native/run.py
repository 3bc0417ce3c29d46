"""The native control callback of the MuJoCo run loop (the C twin of sim.Simulation._sample).

:class:`NativeRun` configures ``ft_control_callback`` (kernel.c) for one Simulation: the addresses
of the MjData arrays it reads and writes, the laws, the plant's sensor map. The run loop then hands
it each batch's per-step inputs and record arrays and steps the whole batch with
``mj_step(m, d, nstep)``: no Python runs between two physics steps.

The callback needs the address of ``d->time``, which the Python bindings do not expose; it is
found once by writing two sentinel times and locating them in the mjData struct (so the C code
does not depend on the struct's layout). With a plant whose sensors are refreshed before each
sample (plants/base.py ``refresh_before_sample``), the callback calls MuJoCo's own
``mj_forwardSkip`` (from the libmujoco the bindings loaded) for the stages after velocity: the
same sensor values as the Python loop's mj_forward before the step, without redoing the position and velocity stages.
"""

from __future__ import annotations

import ctypes
import functools
import weakref
from pathlib import Path

import mujoco
import numpy as np

from ftstab_mj.simulation import native
from ftstab_mj.simulation.native import FtInput, FtLaw, pack_law, require_buffer

MAXLOOPS = 8  # FT_MAXLOOPS in kernel.c
INTEGRATORS = ("euler", "implicitfast")  # one forward pass (one callback call) per step

_p = ctypes.c_void_p
_d = ctypes.c_double
_i32 = ctypes.c_int32
_i64 = ctypes.c_int64


class FtRun(ctypes.Structure):
    """Mirror of ft_run in kernel.c (same field order and types)."""

    _fields_ = [
        ("time", _p), ("ctrl", _p), ("qfrc_applied", _p), ("userdata", _p),
        ("sensordata", _p), ("qvel", _p), ("xpos", _p), ("xquat", _p), ("mj_forward_skip", _p), ("skip_stage", _i32),
        ("n", _i32), ("N", _i32), ("integrating", _i32), ("nbody", _i32),
        ("sensor_adr", _p), ("body_ids", _p), ("refs", _p), ("laws", _p), ("phi_damping", _p), ("phi_mass", _p),
        ("phi_state", _p), ("state_phi", _p), ("force_factor", _p), ("state_adr", _p),
        ("period", _d), ("h", _d), ("divergence_limit", _d),
        ("t0", _d), ("nsteps", _i64), ("t", _p), ("inj", _p), ("force", _p), ("ctrl_steps", _p), ("gain", _p),
        ("u_held", _p), ("rec_t", _p), ("rec_z", _p), ("rec", _p * 8), ("body_pos", _p), ("body_quat", _p),
        ("samples", _i64),
        ("last_step", _i64), ("row", _i64), ("status", _i32), ("bad_loop", _i32),
        ("bad_value", _d), ("bad_time", _d), ("busy", _i32),
        ("stages", _p), ("stage_on", _p), ("stage_adr", _p), ("k0", _i64), ("u_steps", _p),
        ("rec_zm", _p * MAXLOOPS), ("rec_zh", _p * MAXLOOPS), ("rec_ua", _p * MAXLOOPS),
        ("chain", _p), ("ref_table", _p),
    ]


class FtChain(ctypes.Structure):
    """Mirror of ft_chain in kernel.c (a chain plant's readout and truth, plants/chain.py)."""

    _fields_ = [
        ("K", _i32), ("nv", _i32), ("nq", _i32), ("na", _i32), ("nu", _i32), ("integrating", _i32),
        ("adr", _p), ("w", _p), ("dof", _p), ("act", _p), ("b", _p), ("dist_scale", _p),
        ("fwd_position", _p), ("fwd_velocity", _p), ("fwd_actuation", _p), ("fwd_acceleration", _p), ("solve_m", _p),
        ("qpos", _p), ("qvel", _p), ("act_state", _p), ("act_dot", _p), ("qacc_smooth", _p), ("qfrc_applied", _p),
        ("ctrl", _p),
        ("s", _p), ("s_qpos", _p), ("s_qvel", _p), ("s_act", _p), ("s_qfrc_applied", _p), ("s_ctrl", _p),
        ("s_qacc_smooth", _p), ("eps", _d), ("work", _p),
        ("clamp_on", _p), ("ctrl_lo", _p), ("ctrl_hi", _p), ("force_lo", _p), ("force_hi", _p), ("gainprm", _p),
        ("full", _i32), ("fwd_constraint", _p), ("qacc_warmstart", _p), ("s_qacc_warmstart", _p), ("warm", _p),
        ("s_qacc", _p), ("tau_step", _d),
    ]


def _lib():
    lib = native.LIB
    if not hasattr(lib, "_ft_run_ready"):
        if lib.ft_run_size() != ctypes.sizeof(FtRun):
            raise native.NativeUnavailable("the C kernel does not match this ftstab_mj version (rebuild it)")
        lib.ft_run_activate.argtypes = [_p, _p, _p]
        lib.ft_run_activate.restype = _i32
        for name in ("ft_run_finish", "ft_run_forget"):
            getattr(lib, name).argtypes = [_p, _p]
            getattr(lib, name).restype = None
        lib._ft_run_ready = True
    return lib


LAYOUT_POINTERS = ("ctrl", "qfrc_applied", "userdata", "sensordata", "qvel", "xpos", "xquat")  # ft_layout order
_time_offset: list[int] = []  # offset of time in mjData found by the last search (the scan costs ~0.7 ms a run)


def time_address(d: mujoco.MjData) -> int:
    """Address of d->time: located by writing two distinct sentinel times into it and finding the
    one aligned offset of the mjData struct that holds both (time comes before the struct's end, and
    the search reads in small chunks, so it never reads past the struct)."""
    saved = d.time
    a, b = 1234.5678901234567, -9876.54321098765
    try:
        if _time_offset:  # the offset found before (same struct layout): checked with both sentinels
            addr = d._address + _time_offset[0]
            d.time = a
            if ctypes.c_double.from_address(addr).value == a:
                d.time = b
                if ctypes.c_double.from_address(addr).value == b:
                    return addr
        d.time = a
        pattern = np.float64(a).tobytes()
        base, chunk = d._address, 512
        for start in range(0, 1 << 22, chunk):
            buf = ctypes.string_at(base + start, chunk + 8)
            off = buf.find(pattern)
            while off >= 0 and (start + off) % 8:
                off = buf.find(pattern, off + 1)
            if off >= 0:
                addr = base + start + off
                d.time = b
                if ctypes.c_double.from_address(addr).value == b:
                    _time_offset[:] = [addr - base]
                    return addr
                d.time = a
        raise native.NativeUnavailable("cannot locate mjData.time for the native callback")
    finally:
        d.time = saved


class FtLayout(ctypes.Structure):
    """Mirror of ft_layout in kernel.c: byte offsets inside the mjData struct of time and of the
    pointer fields the callback reads, so that it reads the arrays of whichever MjData it is called with."""

    _fields_ = [(name, _i64) for name in ("time",) + LAYOUT_POINTERS]


def data_layout(d: mujoco.MjData) -> FtLayout:
    """The offsets of ``d`` (the same for every MjData of its model): each pointer field is the one
    aligned word of the struct holding that array's address (fields after time, so the scan stays
    inside the struct); -1 for an empty array. Two fields of one model holding one address (empty arrays) point to the same
    place in every MjData of the model, so either is right."""
    base = d._address
    lay = FtLayout(time=time_address(d) - base)
    # an empty array (no userdata) is never read: offset -1, the callback gets NULL for it
    want = {name: getattr(d, name).ctypes.data for name in LAYOUT_POINTERS if getattr(d, name).size}
    for name in set(LAYOUT_POINTERS) - set(want):
        setattr(lay, name, -1)
    off, chunk = lay.time, 512
    while want:
        buf = ctypes.string_at(base + off, chunk)
        words = np.frombuffer(buf, dtype=np.uint64)
        for name in list(want):
            hit = np.flatnonzero(words == np.uint64(want[name]))
            if hit.size:
                setattr(lay, name, off + 8 * int(hit[0]))
                del want[name]
        off += chunk
        if off > lay.time + (1 << 16):
            raise native.NativeUnavailable(f"cannot locate mjData.{next(iter(want))} for the native callback")
    return lay


LAYOUTS_KEPT = 8  # models whose data_layout is kept (model_layout)
_LAYOUTS: dict[int, tuple] = {}  # {id(model): (model, FtLayout)}, the most recent last


def model_layout(m, d: mujoco.MjData) -> FtLayout:
    """:func:`data_layout` of ``d``, an MjData of ``m``, found once per model (the same for all its MjData;
    the scan costs ~0.2 ms, a sweep row's set-up on the cart ~2 ms). Read-only: ft_run_activate copies it."""
    kept = _LAYOUTS.get(id(m))
    if kept is not None and kept[0] is m:
        return kept[1]
    lay = data_layout(d)
    _LAYOUTS[id(m)] = (m, lay)  # keeps m alive, so its id names no other model while it is here
    while len(_LAYOUTS) > LAYOUTS_KEPT:
        _LAYOUTS.pop(next(iter(_LAYOUTS)), None)
    return lay


@functools.lru_cache(maxsize=None)
def mujoco_function(name: str) -> int:
    """Address of MuJoCo's C function ``name`` in the libmujoco the Python bindings use (same file, so
    same library)."""
    libs = sorted(Path(mujoco.__file__).parent.glob("libmujoco.so*")) + sorted(
        Path(mujoco.__file__).parent.glob("libmujoco*.dylib")) + sorted(Path(mujoco.__file__).parent.glob("mujoco.dll"))
    if not libs:
        raise native.NativeUnavailable(f"cannot find the MuJoCo library for {name}")
    return ctypes.cast(getattr(ctypes.CDLL(str(libs[0])), name), ctypes.c_void_p).value


def chain_config(plant, m, d) -> tuple:
    """(FtChain, the arrays and private MjData it points into, to keep alive) for a chain plant
    (plants/chain.py native_chain) on (m, d)."""
    c = plant.native_chain(m)
    s = mujoco.MjData(m)  # the private MjData of the r = 3 central difference
    n = len(c["dof"])
    keep = {"adr": np.ascontiguousarray(c["adr"], dtype=np.int32), "w": np.ascontiguousarray(c["w"], dtype=float),
            "dof": np.ascontiguousarray(c["dof"], dtype=np.int32), "act": np.ascontiguousarray(c["act"], dtype=np.int32),
            "b": np.ascontiguousarray(c["b"], dtype=float),
            "dist_scale": np.ascontiguousarray(plant.dist_scale, dtype=float),
            "work": np.zeros(2 * n * m.nv + 3 * m.nv + 2 * n), "s": s}
    C = FtChain()
    C.K, C.nv, C.nq, C.na, C.nu, C.integrating = keep["adr"].shape[2], m.nv, m.nq, m.na, m.nu, int(plant.integrating)
    for name in ("adr", "w", "dof", "act", "b", "dist_scale", "work"):
        setattr(C, name, keep[name].ctypes.data)
    for field, fn in (("fwd_position", "mj_fwdPosition"), ("fwd_velocity", "mj_fwdVelocity"),
                      ("fwd_actuation", "mj_fwdActuation"), ("fwd_acceleration", "mj_fwdAcceleration"),
                      ("solve_m", "mj_solveM")):
        setattr(C, field, mujoco_function(fn))
    for field, name in (("qpos", "qpos"), ("qvel", "qvel"), ("act_state", "act"), ("act_dot", "act_dot"),
                        ("qacc_smooth", "qacc_smooth"), ("qfrc_applied", "qfrc_applied"), ("ctrl", "ctrl")):
        setattr(C, field, getattr(d, name).ctypes.data)
    C.s = s._address
    for field, name in (("s_qpos", "qpos"), ("s_qvel", "qvel"), ("s_act", "act"), ("s_qfrc_applied", "qfrc_applied"),
                        ("s_ctrl", "ctrl"), ("s_qacc_smooth", "qacc_smooth")):
        setattr(C, field, getattr(s, name).ctypes.data)
    from ftstab_mj.plants.chain import EPS

    C.eps = EPS
    if getattr(plant, "constrained", False):  # contacts, limits: the constraint solver (ChainPlant._full_chain)
        from ftstab_mj.plants.chain import TAU_STEP

        keep["warm"] = np.zeros(m.nv)
        C.full, C.fwd_constraint, C.tau_step = 1, mujoco_function("mj_fwdConstraint"), TAU_STEP
        C.qacc_warmstart, C.s_qacc_warmstart, C.s_qacc = d.qacc_warmstart.ctypes.data, s.qacc_warmstart.ctypes.data, s.qacc.ctypes.data
        C.warm = keep["warm"].ctypes.data
    clamp = c.get("clamp")
    if clamp is not None and np.any(clamp["on"]):  # the actuators' ctrlrange/forcerange (ChainPlant.applied)
        keep["clamp_on"] = np.ascontiguousarray(clamp["on"], dtype=np.int32)
        keep["ctrl_lo"], keep["ctrl_hi"] = (np.ascontiguousarray(a, dtype=float) for a in clamp["ctrl"])
        keep["force_lo"], keep["force_hi"] = (np.ascontiguousarray(a, dtype=float) for a in clamp["force"])
        keep["gainprm"] = np.ascontiguousarray(clamp["gainprm"], dtype=float)
        for name in ("clamp_on", "ctrl_lo", "ctrl_hi", "force_lo", "force_hi", "gainprm"):
            setattr(C, name, keep[name].ctypes.data)
    return C, keep


def unsupported(plant, laws, loops, integrator: str) -> str:
    """Why the native callback cannot run this simulation ("" when it can)."""
    if integrator not in INTEGRATORS:
        return f"the native callback needs one forward pass per step ({' or '.join(INTEGRATORS)}), not {integrator!r}"
    if len(laws) > MAXLOOPS:
        return f"the native callback handles at most {MAXLOOPS} loops"
    if plant.step is not mujoco.mj_step:
        return f"plant {plant.model_name!r} is stepped by its own code, not by mj_step"
    if plant.native_sensing(None) is None and not hasattr(plant, "native_chain"):
        return f"plant {plant.model_name!r} has no native sensor map"
    for L in loops:
        if L.disturbance.state_dependent and L.disturbance.kind != "worst_case":
            return f"the native callback does not know the state-dependent signal {L.disturbance.kind!r}"
    for law in laws:
        why = native._unsupported(law)
        if why:
            return why
    return ""


def _require_indices(name: str, idx: np.ndarray, size: int) -> None:
    """Indices the C side reads through (sensordata, bodies, userdata) must lie in [0, size)."""
    idx = np.asarray(idx)
    if idx.size and (idx.min() < 0 or idx.max() >= size):
        raise ValueError(f"native run: {name} indices must lie in [0, {size}), got {idx.min()}..{idx.max()}")


class NativeRun:
    """The native control callback of one Simulation (m, d), with its configuration kept alive."""

    def __init__(self, m, d, plant, loops, laws, state_slices, refs, force_factor, body_ids, period: float,
                 physics_step: float, N: int, divergence_limit: float):
        self.lib = _lib()
        n = len(laws)
        chain = hasattr(plant, "native_chain")
        if chain:  # z and the true phi, gamma from the chain plant's map (kernel.c ft_chain)
            self._chain, self._chain_keep = chain_config(plant, m, d)
            adr, damping, mass = np.zeros((n, plant.r)), np.zeros(n), np.ones(n)
        else:
            adr, damping, mass = plant.native_sensing(m)
        self._keep = keep = {
            "sensor_adr": np.ascontiguousarray(adr, dtype=np.int32),
            "body_ids": np.ascontiguousarray(body_ids, dtype=np.int32),
            "refs": np.ascontiguousarray(refs, dtype=float),
            "laws": (FtLaw * n)(*(pack_law(law) for law in laws)),
            "phi_damping": np.ascontiguousarray(damping, dtype=float),
            "phi_mass": np.ascontiguousarray(mass, dtype=float),
            "phi_state": np.array([L.disturbance.state_dependent for L in loops], dtype=np.int32),
            "state_phi": (FtInput * n)(*(native.chain_input(L.disturbance, np.zeros((1, 1)))[0]
                                         if L.disturbance.state_dependent else FtInput() for L in loops)),
            "force_factor": np.ascontiguousarray(force_factor, dtype=float),
            # first userdata slot of each loop's law state, -1 for a law without state
            "state_adr": np.array([sl.start if sl.stop > sl.start else -1 for sl in state_slices], dtype=np.int32),
            "u_held": np.zeros(n),
        }
        _require_indices("sensor_adr", keep["sensor_adr"], m.nsensordata)
        _require_indices("body_ids", keep["body_ids"], m.nbody)
        _require_indices("state_adr", keep["state_adr"][keep["state_adr"] >= 0], m.nuserdata)
        if keep["sensor_adr"].shape != (n, plant.r):
            raise ValueError(f"native run: sensor_adr: expected shape {(n, plant.r)}, got {keep['sensor_adr'].shape}")
        R = self.run = FtRun()
        self.layout = model_layout(m, d)  # the callback binds R to the MjData it is called with
        R.mj_forward_skip = mujoco_function("mj_forwardSkip") if plant.refresh_before_sample else None
        R.skip_stage = int(mujoco.mjtStage.mjSTAGE_VEL)
        R.n, R.N, R.integrating, R.nbody = n, N, int(plant.integrating), len(body_ids)
        for name, value in keep.items():
            setattr(R, name, ctypes.addressof(value) if isinstance(value, ctypes.Array) else value.ctypes.data)
        R.period, R.h, R.divergence_limit = period, physics_step, divergence_limit
        R.chain = ctypes.addressof(self._chain) if chain else None
        self.d = d
        # a batch cut between its activation and its finish (a Ctrl-C) leaves d registered: forget it
        # with this run, so that an MjData later allocated at d's address is never served R
        weakref.finalize(self, self.lib.ft_run_forget, ctypes.addressof(R), d._address)
        self.callback = self.lib.ft_control_callback  # a ctypes function pointer: set_mjcb_control takes it

    def use_stages(self, stages, stage_slices, physics_step: float) -> None:
        """Run the loops' stages (loop_stages.LoopStages, None for a loop without) in the callback;
        loop i's stage state lives in userdata[stage_slices[i]]."""
        from ftstab_mj.simulation.native.stages import FtStage, pack_stages

        if all(st is None for st in stages):
            return
        n = len(stages)
        self._stages = stages
        keep = self._keep
        keep["stages"] = (FtStage * n)(*(pack_stages(st, physics_step) if st else FtStage() for st in stages))
        keep["stage_on"] = np.array([st is not None for st in stages], dtype=np.int32)
        keep["stage_adr"] = np.array([sl.start for sl in stage_slices], dtype=np.int32)
        keep["u_steps"] = np.zeros(self.run.N)
        R = self.run
        R.stages = ctypes.addressof(keep["stages"])
        for name in ("stage_on", "stage_adr", "u_steps"):
            setattr(R, name, keep[name].ctypes.data)

    def stage_batch(self, k0: int, recs) -> None:
        """Before a batch whose first sample is sample k0: each staged loop's noise table and the
        record arrays of its stage fields (recs: the run loop's per-loop record dicts)."""
        if getattr(self, "_stages", None) is None:
            return
        from ftstab_mj.simulation.native.stages import noise_table

        R, tables = self.run, []
        R.k0 = k0
        for i, (st, rec) in enumerate(zip(self._stages, recs)):
            if st is None:
                continue
            arrays = [rec[f] for f in ("z_measured", "z_hat", "u_applied")]
            samples = len(rec["u_applied"])
            for f, a, shape in zip(("z_measured", "z_hat", "u_applied"), arrays,
                                   ((samples, st.channels), (samples, st.r), (samples,))):
                require_buffer(f"loop {i} {f}", a, shape)
            R.rec_zm[i], R.rec_zh[i], R.rec_ua[i] = (a.ctypes.data for a in arrays)
            table = np.ascontiguousarray(noise_table(st, k0, len(rec["u_applied"])))
            tables.append(table)
            self._keep["stages"][i].noise = table.ctypes.data
        self._keep["noise_tables"] = tables

    def reference_batch(self, table) -> None:
        """Before a batch: ref^(j)(t_k) (samples, n, r + 1) of tracked references (None: set points, refs)."""
        if table is None:
            self.run.ref_table = None
            return
        require_buffer("ref_table", table, table.shape)
        self._ref_table = table  # kept alive for the batch
        self.run.ref_table = table.ctypes.data

    def record_applied(self, recs) -> None:
        """Before a batch: where each loop that records u_applied (stages, or an actuator that clamps)
        writes it (recs: the run loop's per-loop record dicts)."""
        for i, rec in enumerate(recs):
            a = rec.get("u_applied")
            if a is not None:
                require_buffer(f"loop {i} u_applied", a, (len(a),))
            self.run.rec_ua[i] = None if a is None else a.ctypes.data

    def run_batch(self, m, d, t, inj, gain, force, ctrl_steps, rec_t, rec_z, rec: list, body_pos, body_quat) -> None:
        """Step len(t) periods with mj_step(nstep) (shapes: t (k,); inj, gain, force, ctrl_steps (k N, n);
        rec_t (k,); rec_z (n, k, r); rec: 8 arrays (n, k) in kernel order; body_pos (k, nbody, 3),
        body_quat (k, nbody, 4)). Inputs are the run loop's own arrays, written in place as in Python."""
        R = self.run
        k, n, N, nbody = len(t), R.n, R.N, R.nbody
        r = rec_z.shape[-1] if rec_z.ndim == 3 else -1
        steps = (k * N, n)
        for name, a, shape in (("t", t, (k,)), ("inj", inj, steps), ("gain", gain, steps), ("force", force, steps),
                               ("ctrl_steps", ctrl_steps, steps), ("rec_t", rec_t, (k,)),
                               ("rec_z", rec_z, (n, k, max(r, 1))), ("body_pos", body_pos, (k, nbody, 3)),
                               ("body_quat", body_quat, (k, nbody, 4)),
                               *((f"rec[{i}]", a, (n, k)) for i, a in enumerate(rec))):
            require_buffer(name, a, shape)
        if len(rec) != len(R.rec):
            raise ValueError(f"native run_batch: rec: expected {len(R.rec)} record arrays, got {len(rec)}")
        if any(law.r != r for law in self._keep["laws"]):
            raise ValueError(f"native run_batch: rec_z: expected a last axis of r = {self._keep['laws'][0].r}, got {r}")
        R.t0, R.nsteps, R.samples = d.time, len(inj), len(t)
        R.t, R.inj, R.gain, R.force, R.ctrl_steps = (a.ctypes.data for a in (t, inj, gain, force, ctrl_steps))
        R.rec_t, R.rec_z, R.body_pos, R.body_quat = (a.ctypes.data for a in (rec_t, rec_z, body_pos, body_quat))
        for i, a in enumerate(rec):
            R.rec[i] = a.ctypes.data
        R.last_step, R.row, R.status = -1, -1, 0
        try:  # the callback serves R for the calls made with d, in whichever thread steps it
            if self.lib.ft_run_activate(ctypes.byref(R), d._address, ctypes.byref(self.layout)):
                raise native.NativeUnavailable("the native callback serves at most 256 simulations stepping at once")
            mujoco.mj_step(m, d, nstep=int(R.nsteps))
        finally:  # also on Ctrl-C (raised right after mj_step): the last step's force increment is
            self.lib.ft_run_finish(ctypes.byref(R), d._address)  # applied, and d is no longer served

    def clear_rows(self) -> None:
        """No sample recorded (:attr:`rows` = 0) until the next batch records one."""
        self.run.row = -1

    @property
    def rows(self) -> int:
        """Samples recorded by the last batch."""
        return int(self.run.row) + 1

    def stop_reason(self, loop_names, divergence_limit: float) -> str:
        """The run loop's message for why the batch stopped early ("" when it did not)."""
        R = self.run
        if R.status == 1:
            return (f"diverged at t = {R.bad_time:.6g} s: max |z| = {R.bad_value:.3g} is beyond the divergence "
                    f"limit {divergence_limit:g}")
        if R.status == 2:
            return f"diverged at t = {R.bad_time:.6g} s: the control of loop {loop_names[R.bad_loop]!r} is {R.bad_value}"
        if R.status == 3:
            return f"diverged: the simulation time jumped to {R.bad_time:.6g} s (MuJoCo reset a bad state)"
        return ""

