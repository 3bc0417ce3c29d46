"""Your robot: a MuJoCo model this project did not write, stabilized by the robust law.

Gymnasium's reacher (two motor-driven hinges in a horizontal plane, and a target on two passive
slides) with the scenario examples/reacher.toml: the robust law turns the shoulder by 0.9 rad and the
elbow by 0.6 rad, with the bounds phibar and gamma_m it needs computed from the model over the
workspace the scenario states. The script puts the scenario and gymnasium's XML side by side in DIR,
runs it, checks from the samples that the true phi and gamma stayed within the computed bounds, and
draws the fingertip's path (from the logged body poses), both joints and V1.

Needs gymnasium (pip install gymnasium; only its XML file is used).
Run: python examples/your_robot.py [--out DIR]   (writes DIR/your_robot.png)
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


def gymnasium_model(name: str) -> Path:
    try:
        import gymnasium
    except ImportError:  # one line, as the tool says bad input
        raise SystemExit(f"examples/your_robot.py: expected gymnasium installed (its {name} is the robot: "
                         "pip install gymnasium), found none") from None
    return Path(gymnasium.__file__).parent / "envs" / "mujoco" / "assets" / name


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="runs", help="where the scenario, the model, the logs and the figure go")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    # the scenario names its model relative to itself: keep the two side by side
    shutil.copy(HERE / "reacher.toml", out / "reacher.toml")
    shutil.copy(gymnasium_model("reacher.xml"), out / "reacher.xml")

    res = ftstab_mj.run(out / "reacher.toml", out=out)
    print(f"status {res.status}")
    for name, m in res.metrics["loops"].items():
        s, law = res.samples[name], res.scenario["loops"][name]["controller"]
        print(f"{name}: V1 < {m['settle_level']:g} from t = {m['settle_time']} s, Theorem 1's T(z0) = "
              f"{m['time_bound']:.2f} s; max |phi| = {np.abs(s['phi']).max():.3g} <= phibar = {law['phibar']:.4g}, "
              f"min gamma = {s['gamma'].min():.6g} >= gamma_m = {law['gamma_m']:.6g} (computed)")

    names = list(res.samples)
    fig = plt.figure(figsize=(10, 6), constrained_layout=True)
    grid = fig.add_gridspec(2, 2, width_ratios=(1, 1.4))
    ax_xy = fig.add_subplot(grid[:, 0])
    tip = res.body_pos[:, 2, :2]  # bodies after the world: body0, body1, fingertip, target
    ax_xy.plot(tip[:, 0], tip[:, 1], color="C2", label="fingertip path")
    for i, label in ((0, "start"), (-1, "end")):
        arm = np.vstack([[0.0, 0.0], res.body_pos[i, 1, :2], tip[i]])
        ax_xy.plot(arm[:, 0], arm[:, 1], "o-", color="0.3" if i else "0.7", label=f"arm at {label}")
    ax_xy.set_xlim(-0.05, 0.25)
    ax_xy.set_ylim(-0.05, 0.25)
    ax_xy.set_aspect("equal")
    ax_xy.set_xlabel("x (m)")
    ax_xy.set_ylabel("y (m)")
    ax_xy.legend(loc="upper right")
    ax_xy.set_title("gymnasium's reacher.xml")
    ax_q = fig.add_subplot(grid[0, 1])
    ax_v = fig.add_subplot(grid[1, 1], sharex=ax_q)
    for i, name in enumerate(names):
        s, ref = res.samples[name], res.scenario["loops"][name]["ref"]
        m = res.metrics["loops"][name]
        ax_q.plot(s["t"], s["z"][:, 0] + ref, color=f"C{i}", label=f"{name} q (rad)")
        ax_q.axhline(ref, color=f"C{i}", ls="--", lw=0.8)
        ax_v.semilogy(s["t"], s["V1"], color=f"C{i}", label=f"{name}: settled at {m['settle_time']:.2f} s "
                      f"(bound {m['time_bound']:.2f} s)")
    ax_q.set_ylabel("joint angle (rad)")
    ax_q.legend()
    ax_q.set_title("the robust law, bounds computed from the model")
    ax_v.axhline(res.metrics["loops"][names[0]]["settle_level"], color="0.5", ls=":", label="settle level")
    ax_v.set_xlabel("t (s)")
    ax_v.set_ylabel("V1")
    ax_v.legend(loc="lower left")
    png = out / "your_robot.png"
    fig.savefig(png, dpi=100)
    print(f"wrote {png}")
    return png


if __name__ == "__main__":
    main()
