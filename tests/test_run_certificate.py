"""The certificate a run uses: its guaranteed T(z0) (outward rounded), its work limit, its pins."""

import mpmath as mp
import numpy as np
import pytest

from ftstab_mj.control import HongController, certify
from ftstab_mj.control.certificate import CERTIFIED, Certificate, V1_enclosure


def _certified(k: float, c: float) -> Certificate:
    """A certified full-form Certificate with c_lower = c for the homogeneity degree k."""
    return Certificate(form="full", c=c, alpha=(2.0 + 2.0 * k) / (2.0 + k), c_prime=None, alpha_prime=None,
                       certified=True, samples=100, seed=0, status=CERTIFIED, c_lower=c, c_upper=c, k=k)


def test_the_time_bound_is_above_the_exact_formula_and_the_float_one_is_not():
    """T = V^(1-alpha) / (c (1-alpha)) with alpha = (2+2k)/(2+k) for the float k taken exactly,
    against mpmath at 60 digits: Certificate.time_bound is never below it and within 1e-13 of it
    (outward rounding costs a few ulps: 1 - alpha is enclosed from the rational k, the power has a
    16-ulp margin plus 746 times the exponent's width); the plain float formula falls below the exact
    value in some of these cases, so it is not a guaranteed bound."""
    mp.mp.dps = 60
    rng = np.random.default_rng(5)
    ks = np.concatenate([[-0.2, -0.1, -0.05, -0.02, -0.01, -1e-3, -1e-6, -0.3, -0.45], -rng.uniform(1e-4, 0.16, 40)])
    cs = [0.0175, 0.6104035660530578, 1.3265, 4.5, 1e-3] + list(rng.uniform(1e-3, 10.0, 10))
    Vs = np.concatenate([[1e-8, 0.3, 1.0, 14.499456786671667, 1e6], 10.0 ** rng.uniform(-6, 6, 10)])
    below_float = 0
    worst = 0.0
    for k in ks:
        for c in cs:
            cert = _certified(float(k), float(c))
            T = cert.time_bound(Vs)
            kk = mp.mpf(float(k))
            oma = 1 - (2 + 2 * kk) / (2 + kk)
            for V, t in zip(Vs, T):
                exact = mp.power(mp.mpf(float(V)), oma) / (mp.mpf(float(c)) * oma)
                assert t >= exact, (k, c, V, t, exact)
                worst = max(worst, float((t - exact) / exact))
                a = cert.alpha
                below_float += float(V) ** (1.0 - a) / (c * (1.0 - a)) < exact
    assert worst < 1e-13, worst
    assert below_float > 0, "the float formula was never below the exact value: the test shows nothing"


def test_the_time_bound_of_an_enclosure_bounds_every_value_in_it():
    cert = _certified(-0.05, 0.61)
    from ftstab_mj.control.interval import Iv

    T = cert.time_bound(Iv(np.array([2.0]), np.array([3.0])))
    assert T[0] >= cert.time_bound(3.0) > cert.time_bound(2.0)
    assert cert.time_bound(np.array([1.0, 2.0])).shape == (2,) and isinstance(cert.time_bound(1.0), float)
    not_certified = Certificate(form="full", c=-1.0, alpha=cert.alpha, c_prime=None, alpha_prime=None,
                                certified=False, samples=100, seed=0, status="not certified", k=-0.05)
    assert not_certified.time_bound(1.0) == np.inf
    assert _certified(0.0, 1.0).time_bound(1.0) == np.inf  # k = 0: exponential, not finite-time


@pytest.mark.parametrize("r, k, gains", [(1, -0.3, (2.0,)), (2, -0.2, (1.0, 2.0)), (3, -0.1, (1.0, 1.7, 5.0)),
                                          (4, -0.05, (0.82723, 1.5168, 3.1113, 100.0)),
                                          (5, -0.01, (0.65, 1.2, 1.62, 12.63, 1000.0))])
