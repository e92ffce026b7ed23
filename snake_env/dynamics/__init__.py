"""Pure numerics of the n-link wheeled snake: no gymnasium, no SB3.

``SnakeModel`` holds the parameters; formulations are free functions of
(model, q, u, torques) selected by ``SnakeModel.udot(..., method=...)``:
``kane`` (O(n), default), ``kane_paper`` (the paper's O(n^2) recursion),
``lagrange`` (multipliers, eq. 27) and ``newton_euler`` (Walker-Orin).
"""

from .integrators import Simulation, rk4_step, simulate
from .model import METHODS, SnakeModel

__all__ = ["SnakeModel", "METHODS", "Simulation", "rk4_step", "simulate"]
