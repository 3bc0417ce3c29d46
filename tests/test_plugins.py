"""Laws and plants from outside the package, through the real command line, from a temporary folder.

A plugin file named by a scenario's ``plugins``, and a distribution's entry point (a ``.dist-info``
folder on PYTHONPATH, as pip installs one), each run through ``ftstab run``, ``sweep`` (processes),
``compare`` and ``replay --verify``; a changed or missing plugin is one line, exit 2.
"""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
import textwrap

import pytest

LAW = '''
"""A PD law written outside the package."""
from dataclasses import dataclass

import numpy as np

from ftstab_mj.control import Law, LawOutput, Param, register_law


@register_law
@dataclass(frozen=True)
class {cls}(Law):
    name = "{name}"
    summary = "u = -kp z1 - kd z2 (a user's PD law)"
    params = (Param("kp", float, "proportional gain", "1/s^2"), Param("kd", float, "derivative gain", "1/s"))
    r: int
    kp: float
    kd: float

    @classmethod
    def from_params(cls, r, values):
        return cls(r, float(values["kp"]), float(values["kd"]))

    def evaluate(self, z, state):
        z = np.asarray(z, dtype=float)
        u = -self.kp * z[..., 0] - self.kd * z[..., 1]
        nan = np.full_like(u, np.nan)
        return LawOutput(u, nan, nan, nan, nan, nan)
'''

PLANT = '''
"""A heavier cart registered under a name of its own."""
from ftstab_mj.plants import make_plant, register_plant

register_plant("heavy_cart", lambda name, params: make_plant("cart", {"mass": 4.0, **params}),
               "the cart with a 4 kg mass (a user's plant)")
'''

SCENARIO = '''
name = "{name}"
description = "a user's law on a user's plant"
{plugins}

[plant]
model = "{model}"

[sim]
duration = 3.0
period = 0.002
physics_step = 0.001

[loops.cart]
z0 = [1.0, 0.0]

[loops.cart.controller]
law = "{law}"
kp = 25.0
kd = 10.0
'''


GAINS_SWEEP = textwrap.dedent('''
    name = "pd_gains"
    description = "the plugin's PD law over two gains"
    scenario = "pd.toml"
    [set]
    "sim.duration" = 1.0
    [grid]
    "loops.cart.controller.kp" = [16.0, 36.0]
    ''')


def ftstab(*args, cwd, env=None, timeout=300):
    return subprocess.run([sys.executable, "-m", "ftstab_mj", *map(str, args)], cwd=cwd, capture_output=True,
                          text=True, timeout=timeout, env=env)


@pytest.fixture
def user_folder(tmp_path):
    """A folder outside the repository with a law file, a plant file and a scenario naming both."""
    (tmp_path / "my_laws.py").write_text(LAW.format(cls="MyPD", name="my_pd"))
    (tmp_path / "my_plants.py").write_text(PLANT)
    (tmp_path / "pd.toml").write_text(SCENARIO.format(name="heavy_pd", plugins='plugins = ["my_laws.py", "my_plants.py"]',
                                                      model="heavy_cart", law="my_pd"))
    return tmp_path


def pd_reference(kp=25.0, kd=10.0, period=0.002, step=0.001, duration=3.0):
    """An independent reference: the cart as a double integrator (u in chain units, m/s^2) under MuJoCo's
    semi-implicit Euler (v += h u, then x += h v), u = -kp x - kd v held over each control period.
    Returns the samples x(t_k), t_k = k period."""
    x, v, xs = 1.0, 0.0, []
    for _ in range(round(duration / period)):
        xs.append(x)
        u = -kp * x - kd * v
        for _ in range(round(period / step)):
            v += step * u
            x += step * v
    return xs


def check_pd(json_text: str) -> None:
    """The plugin's PD law ran on a cart: the final window's max |x| (the last 20 % of the run, from
    2.4 s) is the reference's, to rounding (the closed loop is (s + 5)^2: |x| decreasing, near
    13 e^-12 = 8.0e-5 in continuous time, 8.9e-5 sampled at 2 ms)."""
    m = json.loads(json_text)["loops"]["cart"]
    assert m["final_window_start"] == pytest.approx(2.4)
    ref = pd_reference()
    assert m["final_abs_z_max"][0] == pytest.approx(max(abs(x) for x in ref[1200:]), rel=1e-9)


def test_a_plugin_law_and_plant_run_replay_and_verify(user_folder):
    run = ftstab("run", "pd.toml", "--out", "runs", "--json", cwd=user_folder)
    assert run.returncode == 0, run.stderr
    check_pd(run.stdout)
    listed = ftstab("list", cwd=user_folder)  # without the scenario, `list` knows only the installed ones
    assert "heavy_cart" not in listed.stdout
    log = user_folder / "runs" / "heavy_pd.mcap"
    verify = ftstab("replay", log, "--verify", cwd=user_folder)
    assert verify.returncode == 0, verify.stderr
    assert "bit-identical" in verify.stdout
    # the same log replayed from another folder: the log pins the plugins by absolute path and content
    elsewhere = ftstab("replay", log, "--verify", cwd=user_folder.parent)
    assert elsewhere.returncode == 0, elsewhere.stderr


