"""A log's recorded metrics against the ones recomputed from its samples (``ftstab replay``).

The metrics a run records at its end must be those its samples give, with two exceptions that are
not differences, both about what the certificate of a loop's controller gives (metrics.run_metrics
CERTIFICATE_DERIVED: the time bound and what derives from it):

- a log recorded before the metrics held a ``certificate`` (a sampled estimate of c then): what
  derives from the certificate, recomputed now with the guaranteed c_lower;
- a log whose certificate another version of the branch and bound computed
  (run_metrics.certificate_moved: both brackets hold c): the certificate and what derives from it.

A metric the recording version did not compute yet (an older log) is not a difference either; nor is
``bound_applies_reason`` recorded null (older versions left it so when the law or the plant denied the
bound) or recomputed for a law this process does not know (a plugin not loaded: it can only say so).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class MetricsComparison:
    """differ: [(key path, recorded, recomputed)] of the metrics that differ; derived and moved: the key
    paths excused by the two rules of the module docstring (old certificate, moved certificate)."""

    differ: list
    derived: list
    moved: list


def compare_recorded(recorded: dict, metrics: dict) -> MetricsComparison:
    """Compare ``recorded`` (the metrics dict a log recorded at its end) with ``metrics`` (recomputed
    from its samples) by flattened key path (config.keypath.flatten, sorted), under the rules of the
    module docstring."""
    from ftstab_mj.config.keypath import flatten
    from ftstab_mj.metrics.run_metrics import CERTIFICATE_DERIVED, certificate_moved

    rec, now = flatten(recorded), flatten(metrics)
    from ftstab_mj.control.law import declared

    changed = [k for k in sorted(rec) if rec.get(k) != now.get(k)]  # keys new since the recording: not compared
    unknown = {name for name, m in recorded.get("loops", {}).items() if declared(m.get("law")) is None}
    changed = [k for k in changed if not (k.endswith(".bound_applies_reason") and k.startswith("loops.")
                                          and (rec.get(k) is None or k.split(".")[1] in unknown))]
    loops_rec, loops_now = recorded.get("loops", {}), metrics.get("loops", {})

    def in_loops(k, names, fields):
        parts = k.split(".")
        return parts[0] == "loops" and parts[1] in names and parts[2] in fields

    old_cert = {name for name, m in loops_rec.items() if "certificate" not in m}
    derived = [k for k in changed if in_loops(k, old_cert, CERTIFICATE_DERIVED)]
    moved_loops = {name for name, m in loops_rec.items()
                   if certificate_moved(m.get("certificate"), loops_now.get(name, {}).get("certificate"))}
    moved = [k for k in changed if in_loops(k, moved_loops, CERTIFICATE_DERIVED + ("certificate",))]
    differ = [(k, rec.get(k), now.get(k)) for k in changed if k not in derived and k not in moved]
    return MetricsComparison(differ, derived, moved)
