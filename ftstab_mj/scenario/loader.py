"""Strict loader: TOML text or a plain dict -> a validated :class:`Scenario`, errors with key paths.

Every problem raises :class:`ScenarioError` naming the source (file, and the ``--set`` that caused
it), the key path (``loops.cart.controller.gains[1]``), what is allowed and what was found. Checks,
in order: TOML syntax; unknown keys; missing required keys; types; per-field ranges; then the
checks across fields (the control period is a multiple of the physics step, the plant knows the
model and its parameters, one loop per actuated joint, lengths of z0 and gains equal the loop's r,
Hong's parameters admissible through ftstab_mj.control's own validation, the law's parameters
present and no other law's, gamma(t) > 0).

``--set key.path=value`` edits the raw TOML data before validation, so an override gets exactly
the same checks as the file. The value is read as a TOML value (``2``, ``-0.1``, ``[1, 2]``,
``"x"``); anything that is not a TOML value is taken as a string (``--set plant.model=arm``).
"""

from __future__ import annotations

import functools
import math
import threading
import zlib
from dataclasses import fields, is_dataclass, replace
from pathlib import Path

import numpy as np

from ftstab_mj.config import keypath
from ftstab_mj.control import LAWS, law_class
from ftstab_mj.control.law import COMPUTED, Law
from ftstab_mj.plants.disturbances import KEYS_BY_KIND, MAX_VALUE, Signal
from ftstab_mj.plants.reference import KEYS_BY_KIND as REFERENCE_KEYS, Reference, read_samples
from ftstab_mj.config.errors import ParameterError, ScenarioError, counted, describe
from ftstab_mj.simulation.records import MetricSettings
from ftstab_mj.scenario.schema import (
    EXTERNAL_CHECKS, SIGNAL_DERIVED, ControllerSpec, LoopSpec, PlantSpec, Scenario, SensorSpec,
)
from ftstab_mj.scenario.plugins import is_plugin_file, load_entry_points, load_plugins
from ftstab_mj.config.tomlfile import parse_text, read_toml
from ftstab_mj.config.limits import MAX_STATE
from ftstab_mj.config.validate import LIMITS, Reader, TableMemo, limit_text, whole_steps

_SIGNAL_ROLES = {"disturbance": 1, "gain": 2, "sensor": 3}


