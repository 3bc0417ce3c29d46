"""Monte Carlo of the convergence-time guarantee: many initial states, per-trajectory metrics only.

Theorem 1 promises that every trajectory of the nominal (or, under Theorem 2's bounds, robust)
closed loop reaches the origin before T(z0) = V1(z0)^(1-alpha) / (c (1-alpha)). One run checks one
z0; this module checks the promise on N initial states drawn uniformly in a box, and keeps only
what each trajectory says about it:

    row           index of the initial state in the draw
    settle_time   first sample time from which V1 <= settle_level until the end (s; NaN: never)
    time_bound    T(z0) from the loop's certificate (s; NaN where no certificate holds)
    ratio         settle_time / time_bound (<= 1 where the bound holds)
    V1_initial, V1_final, u_max_abs

Two ways to run the trajectories ("on"):

* ``"chain"``: the scenario's loop on the ideal chain z_r' = phi + gamma u integrated exactly
  (ftstab_mj.simulation.ideal_chain; the native kernel runs a chunk of states at once), with the same law,
  period, duration and signals. An ideal-chain scenario is that chain (the same bits); the carts
  take phi and gamma in chain units, so a frictionless, undamped cart scenario has the chain as its
  exact twin (up to MuJoCo's rounding); other plants are refused for this mode.
* ``"plant"``: each state is a run of the scenario with ``loops.<loop>.z0`` set, on the sweep
  engines (serial, threads, local processes or a Dask cluster): the metrics are exactly those ``ftstab run``
  prints for that z0. Each thread validates the scenario once and runs its states on one simulation reset
  to each z0, computing only the metrics kept here (sweep.row.StatesTask; the full run where it cannot).

Memory stays flat: the chain mode records one chunk of states at a time and reduces it to the
per-trajectory rows before the next; the plant mode keeps only each run's metrics (and, per thread, the
samples of one run up to sweep.row.BATCH_SAMPLES, then batch by batch).
"""

from __future__ import annotations

import contextlib
import math
from dataclasses import dataclass

import numpy as np

from ftstab_mj.metrics import run_metrics as mt
from ftstab_mj.config.errors import ScenarioError, UsageError
from ftstab_mj.simulation.records import LoopInfo

from ftstab_mj.config.limits import MAX_STATES  # noqa: E402,F401 - 10^6 trajectories of a 10 s run at 1 ms: hours


@dataclass(frozen=True)
class Distribution:
    """Where the initial states come from: uniform in the box |z0_i| <= box[i] (chain units), seeded."""

    states: int
    box: tuple[float, ...]
    seed: int = 0

    def draw(self) -> np.ndarray:
        """(states, r) initial states; the same seed gives the same states on every machine."""
        rng = np.random.default_rng([int(self.seed), 0x4D43])  # "MC": a stream of its own
        b = np.asarray(self.box, dtype=float)
        return rng.uniform(-1.0, 1.0, size=(self.states, len(b))) * b


def settle_times(t: np.ndarray, V1: np.ndarray, level: float) -> np.ndarray:
    """:func:`ftstab_mj.metrics.run_metrics.settle_time` of every column of V1 (n, B) at once; NaN for "never"."""
    above = ~(V1 <= level)  # NaN counts as above
    n = len(t)
    any_above = above.any(axis=0)
    last = n - 1 - np.argmax(above[::-1], axis=0)  # last index above (meaningless where none is)
    out = np.where(last == n - 1, np.nan, t[np.minimum(last + 1, n - 1)])
    return np.where(any_above, out, t[0])


def params_text(params: dict) -> str:
    """A plant's parameters as ``key = value`` pairs (``no parameters`` when empty)."""
    return ", ".join(f"{k} = {v}" for k, v in params.items()) or "no parameters"


