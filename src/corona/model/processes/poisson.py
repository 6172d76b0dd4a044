"""Independent centres: S(q) = 1."""
from __future__ import annotations


import numpy as np

from corona._validation import check_range
from corona.model import registry
from corona.model.processes.base import Process


class Poisson(Process):
    """Independent, uniformly random centres (overlaps allowed): ``S(q) = 1``.

    Only the dilute limit of a real layer: overlapping scatterers make the
    sum rule ``∫ T_a T_s = 1 - F_a`` fail (the lobe integrates to 1 instead).

    Parameters
    ----------
    area_fraction : float, default 0.1
        ``F_a = n |A|`` in (0, 1).

    Examples
    --------
    ``S = 1`` everywhere, so the lobe of a Poisson layer integrates to ``F_a``
    (not ``F_a (1 - F_a)``: overlaps are counted twice):

    >>> import corona
    >>> p = corona.Poisson(area_fraction=0.3)
    >>> p.structure_factor_radial([0.0, 1.0, 10.0], corona.Circle(radius=1.0))
    array([1., 1., 1.])
    >>> m = corona.Material(corona.Circle(radius=20.0), p)
    >>> round(m.diffuse_transmittance(), 3)
    0.3
    """

    isotropic = True

    def __init__(self, area_fraction: float = 0.1):
        self.fraction = check_range("area_fraction", area_fraction, 0.0, 1.0,
                                    lo_open=True, hi_open=True)

    def __repr__(self):
        return f"Poisson(area_fraction={self.fraction:g})"

    def area_fraction(self, shape) -> float:
        return self.fraction

    varying_area_fraction = True

    def with_area_fraction(self, area_fraction: float) -> "Poisson":
        return Poisson(area_fraction)

    def area_fraction_limit(self, shape) -> float:
        return 1.0 - 1e-6

    def structure_factor_radial(self, q_abs, shape) -> np.ndarray:
        return np.ones_like(np.asarray(q_abs, dtype=np.float64))

    def structure_factor_at(self, q, shape) -> np.ndarray:
        q = np.asarray(q, dtype=np.float64)
        return np.ones(q.shape[:-1])



# --- the family (corona.model.registry): process=poisson -----------------------------------------
registry.add_process(registry.ProcessFamily("poisson", lambda p, shape: Poisson(p["area_fraction"]),
                                            ("area_fraction",), cls=Poisson))
