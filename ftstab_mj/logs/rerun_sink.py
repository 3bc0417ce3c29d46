"""Rerun recording (.rrd, or a live viewer) of a run: the plant in 3D and one entity per plot, on a ``sim_time`` timeline.

Entities (one multi-series entity per plot: one ``send_columns`` per plot and batch):

- ``/world/<body>``: the body's pose over time (Transform3D, world frame); its geoms as static
  children ``/world/<body>/<geom>``; ``/world/world/<geom>`` the static geoms (floor...).
- ``/loop/<name>/z``: z_1..z_r (chain units); a loop with a sensor, observer or actuator model
  (records.STAGE_FIELDS) adds the estimate z_hat (what the law saw) and the reading z_measured.
- ``/loop/<name>/control``: u (the law's output) and u0 (Hong's nominal control), and u_applied
  (what the plant received) for a loop with an actuator model, drawn with **min/max
  aggregation**: when a pixel holds many samples the plot shows their range, so a chattering u
  (between -2.1 and +2.1 at almost every sample) shows as a band, not as its average.
- ``/loop/<name>/V1/log10_V1``: log10 V1 (Rerun plots have no log axis; V1 = 0 is a gap), with
  ``/loop/<name>/V1/settle_level`` (log10 of the metrics' settle level) and, where Theorem 1 gives
  a bound (certificate c > 0, nominal or robust law), ``/loop/<name>/V1/envelope``: the comparison
  lemma's V1(t) <= (V1(0)^(1-alpha) - c (1-alpha) t)^(1/(1-alpha)) until T(z0) =
  V1(0)^(1-alpha) / (c (1-alpha)) (metrics.envelope), marked by the point ``/loop/<name>/V1/T_z0``.
  Its series name says what it is, in the report's words (metrics.envelope_kind): a
  "continuous-time guarantee" only where the metrics say ``bound_applies``, else "not a
  guarantee" and why; named from the loop's description at the start, from the metrics at close.
- ``/loop/<name>/adaptation``: phi_hat, gamma_hat against the true phi, gamma (chain units).
- ``/loop/<name>/other``: any other per-sample field the loop carries (one series per value;
  dV1/dz_r, and what observers or actuators add), in its own plot.
- ``/run/scenario``, ``/run/status``: text documents (the resolved scenario; status, message and
  metrics table, written at the end).

Default blueprint: on the left the 3D view, its camera framing the plant over the first batch,
above tabs with the two documents; on the right one tab per loop with the plots stacked. The
recording goes to its sink (a file, a spawned viewer, a web viewer) at the first batch, with the
camera known; everything logged before is buffered by Rerun and sent then.
"""

from __future__ import annotations

import math

import numpy as np

from ftstab_mj.config.errors import LogWriteError
from ftstab_mj.control.law import declared
from ftstab_mj.logs.files import Pump, can_pump, create_log, discard, write_errors
from ftstab_mj.logs.scene import PLANE_HALF_THICKNESS, model_shapes, quat_rotate
from ftstab_mj.metrics.run_metrics import bound_applies, envelope, envelope_kind, loop_certificate, stage_reasons, time_bound, v1_label
from ftstab_mj.simulation.records import RunInfo, SampleBatch, format_table

TIMELINE = "sim_time"
WHAT = "Rerun recording"
APPLICATION_ID = "ftstab"

# Per plot, the series and their colours (RGB), chosen so that no two series of one plot collide.
PALETTE = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75),
           (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207), (0, 0, 128), (128, 0, 0)]
# plot -> its fields in order (those a batch carries are plotted), and fixed colours where they matter
PLOTS = {
    "z": ("z", "z_hat", "z_measured"),
    "control": ("u", "u0", "u_applied"),
    "adaptation": ("phi_hat", "gamma_hat", "phi", "gamma"),
}
FIXED_COLOURS = {"u": (214, 39, 40), "u0": (30, 30, 30), "u_applied": (44, 160, 44), "phi_hat": (148, 103, 189),
                 "gamma_hat": (23, 190, 207), "phi": (188, 189, 34), "gamma": (140, 86, 75)}
V1_COLOURS = {"log10_V1": (31, 119, 180), "settle_level": (127, 127, 127), "envelope": (148, 103, 189),
              "T_z0": (214, 39, 40)}
