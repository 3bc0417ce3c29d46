"""Foxglove layouts for the MCAP log (and the ``--foxglove`` live stream, which has the same topics).

A layout (built with foxglove-sdk's ``foxglove.layouts``, the format Foxglove's own SDK writes):
on the left the 3D panel (``/scene``, placed by the transforms of ``/tf``, in the ``world`` frame) above the ``/metrics``
message; on the right one tab per loop with three plots against time: z_1..z_r
(``/loop/<name>.z[i]``), u and u0 (``/loop/<name>.u``, ``.u0``), and V1 (``/loop/<name>.V1``;
Foxglove's plot has no log axis: zoom in on the tail to see the settle level).

Shipped layouts, one per plant (its loop names and r), are in ``ftstab_mj/logs/layouts/<plant>.json``
(:data:`SHIPPED`); for any other log (a user model): ``python -m ftstab_mj.logs.foxglove_layout
LOG.mcap OUT.json``. ``python -m ftstab_mj.logs.foxglove_layout --shipped`` rewrites the shipped ones.
"""

from __future__ import annotations

import sys
from pathlib import Path

LAYOUT_DIR = Path(__file__).resolve().parent / "layouts"
# plant -> its loops (name, r): the shipped layouts (tests/test_foxglove_layout.py checks them
# against a real log of each plant)
SHIPPED = {
    "cart": (("cart", 2),),
    "cart_integrating": (("cart", 3),),
    "arm": (("joint0", 2), ("joint1", 2)),
    "arm_integrating": (("joint0", 3), ("joint1", 3)),
    "arm3": (("joint0", 2), ("joint1", 2), ("joint2", 2)),
}
COLOURS = ("#1f77b4", "#ff7f0e", "#2ca02c", "#9467bd")  # z_1..z_4 (as in the Rerun view's palette)
U_COLOUR, U0_COLOUR, V1_COLOUR = "#d62728", "#1e1e1e", "#1f77b4"


def layout(loops):
    """The layout (foxglove.layouts.Layout) of a log whose loops are ``loops``: ((name, r), ...)."""
    import foxglove.layouts as fl

    def plot(title, series, y_label):
        return fl.PlotPanel(title=title, config=fl.PlotConfig(
            paths=[fl.PlotSeries(value=path, label=label, color=colour) for path, label, colour in series],
            x_axis_val="timestamp", y_axis_label=y_label, show_legend=True, legend_display="top"))

    tabs = []
    for name, r in loops:
        topic = f"/loop/{name}"
        z = plot(f"{name}: state z", [(f"{topic}.z[{i}]", f"z{i + 1}", COLOURS[i % len(COLOURS)]) for i in range(r)],
                 "z (chain units)")
        u = plot(f"{name}: u, u0", [(f"{topic}.u", "u", U_COLOUR), (f"{topic}.u0", "u0", U0_COLOUR)], "control")
        v1 = plot(f"{name}: V1", [(f"{topic}.V1", "V1", V1_COLOUR)], "V1")
        tabs.append(fl.TabItem(title=name, content=fl.SplitContainer(direction="column", items=[
            fl.SplitItem(content=z), fl.SplitItem(content=u), fl.SplitItem(content=v1)])))
    scene = fl.ThreeDeePanel(title="plant", config=fl.ThreeDeeConfig(
        fixed_frame="world", follow_tf="world",
        topics={"/scene": fl.BaseRendererSceneUpdateTopicSettings(visible=True)}))  # /tf: read by the panel itself
    metrics = fl.RawMessagesPanel(title="status and metrics", config=fl.RawMessagesConfig(topic_path="/metrics"))
    left = fl.SplitContainer(direction="column", items=[fl.SplitItem(proportion=3, content=scene),
                                                        fl.SplitItem(proportion=1, content=metrics)])
    right = fl.TabContainer(tabs=tabs) if len(tabs) > 1 else tabs[0].content
    return fl.Layout(content=fl.SplitContainer(direction="row", items=[fl.SplitItem(proportion=2, content=left),
                                                                       fl.SplitItem(proportion=3, content=right)]))


def layout_json(loops) -> str:
    """The layout of :func:`layout` as the JSON text a file holds (indented, one trailing newline)."""
    import json

    return json.dumps(json.loads(layout(loops).to_json()), indent=2) + "\n"


def shipped_path(plant: str) -> Path:
    return LAYOUT_DIR / f"{plant}.json"


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv == ["--shipped"]:
        for plant, loops in SHIPPED.items():
            shipped_path(plant).write_text(layout_json(loops))
        return 0
    if len(argv) != 2:
        print("usage: python -m ftstab_mj.logs.foxglove_layout LOG.mcap OUT.json | --shipped", file=sys.stderr)
        return 2
    from ftstab_mj.config.errors import FtstabError
    from ftstab_mj.logs.reader import read_log

    try:
        info = read_log(argv[0]).info
    except FtstabError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    Path(argv[1]).write_text(layout_json([(lp.name, lp.r) for lp in info.loops]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
