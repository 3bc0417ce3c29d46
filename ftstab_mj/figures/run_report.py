"""``ftstab report``: the figures a paper needs from one run, read from its log (PNG, or one self-contained HTML page).

One column of panels per control loop (the arm: one per joint), time t (s) on every x axis:

- ``z1`` .. ``zr``: one panel per component of the chain state, in its unit: with P the loop's
  position unit (m for the carts and slide joints, rad for hinge joints), z_i is in P/s^(i-1);
  with a sensor or observer model the estimate z_hat the law saw is drawn too;
- ``u``: the law's output u, Hong's nominal control u0 and, with an actuator model, the u_applied
  the plant received. Every sample is drawn (no averaging), so a chattering u shows as the band it
  sweeps;
- ``V1`` on a log axis with the settle level of the metrics and, for the nominal and robust laws
  with a sound certificate (c = c_lower > 0), Theorem 1's envelope: from dV1/dt <= -c V1^alpha the
  comparison lemma gives V1(t)^(1-alpha) <= V1(0)^(1-alpha) - c (1-alpha) t, that is
  V1(t) <= (V1(0)^(1-alpha) - c (1-alpha) t)^(1/(1-alpha)) until T(z0) = V1(0)^(1-alpha) / (c (1-alpha)),
  marked by a vertical line. The sampled loop settles into a band of size O(h) (h the control
  period) instead of the origin, so its V1 may cross the envelope once it is that small. The envelope
  is a guarantee only where the run's true bounds are
  within the law's assumed ones (the metrics' ``bound_applies``); otherwise its label says
  "not a guarantee". For the adaptive law (Theorem 3, with the true bounds of the run): the
  ultimate bound limsup V1 <= Delta and the level eps that V1 returns below (liminf V1 <= eps);
- ``phi_hat`` and ``gamma_hat`` (in u's unit, and u per unit of u0) when they vary during the
  run (the adaptive law; the robust law's are constants), phi_hat with Theorem 3's bound
  limsup phi_hat <= 2 Phibar + rate Delta^(1-alpha) / (c (1-alpha)) where it is finite.

:func:`report_data` returns what is drawn (curves of the log's own arrays, envelopes, bounds) and
:func:`draw` the matplotlib Figure built from it (object API on the Agg canvas: no pyplot, no global
state, no display), so the plotted data can be checked against the log without comparing pixels.
"""

from __future__ import annotations

import base64
import errno
import html
import io
import os
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field

from pathlib import Path

import numpy as np

from ftstab_mj.config.errors import FtstabError, LogWriteError
from ftstab_mj.control.law import declared
from ftstab_mj.logs.reader import LogData

FORMATS = (".png", ".html")
PANEL_W, PANEL_H, DPI = 4.6, 1.9, 150  # inches per panel, dots per inch of the PNG


class ReportError(FtstabError, ValueError):
    """A report that cannot be drawn or written (bad --out, a log without samples): one line."""


@dataclass(frozen=True)
class Curve:
    """One thing drawn in a panel. kind "line": y (n,) against x (n,) (s); "hline": the level y[0]
    across the panel; "vline": a vertical line at x[0] (s)."""

    label: str
    x: np.ndarray
    y: np.ndarray
    kind: str = "line"
    style: str = "-"
    color: str | None = None


@dataclass(frozen=True)
class Panel:
    name: str  # "z1".."zr", "u", "V1", "phi_hat", "gamma_hat"
    ylabel: str
    curves: tuple[Curve, ...]
    log: bool = False  # log y axis


@dataclass(frozen=True)
class ReportData:
    title: str
    loops: dict = field(default_factory=dict)  # loop name -> tuple[Panel, ...]
    notes: tuple[str, ...] = ()  # one line each, printed under the figure (HTML) and by the CLI


def _per_s(unit: str, n: int) -> str:
    """unit / s^n as a matplotlib label ('m', 'm/s', 'm/s$^2$')."""
    return unit if n == 0 else f"{unit}/s" if n == 1 else f"{unit}/s$^{{{n}}}$"


