"""The results table of a sweep: one row per run, parameters + status + metrics, and its journal.

A row is flat: nested values are spread over columns named by their path, ``loops.cart.z0[1]``
for a list item, ``metrics.loops.cart.settle_time`` for a metric (``metrics.`` + the path in
:func:`ftstab_mj.metrics.run_metrics.compute_metrics`'s dict). Columns, in this order:

    row, sample                      run index, Monte Carlo draw index
    <key path>...                    the parameters the sweep set for this run
    status, error                    the run's status (records.STATUSES) and its error ("" if none)
    elapsed_s                        wall time of the run (s): the only column that varies between runs
    metrics.<path>...                the metrics (absent, i.e. null, for a failed run)

The journal (``<name>.jsonl``) gets one JSON line per finished run, flushed at once, so an
interrupted sweep loses no finished run; the table (Parquet or CSV) is written from it.
"""

from __future__ import annotations

import json
from pathlib import Path

from ftstab_mj.config.keypath import flatten

# pyarrow is imported where a table is written or read, not here: the worker processes of a sweep
# import this package (the task's module) but never write a table, and pyarrow costs them 0.1 s each

FORMATS = ("parquet", "csv")
VARYING_COLUMNS = ("elapsed_s",)  # everything else is a function of the sweep file only


def make_row(index: int, sample: int, params, result: dict) -> dict:
    """The flat table row of one finished run (params: ((key path, value), ...); result: from the engine)."""
    row = {"row": index, "sample": sample}
    for path, value in params:
        flatten(value, path, row)
    row["status"] = result["status"]
    row["error"] = result.get("error") or ""
    row["elapsed_s"] = result["elapsed_s"]
    flatten(result.get("metrics") or {}, "metrics", row)
    return row


# -- journal ---------------------------------------------------------------------------------------
def read_journal(path: Path) -> dict[int, dict]:
    """{row index: row} of the finished runs in a journal. A last line cut short by a kill is dropped
    (and cut off the file, so appending goes on from a clean line)."""
    if not path.exists():
        return {}
    data = path.read_bytes()
    keep = data[: data.rfind(b"\n") + 1]  # everything up to the last complete line
    if len(keep) != len(data):
        path.write_bytes(keep)
    rows = {}
    for line in keep.decode("utf-8").splitlines():
        if line.strip():
            row = json.loads(line)
            rows[int(row["row"])] = row
    return rows


class Journal:
    """Appends finished rows to the journal file, one flushed JSON line each."""

    def __init__(self, path: Path):
        self._f = open(path, "a", encoding="utf-8")

    def append(self, row: dict) -> None:
        self._f.write(json.dumps(row) + "\n")
        self._f.flush()

    def close(self) -> None:
        self._f.close()


# -- table -----------------------------------------------------------------------------------------
def _column(values: list):
    """One typed column (a pyarrow.Array): bool, int64, float64 or string; None is null. Mixed ints and
    floats are floats; anything else mixed (e.g. a parameter that is a number in one row and a string in another) is text."""
    import pyarrow as pa

    kinds = {type(v) for v in values if v is not None}
    if kinds <= {bool}:
        return pa.array(values, type=pa.bool_())
    if kinds <= {int}:
        return pa.array(values, type=pa.int64())
    if kinds <= {int, float}:
        return pa.array([None if v is None else float(v) for v in values], type=pa.float64())
    return pa.array([None if v is None else (v if isinstance(v, str) else json.dumps(v)) for v in values],
                    type=pa.string())


def to_arrow(rows: list[dict]):
    """The pyarrow.Table of rows (sorted by ``row``), columns in order of first appearance."""
    import pyarrow as pa

    rows = sorted(rows, key=lambda r: r["row"])
    names: dict[str, None] = {}
    for r in rows:
        names.update(dict.fromkeys(r))
    return pa.table({n: _column([r.get(n) for r in rows]) for n in names})


def load_writer(path: Path) -> None:
    """Import what :func:`write_table` needs for ``path``'s format (pyarrow and its Parquet or CSV writer: ~0.05 s
    of CPU), so that a sweep can do it while its workers run rather than after them."""
    import pyarrow  # noqa: F401

    if Path(path).suffix == ".csv":
        import pyarrow.csv  # noqa: F401
    else:
        import pyarrow.parquet  # noqa: F401


def write_table(rows: list[dict], path: Path) -> Path:
    """Write the rows as Parquet (``.parquet``) or CSV (``.csv``), chosen by the file's suffix."""
    table = to_arrow(rows)
    tmp = path.with_name(path.name + ".tmp")  # never leave a half-written table under the real name
    if path.suffix == ".csv":
        import pyarrow.csv as pcsv

        pcsv.write_csv(table, tmp)
    else:
        import pyarrow.parquet as pq

        pq.write_table(table, tmp)
    tmp.replace(path)
    return path


def read_table(path: Path) -> dict[str, list]:
    """{column: values} of a table written by :func:`write_table`."""
    if Path(path).suffix == ".csv":
        import pyarrow.csv as pcsv

        return pcsv.read_csv(path).to_pydict()
    import pyarrow.parquet as pq

    return pq.read_table(path).to_pydict()
