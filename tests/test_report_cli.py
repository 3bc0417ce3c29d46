"""`ftstab report LOG.mcap --out FIG.png|.html` through the real command; what is drawn is checked
against the log's own arrays and the theorems' formulas (the Figure's lines, not its pixels)."""

import base64
import re

import numpy as np
import pytest

from conftest import ROOT, run_cli
from ftstab_mj.cli import main
from ftstab_mj.logs.reader import read_log
from ftstab_mj.metrics.run_metrics import loop_certificate
from ftstab_mj.figures.run_report import draw, report_data

PNG = b"\x89PNG\r\n\x1a\n"
JSON_LOG = ROOT / "tests" / "data" / "json_log_v0.1.mcap"  # a log of ftstab_mj 0.1 (JSON loop messages)


@pytest.fixture(scope="module")
def logs(tmp_path_factory):
    """Real runs: the robust cart long enough for T(z0) = 6.86 s, the adaptive cart, the two-joint arm."""
    out = tmp_path_factory.mktemp("runs")
    for name, duration in (("cart_r2_robust", 8), ("cart_r2_adaptive", 4), ("arm_robust", 0.3)):
        res = run_cli("run", name, "--out", out, "--set", f"sim.duration={duration}")
        assert res.returncode == 0, res.stderr
    return out


def drawn(fig):
    """{(column, ylabel): {label: (x, y)}} of every line drawn (axhline/axvline too), column 0, 1, ... per loop."""
    out = {}
    for ax in fig.axes:
        if not ax.get_visible():
            continue
        lines = {ln.get_label(): (np.asarray(ln.get_xdata(), float), np.asarray(ln.get_ydata(), float))
                 for ln in ax.get_lines()}
        out[(ax.get_subplotspec().colspan.start, ax.get_ylabel())] = lines
    return out


def panel(rep, loop, name):
    return next(p for p in rep.loops[loop] if p.name == name)


def curve(p, prefix):
    return next(c for c in p.curves if c.label.startswith(prefix))


def test_png_of_a_robust_run_draws_the_logs_samples_with_units(logs, tmp_path):
    log_path = logs / "cart_r2_robust.mcap"
    fig_path = tmp_path / "fig.png"
    res = run_cli("report", log_path, "--out", fig_path)
    assert res.returncode == 0, res.stderr
    assert fig_path.read_bytes()[:8] == PNG and fig_path.stat().st_size > 10_000
    assert "cart_r2_robust" in res.stdout and "robust law" in res.stdout
    log = read_log(log_path)
    a = log.loops["cart"]
    fig = draw(report_data(log))
    assert "cart_r2_robust: robust law" in fig.get_suptitle()
    lines = drawn(fig)
    assert set(ylabel for _, ylabel in lines) == {"z1 (m)", "z2 (m/s)", "u (m/s$^{2}$)", "V1 (chain units, log)"}
    for ylabel, label, expected in (("z1 (m)", "z1", a["z"][:, 0]), ("z2 (m/s)", "z2", a["z"][:, 1]),
                                    ("u (m/s$^{2}$)", "u", a["u"]), ("u (m/s$^{2}$)", "u0 (nominal)", a["u0"]),
                                    ("V1 (chain units, log)", "V1", a["V1"])):
        x, y = lines[(0, ylabel)][label]
        assert np.array_equal(x, a["t"]) and np.array_equal(y, expected), (ylabel, label)
    ax_v1 = next(ax for ax in fig.axes if ax.get_ylabel().startswith("V1"))
    assert ax_v1.get_yscale() == "log" and fig.axes[-1].get_xlabel() == "t (s)"