def _joint_type(model_xml: str | None, joint: str) -> str | None:
    """'hinge' or 'slide' for the named joint of an MJCF text (None when it cannot be told)."""
    if not model_xml:
        return None
    try:
        root = ET.fromstring(model_xml)
    except ET.ParseError:
        return None
    defaults_type = any(d.get("type") for d in root.iter("default") for d in d.iter("joint"))
    for j in root.iter("joint"):
        if j.get("name") == joint:
            if j.get("type"):
                return j.get("type")
            # a class default may set the type: not worth resolving MJCF's class inheritance
            return None if defaults_type else "hinge"  # MJCF's default joint type
    return None


def loop_units(data: LogData, name: str, r: int) -> tuple[str | None, str | None]:
    """(position unit P, unit of u) of loop ``name``; None where the log does not tell.

    The carts: P = m and x^(r) = phi + gamma u with gamma a dimensionless gain factor, so u is in
    m/s^r; the arms: P = rad, u is the motor torque (N m; integrating motors: its rate, N m/s);
    a user model: P from the loop's joint type, u in the actuator's own control units."""
    plant = data.info.scenario.get("plant")
    model = plant.get("model") if isinstance(plant, dict) else None
    if model in ("cart", "cart_integrating"):
        return "m", _per_s("m", r)
    if model in ("arm", "arm3"):
        return "rad", "N m"
    if model == "arm_integrating":
        return "rad", "N m/s"
    if isinstance(model, str) and model.endswith(".xml"):
        loops = plant.get("loops") if isinstance(plant.get("loops"), dict) else {}
        joint = loops.get(name, {}).get("joint") if isinstance(loops.get(name), dict) else None
        kind = _joint_type(data.info.model_xml, joint) if isinstance(joint, str) else None
        return {"hinge": "rad", "slide": "m"}.get(kind), "actuator ctrl units"
    return None, None


def _unit(text: str | None) -> str:
    return f" ({text})" if text else " (chain units)"


def _varies(a: np.ndarray) -> bool:
    a = a[np.isfinite(a)]
    return len(a) > 1 and bool(np.ptp(a) > 0)


def _v1_panel(lp, m: dict, a: dict, t: np.ndarray, settle_level: float) -> Panel | None:
    """log V1 with the settle level, Theorem 1's envelope and T(z0), or Theorem 3's Delta and eps."""
    from ftstab_mj.metrics.run_metrics import envelope, envelope_kind, loop_certificate, v1_label

    V1 = a["V1"]
    if not np.isfinite(V1).any():
        return None  # a law without a Lyapunov function (Levant's, super-twisting) logs V1 as NaN
    t0, t_end = float(t[0]), float(t[-1])
    curves = [Curve(v1_label(lp), t, V1, color="C0"),
              Curve(f"settle level {settle_level:g}", np.empty(0), np.array([settle_level]), "hline", ":", "0.4")]
    law = declared(lp.law)
    if law is not None and law.time_bound and m.get("time_bound") is not None:
        et, bound, T = envelope(loop_certificate(lp), float(V1[0]), t_end - t0, T=m["time_bound"])
        kind = envelope_kind(m)
        after = "" if t0 + T <= t_end else ", after the end of the run"
        curves.append(Curve(f"Theorem 1 envelope ({kind})", t0 + et, bound, style="--", color="C4"))
        curves.append(Curve(f"T(z0) = {T:.4g} s{after}", np.array([t0 + T]), np.empty(0), "vline", "-.", "C3"))
    th = m.get("theorem3")
    if th and th["Delta"] is not None:
        curves.append(Curve(f"Theorem 3: limsup V1 <= Delta = {th['Delta']:.3g}", np.empty(0), np.array([th["Delta"]]),
                            "hline", "--", "C4"))
        eps = lp.law_params["eps"]
        curves.append(Curve(f"eps = {eps:g} (liminf V1 <= eps)", np.empty(0), np.array([eps]), "hline", "-.", "C2"))
    return Panel("V1", "V1 (chain units, log)", tuple(curves), log=True)


