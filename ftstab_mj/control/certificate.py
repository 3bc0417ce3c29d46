"""The Lyapunov certificate of Theorem 1 and the bounds of Theorem 3 (the paper's Theorems 1 and 3; formulas in this module).

Full form. V1 is homogeneous of degree 2 + k and dV1/dt of degree 2 + 2k for the dilation
z_i -> lam^p_i z_i, so R(z) = (dV1/dt) / V1^alpha, alpha = (2 + 2k)/(2 + k), has degree 0 and
c = -max R over any set that meets every dilation orbit once. The homogeneous unit sphere
{max_i |z_i|^(1/p_i) = 1} is such a set, and it is the surface of the cube [-1, 1]^r: r pairs of
faces {z_j = +-1}, each a box of dimension r - 1, and V1, dV1/dt are even in z, so the r faces
z_j = +1 suffice. A branch and bound over boxes of those faces (ftstab_mj.control.interval:
outward-rounded intervals, the mean-value form on small boxes) encloses max R:

    c_lower = -(an upper bound of R over every box not yet discarded)   (guaranteed: c >= c_lower)
    c_upper = -(a guaranteed lower bound of R at the witness state)     (c <= c_upper)

and likewise c' = max |dV1/dz_r| / V1^alpha' from above (c_prime_upper, guaranteed).
``status``: "certified" when c_lower > 0, "not certified" when c_upper <= 0 (the witness is a state
with dV1/dt >= 0), "undecided" when the budget ran out first. The B&B stops when the gap
c_upper - c_lower is within ``rtol`` of c_upper (then the result is deterministic) or at the
budget (then it depends on the machine's speed).

Simplified form: its companion V1 = sum (z_j - v_{j-1})^2 / 2 is not homogeneous, so no global
constant exists; ``check_region`` proves dV1/dt < 0 on a shell r_in <= |z|_inf <= r_out, or finds a
state where it fails.
"""

from __future__ import annotations

import functools
import time
from dataclasses import asdict, dataclass, field
from fractions import Fraction
from typing import NamedTuple

import numpy as np

from ftstab_mj.control.hong import HongController
from ftstab_mj.control.hong_terms import SLOTS, SimplifiedTerms, Terms, exact_power, exp_of
from ftstab_mj.control.nelder_mead import nelder_mead
from ftstab_mj.control.interval import Dual, Exp, Iv, round_down, round_up, affine_remainder, secant_slope
from ftstab_mj.config.errors import ParameterError

DEFAULT_SAMPLES = 20_000  # witness search: states sampled on the faces before the B&B
DEFAULT_SEED = 0
DEFAULT_RTOL = 2e-3  # relative gap c_upper - c_lower at which the B&B stops
MAX_SAMPLES = 10_000_000
DEFAULT_MAX_BOXES = 20_000_000  # work cap of one B&B (deterministic, unlike a time budget): ~2-3 min
# memory cap of the B&B, ~100 bytes a box at r = 6: peak RSS 0.93 GB for the r = 6, k = -0.002 designed
# gains (20e6 boxes). At 2e6 phase 1 retired parked boxes there, and their bound held c_lower at 0.038
# (c_upper 0.126); at 8e6 it retires none and the gap phase reaches 0.108 in the same boxes
MAX_LIVE_BOXES = 8_000_000
# boxes split per round: their children are evaluated together and NumPy's overhead is per round
# (r = 5, k = -0.01: 22 % more boxes a CPU second than at 8192; small problems never reach it)
SPLIT_BATCH = 32768
# rounds of at most MERGE_FACES (r - 2) boxes (at least MERGE_FACES) are evaluated in one call for
# every face (Ratio.boxes with an array of faces), larger ones face by face: a call costs ~15 ms
# (r = 3) to ~100 ms (r = 6) of NumPy overhead whatever its size, and one over several faces costs
# more per box (every coordinate a variable). Measured, one call against one a face on random boxes
# of all faces (CPU, median of 3): r = 3 0.47x at 512 boxes, 0.69x at 4096, 1.39x at 16384; r = 4
# 0.32x, 0.58x at 4096, 0.75x at 8192, 1.18x at 16384; r = 5, 6 0.65x, 0.50x at 8192, 0.89x at 32768
MERGE_FACES = 4096
CERTIFIED, NOT_CERTIFIED, UNDECIDED = "certified", "not certified", "undecided"
# factors of Terms.evaluate (slot % SLOTS) that dV1/dt is affine in: |y_i|^(1 - 1/beta_{i-1}) and
# |s_i|^(q_i - 1), which enter only dS_i/dt (step 5 of Ratio.boxes)
AFFINE_SLOTS = (0, 1)
# held only for exponents this small (k ~ -0.002 .. -0.005): |x|^e on a box of width w that holds 0
# ranges over [0, w^e], still [0, 0.93] at w = 1e-6 for e = 0.005, so bisection never narrows it; a
# larger e shrinks with the box, and holding costs more than it saves (measured: r = 3, k = -0.1,
# +20 % CPU for 1.5 % fewer boxes; r = 5, k = -0.01 and -0.02, half the boxes in 30 s, same c_lower)
HELD_EXPONENT = 0.005
# step 6 of Ratio.boxes: the factors whose argument is a box coordinate s_i, sig(s_i, e_i) (in v_i) and
# sig(s_i, q_i) (in S_i), whose remainders are bounded together with s_i
PAIRED_SLOTS = (2, 5)
PAIR_SHARE = 0.1  # paired only where the remainder's term is at least this share of the form's terms
# and only for k this close to 0 (r = 6, k ~ -0.002 .. -0.005, where it was measured to tighten the
# bound; at r = 4 and 5, k = -0.02 it cost 10-15 % CPU per box for the same boxes and c_lower)
PAIR_K = 0.005
# the gradient seed of a variable on the boxes where it is none (a coordinate on its own face, a
# remainder where its factor is not split): every use of such a component is masked there, so any
# value gives the same bounds (a test sets it to NaN and inf)
ABSENT_SEED = 0.0
HELD_SHARE = 0.5  # held only where their mean-value terms are at least this share of the excess
MAX_HELD = 2  # of those, held at the ends of their ranges on one box: 2^MAX_HELD evaluations of it


@dataclass(frozen=True)
class Certificate:
    """Constants of dV1/dt <= -c V1^alpha and |dV1/dz_r| <= c' V1^alpha' (full form).

    c is the guaranteed lower bound c_lower; c_prime the guaranteed upper bound c_prime_upper.
    witness: a state on {V1 = 1} where dV1/dt / V1^alpha >= -c_upper (floats, r values).
    For the simplified form c and alpha are None; the region_* fields report check_region.
    """

    form: str
    c: float | None
    alpha: float | None
    c_prime: float | None
    alpha_prime: float | None
    certified: bool  # status == "certified"
    samples: int
    seed: int
    status: str = UNDECIDED
    c_lower: float | None = None
    c_upper: float | None = None
    c_prime_upper: float | None = None
    c_prime_lower: float | None = None
    witness: tuple | None = None
    boxes: int = 0  # boxes the B&B evaluated
    seconds: float = field(default=0.0, compare=False)  # CPU time of the computation (not part of the result)
    region_radius: float | None = None  # simplified form: outer |z|_inf of the shell checked
    region_inner: float | None = None  # simplified form: inner |z|_inf of the shell
    region_max_dV1dt: float | None = None  # simplified form: guaranteed upper bound of dV1/dt there
    region_negative: bool | None = None  # simplified form: True proven < 0, False a witness >= 0, None undecided
    note: str = ""
    k: float | None = None  # the controller's homogeneity degree (full form): time_bound encloses alpha from it

    def to_dict(self) -> dict:
        d = asdict(self)
        d["witness"] = None if self.witness is None else list(self.witness)
        return d

    @property
    def gap(self) -> float | None:
        """(c_upper - c_lower) / |c_upper|: how far the two bounds are apart (relative)."""
        if self.c_lower is None or self.c_upper is None or self.c_upper == 0:
            return None
        return (self.c_upper - self.c_lower) / abs(self.c_upper)

    def time_bound(self, V1_0):
        """Theorem 1's bound on the convergence time from a state with V1 = V1_0: V1_0^(1-a)/(c(1-a)).

        A guaranteed upper bound for the exact V1_0 (a float or an array of them; an ``Iv`` enclosure
        of V1 gives the bound for every value in it): 1 - alpha = -k / (2 + k) is enclosed from the
        exact rational k, and the power, product and quotient are rounded outward (interval.Iv), with
        c = c_lower. Infinite when the certificate does not hold, and at k = 0 (alpha = 1: the linear
        law converges exponentially, not in finite time).
        """
        if not self.certified or self.alpha >= 1.0:
            return np.full(np.shape(_hi(V1_0)), np.inf) if np.ndim(_hi(V1_0)) else float("inf")
        V = V1_0 if isinstance(V1_0, Iv) else Iv(np.asarray(V1_0, dtype=float))
        T = self._time_to_zero(V).hi
        return T if np.ndim(T) else float(T)

    def V1_bound(self, T: float, t):
        """Theorem 1's envelope as guaranteed upper bounds of V1 at the times t (array, s) of a
        trajectory whose guaranteed T(z0) is T (>= the exact V1_0^(1-a)/(c(1-a))): with V1_0^(1-a) =
        c (1-a) T_exact <= c (1-a) T, V1(t) <= (V1_0^(1-a) - c (1-a) t)^(1/(1-a)) <= (c (1-a) (T - t))^(1/(1-a)),
        rounded outward (1 - a and 1/(1 - a) enclosed from the exact rational k, c = c_lower), 0 from T on.
        The bound is convex in t (a power >= 1 of a linear function), so the chords between these
        points lie above it too: a polyline through them is an upper envelope. Certified, k < 0 only."""
        one_minus_a = self._one_minus_alpha()
        with np.errstate(all="ignore"):
            inner = self._c_times_one_minus_alpha() * (Iv(float(T)) - Iv(np.asarray(t, dtype=float)))
            inner = Iv(np.maximum(inner.lo, 0.0), np.maximum(inner.hi, 0.0))
            # from T on V1 = 0 exactly (T >= the exact T(z0)); outward rounding would leave 5e-324 there
            return np.where(np.asarray(t) >= T, 0.0, _pow_rational(inner, 1 / one_minus_a).hi)

    def _time_to_zero(self, V: Iv) -> Iv:
        """An enclosure of V^(1-a) / (c_lower (1-a)) for every V in the enclosure ``V`` (certified, k < 0):
        the time dV1/dt <= -c V1^alpha takes from V1 = V to 0."""
        e, rate = self._rate
        with np.errstate(all="ignore"):
            return V.pabs(e) * rate.recip()

    def _one_minus_alpha(self) -> Fraction:
        """1 - alpha = -k / (2 + k) as the exact rational of the float k (> 0 for -1/r < k < 0)."""
        F = Fraction(float(self.k))
        return -F / (2 + F)

    def _c_times_one_minus_alpha(self) -> Iv:
        """An enclosure of c_lower (1 - alpha), the rate in Theorem 1's comparison lemma."""
        return self._rate[1]

    @functools.cached_property
    def _rate(self) -> tuple[Exp, Iv]:
        """(1 - alpha enclosed, c_lower (1 - alpha) enclosed), once per certificate: the exact rationals
        cost ~0.15 ms, more than the rest of a T(z0), and each run's T(z0) and envelope use them (a
        frozen dataclass: the fields never change)."""
        e = exp_of(self._one_minus_alpha())
        return e, Iv(float(self.c_lower)) * e.iv()