PLOTTED = {"t", "V1", *(f for fields in PLOTS.values() for f in fields)}
# Rerun's file writer keeps an index entry per chunk for the footer it writes at the end (its RRD
# manifest: ~780 B a chunk measured with rerun-sdk 0.41, one chunk per entity and batch: 47 MB for a
# 10^7-sample run in batches of 1000). A recording expected to hold more chunks than this is written
# without the footer (FileSink(write_footer=False)), so that a long run's memory stays flat: the file
# is a valid .rrd all the same (the viewer and `rerun rrd print` read it; `rerun rrd verify` refuses it
# for the missing footer), and `rerun rrd optimize` adds a
# footer later. At this bound the index costs ~9 MB.
FOOTER_MAX_CHUNKS = 12_000


def _eye(info: RunInfo, body_pos: np.ndarray):
    """(position, look target) of a camera that frames the plant: the bodies' positions over
    body_pos (n, nbody, 3) grown by each body's reach (its geoms), the static geoms but planes, and the origin."""
    reach = {}
    points = [np.zeros(3)]
    for s in model_shapes(info.model_xml, info.body_names):
        r = float(np.linalg.norm(s.pos)) + max(s.half_sizes)
        if s.body == "world":
            if s.kind != "box" or s.half_sizes[2] != PLANE_HALF_THICKNESS:  # an infinite plane frames nothing
                points += [np.asarray(s.pos) - r, np.asarray(s.pos) + r]
        else:
            reach[s.body] = max(reach.get(s.body, 0.0), r)
    for b, name in enumerate(info.body_names):
        p = body_pos[:, b][np.isfinite(body_pos[:, b]).all(axis=1)]
        if len(p):
            points += [p.min(axis=0) - reach.get(name, 0.0), p.max(axis=0) + reach.get(name, 0.0)]
    pts = np.array(points)
    lo, hi = pts.min(axis=0), pts.max(axis=0)
    centre = (lo + hi) / 2.0
    radius = max(float(np.linalg.norm(hi - lo)) / 2.0, 0.2)
    direction = np.array([0.35, -1.0, 0.45])  # from the front (-y), a little above and to the side
    return centre + 2.2 * radius * direction / np.linalg.norm(direction), centre


def blueprint(info: RunInfo, eye=None, others=()):
    """The default layout described in the module docstring; eye: (position, target) of the 3D
    camera; others: names of the loops that have an ``other`` plot."""
    import rerun.blueprint as rrb

    tabs = []
    for lp in info.loops:
        base = f"/loop/{lp.name}"
        staged = getattr(lp, "stages", None) is not None
        plots = [rrb.TimeSeriesView(origin=f"{base}/z", name=f"{lp.name}: " + (
                     "true z vs estimate z_hat and reading z_measured" if staged else "state z")),
                 rrb.TimeSeriesView(origin=f"{base}/control", name=f"{lp.name}: " + (
                     "u asked, u0, u_applied" if staged else "u, u0") + " (min/max per pixel)"),
                 rrb.TimeSeriesView(origin=f"{base}/V1", name=f"{lp.name}: log10 V1, settle level, Theorem 1 envelope"),
                 rrb.TimeSeriesView(origin=f"{base}/adaptation", name=f"{lp.name}: phi_hat, gamma_hat vs true phi, gamma")]
        if lp.name in others:
            plots.append(rrb.TimeSeriesView(origin=f"{base}/other", name=f"{lp.name}: other signals"))
        tabs.append(rrb.Vertical(*plots, name=lp.name))
    right = tabs[0] if len(tabs) == 1 else rrb.Tabs(*tabs)
    docs = rrb.Tabs(rrb.TextDocumentView(origin="/run/status", name="status and metrics"),
                    rrb.TextDocumentView(origin="/run/scenario", name="scenario"))
    if info.model_xml is None:
        left = docs
    else:
        controls = None
        if eye is not None:
            controls = rrb.archetypes.EyeControls3D(kind=rrb.components.Eye3DKind.Orbital, position=eye[0].tolist(),
                                                    look_target=eye[1].tolist(), eye_up=[0.0, 0.0, 1.0])
        left = rrb.Vertical(rrb.Spatial3DView(origin="/world", name="plant", eye_controls=controls), docs,
                            row_shares=[3, 1])
    return rrb.Blueprint(rrb.Horizontal(left, right, column_shares=[2, 3]), collapse_panels=True)


def _xyzw(q_wxyz):
    w, x, y, z = q_wxyz
    return [x, y, z, w]