def test_a_changed_or_missing_plugin_is_one_line_exit_2(user_folder):
    assert ftstab("run", "pd.toml", "--out", "runs", cwd=user_folder).returncode == 0
    log = user_folder / "runs" / "heavy_pd.mcap"
    with open(user_folder / "my_laws.py", "a") as f:
        f.write("# edited after the run\n")
    changed = ftstab("replay", log, "--verify", cwd=user_folder)
    assert changed.returncode == 2
    assert changed.stderr.count("\n") == 1 and "plugins[0]" in changed.stderr and "a changed file" in changed.stderr
    (user_folder / "my_laws.py").unlink()
    missing = ftstab("run", "pd.toml", "--out", "runs", cwd=user_folder)
    assert missing.returncode == 2
    assert missing.stderr.startswith("error: pd.toml: plugins[0]: expected an existing Python file")
    assert missing.stderr.count("\n") == 1


def test_a_plugin_that_raises_is_one_line_naming_its_line(user_folder):
    (user_folder / "my_laws.py").write_text("import numpy\n\nraise RuntimeError('broken on purpose')\n")
    res = ftstab("run", "pd.toml", "--out", "runs", cwd=user_folder)
    assert res.returncode == 2
    assert res.stderr.strip().endswith("found RuntimeError: broken on purpose (line 3)"), res.stderr
    assert "Traceback" not in res.stderr


def test_an_unknown_law_is_named_as_such(user_folder):
    (user_folder / "no_plugin.toml").write_text(SCENARIO.format(name="x", plugins="", model="cart", law="my_pd"))
    res = ftstab("run", "no_plugin.toml", "--out", "runs", cwd=user_folder)
    assert res.returncode == 2
    line = res.stderr.strip()
    assert line.startswith("error: no_plugin.toml: loops.cart.controller.law: expected a registered law (known: nominal, ")
    assert line.endswith("found unknown law 'my_pd'") and "plugins = [...]" in line


def test_a_plugin_law_in_a_sweep_on_processes_and_in_a_comparison(user_folder):
    (user_folder / "gains.toml").write_text(GAINS_SWEEP)
    sweep = ftstab("sweep", user_folder / "gains.toml", "--workers", "2", "--engine", "processes", "--format", "csv",
                   "--out", user_folder / "sw", cwd=user_folder.parent)
    assert sweep.returncode == 0, sweep.stderr
    with open(user_folder / "sw" / "pd_gains.csv", newline="") as f:
        table = list(csv.DictReader(f))
    assert [row["status"] for row in table] == ["completed", "completed"]
    (user_folder / "cmp.toml").write_text(textwrap.dedent('''
        name = "pd_vs_linear"
        description = "the plugin's law beside a shipped one"
        scenario = "pd.toml"
        [set]
        "sim.duration" = 1.0
        [[laws]]
        label = "my pd"
        controller = { law = "my_pd", kp = 25.0, kd = 10.0 }
        [[laws]]
        label = "nominal"
        controller = { law = "nominal", k = -0.2, gains = [1.0, 2.0] }
        '''))
    # from another folder: the plugins are relative to the base scenario, not to where the command runs
    cmp = ftstab("compare", user_folder / "cmp.toml", "--out", user_folder / "cmp", cwd=user_folder.parent)
    assert cmp.returncode == 0, cmp.stderr
    with open(user_folder / "cmp" / "pd_vs_linear.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert [(row["label"], row["status"]) for row in rows] == [("my pd", "completed"), ("nominal", "completed")]


def test_a_plugin_law_in_a_sweep_on_dask_workers(user_folder):
    """Dask workers are processes of their own (not forks of the command): they import the pinned
    plugins when a row's scenario reaches them."""
    from distributed import LocalCluster

    (user_folder / "gains.toml").write_text(GAINS_SWEEP)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None,
                      host="127.0.0.1") as cluster:
        sweep = ftstab("sweep", "gains.toml", "--scheduler", cluster.scheduler_address, "--format", "csv",
                       "--out", "dk", cwd=user_folder)
    assert sweep.returncode == 0, sweep.stderr
    with open(user_folder / "dk" / "pd_gains.csv", newline="") as f:
        assert [row["status"] for row in csv.DictReader(f)] == ["completed", "completed"]


def test_an_installed_distribution_declares_a_law_by_entry_point(tmp_path):
    """An entry point of group ftstab_mj.laws, found by importlib.metadata as pip would install it."""
    site = tmp_path / "site"
    (site / "acme_laws").mkdir(parents=True)
    (site / "acme_laws" / "__init__.py").write_text(LAW.format(cls="AcmePD", name="acme_pd"))
    info = site / "acme_laws-1.0.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: acme-laws\nVersion: 1.0\n")
    (info / "entry_points.txt").write_text("[ftstab_mj.laws]\nacme_pd = acme_laws\n")
    work = tmp_path / "work"
    work.mkdir()
    (work / "acme.toml").write_text(SCENARIO.format(name="acme", plugins="", model="cart", law="acme_pd"))
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(site), os.environ.get("PYTHONPATH")]))}
    run = ftstab("run", "acme.toml", "--out", "runs", "--json", cwd=work, env=env)
    assert run.returncode == 0, run.stderr
    check_pd(run.stdout)
    verify = ftstab("replay", work / "runs" / "acme.mcap", "--verify", cwd=work, env=env)
    assert verify.returncode == 0, verify.stderr
    listed = ftstab("list", cwd=work, env=env)
    assert "acme_pd: u = -kp z1 - kd z2 (a user's PD law)  [distribution acme-laws]" in listed.stdout
