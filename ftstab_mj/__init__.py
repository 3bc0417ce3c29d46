"""ftstab_mj: the finite-time controllers of Harmouche, Laghrouche & Chitour on MuJoCo plants.

Python API (ftstab_mj/api.py; imported on first use, so ``import ftstab_mj`` stays cheap):
``run(scenario_or_path, out=None, overrides=None, live=False)``, ``load_scenario(name_or_path,
overrides=None)``, ``replay(path)``.
"""

__version__ = "0.1.0"
__all__ = ["Result", "load_scenario", "replay", "run", "__version__"]


def __getattr__(name):
    if name in ("Result", "load_scenario", "replay", "run"):
        from ftstab_mj import api

        return getattr(api, name)
    raise AttributeError(f"module 'ftstab_mj' has no attribute {name!r}")
