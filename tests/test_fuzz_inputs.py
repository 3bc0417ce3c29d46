"""The input contract under a seeded fuzzer (issue 17 point 6; the fuzzer is tests/fuzzing.py).

200 mutated shipped scenarios with random --set texts through ``ftstab run``'s ``main``: exit 0, 1 or
2 only, one line for 2, no traceback, no output directory for a refused input. A few seconds; the
long run is ``python benchmarks/fuzz_inputs.py`` (its figures are in the README).
"""

from fuzzing import fuzz

from ftstab_mj.scenario import shipped_scenarios


def test_fuzzed_scenarios_and_overrides_keep_the_input_contract(tmp_path):
    report = fuzz(seed=20261201, cases=200, workdir=tmp_path)
    assert report.failures == []
    assert report.cases == 200
    assert report.scenarios == {name for name, _, _ in shipped_scenarios()}  # every shipped scenario mutated
    # the cases reach both sides of the loader: refusals and runs (the seed is fixed, so are these)
    assert report.exits.get(2, 0) > 100 and report.runs >= 5
