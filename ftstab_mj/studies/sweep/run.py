"""Running a sweep: the runs still to do, on the chosen engine, journaled as they finish, then the table.

Files in the output directory DIR, for a sweep named NAME:

    NAME.sweep.json   what was run: the fingerprint of the rows and of the base (checked on --resume)
    NAME.jsonl        the journal, one line per finished run (see table.py)
    NAME.parquet      the table (or NAME.csv), written at the end, also after an interruption

Resuming (``resume=True``) reads the journal and runs only the rows missing from it: finished
runs, failed ones included (a failure is a result), are never redone. Runs lost by the engine
(a dead worker) are not journaled, so a resume retries them.
"""

from __future__ import annotations

import hashlib
import json
import sys
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from ftstab_mj.config.errors import EngineError, SweepError
from ftstab_mj.simulation.interrupts import interruption
from ftstab_mj.simulation.records import COMPLETED
from ftstab_mj.studies.sweep.engine import execute
from ftstab_mj.studies.sweep.expand import Row
from ftstab_mj.studies.sweep.table import Journal, load_writer, make_row, read_journal, write_table


@dataclass
class SweepOutcome:
    """What a call of :func:`run_sweep` did. ``elapsed_s``: wall time of this call (s); ``rows_wall_s``: wall
    time from the start of its first run to the table written (s; 0 when nothing ran), i.e. without what
    the call spent before a row could start (an engine's start-up)."""

    table: Path
    total: int  # rows of the sweep
    done: int  # rows in the table (finished now or earlier)
    ran: int  # rows run by this call
    failed: int  # rows of the table whose status is not "completed"
    elapsed_s: float
    lost: list[int] = field(default_factory=list)  # rows lost by the engine (not in the table)
    interrupted: bool = False
    statuses: dict[str, int] = field(default_factory=dict)  # {status: rows of the table with it}
    rows_wall_s: float = 0.0
    signal: int = 0  # the signal that interrupted the sweep (interrupted: SIGINT, SIGTERM or SIGHUP)

    @property
    def interrupted_code(self) -> int:
        """The exit code of an interrupted sweep: 128 + its signal (130 Ctrl-C, 143 SIGTERM, 129 SIGHUP)."""
        return 128 + (self.signal or 2)


def fingerprint(rows: list[Row], identity: dict) -> str:
    """sha256 of the rows (index, draw, parameters) and of ``identity`` (the resolved base of every run)."""
    data = {"identity": identity, "rows": [[r.index, r.sample, [list(p) for p in r.params]] for r in rows]}
    return hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()


def _say(stream, text: str) -> None:
    if stream is not None:
        print(text, file=stream, flush=True)


class Progress:
    """Progress of ``total`` items (rows, states) finishing one by one, on ``stream`` (None: silent).

    On a terminal: one status line rewritten in place (carriage return) at most every ``refresh`` s of
    wall time, ``[done/total] 12.3 rows/s, ~40 s left, 1 failed``, and the lines that must stay (a failed
    or lost item: :meth:`note`) printed above it. Elsewhere (a log file, a pipe): the plain line of every
    item as it finishes (:meth:`step`'s ``line``), nothing rewritten. ``done`` counts from ``before``
    (items finished earlier); rate and ETA are over the items of this call since it started.
    """

    def __init__(self, stream, total: int, before: int = 0, unit: str = "rows", refresh: float = 0.5,
                 clock=time.monotonic):
        self.stream, self.total, self.before, self.unit = stream, total, before, unit
        self.refresh, self.clock = refresh, clock
        self.tty = stream is not None and getattr(stream, "isatty", lambda: False)()
        self.ran, self.failed, self.start, self.shown_at, self.width = 0, 0, clock(), None, 0

    def status(self) -> str:
        """``[done/total] R unit/s, ~E s left, F failed`` (rate and ETA once an item finished, failures if any)."""
        text = f"[{self.before + self.ran}/{self.total}]"
        elapsed, left = self.clock() - self.start, self.total - self.before - self.ran
        if self.ran and elapsed > 0:
            rate = self.ran / elapsed
            eta = left / rate
            text += (f" {rate:.3g}" if rate < 1000 else f" {rate:.0f}") + f" {self.unit}/s"
            text += f", ~{eta:.0f} s left" if eta >= 0.5 else ", <1 s left" if left else ""
        return text + (f", {self.failed} failed" if self.failed else "")

    def step(self, failed: bool = False, line: str | None = None, count: int = 1) -> None:
        """``count`` items finished (``failed``: one of them not completed); ``line``: its plain log line (on a
        terminal only a failed item's line is printed, above the status)."""
        self.ran += count
        self.failed += bool(failed)
        if self.stream is None:
            return
        if not self.tty:
            if line is not None:
                _say(self.stream, line)
            return
        if failed and line is not None:
            self.note(line)
        elif (self.shown_at is None or self.clock() - self.shown_at >= self.refresh
              or self.before + self.ran == self.total):
            self._show()

    def note(self, line: str) -> None:
        """A line that stays (a failed or lost item), above the status line on a terminal."""
        if self.stream is None:
            return
        if self.tty and self.width:
            self.stream.write("\r" + " " * self.width + "\r")
        _say(self.stream, line)
        if self.tty:
            self.width = 0
            self._show()

    def _show(self) -> None:
        text = self.status()
        self.stream.write("\r" + text + " " * max(0, self.width - len(text)))
        self.stream.flush()
        self.width, self.shown_at = len(text), self.clock()

    def close(self) -> None:
        """End the status line (terminal), brought up to date: what follows starts on a line of its own."""
        if self.tty and (self.width or self.ran):
            self._show()
            self.stream.write("\n")
            self.stream.flush()
            self.width = 0


