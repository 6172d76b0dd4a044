"""Dr.Jit pieces of spheres on a fixed lattice (docs/physics.md#spheres-on-a-lattice).

:class:`LatticeS` evaluates a fixed :class:`corona.Lattice`'s structure factor per lane in closed
form, as :meth:`corona.Lattice.structure_factor_at` does in numpy:

    S(q) = 1 - e^{-q²δ²} + Σ_{G ≠ 0, near q} (2π)² n e^{-G²δ²} e^{-|q - G|²/2w²} / (2π w²)

over the ``(2m + 1)²`` reciprocal lattice vectors about the one nearest ``q`` in fractional
coordinates (``f = q · a_i / 2π`` rounded; ``m = ⌈1/2 + 6 w a / 2π⌉``, 1 for the default
crystallite of 20 spacings: the nearest 3 × 3 peaks), ``w`` the peaks' rms width.  It is what the
renderer's lattice lobe ``F_s w P S`` needs besides the sphere plugin's Mie rows and the cap
(:mod:`corona.model.mie.lattice_cap`).  The renderer does not carry spheres on a lattice yet
(the sphere plugin refuses them in one line): the cap's per-lane bound is not tight enough to
render with (docs/physics.md#spheres-on-a-lattice).
"""
from __future__ import annotations

import math

import drjit as dr
import mitsuba as mi
import numpy as np

__all__ = ["LatticeS"]


class LatticeS:
    """A fixed lattice's ``S(q)`` in Dr.Jit (module docstring).

    Parameters
    ----------
    lattice : corona.Lattice
        With ``orientation="fixed"``.
    """

    def __init__(self, lattice):
        A = np.asarray(lattice.lattice_vectors, dtype=np.float64)
        B = np.asarray(lattice.reciprocal_vectors, dtype=np.float64)
        w = float(lattice.peak_width)
        self.A = A / (2.0 * np.pi)            # f = q · a_i / 2π
        self.B = B
        self.jitter2 = float(lattice.jitter) ** 2
        self.inv_2w2 = 0.5 / (w * w)
        self.amp = (2.0 * np.pi) ** 2 * float(lattice.number_density) / (2.0 * np.pi * w * w)
        self.m = max(1, int(math.ceil(0.5 + 6.0 * w * lattice.spacing / (2.0 * np.pi))))

    def __call__(self, qx, qy):
        """``S`` at the in-plane momentum transfer ``(qx, qy)`` [rad/µm] (mi.Float each)."""
        A, B = self.A, self.B
        f1 = dr.round(qx * A[0, 0] + qy * A[0, 1])
        f2 = dr.round(qx * A[1, 0] + qy * A[1, 1])
        out = 1.0 - dr.exp(-(qx * qx + qy * qy) * self.jitter2) if self.jitter2 > 0 else mi.Float(0.0)
        for dh in range(-self.m, self.m + 1):
            for dk in range(-self.m, self.m + 1):
                h, k = f1 + dh, f2 + dk
                gx = h * B[0, 0] + k * B[1, 0]
                gy = h * B[0, 1] + k * B[1, 1]
                dx, dy = qx - gx, qy - gy
                e = -(dx * dx + dy * dy) * self.inv_2w2
                if self.jitter2 > 0:
                    e = e - (gx * gx + gy * gy) * self.jitter2
                peak = self.amp * dr.exp(e)
                out = out + dr.select((h == 0) & (k == 0), 0.0, peak)
        return out
