"""ftstab_mj: the finite-time controllers of Harmouche, Laghrouche & Chitour on MuJoCo plants.

Python API (ftstab_mj/api.py; imported on first use, so ``import ftstab_mj`` stays cheap):
``run(scenario_or_path, out=None, overrides=None, live=False)``, ``load_scenario(name_or_path,
overrides=None)``, ``scenario_from_dict(data, overrides=None, base_dir=None)``, ``replay(path)``.
"""

# Bumped, with a CHANGELOG.md entry, whenever the log or scenario format changes; logs record both.
__version__ = "0.4.0"
LOG_FORMAT = 2  # the MCAP log's layout (1: every log written before 0.2.0); readers branch on it
__all__ = ["Result", "load_scenario", "replay", "run", "scenario_from_dict", "__version__"]


def __getattr__(name):
    if name in ("Result", "load_scenario", "replay", "run", "scenario_from_dict"):
        from ftstab_mj import api

        return getattr(api, name)
    raise AttributeError(f"module 'ftstab_mj' has no attribute {name!r}")
