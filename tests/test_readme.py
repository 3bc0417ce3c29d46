"""The README: its quick start (exactly two commands; CI runs the test one verbatim; the run one works),
its length, its tables of verbs and scenarios against the command and scenarios/, and the docs site."""

import re
import shlex
import subprocess
from pathlib import Path

from conftest import ROOT, run_cli

INSTALL = "python -m pip install -e ."


def quick_start() -> list[str]:
    """The command lines of the first code block after the '## Quick start' heading."""
    text = (ROOT / "README.md").read_text()
    section = text.split("## Quick start", 1)[1]
    block = re.search(r"```sh\n(.*?)```", section, re.S).group(1)
    return [line for line in block.splitlines() if line.strip()]


def test_quick_start_has_two_commands_and_ci_runs_the_test_one_verbatim():
    commands = quick_start()
    assert len(commands) == 2
    ci_lines = [line.strip() for line in (ROOT / ".ci" / "run").read_text().splitlines()]
    assert commands[1] in ci_lines
    assert commands[1] == 'python -m pip install -e ".[test]" && python -m pytest -n 2'


def test_quick_start_run_command_runs_the_default_scenario(tmp_path):
    """The part after the install, run as written from a directory that has the repository's
    scenarios/ (the install itself is exercised by .ci/run on a fresh virtual environment)."""
    install, _, run = quick_start()[0].partition(" && ")
    assert install == INSTALL
    argv = shlex.split(run)
    assert argv[:3] == ["python", "-m", "ftstab_mj"]
    (tmp_path / "scenarios").symlink_to(ROOT / "scenarios")
    proc = run_cli(*argv[3:], cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    out = argv[argv.index("--out") + 1]
    name = Path(argv[4]).stem
    assert name == "cart_r2_robust"  # the default scenario
    assert f"{name}: " in proc.stdout and "status completed" in proc.stdout
    assert (tmp_path / out / f"{name}.mcap").stat().st_size > 0
    look = f"ftstab view {out}/{name}.mcap"  # the quick start's way to look at it, printed by the run too
    assert look in proc.stdout and f"`{look}`" in (ROOT / "README.md").read_text().split("## Quick start", 1)[1]


def test_no_tracked_file_sends_users_to_the_teams_private_notes():
    """Users never see the team's shared folder: no tracked file names it or its notes (the
    formulas a module implements are restated in the project's own docs)."""
    names = [".." + "/shared", *(stem + ".md" for stem in ("NOTES", "DESIGN", "LITERATURE"))]  # not literal here
    tracked = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout.split(b"\0")
    found = [(path.decode(), name) for path in tracked if path and (ROOT / path.decode()).is_file()
             for name in names if name.encode() in (ROOT / path.decode()).read_bytes()]
    assert found == []


def _design(*args):
    import json

    res = run_cli("design", *map(str, args), "--json")
    assert res.returncode == 0, res.stderr
    return json.loads(res.stdout)


def test_the_docs_design_examples_are_what_design_prints():
    """The figures of the r = 2 `ftstab design` examples in docs/commands/design.md (max-c, min-time) are what the
    command prints today (it is deterministic): gains to their 5 printed digits, c_lower and T(z0) to the digits
    the page gives. They had gone stale (6.8565 for 6.8587, ...). The page's --u-max example at r = 3 is checked
    by the test that designs it anyway (test_control_design.py::test_cli_u_max_holds_on_the_region)."""
    text = docs_design_text()
    num = r"([0-9]+(?:\.[0-9]+)?)"
    m = re.search(rf"e\.g\. r = 2, k = -0\.2 gives gains {num}, {num} with c_lower = {num}", text)
    d = _design("--r", 2, "--k", -0.2)
    assert d["gains"] == [float(m[1]), float(m[2])] and f"{d['certificate']['c_lower']:.6g}" == m[3]
    m = re.search(rf"r = 2, k = -0\.2, z0 = \(1, 0\) and \(0, 1\): gains {num}, {num}, T = {num} s", text)
    d = _design("--r", 2, "--k", -0.2, "--objective", "min-time", "--z0", "1,0", "--z0", "0,1")
    assert d["gains"] == [float(m[1]), float(m[2])] and f"{d['time_bound']:.5g}" == m[3]


def docs_design_text() -> str:
    """docs/commands/design.md with its line breaks and indents folded to single spaces."""
    return " ".join((ROOT / "docs" / "commands" / "design.md").read_text().split())


def _table(section: str) -> list[list[str]]:
    """The body rows (cells stripped) of the first table after the README's `## section` heading."""
    lines = (ROOT / "README.md").read_text().split(f"## {section}\n", 1)[1].splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("|"))
    block = []
    for line in lines[start:]:
        if not line.startswith("|"):
            break
        block.append([cell.strip() for cell in re.split(r"(?<!\\)\|", line.strip().strip("|"))])
    return block[2:]