def _hi(x):
    return x.hi if isinstance(x, Iv) else x


@functools.lru_cache(maxsize=32)
def _terms(r: int, k: float, gains: tuple) -> Terms:
    """Terms(r, k, gains), built once per parameter set: every run's T(z0) metric encloses V1(z0)
    with them, and building them (exact rational exponents) is ~0.6 ms of a sweep row's ~5 ms.
    Nothing mutates a Terms after its construction."""
    return Terms(r, k, gains)


def V1_enclosure(r: int, k: float, gains, z) -> Iv:
    """An outward-rounded enclosure of the full form's V1 at the float states z (n, r) (shape (n,)):
    the recursion variables s_i of Terms (hong_terms) enclosed in intervals, then V1 from them, with
    each z_i that Terms.z_of would rebuild from s (sig(y_i, 1/beta), Hoelder: it would turn the few
    ulps of s into ~1e-10) taken as the float it is. What a guaranteed T(z0) needs
    (Certificate.time_bound of the enclosure)."""
    return _enclosure_at(_terms(int(r), float(k), tuple(float(g) for g in gains)), z)[0]


def _enclosure_at(t: Terms, z):
    """(V1, dV1/dt, dV1/dz_r) of Terms t enclosed at the float states z (n, r), each an Iv (n,): as
    V1_enclosure, with the factor |y_i|^(1 - 1/beta_{i-1}) = |z_i|^(beta_{i-1} - 1) of dS_i/dt taken
    from the float z_i too (from y_i's enclosure, which holds 0 wherever z_i = 0, it is nearly [0, 1])."""
    r = t.r
    z = np.atleast_2d(np.asarray(z, dtype=float))
    s, S = [], None
    with np.errstate(all="ignore"):
        for i in range(1, r + 1):
            si = Iv(z[:, i - 1]).sig(t.beta[i - 1])
            si = si if S is None else si - S
            s.append(si)
            if i == 1 and r >= 2:
                S = -(t.lb[1] * Iv(z[:, 0]))
            elif i <= r - 1:
                S = -(t.lb[i] * si.sig(t.q[i]))

        def exact_z(slot, x, e, op):  # Terms.evaluate's slots SLOTS (i - 2) + 3 (z_i) and + 0 (that factor)
            i = slot // SLOTS + 2
            if slot % SLOTS == 3:
                return Iv(z[:, i - 1])
            if slot % SLOTS == 0:
                return Iv(z[:, i - 1]).pabs(t.beta_m1[i - 1])
            return exact_power(slot, x, e, op)

        return t.evaluate(s, exact_z)[:3]


ZERO_SET_STATES = 2_000  # face states per face and zero set in certify's refutation (_zero_set_witness)
ZERO_SET_CLIMBS = 32  # of them, the best climbed on the set
GOLDEN = (np.sqrt(5.0) - 1.0) / 2.0
LAST_SWEEP = np.concatenate([-np.logspace(1, -10, 111), [0.0], np.logspace(-10, 1, 111)])  # s_r / |s_r| of the limit state


def _zero_set_witness(obj: "Ratio", seed: int):
    """(guaranteed lower bound of R = dV1/dt / V1^alpha, state z (r,)) at the best of the face states
    put on a zero set z_i = 0 (i = 2..r - 1; ZERO_SET_STATES per face and set), or None (r <= 2).

    For k < 0 the factor beta |z_i|^(beta - 1) of dS_i/dt (beta = beta_{i-1} > 1, beta - 1 ~ -k) is 0
    on z_i = 0 and near 1 once |z_i| > ~1e-30, so there dV1/dt is that of the law without the term
    beta z_{i+1}, and it can be positive where it is negative everywhere else: a layer ~1e-50 thin
    that no sampled state reaches (measured: r = 6, k = -0.002, gains 0.62 .. 1e5: R = +0.263 at
    z_4 = 0, +0.080 at |z_4| = 1e-60, -0.32 at 1e-10). A face state s is put on the set by s_i =
    -S_{i-1} (y_i = 0, so z_i = 0 exactly), the best are climbed on the set, and R is enclosed at the
    exact state (_enclosure_at), so the value is guaranteed. Its own generator (seed, 1), so the
    witness search's states are unchanged."""
    r = obj.r
    if r <= 2:
        return None
    rng = np.random.default_rng((seed, 1))
    t = obj.t
    onto = functools.partial(onto_zero_set, t)
    R = obj.floats
    seeds = zero_set_starts(obj)
    best, arg = -np.inf, None
    for i in range(2, r):
        with np.errstate(all="ignore"):
            s = onto(np.concatenate([face_points(r, ZERO_SET_STATES, rng), seeds.get(i, np.empty((0, r)))]), i)
            # a random local ascent of the float R on the set from its best states (the face
            # coordinate and s_i held: s_i is a function of the others there)
            s = s[np.argsort(R(s))[-ZERO_SET_CLIMBS:]]
            f = R(s)
            free = np.abs(s) < 1.0
            free[:, i - 1] = False
            for step in 0.3 * 0.9 ** np.arange(60):
                trial = onto(np.clip(s + free * rng.normal(0.0, step, s.shape), -1.0, 1.0), i)
                ft = R(trial)
                up = ft > f
                s[up], f[up] = trial[up], ft[up]
            s = np.concatenate([s, [_zero_set_polish(s[j], i, onto, R) for j in np.argsort(f)[-2:]]])
            z = np.stack(t.z_of([s[:, j] for j in range(r)])[0], axis=-1)
        z[:, i - 1] = 0.0
        z = z[np.isfinite(z).all(axis=1)]
        V, dV, sr = _enclosure_at(t, z)
        with np.errstate(all="ignore"):
            lo = obj._ratio(V, dV, sr).lo
        lo = np.where(np.isnan(lo), -np.inf, lo)
        j = int(np.argmax(lo))
        if lo[j] > best:
            best, arg = float(lo[j]), z[j].copy()
    return None if arg is None else (best, arg)


def zero_set_starts(obj: "Ratio") -> dict:
    """{i: face states (2, r) on z_i = 0}: the maximiser of dV1/dt / V1 on that set in the limit
    k -> 0- (linear_limit.limit_forms, both signs) with s_r then set to the best of LAST_SWEEP
    (times its face value) by the float R, refined by a golden section. The limit's maximiser is
    one direction, which random face states rarely come near; s_r has to move with k because l_r
    (up to 1e6) multiplies it (measured: r = 6, gains 0.55176 .. 46.148, 1e5, k = -0.0005, on
    z_3 = 0: R = -11,649 at the limit state, -0.0247 after the sweep; the zero-set climb from
    samples alone reaches -0.084 over the sets, from these -0.0217)."""
    from ftstab_mj.control.linear_limit import limit_forms

    t, r = obj.t, obj.r
    sets, states, lo, hi = [], [], [], []
    for f in limit_forms([g.mid_float() for g in t.l], single=True):
        s = onto_zero_set(t, onto_faces(t, np.stack([f.z, -f.z])), f.z_zero[0])
        grid = LAST_SWEEP[None, :] * np.abs(s[:, r - 1:]).clip(1e-300, 1.0)  # (2, n)
        trial = np.repeat(s, grid.shape[1], axis=0)
        trial[:, r - 1] = grid.ravel()
        j = obj.floats(trial).reshape(2, -1).argmax(axis=1).clip(1, grid.shape[1] - 2)
        sets.append(f.z_zero[0])
        states.append(s)
        lo.append(grid[[0, 1], j - 1])
        hi.append(grid[[0, 1], j + 1])
    if not sets:
        return {}
    # one golden section for every set and both signs at once, both trial points in one evaluation:
    # the float R is elementwise in the states, so this is the per-state section bit for bit, in 60
    # calls instead of 121 per set (a call's fixed cost, not its states, was most of a design's time)
    s, a, b = np.concatenate(states), np.concatenate(lo), np.concatenate(hi)
    pair = np.concatenate([s, s])
    n = len(s)
    for _ in range(60):  # golden section between the best's neighbours (~1e-12 of the bracket)
        x1, x2 = b - GOLDEN * (b - a), a + GOLDEN * (b - a)
        pair[:n, r - 1], pair[n:, r - 1] = x1, x2
        R = obj.floats(pair)
        left = R[:n] >= R[n:]
        a, b = np.where(left, a, x1), np.where(left, x2, b)
    s[:, r - 1] = (a + b) / 2.0
    return {i: s[2 * m:2 * m + 2].copy() for m, i in enumerate(sets)}


