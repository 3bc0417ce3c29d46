"""The command's verbs: one module each in ftstab_mj/cli/ (its parser and its handler), found by
ftstab_mj.cli.verbs(); adding a verb is one new module there."""

import ast
import re
from pathlib import Path

import pytest

import ftstab_mj.cli as cli
from conftest import ROOT

VERBS = ["certify", "design", "replay", "check", "report", "view", "run", "list", "sweep", "montecarlo", "compare"]


def test_every_verb_is_a_module_in_its_help_order():
    modules = cli.verbs()
    assert [m.VERB for m in modules] == VERBS  # the order of `ftstab --help`
    for m in modules:
        assert m.__name__ == f"ftstab_mj.cli.{m.VERB}" and callable(m.add_parser) and callable(m.handle)
        args = cli.build_parser().parse_args([m.VERB, "--help"][:1] + _required(m.VERB))
        assert args.verb == m.VERB and args.func is m.handle


def _required(verb):
    return {"certify": ["--r", "2", "--k", "-0.2", "--gains", "1,2"], "design": ["--r", "2", "--k", "-0.2"],
            "replay": ["x.mcap"], "check": ["x.mcap", "--expect", "e.toml"], "report": ["x.mcap", "--out", "f.png"], "view": ["x.mcap"],
            "run": ["s"], "list": [], "sweep": ["s"], "montecarlo": ["s", "--states", "1"], "compare": ["c"]}[verb]


def test_a_new_module_is_a_new_verb(tmp_path, monkeypatch, capsys):
    (tmp_path / "hello.py").write_text(
        'VERB = "hello"\nORDER = 65\n\n\n'
        'def add_parser(sub):\n    sub.add_parser("hello", help="say hello").set_defaults(func=handle)\n\n\n'
        'def handle(args):\n    print("hello")\n    return 0\n')
    monkeypatch.setattr(cli, "__path__", [*cli.__path__, str(tmp_path)])
    after_run = VERBS.index("run") + 1  # ORDER 65: between run (60) and list (70)
    assert [m.VERB for m in cli.verbs()] == VERBS[:after_run] + ["hello"] + VERBS[after_run:]
    assert cli.main(["hello"]) == 0 and capsys.readouterr().out == "hello\n"
    with pytest.raises(SystemExit):
        cli.main(["--help"])
    text = capsys.readouterr().out
    assert re.search(r"\n +run +run a scenario.*\n +hello +say hello\n +list +", text), text


def test_no_domain_logic_in_the_command():
    """The verb modules import the layers below only inside their handlers (a cheap `ftstab --help`)
    and nothing of theirs is a private name of another module."""
    for path in sorted((ROOT / "ftstab_mj" / "cli").glob("*.py")):
        tree = ast.parse(path.read_text())
        for node in tree.body:  # module level
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("ftstab_mj"):
                assert node.module in ("ftstab_mj.cli.common", "ftstab_mj.config.errors"), (path.name, node.module)
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom):
                assert not any(a.name.startswith("_") and not a.name.startswith("__") for a in node.names), (path.name, node.module)
    assert not (ROOT / "ftstab_mj" / "cli.py").exists()
    assert Path(cli.__file__).parent.name == "cli"