def test_the_v1_enclosure_holds_the_controllers_v1_and_is_tight(r, k, gains):
    """V1_enclosure (the recursion of hong_terms in intervals) against HongController.V1 (the textbook
    chain, floats: an independent implementation): it holds it at 2000 states, among them states with
    zero components (where rebuilding z from s would be Hoelder-loose), and is within 1e-10 relative."""
    h = HongController(r, k, gains)
    z = np.random.default_rng(r).uniform(-1.0, 1.0, size=(2000, r)) * 10.0 ** np.random.default_rng(r).uniform(-3, 1, (2000, 1))
    z[:10, 1:] = 0.0
    z[10:20, 0] = 0.0
    E = V1_enclosure(r, k, gains, z)
    V = h.V1(z)
    assert np.all((E.lo <= V) & (V <= E.hi))
    pos = V > 0  # r = 1 with z_1 = 0: V1 = 0
    assert np.max((E.hi - E.lo)[pos] / V[pos]) < 1e-10 and np.all(E.hi[~pos] < 1e-300)


# -- pins: what the branch and bound guarantees, not its bits ------------------------------------

def _metrics_with(cert_of, duration=2.0):
    """The metrics of a synthetic adaptive r = 2 run (constant phi = 0.5: Theorem 3's Delta depends on
    c') whose certificate is cert_of(r, k, gains, form, box limit, progress)."""
    from synthetic_runs import synthetic_run

    from ftstab_mj.metrics import run_metrics as mt
    from ftstab_mj.plants.disturbances import Signal

    info, loops, _, _ = synthetic_run("adaptive", duration=duration, with_model=False, phi=Signal("constant", 0.5))
    saved = mt._certificate
    mt._certificate = cert_of
    try:
        return info, mt.compute_metrics(info, loops, "completed")
    finally:
        mt._certificate = saved


def test_a_pin_accepts_another_converged_branch_and_bound_and_rejects_a_wrong_bracket():
    """Pinned from the default certificate (stopping gap 2e-3), the expectations hold for the
    certificate of a B&B that stops at 1e-5 (another run of the same guarantee: c_lower, c_upper,
    c', T(z0), Delta and phi_hat_limsup all move, within the ranges), and fail when c_lower is
    1 % low (then T(z0) and phi_hat_limsup too), when c_upper is 1 % high (not converged), and when
    c' is 5 % high (then Delta)."""
    from dataclasses import replace

    from ftstab_mj.metrics.certificate_cache import cached_certify
    from ftstab_mj.metrics.expectations import check_metrics, pin_expectations

    info, pinned_from = _metrics_with(lambda r, k, g, form, n, say: cached_certify(r, k, g, form, n))
    pins = pin_expectations(pinned_from, info)
    assert all(o.ok for o in check_metrics(pinned_from, pins))
    spec = pins["loops"]["cart"]["certificate"]["c_lower"]
    assert set(spec) == {"min", "max"} and "theorem3" in pins["loops"]["cart"]

    tight = certify(HongController(2, -0.2, (1.0, 2.0)), rtol=1e-5)
    _, m = _metrics_with(lambda r, k, g, form, n, say: tight)
    new, old = m["loops"]["cart"], pinned_from["loops"]["cart"]
    assert new["certificate"]["c_lower"] != old["certificate"]["c_lower"]
    assert new["time_bound"] != old["time_bound"] and new["theorem3"]["Delta"] != old["theorem3"]["Delta"]
    assert new["theorem3"]["phi_hat_limsup"] != old["theorem3"]["phi_hat_limsup"]
    bad = [o.line for o in check_metrics(m, pins) if not o.ok]
    assert not bad, bad

    low = 0.99 * tight.c_lower
    high_cp = 1.05 * tight.c_prime_upper
    for wrong, keys in ((replace(tight, c=low, c_lower=low, c_upper=0.99 * tight.c_upper),
                         ("certificate.c_lower", "time_bound", "theorem3.phi_hat_limsup")),
                        (replace(tight, c_upper=tight.c_upper * 1.01), ("certificate.c_upper",)),
                        (replace(tight, c_prime=high_cp, c_prime_upper=high_cp, c_prime_lower=high_cp / 1.001),
                         ("certificate.c_prime_upper", "theorem3.Delta"))):
        _, m = _metrics_with(lambda r, k, g, form, n, say, w=wrong: w)
        failed = {o.path for o in check_metrics(m, pins) if not o.ok}
        assert {f"loops.cart.{key}" for key in keys} <= failed, failed