class _Reader(Reader):
    """Builds the typed Scenario from raw TOML data, raising ScenarioError with the key path."""

    def special(self, tp, value, path):
        if tp is Signal:
            return self.signal(value, path)
        if tp is SensorSpec:  # its seed is derived, as a signal's
            return SensorSpec(**self.fields_of(tp, value, path, skip=SIGNAL_DERIVED))
        if tp is ControllerSpec:
            return self.controller(value, path)
        if tp is Reference:
            return self.reference(value, path)
        return NotImplemented

    def reference(self, value, path) -> Reference:
        """[loops.<name>.reference]: a kind and only the keys that kind uses."""
        if not isinstance(value, dict):
            raise self.error(path, "a table with kind = " + " | ".join(REFERENCE_KEYS) + " and its keys", describe(value))
        kind = value.get("kind", "constant")
        if kind not in REFERENCE_KEYS:
            raise self.error(keypath.join(path, "kind"), "one of " + ", ".join(REFERENCE_KEYS), describe(kind))
        applies = REFERENCE_KEYS[kind]
        for key in value:
            if key != "kind" and key not in applies:
                raise self.error(keypath.join(path, key), f"only keys that a {kind} reference uses ("
                                 + ", ".join(("kind",) + applies) + ")", f"{key} = {describe(value[key])}")
        if kind == "file" and "times" not in value and "values" not in value:  # the samples from the file
            if not isinstance(value.get("path"), str) or not value["path"]:
                raise self.error(keypath.join(path, "path"), "the CSV file of samples t, value (relative to the scenario), "
                                 "or times and values", describe(value.get("path")))
            try:
                times, values = read_samples(value["path"])
            except ParameterError as exc:  # the file's name and line: a finding, shown whole
                raise self.error(keypath.join(path, "path"), exc.allowed, exc.given) from None
            value = {**value, "times": list(times), "values": list(values)}
        kw = self.fields_of(Reference, value, path)
        try:
            return Reference(**kw)
        except ParameterError as exc:
            raise self.error(keypath.join(path, exc.name), exc.allowed, describe(exc.given)) from None

    def controller(self, value, path) -> ControllerSpec:
        """[loops.<name>.controller]: ``law``, then that law's declared parameters (Param: type, check,
        default) and no other key."""
        if not isinstance(value, dict):
            raise self.error(path, "a table with the law and its parameters", describe(value))
        if "law" not in value:
            raise self.error(keypath.join(path, "law"), "a value (the control law: see `ftstab list`)",
                             "nothing: the key is required")
        law = self.string(value["law"], keypath.join(path, "law"))
        self.known_law(value, path)
        declared = law_class(law).all_params()
        names = [p.name for p in declared]
        for key in value:
            if key != "law" and key not in names:
                other = any(key in (p.name for p in cls.all_params()) for cls in LAWS.values())
                raise self.error(keypath.join(path, key), f"only the {law} law's parameters ({', '.join(names) or 'none'})",
                                 f"{key} = {describe(value[key])}" + (", a parameter of another law" if other else ""))
        out = []
        for p in declared:
            where = keypath.join(path, p.name)
            if p.name not in value:
                if p.required:
                    raise self.error(where, f"a value for the {law} law ({p.describe()})", "nothing: the key is required")
                out.append((p.name, p.default))
                continue
            v = self.convert(p.type, value[p.name], where)
            allowed = p.check(v) if p.check is not None else None
            if allowed:
                raise self.error(where, allowed, describe(value[p.name]))
            out.append((p.name, v))
        return ControllerSpec(law, tuple(out))

    def signal(self, value, path) -> Signal:
        kw = self.fields_of(Signal, value, path, skip=SIGNAL_DERIVED)
        kind = kw.get("kind", "constant")
        applies = KEYS_BY_KIND.get(kind, ())
        for key in value:
            if key != "kind" and key not in applies and kind in KEYS_BY_KIND:
                raise self.error(keypath.join(path, key), f"only keys that a {kind} signal uses ("
                                 + (", ".join(("kind",) + applies)) + ")", f"{key} = {describe(value[key])}")
        try:
            sig = Signal(**kw)
        except ParameterError as exc:
            raise self.error(keypath.join(path, exc.name), exc.allowed, describe(exc.given)) from None
        if abs(sig.offset) + abs(sig.amplitude) > MAX_VALUE:  # the API may still drive MuJoCo to its warnings
            key = "amplitude" if abs(sig.amplitude) > abs(sig.offset) else "offset"
            raise self.error(keypath.join(path, key), f"|offset| + |amplitude| <= {MAX_VALUE:g} (MuJoCo treats a "
                             "control or an acceleration beyond 1e10 as a bad state and resets the simulation)",
                             describe(value[key]))
        return sig

    def plant(self, value, path) -> PlantSpec:
        if not isinstance(value, dict):
            raise self.error(path, "a table", describe(value))
        if "model" not in value:
            raise self.error(keypath.join(path, "model"), "a value (the plant model name)",
                             "nothing: the key is required")
        params = {k: v for k, v in value.items() if k != "model"}
        return PlantSpec(model=self.string(value["model"], keypath.join(path, "model")), params=params)

    def loops(self, value, path) -> tuple[LoopSpec, ...]:
        if not isinstance(value, dict) or not value:
            raise self.error(path, "a table of loops [loops.<name>], at least one", describe(value))
        out = []
        for name, body in value.items():
            p = keypath.join(path, name)
            if not isinstance(body, dict):
                raise self.error(p, "a table [loops.<name>]", describe(body))
            if "name" in body:
                raise self.error(keypath.join(p, "name"), "no 'name' key (the table key is the loop name)",
                                 "a 'name' key")
            self.known_law(body.get("controller"), keypath.join(p, "controller"))
            if "ref" in body and "reference" in body:
                raise self.error(keypath.join(p, "ref"), f"either ref (a set point) or a [{p}.reference] table, not both",
                                 f"ref = {describe(body['ref'])} and a reference table")
            out.append(self.memoized(LoopSpec, body, p, lambda tp, v, where, name=name: tp(
                name=name, **self.fields_of(tp, v, where, skip=("name",)))))
        return tuple(out)

    def known_law(self, controller, path) -> None:
        """An unknown law is named as such, before its keys are read (they are another law's, or none)."""
        law = controller.get("law") if isinstance(controller, dict) else None
        if isinstance(law, str) and law not in LAWS:
            raise self.error(keypath.join(path, "law"), f"a registered law (known: {', '.join(LAWS)}; a law of "
                             "your own: name its file or module in plugins = [...])", f"unknown law {law!r}")

    def scenario(self, raw) -> Scenario:
        if not isinstance(raw, dict):
            raise self.error("", "a table", describe(raw))
        self.bounded(raw)
        special = {"plant": self.plant, "loops": self.loops}
        self.table(raw, "", [f.name for f in fields(Scenario)])
        kw = self.fields_of(Scenario, {k: v for k, v in raw.items() if k not in special}, "", skip=tuple(special))
        for key, build in special.items():
            if key not in raw:
                raise self.error(key, f"a [{key}] table", "nothing: the table is required")
            kw[key] = build(raw[key], key)
        return Scenario(**kw)

    def fields_of(self, cls, value, path, skip=(), checks=None):
        if cls is MetricSettings and isinstance(value, dict) and value.get("final_window_max") == math.inf:
            # inf is refused, not read as "no cap": a log records its settings as JSON, which has no
            # inf, and a finite cap of at least final_fraction x sim.duration is already no cap
            raise self.error(keypath.join(path, "final_window_max"), "a finite number of seconds > 0 (to measure "
                             "the whole final fraction of any run, write a value >= final_fraction x sim.duration, "
                             "e.g. 1e9)", "inf")
        return super().fields_of(cls, value, path, skip, checks or EXTERNAL_CHECKS.get(cls))