def chain_refusal(sc, lp, plant) -> str | None:
    """Why loop ``lp`` of ``sc`` has no exact ideal-chain twin (the found part of a refusal), or None when it has."""
    stages = [name for name in ("sensor", "observer", "actuator") if getattr(lp, name) is not None]
    if not plant.exact_chain_twin:
        return f"plant {sc.plant.model} with {params_text(sc.plant.params)}: not the ideal chain"
    return f"loop {lp.name} with a {' and '.join(stages)} model" if stages else None


def chain_loop(sc, loop: str):
    """(LoopSpec, plant) of the scenario's loop, refusing what has no exact ideal-chain twin."""
    from ftstab_mj.plants import make_plant

    lp = next((x for x in sc.loops if x.name == loop), None)
    if lp is None:
        raise ScenarioError("montecarlo", "--loop", "a loop of the scenario (" + ", ".join(x.name for x in sc.loops) + ")",
                            repr(loop))
    plant = make_plant(sc.plant.model, sc.plant.params)
    found = chain_refusal(sc, lp, plant)
    if found:
        raise ScenarioError("montecarlo", "--on chain", "an ideal-chain or frictionless, undamped cart loop without "
                            "sensor, observer or actuator models (its exact twin is the ideal chain); use --on plant",
                            found)
    return lp, plant


def plan(sc, loop: str | None, states: int, box=None, on: str | None = None, workers: int = 1, engine=None,
         scheduler=None) -> tuple[str, tuple[float, ...], str]:
    """(loop name, box, on) of a Monte Carlo of scenario ``sc``, checked before anything runs or is printed:
    ``loop`` (None: the first) one of its loops, 1 <= ``states`` <= MAX_STATES, ``box`` (None: max |z0_i|
    of the loop on every axis, 1 where z0 = 0) one half-width per z_i, and with ``on="chain"`` no
    workers, engine or scheduler (the native chain uses both cores itself) and a loop with an exact
    chain twin (:func:`chain_loop`). ``on`` None: "chain" where the loop has an exact twin and no engine
    option is given (the fastest, exact), else "plant". UsageError or ScenarioError, one line naming the
    command's option."""
    from ftstab_mj.plants import make_plant

    loop = loop or sc.loops[0].name
    lp = next((x for x in sc.loops if x.name == loop), None)
    if lp is None:
        raise UsageError(f"--loop: expected a loop of {sc.name} ({', '.join(x.name for x in sc.loops)}), found {loop!r}")
    if not 1 <= states <= MAX_STATES:
        raise UsageError(f"--states: expected an integer in [1, {MAX_STATES}] (a work limit), found {states}")
    r = len(lp.z0)
    box = tuple(box or (max(abs(x) for x in lp.z0) or 1.0,) * r)
    if len(box) != r:
        raise UsageError(f"--box: expected {r} half-widths (one per z_i of loop {loop}), found {len(box)}")
    engine_asked = workers > 1 or scheduler or engine
    if on is None:
        on = "plant" if engine_asked or chain_refusal(sc, lp, make_plant(sc.plant.model, sc.plant.params)) else "chain"
    if on == "chain" and engine_asked:
        raise UsageError("--on chain: expected no --workers/--engine/--scheduler (the native chain uses both cores itself)")
    if on == "chain":
        chain_loop(sc, loop)  # a plant with no exact chain twin is refused before anything is printed
    return loop, box, on


def loop_info(sc, lp, law, plant) -> LoopInfo:
    """The LoopInfo a run of this loop would record (what metrics.time_bound and bound_applies read)."""
    phibar, gm, gM = plant.true_bounds([lp.disturbance.bounds()], [lp.gain.bounds()])
    return LoopInfo(name=lp.name, r=law.r, law=law.name, hong=law.base_info(), law_params=law.param_values(),
                    true_phibar=float(phibar[0]), true_gamma_m=float(gm[0]), true_gamma_M=float(gM[0]),
                    certificate_boxes=sc.metrics.certificate_boxes)


