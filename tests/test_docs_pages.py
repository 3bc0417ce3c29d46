"""The docs site's pages against the package: one page per verb of the command, the scenario file
reference generated from the schema (every key with a type and a meaning), and the first pages a new
user reads sending them to `ftstab view`, not to a `.rrd` that `ftstab run` no longer writes."""

import importlib.util
import re

from conftest import ROOT, run_cli

DOCS = ROOT / "docs"


def _verbs() -> set[str]:
    proc = run_cli("--help")
    assert proc.returncode == 0, proc.stderr
    listed = proc.stdout.split("positional arguments:", 1)[1].split("options:", 1)[0]
    return set(re.findall(r"^    (\w+)", listed, re.M))


def _nav_pages() -> list[str]:
    """The pages mkdocs.yml's nav names (its entries "- Title: page.md" or "- page.md")."""
    nav = (ROOT / "mkdocs.yml").read_text().split("\nnav:\n", 1)[1]
    return re.findall(r"^\s+- (?:[^:\n]+: )?(\S+\.md)\s*$", nav, re.M)


def test_every_verb_has_its_page_in_the_nav_with_its_generated_help():
    verbs = _verbs()
    assert {"run", "view", "design", "certify", "montecarlo", "compare"} <= verbs
    pages = {p.stem for p in (DOCS / "commands").glob("*.md")} - {"index"}
    assert pages == verbs  # no verb without a page, no page of a verb that is gone
    nav = _nav_pages()
    index = (DOCS / "commands" / "index.md").read_text()
    for verb in verbs:
        page = (DOCS / "commands" / f"{verb}.md").read_text()
        assert page.startswith(f"# ftstab {verb}\n"), verb
        assert f"<!-- ftstab help {verb} -->" in page, verb  # every option, from the parser itself
        assert f"commands/{verb}.md" in nav, verb
        assert f"[`{verb}`]({verb}.md)" in index, verb


def _generate():
    spec = importlib.util.spec_from_file_location("docs_generate", DOCS / "hooks" / "generate.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_scenario_reference_gives_every_key_a_type_and_a_meaning():
    """The tables the scenario file page shows, generated from the schema: a field added without a
    doc (or a docstring entry, for the signal and metrics tables) leaves an empty cell and fails here."""
    import dataclasses

    from ftstab_mj.scenario import schema

    text = _generate().schema()
    rows = [[c.strip() for c in re.split(r"(?<!\\)\|", line.strip().strip("|"))]
            for line in text.splitlines() if line.startswith("| `")]
    keyed = [row for row in rows if len(row) == 5]
    empty = [row[0] for row in keyed if not row[1] or not row[4]]
    assert keyed and empty == []
    shown = {row[0].strip("`") for row in keyed}
    for cls in (schema.SimSpec, schema.SensorSpec, schema.ObserverSpec, schema.ActuatorSpec):
        assert {f.name for f in dataclasses.fields(cls) if f.init} - set(schema.SIGNAL_DERIVED) <= shown, cls
    # the allowed values are the loader's own words: what it says when a value is refused
    assert "| `integrator` | string | \"euler\" | one of 'euler', 'implicitfast', 'rk4' |" in text
    assert "<!-- ftstab schema -->" in (DOCS / "scenario-file.md").read_text()


def test_the_first_pages_look_at_a_run_with_ftstab_view():
    """`ftstab run` writes the MCAP log only: the README, the home page and getting started send the
    reader to `ftstab view LOG.mcap` (which writes the .rrd) before they name any .rrd to open."""
    for page in (ROOT / "README.md", DOCS / "index.md", DOCS / "getting-started.md"):
        text = page.read_text()
        view = text.find("ftstab view runs/cart_r2_robust.mcap")
        assert view >= 0, page.name
        assert not re.search(r"rerun (--serve-web )?runs/\S+\.rrd", text[:view]), page.name
        assert "writes `runs/cart_r2_robust.mcap` and `runs/cart_r2_robust.rrd`" not in text, page.name


def test_the_scenario_file_pages_example_is_a_valid_scenario(tmp_path):
    """The annotated file at the top of the scenario file page, copied as it is, loads (it had a set
    point and a reference table together, which the loader refuses)."""
    import ftstab_mj

    text = (DOCS / "scenario-file.md").read_text()
    path = tmp_path / "example.toml"
    path.write_text(re.search(r"```toml\n(.*?)```", text, re.S).group(1))
    sc = ftstab_mj.load_scenario(path)
    assert sc.name == "cart_r2_robust" and sc.loops[0].reference.kind == "sine"
