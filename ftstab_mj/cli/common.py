"""What the verbs of ``ftstab`` share: the parser class (one-line errors, exit 2), argument types
(numbers in a range, gains, ports, worker counts), the header and progress line they print, and the
log reading with its truncation warning. No verb logic here, no domain logic."""

from __future__ import annotations

import argparse
import math
import os
import sys

from ftstab_mj.config.errors import UsageError

__all__ = ["GAIN_MAX", "GAIN_MIN", "Parser", "UsageError", "certificate_text", "end_progress", "floats", "gains",
           "header", "host_port", "json_safe", "number_in", "numbers", "output_dir", "output_file", "port",
           "progress_line", "read_log", "region", "streamed_metrics", "workers"]

GAIN_MIN, GAIN_MAX = 1e-3, 1e6  # certify/design: gains the interval bounds stay meaningful for


class Parser(argparse.ArgumentParser):
    """argparse that reports errors as one line and exit code 2 (argparse's own code for usage), and takes
    any negative number as a value (``--k -1e-3``, ``--seed -inf``), not only argparse's -1 and -.5 forms."""

    def __init__(self, *args, **kwargs):
        import re

        super().__init__(*args, **kwargs)
        # argparse reads an argument that starts with '-' and is not a number by this pattern as an option
        self._negative_number_matcher = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^-(inf|infinity|nan)$", re.I)

    def error(self, message):  # noqa: D401 - argparse API
        raise UsageError(f"{self.prog}: {message}")


