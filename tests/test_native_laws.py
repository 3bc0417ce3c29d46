"""The C twins of every registered law (native/laws.c) against the NumPy reference (control/laws/).

Two levels, as for the paper's laws (tests/test_native.py, tests/test_native_sim.py):

* one sample, on random states over 10 decades with exact zeros: every LawOutput field and the state
  one period later (law.evaluate then law.advance, as the run loop calls them);
* whole runs of the MuJoCo run loop, native callback against Python callback, over every combination
  the callback takes ({euler, implicitfast} x {cart r = 2, cart_integrating r = 3} x {1, 5} physics
  steps per period), every field of every sample.

Tolerance. The reference is each law evaluated one state at a time, as the run loop's Python path
calls it (its powers of NumPy scalars are libm's pow, as in laws.c). The C code does the NumPy code's
operations in its order, so one sample is bit-identical (tolerance 0), except where NumPy sums
through a BLAS dot product (linear's K z, P z; a surface of r > 2 coefficients), whose order may
differ: there 1e-13 relative to max(1, sum of |terms| x the largest gain), a sum's rounding (r eps
per term) with margin. Whole runs: 1e-12 relative to max(1, |value|) as for the
paper's laws; measured bit-identical.
"""

import numpy as np
import pytest

from ftstab_mj.control.law import LAWS
from ftstab_mj.control.laws.adaptive_super_twisting import AdaptiveSuperTwisting
from ftstab_mj.control.laws.fixed_time import FixedTime
from ftstab_mj.control.laws.huang_adaptive import HuangAdaptive
from ftstab_mj.control.laws.integral_hosm import IntegralHOSM
from ftstab_mj.control.laws.levant import LevantNested, LevantQuasiContinuous
from ftstab_mj.control.laws.linear import LinearLaw
from ftstab_mj.control.laws.paper import RobustLaw
from ftstab_mj.control.laws.sliding_surface import PlestanAdaptive, SuperTwisting
from ftstab_mj.control.laws.terminal import Terminal
from ftstab_mj.control.laws.twisting import Twisting
from ftstab_mj.control import HongController
from ftstab_mj.plants import make_plant
from ftstab_mj.plants.disturbances import Signal
from ftstab_mj.scenario import LoopSpec
from ftstab_mj.simulation import native
from ftstab_mj.simulation.records import LOOP_FIELDS
from ftstab_mj.simulation.run_loop import Simulation, simulate
from test_native import random_states  # states over 10 decades, exact zeros: the paper laws' twins use the same

pytestmark = pytest.mark.skipif(not native.available(), reason=f"native kernel: {native.UNAVAILABLE_REASON}")

PERIOD = 1e-3
SURF = {1: (), 2: (3.0,), 3: (2.0, 3.0), 4: (1.0, 3.0, 3.0)}
HONG = {r: HongController(r, -0.1 / r, g) for r, g in ((1, (2.0,)), (2, (1.0, 2.0)), (3, (1.0, 1.7, 5.0)))}


def field_laws(r: int) -> list:
    """Every law with a C twin other than the paper's explicit ones, at chain length r (those defined there)."""
    out = [LinearLaw(tuple(-2.0 - i for i in range(r))),
           SuperTwisting(r, SURF[r], k1=4.0, k2=8.8), SuperTwisting(r, SURF[r], "implicit", k1=4.0, k2=8.8),
           PlestanAdaptive(r, SURF[r], Kbar=20.0, mu=0.05, eps=0.01),
           PlestanAdaptive(r, SURF[r], "implicit", Kbar=20.0, mu=0.05, eps=0.01),
           IntegralHOSM(r, 2.0, 3.0),
           AdaptiveSuperTwisting(r, SURF[r], omega1=20.0, gamma1=1.0, mu_band=0.01, alpha_min=0.5, epsilon=1.0),
           HuangAdaptive(r, SURF[r], Kbar=20.0, K0=0.5)]
    if r <= 4:
        out += [LevantNested(r, 5.0), LevantQuasiContinuous(r, 5.0)]
    if r in HONG:
        out += [RobustLaw(HONG[r], 1.0, 0.7, "implicit")]
    if r == 2:
        out += [Twisting(2, 5.0, 2.0), Terminal(2, 2.0, 1.5, 3.0), FixedTime(2, 1.0, 2.0, 3.0)]
    return [law.for_period(PERIOD) for law in out]


