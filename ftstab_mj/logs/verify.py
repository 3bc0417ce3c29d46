"""``ftstab replay --verify``: re-run the scenario recorded in a log and compare the samples bit for bit.

Runs are deterministic (same scenario, same seed, same platform and library versions: identical
samples), so any difference means the log was altered or the code changed behaviour. Compared:
every logged field of every loop over the logged samples (a truncated or interrupted log is a
prefix: the scenario is re-run for as many samples as it holds), the body poses of /tf, and the status of a complete log. Floats are compared by their
bits (so -0.0 != 0.0); non-finite values count as equal when both are non-finite (the log stores
them as null).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from ftstab_mj.errors import LogError
from ftstab_mj.interrupts import Interrupted, last_signal
from ftstab_mj.records import COMPLETED, DIVERGED, INTERRUPTED, LOOP_FIELDS, STAGE_FIELDS


@dataclass(frozen=True)
class Verification:
    """ok: every compared value identical; compared: number of float values compared;
    problems: readable lines, the first differing sample of each field that differs."""

    ok: bool
    compared: int
    problems: tuple


def first_bit_difference(logged: np.ndarray, rerun: np.ndarray) -> int | None:
    """Index (along axis 0) of the first sample whose bits differ, None if identical. Same shapes."""
    if len(logged) == 0:
        return None
    a = np.asarray(logged, dtype=float).reshape(len(logged), -1)
    b = np.asarray(rerun, dtype=float).reshape(len(rerun), -1)
    fa, fb = np.isfinite(a), np.isfinite(b)
    bits_differ = (a.view(np.int64) != b.view(np.int64)) & fa & fb
    bad = np.flatnonzero((fa != fb).any(axis=1) | bits_differ.any(axis=1))
    return int(bad[0]) if bad.size else None


def verify_log(log) -> Verification:
    """Re-run ``log.info.scenario`` (no sinks) and compare it with ``log`` (a reader.LogData)."""
    from ftstab_mj.scenario.run import run_scenario_dict

    from ftstab_mj.plants import MODELS

    if not log.info.scenario:
        raise LogError(f"{log.path}: no scenario recorded in /scenario, nothing to re-run")
    plant = log.info.scenario.get("plant")
    model = plant.get("model") if isinstance(plant, dict) else None
    if model not in MODELS:  # a log is untrusted: re-running it must not read a local file it names
        raise LogError(f"{log.path}: /scenario plant.model: --verify re-runs the shipped plants only "
                       f"({', '.join(MODELS)}), found {str(model)[:80]!r}; re-run that scenario with ftstab run")
    finished = log.complete and log.recorded is not None and log.recorded["status"] in (COMPLETED, DIVERGED)
    scenario = copy.deepcopy(log.info.scenario)
    if not finished and log.n_samples and isinstance(scenario.get("sim"), dict):
        # an unfinished log is a prefix: re-run only as far (samples never depend on the duration)
        scenario["sim"]["duration"] = log.n_samples * log.info.period
    rerun = run_scenario_dict(scenario, sinks=(), source=f"{log.path} /scenario").result
    if rerun.status == INTERRUPTED:  # stopped by a signal: nothing to compare (not a difference)
        raise last_signal() or Interrupted()
    n = log.n_samples
    problems, compared = [], 0
    if n > rerun.n_samples:
        problems.append(f"the log has {n} samples, the re-run only {rerun.n_samples} ({rerun.status})")
        n = rerun.n_samples
    if finished:
        if log.n_samples != rerun.n_samples:
            problems.append(f"the log has {log.n_samples} samples, the re-run {rerun.n_samples}")
        if log.recorded["status"] != rerun.status:
            problems.append(f"status: logged {log.recorded['status']}, re-run {rerun.status}")
    t = log.loops[next(iter(log.loops))]["t"] if log.loops else np.empty(0)
    for name, arrays in log.loops.items():
        for f in LOOP_FIELDS + tuple(f for f in STAGE_FIELDS if f in arrays or f in rerun.loops[name]):
            if f not in arrays or f not in rerun.loops[name]:
                problems.append(f"/loop/{name} {f}: in {'the re-run' if f not in arrays else 'the log'} only")
                continue
            a, b = arrays[f][:n], rerun.loops[name][f][:n]
            compared += a.size
            k = first_bit_difference(a, b)
            if k is not None:
                problems.append(f"/loop/{name} {f} differs first at sample {k} (t = {t[k]:.6g} s): "
                                f"logged {a[k].tolist()!r}, re-run {b[k].tolist()!r}")
    idx = np.rint(log.pose_t / log.info.period).astype(int)
    keep = idx < n
    for what, logged, fresh in (("position", log.pose_pos, rerun.body_pos), ("orientation", log.pose_quat,
                                                                            rerun.body_quat)):
        a, b = logged[keep], fresh[idx[keep]]
        compared += a.size
        k = first_bit_difference(a, b) if len(a) else None
        if k is not None:
            problems.append(f"/tf body {what} differs first at t = {log.pose_t[k]:.6g} s")
    return Verification(ok=not problems, compared=compared, problems=tuple(problems))
