"""Speed of the chain plants (the arms, a user model): per-step cost against bare MuJoCo stepping, and
the start-up of the shipped arm scenarios before their first sample.

    python -m benchmarks arm_speed [--repeat 5] [--steps 20000] [--code DIR]

per step   Simulation.advance (robust law, one sample per 1 ms physics step, batches of 1000), native
           and Python callback, against mj_step(m, d, nstep) of the same compiled model with no
           callback: CPU-time ratios, taken alternately in each repetition, median (min-max).
start-up   a fresh interpreter per measurement: the imports, then load_scenario(NAME) (which builds
           the plant and any "computed" bound) up to the moment the run opens its first sink, i.e.
           everything before the first sample is stepped (the bound tables included, cold cache).
           ``--code DIR`` measures the start-up of another checkout (e.g. the code before a change)
           with the same method, alternately with this one. The interpreters read bytecode cached as
           an installed package has it (benchmarks/_common.child_env).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

import mujoco

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks._common import child_env  # noqa: E402
from ftstab_mj.control import HongController, RobustLaw  # noqa: E402
from ftstab_mj.plants import make_plant  # noqa: E402
from ftstab_mj.scenario import LoopSpec  # noqa: E402
from ftstab_mj.simulation.run_loop import Simulation  # noqa: E402

STEP = 1e-3
BATCH = 1000
SCENARIOS = ("arm_robust", "arm_adaptive", "arm_r3_robust", "arm_r3_adaptive", "arm3_robust", "arm3_adaptive")

# Runs in a fresh interpreter: the time of the imports, then of everything up to the first sink's open().
STARTUP = r"""
import sys, time, json
t0 = time.perf_counter()
from ftstab_mj.scenario import find_scenario, load_scenario
from ftstab_mj.scenario.run import run_scenario
t1 = time.perf_counter()
class First:
    def open(self, info):
        self.t = time.perf_counter()
        raise KeyboardInterrupt  # stop before the first sample: only the start-up is measured
    def write(self, batch): pass
    def close(self, *a, **k): pass
sink = First()
try:
    run_scenario(load_scenario(find_scenario(sys.argv[1]), ["sim.duration=0.01"]), [sink])
except KeyboardInterrupt:
    pass
print(json.dumps({"imports": t1 - t0, "startup": sink.t - t1}))
"""


def _reacher():
    import gymnasium

    xml = Path(gymnasium.__file__).parent / "envs" / "mujoco" / "assets" / "reacher.xml"
    sys.path.insert(0, str(ROOT / "tests"))
    from test_plants_user import REACHER  # the reacher's loops and workspace as the tests use them

    return make_plant(str(xml), REACHER)


def _sim(plant, native):
    hong = HongController(plant.r, -0.2 if plant.r == 2 else -0.1, (1.0, 2.0) if plant.r == 2 else (1.0, 1.7, 5.0))
    loops = [LoopSpec(name, z0=(-0.2,) + (0.0,) * (plant.r - 1), controller=RobustLaw(hong, 20.0, 1.5), ref=0.1)
             for name in plant.loop_names]
    return Simulation(plant, loops, STEP, STEP, native=native)


def _cpu(fn) -> float:
    t = time.process_time()
    fn()
    return time.process_time() - t


def per_step(plant, steps: int, repeat: int) -> dict:
    """{"native": [ratios], "python": [ratios]} of CPU time per step against bare stepping."""
    m, d, _ = plant.compile(STEP)
    out = {"native": [], "python": []}
    sims = {"native": _sim(plant, True), "python": _sim(plant, False)}
    for _ in range(repeat):
        bare = _cpu(lambda: mujoco.mj_step(m, d, nstep=steps))
        for kind, sim in sims.items():
            # the Python callback: a tenth, scaled (one batch at least: below 10 batches it timed nothing)
            n = steps if kind == "native" else max(steps // 10, BATCH)
            with sim.installed():
                t = _cpu(lambda: [sim.advance(BATCH) for _ in range(n // BATCH)])
            out[kind].append(t * (steps / n) / bare)
    return out


def startup(code: Path, name: str) -> dict:
    env = child_env(code)
    proc = subprocess.run([sys.executable, "-c", STARTUP, name], capture_output=True, text=True, env=env, cwd=code)
    if proc.returncode != 0:
        return {"error": proc.stderr.strip().splitlines()[-1] if proc.stderr.strip() else "failed"}
    return json.loads(proc.stdout.strip().splitlines()[-1])


def _fmt(values) -> str:
    return f"{statistics.median(values):.3g} ({min(values):.3g}-{max(values):.3g})"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--steps", type=int, default=20000)
    ap.add_argument("--code", type=Path, help="another checkout whose start-up is measured alternately")
    args = ap.parse_args(argv)
    print(f"load average {os.getloadavg()[0]:.2f}, {os.cpu_count()} CPUs")
    print("per step, CPU time against bare mj_step(nstep): median (min-max)")
    for label, build in (("arm", lambda: make_plant("arm")), ("arm_integrating", lambda: make_plant("arm_integrating")),
                         ("arm3", lambda: make_plant("arm3")), ("gymnasium reacher.xml", _reacher)):
        r = per_step(build(), args.steps, args.repeat)
        print(f"  {label:24s} native {_fmt(r['native'])}   python {_fmt(r['python'])}")
    codes = [("this", ROOT)] + ([("--code", args.code.resolve())] if args.code else [])
    print("start-up before the first sample (s, fresh interpreter, cold caches): median (min-max)")
    for name in SCENARIOS:
        times = {label: [] for label, _ in codes}
        imports = {label: [] for label, _ in codes}
        errors = {}
        for _ in range(args.repeat):
            for label, code in codes:  # alternately
                r = startup(code, name)
                if "error" in r:
                    errors[label] = r["error"]
                    continue
                times[label].append(r["startup"])
                imports[label].append(r["imports"])
        row = "   ".join(f"{label}: {_fmt(times[label])} (imports {_fmt(imports[label])})" if times[label]
                         else f"{label}: {errors.get(label, '-')[:60]}" for label, _ in codes)
        print(f"  {name:16s} {row}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
