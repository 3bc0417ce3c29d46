"""``ftstab replay --verify``: compare a log with a re-run of its scenario, bit for bit.

The re-run itself is the scenario runner's (ftstab_mj.scenario.run.verify_log): logs/ imports
nothing above it.

Runs are deterministic (same scenario, same seed, same platform and library versions: identical
samples), so any difference means the log was altered or the code changed behaviour. Compared:
every logged field of every loop over the logged samples (a truncated or interrupted log is a
prefix: the scenario is re-run for as many samples as it holds), the body poses of /tf, and the status of a complete log. Floats are compared by their
bits (so -0.0 != 0.0); non-finite values count as equal when both are non-finite (the log stores
them as null).

A log records the path that computed it (``/run_info`` kernel: "native", the C kernel, or "python").
Both paths do the same operations in the same order but for pow (libm's against NumPy's SIMD one, each
within 1 ulp, where NumPy has one: measured bit-identical on x86-64 without AVX-512), so one sample
differs by a few ulp at most; the closed loop carries
the earlier samples' differences forward, at most unchanged when it does not amplify them. A log
re-run on the other path is therefore compared with the tolerance :func:`cross_path_tolerance`:
sample k may differ by ``CROSS_PATH_ULPS * (k + 1)`` units of 2^-52 relative to max(1, |value|). A log
re-run on its own path, or one that does not record its path, is compared bit for bit. The log is read as it streams and each batch of the re-run compared as it comes
(:class:`StreamingComparison`), so a long log is verified in memory that does not grow with it.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass

import numpy as np

from ftstab_mj.config.errors import LogError
from ftstab_mj.simulation.records import COMPLETED, DIVERGED, LOOP_FIELDS, STAGE_FIELDS


CROSS_PATH_ULPS = 4  # what one sample may add, in units of 2^-52: two pow calls (<= 1 ulp each), margin
KERNELS = ("native", "python")


@dataclass(frozen=True)
class Verification:
    """ok: every compared value identical (or within the cross-path tolerance); compared: number of
    float values compared; problems: readable lines, the first differing sample of each field that
    differs; paths: (the log's kernel, the re-run's) when they differ and the tolerance applied, else
    None; worst: the largest difference found across paths, as a fraction of its tolerance (0 same path)."""

    ok: bool
    compared: int
    problems: tuple
    paths: tuple | None = None
    worst: float = 0.0


def cross_path_tolerance(k, values: np.ndarray) -> np.ndarray:
    """The largest difference accepted between a log and its re-run on the other kernel path, for
    ``values`` (m, ...) the logged samples of indices k (m,): CROSS_PATH_ULPS * (k + 1) * 2^-52 * max(1, |value|)."""
    v = np.asarray(values, dtype=float).reshape(len(values), -1)
    k = np.asarray(k, dtype=float).reshape(-1, 1)
    return CROSS_PATH_ULPS * (k + 1.0) * np.finfo(float).eps * np.maximum(1.0, np.abs(v))


def first_tolerated_difference(logged: np.ndarray, rerun: np.ndarray, k) -> tuple[int | None, float]:
    """(index of the first sample beyond :func:`cross_path_tolerance`, None if none; the largest
    difference as a fraction of its tolerance). Same shapes, k (m,) the samples' indices; non-finite values
    as in first_bit_difference."""
    if len(logged) == 0:
        return None, 0.0
    a = np.asarray(logged, dtype=float).reshape(len(logged), -1)
    b = np.asarray(rerun, dtype=float).reshape(len(rerun), -1)
    fa, fb = np.isfinite(a), np.isfinite(b)
    both = fa & fb
    ratio = np.where(both, np.abs(np.where(both, a - b, 0.0)) / cross_path_tolerance(k, np.where(both, a, 0.0)), 0.0)
    bad = np.flatnonzero((fa != fb).any(axis=1) | (ratio > 1.0).any(axis=1))
    return (int(bad[0]) if bad.size else None), float(ratio.max(initial=0.0))


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


class StreamingComparison:
    """The comparison of a log with the re-run of its scenario, as the re-run streams: a sink (open, write, close) of the re-run that checks
    each of its batches against the next samples of the log, read as it streams (reader.LogStream), so
    neither the log nor the re-run is held whole. ``log``: the reader.LogData of a first reading (its
    n_samples, status, completeness). :meth:`verification` once the re-run is over.

    Each field's first differing sample is reported (sample index, t, both values); a /tf pose is
    compared with the re-run sample at rint(t / period) when that sample's batch passes (a log written
    by a run has it in the same chunk), and one that comes later than its sample is a problem."""

    def __init__(self, log):
        from ftstab_mj.logs.reader import LogStream

        self.log, self.period = log, log.info.period
        self.reading = LogStream(log.path, poses="chunks")
        self._chunks = self.reading.batches()
        self._held = {}  # loop name -> [arrays] of log samples read but not compared yet
        self._poses = []  # [(index (k,), t (k,), pos (k, nbody, 3), quat (k, nbody, 4))] of /tf poses not compared yet
        self.done = 0  # re-run samples seen
        self.compared = 0
        self.first = {}  # (loop, field) -> problem line (the first difference only)
        self.only = {}  # (loop, field) -> which side has it
        self.tf = {}  # "position" | "orientation" -> problem line
        self.late = None
        self.paths = None  # (log's kernel, re-run's) when they differ: compared with the cross-path tolerance
        self.worst = 0.0

    def open(self, info) -> None:
        logged, rerun = self.log.info.kernel, info.kernel
        if logged in KERNELS and rerun in KERNELS and logged != rerun:
            self.paths = (logged, rerun)

    def _first_difference(self, logged, rerun, k) -> int | None:
        """The first differing sample of ``logged`` (samples of indices k (m,)) and ``rerun``: bit for bit on the same
        path, beyond cross_path_tolerance across paths."""
        if self.paths is None:
            return first_bit_difference(logged, rerun)
        first, worst = first_tolerated_difference(logged, rerun, k)
        self.worst = max(self.worst, worst)
        return first

    def close(self, status, metrics, message: str = "") -> None:
        pass

    def release(self) -> None:
        """Let the log's file go (also when the re-run stopped early)."""
        self._chunks.close()

    def _pull(self) -> bool:
        """Read the log's next chunk into the buffers; False at its end."""
        loops = next(self._chunks, None)
        if loops is None:
            return False
        for name, arrays in loops.items():
            if len(arrays["t"]):
                self._held.setdefault(name, []).append(arrays)
        t, pos, quat = self.reading.chunk_poses
        if len(t):
            self._poses.append((np.rint(t / self.period).astype(int), t, pos, quat))
        return True

    def _take(self, name: str, m: int) -> dict | None:
        """The log's next m samples of loop ``name`` ({field: array}), None when it has fewer."""
        while sum(len(a["t"]) for a in self._held.get(name, [])) < m:
            if not self._pull():
                return None
        parts, out, need = self._held[name], [], m
        while need:
            a = parts[0]
            k = min(need, len(a["t"]))
            out.append({f: x[:k] for f, x in a.items()})
            if k == len(a["t"]):
                parts.pop(0)
            else:
                parts[0] = {f: x[k:] for f, x in a.items()}
            need -= k
        return {f: np.concatenate([o[f] for o in out]) for f in out[0]}

    def write(self, batch) -> None:
        off, m = self.done, len(batch)
        self.done += m
        m = max(0, min(m, self.log.n_samples - off))  # the log's samples only
        if m == 0:
            return
        for name, fresh in batch.loops.items():
            logged = self._take(name, m)
            if logged is None:
                continue
            for f in LOOP_FIELDS + tuple(f for f in STAGE_FIELDS if f in logged or f in fresh):
                if f not in logged or f not in fresh:
                    self.only.setdefault((name, f), "the re-run" if f not in logged else "the log")
                    continue
                a, b = logged[f], fresh[f][:m]
                self.compared += a.size
                if (name, f) in self.first:
                    continue
                k = self._first_difference(a, b, np.arange(off, off + m))
                if k is not None:
                    self.first[name, f] = (f"/loop/{name} {f} differs first at sample {off + k} (t = {logged['t'][k]:.6g} "
                                           f"s): logged {a[k].tolist()!r}, re-run {b[k].tolist()!r}")
        if not self._poses:
            return
        i, t, pos, quat = (np.concatenate(x) for x in zip(*self._poses))
        late = i < off
        if late.any() and self.late is None:
            self.late = f"/tf pose at t = {t[late][0]:.6g} s comes after the samples it belongs to"
        now = ~late & (i < off + m)
        for what, logged, fresh in (("position", pos[now], batch.body_pos), ("orientation", quat[now], batch.body_quat)):
            self.compared += logged.size
            k = self._first_difference(logged, fresh[i[now] - off], i[now]) if len(logged) else None
            if k is not None and what not in self.tf:
                self.tf[what] = f"/tf body {what} differs first at t = {t[now][k]:.6g} s"
        later = i >= off + m
        self._poses = [(i[later], t[later], pos[later], quat[later])] if later.any() else []

    def verification(self, rerun) -> Verification:
        """The outcome, given the re-run's RunResult (its status and sample count)."""
        log, problems = self.log, []
        finished = _finished(log)
        if log.n_samples > rerun.n_samples:
            problems.append(f"the log has {log.n_samples} samples, the re-run only {rerun.n_samples} ({rerun.status})")
        if finished:
            if log.n_samples != rerun.n_samples:
                problems.append(f"the log has {log.n_samples} samples, the re-run {rerun.n_samples}")
            if log.recorded["status"] != rerun.status:
                problems.append(f"status: logged {log.recorded['status']}, re-run {rerun.status}")
        self.release()
        for name in [lp.name for lp in log.info.loops]:
            for f in LOOP_FIELDS + STAGE_FIELDS:
                if (name, f) in self.only:
                    problems.append(f"/loop/{name} {f}: in {self.only[name, f]} only")
                elif (name, f) in self.first:
                    problems.append(self.first[name, f])
        problems += [self.tf[w] for w in ("position", "orientation") if w in self.tf]
        if self.late:
            problems.append(self.late)
        if problems and self.paths:
            problems.append(f"the log was written on the {self.paths[0]} kernel path and re-run on the {self.paths[1]} "
                            f"one: compared within {CROSS_PATH_ULPS} (k + 1) ulp at sample k; re-run it on the "
                            f"{self.paths[0]} path to compare bit for bit")
        return Verification(ok=not problems, compared=self.compared, problems=tuple(problems), paths=self.paths,
                            worst=self.worst)