# -- checks across fields ------------------------------------------------------------------------
def _check(sc: Scenario, rd: _Reader) -> Scenario:
    _check_work(sc, rd)  # before the plant is built: nothing is allocated for a run it cannot do
    plant = _check_plant(sc, rd)
    r = plant.r
    loops = []
    for lp in sc.loops:
        p = f"loops.{lp.name}"
        if len(lp.z0) != r:
            raise rd.error(f"{p}.z0", f"{counted(r, 'number')} (z_1..z_r, r = {r} for model {sc.plant.model!r})",
                           counted(len(lp.z0), "number"))
        for i, zi in enumerate(lp.z0):  # MuJoCo silently resets a state beyond 1e10 to zero
            if abs(zi) > MAX_STATE:
                raise rd.error(f"{p}.z0[{i}]", "|z0| <= 1e9 (MuJoCo resets states beyond 1e10)", describe(zi))
        if lp.gain.state_dependent:
            raise rd.error(f"{p}.gain.kind", "a gain signal that depends on time only (worst_case is a "
                           "disturbance: it needs dV1/dz_r)", describe(lp.gain.kind))
        for role in ("disturbance", "gain"):
            sig = getattr(lp, role)
            nyquist = 0.5 / sc.sim.physics_step
            for key in ("freq", "freq_end"):
                if key in KEYS_BY_KIND[sig.kind] and getattr(sig, key) > nyquist:
                    raise rd.error(f"{p}.{role}.{key}", f"a frequency <= {nyquist:g} Hz (half the physics step "
                                   "rate: a faster signal is only sampled as an alias)", describe(getattr(sig, key)))
        lo = lp.gain.bounds()[0]
        if lo <= 0:
            raise rd.error(f"{p}.gain", "gamma(t) > 0 at all times (offset above the amplitude, or a step "
                           "that ends above 0)",
                           f"a signal reaching {lo:g}")
        _check_stages(lp, r, rd)
        ref = lp.reference
        if ref is not None and ref.kind == "file" and r > ref.smooth + 1:  # ref^(r) enters phi: bounded
            raise rd.error(f"{p}.reference.smooth", f"an integer >= {r - 1} for this chain of length r = {r} "
                           "(ref^(r) enters phi and must be bounded)", describe(ref.smooth))
        seeds = {role: _derived_seed(sc.seed, lp.name, role) for role in _SIGNAL_ROLES}
        lp = replace(lp, disturbance=replace(lp.disturbance, seed=seeds["disturbance"]),
                     gain=replace(lp.gain, seed=seeds["gain"]))
        if lp.sensor is not None:
            lp = replace(lp, sensor=replace(lp.sensor, seed=seeds["sensor"]))
        loops.append(lp)
    sc = _computed_bounds(replace(sc, loops=tuple(loops)), plant, rd)
    sc = _computed_observer_L(sc, plant, rd)
    for lp in sc.loops:  # the law's own validation (after "computed" is resolved), e.g. Hong's k and gains
        key = (repr(lp.controller), r)  # repr: -0.0 and 0.0, 1 and 1.0 and True are told apart
        if key in _BUILT:  # the law's check depends on its parameters and r only: passed before
            continue
        try:
            lp.controller.build(r)
        except ParameterError as exc:
            name = exc.name.split(" ")[0]  # "gains[1] (l_2)" -> "gains[1]"
            raise rd.error(f"loops.{lp.name}.controller.{name}", exc.allowed, describe(exc.given)) from None
        if len(_BUILT) >= BUILT_LAWS:
            _BUILT.clear()
        _BUILT.add(key)
    return sc


