"""The benchmarks' one entry point, run from the project's root.

    python -m benchmarks                  # every benchmark, one line each
    python -m benchmarks NAME [ARGS...]   # run one (NAME --help: its options)
    python -m benchmarks NAME --quick     # short settings (QUICK): checks that it runs, not figures to quote
"""

import ast
import runpy
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent

# --quick: short settings that still print every row (seconds to a minute or two; not figures to quote)
QUICK = {
    "arm_speed": ["--repeat", "1", "--steps", "2000"],
    "batch_engine": ["--rows", "8", "--states", "50", "--chain-states", "200", "--long", "2", "--repeat", "1"],
    "certificate_budget": ["--n", "2", "--r", "2"],
    "certificate_table": ["--r", "2", "--budget", "5"],
    "certificate_tree": ["--depth", "8"],
    "field_r2": ["--duration", "0.3", "--no-check"],
    "flexible_joint_montecarlo": ["--states", "10"],
    "fuzz_inputs": ["--cases", "200"],
    "interruptions": ["--tries", "6"],
    "law_costs": ["--repeat", "1", "--steps", "1000"],
    "live_costs": ["--repeat", "1", "--duration", "1.5"],
    "log_costs": ["--repeat", "1"],
    "memory_flat": ["--durations", "1", "10", "--repeat", "1"],
    "montecarlo_speed": ["--states", "500", "--repeat", "1"],
    "physical_loop": ["--repeat", "1", "--steps", "2000"],
    "row_cost": ["--rows", "4", "--duration", "0.05", "--repeat", "1"],
    "run_speed": ["--repeat", "1", "--duration", "0.05", "--scenarios", "cart_r2_robust", "--no-breakdown"],
    "speed": ["--repeat", "1", "--steps", "2000"],
    "sweep_speedup": ["--samples", "20", "--repeat", "1", "--no-external"],
}


def benchmarks() -> dict[str, str]:
    """{name: the first sentence of its docstring} of every benchmark module (read, not imported: listing is instant)."""
    return {p.stem: _summary(ast.get_docstring(ast.parse(p.read_text())) or "")
            for p in sorted(HERE.glob("*.py")) if not p.stem.startswith("_")}


def _summary(doc: str, width: int = 100) -> str:
    """The docstring's first sentence (its first paragraph, cut at ``width`` characters)."""
    text = " ".join(doc.split("\n\n")[0].split())
    end = text.find(". ")
    text = text if end < 0 else text[:end + 1]
    return text if len(text) <= width else text[:width - 3].rstrip() + "..."


def main(argv: list[str]) -> int:
    found = benchmarks()
    if not argv or argv[0] in ("-h", "--help", "list"):
        width = max(map(len, found))
        print("python -m benchmarks NAME [ARGS] (NAME --help; --quick: short settings); what each prints and how "
              "long it takes: benchmarks/README.md")
        for name, line in found.items():
            print(f"  {name:{width}s}  {line}{'' if name in QUICK else '  (no --quick)'}")
        return 0
    name, rest = argv[0], argv[1:]
    if name not in found:
        print(f"python -m benchmarks: no benchmark {name!r}; expected one of: {', '.join(found)}", file=sys.stderr)
        return 2
    if "--quick" in rest:
        if name not in QUICK:
            print(f"python -m benchmarks {name}: no --quick settings (it is short already or has none)", file=sys.stderr)
            return 2
        rest = QUICK[name] + [a for a in rest if a != "--quick"]  # an option given too comes last: it wins
    sys.argv = [name, *rest]  # runpy sets argv[0] to the module's file
    runpy.run_module(f"benchmarks.{name}", run_name="__main__", alter_sys=True)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
