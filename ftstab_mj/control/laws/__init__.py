"""The registered control laws: every module of this package is imported, and registers its laws.

A new law is one new module here (see ftstab_mj/control/law.py for the protocol).
"""

import importlib
import pkgutil

from ftstab_mj.control.laws.paper import AdaptiveLaw, NominalLaw, RobustLaw, advance_phi_hat

for _module in pkgutil.iter_modules(__path__):
    importlib.import_module(f"{__name__}.{_module.name}")

__all__ = ["AdaptiveLaw", "NominalLaw", "RobustLaw", "advance_phi_hat"]
