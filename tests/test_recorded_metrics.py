"""logs.recorded_metrics.compare_recorded: a log's recorded metrics against the recomputed ones, with the
certificate's two exceptions (the rules ``ftstab replay`` applies)."""

from ftstab_mj.logs.recorded_metrics import compare_recorded


def _metrics(cert=None, time_bound=1.5, settle=0.75, extra=None):
    loop = {"settle_time": settle, "time_bound": time_bound, "beat_bound": True}
    if cert is not None:
        loop["certificate"] = cert
    return {"status": "completed", "loops": {"cart": {**loop, **(extra or {})}}}


CERT = {"status": "certified", "c_lower": 1.0, "c_upper": 1.2, "c_prime_lower": None, "c_prime_upper": 3.0}


def test_identical_and_a_plain_difference():
    same = compare_recorded(_metrics(CERT), _metrics(CERT))
    assert (same.differ, same.derived, same.moved) == ([], [], [])
    found = compare_recorded(_metrics(CERT), _metrics(CERT, settle=0.5))
    assert found.differ == [("loops.cart.settle_time", 0.75, 0.5)] and not found.derived and not found.moved


def test_a_metric_newer_than_the_log_is_not_compared():
    found = compare_recorded(_metrics(CERT), _metrics(CERT, extra={"new_metric": 3}))
    assert (found.differ, found.derived, found.moved) == ([], [], [])


def test_a_log_without_certificate_excuses_what_derives_from_it_only():
    found = compare_recorded(_metrics(None, time_bound=2.0), _metrics(CERT, time_bound=1.5, settle=0.5))
    assert found.derived == ["loops.cart.time_bound"]
    assert found.differ == [("loops.cart.settle_time", 0.75, 0.5)] and found.moved == []


def test_a_moved_certificate_is_excused_while_both_brackets_hold_c():
    moved = {**CERT, "c_lower": 1.1, "c_upper": 1.15}
    found = compare_recorded(_metrics(CERT, time_bound=1.5), _metrics(moved, time_bound=1.4))
    assert found.differ == [] and found.derived == []
    assert found.moved == ["loops.cart.certificate.c_lower", "loops.cart.certificate.c_upper", "loops.cart.time_bound"]
    apart = {**CERT, "c_lower": 1.3, "c_upper": 1.4}  # brackets that do not overlap: one of them is wrong
    found = compare_recorded(_metrics(CERT), _metrics(apart))
    assert [k for k, _, _ in found.differ] == ["loops.cart.certificate.c_lower", "loops.cart.certificate.c_upper"]
    assert found.moved == []
