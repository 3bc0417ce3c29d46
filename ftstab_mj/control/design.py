"""Gain design for Hong's controller: gains with a sound certificate (ftstab design).

The search runs on log-gains with a deterministic Nelder-Mead simplex over a cheap estimate of
the objective: at k = 0 the closed form of c (linear_c, exact); for k < 0 the float ratio
dV1/dt / V1^alpha at fixed states of the certificate's faces, improved by a short climb. That
estimate can only over-estimate c, and the simplex goes wherever it over-estimates most. For
r >= 5 and k < 0 the states that refute such gains have a nearly vanishing recursion variable
(|s_4| ~ 1e-3 of the largest at r = 5), a thin layer that uniform states miss and where the powers
|s_i|^(e_i - 1) of k < 0 differ most from the linear law; so half the states have log-uniform
moduli 1e-6..1 (face_points, the distribution of the certificate's witness search). For r = 3
and 4 (faces of dimension 2 and 3) a dense grid of the faces joins them (face_grid, GRID_N values
an axis, linear and log-spaced): random states leave most of a face far from any sample and the
search went there (r = 4, k = -0.15, gains up to 1000: estimate 0.258 where the certificate proved
c <= 0.0849; 0.0914 with the grid) and the designed c_lower rises 0.0847 -> 0.1256 (r = 4,
k = -0.1: 0.178 -> 0.248; twice the CPU time).
The estimate also takes the states of the zero sets z_i = 0 (certificate.zero_set_starts: where
the factor |z_i|^(beta - 1) of k < 0 vanishes and V1 can increase while it decreases everywhere
else); those are rebuilt for each gain set, since a fixed state leaves the set when the gains move.
When the certificate's witness search (no branch and bound) still refutes the gains a search ends
on, that state joins the fixed ones and the search goes on from there, up to REFUTE_ROUNDS times;
not after a search whose best estimate is c <= 0: the fixed states only grow, so their -max R only
falls (up to the short climb) and no later round can find an estimate above 0 (a refuted r = 4
range: 524 -> 104 s CPU).

The first search starts at the k = 0 optimum of the closed form (continuation from the linear
law: k < 0 perturbs it), moved, for k < 0, to the optimum of the limit of c as k -> 0-
(linear_limit.limit_c) where that limit is not positive at the linear optimum (r = 6: its zero
sets bind, and such gains have no certificate for k near 0); the others at geometric gain
sequences. Without u_max the last gain is
gain_max: V1 and the recursion variables s do not involve l_r, and dV1/dt = A(s) - l_r |s_r|^(1+e_r)
with A independent of l_r, so c (a minimum over states of affine functions of l_r, non-decreasing)
and T(z0) only improve with it. The candidates are the end of each search and the first search's
start (the search goes where the estimate over-estimates c most: at r = 6, k = -0.002 the limit
optimum's estimate is 0.209 while its certificate proves c <= 0.125). Each candidate's witness
search (certify without branch and bound, ~1 s at r = 6) gives a guaranteed c_upper; they are then
certified soundly (ftstab_mj.control.certificate.certify, at most max_boxes boxes: deterministic)
in the order of the best objective that c_upper allows, skipping each one that cannot beat the best
certified objective (a skipped candidate could not have won), and the best certified one by the
certified objective is returned; none certified: the first in that order with its "not certified"
/ "undecided" certificate, never a claim. When every candidate is refuted (a state with
dV1/dt >= 0 each: more boxes cannot help) and the range is the default one, the design is done
again in the range WIDEN_FACTOR times wider (c never decreases with l_r), at most WIDEN_STEPS times
and up to GAIN_CEILING. Objectives:

* ``max-c``: maximise c_lower (for a given k, c scales with the gains: multiplying every gain by
  the same factor is not a dilation, so the search is over the gain vector, bounded by
  ``gain_max``: l_1..l_{r-1}, or all r gains with u_max);
* ``min-time``: minimise Theorem 1's guaranteed time bound for given initial states z0^(j),
  T = max_j V1(z0^(j))^(1 - alpha) / (c_lower (1 - alpha)), alpha = (2 + 2k)/(2 + k) (k < 0: at
  k = 0 there is no finite time). V1 depends on the gains too, so this is not max-c: larger gains
  raise c and V1(z0) together. Its search starts from the max-c optimum of each start, and those
  optima stay candidates, so its certified T is never above that of the max-c gains.

Constraint ``u_max`` on a box region |z_i| <= R_i (either objective): |u0(z)| <= u_max on the box.
Exact test: u0 = v_r with v_0 = 0, v_i = -l_i sig(sig(z_i, b) - sig(v_{i-1}, b), e) (b, e > 0) is
non-increasing in every z_j (v_i decreases in z_i and increases in v_{i-1}; induction) and odd, so
its extremes on the box are at the vertices +-R: max |u0| = -u0(R_1, ..., R_r). At that vertex every
v_i < 0 and every argument sig(R_i, b) + |v_{i-1}|^b is a sum of positive terms: no cancellation,
so the float value is within a few ulps per operation (relative 1e-13 for r <= 6) of the exact one;
a candidate is feasible when the float value is <= u_max (1 - U_MARGIN). |u0| also increases with
every gain at that vertex, so the feasible gains are those below a boundary in log-gain space
(the searches start feasible by halving the start's gains).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from ftstab_mj.control.certificate import face_points
from ftstab_mj.control.linear_limit import limit_c, linear_c
from ftstab_mj.control.nelder_mead import nelder_mead

OBJECTIVES = ("max-c", "min-time")
REFUTE_ROUNDS = 8  # searches per start, each after adding the state where the last result failed
DESIGN_MAX_BOXES = 5_000_000  # branch-and-bound cap per candidate: deterministic, ~1 min of CPU at r = 5
# r = 6 at k < 0: the certificates of the limit optima took 15.1e6 and 18.3e6 boxes (k = -0.001,
# -0.002; ~20 CPU minutes each), so the r = 6 cap is the certificate's own default
DESIGN_MAX_BOXES_R6 = 20_000_000
U_MARGIN = 1e-12  # relative: covers the float error of u0 at the vertex (module docstring)
# the default range is widened tenfold, twice, while every candidate is refuted (c never decreases
# with l_r: module docstring): r = 4, k = -0.15 and r = 5, k = -0.05 are refuted with the default
# range and certified with the next one
WIDEN_FACTOR, WIDEN_STEPS = 10.0, 2
GAIN_CEILING = 1e6  # the largest gain a design widens to: the command line's limit (cli.GAIN_MAX)
# r = 3, 4 (faces of dimension 2, 3): the search's fixed states also include a dense grid of the
# faces (face_grid, module docstring); 2000 random states a face miss most of a 3-dimensional face
GRID_N = {3: 80, 4: 20}  # values an axis, by r (1e5, 2e5 states); r = 2: its 2000 random states a face are as good
PRUNE_MARGIN = 1e-9  # relative: covers the float rounding of a skipped candidate's least possible T(z0)


def _estimate_c(r, k, gains, pts, rng):
    """-max over the fixed states pts (n, r) (recursion variables s on the faces) of the float
    ratio, improved by a short climb: an estimate of c from above (cheap; the final candidate is
    certified soundly). At k = 0 the closed form linear_c."""
    from ftstab_mj.control.certificate import climb, Ratio, zero_set_starts
    from ftstab_mj.control.hong_terms import Terms

    if k == 0:
        return linear_c(gains)
    obj = Ratio(Terms(r, k, gains), "c")
    pts = np.concatenate([pts, *zero_set_starts(obj).values()])  # they move with the gains
    f = obj.floats(pts)
    top = pts[np.argsort(f)[-8:]]
    z = climb(obj, top, rng, rounds=20)
    return -float(max(np.max(f), np.max(obj.floats(z))))


def face_grid(r: int, n: int) -> np.ndarray:
    """States on the r faces s_j = 1 of the cube (m, r): the free coordinates on the product of one
    axis, n values uniform in [-1, 1] with 0 and n // 2 log-uniform moduli 1e-6..1 of each sign (the
    thin layers where a recursion variable nearly vanishes, see face_points). Deterministic."""
    mod = 10.0 ** np.linspace(-6.0, 0.0, n // 2)
    axis = np.unique(np.concatenate([np.linspace(-1.0, 1.0, n), mod, -mod, [0.0]]))
    mesh = np.stack(np.meshgrid(*[axis] * (r - 1), indexing="ij"), axis=-1).reshape(-1, r - 1)
    return np.concatenate([np.insert(mesh, face, 1.0, axis=1) for face in range(r)])


def _floor5(g: float) -> float:
    """g rounded down to 5 significant digits (a printable gain; never above g, so |u0| at the
    region's vertex, which grows with every gain, stays within u_max)."""
    e = math.floor(math.log10(g)) - 4
    n = math.floor(g / 10.0 ** e)
    while float(f"{n}e{e}") > g:
        n -= 1
    return float(f"{n}e{e}")


def vertex_u0(r, k, gains, region) -> float:
    """max |u0| over the box |z_i| <= region[i]: -u0 at the vertex (region_1..region_r) (module docstring)."""
    from ftstab_mj.control.hong import HongController

    return -float(HongController(r, k, gains, check_hurwitz=False).u0(np.asarray(region, dtype=float)))


def time_bound(cert, r, k, gains, z0) -> float:
    """Theorem 1's guaranteed bound max_j T(z0[j]) (s) for the certificate ``cert`` of (r, k, gains);
    z0 (m, r). The number a run of these gains reports (metrics.time_bound): V1(z0) enclosed
    (certificate.V1_enclosure) and every step rounded outward (Certificate.time_bound). Infinite
    when not certified or k = 0."""
    from ftstab_mj.control.certificate import V1_enclosure

    return float(np.max(cert.time_bound(V1_enclosure(r, k, gains, z0))))


@dataclass(frozen=True)
class Design:
    """What ``design`` found. gains (r,) or None (no Hurwitz / feasible start); certificate of the
    gains (None when there are no gains); time_bound: the guaranteed max_j T(z0[j]) (s) for
    min-time (None otherwise); u0_max: max |u0| on the region (None without u_max)."""

    gains: tuple | None
    certificate: object
    time_bound: float | None = None
    u0_max: float | None = None
    gain_max: float | None = None  # the upper end of the range searched (after any widening)
    refuted_gain_max: tuple = ()  # the upper ends of narrower ranges where every candidate was refuted

    @property
    def certified(self) -> bool:
        return self.certificate is not None and self.certificate.certified


def default_gain_max(r: int) -> float:
    """The default largest gain for chains of length r: 100 up to r = 4, 1000 for r = 5, 1e6 for r = 6.
    Longer chains need a larger last gain: the best c over [0.1, 100]^r of the linear law (k = 0,
    closed form) is 0.31 at r = 5 and negative (-0.23) at r = 6, so no gain set in that box has a
    certificate at k = 0; with 1000 and 1e5 it is 0.56 and 0.18. At r = 6 with k < 0 the limit of c
    as k -> 0- (linear_limit.limit_c) is what binds: its best value is 0.021 with gains up to 1e5
    and 0.125 up to 1e6 (the largest gain the command line takes)."""
    return 100.0 if r <= 4 else 1000.0 if r == 5 else 1e6


def design(r: int, k: float, objective: str = "max-c", z0=None, u_max: float | None = None, region=None,
           gain_min=0.1, gain_max=None, widen=None, starts=3, iters=150, budget=None, seed=0, max_boxes=None,
           progress=None, prune=True) -> Design:
    """Gains l_1..l_r in [gain_min, gain_max]^r for ``objective`` (module docstring) with a sound
    certificate.

    z0: (m, r) initial states (min-time only); u_max, region (r,): |u0| <= u_max on |z_i| <= region[i]
    (both or neither). Returns the best certified candidate by the certified objective, else the
    first candidate in the order of its guaranteed c_upper with its (not certified / undecided)
    certificate. Deterministic for a given seed on one machine: no step depends on time (the
    candidates' certificates have no time budget unless ``budget``, CPU s per candidate; max_boxes
    caps each one's branch and bound, default DESIGN_MAX_BOXES, DESIGN_MAX_BOXES_R6 for r = 6), but
    another NumPy power (SIMD or not) moves the float search, which can then end at other gains,
    each certified by its own certificate. gain_max None: default_gain_max(r).
    widen: how many times the range may grow WIDEN_FACTOR-fold (never above GAIN_CEILING) while
    every candidate is refuted; None: WIDEN_STEPS with the default range, 0 with a given gain_max
    (a range the caller chose is kept). A widened design is the design of the wider range
    (Design.gain_max; Design.refuted_gain_max lists the upper ends that were refuted).
    progress(text), if given, is told what is being done. prune: skip the
    candidates whose guaranteed c_upper cannot beat the best certified objective (False: certify
    every candidate; the same answer, slower).
    """
    if objective not in OBJECTIVES:
        raise ValueError(f"objective: expected one of {', '.join(OBJECTIVES)}, got {objective!r}")
    if (u_max is None) != (region is None):
        raise ValueError("u_max and region: both or neither")
    if objective == "min-time":
        z0 = np.atleast_2d(np.asarray(z0, dtype=float))
        if k >= 0 or z0.shape[-1] != r:
            raise ValueError("min-time needs k < 0 and initial states z0 of shape (m, r)")
    if widen is None:
        widen = WIDEN_STEPS if gain_max is None else 0
    gain_max = default_gain_max(r) if gain_max is None else float(gain_max)
    say = progress or (lambda text: None)
    tops = gain_ranges(gain_max, widen)
    for n, top in enumerate(tops):
        if n:
            say(f"every candidate with gains up to {tops[n - 1]:g} refuted; searching up to {top:g} ...")
        found, all_refuted = _design_in_range(r, k, objective, z0, u_max, region, gain_min, top, starts,
                                              iters, budget, seed, max_boxes, say, prune)
        if not all_refuted:  # certified, undecided (more boxes might decide) or no candidate at all
            break
    return replace(found, gain_max=top, refuted_gain_max=tops[:n])


def gain_ranges(gain_max: float, widen: int) -> tuple:
    """The upper ends of the gain ranges a design tries in turn while every candidate is refuted:
    gain_max, then WIDEN_FACTOR times the previous one, ``widen`` times at most, never above
    GAIN_CEILING (a gain_max already there is not widened)."""
    tops = [float(gain_max)]
    while len(tops) <= widen and tops[-1] < GAIN_CEILING:
        tops.append(min(tops[-1] * WIDEN_FACTOR, GAIN_CEILING))
    return tuple(tops)


def _design_in_range(r, k, objective, z0, u_max, region, gain_min, gain_max, starts, iters, budget, seed,
                     max_boxes, say, prune) -> tuple:
    """(design() in the one range [gain_min, gain_max], whether every candidate was refuted: a state
    with dV1/dt >= 0 each); arguments checked by design."""
    from ftstab_mj.control.certificate import V1_enclosure, certify
    from ftstab_mj.control.hong import HongController, is_hurwitz
    from ftstab_mj.control.hong_terms import Terms

    if max_boxes is None:
        max_boxes = DESIGN_MAX_BOXES_R6 if r >= 6 else DESIGN_MAX_BOXES
    rng = np.random.default_rng(seed)
    pts = face_points(r, 2000, rng)
    if r in GRID_N:
        pts = np.concatenate([pts, face_grid(r, GRID_N[r])])
    lo, hi = np.log(gain_min), np.log(gain_max)
    alpha = (2.0 + 2.0 * k) / (2.0 + k)
    # without u_max, l_r = gain_max: V1 and the recursion variables do not involve l_r and
    # dV1/dt = A(s) - l_r |s_r|^(1 + e_r), so c and T(z0) only improve with l_r (module docstring)
    free = r if u_max is not None else r - 1

    def gains_of(x):
        g = tuple(float(v) for v in np.exp(np.clip(x, lo, hi)))
        return g if free == r else g + (float(gain_max),)

    def feasible(g):
        return is_hurwitz(g) and (u_max is None or vertex_u0(r, k, g, region) <= u_max * (1.0 - U_MARGIN))

    def c_est(g):
        with np.errstate(all="ignore"):
            c = _estimate_c(r, k, g, pts, np.random.default_rng(seed))
        return c if np.isfinite(c) else -np.inf

    def cost_max_c(x):
        g = gains_of(x)
        return -c_est(g) if feasible(g) else np.inf

    def cost_min_time(x):
        """The search's estimate of log T(z0): floats (estimated c, float V1), a heuristic that only
        steers the search; the candidates are ranked by their guaranteed time_bound below."""
        g = gains_of(x)
        if not feasible(g):
            return np.inf
        c = c_est(g)
        if not c > 0:  # no bound: worse than any bound, still steering towards c > 0
            return 1e6 - c if np.isfinite(c) else np.inf
        V0 = np.max(HongController(r, k, g, check_hurwitz=False).V1(z0))
        return float(np.log(V0 ** (1.0 - alpha) / (c * (1.0 - alpha))))

    def feasible_start(x0):
        """x0 with every gain halved until feasible (|u0| at the vertex grows with every gain)."""
        x = np.clip(x0, lo, hi)
        while not feasible(gains_of(x)):
            if np.all(x <= lo):
                return None
            x = np.maximum(x - np.log(2.0), lo)
        return x

    def geometric(ratio):  # each gain `ratio` times the previous one
        return (np.log(ratio) * np.arange(r) - np.log(ratio) * (r - 1) / 3.0)[:free]

    def linear_cost(x):
        g = gains_of(x)
        return -linear_c(g) if feasible(g) else np.inf

    def limit_cost(x):
        g = gains_of(x)
        return -limit_c(g).c if feasible(g) else np.inf

    # starts: the k = 0 optimum of the closed form (exact and cheap: the continuation from k = 0,
    # where k < 0 is a perturbation of the linear law) or of its k -> 0- limit, then `starts`
    # geometric gain sequences
    x_lin = feasible_start(geometric(2.0))
    if x_lin is not None and free:
        for _ in range(3):  # restarts: the simplex collapses on the ridges of c
            x_lin, _ = nelder_mead(linear_cost, x_lin, step=0.3, iters=1000, tol=1e-12)
        # k < 0 and the limit k -> 0- of c not positive there (its zero sets bind: r = 6): those gains
        # have no certificate for k near 0, so the limit's optimum instead (at r = 5 the linear one
        # is better: k = -0.02, first search certified with c_lower 0.2916 against 0.1789)
        if k < 0 and limit_c(gains_of(x_lin)).c <= 0.0:
            for _ in range(3):
                x_lin, _ = nelder_mead(limit_cost, x_lin, step=0.3, iters=1000, tol=1e-12)
    inits = [(x_lin, 0.3)] + [(feasible_start(geometric(2.0 + 2.0 * s)), 0.7) for s in range(starts)]
    found = []  # (estimated cost, gains)
    cost = cost_min_time if objective == "min-time" else cost_max_c
    if x_lin is not None:  # the start itself: the estimate over-estimates c, and most where the search
        found.append((cost(x_lin), tuple(_floor5(v) for v in gains_of(x_lin))))  # goes (r = 6: 0.209 vs c <= 0.125)
    for n, (x0, step) in enumerate(inits):
        if x0 is None:
            continue
        say(f"search {n + 1} of {len(inits)} ...")
        x, fx = x0, cost_max_c(x0)
        for _ in range(REFUTE_ROUNDS if free else 0):  # search, then add the state that refutes the result (if any) and again
            x, fx = nelder_mead(cost_max_c, x, step=step, iters=iters)
            g = gains_of(x)
            # fx >= 0: the best estimate is c <= 0. Another round only adds states, which lowers the
            # estimate -max R at every gain set, so no later round can reach a positive one: stop
            if not np.isfinite(fx) or fx >= 0.0 or not is_hurwitz(g):
                break
            # the witness search only: a box cap, not a CPU budget (0.01 s once), so that where the B&B
            # stops, hence the witness, does not depend on the machine's speed (design is deterministic)
            quick = certify(HongController(r, k, g), max_boxes=1)
            if quick.status != "not certified":
                break
            z = np.array([quick.witness])
            pts = np.concatenate([pts, Terms(r, k, g).s_of(z)])
        if objective == "min-time" and free:  # from the max-c optimum, which stays a candidate: the estimate of T
            found.append((cost_min_time(x), tuple(_floor5(v) for v in gains_of(x))))  # can mislead the search
            x, fx = nelder_mead(cost_min_time, x, step=step, iters=iters)
        elif objective == "min-time":
            fx = cost_min_time(x)
        found.append((fx, tuple(_floor5(v) for v in gains_of(x))))
    estimate = {}  # each gain set once (searches often end on the same rounded gains), its best estimate
    for fx, g in found:
        estimate[g] = min(fx, estimate.get(g, np.inf))
    found = sorted((fx, g) for g, fx in estimate.items())  # the best estimate first
    found = [g for fx, g in found if np.isfinite(fx) and feasible(g)]
    # the witness search of each candidate (no branch and bound, ~1 s at r = 6): a guaranteed c_upper,
    # and the whole answer where it refutes. The candidates are then certified in the order of their
    # best possible objective (c_upper, or T from it), and one that cannot beat the best certified
    # objective is skipped: that changes what costs time, never what is claimed
    quick = {g: certify(HongController(r, k, g), max_boxes=1) for g in found}

    def hope(g):
        """The best objective the candidate's certificate could reach (c_lower <= c_upper)."""
        c = quick[g].c_upper
        if objective == "max-c":
            return -c
        if not c > 0:
            return np.inf
        V0 = float(np.max(V1_enclosure(r, k, g, z0).lo))  # T grows with V1(z0): its lower end
        return V0 ** (1.0 - alpha) / (c * (1.0 - alpha)) * (1.0 - PRUNE_MARGIN)

    hopes = {g: hope(g) for g in found}
    best, fallback, statuses = None, None, []  # statuses: of the candidates certified or refuted (not skipped)
    for g in sorted(found, key=hopes.get):
        cert, shown = quick[g], ", ".join(f"{v:g}" for v in g)
        if cert.status != "not certified":  # refuted by the witness search alone: that is its certificate
            if best is not None and prune and hopes[g] >= best[0]:
                say(f"skipping gains {shown}: c <= {cert.c_upper:.6g} cannot beat the best")
                continue
            say(f"certifying gains {shown} ...")
            cert = certify(HongController(r, k, g), budget=budget, max_boxes=max_boxes)
            say(f"gains {shown}: {cert.status}, c in [{cert.c_lower:.6g}, {cert.c_upper:.6g}] "
                f"({cert.boxes} boxes, {cert.seconds:.0f} s)")
        statuses.append(cert.status)
        d = Design(g, cert, time_bound(cert, r, k, g, z0) if objective == "min-time" else None,
                   vertex_u0(r, k, g, region) if u_max is not None else None)
        score = d.time_bound if objective == "min-time" else -cert.c_lower
        if cert.certified and (best is None or score < best[0]):
            best = (score, d)
        if fallback is None and not cert.certified:
            fallback = d
    refuted = bool(statuses) and all(st == "not certified" for st in statuses)
    if best is not None:
        return best[1], refuted
    if fallback is not None:
        return fallback, refuted
    return Design(None, None), refuted