def _loop_panels(data: LogData, lp) -> tuple[Panel, ...]:
    from ftstab_mj.metrics.run_metrics import loop_metrics

    a = data.loops[lp.name]
    m = loop_metrics(data.info, lp, a)  # what replay recomputes: bound_applies, time_bound, theorem3
    t = a["t"]
    pos, u_unit = loop_units(data, lp.name, lp.r)
    panels = []
    z, z_hat = a["z"], a.get("z_hat")
    ref_info = getattr(lp, "reference", None)
    if ref_info:  # a tracked reference: q with ref(t) (z_1 = q - ref)
        from ftstab_mj.plants.reference import Reference

        ref = Reference(**{k: tuple(v) if isinstance(v, list) else v for k, v in ref_info.items() if k != "max_abs"})
        r_t = ref.derivatives(t, 0)[:, 0]
        panels.append(Panel("q", f"q and its reference{_unit(pos)}", (
            Curve("q", t, z[:, 0] + r_t, color="C0"), Curve(f"ref ({ref.kind})", t, r_t, style="--", color="k"))))
    for i in range(z.shape[1]):
        unit = _per_s(pos, i) if pos else None
        curves = [Curve(f"z{i + 1}", t, z[:, i], color="C0")]
        if z_hat is not None and z_hat.shape[1] > i:
            curves.append(Curve(f"z{i + 1} estimate (what the law saw)", t, z_hat[:, i], style="--", color="C1"))
        panels.append(Panel(f"z{i + 1}", f"z{i + 1}{_unit(unit)}", tuple(curves)))
    controls = [Curve("u", t, a["u"], color="C3")]
    if np.isfinite(a["u0"]).any():
        controls.append(Curve("u0 (nominal)", t, a["u0"], color="k"))
    if "u_applied" in a and not np.array_equal(a["u_applied"], a["u"], equal_nan=True):  # (else it hides u)
        controls.append(Curve("u applied (after the actuator)", t, a["u_applied"], color="C2"))
    panels.append(Panel("u", f"u{_unit(u_unit)}", tuple(controls)))
    v1 = _v1_panel(lp, m, a, t, data.info.metric_settings.settle_level)
    if v1 is not None:
        panels.append(v1)
    if _varies(a["phi_hat"]):
        curves = [Curve("phi_hat", t, a["phi_hat"], color="C4")]
        th = m.get("theorem3")
        if th and th["phi_hat_limsup"] is not None:  # None: infinite (k = 0), no bound to draw
            curves.append(Curve(f"Theorem 3: limsup phi_hat <= {th['phi_hat_limsup']:.3g}", np.empty(0),
                                np.array([th["phi_hat_limsup"]]), "hline", "--", "C3"))
        panels.append(Panel("phi_hat", f"phi_hat{_unit(u_unit)}", tuple(curves)))
    if _varies(a["gamma_hat"]):
        chain = _per_s(pos, lp.r) if pos else None
        unit = "dimensionless" if u_unit == chain and u_unit else f"{u_unit} per {chain}" if u_unit and chain else None
        panels.append(Panel("gamma_hat", f"gamma_hat{_unit(unit)}", (Curve("gamma_hat", t, a["gamma_hat"], color="C9"),)))
    return tuple(panels)


def report_data(data: LogData) -> ReportData:
    """What the report draws for the run in ``data`` (a log read by logs.reader.read_log)."""
    if data.n_samples == 0:
        run = f"run {data.recorded['status']}: {data.recorded.get('message') or 'no message'}" if data.recorded \
            else "the run did not finish writing it"
        raise ReportError(f"{data.path}: the log has no samples ({run}): nothing to draw")
    sc = data.info.scenario
    laws = ", ".join(f"{lp.name}: {lp.law}" for lp in data.info.loops) if len(data.info.loops) > 1 \
        else f"{data.info.loops[0].law} law"
    plant = sc.get("plant", {}).get("model") if isinstance(sc.get("plant"), dict) else None
    status = data.recorded["status"] if data.recorded else "truncated log"
    if isinstance(plant, str) and plant.endswith(".xml"):  # a user model: its file name, not its path
        plant = Path(plant).name
    title = (f"{sc.get('name', '?')}: {laws}\n" + (f"plant {plant}, " if plant else "")
             + f"control period {data.info.period * 1e3:g} ms, {status}")
    loops = {lp.name: _loop_panels(data, lp) for lp in data.info.loops}
    return ReportData(title, loops, (data.warning,) if data.warning else ())


