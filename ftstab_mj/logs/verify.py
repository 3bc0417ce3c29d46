"""``ftstab replay --verify``: compare a log with a re-run of its scenario, bit for bit.

The re-run itself is the scenario runner's (ftstab_mj.scenario.run.verify_log): logs/ imports
nothing above it.

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
from ftstab_mj.records import COMPLETED, DIVERGED, LOOP_FIELDS, STAGE_FIELDS


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


def rerun_scenario(log) -> dict:
    """The scenario to re-run for ``log`` (a reader.LogData): the recorded one, cut to the samples the
    log holds when it is unfinished (a prefix: samples never depend on the duration)."""
    if not log.info.scenario:
        raise LogError(f"{log.path}: no scenario recorded in /scenario, nothing to re-run")
    scenario = copy.deepcopy(log.info.scenario)
    if not _finished(log) and log.n_samples and isinstance(scenario.get("sim"), dict):
        scenario["sim"]["duration"] = log.n_samples * log.info.period
    return scenario


def _finished(log) -> bool:
    return log.complete and log.recorded is not None and log.recorded["status"] in (COMPLETED, DIVERGED)


def compare_log(log, rerun) -> Verification:
    """Compare ``log`` with ``rerun`` (the sim RunResult of :func:`rerun_scenario`'s scenario, run by
    ftstab_mj.scenario.run.verify_log)."""
    finished = _finished(log)
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
