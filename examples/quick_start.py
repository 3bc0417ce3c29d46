"""Quick start: run a shipped scenario from Python, read its log back, plot z and V1.

The robust law on the cart (scenarios/cart_r2_robust.toml, shortened to 4 s): `ftstab_mj.run` runs it
and writes its logs, `ftstab_mj.replay` reads the MCAP log back (the same samples, bit for bit, and the
same metrics), and matplotlib draws the two coordinates of z and V1 against Theorem 1's time bound.

Run: python examples/quick_start.py [--out DIR] [--duration S]   (writes DIR/quick_start.png)
"""

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # no display needed
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import ftstab_mj  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="runs", help="where the logs and the figure go (default: runs)")
    ap.add_argument("--duration", type=float, default=4.0, help="simulated seconds (default 4)")
    args = ap.parse_args(argv)
    out = Path(args.out)

    res = ftstab_mj.run("cart_r2_robust", out=out, overrides={"sim.duration": args.duration})
    log = ftstab_mj.replay(res.logs["mcap"])  # what a later session, or a colleague, reads back
    same = all(np.array_equal(res.samples["cart"][f], log.samples["cart"][f], equal_nan=True)
               for f in res.samples["cart"])
    m = log.metrics["loops"]["cart"]
    print(f"status {log.status}; replayed samples identical: {same}; metrics identical: {log.metrics == res.metrics}")
    print(f"V1 < {m['settle_level']:g} from t = {m['settle_time']} s (Theorem 1's bound T(z0) = {m['time_bound']:.2f} s)")

    s = log.samples["cart"]
    t, z, V1 = s["t"], s["z"], s["V1"]
    fig, (ax_z, ax_v) = plt.subplots(2, 1, figsize=(7, 5.5), sharex=True, constrained_layout=True)
    ax_z.plot(t, z[:, 0], label="z1 = x (m)")
    ax_z.plot(t, z[:, 1], label="z2 = x' (m/s)")
    ax_z.axhline(0.0, color="0.6", lw=0.8)
    ax_z.set_ylabel("z")
    ax_z.legend()
    ax_z.set_title("cart_r2_robust: the robust law under a sine disturbance")
    ax_v.semilogy(t, V1, label="V1")
    ax_v.axhline(m["settle_level"], color="C2", ls="--", label=f"settle level {m['settle_level']:g}")
    if m["time_bound"] is not None and m["time_bound"] <= t[-1]:
        ax_v.axvline(m["time_bound"], color="C3", ls=":", label="Theorem 1's T(z0)")
    if m["settle_time"] is not None:
        ax_v.axvline(m["settle_time"], color="C2", ls=":", label=f"settled at {m['settle_time']:.2f} s")
    ax_v.set_xlabel("t (s)")
    ax_v.set_ylabel("V1 (chain units)")
    ax_v.legend(loc="lower left")
    png = out / "quick_start.png"
    fig.savefig(png, dpi=100)
    print(f"wrote {png}")
    return png


if __name__ == "__main__":
    main()
