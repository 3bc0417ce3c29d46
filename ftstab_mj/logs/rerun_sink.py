"""Rerun recording (.rrd) of a run: the plant in 3D and the loop signals, on a ``sim_time`` timeline.

Entities:

- ``/world/<body>``: the body's pose over time (Transform3D, world frame); its geoms as static
  children ``/world/<body>/<geom>`` (boxes, ellipsoids for spheres, capsules, cylinders);
  ``/world/world/<geom>`` the static geoms of the world body (floor...).
- ``/loop/<name>/z/z<i>``, ``/loop/<name>/u``, ``u0``, ``V1``, ``dV1_dzr``, ``phi_hat``,
  ``gamma_hat``, ``phi``, ``gamma``: scalar time series.
- a loop with a sensor, observer or actuator model (records.STAGE_FIELDS) also has
  ``/loop/<name>/z_hat/z<i>`` (what the law saw), ``/loop/<name>/z_measured/z<i>`` (the sensor's
  reading) and ``/loop/<name>/u_applied`` (what the plant received).
- ``/run/status``: a text document written at the end (status, message, metrics table).

Default blueprint: the 3D view on the left; on the right one tab per loop with four plots stacked
(state z, control u and u0, V1, and phi_hat / gamma_hat against the true phi / gamma). A loop
with stages shows the estimate z_hat and the reading against the true z in the first plot and
u_applied against u in the second.
Samples are sent with ``send_columns`` per batch and the recording is flushed after every batch.
"""

from __future__ import annotations

import numpy as np

from ftstab_mj.errors import LogError
from ftstab_mj.logs.scene import model_shapes, quat_rotate
from ftstab_mj.records import LOOP_FIELDS, RunInfo, SampleBatch

TIMELINE = "sim_time"
APPLICATION_ID = "ftstab"


def blueprint(info: RunInfo):
    """The default layout described in the module docstring."""
    import rerun.blueprint as rrb

    tabs = []
    for lp in info.loops:
        base = f"/loop/{lp.name}"
        if getattr(lp, "stages", None) is None:
            z_view = rrb.TimeSeriesView(origin=f"{base}/z", name=f"{lp.name}: state z")
            u_view = rrb.TimeSeriesView(origin=base, contents=[f"{base}/u", f"{base}/u0"], name=f"{lp.name}: control u, u0")
        else:
            z_view = rrb.TimeSeriesView(origin=base, contents=[f"{base}/{f}/**" for f in ("z", "z_hat", "z_measured")],
                                        name=f"{lp.name}: true z vs estimate z_hat and reading z_measured")
            u_view = rrb.TimeSeriesView(origin=base, contents=[f"{base}/u", f"{base}/u_applied", f"{base}/u0"],
                                        name=f"{lp.name}: u asked vs u_applied, u0")
        tabs.append(rrb.Vertical(
            z_view,
            u_view,
            rrb.TimeSeriesView(origin=base, contents=[f"{base}/V1"], name=f"{lp.name}: V1"),
            rrb.TimeSeriesView(origin=base, contents=[f"{base}/{f}" for f in ("phi_hat", "gamma_hat", "phi", "gamma")],
                               name=f"{lp.name}: phi_hat, gamma_hat vs true phi, gamma"),
            name=lp.name))
    plots = tabs[0] if len(tabs) == 1 else rrb.Tabs(*tabs)
    if info.model_xml is None:
        return rrb.Blueprint(plots, collapse_panels=True)
    return rrb.Blueprint(rrb.Horizontal(rrb.Spatial3DView(origin="/world", name="plant"), plots),
                         collapse_panels=True)


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


class RerunSink:
    """Writes a run to a Rerun recording file at ``path`` (created or overwritten at :meth:`open`)."""

    def __init__(self, path, application_id: str = APPLICATION_ID):
        self.path = str(path)
        self.application_id = application_id
        self._rec = None

    def open(self, info: RunInfo) -> None:
        import rerun as rr

        self._info = info
        try:  # fail with our own one-line error before Rerun builds anything
            open(self.path, "wb").close()
        except OSError as exc:
            raise LogError(f"{self.path}: cannot write the Rerun recording ({exc.strerror})") from None
        rec = rr.RecordingStream(self.application_id)
        rec.save(self.path, default_blueprint=blueprint(info))
        self._rec = rec
        rec.log("/run/scenario", rr.TextDocument(_pretty(info.scenario), media_type="text/plain"), static=True)
        if info.model_xml is not None:
            log_shapes(rec, info)
        rec.flush()

    def write(self, batch: SampleBatch) -> None:
        import rerun as rr

        rec = self._rec
        t = None
        for name, arrays in batch.loops.items():
            t = np.asarray(arrays["t"], dtype=float)
            idx = [rr.TimeColumn(TIMELINE, duration=t)]
            for f in ("z", "z_hat", "z_measured"):
                if f not in arrays:
                    continue
                z = np.asarray(arrays[f], dtype=float)
                for i in range(z.shape[1]):
                    rec.send_columns(f"/loop/{name}/{f}/z{i + 1}", indexes=idx,
                                     columns=rr.Scalars.columns(scalars=z[:, i]))
            for f in LOOP_FIELDS[2:] + (("u_applied",) if "u_applied" in arrays else ()):
                rec.send_columns(f"/loop/{name}/{f}", indexes=idx,
                                 columns=rr.Scalars.columns(scalars=np.asarray(arrays[f], dtype=float)))
        if t is not None and batch.body_pos.shape[1] > 0:
            self.write_poses(t, batch.body_pos, batch.body_quat)
        rec.flush()

    def write_poses(self, t, pos, quat) -> None:
        """Body poses at times t (m,) s: pos (m, nbody, 3) m, quat (m, nbody, 4) (w, x, y, z)."""
        import rerun as rr

        idx = [rr.TimeColumn(TIMELINE, duration=np.asarray(t, dtype=float))]
        for b, body in enumerate(self._info.body_names):
            q = quat[:, b]
            self._rec.send_columns(f"/world/{body}", indexes=idx, columns=rr.Transform3D.columns(
                translation=pos[:, b], quaternion=np.column_stack([q[:, 1], q[:, 2], q[:, 3], q[:, 0]])))

    def close(self, status: str, metrics: dict, message: str = "") -> None:
        import rerun as rr

        from ftstab_mj.metrics import format_table

        if self._rec is None:
            return
        text = f"status: {status}\n" + (f"message: {message}\n" if message else "")
        if metrics:  # a failed run is closed without metrics
            text += "\n" + format_table(metrics)
        self._rec.log("/run/status", rr.TextDocument(text, media_type="text/plain"), static=True)
        self._rec.flush()
        self._rec.disconnect()
        self._rec = None


def _pretty(obj) -> str:
    import json

    return json.dumps(obj, indent=2, default=str)


def write_rrd(path, info: RunInfo, loops: dict, poses, status: str, metrics: dict, message: str = "") -> None:
    """A whole recording at once (replay --rrd): loops {name: {field: array}}, poses (t, pos, quat)
    at their own rate (see :meth:`RerunSink.write_poses`)."""
    sink = RerunSink(path)
    sink.open(info)
    n = min((len(a["t"]) for a in loops.values()), default=0)
    sink.write(SampleBatch(loops, np.zeros((n, 0, 3)), np.zeros((n, 0, 4))))
    t, pos, quat = poses
    if len(t) and pos.shape[1]:
        sink.write_poses(t, pos, quat)
    sink.close(status, metrics, message)
