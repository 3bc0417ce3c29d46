"""The Python API: a cheap import, the README's example executed as written, the example script."""

import re
import subprocess
import sys

import numpy as np

from conftest import ROOT


def test_import_is_cheap_and_exposes_the_api():
    # a fresh interpreter: importing the package (and reaching the API) loads neither MuJoCo nor Rerun
    code = ("import sys, ftstab_mj\n"
            "assert all(callable(f) for f in (ftstab_mj.run, ftstab_mj.replay, ftstab_mj.load_scenario))\n"
            "print(sorted(m for m in ('mujoco', 'rerun', 'numpy') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, check=True).stdout
    assert out.strip() == "[]"


def test_the_readme_example_runs_as_written(tmp_path, monkeypatch):
    text = (ROOT / "README.md").read_text()
    block = re.search(r"## Python API.*?```python\n(.*?)```", text, re.S).group(1)
    monkeypatch.chdir(tmp_path)
    scope = {}
    exec(compile(block, "README.md", "exec"), scope)  # noqa: S102 - the README's own code
    res = scope["res"]
    assert res.status == "completed" and res.logs["mcap"].exists() and "rrd" not in res.logs
    assert not list(tmp_path.rglob("*.rrd"))  # the MCAP log only, as `ftstab run` (rrd=True, --rrd: the recording)
    assert res.samples["cart"]["z"].shape == (2000, 2) and np.isclose(res.samples["cart"]["t"][-1], 1.999)


def test_run_from_a_path_with_list_overrides_and_no_logs():
    import ftstab_mj

    res = ftstab_mj.run(ROOT / "scenarios" / "cart_r2_nominal.toml", overrides=["sim.duration=0.5"])
    assert res.logs == {} and res.status == "completed" and len(res.samples["cart"]["t"]) == 500
    assert res.metrics["n_samples"] == 500 and res.scenario["sim"]["duration"] == 0.5


def test_run_and_replay_without_samples_give_the_same_metrics(tmp_path):
    import ftstab_mj

    from ftstab_mj.logs import McapSink
    from ftstab_mj.scenario.run import run_scenario

    kept = ftstab_mj.run("cart_r2_robust", overrides={"sim.duration": 0.5})
    bare = ftstab_mj.run("cart_r2_robust", overrides={"sim.duration": 0.5}, keep_samples=False)
    assert bare.samples is None and bare.body_pos is None and bare.metrics == kept.metrics
    log = tmp_path / "run.mcap"  # (an MCAP log only: no Rerun recording in this process)
    run_scenario(ftstab_mj.load_scenario("cart_r2_robust", {"sim.duration": 0.5}), [McapSink(log)])
    whole, streamed = ftstab_mj.replay(log), ftstab_mj.replay(log, keep_samples=False)
    assert len(whole.samples["cart"]["t"]) == 500 and streamed.samples is None and streamed.body_pos is None
    assert streamed.metrics == whole.metrics == kept.metrics and streamed.status == whole.status == "completed"


def test_run_checks_its_log_paths_like_the_command(tmp_path):
    """ftstab_mj.run(out=) goes through logs.run_logs.open_run_logs, as ``ftstab run`` does: a file as
    the directory, or another program's file at a log path, is one LogError before anything runs."""
    import pytest

    import ftstab_mj
    from ftstab_mj.config.errors import LogError

    (tmp_path / "file").write_text("x")
    with pytest.raises(LogError, match=r"file: expected a directory for the logs, found a file$"):
        ftstab_mj.run("cart_r2_nominal", out=tmp_path / "file", overrides={"sim.duration": 0.01})
    (tmp_path / "cart_r2_nominal.rrd").write_text("another program's file")
    with pytest.raises(LogError, match=r"cart_r2_nominal.rrd: expected no file or an ftstab log there"):
        ftstab_mj.run("cart_r2_nominal", out=tmp_path, overrides={"sim.duration": 0.01}, rrd=True)
    assert not (tmp_path / "cart_r2_nominal.mcap").exists()  # neither log written
    with pytest.raises(ValueError, match="rrd: expected out= as well"):
        ftstab_mj.run("cart_r2_nominal", overrides={"sim.duration": 0.01}, rrd=True)


def test_run_of_a_user_model_returns_the_notes_the_command_prints(tmp_path):
    """A user's MJCF with a ctrlrange: Result.notes holds the line `ftstab run` prints as "note:"."""
    import ftstab_mj

    (tmp_path / "m.xml").write_text("""<mujoco><worldbody><body name="b"><joint name="x" type="slide" axis="1 0 0"/>
<geom type="box" size=".1 .1 .1" contype="0" conaffinity="0"/></body></worldbody>
<actuator><motor name="m" joint="x" ctrlrange="-5 5"/></actuator></mujoco>""")
    sc = ftstab_mj.scenario_from_dict(
        {"name": "box", "description": "a box on a slide", "plant": {"model": "m.xml", "loops": {"x": {"joint": "x", "saturation": True}}},
         "sim": {"duration": 0.01},
         "loops": {"x": {"z0": [0.1, 0.0], "controller": {"law": "nominal", "k": -0.2, "gains": [1.0, 2.0]}}}},
        base_dir=tmp_path)
    res = ftstab_mj.run(sc)
    assert res.status == "completed" and len(res.notes) == 1
    assert res.notes[0].startswith("loop 'x': ctrlrange [-5.0, 5.0] of actuator 'm' kept as its saturation")
    assert ftstab_mj.run("cart_r2_nominal", overrides={"sim.duration": 0.01}).notes == ()