def onto_zero_set(t: Terms, s, i: int) -> np.ndarray:
    """s (n, r) with s_i set to -S_{i-1}, so y_i = s_i + S_{i-1} = 0 and z_i = 0 exactly (S_{i-1}
    depends on s_1 .. s_{i-1} only). In place; returns s."""
    s[:, i - 1] = -t.z_of([s[:, j] for j in range(t.r)])[2][i - 1]
    return s


def onto_faces(t: Terms, z) -> np.ndarray:
    """The recursion variables (n, r) of float states z (n, r), none 0, dilated onto the faces
    max_i |s_i| = 1 (s_i has degree 1 - (i - 2) k for the dilation z_i -> lam^(p_i) z_i)."""
    r = t.r
    i = np.arange(1, r + 1)
    s = t.s_of(z)
    lam = np.min(np.abs(s) ** (-1.0 / (1.0 - (i - 2) * t.k)), axis=1)
    s = t.s_of(z * lam[:, None] ** (1.0 + (i - 1) * t.k))
    top = np.argmax(np.abs(s), axis=1)
    s[np.arange(len(s)), top] = np.sign(s[np.arange(len(s)), top])
    return s


def unit_level_set_points(hong: HongController, n: int, rng: np.random.Generator) -> np.ndarray:
    """n points with V1 = 1 (full form): random directions dilated onto the level set. Shape (n, r)."""
    r = hong.r
    mags = 10.0 ** rng.uniform(-3.0, 1.0, size=(n, r))
    z = mags * rng.choice([-1.0, 1.0], size=(n, r))
    return _onto_unit_level(hong, z)


def _onto_unit_level(hong, z):
    V = hong.V1(z)
    lam = V ** (-1.0 / hong.degree_V1)
    return hong.dilate(z, lam)


def refine_max(hong, f, z_best, rng, rounds=60, spread=0.2):
    """Local random search for max f on {V1 = 1}, started from the rows of z_best (m, r): an estimate
    from below of a maximum (loop_stages.actuator's u_needed uses it; the certificate does not)."""
    z = z_best.copy()
    fz = f(z)
    scale = np.abs(z).mean(axis=0) + 1e-12
    for it in range(rounds):
        step = spread * (0.5 ** (it / 12.0))
        cand = _onto_unit_level(hong, z + step * scale * rng.standard_normal(z.shape))
        fc = f(cand)
        better = np.isfinite(fc) & (fc > fz)
        z[better], fz[better] = cand[better], fc[better]
    return float(np.nanmax(fz))


# -- the quantity maximised over the faces ----------------------------------------------------------