def gains(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers like 1,2, got {text!r}") from None
    for i, g in enumerate(values):
        if not GAIN_MIN <= g <= GAIN_MAX:  # also refuses nan and inf
            raise argparse.ArgumentTypeError(f"expected every gain in [{GAIN_MIN:g}, {GAIN_MAX:g}], "
                                             f"found l_{i + 1} = {g!r}")
    return values


def number_in(lo, hi, kind=float, what=""):
    """An argparse type: a number of ``kind`` in [lo, hi] (inclusive), with a one-line error."""
    def parse(text):
        try:
            x = kind(text)
        except ValueError:
            x = None
        if x is None or not lo <= x <= hi:
            fmt = str if kind is int else (lambda v: f"{v:g}")
            raise argparse.ArgumentTypeError(f"expected {'an integer' if kind is int else 'a number'} in "
                                             f"[{fmt(lo)}, {fmt(hi)}]{what}, got {text!r}")
        return x
    return parse


def output_dir(path, what: str, make: bool = True):
    """``path`` (a Path) made a directory to write in (``make``; else only checked), before any work: a file,
    a FIFO, a device, a symbolic link loop or a folder that cannot be made is one UsageError line naming
    ``what`` (e.g. "--out DIR")."""
    from pathlib import Path

    out = Path(path)
    if (out.exists() or out.is_symlink()) and not out.is_dir():
        raise UsageError(f"{what}: expected a directory for the output, found "
                         + ("a symbolic link that leads nowhere" if not out.exists() else "a file"))
    try:
        if make:
            out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise UsageError(f"{what}: expected a directory the output can be written in, found {exc.strerror}") from None
    return out


def output_file(path, what: str) -> None:
    """Refuse (one UsageError line naming ``what``) an output file that exists and is not a regular file:
    a FIFO would block the write until a reader comes, a device would take the bytes."""
    if os.path.lexists(path) and not os.path.isfile(path):
        raise UsageError(f"{what}: expected a regular file to write (or none), found "
                         + ("a directory" if os.path.isdir(path) else "no regular file"))


def json_safe(x):
    """Non-finite floats as null (strict JSON), recursively."""
    if isinstance(x, float):
        return x if x == x and abs(x) != float("inf") else None
    if isinstance(x, dict):
        return {k: json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [json_safe(v) for v in x]
    return x


def header(name: str, description: str, sets) -> str:
    """"name: description", and when --set changed the file, a second line saying that the description
    was written for the file and what changed (it may no longer hold: a duration, a bound, a law)."""
    if not sets:
        return f"{name}: {description}"
    keys = ", ".join(dict.fromkeys(text.split("=", 1)[0].strip() for text in sets))  # (validated by now)
    return (f"{name}: {description}\n  (description possibly stale: written for the file, before --set {keys})")


def progress_line():
    """A callback that rewrites one status line on stderr when it is a terminal (else None)."""
    if not sys.stderr.isatty():
        return None

    def say(text):
        print(f"\r\033[K{text}", end="", file=sys.stderr, flush=True)
    return say


def end_progress(say):
    if say is not None:
        print("\r\033[K", end="", file=sys.stderr, flush=True)


def certificate_text(hong, cert) -> str:
    lines = [f"form {cert.form}, r = {hong.r}, k = {hong.k:g}, gains = {', '.join(f'{g:g}' for g in hong.gains)}"]
    if cert.form == "full":
        gap = f"gap {100 * cert.gap:.2g} %" if cert.gap is not None and cert.gap == cert.gap else "no lower bound"
        lines.append(f"  status: {cert.status}   (c_lower > 0 proven: certified; a state with dV1/dt >= 0: not certified)")
        lines.append(f"  c       = {cert.c_lower:.6g}    (guaranteed: c >= c_lower; best witness c <= {cert.c_upper:.6g}, "
                     f"{gap})   alpha  = {cert.alpha:.6g}   (dV1/dt <= -c V1^alpha)")
        if cert.c_prime_upper is not None:
            lines.append(f"  c'      = {cert.c_prime_upper:.6g}    (guaranteed upper bound)   alpha' = {cert.alpha_prime:.6g}"
                         f"   (|dV1/dz_r| <= c' V1^alpha')")
        lines.append(f"  witness on V1 = 1: z = ({', '.join(f'{x:.6g}' for x in cert.witness)})")
    else:
        neg = {True: "negative (proven)", False: "NOT negative (witness below)", None: "undecided"}[cert.region_negative]
        lines.append(f"  dV1/dt on {cert.region_inner:g} <= |z|_inf <= {cert.region_radius:g}: {neg}")
        if cert.witness is not None:
            lines.append(f"  witness: z = ({', '.join(f'{x:.6g}' for x in cert.witness)}), dV1/dt >= {cert.region_max_dV1dt:.6g}")
    lines.append(f"  {cert.boxes} boxes, {cert.seconds:.2f} s CPU (witness search: {cert.samples} samples, seed {cert.seed})")
    if cert.note:
        lines.append(f"  note: {cert.note}")
    return "\n".join(lines)


def numbers(lo, hi, what):
    """An argparse type: comma-separated finite numbers in [lo, hi] (lo excluded when lo == 0 and
    ``what`` says positive), with a one-line error."""
    def parse(text):
        try:
            xs = tuple(float(x) for x in text.split(","))
        except ValueError:
            xs = None
        if not xs or not all(lo <= x <= hi for x in xs) or (what == "positive" and not all(x > 0 for x in xs)):
            raise argparse.ArgumentTypeError(f"expected comma-separated {what} numbers in [{lo:g}, {hi:g}], got {text!r}")
        return xs
    return parse


def region(text: str):
    try:
        inner, outer = (float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected R_IN,R_OUT (two numbers), got {text!r}") from None
    if not (0 < inner < outer <= 1e6):
        raise argparse.ArgumentTypeError(f"expected 0 < R_IN < R_OUT <= 1e6, got {text!r}")
    return inner, outer


def read_log(path):
    """logs.reader.read_log + the truncation warning on stderr."""
    from ftstab_mj.logs import reader

    log = reader.read_log(path)
    if log.warning:
        print(f"warning: {log.warning}", file=sys.stderr)
    return log


def streamed_metrics(path):
    """reader.stream_metrics (the log read as it streams) + the truncation warning on stderr, and a
    status line on a terminal while a certificate is computed."""
    from ftstab_mj.logs.reader import stream_metrics

    say = progress_line()
    try:
        log, metrics = stream_metrics(path, say)
    finally:
        end_progress(say)
    if log.warning:
        print(f"warning: {log.warning}", file=sys.stderr)
    return log, metrics


def replayed_metrics(log) -> dict:
    """Metrics recomputed from a log read whole (LogData), with the recorded status (interrupted if none)."""
    from ftstab_mj.metrics.run_metrics import compute_metrics
    from ftstab_mj.simulation.records import INTERRUPTED

    status = log.recorded["status"] if log.recorded else INTERRUPTED
    return compute_metrics(log.info, log.loops, status)


def write_log_rrd(log, metrics: dict, out, force: bool = False) -> None:
    """The Rerun recording of a log read whole (LogData) at ``out``, as ``ftstab run --rrd`` writes
    it: the plant in 3D at the logged poses, the plots, the blueprint, the status with ``metrics``."""
    from ftstab_mj.logs.rerun_sink import write_rrd

    message = log.recorded.get("message", "") if log.recorded else "truncated log"
    write_rrd(out, log.info, log.loops, (log.pose_t, log.pose_pos, log.pose_quat), metrics["status"],
              metrics, message, force=force)


def port(text: str) -> int:
    try:
        number = int(text)
    except ValueError:
        number = -1
    if not 0 <= number <= 65535:
        raise argparse.ArgumentTypeError(f"expected a TCP port 0..65535 (0: any free one), got {text!r}")
    return number


def host_port(text: str) -> tuple[str, int]:
    """[HOST:]PORT -> (host, port); HOST defaults to 127.0.0.1 (this machine only)."""
    host, _, number = text.rpartition(":")
    return (host or "127.0.0.1"), port(number)


def workers(text: str) -> int:
    if text == "all":
        return os.cpu_count() or 1
    try:
        n = int(text)
    except ValueError:
        n = 0
    if n < 1:
        raise argparse.ArgumentTypeError(f"expected an integer >= 1 or 'all' (every core), got {text!r}")
    return n


def floats(text: str) -> tuple[float, ...]:
    try:
        vals = tuple(float(x) for x in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected comma-separated numbers like 1,0.5, got {text!r}") from None
    if not all(math.isfinite(v) and v >= 0 for v in vals):
        raise argparse.ArgumentTypeError(f"expected finite numbers >= 0, got {text!r}")
    return vals

