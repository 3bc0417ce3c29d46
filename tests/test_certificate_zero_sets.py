"""Where V1 stops decreasing for k < 0: on the zero sets of the recursion's small-exponent factors.

For k < 0 the factor beta |z_i|^(beta - 1) of dS_i/dt (beta = beta_{i-1} > 1, beta - 1 ~ -k) is 0 at
z_i = 0 and close to 1 as soon as |z_i| > 1e-30 or so (|1e-100|^0.002 = 0.63): on the hypersurface
z_i = 0 (and within ~1e-50 of it) dV1/dt is that of a different law, the one with the term
beta z_{i+1} missing. A gain set can have dV1/dt < 0 on the rest of {V1 = 1} and > 0 there, in a
layer no uniform or log-uniform sample reaches. The r = 6, k = -0.002 gains 0.62, 1.15, 1.54, 3.88,
39.13, 1e5 (the certificate table's "6 decades" row, whose witness search reported c <= 0.069) are
such a set: the branch and bound's bound stalled near 0.264 on boxes around z_4 = 0, the true
maximum of dV1/dt / V1^alpha there, so no certificate of them can exist and "undecided" was the
only honest answer its budget allowed."""

import numpy as np

from ftstab_mj.control import HongController, certify
from ftstab_mj.control.hong_terms import Terms

R6, K6, GAINS6 = 6, -0.002, (0.62, 1.15, 1.54, 3.88, 39.13, 1e5)
# on the face s_2 = 1 with y_4 = s_4 + S_3 = 0 exactly, from the box the bound stalled on
Z_ON_ZERO_SET = (0.9099845604021, 0.43707414113409343, -1.435437303845193, 0.0, 1.6521858789308743, 3.5837913000073534)


def _ratio(h, z):
    """dV1/dt / V1^alpha at float states z (n, r), from the controller's own Lie derivative."""
    alpha = (2 + 2 * h.k) / (2 + h.k)
    return h.closed_loop_dV1dt(z) / h.V1(z) ** alpha


def test_r6_gains_increase_V1_on_z4_zero_so_they_have_no_certificate():
    """At the state with z_4 = 0, and at z_4 = +-1e-100 and +-1e-60 (representable states, the factor
    |z_4|^(beta_3 - 1) there 0.63 and 0.76), dV1/dt / V1^alpha is 0.263, 0.191 and 0.080 by the
    controller's Lie derivative (asserted > 0.05, far above its float error: < 1e-9 here), and the certificate's own formula (Terms.evaluate in the recursion variables) agrees
    to 1e-9 at z_4 = 0; at z_4 = 1e-10 it is back below -0.3 (the layer is that thin). So c < 0 for
    these gains: certify, with any budget, must not answer "certified"."""
    h = HongController(R6, K6, GAINS6, check_hurwitz=False)
    z = np.tile(np.array(Z_ON_ZERO_SET), (5, 1))
    z[1:, 3] = [1e-100, -1e-100, 1e-60, -1e-60]
    R = _ratio(h, z)
    assert np.all(R > 0.05), R
    t = Terms(R6, K6, GAINS6)
    s = t.s_of(z[:1])
    V, dV, _, _ = t.evaluate([s[:, i] for i in range(R6)])
    assert abs(float(dV[0] / V[0] ** t.alpha.mid) - R[0]) <= 1e-9, (dV, V, R[0])
    off = z[:1].copy()
    off[0, 3] = 1e-10
    assert _ratio(h, off)[0] < -0.3
    cert = certify(h, budget=2.0)
    assert cert.status != "certified" and not cert.c_lower > 0, cert.status