class Ratio:
    """num / V1^a on the faces z_f = 1 of the cube: num = dV1/dt (kind "c") or |dV1/dz_r| ("cp")."""

    def __init__(self, terms: Terms, kind: str):
        self.t, self.kind = terms, kind
        self.a = terms.alpha if kind == "c" else terms.alpha_prime
        self.r = terms.r

    def _ratio(self, V, dV, sr):
        num = dV if self.kind == "c" else sr.abs()
        # V1 > 0 at every state of the faces (positive definite, the faces exclude z = 0), so 1/V1^a
        # is in [1/hi, inf) also where the enclosure of V1 reaches 0
        return num * V.pabs(self.a).recip_pos()

    def floats(self, z):
        """R at float states z (n, r) (an estimate: rounding not enclosed)."""
        with np.errstate(all="ignore"):
            V, dV, sr, _ = self.t.evaluate([z[:, i] for i in range(self.r)])
            num = dV if self.kind == "c" else np.abs(sr)
            out = num / V ** self.a.mid
        return np.where(np.isfinite(out), out, -np.inf)

    def points(self, z) -> Iv:
        """An enclosure of R at the float states z (n, r)."""
        with np.errstate(all="ignore"):
            return self._ratio(*self.t.evaluate([Iv(z[:, i]) for i in range(self.r)])[:3])

    def product(self, face, lo, hi, pin=None):
        """R on boxes of the faces ``face`` (an int, or (n,) ints: boxes of several faces in one
        evaluation; lo, hi (n, r - 1): the s_i, i != the box's face) as the function F of the box and
        the remainder ranges (see ``boxes``), with forward differentiation.

        pin: {slot: (n,) int8} for slots of the affine factors (AFFINE_SLOTS): 1 (2) holds that
        factor's remainder at the lower (upper) end of its range D on that box, a point (step 5 of
        ``boxes``); 0 leaves it a variable over D.

        Returns (F: Dual, value and gradient enclosures over the product, its gradient components
        0..r-1 the states' coordinates s_1..s_r and r + slot the remainders; phis: {slot: _Split},
        the factors split affinely on the boxes ``near``; split: {slot: (n, r)}, how much of each
        remainder's range a halving of each coordinate removes, for the split rule). A coordinate
        that is every box's face is the constant 1 (its component None); with boxes of several faces
        it is a variable whose component is meaningless on the boxes of its face (seeded ABSENT_SEED
        there, and outward rounding can make it anything), as is a remainder's on the boxes where its
        factor is not split: no caller uses them there."""
        r, n, face = self.r, len(lo), np.asarray(face)
        m = SLOTS * max(0, r - 1)  # extra variables: the factor slots of Terms.evaluate
        LO, HI, fixed = _on_faces(lo, face), _on_faces(hi, face), _fixed(face, n, r)
        phis, split, through = {}, {}, {}

        def box_factor(slot, x, e, op):
            if op == "value":  # z_j - v_{j-1}: on the product it is off the manifold by at most dev
                if not isinstance(x, Dual):
                    return e
                return Dual(_widened(e, x, phis, r), x.g)
            chain = x.sig(e) if op == "sig" else x.pabs(e)
            if (not isinstance(x, Dual) or e.is_exactly(1.0) or e.is_exactly(0.0) or e.lo <= 1.0 <= e.hi
                    or (op == "pabs" and e.lo > 1.0)):  # |x|^0 = 1 (k = 0); no |x|^e, e > 1, is a slot
                return chain
            near = x.v.mig() < x.v.hi - x.v.lo
            if not near.any():
                return chain
            # phi = a x + delta, delta a variable over its range D on the box (a = 0: phi itself)
            a = np.where(near, secant_slope(x.v, e, op), 0.0)
            D = affine_remainder(x.v, e, op, a)
            D = Iv(np.where(a == 0.0, chain.v.lo, D.lo), np.where(a == 0.0, chain.v.hi, D.hi))
            if pin is not None and slot in pin:
                assert slot % SLOTS in AFFINE_SLOTS and self.kind == "c", "only R = dV1/dt / V1^a is affine in it"
                end = np.where(pin[slot] == 1, D.lo, np.where(pin[slot] == 2, D.hi, np.nan))
                held = near & ~np.isnan(end)
                D = Iv(np.where(held, end, D.lo), np.where(held, end, D.hi))
            A = Iv(a)
            g = [None if gg is None else _rows(near, A * xg, gg) for gg, xg in zip(chain.g, x.g)]
            g[r + slot] = Iv(np.where(near, 1.0, ABSENT_SEED))
            phis[slot] = _Split(near, a, D)
            # which box coordinates make phi's argument wide (directly and through the remainders it
            # depends on): a split of one of them narrows D, by 2^-e only near its zero
            wid = np.zeros((n, r))
            for jj in range(r):
                if x.g[jj] is not None:
                    wid[:, jj] = np.where(fixed[jj], 0.0, x.g[jj].mag() * (HI[:, jj] - LO[:, jj]))
            for sl, var in phis.items():
                gg = x.g[r + sl]
                if gg is not None and sl != slot:
                    wid += through[sl] * np.where(var.near, gg.mag() * (var.rng.hi - var.rng.lo), 0.0)[:, None]
            bad = ~np.isfinite(wid).all(axis=1)
            wid[bad] = np.where(np.isfinite(wid[bad]), 0.0, (HI - LO)[bad])
            tot = wid.sum(axis=1, keepdims=True)
            through[slot] = np.where(tot > 0, wid / np.where(tot > 0, tot, 1.0), 0.0)
            split[slot] = through[slot] * (2.0 * (1.0 - 2.0 ** -e.lo))
            return Dual(_rows(near, A * x.v + D, chain.v), g)

        zs = []
        for i in range(r):
            if fixed[i].all():
                zs.append(Iv(1.0))
            else:
                seed = Iv(np.where(fixed[i], ABSENT_SEED, 1.0)) if fixed[i].any() else Iv(1.0)
                zs.append(Dual(Iv(LO[:, i], HI[:, i]), [seed if jj == i else None for jj in range(r + m)]))
        F = self._ratio(*self.t.evaluate(zs, box_factor, lambda sl: phis[sl].near if sl in phis else None)[:3])
        return F, phis, split

    def at(self, face, x, phis):
        """F at points of the product: x (n, r - 1) box coordinates on the faces ``face`` (an int or
        (n,) ints), phis {slot: (near (n,), slope (n,), value (n,))}: where ``near`` the factor is
        slope x + value (x its argument), elsewhere it is computed; z_j - v_{j-1} is its plain
        difference (F's, off the manifold). An Iv (n,)."""
        return self._at(_on_faces(x, face), phis)

    def _at(self, z, phis):
        """``at`` at the states z (n, r)."""
        off = np.zeros(len(z), dtype=bool)
        for near, _, _ in phis.values():
            off |= near

        def point_factor(slot, xx, e, op):
            if op == "value":  # on the manifold also the tight enclosure
                return _rows(off, xx, Iv(np.maximum(xx.lo, e.lo), np.minimum(xx.hi, e.hi)))
            val = xx.sig(e) if op == "sig" else xx.pabs(e)
            if slot not in phis:
                return val
            near, a, c = phis[slot]
            return _rows(near, Iv(a) * xx + c, val)

        zs = [Iv(z[:, i]) for i in range(self.r)]
        return self._ratio(*self.t.evaluate(zs, point_factor, lambda sl: phis[sl][0] if sl in phis else None)[:3])

    def boxes(self, face, lo, hi):
        """Bounds over boxes of the faces ``face`` (an int, or (n,) ints: several faces in one
        evaluation, the same bounds as one face at a time): lo, hi (n, r - 1) box coordinates (the
        s_i, i != the box's face).

        Returns (upper bound of R on each box (n,), box coordinate to split (n,), a column of lo/hi,
        guaranteed lower bound of R at each centre (n,), centres (n, r)).

        The upper bound is the smallest of two interval enclosures of R, a mean-value form, and the
        largest of the mean-value forms with some remainders held at the ends of their ranges (each
        mean-value form with the pairs of step 6).
        Every step below is proven; the soundness of each is stated with what it rests on.

        1. The enclosure E1 = Terms.evaluate over the box in intervals. Each quantity is enclosed by
           an interval extension of a formula that holds at every state of the box (the identities
           y_i - S_{i-1} = s_i, z_i = sig(y_i, 1/beta_{i-1}), sig(v_{i-1}, beta_{i-1}) = S_{i-1} of
           _diff and _W hold at every state: they are the definitions of the recursion; W's floor
           C_b |z - a|^(b+1) holds for all real z, a: hong_terms._W_floor). V1 > 0 at every state of
           a face, so 1/V1^alpha lies in [1/hi, inf) of the enclosure of V1^alpha even where its
           lower end is 0 (Iv.recip_pos). So R(s) is in E1 for every s of the box.
        2. Near the zero of the argument x of a factor phi = |x|^e or sig(x, e) (a slot of
           Terms.evaluate, e != 0, 1; the box "near" when the enclosure X of x comes within its width
           of 0), dphi/dx is unbounded (e < 1) or its enclosure is wide (e > 1). There phi is split
           affinely: phi = a x + delta, with a float slope a (the secant over X; 0 for |x|^e on an X
           that holds 0) and delta a variable of its own over D, an enclosure of phi(t) - a t for all
           t in X (interval.affine_remainder: the extremes of a function continuous on X and
           differentiable but at 0 lie at the ends, at 0 or where phi' = a). F(s, d) is the function
           that the evaluation computes with a x + d in place of phi (``product``: Terms.evaluate's
           ``extra`` masks), one function on the product X x D of the box and the ranges: each of its
           steps is a formula in (s, d) with no identity that needs d = delta(s) — where z_j,
           v_{j-1} or S_{j-1} holds a split factor, the enclosures of z_j - v_{j-1} and of
           sig(z_j, b) - sig(v_{j-1}, b) that the identities give on the manifold (d = delta(s)) are
           widened by sum_k max|dq/dd_k| width(D_k) (mean value theorem in d on the segment from
           (s, delta(s)) to (s, d), inside the product; ``_widened``), and W(z_j, v_{j-1}) is the
           integral itself with its own partial derivatives (Terms._W: ``offm``); elsewhere those
           quantities are functions of s and the identities hold. So the value enclosures of the
           Dual arithmetic hold on all of X x D, and each gradient rule is the derivative (a Clarke
           gradient at |x|, Lipschitz) of that step; F is Lipschitz on the convex X x D and its
           gradient is enclosed there by G (``F.g``).
        3. F(c) + sum_j sup(G_j (x_j - c_j)) >= F(x) for all x, c in X x D (mean value theorem on the
           segment from c to x, inside X x D); c is Baumann's centre of each variable, F(c) enclosed
           by ``_at``. Since (s, delta(s)) is in X x D and F(s, delta(s)) = R(s), this bounds R on X.
        4. E2 = F's value enclosure over X x D (``F.v``), a bound for the same reason.
        5. Held ends (R = dV1/dt / V1^alpha only). The factors of slots AFFINE_SLOTS,
           f = |y_i|^(1 - 1/beta_{i-1}) and g = |s_i|^(q_i - 1) (i = 2..r-1; exponents ~ -k, so on a
           box that holds y_i = 0 or s_i = 0 their range is nearly [0, 1] however thin the box),
           occur in Terms.evaluate only in dS_i/dt = -l_i^beta_i q_i g (beta_{i-1} f z_{i+1} -
           dS_{i-1}/dt), and dS_i/dt only in dS_{i+1}/dt (linearly, in the same form) and in
           dV1/dt's term -(z_{i+1} - v_i) dS_i/dt; neither V1 nor any z_j, v_j, S_j, W or z_j - v_j
           holds them (nor is any argument of a slot computed from them). So F = dV1/dt(s, d) x
           V1(s, d)^-alpha is, with every other variable held, affine in each of their remainders d
           (phi = a x + d, step 2): multi-affine in them jointly. A multi-affine function on a box
           of those remainders takes its maximum at a vertex (held the others, it is affine in one,
           so at one of its ends; by induction). Hence for any s in X, R(s) = F(s, delta(s)) <= max
           over the 2^m vertices v of the held ranges of sup F(s, v, d'), d' the other remainders in
           their ranges; each sup is bounded by steps 3-4 on the product with the held ranges made
           the points D.lo or D.hi (the floats of the outward enclosure D, so [D.lo, D.hi] still holds
           delta(s); the evaluation at a point is outward-rounded as any other), and the largest of
           the 2^m bounds bounds R on the box. The kind "cp" (|dV1/dz_r| = |s_r|) holds none of them.
        6. Paired remainders (``_pair``). The factors sig(s_i, e_i) (in v_i) and sig(s_i, q_i) (in
           S_i) of PAIRED_SLOTS have as argument the box coordinate s_i itself, so at every point
           (s, delta(s)) that steps 3 and 5 bound, the remainder d of such a factor is delta(s_i) =
           phi(s_i) - a s_i, a function of the coordinate, not a free variable. In step 3's equality
           F(p) - F(c) = sum_j gam_j (p_j - c_j) (gam in G, at a point of the segment), write for the
           pair (x = s_i, d) and any floats g, h (the midpoints of G_x, G_d):
               gam_x (x - c_x) + gam_d (d - c_d) = psi(x) + (gam_x - g)(x - c_x) + (gam_d - h)(d - c_d),
               psi(x) = g (x - c_x) + h (delta(x) - c_d) = h (phi(x) - b x) + (g - h (a - b)) x - g c_x - h c_d
           (an identity for every float b; b = a - g / h makes the middle coefficient ~0). Where
           d = delta(x), psi(x) is at most the upper end of the interval evaluation
           h D_b + (g - h (a - b)) X - g c_x - h c_d, D_b = affine_remainder(X, e, b) an enclosure of
           phi(t) - b t on X (as in step 2); the other two parts are at most the terms of step 3
           with G_x - g and G_d - h in place of G_x, G_d (d = delta(x) is in D). So the sum of these
           three bounds the pair's two terms at every point with d = delta(s_i), which includes each
           (s, delta(s)) and each point that step 5 bounds (it holds only slots AFFINE_SLOTS); it
           replaces them where it is smaller, one factor per coordinate (the one that gains most;
           used only for -k <= PAIR_K and where the remainder's term is PAIR_SHARE of the terms or
           more: speed only, any choice is sound).
           The gain: the decoupled terms charge h's full range of delta and x's end at once; the
           pair's third parts are products of two widths (second order) and psi is nearly exact.
        tests/test_control_certificate.py checks steps 2-3 against F at random points of X x D off
        the manifold (the manifold's identities taken off it fail it, and so does F with slopes 10 %
        off its gradient's); tests/test_interval_soundness.py checks D against mpmath at the exact
        extrema of phi(t) - a t.
        """
        r, n, face = self.r, len(lo), np.asarray(face)
        zc = _on_faces(0.5 * (lo + hi), face)
        with np.errstate(all="ignore"):
            vhi, mv, score, F, phis = self._forms(face, lo, hi)
            ub = np.fmin(vhi, mv)
            if self.kind == "c":
                ub = np.fmin(ub, self._held(face, lo, hi, F, phis, self._excess))
            near = np.zeros(n, dtype=bool)
            for var in phis.values():
                near |= var.near
            # R at the centres (a witness candidate) and E1 on the boxes ``near`` (elsewhere F = R,
            # E1 = E2), in one evaluation: a call's cost is mostly per evaluation, not per row
            sel = np.nonzero(near)[0]
            blo, bhi = _on_faces(lo[sel], _face_rows(face, sel)), _on_faces(hi[sel], _face_rows(face, sel))
            both = self._ratio(*self.t.evaluate([Iv(np.concatenate([zc[:, i], blo[:, i]]),
                                                    np.concatenate([zc[:, i], bhi[:, i]])) for i in range(r)])[:3])
            Rc = Iv(both.lo[:n], both.hi[:n])
            ub[sel] = np.fmin(ub[sel], both.hi[n:])
        ub = np.where(np.isnan(ub), np.inf, ub)
        rad = hi - lo
        # split where the mean-value form says the enclosure is widest (a variable factor's term
        # charged to the coordinates its range comes from); where it is unbounded, the widest side
        score = _off_faces(score, face)
        plain = ~np.isfinite(score).all(axis=1) | ~(score > 0).any(axis=1)
        split = np.where(plain, np.argmax(rad, axis=1), np.argmax(np.where(np.isfinite(score), score, 0.0), axis=1))
        lb = np.where(np.isnan(Rc.lo), -np.inf, Rc.lo)
        return ub, split, lb, zc

    def _forms(self, face, lo, hi, pin=None):
        """Steps 2-4 of ``boxes`` on the product (with ``pin``'s remainders held at an end, step 5):
        (E2's upper bound (n,), the mean-value form's (n,), the split scores (n, r) of the states'
        coordinates, F, phis)."""
        r, n, face = self.r, len(lo), np.asarray(face)
        LO, HI, fixed = _on_faces(lo, face), _on_faces(hi, face), _fixed(face, n, r)
        mid = 0.5 * (LO + HI)
        F, phis, share = self.product(face, lo, hi, pin)
        # the mean-value form about Baumann's centre: per variable x in [lo, hi] with dF/dx in
        # [a, b], the centre c where b (hi - c) = -a (c - lo) minimises the bound's term
        # max over x, g of g (x - c) (c = hi where a >= 0, lo where b <= 0: monotone in x)
        cb = mid.copy()  # 1 at each box's face
        for jj in range(r):
            if F.g[jj] is not None:
                cb[:, jj] = np.where(fixed[jj], 1.0, _baumann(F.g[jj], LO[:, jj], HI[:, jj], mid[:, jj]))
        centres = {}
        for slot, (near, a, val) in phis.items():
            g, c = F.g[r + slot], 0.5 * (val.lo + val.hi)
            centres[slot] = (near, a, c if g is None else _baumann(g, val.lo, val.hi, c))
        mv = self._at(cb, centres).hi.copy()
        base = mv.copy()
        score = np.zeros((n, r))
        terms = {}  # variable (F.g's index) -> its term of the form (n,); a coordinate's is 0 on its face
        for jj, g in enumerate(F.g):
            if g is None:
                continue
            if jj < r:
                terms[jj] = np.where(fixed[jj], 0.0, _term(g, LO[:, jj], HI[:, jj], cb[:, jj]))
                # the midpoint form's term (x2)
                score[:, jj] += np.where(fixed[jj], 0.0, g.mag() * (HI[:, jj] - LO[:, jj]))
            elif jj - r in phis:
                var = phis[jj - r]
                terms[jj] = np.where(var.near, _term(g, var.rng.lo, var.rng.hi, centres[jj - r][2]), 0.0)
                w = g.mag() * (var.rng.hi - var.rng.lo)
                score += share[jj - r] * np.where(var.near & np.isfinite(w), w, 0.0)[:, None]
        self._pair(fixed, LO, HI, F, phis, cb, centres, terms)
        for jj, term in terms.items():
            # a box's bound is the same whatever boxes are evaluated with it: a variable that is not one
            # on a box (its coordinate held at 1, a factor not split there: its gradient component is
            # then seeded 0, and outward rounding leaves a trace) adds nothing there, not even a rounding
            absent = fixed[jj] if jj < r else ~phis[jj - r].near
            mv = np.where(absent, mv, round_up(mv + term)) if absent.any() else round_up(mv + term)
        self._excess = mv - base  # the mean-value form's terms (for the choice of step 5's boxes)
        return F.v.hi.copy(), mv, score, F, phis

    def _pair(self, fixed, lo, hi, F, phis, cb, centres, terms):
        """Step 6 of ``boxes``: on each box where it is smaller, the terms of a coordinate s_i and of
        the remainder of one factor of s_i itself (PAIRED_SLOTS) replaced by their joint bound
        (_paired_term): ``terms`` {F.g index: (n,)} updated in place, the pair's bound in the
        coordinate's entry and 0 in the remainder's. One remainder per coordinate and box; none on
        the boxes where s_i is the face (``fixed``). lo, hi, cb: (n, r), the states' coordinates."""
        r = self.r
        if not -self.t.k <= PAIR_K:
            return
        total = np.zeros(len(lo))
        for term in terms.values():
            total = total + np.where(np.isfinite(term), np.abs(term), 0.0)
        for i in range(2, r + 1):
            jj = i - 1  # the coordinate s_i
            if F.g[jj] is None or jj not in terms:
                continue
            best, pick, saving = None, None, np.zeros(len(lo))
            for j in PAIRED_SLOTS:
                slot = SLOTS * (i - 2) + j
                if slot not in phis or (r + slot) not in terms:
                    continue
                e = self.t.e[i] if j == 2 else self.t.q[i]  # sig(s_i, e_i) in v_i, sig(s_i, q_i) in S_i
                near, a, D = phis[slot]
                # only where the remainder's term is a share of the form's terms: elsewhere the pair
                # cannot gain much (speed only: any choice of boxes is sound)
                rows = np.nonzero(near & ~fixed[jj] & ~(terms[r + slot] < PAIR_SHARE * total))[0]
                if not len(rows):
                    continue
                new = np.full(len(lo), np.inf)
                new[rows] = _paired_term(_sub(F.g[jj], rows), _sub(F.g[r + slot], rows), lo[rows, jj], hi[rows, jj],
                                         cb[rows, jj], a[rows], _sub(D, rows), centres[slot][2][rows], e, "sig")
                with np.errstate(invalid="ignore"):
                    gain = np.where(np.isfinite(new), (terms[jj] + terms[r + slot]) - new, 0.0)
                better = gain > saving
                if better.any():
                    best = new if best is None else np.where(better, new, best)
                    pick = np.where(better, slot, -1 if pick is None else pick)
                    saving = np.where(better, gain, saving)
            if best is None:
                continue
            for slot in np.unique(pick[pick >= 0]):
                use = pick == slot
                terms[jj] = np.where(use, best, terms[jj])
                terms[r + slot] = np.where(use, 0.0, terms[r + slot])

    def _exponent(self, slot: int) -> Exp:
        """The exponent of an affine factor's slot (AFFINE_SLOTS; Terms.evaluate's numbering)."""
        i = slot // SLOTS + 2
        return self.t.one_m_inv_beta[i - 1] if slot % SLOTS == 0 else self.t.q_m1[i]

    def _held(self, face, lo, hi, F, phis, excess):
        """Step 5 of ``boxes``: on each box, up to MAX_HELD of the affine factors' remainders (those
        whose mean-value term |dF/d delta| width(D) is largest) held at each end of their ranges in
        turn, and the largest of the 2^m bounds (inf where none is held)."""
        r, n = self.r, len(lo)
        cand = [sl for sl in phis if sl % SLOTS in AFFINE_SLOTS and F.g[r + sl] is not None
                and self._exponent(sl).hi <= HELD_EXPONENT]
        out = np.full(n, np.inf)
        if not cand:
            return out
        W = np.zeros((n, len(cand)))
        for c, sl in enumerate(cand):
            w = F.g[r + sl].mag() * (phis[sl].rng.hi - phis[sl].rng.lo)
            W[:, c] = np.where(phis[sl].near & ~(w <= 0), np.where(np.isnan(w), np.inf, w), 0.0)
        order = np.argsort(-W, axis=1, kind="stable")[:, :MAX_HELD]
        m = np.minimum((W > 0).sum(axis=1), MAX_HELD)
        # only where the held factors' terms are most of the form's excess: elsewhere holding them
        # cannot gain much, and it costs 2^m evaluations (speed only: any choice is sound)
        gain = np.take_along_axis(W, order, axis=1).sum(axis=1)
        m = np.where(gain >= HELD_SHARE * excess, m, 0)
        rows, pins = [], {sl: [] for sl in cand}
        for mm in range(1, MAX_HELD + 1):
            boxes = np.nonzero(m == mm)[0]
            if not len(boxes):
                continue
            for v in range(2 ** mm):  # every vertex of the held ranges
                rows.append(boxes)
                for sl in cand:
                    p = np.zeros(len(boxes), dtype=np.int8)
                    for kk in range(mm):
                        p[order[boxes, kk] == cand.index(sl)] = 1 + ((v >> kk) & 1)
                    pins[sl].append(p)
        if not rows:
            return out
        rows = np.concatenate(rows)
        pin = {sl: np.concatenate(p) for sl, p in pins.items()}
        vhi, mv = self._forms(_face_rows(face, rows), lo[rows], hi[rows], pin)[:2]
        ubv = np.fmin(vhi, mv)
        ubv = np.where(np.isnan(ubv), np.inf, ubv)
        top = np.full(n, -np.inf)
        np.maximum.at(top, rows, ubv)
        return np.where(m > 0, top, np.inf)