def log_shapes(rec, info: RunInfo) -> None:
    """Static geoms of the bodies (and of the world body) under /world."""
    import rerun as rr

    for s in model_shapes(info.model_xml, info.body_names):
        path = f"/world/{s.body}/{s.name}"
        color = [np.clip(s.rgba, 0.0, 1.0).tolist()]
        quat = [_xyzw(s.quat)]
        if s.kind == "box":
            arch = rr.Boxes3D(half_sizes=[s.half_sizes], centers=[s.pos], quaternions=quat, colors=color)
        elif s.kind == "ellipsoid":
            arch = rr.Ellipsoids3D(half_sizes=[s.half_sizes], centers=[s.pos], quaternions=quat, colors=color)
        elif s.kind == "cylinder":
            arch = rr.Cylinders3D(lengths=[2 * s.half_sizes[2]], radii=[s.half_sizes[0]], centers=[s.pos],
                                  quaternions=quat, colors=color)
        else:  # capsule: Rerun's runs from (0,0,0) to (0,0,length) in its frame, MuJoCo's is centred
            end = np.asarray(s.pos) + quat_rotate(s.quat, (0.0, 0.0, -s.half_sizes[2]))
            arch = rr.Capsules3D(lengths=[2 * s.half_sizes[2]], radii=[s.half_sizes[0]], translations=[end.tolist()],
                                 quaternions=quat, colors=color)
        rec.log(path, arch, static=True)


def _labels(field: str, a) -> list[str]:
    """Series names of one field: itself for (n,), field1..fieldw for (n, w) (z -> z1, z2)."""
    w = int(np.prod(np.shape(a)[1:], dtype=int))
    return [field] if np.ndim(a) == 1 else [f"{field}{i + 1}" for i in range(w)]


# a Rerun timeline holds int64 nanoseconds: 2^63 ns is 292 years (rerun-sdk raises OverflowError beyond)
TIMELINE_MAX_S = (2 ** 63 - 1) / 1e9 * (1 - 1e-9)


def on_timeline(t) -> np.ndarray:
    """Mask (m,) of the times t (m,) (s) a Rerun timeline can hold. Every time bound the sink draws goes
    through it: a valid scenario can have a T(z0) of centuries (k = -1e-12 gives 1e14 s), which is then
    no point on the timeline but stays a number in its note; a run's own samples are within 1e7 periods."""
    t = np.asarray(t, dtype=float)
    return np.isfinite(t) & (np.abs(t) <= TIMELINE_MAX_S)


def _log10(v: np.ndarray) -> np.ndarray:
    out = np.full(v.shape, np.nan)
    pos = v > 0
    out[pos] = np.log10(v[pos])
    return out