def _rows(info: LoopInfo, first: int, Z0, settle, V1_0, V1_end, u_max, status) -> list[dict]:
    rows = []
    bounds = mt.time_bound(info, Z0)  # NaN where no certificate holds
    for j in range(len(Z0)):
        ts = float(settle[j])
        tb = float(bounds[j])
        rows.append({"row": first + j, "z0": [float(x) for x in Z0[j]], "settle_time": ts, "time_bound": tb,
                     "ratio": ts / tb if math.isfinite(ts) and math.isfinite(tb) and tb > 0 else math.nan,
                     "V1_initial": float(V1_0[j]), "V1_final": float(V1_end[j]), "u_max_abs": float(u_max[j]),
                     "status": status[j] if isinstance(status, list) else status})
    return rows


def run_chain(sc, loop: str, Z0: np.ndarray, chunk: int = 128, native="auto", progress=None,
              segment: int = 1000) -> tuple[list[dict], LoopInfo]:
    """Per-trajectory rows of the scenario's loop on the ideal chain from every row of Z0 (N, r).

    Each chunk of states runs in pieces of ``segment`` samples, each reduced as it comes (settle time,
    first and last V1, max |u|, finiteness), so memory is flat in the duration; the rows are those of
    the whole run reduced at once (the same bits)."""
    from ftstab_mj.simulation.ideal_chain import simulate_chain_segments
    from ftstab_mj.simulation.run_loop import steps_per_period

    lp, plant = chain_loop(sc, loop)
    law = lp.law(plant.r)
    info = loop_info(sc, lp, law, plant)
    substeps = steps_per_period(sc.sim.period, sc.sim.physics_step)
    level = sc.metrics.settle_level
    rows = []
    for first in range(0, len(Z0), chunk):
        Zc = Z0[first:first + chunk]
        settle = _Settle(level)
        V1_0 = V1_end = u_max = finite = None
        for run in simulate_chain_segments(law, Zc, sc.sim.period, sc.sim.duration, phi=lp.disturbance,
                                           gamma=lp.gain, substeps=substeps, native=native, segment=segment):
            if not len(run.t):
                continue
            settle.add(run.t, run.V1)
            piece_max = np.max(np.abs(run.u), axis=0)
            piece_finite = np.isfinite(run.z).all(axis=(0, 2))
            V1_0 = run.V1[0] if V1_0 is None else V1_0
            V1_end = run.V1[-1]
            u_max = piece_max if u_max is None else np.maximum(u_max, piece_max)  # NaN propagates, as np.max
            finite = piece_finite if finite is None else finite & piece_finite
        if V1_0 is None:  # no sample (a duration shorter than a period): the whole-run reduction of nothing
            raise ScenarioError("montecarlo", "sim.duration", "at least one control period", sc.sim.duration)
        status = ["completed" if f else "diverged" for f in finite]
        rows += _rows(info, first, Zc, settle.times(), V1_0, V1_end, u_max, status)
        if progress:
            progress(min(first + chunk, len(Z0)), len(Z0))
    return rows, info


class _Settle:
    """:func:`settle_times` of samples given in consecutive pieces: the first sample time of each
    trajectory after its last sample above ``level`` (NaN counts as above), the run's first time if
    none is above, NaN if the last sample is above."""

    def __init__(self, level: float):
        self.level, self.t0, self.after, self.ever, self.pending = level, None, None, None, None

    def add(self, t: np.ndarray, V1: np.ndarray) -> None:
        """One piece: t (n,), V1 (n, B)."""
        above = ~(V1 <= self.level)
        some = above.any(axis=0)
        piece = settle_times(t, V1, self.level)  # NaN where the piece's last sample is above
        if self.t0 is None:
            self.t0, self.after, self.ever = t[0], np.full(V1.shape[1], np.nan), np.zeros(V1.shape[1], bool)
            self.pending = np.zeros(V1.shape[1], bool)
        # a trajectory above at the end of the last piece settles at this piece's first time if none is above here
        self.after = np.where(some, piece, np.where(self.pending, t[0], self.after))
        self.pending = above[-1]
        self.ever |= some

    def times(self) -> np.ndarray:
        return np.where(self.ever, np.where(self.pending, np.nan, self.after), self.t0)