def law_id(law) -> str:
    return f"{law.name}-r{law.r}" + ("-implicit" if getattr(law, "discretization", "") == "implicit" else "")


ALL = [pytest.param(law, id=law_id(law)) for r in (1, 2, 3, 4) for law in field_laws(r)]


def test_every_registered_law_has_a_twin():
    """Each shipped law's class declares its C twin; a subclass (a plugin changing the maths) does not."""
    shipped = {type(law) for r in (1, 2, 3) for law in field_laws(r)}
    assert {cls for cls in LAWS.values() if cls.__module__.startswith("ftstab_mj.")} - shipped <= {
        LAWS["nominal"], LAWS["robust"], LAWS["adaptive"]}  # pinned in tests/test_native.py
    codes = [cls.native_code for cls in LAWS.values() if cls.__module__.startswith("ftstab_mj.")]
    assert None not in codes and len(set(codes)) == len(codes)

    class Mine(SuperTwisting):
        def evaluate(self, z, state):
            return super().evaluate(z, state)

    assert not native.use_native("auto", Mine(2, (3.0,), k1=1.0, k2=1.0))


def random_law_states(rng, law, n):
    """The law's state spread over its regimes (below and above its floors, tau before and after t_final)."""
    x = np.broadcast_to(law.initial_state(), (n, law.state_size)).copy()
    if law.state_size:
        x = x * rng.uniform(0.0, 3.0, x.shape) + rng.standard_normal(x.shape) * (rng.random(x.shape) < 0.5)
    if isinstance(law, IntegralHOSM):
        x[:, 0] = np.where(rng.random(n) < 0.1, 0.0, rng.uniform(0.0, 3.0, n))
    return x


def dot_scale(law, z):
    """max(1, sum of |terms|) of the BLAS sums in the law's NumPy code, times its largest gain (1: none)."""
    a = np.abs(z)
    if isinstance(law, LinearLaw):
        P = np.abs(law.P)
        return np.maximum(1.0, a @ np.abs(law.K) + np.einsum("ni,ij,nj->n", a, P, a) + np.max(a @ P, axis=1))
    c = getattr(law, "surface", ())
    c = np.abs(c) if isinstance(c, tuple) else ()  # a tuple of coefficients (terminal's is a method)
    if len(c) > 1:
        return np.maximum(1.0, a[:, :-1] @ c + a[:, 1:] @ c) * np.max(np.abs(law.native_params()["par"]))
    return np.ones(len(z))


def reference_sample(law, z, x):
    """law.evaluate and law.advance one state at a time, as the run loop's Python path calls them
    (z (r,), state (m,)): LawOutput of (n,) fields, states (n, m)."""
    outs, nxt = [], []
    for zk, xk in zip(z, x):
        out = law.evaluate(zk, xk)
        outs.append(out)
        nxt.append(np.reshape(law.advance(zk, xk, out, PERIOD), law.state_size))
    return type(outs[0])(*(np.array([float(getattr(o, f)) for o in outs]) for f in outs[0]._fields)), np.array(nxt)


@pytest.mark.parametrize("law", ALL)
def test_one_sample_agrees_on_random_states(law):
    rng = np.random.default_rng(0)
    n = 1500
    z = random_states(rng, n, law.r)
    x = random_law_states(rng, law, n)
    ref, ref_next = reference_sample(law, z, x)
    fast, fast_next = native.law_sample(law, z, x, PERIOD)
    scale = dot_scale(law, z)
    # a BLAS sum: its rounding; else the same doubles (Hong's V1 included: |a|^(b+1) as |a|^b |a| on both)
    tol = 1e-13 if np.any(scale != 1.0) else 0.0
    for name in ref._fields:
        a = np.broadcast_to(getattr(ref, name), (n,))
        b = getattr(fast, name)
        assert np.array_equal(np.isnan(a), np.isnan(b)), name
        err = np.abs(np.nan_to_num(b) - np.nan_to_num(a)) / np.maximum(scale, np.abs(np.nan_to_num(a)))
        assert np.max(err) <= tol, f"{name}: max relative difference {np.max(err):.3g} > {tol:g}"
    if law.state_size:
        err = np.abs(fast_next - ref_next) / np.maximum(scale[:, None], np.abs(ref_next))
        assert np.max(err) <= tol, f"state: max relative difference {np.max(err):.3g} > {tol:g}"
    assert np.all(np.isfinite(fast.u))


