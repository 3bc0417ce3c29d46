"""A Ctrl-C at any point of a batch: every sample the run hands out was computed (issue: a Ctrl-C at
the start of a native batch kept the previous batch's row count, so a whole batch of uninitialised
memory, values like 6.9e-310, went to both logs as real samples).

In process, deterministic: a trace function raises KeyboardInterrupt (what Python's SIGINT handler
does) at the k-th line executed in the batch code (the simulation's methods) during one batch,
for every k; every
sample the sink received, and every sample of the run's own result, is compared bit for bit with
the same sample of an uninterrupted run.
"""

import sys

import numpy as np
import pytest

from conftest import ROOT
from ftstab_mj.simulation import native
from ftstab_mj.simulation.records import INTERRUPTED, LOOP_FIELDS
from ftstab_mj.scenario import load_scenario
from ftstab_mj.scenario.run import run_scenario

# The code a batch runs through (the methods of these classes), where the interrupts are placed.
# The glue around batches (opening and closing sinks, handing batches out) is protected from signals
# by the run's deferral of them, and tested with real signals (tests/test_interruptions.py).
BATCH_CODE = ("Simulation.", "NativeRun.")


class Interrupter:
    """Raises KeyboardInterrupt at the ``at``-th line event (0-based) of the batch code while armed (``at`` = -1: never; ``count`` then says how many lines the armed stretch has)."""

    def __init__(self, at):
        self.at, self.count, self.armed = at, 0, False

    def arm(self):
        """Trace from here on, the frames already running included."""
        self.armed = True
        sys.settrace(self.trace)
        frame = sys._getframe(1)
        while frame is not None:
            if frame.f_code.co_qualname.startswith(BATCH_CODE):
                frame.f_trace = self.local
            frame = frame.f_back

    def trace(self, frame, event, arg):
        return self.local if frame.f_code.co_qualname.startswith(BATCH_CODE) else None

    def local(self, frame, event, arg):
        if event == "line" and self.armed:
            self.count += 1
            if self.count - 1 == self.at:
                raise KeyboardInterrupt
        return self.local


class Collector:
    """A sink keeping the samples it is handed. With an interrupter, the interrupts land in one
    batch: the first (armed at open, disarmed when it arrives) or the second (armed when the first
    arrives, disarmed when the second does)."""

    def __init__(self, interrupter=None, batch=1):
        self.interrupter, self.batch, self.batches, self.closed = interrupter, batch, [], None

    def open(self, info):
        if self.interrupter is not None and self.batch == 1:
            self.interrupter.arm()

    def write(self, batch):
        self.batches.append(batch)
        if self.interrupter is not None:
            self.interrupter.armed = False
            if len(self.batches) == self.batch - 1:
                self.interrupter.arm()

    def close(self, status, metrics, message=""):
        self.closed = status

    def samples(self, loop):
        if not self.batches:
            return {f: np.empty(0) for f in LOOP_FIELDS}
        return {f: np.concatenate([b.loops[loop][f] for b in self.batches]) for f in LOOP_FIELDS}


def run_interrupted(sc, at, batch):
    stop = Interrupter(at)
    sink = Collector(stop, batch)
    try:
        run = run_scenario(sc, (sink,), keep_samples=True)
    except KeyboardInterrupt:
        pytest.fail(f"a Ctrl-C at line {at} of the batch came out of the run instead of ending it as interrupted")
    finally:
        sys.settrace(None)
    return run, sink, stop


@pytest.mark.parametrize("path, batch", [("native", 1), ("native", 2), ("python", 1)])
def test_a_ctrl_c_at_every_line_of_a_batch_hands_out_only_computed_samples(path, batch):
    if path == "native" and not native.available():
        pytest.skip("the C kernel is not built")
    # batches of 1000 samples: the run's first batch of 3 samples, or its second after 1000
    settings = ["sim.period=0.001", "sim.physics_step=0.001", f"sim.duration={0.003 if batch == 1 else 1.003}"]
    if path == "python":  # rk4 needs the Python callback (the native one wants one forward pass a step)
        settings.append("sim.integrator=rk4")
    sc = load_scenario(ROOT / "scenarios" / "cart_r2_robust.toml", settings)
    ref_sink = Collector()
    reference = run_scenario(sc, (ref_sink,), keep_samples=True)
    ref = ref_sink.samples("cart")
    _, _, counter = run_interrupted(sc, -1, batch)  # how many lines the batch runs
    assert counter.count > 20
    interrupted = 0
    for at in range(counter.count):
        run, sink, _ = run_interrupted(sc, at, batch)
        for what, got in (("sink", sink.samples("cart")), ("result", run.result.loops["cart"])):
            n = len(got["t"])
            assert n <= len(ref["t"])
            for f in LOOP_FIELDS if n else ():
                np.testing.assert_array_equal(got[f], ref[f][:n], err_msg=f"interrupt at line {at}: {what} {f}")
        assert sink.closed == run.result.status
        interrupted += run.result.status == INTERRUPTED
    assert reference.result.status == "completed" and interrupted > counter.count // 2
