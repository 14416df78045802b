"""Beam theory oracles shared by tests: the inextensible elastica of a cantilever under its own weight.

Kirchhoff rod in the x–z plane, arc length s ∈ [0, L], tangent (cos θ, sin θ) (θ counter-clockwise from +x towards
+z), a dead vertical load −q e_z per unit length. The internal force is n(s) = −q (L − s) e_z and the moment balance
m' + t × n = 0 with m = EI θ' gives

    EI θ''(s) = q (L − s) cos θ(s),      θ(0) = θ0 (the clamp),      θ'(L) = 0 (free tip),

solved here by collocation (scipy's ``solve_bvp``) from the straight beam. For small loads the tip deflection is
Euler–Bernoulli's −q L⁴/(8 EI); a helper module of the tests, not a test file.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.integrate import solve_bvp


@dataclass(frozen=True)
class ElasticaTip:
    x: float       #: tip position along x (m)
    z: float       #: tip position along z (m)
    theta: float   #: tip tangent angle (rad, counter-clockwise from +x towards +z)


def cantilever_elastica(q: float, EI: float, L: float, theta0: float = 0.0, nodes: int = 2001,
                        continuation: int = 1) -> ElasticaTip:
    """Tip of the elastica of a cantilever of length ``L`` clamped at angle ``theta0`` under ``q`` (N/m) along −z.

    ``continuation`` > 1 ramps the load geometrically from ``q``/100 in that many solves, each started from the
    previous solution (large loads, where the straight beam is too far from the solution for one solve)."""
    s = np.linspace(0.0, L, nodes)
    y = np.vstack([np.full_like(s, theta0), np.zeros_like(s), s * np.cos(theta0), s * np.sin(theta0)])
    loads = q * np.geomspace(0.01, 1.0, continuation) if continuation > 1 else [q]
    for load in loads:
        def rhs(s, y, load=load):  # y = (θ, θ', x, z)
            return np.vstack([y[1], load * (L - s) * np.cos(y[0]) / EI, np.cos(y[0]), np.sin(y[0])])

        def bc(a, b):
            return np.array([a[0] - theta0, b[1], a[2], a[3]])

        sol = solve_bvp(rhs, bc, s, y, tol=1e-10, max_nodes=200000)
        if not sol.success:
            raise RuntimeError(f"elastica did not converge at load {load:g} N/m: {sol.message}")
        y = sol.sol(s)
    theta, _, x, z = sol.sol(L)
    return ElasticaTip(float(x), float(z), float(theta))
