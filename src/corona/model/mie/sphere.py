"""A transparent (optionally absorbing) sphere: the Mie scatterer (docs/physics.md#transparent-droplets-mie-spheres).

Unlike the flat shapes, a sphere's far field is not the Fourier transform of
a profile in the layer plane: it depends on the size parameter
``x = 2π r / λ`` and the index ``m(λ)`` separately, and on the true scattering
angle Θ rather than on the projected offset ``d``.  :class:`Sphere` therefore
carries the geometry the point processes need (area ``π r²``, exclusion
diameter ``2r``) and the index; the lobe itself comes from Mie theory
(:mod:`corona.model.mie.theory`) through the sphere material (:mod:`corona.model.mie.layer`),
which :class:`corona.Material` builds for it.
"""
from __future__ import annotations

import math

import numpy as np

from corona._validation import CoronaError, check_positive
from corona.model.shapes.base import Shape

#: ``ior=None``: water at 20 °C with its dispersion (corona.model.mie.theory.water_ior).
WATER = "water"


def _check_ior(ior):
    """None (water) or a complex index n + iκ with n > 0, κ >= 0."""
    if ior is None or (isinstance(ior, str) and ior == WATER):
        return None
    if isinstance(ior, (bool, np.bool_)):
        raise CoronaError(f"ior={ior!r} is not a number; allowed a real or complex index n + iκ "
                          "with n > 0 and κ >= 0, or None (water)")
    try:
        m = complex(ior)
    except (TypeError, ValueError):
        raise CoronaError(f"ior={ior!r} is not a number; allowed a real or complex index n + iκ "
                          "with n > 0 and κ >= 0, or None (water)") from None
    if not (math.isfinite(m.real) and math.isfinite(m.imag)) or m.real <= 0 or m.imag < 0:
        raise CoronaError(f"ior={ior!r} is out of range; allowed n + iκ with n in (0, ∞) and κ in "
                          "[0, ∞) (κ > 0 absorbs; convention of Bohren & Huffman)")
    return m


class Sphere(Shape):
    """A homogeneous sphere of radius ``radius`` [µm] and refractive index ``ior``.

    Parameters
    ----------
    radius : float
        Radius r > 0 [µm]; also ``length_scale``; ``exclusion_diameter = 2r``;
        ``area = π r²`` is its geometric cross-section, so a layer's area
        fraction is ``F_a = n π r²``.
    ior : None, float or complex
        Refractive index relative to the surrounding air, ``n + iκ`` with
        ``κ >= 0`` (absorbing).  None (default): water at 20 °C with its
        dispersion over 360–830 nm (:func:`corona.model.mie.theory.water_ior`, Daimon &
        Masumura 2007).

    Notes
    -----
    The methods of :class:`Shape` that need a planar transmission profile
    (``amplitude``, ``form_factor`` of ``q``) raise a :class:`corona.CoronaError`:
    a sphere's pattern depends on the wavelength through both ``x`` and
    ``m``.  Use ``corona.Material(Sphere(...), process)`` for the lobe, or
    :mod:`corona.model.mie.theory` for the amplitudes.

    Examples
    --------
    >>> import corona
    >>> s = corona.Sphere(5.0)                      # a water droplet, 10 µm across
    >>> s
    Sphere(radius=5, ior='water')
    >>> round(float(s.index(589.29).real), 4)       # 20 °C, relative to air
    1.333
    >>> corona.Sphere(2.0, ior=1.5 + 0.01j).index([400.0, 700.0])
    array([1.5+0.01j, 1.5+0.01j])
    """

    isotropic = True
    _symmetry = 0

    def __init__(self, radius: float, ior=None):
        self.radius = check_positive("radius", radius, "µm")
        self.ior = _check_ior(ior)

    def __repr__(self):
        ior = "'water'" if self.ior is None else (f"{self.ior.real:g}" if self.ior.imag == 0
                                                 else f"{self.ior:g}".strip("()"))
        return f"Sphere(radius={self.radius:g}, ior={ior})"

    @property
    def area(self) -> float:
        return math.pi * self.radius**2

    @property
    def length_scale(self) -> float:
        return self.radius

    def index(self, wavelength) -> np.ndarray:
        """Complex index ``m(λ)`` relative to air at ``wavelength`` [nm]."""
        lam = np.asarray(wavelength, dtype=np.float64)
        if self.ior is None:
            from corona.model.mie.theory import water_ior
            return water_ior(lam).astype(np.complex128)
        return np.full(lam.shape, self.ior, dtype=np.complex128)

    def key(self) -> dict:
        ior = WATER if self.ior is None else [self.ior.real, self.ior.imag]
        return {"type": "Sphere", "radius": self.radius, "ior": ior}

    def _no_profile(self, *args, **kwargs):
        raise CoronaError(f"{self!r} has no planar transmission profile: its Mie pattern depends on "
                          "the wavelength, not on q alone; use corona.Material(sphere, process) or corona.model.mie.theory")

    amplitude = form_factor = coherent_form_factor = _no_profile
    amplitude_radial = form_factor_radial = coherent_form_factor_radial = _no_profile
    table = table_radial = _no_profile


def sphere_parts(shape):
    """``(Sphere, SizeDistribution or None)`` if ``shape`` is a sphere (optionally with a size
    distribution), None if it holds no sphere; a CoronaError for other combinations."""
    from corona.model.shapes.modifiers import SizeDistribution
    if isinstance(shape, Sphere):
        return shape, None
    if isinstance(shape, SizeDistribution) and isinstance(shape.shape, Sphere):
        return shape.shape, shape
    if _contains_sphere(shape):
        raise CoronaError(f"{shape!r}: a Sphere takes only a size distribution "
                          "(corona.SizeDistribution(corona.Sphere(...), spread)); soft edges, "
                          "orientations and mixtures do not apply to Mie spheres")
    return None


def _contains_sphere(shape) -> bool:
    if isinstance(shape, Sphere):
        return True
    inner = getattr(shape, "shape", None)
    if isinstance(inner, Shape) and _contains_sphere(inner):
        return True
    for item in getattr(shape, "components", ()) or ():
        s = item[0] if isinstance(item, tuple) else item
        if isinstance(s, Shape) and _contains_sphere(s):
            return True
    return False