# -- whole runs -------------------------------------------------------------------------------------
def run_laws(r: int) -> list:
    """The laws tuned to settle the cart (r = 2) or the integrating cart (r = 3) from z_1 = 0.3."""
    laws = [law for law in field_laws(r) if not isinstance(law, IntegralHOSM)] + [IntegralHOSM(r, 0.5, 3.0)]
    return [pytest.param(r, law, id=law_id(law)) for law in laws]


GRID = [(integrator, N) for integrator in ("euler", "implicitfast") for N in (1, 5)]


def assert_same_run(ref, fast):
    assert (fast.status, fast.message, fast.n_samples) == (ref.status, ref.message, ref.n_samples)
    for name in ref.loops:
        for f in ref.loops[name]:
            a, b = ref.loops[name][f], fast.loops[name][f]
            assert np.array_equal(np.isnan(a), np.isnan(b)), f"{name} {f}: NaN pattern"
            a, b = np.nan_to_num(a), np.nan_to_num(b)
            err = np.max(np.abs(b - a) / np.maximum(1.0, np.abs(a)), initial=0.0)
            assert err <= 1e-12, f"{name} {f}: max relative difference {err:.3g}"
    np.testing.assert_allclose(fast.body_pos, ref.body_pos, rtol=0, atol=1e-12)


@pytest.mark.parametrize("integrator,N", GRID, ids=[f"{i}-N{n}" for i, n in GRID])
@pytest.mark.parametrize("r,law", run_laws(2) + run_laws(3))
def test_native_run_records_what_the_python_run_records(r, law, integrator, N):
    """0.6 s of the cart (r = 2) or the integrating cart (r = 3) in batches of 70, sine disturbance and gain."""
    lp = LoopSpec("cart", controller=law, disturbance=Signal("sine", 0.0, 0.4, freq=2.0),
                  gain=Signal("sine", 1.0, 0.2, freq=1.5), z0=(0.3,) + (0.0,) * (r - 1))
    args = (make_plant("cart" if r == 2 else "cart_integrating"), [lp], 0.6, N * 1e-3, 1e-3, integrator)
    sim = Simulation(args[0], [lp], N * 1e-3, 1e-3, integrator, native=True)
    assert sim._native is not None  # the law's declared twin runs, not the Python callback
    ref = simulate(*args, batch_size=70, native=False)
    fast = simulate(*args, batch_size=70, native=True)
    assert_same_run(ref, fast)
    assert set(LOOP_FIELDS) <= set(ref.loops["cart"])
    z = ref.loops["cart"]["z"]
    assert abs(z[-1, 0]) < abs(z[0, 0])  # the controller acted: z_1 moved towards 0


def test_arm_with_super_twisting_on_both_joints_runs_natively():
    plant = make_plant("arm")
    loops = [LoopSpec(f"joint{i}", controller=SuperTwisting(2, (3.0,), k1=4.0, k2=8.8), z0=(0.2, 0.0), ref=0.3 * i)
             for i in range(2)]
    args = (plant, loops, 0.3, 1e-3, 1e-3)
    assert Simulation(plant, loops, 1e-3, 1e-3, native=True)._native is not None
    assert_same_run(simulate(*args, native=False), simulate(*args, native=True))


def test_a_field_law_with_loop_stages_runs_natively():
    """A sensor with noise and delay, Levant's differentiator and a lagged, saturated actuator around
    the quasi-continuous law: the stages and the law in the callback, as in Python."""
    from ftstab_mj.scenario.schema import ActuatorSpec, ObserverSpec, SensorSpec

    lp = LoopSpec("cart", controller=LevantQuasiContinuous(2, 5.0), disturbance=Signal("sine", 0.0, 0.4, freq=2.0),
                  z0=(0.3, 0.0), sensor=SensorSpec(measured="position", noise=1e-4, delay=1, seed=3),
                  observer=ObserverSpec("levant", 6.0), actuator=ActuatorSpec(u_max=4.0, tau=0.003))
    args = (make_plant("cart"), [lp], 0.5, 2e-3, 1e-3)
    assert Simulation(args[0], [lp], 2e-3, 1e-3, native=True)._native is not None
    assert_same_run(simulate(*args, batch_size=70, native=False), simulate(*args, batch_size=70, native=True))