def run_plant(task, loop: str, Z0: np.ndarray, engine="serial", workers=1, scheduler=None, progress=None) -> list[dict]:
    """Per-trajectory rows from runs of the scenario (sweep.row.ScenarioTask or StatesTask ``task``) with
    ``loops.<loop>.z0`` set to each row of Z0, on a sweep engine; the metrics are those of ``ftstab run``."""
    from ftstab_mj.studies.sweep.engine import execute

    key = f"loops.{loop}.z0"
    items = [(i, ((key, [float(x) for x in z]),)) for i, z in enumerate(Z0)]
    rows, done = [None] * len(Z0), 0
    for i, result in execute(items, task, engine, workers, scheduler):
        m = (result or {}).get("metrics", {}).get("loops", {}).get(loop, {})
        nan = math.nan

        def num(name):
            v = m.get(name)
            return nan if v is None else float(v)

        ts, tb = num("settle_time"), num("time_bound")
        rows[i] = {"row": i, "z0": [float(x) for x in Z0[i]], "settle_time": ts, "time_bound": tb,
                   "ratio": ts / tb if math.isfinite(ts) and math.isfinite(tb) and tb > 0 else nan,
                   "V1_initial": num("V1_initial"), "V1_final": num("V1_final"), "u_max_abs": num("u_max_abs"),
                   "bound_applies": bool(m.get("bound_applies")),
                   "status": "lost" if result is None else result["status"]}
        done += 1
        if progress:
            progress(done, len(Z0))
    return rows


def run_on(on: str, sc, path, overrides, loop: str, Z0: np.ndarray, engine=None, workers: int = 1,
           scheduler=None, progress=None) -> tuple[list[dict], bool]:
    """(rows, whether the time bound applies) of the states ``Z0`` of ``loop``: ``on="chain"`` on the ideal
    chain (:func:`run_chain`; the bound as the loop's LoopInfo says), ``"plant"`` as runs of the scenario
    file ``path`` with ``overrides`` (--set texts) on the sweep engine of ``engine``/``workers``/``scheduler``
    (sweep.engine.choose_engine; :func:`run_plant`; the bound where every run's own metric says it applies)."""
    if on == "chain":
        rows, info = run_chain(sc, loop, Z0, progress=progress)
        return rows, mt.bound_applies(info)
    from ftstab_mj.config.tomlfile import read_toml
    from ftstab_mj.scenario.loader import apply_override
    from ftstab_mj.studies.sweep.engine import choose_engine
    from ftstab_mj.studies.sweep.row import ScenarioTask, StatesTask

    raw = read_toml(path, "scenario file (.toml)")
    for text in overrides:
        apply_override(raw, text, str(path))
    engine = choose_engine(engine, workers, scheduler)
    lp = next(x for x in sc.loops if x.name == loop)
    hong = lp.law(len(lp.z0)).base_info()
    # the runs' T(z0) from V1(z0) enclosed for every state at once (the same bits; runs in this process)
    ahead = mt.V1_enclosures_ahead(hong, Z0) if hong else contextlib.nullcontext()
    with ahead:
        # each state a run of the scenario, on one simulation per thread reset to its z0 (StatesTask)
        rows = run_plant(StatesTask(ScenarioTask(raw, str(path)), loop), loop, Z0, engine, workers, scheduler,
                         progress)
    return rows, bool(rows) and all(rw["bound_applies"] for rw in rows)  # each run's own metric