def test_the_envelope_is_theorem_1s_formula_and_t_z0_the_recorded_time_bound(logs):
    log = read_log(logs / "cart_r2_robust.mcap")
    (lp,) = log.info.loops
    cert = loop_certificate(lp)
    a, c = cert.alpha, cert.c_lower  # the guaranteed constant (c is c_lower)
    assert cert.certified and c == cert.c
    rep = report_data(log)
    v1 = panel(rep, "cart", "V1")
    env = curve(v1, "Theorem 1 envelope")
    assert "continuous-time guarantee" in env.label
    V1_0 = log.loops["cart"]["V1"][0]
    formula = np.maximum(V1_0 ** (1 - a) - c * (1 - a) * env.x, 0.0) ** (1 / (1 - a))
    T = V1_0 ** (1 - a) / (c * (1 - a))
    (t_mark,) = curve(v1, "T(z0)").x
    # the mark is the run's guaranteed T(z0): V1(z0) enclosed and rounded outward, so at or above the
    # float formula, by the enclosure's width (about 1e-11 relative; interval.py's power margins)
    assert t_mark == log.recorded["metrics"]["loops"]["cart"]["time_bound"]
    assert T <= t_mark <= T * (1 + 1e-10)
    # the curve is Theorem 1's envelope written from that guaranteed T, (c (1-a) (T - t))^(1/(1-a)),
    # rounded upward: to rounding that formula, never below it nor below the float formula from V1_0;
    # on the first half of [0, T] within 1/(1-a) = 9 times T's 1e-10 of the latter
    from_T = (c * (1 - a) * np.maximum(t_mark - env.x, 0.0)) ** (1 / (1 - a))
    np.testing.assert_allclose(env.y, from_T, rtol=1e-12, atol=0)
    assert np.all(env.y >= from_T) and np.all(env.y >= formula)
    first = env.x <= T / 2
    np.testing.assert_allclose(env.y[first], formula[first], rtol=1e-9, atol=0)
    assert 6 < T < 8 and env.x[0] == 0.0 and env.x[-1] == pytest.approx(T, rel=1e-12) and env.y[-1] == 0.0
    # Theorem 1 on the sampled run: V1 stays under the envelope while the envelope is above the
    # settle level (below it the sampled loop's O(h) band may cross it, and does, near T(z0))
    t, V1 = log.loops["cart"]["t"], log.loops["cart"]["V1"]
    bound = np.maximum(V1_0 ** (1 - a) - c * (1 - a) * t, 0.0) ** (1 / (1 - a))
    above = bound >= log.info.metric_settings.settle_level
    assert above.sum() > 3000 and np.all(V1[above] <= bound[above])
    (level,) = curve(v1, "settle level").y
    assert level == log.info.metric_settings.settle_level


def test_adaptive_run_draws_phi_hat_gamma_hat_and_theorem_3s_bounds(logs, tmp_path):
    log_path = logs / "cart_r2_adaptive.mcap"
    assert main(["report", str(log_path), "--out", str(tmp_path / "a.png")]) == 0
    assert (tmp_path / "a.png").read_bytes()[:8] == PNG
    log = read_log(log_path)
    th = log.recorded["metrics"]["loops"]["cart"]["theorem3"]
    rep = report_data(log)
    names = [p.name for p in rep.loops["cart"]]
    assert names == ["z1", "z2", "u", "V1", "phi_hat", "gamma_hat"]
    ph = panel(rep, "cart", "phi_hat")
    assert np.array_equal(curve(ph, "phi_hat").y, log.loops["cart"]["phi_hat"])
    assert curve(ph, "Theorem 3: limsup phi_hat").y[0] == th["phi_hat_limsup"]
    v1 = panel(rep, "cart", "V1")
    assert curve(v1, "Theorem 3: limsup V1 <= Delta").y[0] == th["Delta"]
    assert not any(c.label.startswith("Theorem 1") for c in v1.curves)  # no time bound for the adaptive law
    assert panel(rep, "cart", "gamma_hat").ylabel == "gamma_hat (dimensionless)"
    assert np.array_equal(panel(rep, "cart", "gamma_hat").curves[0].y, log.loops["cart"]["gamma_hat"])
    robust = report_data(read_log(logs / "cart_r2_robust.mcap"))
    assert "phi_hat" not in [p.name for p in robust.loops["cart"]]  # the robust law's are constants


