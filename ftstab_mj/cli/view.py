"""``ftstab view``: a run's Rerun recording made from its MCAP log (the entities and layout of the one
``ftstab run --rrd`` writes as it goes, the plant at the log's display rate), opened in the Rerun viewer."""

from __future__ import annotations

import os
import sys
from pathlib import Path

from ftstab_mj.cli.common import UsageError, port, read_log, replayed_metrics, write_log_rrd

VERB = "view"
ORDER = 55  # its place in `ftstab --help`


def add_parser(sub) -> None:
    v = sub.add_parser("view", help="open a run in the Rerun viewer (its .rrd made from the MCAP log)",
                       description="Write OUT.rrd (default: LOG.mcap's path with .rrd) from LOG.mcap, a Rerun "
                                   "recording of the run: the plant in 3D at the logged poses, z, u, V1 with Theorem "
                                   "1's envelope, the status and metrics, in the default layout; then open it: a "
                                   "native viewer when there is a display, else a web viewer served on --web-port "
                                   "(until Ctrl-C). Exit 2 on a log that cannot be read.",
                       epilog="example: ftstab run cart_r2_robust --out runs && ftstab view runs/cart_r2_robust.mcap")
    v.add_argument("log", metavar="LOG.mcap")
    v.add_argument("--rrd", metavar="OUT.rrd", help="the recording to write (default: LOG with the suffix .rrd)")
    v.add_argument("--open", choices=("auto", "spawn", "serve", "none"), default="auto",
                   help="auto (default): spawn with a display, else serve; spawn: a native viewer window; serve: "
                        "`rerun --serve-web` in the foreground (the link is printed); none: only write the .rrd")
    v.add_argument("--web-port", type=port, default=9090, metavar="PORT", help="serve: the web viewer's port (9090)")
    v.add_argument("--force", action="store_true",
                   help="let OUT.rrd replace a file that is not an ftstab log (or a symbolic link)")
    v.set_defaults(func=handle)


def handle(args) -> int:
    import shutil
    import subprocess

    from ftstab_mj.logs.live import has_display, rerun_binary

    out = args.rrd or (None if args.log == "-" else str(Path(args.log).with_suffix(".rrd")))
    if out is None:
        raise UsageError("view -: expected --rrd OUT.rrd for a log read from standard input, found none")
    log = read_log(args.log)
    write_log_rrd(log, replayed_metrics(log), out, force=args.force)
    print(f"wrote {out}: {log.n_samples} samples of {', '.join(lp.name for lp in log.info.loops)}")
    how = args.open if args.open != "auto" else ("spawn" if has_display() else "serve")
    if how == "none":
        return 0
    exe = rerun_binary() or shutil.which("rerun")
    if exe is None:
        raise UsageError(f"view: expected the `rerun` command of rerun-sdk on PATH, found none (wrote {out})")
    if how == "spawn":  # a window of its own that outlives this command
        try:
            subprocess.Popen([exe, out], stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL, start_new_session=True)
        except OSError as exc:
            raise UsageError(f"view: expected the `rerun` viewer of rerun-sdk, found {exc.strerror} "
                             f"(open {out} with it yourself)") from None
        print(f"opened {out} in the Rerun viewer")
        return 0
    print(f"serving {out} on port {args.web_port}: open the link Rerun prints below (from your desk: ssh -L "
          f"{args.web_port}:localhost:{args.web_port} -L 9876:localhost:9876 HOST, then the link); Ctrl-C stops it",
          flush=True)
    sys.stdout.flush()
    try:
        os.execv(exe, [exe, "--serve-web", "--web-viewer-port", str(args.web_port), out])
    except OSError as exc:
        raise UsageError(f"view: expected the `rerun` command of rerun-sdk, found {exc.strerror} "
                         f"(serve {out} with `rerun --serve-web` yourself)") from None
