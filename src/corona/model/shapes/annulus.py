"""A ring: shape=annulus, added through the registry alone (docs/adding_a_scatterer.md)."""
from __future__ import annotations

import numpy as np

from corona._validation import check_positive, check_range
from corona.model import registry
from corona.model.shapes.analytic import Circle
from corona.model.shapes.base import Shape, _q_array, _radial_array

#: Largest inner radius over the outer one: a thinner ring spreads its lobe beyond the tables' range.
INNER_RATIO_MAX = 0.9


class Annulus(Shape):
    """A ring of outer radius ``radius`` R and inner radius ``inner_ratio · R`` [µm].

    ``Â(q) = π R² · 2 J1(qR)/(qR) - π r² · 2 J1(qr)/(qr)``: the disk of radius R less the
    disk of radius r (the transform is linear), ``|A| = π (R² - r²)``.

    >>> import numpy as np, corona
    >>> a = corona.model.shapes.annulus.Annulus(radius=2.0, inner_ratio=0.5)
    >>> bool(np.isclose(a.form_factor_radial(0.0), a.area)), round(a.area, 4)
    (True, 9.4248)
    """

    isotropic = True
    _symmetry = 0

    def __init__(self, radius: float, inner_ratio: float = 0.5):
        self.radius = check_positive("radius", radius, "µm")
        self.inner_ratio = check_range("inner_ratio", inner_ratio, 0.0, INNER_RATIO_MAX)

    def __repr__(self):
        return f"Annulus(radius={self.radius:g}, inner_ratio={self.inner_ratio:g})"

    @property
    def area(self) -> float:
        return np.pi * self.radius**2 * (1.0 - self.inner_ratio**2)

    @property
    def length_scale(self) -> float:
        return self.radius

    def amplitude_radial(self, q_abs) -> np.ndarray:
        R, r = self.radius, self.radius * self.inner_ratio
        q = _radial_array(q_abs)
        return (np.pi * (R * R * Circle.airy(q * R) - r * r * Circle.airy(q * r))).astype(np.complex128)

    def amplitude(self, q) -> np.ndarray:
        q = _q_array(q)
        return self.amplitude_radial(np.hypot(q[..., 0], q[..., 1]))

    def signed_distance(self, x, y) -> np.ndarray:
        """Signed distance [µm] to the two circles (negative inside the ring)."""
        rho = np.hypot(x, y)
        return np.maximum(rho - self.radius, self.radius * self.inner_ratio - rho)


registry.add_shape(registry.ShapeFamily(
    "annulus", lambda p: Annulus(p["radius"], p["inner_ratio"]), ("radius", "inner_ratio") + registry.FLAT,
    new_parameters=(dict(name="inner_ratio", kind="float", unit="", default=0.5, low=0.0, high=INNER_RATIO_MAX,
                         meaning="annulus: inner radius over radius"),), cls=Annulus, mixable=True))
