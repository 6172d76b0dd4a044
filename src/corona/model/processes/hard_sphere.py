"""The hard-sphere fluid in 3D: the Percus–Yevick structure factor (docs/volumes.md#dense-media).

Spheres of diameter ``σ`` at volume fraction ``φ = n π σ³ / 6`` that do not
overlap (milk fat globules, latex, pigments, packed powders) have correlated
positions.  The Percus–Yevick closure of the Ornstein–Zernike equation has the
analytic solution of Wertheim (1963) and Thiele (1963); in the form of Kinning
& Thomas (1984), with ``A = q σ``,

    S(q) = 1 / (1 + 24 φ G(A) / A),
    G(A) / A = α t1(A) + β t2(A) + γ t3(A),
    t1 = (sin A - A cos A) / A³,
    t2 = (2A sin A + (2 - A²) cos A - 2) / A⁴,
    t3 = (-A⁴ cos A + 4[(3A² - 6) cos A + (A³ - 6A) sin A + 6]) / A⁶,
    α = (1 + 2φ)² / (1 - φ)⁴,  β = -6φ (1 + φ/2)² / (1 - φ)⁴,  γ = φ α / 2.

At ``q → 0`` this is the compressibility route of the same closure,
``S(0) = (1 - φ)⁴ / (1 + 2φ)²``.  For small ``A`` the three ``t`` are
evaluated from their series (1/3 - A²/30 + A⁴/840, 1/4 - A²/36 + A⁴/960,
1/6 - A²/48 + A⁴/1200), which avoids the cancellation of the closed forms.

The closure is accurate for the fluid up to ``φ ≈ 0.4`` (the first peak's
height is underestimated by a few per cent at ``φ = 0.4``); the fluid freezes
at ``φ = 0.494``.  :mod:`corona.reference.hard_sphere` checks it against a
Metropolis simulation.

References
----------
1. M. S. Wertheim, "Exact solution of the Percus–Yevick integral equation for
   hard spheres", Phys. Rev. Lett. 10, 321 (1963).
2. E. Thiele, "Equation of state for hard spheres", J. Chem. Phys. 39, 474 (1963).
3. D. J. Kinning, E. L. Thomas, "Hard-sphere interactions between spherical
   domains in diblock copolymers", Macromolecules 17, 1712 (1984).
"""
from __future__ import annotations

import numpy as np

from corona._validation import CoronaError, check_positive

__all__ = ["percus_yevick_3d", "PY_FLUID_LIMIT"]

#: The hard-sphere fluid freezes above this volume fraction (Hoover & Ree 1968).
PY_FLUID_LIMIT = 0.494


def percus_yevick_3d(q, diameter: float, volume_fraction: float) -> np.ndarray:
    """Percus–Yevick ``S(q)`` of hard spheres (module docstring).

    Parameters
    ----------
    q : array
        Momentum transfer ``|q| = 4π sin(Θ/2) / λ`` [rad/µm] (>= 0).
    diameter : float
        Hard-sphere diameter σ [µm].
    volume_fraction : float
        ``φ`` in [0, 0.494) (the fluid).

    Returns
    -------
    ndarray
        ``S(q)`` (dimensionless, > 0), the shape of ``q``.

    Examples
    --------
    The compressibility route, ``S(0) = (1 - φ)⁴ / (1 + 2φ)²``:

    >>> round(float(percus_yevick_3d(0.0, 1.0, 0.3)), 6), round(0.7**4 / 1.6**2, 6)
    (0.093789, 0.093789)
    """
    d = check_positive("diameter", diameter, "µm")
    try:
        phi = float(volume_fraction)
    except (TypeError, ValueError):
        raise CoronaError(f"volume_fraction={volume_fraction!r} is not a number") from None
    if not (0.0 <= phi < PY_FLUID_LIMIT):
        raise CoronaError(f"volume_fraction={volume_fraction!r} is out of range; allowed [0, "
                          f"{PY_FLUID_LIMIT}) (the hard-sphere fluid)")
    A = np.abs(np.asarray(q, dtype=np.float64)) * d
    if phi == 0.0:
        return np.ones_like(A)
    alpha = (1 + 2 * phi) ** 2 / (1 - phi) ** 4
    beta = -6 * phi * (1 + phi / 2) ** 2 / (1 - phi) ** 4
    gamma = phi * alpha / 2
    small = A < 0.5
    As = np.where(small, 1.0, A)              # closed forms away from 0 only
    s, c = np.sin(As), np.cos(As)
    t1 = (s - As * c) / As**3
    t2 = (2 * As * s + (2 - As**2) * c - 2) / As**4
    t3 = (-As**4 * c + 4 * ((3 * As**2 - 6) * c + (As**3 - 6 * As) * s + 6)) / As**6
    A2 = A * A
    t1 = np.where(small, 1 / 3 - A2 / 30 + A2 * A2 / 840, t1)
    t2 = np.where(small, 1 / 4 - A2 / 36 + A2 * A2 / 960, t2)
    t3 = np.where(small, 1 / 6 - A2 / 48 + A2 * A2 / 1200, t3)
    return 1.0 / (1.0 + 24 * phi * (alpha * t1 + beta * t2 + gamma * t3))
