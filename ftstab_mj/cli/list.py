"""``ftstab list``: the shipped scenarios, the control laws and the plants."""

from __future__ import annotations

VERB = "list"
ORDER = 70  # its place in `ftstab --help`


def add_parser(sub) -> None:
    ls = sub.add_parser("list", help="the shipped scenarios, the control laws and the plants",
                        description="List the scenarios shipped in scenarios/ with their one-line descriptions, "
                                    "then the registered control laws with their scenario keys, then the plants.")
    ls.set_defaults(func=handle)


def handle(args) -> int:
    from ftstab_mj.control import LAWS
    from ftstab_mj.plants import PLANTS
    from ftstab_mj.scenario import SCENARIO_DIR, shipped_scenarios
    from ftstab_mj.scenario.plugins import load_entry_points, origin

    load_entry_points()  # installed distributions' laws and plants are listed with the others
    rows = shipped_scenarios()
    width = max((len(name) for name, _, _ in rows), default=0)
    for name, _, description in rows:
        print(f"{name:<{width}}  {description}")
    print(f"\n{len(rows)} scenarios in {SCENARIO_DIR}; run one with: ftstab run NAME [--set key.path=value]")
    print("\nlaws (loops.<name>.controller.law) and their keys:")
    for cls in LAWS.values():
        where = origin(cls.__module__)
        print(f"  {cls.name}: {cls.summary}" + ("" if where == "built in" else f"  [{where}]"))
        for p in cls.all_params():
            default = "" if p.required else f" [default {p.default!r}]"
            print(f"      {p.name}: {p.describe()}{default}")
    print("\nplants (plant.model):")
    for entry in PLANTS.values():
        where = origin(entry.build.__module__)
        print(f"  {entry.name}: {entry.summary}" + ("" if where == "built in" else f"  [{where}]"))
    return 0
