"""MuJoCo's own log stays out of the user's way: a run whose control MuJoCo calls huge says so in its
own line (mjWARN_BADCTRL and its count), without MuJoCo's console line or a MUJOCO_LOG.TXT in the
working directory (plants/base.quiet_mujoco_log), in a fresh process as a user runs it."""

from conftest import run_cli


def test_a_huge_control_is_our_one_line_and_leaves_no_mujoco_log(tmp_path):
    # phibar = 1e300: the robust law's control is ~2e300, which MuJoCo refuses at every step
    res = run_cli("run", "cart_r2_robust", "--out", tmp_path / "o", "--set", "sim.duration=0.2",
                  "--set", "loops.cart.controller.phibar=1e300", "--json", cwd=tmp_path)
    assert res.returncode == 1, res.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["o"]  # no MUJOCO_LOG.TXT
    assert "WARNING" not in res.stderr + res.stdout  # MuJoCo's "WARNING: Nan, Inf or huge value in CTRL"
    errors = [line for line in res.stderr.splitlines() if line.startswith("error:")]
    assert len(errors) == 1 and "mjWARN_BADCTRL x" in errors[0], res.stderr


def test_errors_still_raise_with_the_log_quiet():
    import mujoco
    import pytest

    import ftstab_mj.plants.base  # noqa: F401 - quiets the log at import

    config = mujoco.MjLogConfig.get()
    assert not config.logto_console and not config.logto_file
    with pytest.raises(ValueError, match="unrecognized element"):
        mujoco.MjModel.from_xml_string("<mujoco><bad/></mujoco>")