_BUILT: set = set()  # (repr of a ControllerSpec, r) whose law was built without error (a sweep's rows share a few)
BUILT_LAWS = 10_000


def _check_stages(lp: LoopSpec, r: int, rd: _Reader) -> None:
    """The sensor, observer and actuator of a loop fit together and fit its chain length r."""
    from ftstab_mj.simulation.stages.differentiator import MAX_TOTAL_ORDER

    p = f"loops.{lp.name}"
    sensor, obs = lp.sensor, lp.observer
    if lp.actuator is not None and lp.actuator.lag_order is not None and lp.actuator.tau == 0:
        raise rd.error(f"{p}.actuator.lag_order", "a lag order only with a lag (actuator.tau > 0)",
                       f"lag_order = {lp.actuator.lag_order} with tau = 0")
    measured = sensor.measured if sensor is not None else "state"
    if sensor is not None:
        m = r if measured == "state" else 1
        for name in ("noise", "quantum"):
            v = getattr(sensor, name)
            if isinstance(v, tuple) and len(v) != m:
                raise rd.error(f"{p}.sensor.{name}", f"a number or {counted(m, 'number')} (one per measured "
                               f"channel: measured = {measured!r}, r = {r})", counted(len(v), "number"))
    if measured == "position" and obs is None:
        raise rd.error(f"{p}.observer", f'a [{p}.observer] table (sensor.measured = "position": the law needs '
                       f"z_2..z_r, which an observer rebuilds)", "none")
    if obs is None:
        return
    if measured != "position":
        raise rd.error(f"{p}.sensor.measured", '"position" (the observer rebuilds z_2..z_r from z_1)',
                       f"{measured!r}" + ("" if sensor is not None else " (the default: no [sensor] table)"))
    order = r - 1 if obs.order is None else obs.order
    if order < r - 1:
        raise rd.error(f"{p}.observer.order", f"an order >= r - 1 = {r - 1}", describe(obs.order))
    law = lp.controller if isinstance(lp.controller, Law) else law_class(lp.controller.law)
    lagged = lp.actuator is not None and lp.actuator.tau > 0  # a lag makes the applied u continuous
    if order > r - 1 and not law.u_continuous and not lagged:
        # z_1^(r) = phi + gamma u jumps with a discontinuous u: no L bounds z_1^(n+1) (Levant 2003)
        raise rd.error(f"{p}.observer.order", f"order = r - 1 = {r - 1}: law {law.name!r} declares a discontinuous u, so "
                       f"z_1^({r}) jumps and no L bounds z_1^(n+1) (an actuator lag, tau > 0, would smooth it)", describe(obs.order))
    if obs.kind == "levant" and obs.filter_order is not None:
        raise rd.error(f"{p}.observer.filter_order", 'no filter_order for kind = "levant" (only "levant_filtering")',
                       describe(obs.filter_order))
    nf = (1 if obs.filter_order is None else obs.filter_order) if obs.kind == "levant_filtering" else 0
    if order + nf > MAX_TOTAL_ORDER:
        raise rd.error(f"{p}.observer.order", f"order + filter_order <= {MAX_TOTAL_ORDER} (the range of Levant's "
                       "coefficients)", f"{order} + {nf}")


