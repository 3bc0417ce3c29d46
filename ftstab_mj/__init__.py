"""ftstab_mj: the finite-time controllers of Harmouche, Laghrouche & Chitour on MuJoCo plants."""

__version__ = "0.1.0"
