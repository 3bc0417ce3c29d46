"""Sweeps: many runs of a base scenario with varied parameters, serially, on local processes or on Dask.

spec (the sweep file and its loader) -> expand (the runs) -> engine (where they execute) ->
table (one row per run, journaled) ; run.run_sweep ties them together.
"""

from ftstab_mj.studies.sweep.expand import Row, expand
from ftstab_mj.studies.sweep.run import SweepOutcome, run_sweep
from ftstab_mj.studies.sweep.spec import Sweep, load_sweep

__all__ = ["Row", "Sweep", "SweepOutcome", "expand", "load_sweep", "run_sweep"]