def _check_work(sc: Scenario, rd: _Reader) -> None:
    """The run's size: samples, physics steps per period and per run, within validate.LIMITS."""
    sim = sc.sim
    steps = sim.period / sim.physics_step  # both are finite and > 0: at most 1e308 / 1e-7, still finite
    if steps > LIMITS["steps_per_period"][0]:
        raise rd.error("sim.period", limit_text("steps_per_period", "physics steps per period"),
                       f"{sim.period:g} s = {steps:.3g} steps of {sim.physics_step:g} s".replace("inf", "> 1e308"))
    n = whole_steps(sim.period, sim.physics_step)
    if n is None:
        raise rd.error("sim.period", f"an integer multiple of sim.physics_step = {sim.physics_step:g} s",
                       f"{sim.period:g} s ({steps:.6g} steps)")
    samples = sim.duration / sim.period
    if samples > LIMITS["samples"][0]:
        raise rd.error("sim.duration", limit_text("samples", "control samples per run"),
                       f"{sim.duration:g} s = {samples:.3g} periods of {sim.period:g} s")
    if samples * n > LIMITS["steps"][0]:
        raise rd.error("sim.duration", limit_text("steps", "physics steps per run"),
                       f"{sim.duration:g} s = {samples * n:.3g} steps of {sim.physics_step:g} s")


def _check_plant(sc: Scenario, rd: _Reader):
    """Build the plant (validating model and parameters) and check there is one loop per joint."""
    from ftstab_mj.plants import make_plant  # imports MuJoCo: only once the file itself is valid

    try:
        plant = make_plant(sc.plant.model, sc.plant.params)
    except ParameterError as exc:  # names "model" or "params.<key>"
        from ftstab_mj.plants.chain import Finding  # a sentence of the plant's: shown whole, not cut to a value's length

        key = exc.name.removeprefix("params.")
        raise rd.error(f"plant.{key}", exc.allowed, exc.given if isinstance(exc.given, Finding) else describe(exc.given)) from None
    except ValueError as exc:  # MuJoCo's compiler refused the model these parameters make
        raise rd.error("plant", "parameters MuJoCo can compile a model from",
                       f"MuJoCo: {str(exc).removeprefix('Error: ').splitlines()[0]}") from None
    if sc.sim.integrator not in plant.integrators:
        raise rd.error("sim.integrator", f"one of {', '.join(plant.integrators)} for model {sc.plant.model!r}",
                       describe(sc.sim.integrator))
    names = [lp.name for lp in sc.loops]
    if sorted(names) != sorted(plant.loop_names):
        raise rd.error("loops", f"one table per loop of model {sc.plant.model!r}: "
                       + ", ".join(f"[loops.{n}]" for n in plant.loop_names), ", ".join(f"[loops.{n}]" for n in names))
    return plant