def run_sweep(name: str, rows: list[Row], task, out_dir, identity: dict, *, engine: str = "serial",
              workers: int = 1, scheduler: str | None = None, resume: bool = False, fmt: str = "parquet",
              progress=sys.stderr, ahead=None) -> SweepOutcome:
    """Run the rows not yet journaled in ``out_dir``; write the table. See the module docstring.

    task: picklable, task(index, params) -> {"status", "error", "metrics"}; params: ((key path, value), ...).
    identity: JSON-able description of what every run starts from (part of the fingerprint).
    progress: stream for the progress (None: silent): one line per finished run, or one status line
    rewritten in place on a terminal (:class:`Progress`).
    ahead: the engine started ahead (engine.started_ahead), or None.
    """
    t0 = time.perf_counter()
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise SweepError(str(out), "(--out)", "a directory for the sweep's table", "a file")
    out.mkdir(parents=True, exist_ok=True)
    header, journal_path, table_path = out / f"{name}.sweep.json", out / f"{name}.jsonl", out / f"{name}.{fmt}"
    fp = fingerprint(rows, identity)
    if header.exists():
        if not resume:
            raise SweepError(str(out), name, "an output directory without this sweep (or --resume to continue it)",
                             f"{header.name} of an earlier run")
        if json.loads(header.read_text(encoding="utf-8")).get("fingerprint") != fp:
            raise SweepError(str(header), "fingerprint", "the sweep being resumed (same rows, same base scenario)",
                             "a different sweep: its parameters or its base changed since")
        done = read_journal(journal_path)
    else:
        header.write_text(json.dumps({"name": name, "rows": len(rows), "fingerprint": fp}, indent=2) + "\n",
                          encoding="utf-8")
        journal_path.unlink(missing_ok=True)  # a journal without its header is not ours to continue
        done = {}
    by_index = {r.index: r for r in rows}
    todo = [r for r in rows if r.index not in done]
    where = (f"engine {engine}" + (f", scheduler {scheduler}" if scheduler else
                                   f", {workers} worker(s)" if engine != "serial" else ""))
    _say(progress, f"sweep {name}: {len(rows)} runs, {len(done)} done earlier, {len(todo)} to run ({where})")
    outcome = SweepOutcome(table_path, len(rows), len(done), 0, 0, 0.0)
    journal = Journal(journal_path)
    results = execute(((r.index, r.params) for r in todo), task, engine, workers, scheduler,
                      meanwhile=lambda: load_writer(table_path), ahead=ahead)  # imported while the workers run
    first_start = None  # time.time() at the start of the first run (its worker's clock: this machine's, or one kept in step)
    shown = Progress(progress, len(rows), before=len(done))
    try:
        for i, result in results:
            if result is None:
                outcome.lost.append(i)
                shown.note(f"row {i}: lost (its worker process died); --resume retries it")
                continue
            first_start = result["started_at"] if first_start is None else min(first_start, result["started_at"])
            r = by_index[i]
            row = make_row(i, r.sample, r.params, result)
            journal.append(row)
            done[i] = row
            outcome.ran += 1
            left = len(todo) - outcome.ran - len(outcome.lost)
            eta = (time.perf_counter() - t0) / outcome.ran * left
            err = f": {row['error'].splitlines()[0]}" if row["error"] else ""
            shown.step(row["status"] != COMPLETED,
                       f"[{len(done)}/{len(rows)}] row {i} {row['status']} in {row['elapsed_s']:.2f} s{err}"
                       + (f"; {left} to go, ~{eta:.0f} s left" if left else ""))
    except KeyboardInterrupt as exc:
        outcome.interrupted, outcome.signal = True, interruption(exc).signum
    except EngineError:
        if not done:  # nothing ran: leave no trace, so the same command works once the engine is there
            journal.close()
            header.unlink()
            journal_path.unlink(missing_ok=True)
        raise
    finally:
        shown.close()
        results.close()  # stops the engine (pool, cluster) even when interrupted
        journal.close()
    if outcome.interrupted:
        # the journal is the record: a Ctrl-C between journaling a row and noting it in `done`
        # must not leave a table that lacks a journaled row (the resume would skip it)
        done = read_journal(journal_path)
    write_table(list(done.values()), table_path)
    outcome.done = len(done)
    outcome.statuses = dict(Counter(row["status"] for row in done.values()))
    outcome.failed = outcome.done - outcome.statuses.get(COMPLETED, 0)
    outcome.elapsed_s = time.perf_counter() - t0
    if first_start is not None:
        outcome.rows_wall_s = time.time() - first_start
    if outcome.interrupted:
        _say(progress, f"interrupted: {outcome.done}/{len(rows)} runs in {table_path}; --resume runs the others")
    return outcome