class RerunSink:
    """Writes a run to a Rerun recording: a file at ``path``, or, with ``live``, a viewer as well:
    "spawn" (a native viewer), "serve" (a web viewer on ``web_port``, gRPC on ``grpc_port``) or a
    gRPC URL to connect to.

    The file is created at :meth:`open` without following a symlink and replaces only one of our
    logs unless ``force`` (logs/files.py). Rerun's file writer writes into a pipe whose bytes this
    sink copies into it (logs/files.py Pump): a write error (disk full, the file removed) is raised
    here as LogWriteError naming the file, at the batch it hit, instead of stopping Rerun's writer,
    after which Rerun waits for ever at the next flush and at the exit of the process. Without
    /proc (not Linux) Rerun writes the file by name.
    """

    def __init__(self, path, application_id: str = APPLICATION_ID, live: str | None = None,
                 web_port: int = 9090, grpc_port: int = 9876, force: bool = False):
        self.path = str(path) if path is not None else None
        self.application_id = application_id
        self.live, self.web_port, self.grpc_port = live, web_port, grpc_port
        self.force = force
        self.closed_status = None  # the status the recording was closed with (None: not closed whole)
        self._kinds: dict[str, str] = {}  # loop -> what its envelope is (metrics.envelope_kind)
        self._time_bounds: dict[str, float] = {}  # loop -> T(z0) (s), where finite
        self._rec = None
        self._pump = None
        self.footer = None  # whether the file gets Rerun's footer (FOOTER_MAX_CHUNKS), decided at the first batch
        self.expected_chunks = None  # the chunks the batches of the run will make, estimated then

    @write_errors(WHAT)
    def open(self, info: RunInfo) -> None:
        self._info = info
        if self.path is not None:  # our one-line errors before Rerun builds anything
            created = create_log(self.path, self.force, WHAT)  # LogError (bad input) when refused
            if can_pump():
                self._pump = Pump(created)
            else:
                created.close()
        try:
            self._start(info)
        except BaseException:  # no half-opened log: the file this call created goes
            self._abandon()
            if self.path is not None:
                discard(self.path)
            raise

    def _start(self, info: RunInfo) -> None:
        import rerun as rr

        rec = rr.RecordingStream(self.application_id)
        self._rec = rec
        self._attached = False
        self._V1_0 = {}
        rec.log("/run/scenario", rr.TextDocument(_pretty(info.scenario), media_type="text/plain"), static=True)
        rec.log("/run/status", rr.TextDocument("running", media_type="text/plain"), static=True)
        for lp in info.loops:
            self._log_styles(lp)
        if info.model_xml is not None:
            log_shapes(rec, info)

    def _log_styles(self, lp) -> None:
        import rerun as rr

        rec, base = self._rec, f"/loop/{lp.name}"
        for name, label in (("log10_V1", v1_label(lp, "log10 V1")), ("settle_level", "log10 settle level")):
            rec.log(f"{base}/V1/{name}", rr.SeriesLines(names=label, colors=V1_COLOURS[name],
                                                        aggregation_policy="MinMax"), static=True)
        rec.log(f"{base}/V1/T_z0", rr.SeriesPoints(names="T(z0)", colors=V1_COLOURS["T_z0"], markers="Cross",
                                                   marker_sizes=8.0), static=True)
        # until the metrics say (at close): what the loop's description alone says, the workspace unknown
        reasons = stage_reasons(getattr(lp, "stages", None))
        self._label_envelope(lp, {"bound_applies": bound_applies(lp) and not reasons,
                                  "bound_applies_reason": "; ".join(reasons) or None}, final=False)

    def _label_envelope(self, lp, m: dict, final: bool) -> None:
        """Name loop ``lp``'s envelope series and T(z0) note with what they are for metrics ``m``
        (metrics.envelope_kind, the report's words); static: the close's (final) name replaces the open's."""
        import rerun as rr

        kind = envelope_kind(m)
        if not final and m["bound_applies"]:
            kind += " if the run stays in its workspace"
        self._kinds[lp.name] = kind
        base = f"/loop/{lp.name}/V1"
        self._rec.log(f"{base}/envelope", rr.SeriesLines(names=f"log10 Theorem 1 envelope ({kind})",
                                                         colors=V1_COLOURS["envelope"], aggregation_policy="MinMax"),
                      static=True)
        if lp.name in self._time_bounds:
            self._rec.log(f"{base}/T_z0/note", rr.TextDocument(f"T(z0) = {self._time_bounds[lp.name]:.4g} s ({kind})"),
                          static=True)

    def _attach(self, body_pos, loops=None) -> None:
        """Send the recording to its sinks, with the blueprint (camera from ``body_pos``; a plot of
        the other fields of the first batch's ``loops``)."""
        import rerun as rr

        info, rec = self._info, self._rec
        eye = _eye(info, body_pos) if info.model_xml is not None else None
        others = []
        per_batch = len(info.body_names)  # the chunks a batch makes: one per body and per plotted entity
        for name, arrays in (loops or {}).items():
            per_batch += 1  # log10_V1
            for plot, fields in (*PLOTS.items(), ("other", [f for f in arrays if f not in PLOTTED])):
                names = [n for f in fields if f in arrays for n in _labels(f, arrays[f])]
                if not names:
                    continue
                per_batch += 1
                others += [name] if plot == "other" else []
                colours = [FIXED_COLOURS.get(n) for n in names]
                free = iter(c for c in PALETTE if c not in colours)
                rec.log(f"/loop/{name}/{plot}", rr.SeriesLines(
                    names=names, colors=[c or next(free) for c in colours],
                    aggregation_policy="MinMax" if plot == "control" else None), static=True)
        bp = blueprint(info, eye, others)
        sinks = []
        self.expected_chunks = self._expected_chunks(loops, per_batch)
        self.footer = self.path is not None and self.expected_chunks <= FOOTER_MAX_CHUNKS
        if self.path is not None:
            sinks.append(rr.FileSink(self._pump.target if self._pump is not None else self.path,
                                     write_footer=self.footer))
        if self.live:
            sinks.append(rr.GrpcSink(start_viewer(self.live, self.grpc_port, self.web_port)))
        if sinks:
            with _quiet_stderr(not self.footer and self.path is not None):
                rec.set_sinks(*sinks, default_blueprint=bp)
        if self._pump is not None:
            self._pump.writer_opened()
        self._attached = True

    def _expected_chunks(self, loops, per_batch: int) -> float:
        """The chunks the recording will hold: per_batch for each batch of the first one's size
        (``loops``: the first batch) over the run's duration (a recording of unknown length: 0)."""
        sim = self._info.scenario.get("sim")
        duration = float(sim.get("duration", 0.0) or 0.0) if isinstance(sim, dict) else 0.0
        size = max((len(a["t"]) for a in (loops or {}).values()), default=0)
        if size == 0 or not duration > 0:
            return 0.0
        return math.ceil(round(duration / self._info.period) / size) * per_batch

    def _flush(self) -> None:
        """Everything logged so far is in the file; raises the first write error (then abandons)."""
        self._rec.flush()
        error = self._pump.sync() if self._pump is not None else None
        if error is not None:
            self._abandon()
            raise error

    def _abandon(self) -> None:
        """Stop writing: Rerun's writer is let go (its pipe is drained to the end, never into the
        file after an error) and the file closed."""
        rec, self._rec = self._rec, None
        if rec is not None:
            rec.disconnect()
        pump, self._pump = self._pump, None
        if pump is not None:
            pump.close()

    def _static_bounds(self, lp, V1_0: float, z0) -> None:
        """Settle level and Theorem 1's envelope for loop ``lp`` from its first V1 (V1_0) and z (z0)."""
        import rerun as rr

        base, rec = f"/loop/{lp.name}", self._rec
        duration = float(self._info.scenario.get("sim", {}).get("duration", 0.0) or 0.0) if isinstance(
            self._info.scenario.get("sim"), dict) else 0.0
        level = self._info.metric_settings.settle_level
        ends = np.array([0.0, max(duration, self._info.period)])
        ends = ends[on_timeline(ends)]
        rec.send_columns(f"{base}/V1/settle_level", indexes=[rr.TimeColumn(TIMELINE, duration=ends)],
                         columns=rr.Scalars.columns(scalars=np.log10(np.full(len(ends), level))))
        law = declared(lp.law)
        if law is None or not law.time_bound:
            return
        cert = loop_certificate(lp)
        t, bound, T = envelope(cert, V1_0, duration if duration > 0 else math.inf, T=time_bound(lp, z0))
        keep = on_timeline(t)
        if keep.any():
            rec.send_columns(f"{base}/V1/envelope", indexes=[rr.TimeColumn(TIMELINE, duration=t[keep])],
                             columns=rr.Scalars.columns(scalars=_log10(bound[keep])))
        if math.isfinite(T):
            if on_timeline([T])[0]:  # beyond the timeline, T stays a number in the note
                rec.send_columns(f"{base}/V1/T_z0", indexes=[rr.TimeColumn(TIMELINE, duration=[T])],
                                 columns=rr.Scalars.columns(scalars=[math.log10(level)]))
            self._time_bounds[lp.name] = T
            rec.log(f"{base}/V1/T_z0/note", rr.TextDocument(f"T(z0) = {T:.4g} s ({self._kinds[lp.name]})"), static=True)

    @write_errors(WHAT)
    def write(self, batch: SampleBatch) -> None:
        import rerun as rr

        rec = self._rec
        if rec is None:
            raise LogWriteError(self.path, f"cannot write the {WHAT}: it was abandoned after a write error")
        if not self._attached:
            self._attach(batch.body_pos, batch.loops)
        t = None
        for lp in self._info.loops:
            arrays = batch.loops.get(lp.name)
            if arrays is None or len(arrays["t"]) == 0:
                continue
            t = np.asarray(arrays["t"], dtype=float)
            base = f"/loop/{lp.name}"
            if lp.name not in self._V1_0:
                self._V1_0[lp.name] = float(arrays["V1"][0])
                self._static_bounds(lp, self._V1_0[lp.name], np.asarray(arrays["z"][0], dtype=float))
            idx = [rr.TimeColumn(TIMELINE, duration=t)]
            for plot, fields in PLOTS.items():
                rec.send_columns(f"{base}/{plot}", indexes=idx, columns=rr.Scalars.columns(scalars=np.column_stack(
                    [np.asarray(arrays[f], float).reshape(len(t), -1) for f in fields if f in arrays])))
            rec.send_columns(f"{base}/V1/log10_V1", indexes=idx,
                             columns=rr.Scalars.columns(scalars=_log10(np.asarray(arrays["V1"], float))))
            others = [np.asarray(a, float).reshape(len(t), -1) for f, a in arrays.items() if f not in PLOTTED]
            if others:
                rec.send_columns(f"{base}/other", indexes=idx, columns=rr.Scalars.columns(scalars=np.hstack(others)))
        if t is not None and batch.body_pos.shape[1] > 0:
            self.write_poses(t, batch.body_pos, batch.body_quat)
        self._flush()

    def write_poses(self, t, pos, quat) -> None:
        """Body poses at times t (m,) s: pos (m, nbody, 3) m, quat (m, nbody, 4) (w, x, y, z)."""
        import rerun as rr

        if not self._attached:
            self._attach(pos)
        idx = [rr.TimeColumn(TIMELINE, duration=np.asarray(t, dtype=float))]
        for b, body in enumerate(self._info.body_names):
            q = quat[:, b]
            self._rec.send_columns(f"/world/{body}", indexes=idx, columns=rr.Transform3D.columns(
                translation=pos[:, b], quaternion=np.column_stack([q[:, 1], q[:, 2], q[:, 3], q[:, 0]])))

    @write_errors(WHAT)
    def close(self, status: str, metrics: dict, message: str = "") -> None:
        import rerun as rr

        if self._rec is None:
            return
        if not self._attached:
            self._attach(np.zeros((0, len(self._info.body_names), 3)))
        text = f"status: {status}\n" + (f"message: {message}\n" if message else "")
        if metrics:  # a failed run is closed without metrics
            text += "\n" + format_table(metrics)
            for lp in self._info.loops:  # the envelope's name from the run's own metrics (the workspace known)
                if lp.name in metrics["loops"]:
                    self._label_envelope(lp, metrics["loops"][lp.name], final=True)
        self._rec.log("/run/status", rr.TextDocument(text, media_type="text/plain"), static=True)
        self._flush()
        pump = self._pump
        self._abandon()  # the end: Rerun writes its footer and closes the pipe, the copy ends
        if pump is not None and pump.error is not None:
            raise pump.error
        self.closed_status = status


