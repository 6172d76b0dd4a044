"""Structure factors of the scatterers' positions (DESIGN §3).

A point process provides

* ``area_fraction(shape)`` — ``F_a = n |A|``;
* ``structure_factor_at(q, shape)`` — ``S(q)`` at wave vectors ``q``
  [rad/µm] of shape (..., 2), without the forward delta, ``S → 1`` at large q;
* ``structure_factor_radial(q_abs, shape)`` for isotropic processes;
* ``isotropic`` — True when S depends on ``|q|`` only.
"""
from __future__ import annotations

import numpy as np

from ._validation import check_range


class Process:
    """Base class of a point process of scatterer centres."""

    isotropic: bool = True

    def area_fraction(self, shape) -> float:
        raise NotImplementedError

    def structure_factor_at(self, q, shape) -> np.ndarray:
        """``S(q)`` at ``q`` [rad/µm] of shape (..., 2)."""
        q = np.asarray(q, dtype=np.float64)
        return self.structure_factor_radial(np.hypot(q[..., 0], q[..., 1]), shape)

    def structure_factor_radial(self, q_abs, shape) -> np.ndarray:
        """``S(|q|)`` for isotropic processes, ``q_abs`` in rad/µm."""
        raise NotImplementedError

    def validate(self, shape) -> None:
        """Raise a clear error if this process cannot hold ``shape`` as given."""

    def key(self) -> dict:
        from .shapes import _keyable
        return {"type": type(self).__name__, **{k: _keyable(v) for k, v in vars(self).items()
                                                if not k.startswith("_")}}


class Poisson(Process):
    """Independent, uniformly random centres (overlaps allowed): ``S(q) = 1``.

    Only the dilute limit of a real layer: overlapping scatterers make the
    sum rule ``∫ T_a T_s = 1 - F_a`` fail (the lobe integrates to 1 instead).

    Parameters
    ----------
    area_fraction : float, default 0.1
        ``F_a = n |A|`` in (0, 1).
    """

    isotropic = True

    def __init__(self, area_fraction: float = 0.1):
        self.fraction = check_range("area_fraction", area_fraction, 0.0, 1.0,
                                    lo_open=True, hi_open=True)

    def __repr__(self):
        return f"Poisson(area_fraction={self.fraction:g})"

    def area_fraction(self, shape) -> float:
        return self.fraction

    def structure_factor_radial(self, q_abs, shape) -> np.ndarray:
        return np.ones_like(np.asarray(q_abs, dtype=np.float64))

    def structure_factor_at(self, q, shape) -> np.ndarray:
        q = np.asarray(q, dtype=np.float64)
        return np.ones(q.shape[:-1])
