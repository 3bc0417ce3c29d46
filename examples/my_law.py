"""Your own law as a plugin: examples/my_laws.py registers Bhat and Bernstein's finite-time law, the
scenario examples/my_law.toml names that file in `plugins` and uses it like a shipped law.

The script puts the two files side by side in DIR, runs the scenario (logs in DIR: the log pins the
plugin by path and sha256, so `ftstab replay DIR/my_law.mcap --verify` re-runs exactly that code),
runs the shipped linear law on the same scenario for contrast, and draws |z1| and u of both: the
finite-time law reaches the sampling floor in about two seconds, the linear one only decays.

Run: python examples/my_law.py [--out DIR]   (writes DIR/my_law.png)
"""

import argparse
import shutil
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

import ftstab_mj  # noqa: E402

HERE = Path(__file__).resolve().parent
LINEAR = 'loops.cart.controller={law = "linear", poles = [-3.0, -3.0]}'  # a --set override: a TOML inline table


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="runs", help="where the plugin, the scenario, the log and the figure go")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name in ("my_laws.py", "my_law.toml"):  # a scenario finds its plugin file relative to itself
        shutil.copy(HERE / name, out / name)

    mine = ftstab_mj.run(out / "my_law.toml", out=out)
    linear = ftstab_mj.run(out / "my_law.toml", overrides=[LINEAR])  # no logs: only for the figure
    fig, (ax_z, ax_u) = plt.subplots(2, 1, figsize=(7, 5.5), sharex=True, constrained_layout=True)
    for res, label in ((mine, "bhat_bernstein (the plugin)"), (linear, "linear, poles -3, -3 (shipped)")):
        s = res.samples["cart"]
        z1 = np.abs(s["z"][:, 0])
        above = np.flatnonzero(z1 >= 1e-6)  # |z1| stays below 1e-6 after the last of these
        when = f", |z1| < 1e-6 from {s['t'][above[-1] + 1]:.2f} s on" if above.size < len(z1) - 1 else ""
        print(f"{label}: status {res.status}, final |z1| = {z1[-1]:.3g} m{when}")
        ax_z.semilogy(s["t"], z1, label=label)
        ax_u.plot(s["t"], s["u"], label=label)
    ax_z.set_ylabel("|z1| = |x| (m)")
    ax_z.set_title("your own law, loaded from my_laws.py by the scenario's plugins key")
    ax_z.legend(loc="lower left")
    ax_u.set_xlabel("t (s)")
    ax_u.set_ylabel("u (m/s^2)")
    png = out / "my_law.png"
    fig.savefig(png, dpi=100)
    print(f"wrote {png}; check the log: ftstab replay {out / 'my_law.mcap'} --verify")
    return png


if __name__ == "__main__":
    main()