class _Split(NamedTuple):
    """A factor phi split affinely on some boxes: phi = slope x + delta, delta a variable over rng."""

    near: np.ndarray  # (n,) bool: the boxes where it is split
    slope: np.ndarray  # (n,) float: a (0 elsewhere)
    rng: Iv  # (n,): D, the range of phi(x) - a x over the box


def _on_faces(x, face):
    """Box coordinates x (n, r - 1) as states (n, r): 1.0 put in at each box's face (an int, or (n,)
    ints)."""
    if np.ndim(face) == 0:
        return np.insert(x, int(face), 1.0, axis=1)
    n, d = x.shape
    z = np.empty((n, d + 1))
    for i in range(d + 1):  # column i: the coordinate i - 1 of the boxes whose face is before it, i after
        before = x[:, i - 1] if i > 0 else 1.0
        after = x[:, i] if i < d else 1.0
        z[:, i] = np.where(face < i, before, np.where(face > i, after, 1.0))
    return z


def _off_faces(z, face):
    """The inverse of _on_faces: the columns of z (n, r) other than each row's face, (n, r - 1)."""
    if np.ndim(face) == 0:
        return np.delete(z, int(face), axis=1)
    n, r = z.shape
    cols = np.arange(r - 1)[None, :]
    return np.take_along_axis(z, cols + (cols >= face[:, None]), axis=1)


def _face_rows(face, rows):
    """The faces of the boxes ``rows`` (an index or mask) of boxes whose faces are ``face`` (an int or (n,))."""
    return face if np.ndim(face) == 0 else face[rows]


def _fixed(face, n: int, r: int) -> list:
    """[(n,) bool] for each coordinate i of the states: the boxes whose face it is (held at 1)."""
    return [np.broadcast_to(np.asarray(face) == i, (n,)) for i in range(r)]


def _rows(mask, a: Iv, b: Iv) -> Iv:
    """a where mask, b elsewhere (Iv of one shape)."""
    return Iv(np.where(mask, a.lo, b.lo), np.where(mask, a.hi, b.hi))