# -- the run's certificate: a deterministic work limit (metrics.certificate_boxes) ------------------

def _run_json(capsys, tmp_path, name, *sets):
    import json

    from ftstab_mj.cli import main

    args = ["run", name, "--out", str(tmp_path), "--json"]
    for s in sets:
        args += ["--set", s]
    assert main(args) == 0
    return json.loads(capsys.readouterr().out)["loops"]


def test_a_limit_that_stops_the_branch_and_bound_before_c_is_proven_leaves_no_time_bound(tmp_path, capsys):
    """cart_r3_robust (certified at 0.2 % within 1336 boxes, c and c') with metrics.certificate_boxes = 50:
    the run's certificate is undecided, and its metrics say so: no T(z0), no guarantee, a note
    naming the limit; the log records the limit, so its replay recomputes the same metrics."""
    import json

    from ftstab_mj.cli import main
    from ftstab_mj.logs.reader import read_log
    from ftstab_mj.metrics.run_metrics import envelope_kind

    m = _run_json(capsys, tmp_path, "cart_r3_robust", "sim.duration=0.2", "metrics.certificate_boxes=50")["cart"]
    cert = m["certificate"]
    assert cert["status"] == "undecided" and cert["box_limit"] == 50 and cert["boxes"] >= 50
    assert "undecided within 50 boxes (metrics.certificate_boxes)" in cert["note"] and "no T(z0)" in cert["note"]
    assert m["time_bound"] is None and m["bound_applies"] is False and m["beat_bound"] is None
    assert envelope_kind(m) == "not a guarantee: the certificate is undecided within 50 boxes"
    log = tmp_path / "cart_r3_robust.mcap"
    info = read_log(log).info
    assert info.metric_settings.certificate_boxes == 50 and info.loops[0].certificate_boxes == 50
    assert main(["replay", str(log), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["loops"]["cart"] == m
    assert main(["replay", str(log)]) == 0
    out = capsys.readouterr().out
    assert "identical to the ones recomputed" in out and "undecided within 50 boxes" in out


def test_a_limit_reached_once_c_is_proven_gives_a_looser_guaranteed_time_bound(tmp_path, capsys):
    """At 600 boxes the same certificate has proven c > 0 (the B&B proves that first) but not closed
    its gap: certified, the gap said in the note, and T(z0) = V1^(1-a)/(c_lower (1-a)) from that
    smaller c_lower, above the converged run's by exactly their ratio of c_lower."""
    limited = _run_json(capsys, tmp_path, "cart_r3_robust", "sim.duration=0.2", "metrics.certificate_boxes=600")["cart"]
    full = _run_json(capsys, tmp_path, "cart_r3_robust", "sim.duration=0.2")["cart"]
    a, b = limited["certificate"], full["certificate"]
    assert a["status"] == b["status"] == "certified" and b["note"] == ""
    assert a["c_lower"] < (1 - 2e-3) * b["c_lower"] and "with the gap still" in a["note"]
    assert limited["bound_applies"] and limited["time_bound"] > full["time_bound"]
    assert limited["time_bound"] == pytest.approx(full["time_bound"] * b["c_lower"] / a["c_lower"], rel=1e-9)


@pytest.mark.parametrize("value, found", [("0", "0"), ("1.5", "1.5"), ('"many"', "'many'"), ("100000000000", "100000000000")])
def test_a_bad_certificate_boxes_is_one_line_naming_the_key(value, found):
    from conftest import run_cli

    res = run_cli("run", "cart_r2_nominal", "--set", f"metrics.certificate_boxes={value}", "--out", "/nonexistent/x")
    assert res.returncode == 2 and res.stdout == ""
    (line,) = res.stderr.strip().splitlines()
    assert "metrics.certificate_boxes" in line and found in line, line


def test_a_log_recorded_before_the_limit_replays_with_the_branch_and_bounds_own_cap():
    from synthetic_runs import synthetic_run

    from ftstab_mj.control.certificate import DEFAULT_MAX_BOXES
    from ftstab_mj.simulation.records import RUN_CERTIFICATE_BOXES, RunInfo

    info, _, _, _ = synthetic_run("nominal", duration=0.01, with_model=False)
    d = info.to_dict()
    assert info.loops[0].certificate_boxes == info.metric_settings.certificate_boxes == RUN_CERTIFICATE_BOXES
    d["metric_settings"].pop("certificate_boxes")
    d["loops"][0].pop("certificate_boxes")
    old = RunInfo.from_dict(d)
    assert old.metric_settings.certificate_boxes == old.loops[0].certificate_boxes == DEFAULT_MAX_BOXES


def test_the_certificates_are_computed_before_any_log_opens_with_a_progress_line(tmp_path, monkeypatch):
    """run_scenario computes each loop's certificate before it opens a sink (a sink's open finds it
    in the cache), calling progress with a line naming the loop and its limit while the branch and
    bound runs (here from its start: PROGRESS_AFTER = 0), then "" (clear the line); a second run finds it
    cached and says nothing but ""."""
    from ftstab_mj.metrics import certificate_cache as cc
    from ftstab_mj.metrics import run_metrics as mt
    from ftstab_mj.scenario import find_scenario, load_scenario
    from ftstab_mj.scenario.run import run_scenario

    monkeypatch.setenv("FTSTAB_CACHE_DIR", str(tmp_path))
    cc.clear_memory()
    sc = load_scenario(find_scenario("cart_r3_robust"), ["sim.duration=0.05", "metrics.certificate_boxes=3001"])

    class Opened:
        cached = None

        def open(self, info):
            h = info.loops[0].hong
            Opened.cached = cc.cache_key(h["r"], h["k"], tuple(h["gains"]), h["form"], 3001) in cc._MEMORY

        def write(self, batch):
            pass

        def close(self, status, metrics, message=""):
            pass

    lines = []
    monkeypatch.setattr(mt, "PROGRESS_AFTER", 0.0)
    try:
        run_scenario(sc, (Opened(),), progress=lines.append)
        assert Opened.cached is True
        assert lines[-1] == "" and len(lines) >= 2  # at least the first round of the B&B is shown
        assert all(t.startswith("certificate of loop cart (r = 3, at most 3001 boxes per bound): c") for t in lines[:-1])
        again = []
        run_scenario(sc, (Opened(),), progress=again.append)
        assert again == [""]
    finally:
        cc.clear_memory()


def test_processes_that_miss_the_cache_at_once_compute_the_certificate_once(tmp_path):
    """Two processes ask for the same certificate at the same moment (each waits until both are
    ready): one computes it, the other waits for the lock and reads its file; both get the same."""
    import subprocess
    import sys
    from pathlib import Path

    child = """
import sys, time
from pathlib import Path
from ftstab_mj.metrics import certificate_cache as cc
calls = []
real = cc._cert.certify
cc._cert.certify = lambda *a, **k: calls.append(1) or real(*a, **k)
d = Path(sys.argv[1])
(d / ("ready" + sys.argv[2])).touch()
while len(list(d.glob("ready*"))) < 2:
    time.sleep(0.001)
c = cc.cached_certify(3, -0.1, (1.0, 1.7, 5.0), max_boxes=2999)
print(len(calls), repr(c.c_lower), c.boxes)
"""
    env = {**__import__("os").environ, "FTSTAB_CACHE_DIR": str(tmp_path / "cache")}
    root = Path(__file__).resolve().parent.parent
    procs = [subprocess.Popen([sys.executable, "-c", child, str(tmp_path), str(i)], env=env, cwd=root,
                              stdout=subprocess.PIPE, text=True) for i in range(2)]
    outs = [p.communicate(timeout=120)[0].split() for p in procs]
    assert all(p.returncode == 0 for p in procs)
    assert sorted(int(o[0]) for o in outs) == [0, 1], outs
    assert outs[0][1:] == outs[1][1:]


def test_replay_of_a_log_from_another_machine_shows_the_certificates_progress(tmp_path, monkeypatch):
    """A log whose certificate is not in this machine's cache: stream_metrics computes it before
    the metrics, with the same status lines as a run (and "" at the end), and the same metrics."""
    from ftstab_mj.metrics import certificate_cache as cc
    from ftstab_mj.metrics import run_metrics as mt
    from ftstab_mj.cli import main
    from ftstab_mj.logs.reader import stream_metrics

    monkeypatch.setenv("FTSTAB_CACHE_DIR", str(tmp_path / "here"))
    assert main(["run", "cart_r3_robust", "--set", "sim.duration=0.05", "--set", "metrics.certificate_boxes=2998",
                 "--out", str(tmp_path), "--json"]) == 0
    log = tmp_path / "cart_r3_robust.mcap"
    _, recorded = stream_metrics(log)
    monkeypatch.setenv("FTSTAB_CACHE_DIR", str(tmp_path / "elsewhere"))
    monkeypatch.setattr(mt, "PROGRESS_AFTER", 0.0)
    cc.clear_memory()
    lines = []
    try:
        _, metrics = stream_metrics(log, lines.append)
    finally:
        cc.clear_memory()
    assert metrics == recorded and lines[-1] == "" and len(lines) >= 2
    assert lines[0].startswith("certificate of loop cart (r = 3, at most 2998 boxes per bound): c")


@pytest.mark.parametrize("r, k, gains", [(1, -0.3, (2.0,)), (2, -0.2, (1.0, 2.0)), (2, 0.0, (1.0, 2.0)),
                                          (3, -0.1, (1.0, 1.7, 5.0)), (3, -0.25, (1.0, 1.7, 5.0)),
                                          (4, -0.05, (0.82723, 1.5168, 3.1113, 100.0)),
                                          (5, -0.01, (0.65, 1.2, 1.62, 12.63, 1000.0))])
def test_the_v1_enclosure_of_many_states_at_once_is_each_state_s_alone_bit_for_bit(r, k, gains):
    """V1_enclosure is elementwise (a Monte Carlo encloses all its states in one call, each run's T(z0)
    then reads its row): over 150 states per r = 1..5 (zero components, magnitudes 1e-6..1e2, subnormal
    and huge ones), the enclosure of the whole array equals that of each state alone, both ends, bit for bit."""
    rng = np.random.default_rng(100 + r)
    z = rng.uniform(-1.0, 1.0, size=(150, r)) * 10.0 ** rng.uniform(-6, 2, (150, 1))
    z[:10, 1:] = 0.0
    z[10:20, 0] = 0.0
    z[20, :] = 0.0
    z[21, :] = 5e-324
    z[22, :] = -1e150
    E = V1_enclosure(r, k, gains, z)
    for j in range(len(z)):
        e = V1_enclosure(r, k, gains, z[j:j + 1])
        assert e.lo.tobytes() == E.lo[j:j + 1].tobytes() and e.hi.tobytes() == E.hi[j:j + 1].tobytes(), (j, z[j])