def summarize(rows: list[dict], bound_applies: bool, duration: float | None = None) -> dict:
    """The distribution of settle_time / T(z0) and the worst case, as plain JSON-able data.

    ``duration`` (s): the runs' simulated time. A state not settled by then breaks its bound only where its
    T(z0) lies within the run (``late``); one whose T(z0) lies beyond the run says nothing either way
    (``unsettled_bound_beyond``, with ``longest_bound`` the run length that would show them settle).
    ``violations``: states with settle_time / T(z0) > 1 plus the late ones, while the bound applies.
    ``worst``: a late state if any, else the largest ratio, else a state that never settled (not one whose bound
    lies beyond the run: it is no worst case of anything)."""
    ratio = np.array([r["ratio"] for r in rows], dtype=float)
    settled = np.array([math.isfinite(r["settle_time"]) for r in rows])
    finite = ratio[np.isfinite(ratio)]
    q = (lambda p: float(np.quantile(finite, p))) if len(finite) else (lambda p: None)
    never = [r for r in rows if not math.isfinite(r["settle_time"])]
    late = [r for r in never if duration is not None and math.isfinite(r["time_bound"]) and r["time_bound"] <= duration]
    beyond = [r for r in never if duration is not None and math.isfinite(r["time_bound"]) and r["time_bound"] > duration]
    infinite = sum(1 for r in rows if not math.isfinite(r.get("V1_initial", 0.0)))
    if infinite:  # V1(z0) beyond float range: T(z0) is no number, the bound cannot be said to apply (W3)
        bound_applies = False
    largest = max((r for r in rows if math.isfinite(r["ratio"])), key=lambda r: r["ratio"]) if len(finite) else None
    unknown = [r for r in never if r not in beyond]  # never settled, no bound within or beyond the run to judge by
    worst = late[0] if late else largest if largest is not None else (unknown[0] if unknown else None)
    return {"states": len(rows), "settled": int(settled.sum()), "never_settled": len(never),
            "bound_applies": bool(bound_applies), "with_bound": int(len(finite)),
            "ratio": {"min": q(0.0), "median": q(0.5), "p90": q(0.9), "p99": q(0.99), "max": q(1.0)},
            "violations": int(np.sum(finite > 1.0)) + len(late) if bound_applies else None,
            "unsettled_bound_beyond": len(beyond),
            "longest_bound": max((r["time_bound"] for r in beyond), default=None),
            "bound_note": (f"V1(z0) is not a finite number for {infinite} state(s) (the box is beyond float range): "
                           "no time bound is checked" if infinite else None),
            "worst": None if worst is None else {k: worst[k] for k in ("row", "z0", "settle_time", "time_bound", "ratio")}}


def json_text(summary: dict) -> str:
    """The summary as strict JSON: a non-finite number (a state that never settled, no time bound) is null,
    never the bare NaN or Infinity that JSON does not have; what each null means is in the field's doc
    (settle_time null: never settled; time_bound and ratio null: no certificate or V1 not finite)."""
    import json

    def strict(v):
        if isinstance(v, float) and not math.isfinite(v):
            return None
        if isinstance(v, dict):
            return {k: strict(x) for k, x in v.items()}
        if isinstance(v, (list, tuple)):
            return [strict(x) for x in v]
        return v

    return json.dumps(strict(summary), indent=2, allow_nan=False)


def figure(rows: list[dict], summary: dict, title: str, path) -> None:
    """Histogram of settle_time / T(z0) with the guarantee (ratio 1) marked; PNG at ``path``. Drawn with
    matplotlib's object API (Figure + Agg canvas): importing pyplot would cost ~0.1 s more CPU, no global state."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    ratio = np.array([r["ratio"] for r in rows], dtype=float)
    ratio = ratio[np.isfinite(ratio)]
    fig = Figure(figsize=(7, 4))
    FigureCanvasAgg(fig)
    ax = fig.subplots()
    if len(ratio):
        ax.hist(ratio, bins=min(60, max(10, int(np.sqrt(len(ratio))))), color="#4477aa")
        ax.axvline(1.0, color="#cc3311", lw=1.5, label="guarantee: settle time = T(z0)")
        ax.legend(loc="upper right")
    else:
        ax.text(0.5, 0.5, "no state has a time bound (no certificate)", ha="center", transform=ax.transAxes)
    ax.set_xlabel("settle time / T(z0)  (dimensionless)")
    ax.set_ylabel("initial states")
    never = summary["never_settled"]
    ax.set_title(f"{title}\n{summary['states']} states, {never} never settled", fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
