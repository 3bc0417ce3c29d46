"""Layer 6, logs: sinks that observe a run (MCAP for Foxglove, Rerun .rrd, live views) and the reader used by replay.

May import: config, control, plants, simulation, metrics.
"""

from ftstab_mj.logs.mcap_sink import McapSink
from ftstab_mj.logs.rerun_sink import RerunSink

__all__ = ["McapSink", "RerunSink"]
