"""Layer 2, control: the paper's mathematics and every law as plain NumPy (no MuJoCo).

Hong's controller, V1, the laws (one module each in ``laws/``; the protocol and registry in ``law``),
the certificate and the gain designer. May import: config.
"""

from ftstab_mj.control.certificate import Certificate, Theorem3Bounds, certify, theorem3_bounds
from ftstab_mj.control.hong import (
    HongController, HongOutput, gains_for_polynomial, is_hurwitz, nested_polynomial, sig,
)
from ftstab_mj.control.law import LAWS, Law, LawOutput, Param, law_class, register_law
from ftstab_mj.control.laws import AdaptiveLaw, NominalLaw, RobustLaw, advance_phi_hat

__all__ = [
    "LAWS", "AdaptiveLaw", "Certificate", "HongController", "HongOutput", "Law", "LawOutput", "NominalLaw", "Param",
    "RobustLaw", "law_class", "register_law",
    "Theorem3Bounds", "advance_phi_hat", "certify", "gains_for_polynomial", "is_hurwitz", "nested_polynomial", "sig", "theorem3_bounds",
]