def _widened(val: Iv, x: Dual, phis, r: int) -> Iv:
    """An enclosure over the product of z_j - v_{j-1} = x: val encloses it on the manifold (delta =
    delta(s)), and moving the remainders from there changes it by at most sum_k max|dx/d delta_k|
    width(D_k) (mean value theorem in delta, on the segment inside the product); intersected with x's
    own enclosure. Outward-rounded; x's where that sum is not finite. x.g[r + slot]: the remainders'."""
    dev = np.zeros(np.shape(val.lo))
    with np.errstate(invalid="ignore"):
        for sl, var in phis.items():
            gg = x.g[r + sl]
            if gg is not None:
                term = round_up(gg.mag() * round_up(var.rng.hi - var.rng.lo))
                # only where the factor is split (elsewhere it is no variable: no term, no rounding)
                dev = np.where(var.near, round_up(dev + np.where(np.isnan(term), np.inf, term)), dev)
    return Iv(np.maximum(round_down(val.lo - dev), x.v.lo), np.minimum(round_up(val.hi + dev), x.v.hi))


def _baumann(g, lo, hi, mid):
    """Baumann's centre in [lo, hi] (arrays) for a derivative enclosure g (Iv); mid where g is unbounded.
    Any point of the box keeps the form sound: this choice only makes it tighter."""
    a, b = g.lo, g.hi
    with np.errstate(all="ignore"):
        c = (b * hi - a * lo) / (b - a)
    c = np.where(a >= 0, hi, np.where(b <= 0, lo, c))
    c = np.where(np.isfinite(c) & np.isfinite(a) & np.isfinite(b), c, mid)
    return np.clip(c, lo, hi)


def _sub(x: Iv, rows) -> Iv:
    """The rows ``rows`` of an Iv of shape (n,) (a scalar Iv stays as it is)."""
    return Iv(x.lo[rows] if np.ndim(x.lo) else x.lo, x.hi[rows] if np.ndim(x.hi) else x.hi)


def _paired_term(gj, ga, lo, hi, cj, a, D, ca, e, op):
    """An upper bound of gj (x - cj) + ga (d - ca) over x in [lo, hi], d = phi(x) - a x, gj in the
    Iv gj, ga in the Iv ga (phi = sig(., e) or |.|^e as op): step 6 of Ratio.boxes. With floats
    g = mid gj, h = mid ga and any float slope b, it is h (phi(x) - b x) + (g - h (a - b)) x - g cj -
    h ca (an identity) plus (gj - g)(x - cj) + (ga - h)(d - ca), each part bounded on its own; inf
    where that is not a number."""
    with np.errstate(all="ignore"):
        g, h = 0.5 * (gj.lo + gj.hi), 0.5 * (ga.lo + ga.hi)
        ok = np.isfinite(g) & np.isfinite(h)
        g, h = np.where(ok, g, 0.0), np.where(ok, h, 0.0)
        b = np.where(h != 0, a - g / np.where(h != 0, h, 1.0), a)
        b = np.where(np.isfinite(b), b, a)
        X = Iv(lo, hi)
        G, H = Iv(g), Iv(h)
        eps = G - H * (Iv(a) - Iv(b))
        lin = H * affine_remainder(X, e, op, b) + eps * X - G * Iv(cj) - H * Iv(ca)
        out = round_up(round_up(lin.hi + _term(gj - G, lo, hi, cj)) + _term(ga - H, D.lo, D.hi, ca))
    return np.where(ok & ~np.isnan(out), out, np.inf)


def _term(g, lo, hi, c):
    """An upper bound of g (x - c) over g in the Iv g and x in [lo, hi] (arrays), outward-rounded; inf
    where g is NaN or the centre c is not a finite number (Iv's product reads a NaN factor as 0)."""
    t = (g * Iv(round_down(lo - c), round_up(hi - c))).hi
    return np.where(np.isnan(g.lo) | np.isnan(g.hi) | ~np.isfinite(c), np.inf, t)


@dataclass
class _Max:
    upper: float  # guaranteed: R <= upper on every face
    lower: float  # guaranteed: R(witness) >= lower
    witness: np.ndarray  # (r,)
    boxes: int
    converged: bool


def face_points(r: int, per_face: int, rng) -> np.ndarray:
    """States on the r faces z_j = 1 of the cube, per_face each (per_face r, r): half uniform in
    [-1, 1]^(r-1), half with log-uniform moduli 1e-6..1 (the failures of k < 0 lie in thin layers
    where a recursion variable nearly vanishes, which uniform points miss: the distribution of the
    certificate's witness search)."""
    pts = []
    for face in range(r):
        x = rng.uniform(-1.0, 1.0, size=(per_face, r - 1))
        half = per_face // 2
        x[half:] = np.sign(x[half:]) * 10.0 ** rng.uniform(-6.0, 0.0, size=x[half:].shape)
        pts.append(np.insert(x, face, 1.0, axis=1))
    return np.concatenate(pts)