def _computed_bounds(sc: Scenario, plant, rd: _Reader) -> Scenario:
    """Replace robust bounds given as "computed" by the plant's bounds for the scenario's signals."""
    wanted = [(i, p.name, p.plant_bound) for i, lp in enumerate(sc.loops)
              for p in law_class(lp.controller.law).all_params()
              if p.plant_bound and getattr(lp.controller, p.name) == COMPUTED]
    if not wanted:
        return sc
    by_name = {lp.name: lp for lp in sc.loops}
    ordered = [by_name[n] for n in plant.loop_names]  # true_bounds takes the plant's loop order
    phibar, gamma_m, _ = plant.true_bounds([lp.disturbance.bounds() for lp in ordered],
                                           [lp.gain.bounds() for lp in ordered])
    # a tracked reference's ref^(r) is part of the error chain's phi (plants/reference.py)
    extra = {lp.name: float(lp.reference.max_abs(plant.r, sc.sim.duration)[plant.r])
             for lp in ordered if lp.reference is not None and not lp.reference.constant}
    value = {(n, "phibar"): float(phibar[k]) + extra.get(n, 0.0) for k, n in enumerate(plant.loop_names)}
    value.update({(n, "gamma_m"): float(gamma_m[k]) for k, n in enumerate(plant.loop_names)})
    loops = list(sc.loops)
    for i, name, bound in wanted:
        if not math.isfinite(value[(loops[i].name, bound)]):
            reason = getattr(plant, "unbounded_reason", "")  # a chain plant says why (no workspace, friction)
            if reason:
                raise rd.error(f"loops.{loops[i].name}.controller.{name}",
                               f"a number, since this plant's bound is infinite ({reason})", f'"{COMPUTED}"')
            why = (f"damping = {plant.damping:g}" if getattr(plant, "damping", 0) else
                   "signals whose bounds overflow")
            raise rd.error(f"loops.{loops[i].name}.controller.{name}",
                           "a number, since this plant's bound is infinite (a damped cart: damping adds -b x'/m to "
                           "phi, unbounded without a speed limit; or signals beyond float range)", f'"{COMPUTED}" with {why}')
        loops[i] = replace(loops[i], controller=loops[i].controller.with_values(**{name: value[(loops[i].name, bound)]}))
    return replace(sc, loops=tuple(loops))


def _computed_observer_L(sc: Scenario, plant, rd: _Reader) -> Scenario:
    """Replace an observer's L = "computed" by the rule (differentiator.lipschitz_rule): the sup of
    |z_1^(r)| = |phi + gamma u_applied| over the reachable set, from the plant's true bounds for the
    scenario's signals and the actuator's saturation."""
    from ftstab_mj.simulation.stages.differentiator import lipschitz_rule

    if not any(lp.observer is not None and lp.observer.L == COMPUTED for lp in sc.loops):
        return sc
    by_name = {lp.name: lp for lp in sc.loops}
    ordered = [by_name[n] for n in plant.loop_names]
    phibar, _, gamma_M = plant.true_bounds([lp.disturbance.bounds() for lp in ordered],
                                           [lp.gain.bounds() for lp in ordered])
    k_of = {n: k for k, n in enumerate(plant.loop_names)}
    loops = list(sc.loops)
    for i, lp in enumerate(loops):
        if lp.observer is None or lp.observer.L != COMPUTED:
            continue
        r, k = plant.r, k_of[lp.name]
        order = r - 1 if lp.observer.order is None else lp.observer.order
        u_max = None if lp.actuator is None else lp.actuator.u_max
        L = lipschitz_rule(r, order, float(phibar[k]), float(gamma_M[k]), u_max)
        if L is None or not math.isfinite(L) or L <= 0:
            raise rd.error(f"loops.{lp.name}.observer.L", "a number, or \"computed\" with order r - 1 = "
                           f"{r - 1}, an actuator.u_max and bounded signals (the rule phibar + gamma_M u_max)",
                           f'"{COMPUTED}" with order {order}, u_max {u_max}')
        loops[i] = replace(lp, observer=replace(lp.observer, L=L))
    return replace(sc, loops=tuple(loops))


@functools.lru_cache(maxsize=1024)  # a pure function, 60 us a call: every sweep row asks it again
def _derived_seed(seed: int, loop: str, role: str) -> int:
    """Seed of one signal: a stable function of the scenario seed, the loop name and the role."""
    ss = np.random.SeedSequence([seed, zlib.crc32(loop.encode()), _SIGNAL_ROLES[role]])
    return int(ss.generate_state(1)[0])


