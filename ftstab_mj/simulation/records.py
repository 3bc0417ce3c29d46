"""What a run produces: the contract between the run loop (producer), the log sinks and the metrics.

The run loop describes the run once (:class:`RunInfo`), then hands samples to every sink in
batches (:class:`SampleBatch`), then closes with a status and the metrics. Sinks only observe.
Metrics are computed from the same arrays (live) or from the arrays read back from a log (replay),
so both give the same numbers.

Per control loop, one sample per control period with the fields of :data:`LOOP_FIELDS`
(a user-facing contract: the README's "Logs" section): ``z`` has shape (n, r), every other field (n,).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Protocol

import numpy as np

LOOP_FIELDS = ("t", "z", "u", "u0", "V1", "dV1_dzr", "phi_hat", "gamma_hat", "phi", "gamma")
# Recorded as well for a loop with a sensor, observer or actuator model (ftstab_mj/loop_stages):
# what the sensor gave (n, m), what the law saw (n, r), what the plant received (n,). The true z
# stays in ``z`` and the law's output in ``u``.
STAGE_FIELDS = ("z_measured", "z_hat", "u_applied")

# Run statuses (the /metrics message carries one).
COMPLETED = "completed"  # ran for the whole duration
DIVERGED = "diverged"  # stopped by NaN, a MuJoCo warning or |z| beyond the limit
INTERRUPTED = "interrupted"  # Ctrl-C
FAILED = "failed"  # any other error inside the run (e.g. an exception in the controller)
STATUSES = (COMPLETED, DIVERGED, INTERRUPTED, FAILED)

# The work limit of a run's certificate (boxes per bound; MetricSettings.certificate_boxes): about
# 30 s of one core at r = 5, more than every shipped r <= 4 scenario needs to close its 0.2 % gap.
RUN_CERTIFICATE_BOXES = 2_000_000
# What a log recorded before that key existed used (the branch and bound's own cap): its replay
# computes the same certificate.
UNLIMITED_RUN_BOXES = 20_000_000


@dataclass(frozen=True)
class LoopInfo:
    """Everything metrics need to know about one control loop, independent of the scenario schema.

    law: a registered law's name (its declarations: control/law.py); hong: {"r", "k", "gains", "form"};
    law_params: robust {"phibar", "gamma_m"}, adaptive {"kappa", "delta", "rate", "eta", "eps"}, nominal {};
    true_phibar: sup |phi| of the disturbance actually injected, chain units (for Theorem 3's bounds);
    true_gamma_m, true_gamma_M: range of the true gain gamma(t), chain units.
    For plants whose phi/gamma bounds come from physics (arm), these are the computed bounds.
    """

    name: str
    r: int
    law: str
    hong: dict
    law_params: dict
    true_phibar: float
    true_gamma_m: float
    true_gamma_M: float
    # Where the true bounds hold (Plant.loop_workspace), None when everywhere: z1_min, z1_max,
    # z2_abs_max (chain units), u_abs_max (control units). Metrics check the samples against it.
    workspace: dict | None = None
    # The loop's sensor, observer and actuator (ftstab_mj/loop_stages), None for an ideal loop:
    # {"sensor": {measured, noise, noise_kind, quantum, delay}, "observer": {kind, order, L,
    # filter_order} | None, "actuator": {u_max, rate_max, tau, dead_zone} (None: no limit),
    # "u_needed": the |u| the law's guarantee may ask for (None: no a priori bound), "u_needed_note"}.
    stages: dict | None = None
    # The work limit of this loop's certificate (the run's MetricSettings.certificate_boxes)
    certificate_boxes: int = RUN_CERTIFICATE_BOXES
    # What the plant's own actuator clamps (a user model's ctrlrange/forcerange kept as its
    # saturation), None when nothing does: such a loop records u_applied, the control received.
    clamp: str | None = None
    # A reference to track (z_i = q^(i-1) - ref^(i-1)(t)): {"kind", its parameters, "max_abs": max
    # |ref^(j)| for j = 0..r}, None for a set point (``ref``).
    reference: dict | None = None


@dataclass(frozen=True)
class MetricSettings:
    """How metrics read a run. settle_level: V1 below it counts as settled; final_fraction: the
    last part of the run over which accuracy and chattering are measured; chatter_band: (low, high)
    in Hz, the band of the band-RMS chattering index (clipped to the Nyquist frequency 1 / (2 period));
    settle_z1: |z_1| below it (chain units, m or rad) counts as settled for the law-independent
    settling time (every law has z_1, not every law has V1); final_window_max: the final window's
    longest duration in s (a run longer than final_window_max / final_fraction measures its last
    final_window_max s: its memory stays flat; None: no limit, as in the logs written before it);
    certificate_boxes: the work limit of the run's certificate, boxes the branch and bound may evaluate
    for c and again for c' (deterministic, unlike a time budget: the same log on every machine);
    undecided within it, the run claims no T(z0)."""

    settle_level: float = 1e-4
    final_fraction: float = 0.2
    chatter_band: tuple[float, ...] = (10.0, 1000.0)
    settle_z1: float = 1e-3
    final_window_max: float | None = 100.0
    certificate_boxes: int = RUN_CERTIFICATE_BOXES


@dataclass(frozen=True)
class RunInfo:
    """Static description of a run, written once at its start.

    scenario: the resolved scenario as plain JSON-able data (enough to re-run it);
    period: control period (s); physics_step: MuJoCo timestep (s);
    model_xml: the MJCF actually simulated (None for the ideal chain), so a log can rebuild 3D;
    body_names: names of the bodies whose poses are in SampleBatch.body_pos/quat (world excluded);
    kernel: the path that computed the samples, "native" (the C kernel) or "python" ("" in older logs).
    """

    scenario: dict
    loops: tuple[LoopInfo, ...]
    period: float
    physics_step: float
    metric_settings: MetricSettings = field(default_factory=MetricSettings)
    model_xml: str | None = None
    body_names: tuple[str, ...] = ()
    kernel: str = ""

    def to_dict(self) -> dict:
        d = asdict(self)
        for lp in d["loops"]:  # an ideal loop is described as before loop stages existed
            for key in ("stages", "clamp", "reference"):  # (and clamps and references)
                if lp.get(key) is None:
                    lp.pop(key, None)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> "RunInfo":
        """Inverse of :meth:`to_dict` (a log stores RunInfo as JSON; replay rebuilds it)."""
        return cls(
            scenario=d["scenario"],
            loops=tuple(LoopInfo(**{"certificate_boxes": UNLIMITED_RUN_BOXES, **lp}) for lp in d["loops"]),
            period=float(d["period"]), physics_step=float(d["physics_step"]),
            # a log written before final_window_max existed measured the whole final fraction, and one
            # written before certificate_boxes existed had the branch and bound's own cap
            metric_settings=MetricSettings(**{"final_window_max": None, "certificate_boxes": UNLIMITED_RUN_BOXES, **{
                k: tuple(v) if isinstance(v, list) else v for k, v in d.get("metric_settings", {}).items()}}),
            model_xml=d.get("model_xml"), body_names=tuple(d.get("body_names", ())), kernel=str(d.get("kernel", "")))


@dataclass
class SampleBatch:
    """n consecutive control samples.

    loops: {loop name: {field: array}} with the fields of LOOP_FIELDS (z (n, r), others (n,));
    body_pos: (n, nbody, 3) world positions (m) and body_quat: (n, nbody, 4) (w, x, y, z) of the
    bodies named in RunInfo.body_names, at the same sample times; empty (n, 0, 3)/(n, 0, 4) when
    there is no 3D model.
    """

    loops: dict[str, dict[str, np.ndarray]]
    body_pos: np.ndarray
    body_quat: np.ndarray

    def __len__(self) -> int:
        first = next(iter(self.loops.values()))
        return int(len(first["t"]))


class Sink(Protocol):
    """An observer of a run (MCAP writer, Rerun writer, in-memory collector)."""

    def open(self, info: RunInfo) -> None: ...

    def write(self, batch: SampleBatch) -> None: ...

    def close(self, status: str, metrics: dict, message: str = "") -> None: ...


# -- the metrics dict as text (the CLI and the Rerun log show it) -----------------------------------
def _fmt(v) -> str:
    if v is None:
        return "-"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, float):
        return f"{v:.6g}"
    if isinstance(v, list):
        return "[" + ", ".join(_fmt(x) for x in v) + "]"
    return str(v)


# The unit of each metric as the table prints it after the value ("" for counts, flags and text):
# s seconds; u the control's unit; chain: chain units (z_i in m/s^(i-1), or rad/s^(i-1) on a joint,
# and V1 of them). UNITS_LEGEND says it under the table. Definitions: ftstab_mj/metrics/run_metrics.py.
METRIC_UNITS = {
    "n_samples": "", "z0": "chain", "V1_initial": "chain", "V1_final": "chain", "settle_level": "chain",
    "settle_time": "s", "settle_time_z1": "s", "time_bound": "s", "workspace_left": "", "bound_applies": "",
    "beat_bound": "", "final_window_start": "s", "final_abs_z_max": "chain", "chattering": "u/s",
    "chattering_du_dt_var": "(u/s)^2", "chattering_zero_crossings": "1/s", "chattering_band_rms": "u",
    "effort_abs": "u s", "effort_sq": "u^2 s", "u_max_abs": "u", "eps": "chain", "eps_entry_time": "s",
    "V1_min_after_entry": "chain", "V1_max_after_entry": "chain", "phi_hat_max": "u", "phi_hat_final": "u",
    "certificate": "", "clamp": "", "bound_applies_reason": "", "u_needed": "u", "estimation_error_max": "chain",
    "estimation_error_rms": "chain", "time_saturated": "s", "saturated_fraction": "", "chattering_applied": "u/s",
    "u_applied_max_abs": "u", "reference_r_max_abs": "chain", "phibar_covers_reference": "",
    # the differentiator's assumption |z_1^(n+1)| <= L (L and the max in m/s^(n+1) on a cart)
    "observer_L": "chain", "observer_derivative_max": "chain", "observer_L_exceeded_ratio": "",
    "observer_L_exceeded_fraction": "",
    # the steady oscillation (metrics/oscillation.py) and its describing-function prediction
    "z1_osc_amplitude": "chain", "z1_osc_frequency": "Hz", "u_osc_amplitude": "u", "u_osc_frequency": "Hz",
    "averaged_power": "chain^2/s", "limit_cycle_predicted": "", "frequency": "Hz", "amplitude_z1": "chain",
    "amplitude_u": "u", "delay": "s", "V1_max_over_Delta": "",
    # theorem 3 (true bounds)
    "Phibar": "u", "Delta": "chain", "phi_hat_limsup": "u", "V1_max_final": "chain", "Delta_held": "",
    "phi_hat_max_final": "u", "phi_hat_bound_held": "", "V1_min_final": "chain", "eps_reached": "",
}
UNITS_LEGEND = ("units: s seconds; u the control's unit (m/s^r on the carts, N m on the arms); "
                "chain units: z_i in m/s^(i-1) or rad/s^(i-1), V1 of them")


def _with_unit(key: str, val) -> str:
    unit = METRIC_UNITS.get(key, "")
    text = _fmt(val)
    if not unit or val is None or isinstance(val, (bool, str)):
        return text
    return f"{text} {'chain units' if unit == 'chain' else unit}"


def format_table(metrics: dict) -> str:
    """A human-readable table of a metrics dict (ftstab_mj.metrics.run_metrics.compute_metrics; one block per loop),
    each value with its unit (METRIC_UNITS), the units explained on the last line."""
    lines = [f"status {metrics['status']}, {metrics['n_samples']} samples, {_fmt(metrics['duration'])} s"]
    for name, m in metrics["loops"].items():
        lines.append(f"loop {name} ({m['law']})")
        for key, val in m.items():
            if key in ("law", "theorem3"):
                continue
            if key == "certificate" and val:
                note = f"; {val['note']}" if val.get("note") else ""
                val = f"{val['status']}, c in [{_fmt(val['c_lower'])}, {_fmt(val['c_upper'])}] (guaranteed){note}"
            lines.append(f"  {key:<26} {_with_unit(key, val)}")
        th = m.get("theorem3")
        if th:
            lines.append("  theorem 3 (true bounds):")
            for key, val in th.items():
                lines.append(f"    {key:<24} {_with_unit(key, val)}")
    if metrics["loops"]:
        lines.append(UNITS_LEGEND)
    return "\n".join(lines)
