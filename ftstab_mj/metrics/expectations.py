"""Pinned metrics with tolerances (``ftstab check LOG.mcap --expect EXPECT.toml``).

An expectation file mirrors the metrics dict (``ftstab replay LOG.mcap --json``): tables and
keys are metric names, and each leaf is either an exact value (string, boolean, integer, float,
or a list of them) or a table with these keys::

    value = X, atol = A, rtol = R     |got - X| <= A + R |X|   (element-wise for lists; A, R default 0)
    min = A  /  max = B               A <= got  /  got <= B  (may be combined with value)
    null = true                       the metric is undefined (JSON null: e.g. never settled)

Example::

    status = "completed"
    [loops.cart]
    settle_time = { value = 1.234, atol = 0.002 }   # s, two control periods
    final_abs_z_max = { max = [1e-3, 2e-2] }
    theorem3 = { Delta_held = true }
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

from ftstab_mj.config import keypath
from ftstab_mj.control.certificate import DEFAULT_RTOL
from ftstab_mj.control.law import declared
from ftstab_mj.config.errors import ScenarioError, describe
from ftstab_mj.config.tomlfile import dumps, read_toml
from ftstab_mj.config.validate import Reader, non_negative


class ExpectationError(ScenarioError):
    """An expectation file is malformed or names a metric the log does not have (exit 2, one line)."""


@dataclass(frozen=True)
class Spec:
    """The table of one metric's expectation (read by the configuration layer, ftstab_mj.config.validate):
    value, min, max a number or an array of numbers (one per element of the metric), atol and rtol
    numbers >= 0, null = true alone."""

    value: float | tuple[float, ...] | None = None
    atol: float = field(default=0.0, metadata={"check": non_negative})
    rtol: float = field(default=0.0, metadata={"check": non_negative})
    min: float | tuple[float, ...] | None = None
    max: float | tuple[float, ...] | None = None
    null: bool | None = None


SPEC_KEYS = tuple(f.name for f in fields(Spec))


@dataclass(frozen=True)
class Outcome:
    """One expectation checked: its key path, whether it holds, and a readable line."""

    path: str
    ok: bool
    line: str


def load_expectations(path) -> dict:
    """Parse an expectation file (TOML). Raises ExpectationError naming the file on bad syntax."""
    return read_toml(path, "expectation file (.toml)", ExpectationError)


def _is_number(x) -> bool:
    return isinstance(x, (int, float)) and not isinstance(x, bool)


def _fmt(x) -> str:
    if x is None:
        return "null"
    if isinstance(x, list):
        return "[" + ", ".join(_fmt(v) for v in x) + "]"
    if isinstance(x, float):
        return f"{x:.10g}"
    return repr(x) if isinstance(x, str) else str(x).lower() if isinstance(x, bool) else str(x)


def _check_spec(reader: Reader, path: str, raw: dict, got) -> Outcome:
    """The metric ``got`` against the expectation table ``raw`` at ``path`` (ExpectationError
    through ``reader`` when the table is malformed or does not fit the metric)."""
    spec = Spec(**reader.fields_of(Spec, raw, path))
    if spec.null is not None:
        if spec.null is not True or len(raw) > 1:
            raise reader.error(keypath.join(path, "null"), "null = true alone", describe(raw))
        return Outcome(path, got is None, f"{path}: expected null, got {_fmt(got)}")
    if spec.value is None and spec.min is None and spec.max is None:
        raise reader.error(path, "a table with value, min or max", describe(raw))
    g = got if isinstance(got, list) else [got]
    if any(v is not None and not _is_number(v) for v in g):
        raise reader.error(path, "a numeric metric for value/min/max", f"the metric is {_fmt(got)}")
    problems, wanted = [], []
    for key in ("value", "min", "max"):
        if key not in raw:
            continue
        ref = getattr(spec, key)
        ref = list(ref) if isinstance(ref, tuple) else [ref]
        if len(ref) == 1 and len(g) > 1:
            ref = ref * len(g)
        if len(ref) != len(g):
            problems.append(f"{len(g)} values where {key} has {len(ref)}")
            continue
        if key == "value":
            tol = "".join(f" {n} {v:g}" for n, v in (("atol", spec.atol), ("rtol", spec.rtol)) if v)
            wanted.append(f"{_fmt(raw[key])}" + (f" ({tol.strip()})" if tol else ""))
        else:
            wanted.append(f"{key} {_fmt(raw[key])}")
        for i, (x, r) in enumerate(zip(g, ref)):
            where = f"[{i}]" if len(g) > 1 else ""
            allowed = spec.atol + spec.rtol * abs(r)
            if x is None or not math.isfinite(x):
                problems.append(f"{where} is {_fmt(x)}".strip())
            elif key == "value" and abs(x - r) > allowed:
                problems.append(f"{where} off by {x - r:+.3g} (allowed {allowed:.3g})".strip())
            elif key == "min" and x < r:
                problems.append(f"{where} below min by {r - x:.3g}".strip())
            elif key == "max" and x > r:
                problems.append(f"{where} above max by {x - r:.3g}".strip())
    line = f"{path}: expected {', '.join(wanted)}, got {_fmt(got)}" + (f": {'; '.join(problems)}" if problems else "")
    return Outcome(path, not problems, line)


def check_metrics(metrics: dict, expected: dict, source: str = "<expectations>") -> list[Outcome]:
    """Compare ``metrics`` (compute_metrics' dict) with an expectation tree; one Outcome per leaf.

    Raises ExpectationError (naming ``source`` and the key path) for a malformed expectation or a
    metric the log does not have.
    """
    out: list[Outcome] = []
    reader = Reader(source, error_cls=ExpectationError)

    def walk(exp, got, path):
        for key, want in exp.items():
            p = keypath.join(path, key)
            if not isinstance(got, dict) or key not in got:
                have = ", ".join(sorted(got)) if isinstance(got, dict) else "a value, not a table"
                raise reader.error(p, f"a metric of the log ({have})", "no such metric")
            value = got[key]
            if isinstance(want, dict) and isinstance(value, dict):
                walk(want, value, p)
            elif isinstance(want, dict):
                out.append(_check_spec(reader, p, want, value))
            else:
                same = (type(want) is type(value) or (_is_number(want) and _is_number(value))) and want == value
                out.append(Outcome(p, same, f"{p}: expected {_fmt(want)}, got {_fmt(value)}"))

    walk(expected, metrics, "")
    return out


# -- pinning: an expectation file from a log, with tolerances from the maths and the step ---------

CHATTER_RTOL = 0.25  # amplitudes of the chattering band (final accuracy, chattering, V1 max after entry)
TIMING_PERIODS = 2  # settling / entry times: one period of metric resolution + one of sample phase
INTEGRAL_RTOL = 1e-3  # effort integrals (dominated by the smooth transient)
CLOSED_FORM_RTOL = 1e-9  # closed-form values (V1 of z0) and exact copies
CERTIFICATE_RTOL = 1e-6  # other seeded estimates (u_needed) and Theorem 3's Phibar (no certificate in it)
# The certificate is pinned by what the branch and bound guarantees, not by its bits: every sound run
# gives c_lower <= c <= c_upper, and a converged one (c_upper - c_lower <= GAP_RTOL c_upper, the
# stopping gap of ftstab_mj/control/certificate.py) has both ends within GAP_RTOL of c. So a new run's
# bracket must overlap the pinned one (c_lower <= pinned c_upper, c_upper >= pinned c_lower: both hold c),
# and where the pinned one converged, c_lower >= (1 - GAP_RTOL) pinned c_lower and c_upper <= pinned
# c_upper / (1 - GAP_RTOL). c' likewise (its gap: c'_upper <= (1 + GAP_RTOL) c'_lower). What derives
# from them (T(z0) ~ 1 / c_lower; Theorem 3's Delta, increasing in c', and phi_hat_limsup) gets the range
# those brackets allow, widened by ROUNDING_RTOL for the float formulas around them.
GAP_RTOL = DEFAULT_RTOL  # the B&B's stopping gap: the pins follow it if it changes
ROUNDING_RTOL = 1e-9


def _tol(value, **tol):
    """A spec, or null = true when the value is undefined."""
    if value is None:
        return {"null": True}
    return {"value": value, **{k: v for k, v in tol.items() if v}}


def pin_loop(m: dict, period: float, rate: float | None, hong: dict | None = None) -> dict:
    """Expectations for one loop's metrics (see :data:`TIMING_PERIODS` and the other constants);
    hong: the loop's Hong controller (LoopInfo.hong: r, k, ...), for Theorem 3's exponents.

    phi_hat (adaptive, rate = the adaptation rate): grows at most at ``rate`` per second, so a timing
    shift of TIMING_PERIODS periods moves it by at most TIMING_PERIODS * period * rate.
    """
    if not m["n_samples"]:  # a run that failed before its first sample has no other metric
        return {"law": m["law"], "n_samples": 0}
    dt = TIMING_PERIODS * period
    out = {
        "law": m["law"], "n_samples": m["n_samples"], "z0": m["z0"],
        "V1_initial": _tol(m["V1_initial"], rtol=CLOSED_FORM_RTOL),
        "settle_time": _tol(m["settle_time"], atol=dt),
        "time_bound": _tol(m["time_bound"], rtol=CERTIFICATE_RTOL),  # replaced below from the certificate's bracket
        "bound_applies": m["bound_applies"],
        "final_abs_z_max": _tol(m["final_abs_z_max"], rtol=CHATTER_RTOL, atol=1e-12),
        "chattering": _tol(m["chattering"], rtol=CHATTER_RTOL, atol=1e-12),
        "effort_abs": _tol(m["effort_abs"], rtol=INTEGRAL_RTOL),
        "effort_sq": _tol(m["effort_sq"], rtol=INTEGRAL_RTOL),
        "u_max_abs": _tol(m["u_max_abs"], rtol=INTEGRAL_RTOL),
        "eps_entry_time": _tol(m["eps_entry_time"], atol=dt),
        "V1_max_after_entry": _tol(m["V1_max_after_entry"], rtol=CHATTER_RTOL, atol=1e-12),
    }
    if m["beat_bound"] is not None:
        out["beat_bound"] = m["beat_bound"]
    if rate is None:  # phi_hat is a constant of the law
        out["phi_hat_max"] = _tol(m["phi_hat_max"], rtol=CLOSED_FORM_RTOL)
    else:
        out["phi_hat_max"] = _tol(m["phi_hat_max"], atol=dt * rate, rtol=CLOSED_FORM_RTOL)
        out["phi_hat_final"] = _tol(m["phi_hat_final"], atol=dt * rate, rtol=CLOSED_FORM_RTOL)
    if "u_needed" in m:  # a loop with sensor, observer or actuator stages (metrics.stage_reasons)
        out["u_needed"] = _tol(m["u_needed"], rtol=CERTIFICATE_RTOL)  # a seeded sampled sup, like c
        out["estimation_error_max"] = _tol(m["estimation_error_max"], rtol=CHATTER_RTOL, atol=1e-12)
        out["time_saturated"] = _tol(m["time_saturated"], atol=dt)
    cert = m.get("certificate")
    if cert:
        c, cp = _bracket(cert["c_lower"], cert["c_upper"], 1.0 / (1.0 - GAP_RTOL)), _bracket(
            cert.get("c_prime_lower"), cert["c_prime_upper"], 1.0 + GAP_RTOL)
        out["certificate"] = {"status": cert["status"], **_bracket_pins("c", c, cert["status"])}
        if cp is not None:
            out["certificate"].update(_bracket_pins("c_prime", cp, None))
        if m["time_bound"] is not None and c is not None:  # T ~ 1 / c_lower
            out["time_bound"] = _range(m["time_bound"], 1.0 / c.up_lower, 1.0 / c.down_lower if c.down_lower else math.inf)
        th = m.get("theorem3")
        if th and c is not None and cp is not None and hong is not None:
            out["theorem3"] = _theorem3_pins(th, c, cp, hong)
        elif th:
            out["theorem3"] = {key: th[key] for key in ("Delta_held", "phi_hat_bound_held", "eps_reached")}
    return out


@dataclass(frozen=True)
class _Bracket:
    """A pinned bracket [lo, hi] of a certificate constant and the factors by which a new run's ends
    may differ from it (see GAP_RTOL): lower end in [lo down_lower, hi], upper end in [lo, hi up_upper]
    (down_lower = 0 and up_upper = inf when the pinned run did not converge: only the overlap is due)."""

    lo: float
    hi: float
    down_lower: float  # new lower end >= lo * down_lower
    up_lower: float  # new lower end <= lo * up_lower (= hi / lo)
    up_upper: float  # new upper end <= hi * up_upper


def _bracket(lo, hi, gap_factor: float):
    """The bracket of a constant with ends lo <= hi (None: not known, e.g. c_lower = -inf), converged
    when hi <= gap_factor lo (c: 1 / (1 - GAP_RTOL); c': 1 + GAP_RTOL)."""
    if lo is None or hi is None or not 0 < lo <= hi:
        return None
    done = hi <= gap_factor * lo
    return _Bracket(lo, hi, 1.0 / gap_factor if done else 0.0, hi / lo, gap_factor if done else math.inf)


def _bracket_pins(name: str, b, status) -> dict:
    """{name_lower: spec, name_upper: spec} for the bracket b; without one, a not-certified c has
    c_upper <= 0 (a witness with dV1/dt >= 0: what "not certified" means) and nothing else is due."""
    if b is None:
        return {f"{name}_upper": {"max": 0.0}} if status == "not certified" else {}
    lower = {"min": _out(b.lo * b.down_lower, -1)} if b.down_lower else {}
    lower["max"] = _out(b.hi, +1)
    upper = {"min": _out(b.lo, -1)}
    if math.isfinite(b.up_upper):
        upper["max"] = _out(b.hi * b.up_upper, +1)
    return {f"{name}_lower": lower, f"{name}_upper": upper}


def _out(x: float, direction: int) -> float:
    """x moved outward by ROUNDING_RTOL (direction +1: up, -1: down)."""
    return x * (1.0 + direction * ROUNDING_RTOL) if x >= 0 else x * (1.0 - direction * ROUNDING_RTOL)


def _range(x: float, lo_factor: float, hi_factor: float) -> dict:
    """{min, max} for a metric pinned at x that may move by a factor in [lo_factor, hi_factor]."""
    out = {"min": _out(x * lo_factor, -1)}
    if math.isfinite(hi_factor):
        out["max"] = _out(x * hi_factor, +1)
    return out


def _theorem3_pins(th: dict, c: _Bracket, cp: _Bracket, hong: dict) -> dict:
    """Theorem 3's constants (metrics.theorem3_check) for the brackets of c and c'. Delta =
    (eps^(1-a') + c' K)^q with q = 1/(1 - a') and K > 0: a factor lam on c' moves Delta by a factor
    between 1 and lam^q. phi_hat_limsup = 2 Phibar + G with G = rate Delta^(1-a) / (c_lower (1-a)).
    a = (2 + 2k)/(2 + k), 1 - a' = p_r / (2 + k), p_r = 1 + (r - 1) k (ftstab_mj/control/certificate.py)."""
    r, k = int(hong["r"]), float(hong["k"])
    one_m_a, q = -k / (2.0 + k), (2.0 + k) / (1.0 + (r - 1) * k)
    cp_lo, cp_hi = cp.lo / cp.hi, cp.up_upper  # the new c'_upper over the pinned one
    out = {"Phibar": _tol(th["Phibar"], rtol=CERTIFICATE_RTOL)}
    if th["Delta"] is None:
        out["Delta"] = {"null": True}
    else:
        out["Delta"] = _range(th["Delta"], cp_lo ** q, cp_hi ** q)
    L, Phibar = th["phi_hat_limsup"], th["Phibar"]
    if L is None or th["Delta"] is None or one_m_a == 0.0:
        out["phi_hat_limsup"] = _tol(L, rtol=CERTIFICATE_RTOL)
    else:
        G = L - 2.0 * Phibar
        g = _range(G, cp_lo ** (q * one_m_a) / c.up_lower,
                   cp_hi ** (q * one_m_a) / c.down_lower if c.down_lower else math.inf)
        out["phi_hat_limsup"] = {key: 2.0 * Phibar + v for key, v in g.items()}
    out.update({key: th[key] for key in ("Delta_held", "phi_hat_bound_held", "eps_reached")})
    return out


def _adaptation_rate(lp) -> float | None:
    """The rate of phi_hat of a law with Theorem 3's ultimate bounds (it sets phi_hat's tolerance), else None."""
    law = declared(lp.law)
    ultimate = law.ultimate_bound(lp.law_params) if law is not None else None
    return ultimate["rate"] if ultimate else None


def pin_expectations(metrics: dict, info) -> dict:
    """An expectation tree for ``metrics`` of the run described by ``info`` (records.RunInfo)."""
    rates = {lp.name: (_adaptation_rate(lp)) for lp in info.loops}
    hongs = {lp.name: lp.hong for lp in info.loops}
    return {"status": metrics["status"], "n_samples": metrics["n_samples"],
            "loops": {name: pin_loop(m, info.period, rates[name], hongs[name]) for name, m in metrics["loops"].items()}}


def to_toml(tree: dict, header: str = "") -> str:
    """TOML text of an expectation tree: scalars and specs inline, metric groups as tables."""
    return dumps(tree, header, inline=lambda table: set(table) <= set(SPEC_KEYS))


PIN_HEADER = f"""Pinned metrics (ftstab check LOG.mcap --expect THIS_FILE). Tolerances (ftstab_mj/metrics/expectations.py):
times (settle_time, eps_entry_time): +- {TIMING_PERIODS} control periods (metric resolution + sample phase);
phi_hat: +- {TIMING_PERIODS} periods x the adaptation rate; V1(z0): rtol {CLOSED_FORM_RTOL:g};
effort integrals and max |u|: rtol {INTEGRAL_RTOL:g}; chattering-band amplitudes: rtol {CHATTER_RTOL:g}.
The certificate: what the branch and bound guarantees, not its bits. c_lower <= c <= c_upper in every
sound run, so a new bracket overlaps the pinned one (c_lower <= pinned c_upper, c_upper >= pinned c_lower);
where the pinned run converged (gap c_upper - c_lower <= {GAP_RTOL:g} c_upper, the B&B's stopping gap),
c_lower >= (1 - {GAP_RTOL:g}) pinned c_lower and c_upper <= pinned c_upper / (1 - {GAP_RTOL:g}); c' alike
(its gap: c'_upper <= (1 + {GAP_RTOL:g}) c'_lower). time_bound ~ 1/c_lower and Theorem 3's Delta and
phi_hat_limsup get the range these brackets allow; every range is widened by {ROUNDING_RTOL:g} relative."""