def _seed_points(obj: Ratio, samples: int, rng) -> np.ndarray:
    """States on the faces with a large float R: sampled, then improved by a local random search."""
    z = face_points(obj.r, max(1, samples // obj.r), rng)
    f = obj.floats(z)
    top = np.argsort(f)[-min(32, len(f)):]
    z = climb(obj, z[top], rng)
    return np.concatenate([z, _polish(obj, z[np.argsort(obj.floats(z))[-4:]])])


def _zero_set_polish(row, i, onto, R, iters=400):
    """Nelder-Mead ascent of the float R on the zero set y_i = 0 from the face state ``row`` (r,):
    the free coordinates are those with |s_j| < 1 but s_i (``onto`` sets it)."""

    free = np.nonzero(np.abs(row) < 1.0)[0]
    free = free[free != i - 1]
    if not len(free):
        return row

    def state(x):
        s = row.copy()
        s[free] = np.clip(x, -1.0, 1.0)
        return onto(s[None, :], i)

    x, _ = nelder_mead(lambda x: -float(R(state(x))[0]), row[free], step=0.05, iters=iters)
    return state(x)[0]


def _polish(obj: Ratio, z, iters=400):
    """Nelder-Mead ascent of the float R from each row of z (n, r), its largest coordinate held:
    the simplex is affine invariant, so it climbs the narrow ridges of gains spanning many decades
    where a random search stalls. Any state is a valid witness (it need not stay on the cube)."""

    if obj.r == 1:
        return z
    out = []
    for row in z:
        face = int(np.argmax(np.abs(row)))
        fix = row[face]

        def cost(x):
            v = obj.floats(np.insert(x, face, fix)[None, :])[0]
            return -v if np.isfinite(v) else np.inf

        x, _ = nelder_mead(cost, np.delete(row, face), step=0.05 * (np.abs(np.delete(row, face)).max() + 1e-3),
                           iters=iters, tol=1e-12)
        out.append(np.insert(x, face, fix))
    return np.array(out)


def climb(obj: Ratio, z, rng, rounds=80, step0=0.3):
    """Local random search for larger float R from the rows of z (n, r), staying on their faces."""
    z = z.copy()
    f = obj.floats(z)
    on_face = np.abs(z) == 1.0
    for it in range(rounds):
        step = step0 * 0.85 ** it
        cand = np.clip(z + step * rng.standard_normal(z.shape) * np.maximum(np.abs(z), 1e-6), -1.0, 1.0)
        cand[on_face] = z[on_face]
        fc = obj.floats(cand)
        better = fc > f
        z[better], f[better] = cand[better], fc[better]
    return z


def _maximise(obj: Ratio, seeds, rtol, deadline, stop_if_positive, progress=None, rng=None,
              max_boxes=DEFAULT_MAX_BOXES, proven=-np.inf) -> _Max:
    """Branch and bound for max R over the r faces (see the module docstring).

    Every box has an upper bound ub. A box with ub <= best + rtol |best| (best: the guaranteed
    value at the witness) never needs splitting: it is retired and only the largest such ub is
    kept (``done``). When stop_if_positive (R is dV1/dt / V1^alpha: "is c > 0?"), the boxes with
    ub < 0 are parked first and only those with ub >= 0 are split, until none is left (c_lower > 0
    proven) or the witness reaches R >= 0 (stop: not certified); then the parked boxes are refined
    for the gap. A budget that runs out so decides the status before it tightens the gap. Each round splits
    the open boxes with the largest ub (at most SPLIT_BATCH of them) along one coordinate; a small
    round's children of every face are bounded in one call (MERGE_FACES), which gives each box the
    bound it gets alone (test_a_box_bound_does_not_depend_on_the_boxes_evaluated_with_it).

    Memory in phase 1 (r = 6 at k < 0 needs ~1e7 boxes of it): the boxes phase 1 splits are those
    with ub >= 0, whatever the order, so above MAX_LIVE_BOXES / 2 open boxes it splits those with
    the smallest ub first (their children are the likeliest to be parked), and above
    MAX_LIVE_BOXES / 2 parked boxes it keeps the quarter with the largest ub for the gap and retires
    the rest (their largest ub, < 0, joins ``done``: c_lower stays a bound, the gap may stop there,
    and the B&B does stop once every live box's ub is at most that: no split can raise c_lower).
    """
    r, d = obj.r, obj.r - 1
    lb_seed = obj.points(seeds).lo
    lb_seed = np.where(np.isnan(lb_seed), -np.inf, lb_seed)
    i = int(np.argmax(lb_seed))
    best, wit = float(lb_seed[i]), seeds[i].copy()
    best = max(best, float(proven))  # a guaranteed value of R at a state the caller found (and names)
    if d == 0:  # r = 1: the sphere is the point z_1 = 1
        R = obj.points(np.ones((1, 1)))
        return _Max(float(R.hi[0]), float(R.lo[0]), np.ones(1), 1, True)
    nbox = 0

    def evaluate(lo, hi, face):
        nonlocal best, wit, nbox
        ub, split = np.empty(len(lo)), np.empty(len(lo), dtype=int)
        # a small round in one evaluation: its cost is NumPy's per-call overhead, paid once instead of
        # once a face; a large one face by face (several faces cost more gradient work per box)
        merge = len(lo) <= MERGE_FACES * max(1, r - 2)
        groups = [np.ones(len(lo), dtype=bool)] if merge else [face == f for f in np.unique(face)]
        for sel in groups:
            u, s, lbc, zc = obj.boxes(face[sel], lo[sel], hi[sel])
            ub[sel], split[sel] = u, s
            # the best centre; among equal ones the first of the lowest face (the order face by face)
            top = np.nonzero(lbc == lbc.max())[0]
            j = int(top[np.argmin(face[sel][top])])
            if lbc[j] > best:
                best, wit = float(lbc[j]), zc[j].copy()
        nbox += len(lo)
        return ub, split

    lo, hi, face = np.full((r, d), -1.0), np.full((r, d), 1.0), np.arange(r)
    ub, split = evaluate(lo, hi, face)
    done = -np.inf  # the largest ub of the retired boxes
    proving = stop_if_positive  # phase 1: only the boxes with ub >= 0 are split
    parked, parked_top = [], -np.inf  # boxes (lo, hi, face, ub, split) with ub < 0, set aside in phase 1
    n_parked = 0
    converged = False
    iteration = 0
    rng = rng if rng is not None else np.random.default_rng(0)
    while True:
        thr = best + rtol * abs(best)
        retire = ub <= thr
        if retire.any():
            done = max(done, float(ub[retire].max()))
            lo, hi, face, ub, split = lo[~retire], hi[~retire], face[~retire], ub[~retire], split[~retire]
        if stop_if_positive and best >= 0.0:  # a state with dV1/dt >= 0: not certified
            break
        if proving:
            park = ub < 0.0
            if park.any():
                parked.append((lo[park], hi[park], face[park], ub[park], split[park]))
                parked_top = max(parked_top, float(ub[park].max()))
                lo, hi, face, ub, split = lo[~park], hi[~park], face[~park], ub[~park], split[~park]
                n_parked += int(park.sum())
                if n_parked > MAX_LIVE_BOXES // 2:  # memory: keep the parked boxes with the largest ub for
                    P = [np.concatenate(a) for a in zip(*parked)]  # the gap, retire the rest into done
                    order = np.argpartition(P[3], len(P[3]) - MAX_LIVE_BOXES // 4)
                    gone, kept = order[:len(P[3]) - MAX_LIVE_BOXES // 4], order[len(P[3]) - MAX_LIVE_BOXES // 4:]
                    done = max(done, float(P[3][gone].max()))
                    parked, n_parked = [tuple(a[kept] for a in P)], len(kept)
            if not len(ub):  # c > 0 proven: now the gap
                proving = False
                if parked:
                    lo, hi, face, ub, split = (np.concatenate(a) for a in zip(*parked))
                parked, parked_top, n_parked = [], -np.inf, 0
                continue
        if not len(ub):
            converged = True
            break
        if not proving and float(ub.max()) <= done:  # a box retired for memory now sets c_lower: splitting
            break  # the live ones cannot raise it (r = 6, k = -0.002: >= 2.2e6 of 18.4e6 boxes spent so)
        if time.process_time() > deadline or len(ub) > MAX_LIVE_BOXES or nbox > max_boxes:
            break
        if progress is not None:
            progress(best, max(float(ub.max()), done, parked_top), nbox)
        iteration += 1
        if iteration % 4 == 0:  # climb from the centres of the best boxes: a better witness prunes more
            order = np.argsort(ub)[-16:]
            cz = np.array([np.insert(0.5 * (lo[j] + hi[j]), face[j], 1.0) for j in order])
            cz = climb(obj, cz, rng, rounds=30, step0=0.05)
            lbs = obj.points(cz).lo
            j = int(np.nanargmax(lbs)) if np.isfinite(lbs).any() else -1
            if j >= 0 and lbs[j] > best:
                best, wit = float(lbs[j]), cz[j].copy()
        m = min(len(ub), max(256, min(SPLIT_BATCH, len(ub) // 2)))  # half: a few boxes far above the rest go deep fast
        if m < len(ub):
            if proving and len(ub) > MAX_LIVE_BOXES // 2:
                # phase 1 splits every box with ub >= 0 whatever the order, so the order only sets the
                # memory: near the cap, the boxes closest to ub < 0 first (their children get parked)
                pick = np.argpartition(ub, m)[:m]
            else:
                pick = np.argpartition(ub, len(ub) - m)[len(ub) - m:]
            rest = np.ones(len(ub), dtype=bool)
            rest[pick] = False
            keep = (lo[rest], hi[rest], face[rest], ub[rest], split[rest])
            lo, hi, face, split, ub = lo[pick], hi[pick], face[pick], split[pick], ub[pick]
        else:
            keep = None
        rows = np.arange(m)
        cut = 0.5 * (lo[rows, split] + hi[rows, split])
        hi1, lo2 = hi.copy(), lo.copy()
        hi1[rows, split] = cut
        lo2[rows, split] = cut
        lo, hi, face = np.concatenate([lo, lo2]), np.concatenate([hi1, hi]), np.concatenate([face, face])
        parent = np.concatenate([ub, ub])
        ub, split = evaluate(lo, hi, face)
        ub = np.minimum(ub, parent)  # a child lies in its parent: the parent's bound holds on it too
        if keep is not None:
            lo, hi, face = np.concatenate([keep[0], lo]), np.concatenate([keep[1], hi]), np.concatenate([keep[2], face])
            ub, split = np.concatenate([keep[3], ub]), np.concatenate([keep[4], split])
    top = max(float(ub.max()) if len(ub) else -np.inf, done, parked_top)
    return _Max(max(top, best), best, wit, nbox, converged)



def certify(hong: HongController, samples: int = DEFAULT_SAMPLES, seed: int = DEFAULT_SEED,
            region_radius: float = 1.0, budget: float | None = None, rtol: float = DEFAULT_RTOL,
            region_inner: float | None = None, progress=None, max_boxes: int = DEFAULT_MAX_BOXES) -> Certificate:
    """The certificate of ``hong`` (see the module docstring).

    samples, seed: the witness search before the B&B (seeded: deterministic). budget: CPU seconds
    (None: until the gap is within rtol or max_boxes boxes were evaluated), 90 % of it for c and
    the rest (at least 0.1 s) for c' when c > 0 is proven. progress: called as
    progress(text) now and then.
    Simplified form: check_region on the shell region_inner <= |z|_inf <= region_radius
    (region_inner defaults to region_radius / 100).
    """
    _check_int("samples", samples, 100, MAX_SAMPLES)
    _check_int("seed", seed, 0, 2 ** 63 - 1)
    if not (isinstance(rtol, float) and 1e-9 <= rtol <= 1.0):
        raise ParameterError("rtol", "a number in [1e-9, 1]", rtol)
    _check_int("max_boxes", max_boxes, 1, 10 ** 10)
    if budget is not None and not (np.isfinite(budget) and 0 < budget <= 86400):
        raise ParameterError("budget", "a number of seconds in (0, 86400]", budget)
    t0 = time.process_time()
    deadline = t0 + (budget if budget is not None else np.inf)
    rng = np.random.default_rng(seed)
    if hong.form == "simplified":
        inner = region_radius / 100.0 if region_inner is None else region_inner
        return check_region(hong, inner, region_radius, samples, seed, deadline, t0)
    terms = Terms(hong.r, hong.k, hong.gains)
    say = None
    if progress is not None:
        def say(best, top, n, what="c"):
            progress(f"{what}: bound {-top if what == 'c' else top:.6g} .. {-best if what == 'c' else best:.6g}"
                     f" after {n} boxes, {time.process_time() - t0:.1f} s")
    obj = Ratio(terms, "c")
    # a budget keeps a tenth for c' (Theorem 3 needs it once c > 0 is proven)
    deadline_c = deadline if budget is None else t0 + 0.9 * budget
    # the best zero-set state's guaranteed value is the B&B's witness value wherever it beats the
    # sampled one: dV1/dt >= 0 there refutes the gains at once, and otherwise the B&B retires the
    # boxes whose bound is within rtol of it. No sampled or climbed state reaches a layer that thin,
    # so with the sampled value as its threshold the B&B kept splitting the boxes whose bound lay
    # between the two, until its box cap (r = 4, k = -0.005, gains 1.009 .. 56.113: 3e6 boxes
    # against 18,928; tests/test_certificate_zero_sets.py)
    zero = _zero_set_witness(obj, seed)
    mc = _maximise(obj, _seed_points(obj, samples, rng), rtol, deadline_c, True, say, rng, max_boxes,
                   zero[0] if zero is not None else -np.inf)
    c_lower, c_upper = -mc.upper, -mc.lower
    on_zero_set = zero is not None and zero[0] >= mc.lower  # no better state found: the witness is the zero set's
    status = CERTIFIED if c_lower > 0 else NOT_CERTIFIED if c_upper <= 0 else UNDECIDED
    mp = None
    if status == CERTIFIED:  # c' only matters (Theorem 3) where the certificate holds
        objp = Ratio(terms, "cp")
        mp = _maximise(objp, _seed_points(objp, samples, rng), rtol, max(deadline, time.process_time() + 0.1), False,
                       None if say is None else (lambda b, t, n: say(b, t, n, "c'")), rng, max_boxes)
    k = hong.k
    with np.errstate(all="ignore"):
        zw = zero[1] if on_zero_set else np.array([float(x) for x in terms.z_of([float(x) for x in mc.witness])[0]])
        wit = _onto_unit_level(hong, zw[None, :])[0]
    note = {CERTIFIED: "k = 0: linear law, exponential (not finite-time) convergence" if k == 0 else "",
            NOT_CERTIFIED: "dV1/dt >= 0 at the witness state on {V1 = 1}: no finite-time certificate for these gains",
            UNDECIDED: "the budget ran out before the bounds separated: no certificate (raise --budget)"}[status]
    return Certificate(
        form="full", c=c_lower, alpha=(2.0 + 2.0 * k) / (2.0 + k), c_prime=mp.upper if mp else None,
        alpha_prime=1.0 - float(hong.p[hong.r - 1]) / (2.0 + k), certified=status == CERTIFIED,
        samples=samples, seed=seed, status=status, c_lower=c_lower, c_upper=c_upper,
        c_prime_upper=mp.upper if mp else None, c_prime_lower=mp.lower if mp else None,
        witness=tuple(float(x) for x in wit), boxes=mc.boxes + (mp.boxes if mp else 0), seconds=time.process_time() - t0, note=note,
        k=float(k))


def _check_int(name, val, lo, hi):
    if isinstance(val, bool) or not isinstance(val, (int, np.integer)) or not lo <= val <= hi:
        raise ParameterError(name, f"an integer in [{lo}, {hi}]", val)


# -- simplified form: a sound check on a bounded shell ----------------------------------------------

def check_region(hong: HongController, inner: float, outer: float, samples: int = DEFAULT_SAMPLES,
                 seed: int = DEFAULT_SEED, deadline: float = np.inf, t0: float | None = None) -> Certificate:
    """Prove dV1/dt < 0 on {inner <= |z|_inf <= outer} (any form's own V1; used for the simplified
    form) by bisecting the 2r slabs of the shell until every box has an upper bound < 0, or find a
    state with a guaranteed dV1/dt >= 0 (region_negative False), or stop at the deadline (None)."""
    t0 = time.process_time() if t0 is None else t0
    if not (np.isfinite(outer) and np.isfinite(inner) and 0 < inner < outer <= 1e6):
        raise ParameterError("region", "0 < inner < outer <= 1e6 (|z|_inf)", (inner, outer))
    r = hong.r
    terms = SimplifiedTerms(r, hong.k, hong.gains) if hong.form == "simplified" else Terms(r, hong.k, hong.gains)

    def dV(z):
        return terms.evaluate(z)[1]

    rng = np.random.default_rng(seed)
    z = rng.uniform(-outer, outer, size=(samples, r))
    with np.errstate(all="ignore"):
        f = dV([z[:, i] for i in range(r)])
    f = np.where(np.isfinite(f), f, -np.inf)
    lo, hi = [], []
    for j in range(r):
        for sgn in (-1.0, 1.0):
            a, b = np.full(r, -outer), np.full(r, outer)
            a[j], b[j] = (inner, outer) if sgn > 0 else (-outer, -inner)
            lo.append(a)
            hi.append(b)
    lo, hi = np.array(lo), np.array(hi)
    witness, wval, nbox, negative = None, None, 0, None
    while True:
        with np.errstate(all="ignore"):
            mid = 0.5 * (lo + hi)
            box = dV([Iv(lo[:, i], hi[:, i]) for i in range(r)])
            cen = dV([Iv(mid[:, i]) for i in range(r)])
        nbox += len(lo)
        ub = np.where(np.isnan(box.hi), np.inf, box.hi)
        clo = np.where(np.isnan(cen.lo), -np.inf, cen.lo)
        if (clo >= 0).any():
            j = int(np.argmax(clo))
            witness, wval, negative = mid[j], float(clo[j]), False
            break
        open_ = ub >= 0
        if not open_.any():
            negative = True
            break
        if time.process_time() > deadline or open_.sum() > MAX_LIVE_BOXES // 2:
            break
        lo, hi = lo[open_], hi[open_]
        m = min(len(lo), 8192)
        order = np.argsort(-ub[open_])[:m]
        rest = np.ones(len(lo), dtype=bool)
        rest[order] = False
        plo, phi = lo[order], hi[order]
        ax = np.argmax(phi - plo, axis=1)
        rows = np.arange(m)
        cut = 0.5 * (plo[rows, ax] + phi[rows, ax])
        lo1, hi1, lo2, hi2 = plo.copy(), phi.copy(), plo.copy(), phi.copy()
        hi1[rows, ax] = cut
        lo2[rows, ax] = cut
        lo, hi = np.concatenate([lo[rest], lo1, lo2]), np.concatenate([hi[rest], hi1, hi2])
    top = float(np.max(ub)) if negative is not False else wval
    verdict = {True: "dV1/dt < 0 proven on the whole shell",
               False: "dV1/dt >= 0 (guaranteed) at the witness state",
               None: "undecided within the budget"}[negative]
    return Certificate(
        form=hong.form, c=None, alpha=None, c_prime=None, alpha_prime=None, certified=False,
        samples=samples, seed=seed, status=UNDECIDED if negative is None else NOT_CERTIFIED,
        witness=None if witness is None else tuple(float(x) for x in witness), boxes=nbox,
        seconds=time.process_time() - t0, region_radius=outer, region_inner=inner,
        region_max_dV1dt=top, region_negative=negative,
        note=(f"{hong.form} form: V1 = sum (z_j - v_{{j-1}})^2/2 is not homogeneous, so this is a check on the shell "
              f"{inner:g} <= |z|_inf <= {outer:g} only, not a global certificate: {verdict}"),
    )


@dataclass(frozen=True)
class Theorem3Bounds:
    """Theorem 3's constants for the adaptive law, computed with the TRUE phibar and gamma_m: each a
    guaranteed upper bound of the paper's formula (theorem3_bounds); inf where none is finite."""

    Phibar: float
    Delta: float  # limsup V1 <= Delta
    phi_hat_limsup: float  # limsup phi_hat <= 2 Phibar + rate Delta^(1-alpha) / (c (1-alpha)); inf at k = 0


def theorem3_bounds(cert: Certificate, phibar: float, gamma_m: float, kappa: float, delta: float,
                    rate: float, eps: float) -> Theorem3Bounds:
    """Theorem 3 of Harmouche, Laghrouche and Chitour (section 4, the adaptive controller), with the
    true bounds phibar >= |phi|, gamma_m <= gamma of the plant and the law's kappa, delta, rate (the
    paper's adaptation gain k) and eps. Needs a certified full-form certificate.

    Above V1 = eps the estimate phi_hat grows at the rate; until it passes Phibar, dV1/dt <= -c V1^alpha
    + gamma_m c' V1^alpha' (Phibar - phi_hat), and Delta bounds the overshoot of V1 this allows; the
    limsup of phi_hat adds to 2 Phibar its growth during the time from V1 = Delta to 0. The paper's
    constants:

        Phibar = (phibar + (kappa gamma_m - 1)^2 / (4 gamma_m delta)) / gamma_m
        Delta  = (eps^(1-alpha') + c' (1-alpha') gamma_m Phibar^2 / (2 rate))^(1/(1-alpha'))
        limsup V1 <= Delta,  liminf V1 <= eps,
        limsup phi_hat <= 2 Phibar + rate Delta^(1-alpha) / (c (1-alpha))

    with alpha = (2 + 2k)/(2 + k), alpha' = 1 - p_r/(2 + k), p_r = 1 + (r - 1) k (k the homogeneity
    degree); the last term is rate times the time the certificate gives from V1 = Delta to 0
    (Certificate.time_bound), infinite at k = 0 (alpha = 1: exponential decay, no end).

    Guaranteed: Delta grows with c' and the limsup falls with c, so with c = c_lower and c' =
    c_prime_upper they bound the constants of the true c, c' from above; and each is computed in
    outward-rounded intervals (interval.Iv; 1 - alpha, 1 - alpha' and 1/(1 - alpha') enclosed from the
    exact rational k, the last as its integer part and the rest: _pow_rational), so the number returned is never below the formula's exact value at those
    constants and above it by at most 3e-13 relative (tests/test_control_certificate.py, against mpmath
    at 60 digits; the plain float formula was below it in about half of those cases).
    All three are upper bounds (Theorem 3 has no lower one); an enclosure beyond the largest float
    gives inf, an honest "no finite bound".
    """
    if not cert.certified:
        raise ParameterError("certificate", "a full-form certificate with c > 0", cert.c)
    for name, val in (("phibar", phibar), ("gamma_m", gamma_m), ("kappa", kappa), ("delta", delta),
                      ("rate", rate), ("eps", eps)):
        if not (np.isfinite(val) and (val > 0 or (name == "phibar" and val == 0))):
            raise ParameterError(name, "a finite number > 0" + (" (or 0)" if name == "phibar" else ""), val)
    F = Fraction(float(cert.k))
    p_r = 1 + (len(cert.witness) - 1) * F  # the witness is a state of the chain: r values
    one_m_ap = exp_of(p_r / (2 + F))  # 1 - alpha'
    phibar, gamma_m, kappa, delta, rate, eps = (Iv(float(x)) for x in (phibar, gamma_m, kappa, delta, rate, eps))
    with np.errstate(all="ignore"):
        Phibar = (phibar + (kappa * gamma_m - 1.0).sq() / (4.0 * gamma_m * delta)) / gamma_m
        Delta = (eps.pabs(one_m_ap) + Iv(float(cert.c_prime_upper)) * one_m_ap.iv() * gamma_m * Phibar.sq()
                 / (2.0 * rate))
        Delta = _pow_rational(Delta, (2 + F) / p_r)
        # At k = 0 (alpha = 1) V1 decays exponentially, never reaching 0 in finite time: the proof's
        # last phase has no end, so the bound on phi_hat is infinite.
        limsup = 2.0 * Phibar + rate * cert._time_to_zero(Delta) if cert.alpha < 1.0 else None

    def bound(x):  # the upper end; NaN cannot occur in an Iv, inf is "no finite bound"
        return float("inf") if x is None or not np.isfinite(x.hi) else float(x.hi)

    return Theorem3Bounds(Phibar=bound(Phibar), Delta=bound(Delta), phi_hat_limsup=bound(limsup))


def _pow_rational(x: Iv, q: Fraction) -> Iv:
    """|x|^q for a rational q >= 0, as |x|^n |x|^(q - n), n = floor(q): the integer exponent is exact and
    the rest is enclosed to an ulp of a number < 1, where Iv.pabs of the float interval around q
    would widen by 746 ulps of q relative (up to 1.3e-12 at Delta's q = 1/(1 - alpha') ~ 11)."""
    n = q.numerator // q.denominator
    return x.pabs(Exp(float(n))) * x.pabs(exp_of(q - n))