def test_certified_gains_keep_V1_decreasing_on_the_zero_sets():
    """The zero sets y_i = 0 (z_i = 0) and s_i = 0 of every level, sampled on the faces of {max |s_i| = 1}
    (20,000 states each): for shipped certified gains (r = 3 NOTES, r = 4 and r = 5 designed) no state
    has dV1/dt / V1^alpha above -c_lower, c_lower the certificate's (measured maxima -1.17, -0.72,
    -0.34 against -0.573, -0.663, -0.267)."""
    from ftstab_mj.control.certificate import face_points

    rng = np.random.default_rng(0)
    for r, k, gains, c_lower in ((3, -0.1, (1.0, 1.7, 5.0), 0.573132), (4, -0.05, (0.83467, 1.4216, 2.8157, 100.0), 0.663414),
                                 (5, -0.02, (0.78947, 1.185, 1.8612, 7.6323, 1000.0), 0.26727)):
        t = Terms(r, k, gains)
        s = face_points(r, 20000 // r, rng)
        worst = -np.inf
        for i in range(2, r + 1):
            for zero_y in (True, False):
                s2 = s.copy()
                s2[:, i - 1] = -t.z_of([s2[:, j] for j in range(r)])[2][i - 1] if zero_y else 0.0
                ok = np.isclose(np.max(np.abs(s2), axis=1), 1.0) & (np.max(np.abs(s2), axis=1) <= 1.0)
                V, dV, _, _ = t.evaluate([s2[ok, j] for j in range(r)])
                worst = max(worst, float(np.nanmax(dV / V ** t.alpha.mid)))
        assert worst < -c_lower, (r, k, worst, c_lower)


def test_certify_refutes_those_gains_on_the_zero_set_with_a_guaranteed_witness():
    """certify looks at the zero sets z_i = 0 (i = 2..r-1) before its branch and bound, and a state
    there with a guaranteed dV1/dt >= 0 refutes the gains at once: the r = 6 row is "not certified"
    (it was undecided after any budget), c_upper <= -0.2 (measured -0.259), with a witness on
    {V1 = 1} that has one z_i exactly 0 and where the controller's own Lie derivative is > 0.2 too.
    The k = -0.005 and -0.01 gains of the designer's first searches are refuted the same way
    (measured c_upper -0.246 and -0.075 .. -0.181 over seeds)."""
    h = HongController(R6, K6, GAINS6, check_hurwitz=False)
    cert = certify(h, budget=20.0)
    assert cert.status == "not certified" and cert.c_upper <= -0.2, (cert.status, cert.c_upper)
    w = np.array([cert.witness])
    assert (w[0, 1:-1] == 0.0).any() and abs(h.V1(w)[0] - 1.0) < 1e-9, cert.witness
    assert _ratio(h, w)[0] > 0.2
    assert cert.boxes <= 100  # refuted before the branch and bound splits anything


def test_the_zero_sets_leave_gains_whose_sampled_witness_is_better_as_they_were(monkeypatch):
    """Where the zero sets' best state is below the sampled witness (r = 3 NOTES gains, r = 4
    designed), certify's answer (status, c_lower, c_upper, boxes, witness) is the same with the
    zero sets searched or not: they only act where their value is the higher one."""
    import ftstab_mj.control.certificate as cm

    for r, k, gains in ((3, -0.1, (1.0, 1.7, 5.0)), (4, -0.05, (0.83467, 1.4216, 2.8157, 100.0))):
        h = HongController(r, k, gains)
        a = certify(h)
        with monkeypatch.context() as m:
            m.setattr(cm, "_zero_set_witness", lambda *args: None)
            b = certify(h)
        assert (a.status, a.c_lower, a.c_upper, a.boxes, a.witness) == (b.status, b.c_lower, b.c_upper, b.boxes, b.witness)


def test_the_branch_and_bound_stops_at_the_zero_set_witness_value(monkeypatch):
    """r = 4, k = -0.005, gains 1.009, 1.651, 3.699, 56.113 (limit_c 0.611 on z_3 = 0 against
    linear_c 0.947: the zero set binds). The largest dV1/dt / V1^alpha is on z_3 = 0, in a layer no
    sampled state reaches, so the B&B's own witness stays below it and, with that as the threshold
    for retiring boxes, the B&B splits the boxes around z_3 = 0 until its cap (measured: 3e6 boxes,
    cap reached). With the zero set's guaranteed value as its witness it stops when the bracket is
    within rtol (measured 18,928 boxes): so here within 200,000 boxes, the bracket within rtol, the
    witness on z_3 = 0, and without the zero sets the cap is reached with a wider bracket."""
    import ftstab_mj.control.certificate as cm

    h = HongController(4, -0.005, (1.009, 1.651, 3.699, 56.113))
    cap = 200_000
    cert = certify(h, max_boxes=cap)
    assert cert.certified and cert.boxes < cap // 2, cert.boxes  # c' included: it converges too
    assert cert.gap <= cm.DEFAULT_RTOL * (1 + 1e-9), cert.gap
    assert cert.witness[2] == 0.0 and abs(h.V1(np.array([cert.witness]))[0] - 1.0) < 1e-9, cert.witness
    with monkeypatch.context() as m:
        m.setattr(cm, "_zero_set_witness", lambda *args: None)
        blind = certify(h, max_boxes=cap)
    assert blind.boxes > cap and blind.c_upper > cert.c_upper * (1 + 10 * cm.DEFAULT_RTOL), (blind.boxes, blind.c_upper)
    assert blind.c_lower <= cert.c_upper  # both brackets hold c