class _quiet_stderr:
    """Within it, file descriptor 2 goes to /dev/null (when ``on``), then back: Rerun's Rust logger
    warns there when a file sink has no footer, naming the pipe the sink writes into; the README says
    what that means for the user (section "Long runs and long logs in flat memory")."""

    def __init__(self, on: bool):
        self.on, self.saved = on, None

    def __enter__(self):
        import os
        import sys

        if self.on:
            sys.stderr.flush()
            self.saved = os.dup(2)
            null = os.open(os.devnull, os.O_WRONLY)
            os.dup2(null, 2)
            os.close(null)

    def __exit__(self, *exc):
        import os

        if self.saved is not None:
            os.dup2(self.saved, 2)
            os.close(self.saved)
            self.saved = None


def start_viewer(live: str, grpc_port: int, web_port: int) -> str:
    """Start the viewer a live run streams to and return its gRPC URL.

    live: "spawn" (the native viewer, a separate process that outlives the run), "serve" (a
    separate ``rerun --serve-web`` process, logs/live.serve_rerun: a web viewer at
    http://localhost:<web_port> and its gRPC proxy on grpc_port, for a machine without a display),
    or a rerun+http:// URL of a viewer or server already running (nothing is started)."""
    import rerun as rr

    if live == "spawn":
        rr.spawn(port=grpc_port, connect=False)
        return f"rerun+http://127.0.0.1:{grpc_port}/proxy"
    if live == "serve":
        from ftstab_mj.logs.live import serve_rerun

        return serve_rerun(grpc_port, web_port).url
    return live


def _pretty(obj) -> str:
    import json

    return json.dumps(obj, indent=2, default=str)


def write_rrd(path, info: RunInfo, loops: dict, poses, status: str, metrics: dict, message: str = "",
              force: bool = False) -> None:
    """A whole recording at once (replay --rrd): loops {name: {field: array}}, poses (t, pos, quat)
    at their own rate (see :meth:`RerunSink.write_poses`); force: as for :class:`RerunSink`."""
    sink = RerunSink(path, force=force)
    sink.open(info)
    t, pos, quat = poses
    sink._attach(pos, loops)  # the camera frames the recorded poses, the plots follow the logged fields
    if len(t) and pos.shape[1]:
        sink.write_poses(t, pos, quat)
    n = min((len(a["t"]) for a in loops.values()), default=0)
    sink.write(SampleBatch(loops, np.zeros((n, 0, 3)), np.zeros((n, 0, 4))))
    sink.close(status, metrics, message)
