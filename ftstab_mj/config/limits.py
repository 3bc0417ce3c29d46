"""Every size and count the tool accepts from its user, in one table, each checked before memory is spent.

The modules that check a limit import it from here (config/validate.py for scenario, sweep and --set data;
plants/user.py for MJCF files; logs/reader.py for logs; studies/ for counts), so a limit has one value and one
reason. :data:`TABLE` is what the README's limits table shows (:func:`markdown`); a test checks they agree.
"""

from __future__ import annotations

KiB, MiB, GiB = 1 << 10, 1 << 20, 1 << 30

# -- input files -----------------------------------------------------------------------------------------------
MAX_FILE_BYTES = 1 * MiB  # a scenario, sweep, comparison or expectations file (.toml): ours are ~2 kB to ~100 kB
MAX_MJCF_BYTES = 16 * MiB  # a user's MJCF model file: MuJoCo's own test models are < 1 MB; 200 MB took 55 s, 1.9 GB
MAX_INCLUDE_BYTES = 16 * MiB  # each file an MJCF <include>s
MAX_INCLUDES = 256  # <include> files of one model, nested ones counted
MAX_PLUGIN_BYTES = 1 * MiB  # a plugin's source file
# -- logs --------------------------------------------------------------------------------------------------------
MAX_LOG_BYTES = 64 * GiB  # a log file read by replay, report, check (mapped, not read into memory)
MAX_RECORD_BYTES = 64 * MiB  # a record other than a chunk in a log read from a pipe (ours: < 1 MB)
MAX_CHUNK_BYTES = 256 * MiB  # one decompressed MCAP chunk (the sink writes ~1 MB per batch)
# -- runs --------------------------------------------------------------------------------------------------------
MAX_SAMPLES = 10 ** 7  # control samples per run (duration / period)
MAX_STEPS = 10 ** 9  # physics steps per run
MAX_STEPS_PER_PERIOD = 10 ** 6  # physics steps per control period
MAX_DELAY_SAMPLES = 10 ** 6  # a sensor delay, in control periods (the delay line holds them all)
# -- studies -----------------------------------------------------------------------------------------------------
MAX_SWEEP_ROWS = 10 ** 5  # runs of one sweep (grid points x samples), and a sweep's samples
MAX_STATES = 10 ** 6  # initial states of one `montecarlo`
# -- values MuJoCo holds ----------------------------------------------------------------------------------------
MUJOCO_MAXVAL = 1e10  # mjMAXVAL: MuJoCo leaves a control beyond it unapplied and resets a state or acceleration beyond it
MAX_STATE = 1e9  # |z0_i|, a signal's or a reference's values: an order below MUJOCO_MAXVAL, so our check fires first

TABLE = (  # (what, limit as the user reads it, where it is checked, why)
    ("scenario, sweep, comparison, expectations file", "1 MiB", "read", "ours are 2 kB to 100 kB"),
    ("MJCF model file", "16 MiB", "before MuJoCo parses it", "a 200 MB model took 55 s and 1.9 GB"),
    ("each MJCF include", "16 MiB, 256 includes", "before MuJoCo parses the model", "as the model"),
    ("plugin source file", "1 MiB", "before it is imported", "a law or plant module is a few kB"),
    ("log file (replay, report, check)", "64 GiB", "at open", "mapped, read in bounded memory"),
    ("log from a pipe or standard input", "64 GiB, each record 64 MiB (a chunk 256 MiB)",
     "as it is read: its magic in the first 8 bytes, then each record's opcode and length", "read record by record"),
    ("decompressed MCAP chunk", "256 MiB", "before it is decompressed", "the sink writes ~1 MB per batch"),
    ("control samples per run", "10^7", "scenario load", "~3.5 GB of logs"),
    ("physics steps per run", "10^9", "scenario load", "about an hour of computing"),
    ("physics steps per control period", "10^6", "scenario load", "32 B per step and loop held per batch"),
    ("sensor delay", "10^6 control periods", "scenario load", "the delay line holds every delayed sample"),
    ("sweep runs (grid x samples)", "10^5", "sweep load", "a journal line per run"),
    ("montecarlo --states", "10^6", "before any run", "hours of computing"),
    ("scenario, sweep, comparison names", "200 characters", "load", "NAME.sweep.json must fit in 255 bytes"),
)


def markdown() -> str:
    """:data:`TABLE` as the README's Markdown table."""
    lines = ["| What | Largest accepted | Checked | Why |", "|---|---|---|---|"]
    lines += [f"| {what} | {limit} | {where} | {why} |" for what, limit, where, why in TABLE]
    return "\n".join(lines)
