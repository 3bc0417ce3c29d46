"""Run logs: sinks that observe a run (MCAP for Foxglove, Rerun .rrd) and the reader used by replay."""

from ftstab_mj.logs.mcap_sink import McapSink
from ftstab_mj.logs.rerun_sink import RerunSink

__all__ = ["McapSink", "RerunSink"]
