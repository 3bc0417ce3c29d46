"""The integrator chain z_i' = z_{i+1}, z_r' = w: its exact transition over a step with w held constant.

With w piecewise constant the chain is linear, so z(t + h) = Phi(h) z(t) + G(h) w exactly, Phi upper
triangular with entries h^(j-i)/(j-i)! and G_i = h^(r-i+1)/(r-i+1)!. The ideal plant and the
reference simulation of the ideal chain both step with it.
"""

from __future__ import annotations

from math import factorial

import numpy as np


def chain_transition(r: int, h: float) -> tuple[np.ndarray, np.ndarray]:
    """(Phi (r, r), G (r,)) with z(t+h) = Phi z(t) + G w for the chain driven by a constant w."""
    Phi = np.zeros((r, r))
    for i in range(r):
        for j in range(i, r):
            Phi[i, j] = h ** (j - i) / factorial(j - i)
    G = np.array([h ** (r - i) / factorial(r - i) for i in range(r)])
    return Phi, G