def test_html_is_one_self_contained_page_and_the_arm_has_one_column_per_joint(logs, tmp_path):
    out = tmp_path / "arm.html"
    res = run_cli("report", logs / "arm_robust.mcap", "--out", out)
    assert res.returncode == 0, res.stderr
    text = out.read_text()
    assert not re.search(r"https?://|<script|<link|src=\"(?!data:)", text)  # nothing fetched from anywhere
    (b64,) = re.findall(r'src="data:image/png;base64,([A-Za-z0-9+/=]+)"', text)
    assert base64.b64decode(b64)[:8] == PNG
    assert "arm_robust: joint0: robust, joint1: robust" in text
    log = read_log(logs / "arm_robust.mcap")
    lines = drawn(draw(report_data(log)))
    for col, joint in enumerate(("joint0", "joint1")):
        a = log.loops[joint]
        for ylabel, label, expected in (("z1 (rad)", "z1", a["z"][:, 0]), ("z2 (rad/s)", "z2", a["z"][:, 1]),
                                        ("u (N m)", "u", a["u"]), ("V1 (chain units, log)", "V1", a["V1"])):
            x, y = lines[(col, ylabel)][label]
            assert np.array_equal(x, a["t"]) and np.array_equal(y, expected), (joint, ylabel)
    fig = draw(report_data(log))
    assert [ax.get_title() for ax in fig.axes if ax.get_title()] == ["loop joint0", "loop joint1"]


def test_an_old_json_log_is_drawn_from_its_samples(tmp_path):
    res = run_cli("report", JSON_LOG, "--out", tmp_path / "old.png")
    assert res.returncode == 0, res.stderr
    log = read_log(JSON_LOG)
    assert log.encoding == "json"
    rep = report_data(log)
    assert np.array_equal(panel(rep, "cart", "z1").curves[0].y, log.loops["cart"]["z"][:, 0])
    assert panel(rep, "cart", "z1").ylabel == "z1 (chain units)"  # its scenario names no plant


def test_bad_input_is_one_line_and_exit_2(logs, tmp_path, capsys):
    text = tmp_path / "notes.mcap"
    text.write_text("not a log\n")
    damaged = tmp_path / "damaged.mcap"
    data = bytearray((logs / "arm_robust.mcap").read_bytes())
    data[len(data) // 3] ^= 0x10  # inside the chunks (the summary is at the end)
    damaged.write_bytes(bytes(data))
    cases = [
        (tmp_path / "missing.mcap", "fig.png", "cannot read the log"),
        (text, "fig.png", "not an MCAP log"),
        (damaged, "fig.png", "damaged"),
        (logs / "arm_robust.mcap", "fig.jpg", "expected a file name ending in .png or .html, found '.jpg'"),
        (logs / "arm_robust.mcap", "fig", "found no extension"),
        (logs / "arm_robust.mcap", "no/such/dir/fig.png", "cannot write the figure"),
    ]
    for log, fig, message in cases:  # the command's main() in this process (a subprocess each costs ~1 s)
        assert main(["report", str(log), "--out", str(tmp_path / fig)]) == 2, (log, fig)
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and message in err, err
        assert not (tmp_path / fig).exists()
    res = run_cli("report", damaged, "--out", tmp_path / "fig.png")  # and once as a user runs it
    assert res.returncode == 2 and res.stderr.count("\n") == 1 and "Traceback" not in res.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["damaged.mcap", "notes.mcap"]  # no temp file left


def test_a_truncated_log_is_drawn_up_to_its_last_complete_chunk_and_an_empty_one_refused(logs, tmp_path, capsys):
    whole = (logs / "cart_r2_robust.mcap").read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(whole[:len(whole) // 2])  # a run killed half way
    assert main(["report", str(cut), "--out", str(tmp_path / "cut.png")]) == 0
    err = capsys.readouterr().err
    assert err.startswith("warning: ") and "truncated log" in err
    log, full = read_log(cut), read_log(logs / "cart_r2_robust.mcap")
    n = log.n_samples
    assert 0 < n < full.n_samples and not log.complete
    rep = report_data(log)
    assert rep.title.endswith("truncated log") and rep.notes == (log.warning,)
    z1 = panel(rep, "cart", "z1").curves[0]
    assert np.array_equal(z1.x, full.loops["cart"]["t"][:n]) and np.array_equal(z1.y, full.loops["cart"]["z"][:n, 0])
    cut.write_bytes(whole[:5000])  # the run's description, no sample yet
    assert main(["report", str(cut), "--out", str(tmp_path / "empty.png")]) == 2
    assert "the log has no samples" in capsys.readouterr().err and not (tmp_path / "empty.png").exists()