def test_the_readme_is_a_guide_not_a_notebook():
    """At most 300 lines, and no measurement history: load averages, "(measured)" titles, before/after."""
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 300
    for word in ("load average", "(measured", "before/after", "Before/after"):
        assert word not in text, word


def test_the_readme_verb_table_lists_every_verb_of_the_command():
    proc = run_cli("--help")
    assert proc.returncode == 0, proc.stderr
    listed = proc.stdout.split("positional arguments:", 1)[1].split("options:", 1)[0]
    verbs = set(re.findall(r"^    (\w+)", listed, re.M))
    assert {"run", "list", "design", "certify", "sweep", "compare"} <= verbs
    in_table = {re.match(r"`ftstab (\w+)", row[0]).group(1) for row in _table("Commands")}
    assert in_table == verbs


def test_the_readme_scenario_table_is_the_shipped_scenarios():
    """One row per scenarios/*.toml, with the plant model and the law(s) the file declares."""
    import tomllib

    rows = {row[0].split()[0]: row for row in _table("Shipped scenarios")}
    files = {p.stem: tomllib.loads(p.read_text()) for p in (ROOT / "scenarios").glob("*.toml")}
    assert set(rows) == set(files)
    for name, sc in files.items():
        laws = sorted({loop["controller"]["law"] for loop in sc["loops"].values()})
        assert rows[name][1] == sc["plant"]["model"], name
        assert rows[name][2] == ", ".join(laws), name


def test_the_readme_links_exist():
    """Every relative link of the README names a file of the checkout (the docs pages above all)."""
    text = (ROOT / "README.md").read_text()
    links = [link.split("#")[0] for link in re.findall(r"\]\(([^)\s]+)\)", text) if "://" not in link]
    assert links
    missing = [link for link in links if link and not (ROOT / link).exists()]
    assert missing == []


def test_the_docs_site_builds_strictly(tmp_path):
    """`mkdocs build --strict` (a broken link, a missing page or an API name that no longer resolves
    fails it), into a temporary folder, never into the checkout."""
    import importlib.util
    import os
    import sys

    if importlib.util.find_spec("mkdocs") is None:
        import pytest

        pytest.skip("mkdocs is not installed (the docs extra)")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH", "")) if p))
    proc = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(tmp_path / "site"),
                           "--config-file", str(ROOT / "mkdocs.yml")], capture_output=True, text=True, cwd=ROOT,
                          env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr[-4000:]
    assert (tmp_path / "site" / "index.html").exists() and (tmp_path / "site" / "api" / "index.html").exists()


def test_the_first_screen_answers_run_view_headless_robot_law_compare():
    """Within the README's first 40 lines (a screen): how to run, to view (headless too), to bring a
    robot, to write a law, to compare laws, each with its command or its key."""
    head = "\n".join((ROOT / "README.md").read_text().splitlines()[:40])
    for needle in ("python -m ftstab_mj run scenarios/cart_r2_robust.toml", "`ftstab view runs/cart_r2_robust.mcap`",
                   "without a display", "bring your own robot", '`[plant] model = "my_robot.xml"`',
                   "write your own law", "register", "compare laws", "`ftstab compare "):
        assert needle in head, needle
