"""The scenario reference (docs/scenario-file.md, from `ftstab list`) is made from the laws' own `Param`
declarations, so each declaration must carry what the page needs: every parameter of every shipped law
has a one-line doc, and every quantity says its units.

How a dimensionless parameter is told apart, honestly: a number has no "no units"; it either has units
or it is a pure number (an exponent, a ratio, the homogeneity degree), and the law says which, in the
units field itself, as units = "dimensionless" (shown as such on the page). An empty units field is
allowed only for a str parameter (a word from a list, such as form or discretization: a choice, not a
quantity). Laws that tests or users register (plugins) are not the shipped reference, and not checked."""

from ftstab_mj.control import LAWS

DIMENSIONLESS = "dimensionless"


def _shipped():
    import ftstab_mj.control.laws  # noqa: F401 - registers every shipped law

    return {name: cls for name, cls in LAWS.items() if cls.__module__.startswith("ftstab_mj.")}


def _is_word(param) -> bool:
    """A str parameter: a word from a list (float | str, as phibar = "computed", is a quantity)."""
    return param.type is str


def test_there_are_shipped_laws_to_check():
    laws = _shipped()
    assert {"nominal", "robust", "adaptive", "linear", "levant_qc", "super_twisting"} <= set(laws)


def test_every_param_of_a_shipped_law_has_a_one_line_doc():
    missing = [(law, p.name) for law, cls in _shipped().items() for p in cls.all_params()
               if not (isinstance(p.doc, str) and p.doc.strip() and "\n" not in p.doc)]
    assert missing == []


def test_every_quantity_of_a_shipped_law_states_its_units_or_says_it_is_dimensionless():
    no_units = [(law, p.name) for law, cls in _shipped().items() for p in cls.all_params()
                if not _is_word(p) and not (isinstance(p.units, str) and p.units.strip())]
    assert no_units == [], "give units, or units='dimensionless' for a pure number"


def test_a_word_parameter_has_no_units_and_a_list_of_values():
    """form, discretization: the check names the allowed words, and units would mean nothing."""
    bad = [(law, p.name) for law, cls in _shipped().items() for p in cls.all_params()
           if _is_word(p) and (p.units or p.check is None)]
    assert bad == []


def test_the_reference_shows_the_units():
    """What the page prints for a parameter (Param.describe) carries its units, dimensionless included."""
    for cls in _shipped().values():
        for p in cls.all_params():
            if not _is_word(p):
                assert p.describe().endswith(f"({p.units})"), (cls.name, p.name)
    robust = _shipped()["robust"]
    k = next(p for p in robust.all_params() if p.name == "k")
    assert k.units == DIMENSIONLESS


def test_param_types_are_what_the_loader_reads():
    """A Param's type is one the scenario loader converts (float, int, str, bool, tuple[float, ...],
    float | str): a stray type would make the reference print a Python repr."""
    allowed = {float, int, str, bool, tuple[float, ...], float | str}
    odd = [(law, p.name, p.type) for law, cls in _shipped().items() for p in cls.all_params() if p.type not in allowed]
    assert odd == []