def draw(rep: ReportData):
    """The matplotlib Figure of ``rep``: one column per loop, its panels stacked, x shared per column."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    cols, rows = len(rep.loops), max(len(p) for p in rep.loops.values())
    fig = Figure(figsize=(PANEL_W * cols, PANEL_H * rows + 0.6), dpi=DPI, layout="constrained")
    FigureCanvasAgg(fig)
    axes = fig.subplots(rows, cols, squeeze=False, sharex="col")
    for c, (name, panels) in enumerate(rep.loops.items()):
        for r in range(rows):
            ax = axes[r][c]
            if r >= len(panels):
                ax.set_visible(False)
                continue
            p = panels[r]
            for cv in p.curves:
                kw = dict(label=cv.label, linestyle=cv.style, color=cv.color, linewidth=0.8)
                if cv.kind == "line":
                    ax.plot(cv.x, cv.y, **kw)
                elif cv.kind == "hline":
                    ax.axhline(float(cv.y[0]), **kw)
                elif float(cv.x[0]) <= float(panels[0].curves[0].x[-1]):  # vline within the run
                    ax.axvline(float(cv.x[0]), **kw)
                else:  # T(z0) past the end: said in the legend, not drawn (it would squash the run)
                    ax.plot([], [], **kw)
            if p.log:
                ax.set_yscale("log")
                # the envelope falls to 0 at T(z0): keep the axis on the run's own V1 (a decade below its least)
                v = p.curves[0].y[np.isfinite(p.curves[0].y) & (p.curves[0].y > 0)]
                levels = [float(cv.y[0]) for cv in p.curves if cv.kind == "hline" and cv.y[0] > 0]
                if len(v):
                    ax.set_ylim(bottom=min([float(v.min()), *levels]) / 10)
            ax.set_ylabel(p.ylabel, fontsize=7)
            ax.tick_params(labelsize=6)
            ax.grid(True, which="both", linewidth=0.3, alpha=0.5)
            if len(p.curves) > 1:
                ax.legend(fontsize=5.5, loc="best")
            if r == 0 and cols > 1:
                ax.set_title(f"loop {name}", fontsize=8)
        axes[len(panels) - 1][c].set_xlabel("t (s)", fontsize=7)
        axes[len(panels) - 1][c].tick_params(labelbottom=True)
    fig.suptitle(rep.title, fontsize=9)
    return fig


def _html(rep: ReportData, png: bytes) -> str:
    """One page, no external resource: the PNG embedded as a data URI."""
    notes = "".join(f"<p>{html.escape(n)}</p>" for n in rep.notes)
    return ("<!DOCTYPE html>\n<html><head><meta charset=\"utf-8\"><title>" + html.escape(rep.title) + "</title></head>\n"
            "<body style=\"font-family: sans-serif\"><h1 style=\"font-size: 1.1em\">" + html.escape(rep.title)
            + "</h1>\n<img alt=\"" + html.escape(rep.title) + "\" style=\"max-width: 100%\" src=\"data:image/png;base64,"
            + base64.b64encode(png).decode("ascii") + "\">\n" + notes + "</body></html>\n")


def check_out(path) -> str:
    """The format of --out (".png" or ".html"); ReportError for any other name."""
    ext = os.path.splitext(str(path))[1].lower()
    if ext not in FORMATS:
        raise ReportError(f"--out {path}: expected a file name ending in .png or .html, found "
                          + (f"{ext!r}" if ext else "no extension"))
    return ext


def write_report(rep: ReportData, path) -> None:
    """Draw ``rep`` into ``path`` (.png or .html), written whole or not at all (temp file + rename)."""
    ext = check_out(path)
    buf = io.BytesIO()
    draw(rep).savefig(buf, format="png")
    body = buf.getvalue() if ext == ".png" else _html(rep, buf.getvalue()).encode("utf-8")
    tmp = f"{path}.tmp{os.getpid()}"
    try:
        with open(tmp, "wb") as f:
            f.write(body)
        os.replace(tmp, path)
    except OSError as exc:
        try:
            os.unlink(tmp)
        except OSError:
            pass
        if exc.errno in (errno.ENOSPC, errno.EDQUOT, errno.EIO):  # the disk, not the input: exit 1
            raise LogWriteError(path, f"cannot write the figure: {exc.strerror}") from None
        raise ReportError(f"--out {path}: cannot write the figure ({exc.strerror})") from None