# -- public API ------------------------------------------------------------------------------------
def scenario_from_dict(raw: dict, source: str = "<scenario>", overrides: dict[str, str] | None = None) -> Scenario:
    """Validate raw scenario data (as parsed from TOML, or read back from a log) into a Scenario."""
    return _validated(raw, source, overrides)


def _validated(raw, source: str, overrides: dict[str, str] | None, memo: TableMemo | None = None) -> Scenario:
    """:func:`scenario_from_dict`, reading each table the reader's ``memo`` holds as it was read before
    (Reader.memoized); the checks across fields are all made again."""
    rd = _Reader(source, overrides, memo=memo)
    load_entry_points()
    if isinstance(raw, dict) and "plugins" in raw:  # imported before anything names what they register
        base = Path(source).parent if source.endswith(".toml") else Path.cwd()
        raw = {**raw, "plugins": load_plugins(raw["plugins"], base, rd.error)}
    return _check(rd.scenario(raw), rd)


def scenario_with(raw: dict, values, source: str, notes: dict[str, str] | None = None) -> Scenario:
    """Validate a copy of ``raw`` with typed ``values`` ((key path, value), ...) set at their paths.

    The values are set as they are (no TOML text in between); a table value replaces the table at its
    path. ``notes``: {key path: what set it}, named in errors after ``source``.

    ``raw`` is not changed: only the tables and arrays along the values' paths are copied, the others
    are ``raw``'s own objects, which the reader reads once per ``raw`` (:data:`_MEMOS`; so the caller
    must not change ``raw`` between two calls, as a sweep's task never does): a sweep row that
    sets a disturbance's amplitude reads that signal, its loop and the top level, then makes every check
    across fields, as the whole file would (the same errors; ~0.3 ms instead of ~0.8 ms a row on the cart).
    """
    data = dict(raw)
    for path, value in values:
        parts = keypath.parse(path)
        _own_path(data, parts)
        keypath.assign(data, parts, value, f"{source} ({(notes or {}).get(path, path)})")
    return _validated(data, source, notes, _memo_of(raw))


# {id(raw): TableMemo(raw)}: the tables of the last few bases already read (Reader.memoized)
_MEMOS: dict[int, TableMemo] = {}
MEMO_BASES = 4  # bases whose memo is kept (a sweep has one; a comparison one per scenario)
_MEMOS_LOCK = threading.Lock()  # the batch engine's threads validate rows at once


def _memo_of(raw: dict) -> TableMemo:
    with _MEMOS_LOCK:
        hit = _MEMOS.get(id(raw))
        if hit is None or hit.base is not raw:
            while len(_MEMOS) >= MEMO_BASES:
                _MEMOS.pop(next(iter(_MEMOS)))
            hit = _MEMOS[id(raw)] = TableMemo(raw)
        return hit


def _own_path(data: dict, parts) -> None:
    """Replace the tables and arrays along ``parts`` (but the last) by copies, so that setting the value
    at ``parts`` in ``data`` (a copy of the base's top level) leaves the base unchanged."""
    node = data
    for part in (parts or ())[:-1]:
        if isinstance(node, dict) and part in node or isinstance(node, list) and isinstance(part, int) \
                and 0 <= part < len(node):
            child = node[part]
            if not isinstance(child, (dict, list)):
                return
            node[part] = child = dict(child) if isinstance(child, dict) else list(child)
            node = child
        else:
            return


def parse_override(text: str, source: str) -> tuple[list, object, str]:
    """``"a.b[1]=2"`` -> (["a", "b", 1], 2, "a.b[1]"). Raises ScenarioError on a malformed override.

    The value is read as a TOML value (bounded like a file); anything that is not one is a string.
    """
    if "=" not in text:
        raise ScenarioError(source, f"--set {_short(text)}", "key.path=value", "no '='")
    key, _, val = text.partition("=")
    key = key.strip()
    parts = keypath.parse(key)
    if parts is None:
        raise ScenarioError(source, f"--set {_short(text)}", "a key path like sim.duration or loops.cart.z0[0]",
                            repr(_short(key)))
    val = val.strip()
    try:
        value = parse_text(f"v = {val}", f"{source} (--set {_short(text)})", where=key)["v"]
    except ScenarioError as exc:
        if exc.expected != "valid TOML":  # too deep or too big: a TOML value, refused
            raise
        value = val  # not a TOML value: a bare string such as a model name
    return parts, value, key


def _short(text: str) -> str:
    return text if len(text) <= 80 else text[:77] + "..."


def apply_override(raw: dict, text: str, source: str) -> str:
    """Apply one ``--set key.path=value`` to raw data in place; returns the key path it set."""
    parts, value, key = parse_override(text, source)
    keypath.assign(raw, parts, value, f"{source} (--set {_short(text)})")
    return key


def load_scenario(path, overrides=()) -> Scenario:
    """Read, override and validate a scenario file. Raises ScenarioError (one line) on any problem."""
    src = str(path)
    raw = read_toml(path, "scenario file (.toml)")
    where = {}
    for text in overrides:
        where[apply_override(raw, text, src)] = f"--set {_short(text)}"
    resolve_relative_paths(raw, Path(src).parent)
    return scenario_from_dict(raw, src, where)


def resolve_relative_paths(raw: dict, base: Path) -> None:
    """A user model's ``plant.model = "robot.xml"`` and the ``plugins`` files are relative to the
    scenario file (folder ``base``): make them absolute, so the resolved scenario (a log's /scenario,
    a sweep's or comparison's rows) names the same files wherever it is run from."""
    plant = raw.get("plant")
    model = plant.get("model") if isinstance(plant, dict) else None
    if isinstance(model, str) and model.endswith(".xml") and not Path(model).is_absolute():
        plant["model"] = str((base / model).resolve())
    loops = raw.get("loops")
    for body in (loops.values() if isinstance(loops, dict) else ()):  # a file reference's samples
        ref = body.get("reference") if isinstance(body, dict) else None
        if isinstance(ref, dict) and ref.get("kind") == "file" and isinstance(ref.get("path"), str) \
                and ref["path"] and not Path(ref["path"]).is_absolute():
            ref["path"] = str((base / ref["path"]).resolve())
    plugins = raw.get("plugins")
    if isinstance(plugins, list):
        raw["plugins"] = [str((base / p).resolve()) if isinstance(p, str) and is_plugin_file(p) and not Path(p).is_absolute()
                          else p for p in plugins]


def scenario_to_dict(sc: Scenario) -> dict:
    """The resolved scenario as plain TOML/JSON-able data; ``scenario_from_dict`` of it gives ``sc`` back."""

    def plain(obj, skip=()):
        if isinstance(obj, Signal):  # the keys its kind uses (the loader refuses the others)
            return {"kind": obj.kind, **{k: getattr(obj, k) for k in KEYS_BY_KIND[obj.kind]}}
        if isinstance(obj, ControllerSpec):
            return {"law": obj.law, **{k: plain(v) for k, v in obj.params if v is not None}}
        if isinstance(obj, Reference):  # the keys its kind uses, as a Signal
            return {"kind": obj.kind, **{k: plain(getattr(obj, k)) for k in REFERENCE_KEYS[obj.kind]}}
        if is_dataclass(obj):
            skip = skip + (SIGNAL_DERIVED if isinstance(obj, SensorSpec) else ())
            return {f.name: plain(getattr(obj, f.name)) for f in fields(obj)
                    if f.name not in skip and getattr(obj, f.name) is not None}
        if isinstance(obj, tuple):
            return [plain(x) for x in obj]
        return obj

    d = plain(sc, skip=("plant", "loops") + (() if sc.plugins else ("plugins",)))  # logs without plugins unchanged
    d["plant"] = {"model": sc.plant.model, **sc.plant.params}
    d["loops"] = {lp.name: plain(lp, skip=("name",) + (("ref",) if lp.reference is not None else ())) for lp in sc.loops}
    return d
