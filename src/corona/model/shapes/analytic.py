"""Shapes with closed-form Fourier transforms: circle, ellipse, rectangle, square."""
from __future__ import annotations

import math

import numpy as np
import scipy   # scipy.special: loaded on first use (scipy imports its submodules lazily)

from corona._validation import check_positive
from corona.model import registry
from corona.model.shapes.base import (
    Shape,
    Term,
    _check_finite,
    _gauss_legendre,
    _q_array,
    _radial_array,
    _rotate,
    _sinc,
)


class Circle(Shape):
    """A circular aperture or particle of radius ``radius`` [µm].

    ``Â(q) = π R² · 2 J1(qR)/(qR)``, so ``T_a = (π R²/λ²) (2 J1(u)/u)²``
    with ``u = 2π R |d| / λ`` (Airy pattern; zeros at u = 3.8317, 7.0156, ...).

    Parameters
    ----------
    radius : float
        Radius R > 0 [µm]; also ``length_scale``; ``exclusion_diameter = 2R``.

    References
    ----------
    Born & Wolf, *Principles of Optics*, §8.5.2.

    Examples
    --------
    ``P(0) = |A| = π R²``, and the form factor vanishes on the Airy pattern's
    dark rings (u = qR = 3.8317, 7.0156):

    >>> import numpy as np, corona
    >>> c = corona.Circle(radius=2.0)
    >>> bool(np.isclose(c.form_factor_radial(0.0), np.pi * 2.0**2))
    True
    >>> bool(np.all(c.form_factor_radial(np.array([3.8317, 7.0156]) / 2.0) < 1e-10 * c.area))
    True

    Inside the first dark ring lies ``1 - J0(u1)² - J1(u1)² = 83.8 %`` of the
    diffracted energy (Rayleigh); ``∫ P d²q = (2π)²`` (Parseval):

    >>> from scipy.integrate import quad
    >>> inside, _ = quad(lambda q: 2 * np.pi * q * c.form_factor_radial(q), 0.0, 3.8317 / 2.0)
    >>> round(inside / (2 * np.pi) ** 2, 4)
    0.8378
    """

    isotropic = True
    _symmetry = 0

    def __init__(self, radius: float):
        self.radius = check_positive("radius", radius, "µm")

    def __repr__(self):
        return f"Circle(radius={self.radius:g})"

    @property
    def area(self) -> float:
        return np.pi * self.radius**2

    @property
    def length_scale(self) -> float:
        return self.radius

    @staticmethod
    def airy(u) -> np.ndarray:
        """``2 J1(u)/u`` with its limit 1 at u = 0."""
        u = np.asarray(u, dtype=np.float64)
        out = np.ones_like(u)
        nz = np.abs(u) > 1e-8
        out[nz] = 2.0 * scipy.special.j1(u[nz]) / u[nz]
        return out

    def kernel_terms(self):
        """The shape's closed-form outline(s) for the render kernel (:mod:`corona.mitsuba.kernels`)."""
        if type(self).amplitude is not Circle.amplitude:      # a subclass with a form factor of its own
            return None
        return [Term("circle", {"radius": self.radius}, 1.0, self.area, shape=self)]

    def signed_distance(self, x, y) -> np.ndarray:
        """Signed distance [µm] of the points (x, y) [µm] to the outline (negative inside): the
        brute-force reference rasterises the shape from it (:mod:`corona.reference.wave`)."""
        return np.hypot(x, y) - self.radius

    def amplitude(self, q) -> np.ndarray:
        q = _q_array(q)
        qa = np.hypot(q[..., 0], q[..., 1])
        return (self.area * self.airy(qa * self.radius)).astype(np.complex128)

    def amplitude_radial(self, q_abs) -> np.ndarray:
        u = _radial_array(q_abs) * self.radius
        return (self.area * self.airy(u)).astype(np.complex128)

    def form_factor(self, q) -> np.ndarray:
        q = _q_array(q)
        return self.form_factor_radial(np.hypot(q[..., 0], q[..., 1]))

    def form_factor_radial(self, q_abs) -> np.ndarray:
        u = np.asarray(q_abs, dtype=np.float64) * self.radius
        return self.area * self.airy(u) ** 2

    coherent_form_factor_radial = form_factor_radial

    def coherent_form_factor(self, q) -> np.ndarray:
        return self.form_factor(q)

    def _overlap_sum(self, widths, coeffs) -> float:
        # ∫(B*G_w)² = ∫ C(r) G_{√2 w}(r) d²r with the disk's covariogram
        # C(r) = 2R² acos(r/2R) - (r/2) √(4R² - r²).
        R = self.radius
        x, wt = _gauss_legendre(400)
        total = 0.0
        for w, c in zip(np.ravel(widths), np.ravel(coeffs)):
            if w <= 0.0:
                total += c * self.area
                continue
            s = math.sqrt(2.0) * w
            r_max = min(2.0 * R, 12.0 * s)
            r = 0.5 * r_max * (x + 1.0)
            C = 2 * R**2 * np.arccos(np.minimum(r / (2 * R), 1.0)) \
                - 0.5 * r * np.sqrt(np.maximum(4 * R**2 - r**2, 0.0))
            total += c * float(np.sum(0.5 * r_max * wt * C * np.exp(-r**2 / (2 * s**2)) * r)) / s**2
        return total


class Ellipse(Shape):
    """An elliptical aperture or particle: semi-axis ``radius`` along x, ``aspect · radius`` along y.

    With ``q'`` the wave vector in the ellipse's frame (rotated by ``angle``),
    ``Â(q) = π a b · 2 J1(v)/v``, ``v = √((a q'_x)² + (b q'_y)²)``,
    ``a = radius``, ``b = aspect · radius``: the Airy pattern with
    anisotropically scaled q (the ellipse is an affine image of the unit disk).

    Parameters
    ----------
    radius : float
        Semi-axis a > 0 [µm] along the ellipse's own x axis (the plugin's
        ``radius``).
    aspect : float, default 1
        Semi-axis along y over semi-axis along x, ``b / a`` > 0 (the plugin's
        ``aspect``).
    angle : float, default 0
        Rotation of the ellipse's x axis from the layer's x axis [degree],
        counter-clockwise (the plugin's ``angle``).

    Notes
    -----
    ``length_scale = max(a, b)`` (circumradius), ``exclusion_diameter = 2 max(a, b)``.
    Isotropic only when a == b.  The attributes ``semi_axis_x`` and
    ``semi_axis_y`` are a and b [µm].

    References
    ----------
    Born & Wolf, *Principles of Optics*, §8.5.2; Goodman, *Introduction to
    Fourier Optics*, §2.1 (similarity theorem).

    Examples
    --------
    The same ellipse as the plugin's ``{"shape": "ellipse", "radius": 2, "aspect": 0.5,
    "angle": 30}``; along its short axis the first dark ring is at ``q b = 3.8317``:

    >>> import numpy as np, corona
    >>> e = corona.Ellipse(2.0, aspect=0.5, angle=30.0)
    >>> e.semi_axis_x, e.semi_axis_y, e.length_scale
    (2.0, 1.0, 2.0)
    >>> short = np.array([-np.sin(np.radians(30.0)), np.cos(np.radians(30.0))])
    >>> bool(e.form_factor(3.8317 / 1.0 * short) < 1e-10 * e.area)
    True
    """

    _symmetry = 2

    def __init__(self, radius: float | None = None, *, aspect: float | None = None, angle: float = 0.0):
        self.semi_axis_x = check_positive("radius", radius, "µm")
        aspect = 1.0 if aspect is None else check_positive("aspect", aspect)
        self.semi_axis_y = self.semi_axis_x * aspect
        self.angle = _check_finite("angle", angle, "degree")

    def __repr__(self):
        return f"Ellipse(radius={self.radius:g}, aspect={self.aspect:g}, angle={self.angle:g})"

    @property
    def radius(self) -> float:
        """Semi-axis along the ellipse's x axis [µm] (the plugin's ``radius``)."""
        return self.semi_axis_x

    @property
    def aspect(self) -> float:
        """``semi_axis_y / semi_axis_x``."""
        return self.semi_axis_y / self.semi_axis_x

    @property
    def isotropic(self) -> bool:
        return self.semi_axis_x == self.semi_axis_y

    @property
    def area(self) -> float:
        return np.pi * self.semi_axis_x * self.semi_axis_y

    @property
    def length_scale(self) -> float:
        return max(self.semi_axis_x, self.semi_axis_y)

    def kernel_terms(self):
        """The shape's closed-form outline(s) for the render kernel (:mod:`corona.mitsuba.kernels`)."""
        if type(self).amplitude is not Ellipse.amplitude:      # a subclass with a form factor of its own
            return None
        return [Term("ellipse", {"a": self.semi_axis_x, "b": self.semi_axis_y, "angle": math.radians(self.angle)},
                     1.0, self.area, shape=self)]

    def signed_distance(self, x, y) -> np.ndarray:
        """Signed distance [µm] to the outline, negative inside (to first order off the outline:
        the rasteriser's antialiasing needs it within a pixel of it)."""
        c, s = math.cos(math.radians(self.angle)), math.sin(math.radians(self.angle))
        x, y = c * x + s * y, -s * x + c * y
        a, b = self.semi_axis_x, self.semi_axis_y
        rho = np.hypot(x / a, y / b)
        grad = np.hypot(x / (a * a), y / (b * b))
        with np.errstate(invalid="ignore", divide="ignore"):
            return np.where(grad > 0, (rho - 1.0) * rho / np.maximum(grad, 1e-300), -min(a, b))

    def amplitude(self, q) -> np.ndarray:
        q = _q_array(q)
        qx, qy = _rotate(q, math.radians(self.angle))
        v = np.hypot(self.semi_axis_x * qx, self.semi_axis_y * qy)
        return (self.area * Circle.airy(v)).astype(np.complex128)

    def form_factor(self, q) -> np.ndarray:
        q = _q_array(q)
        qx, qy = _rotate(q, math.radians(self.angle))
        v = np.hypot(self.semi_axis_x * qx, self.semi_axis_y * qy)
        return self.area * Circle.airy(v) ** 2


class Rectangle(Shape):
    """A rectangular aperture or particle: half-width ``radius`` along x, ``aspect · radius`` along y.

    ``Â(q) = W H · sinc(q'_x W/2) · sinc(q'_y H/2)`` with ``sinc(x) = sin(x)/x``,
    the side lengths ``W = 2 radius``, ``H = 2 aspect · radius``, and ``q'`` the
    wave vector in the rectangle's frame (rotated by ``angle``).

    Parameters
    ----------
    radius : float
        Half-width W/2 > 0 [µm] along the rectangle's own x axis (the
        plugin's ``radius``).
    aspect : float, default 1
        Extent along y over extent along x, ``H / W`` > 0 (the plugin's ``aspect``).
    angle : float, default 0
        Rotation of the rectangle's x axis from the layer's x axis [degree],
        counter-clockwise (the plugin's ``angle``).

    Notes
    -----
    ``length_scale = √(W² + H²)/2`` (circumradius, half the diagonal).  The
    attributes ``width`` and ``height`` are the full side lengths W, H [µm].

    References
    ----------
    Born & Wolf, *Principles of Optics*, §8.5.1.
    """

    _symmetry = 2
    _cost = 2.0

    def __init__(self, radius: float | None = None, *, aspect: float | None = None, angle: float = 0.0):
        r = check_positive("radius", radius, "µm")
        aspect = 1.0 if aspect is None else check_positive("aspect", aspect)
        self._set(2.0 * r, 2.0 * r * aspect, _check_finite("angle", angle, "degree"))

    def _set(self, width: float, height: float, angle_deg: float) -> None:
        self.width = width
        self.height = height
        self.angle = angle_deg

    def __repr__(self):
        return f"Rectangle(radius={self.radius:g}, aspect={self.aspect:g}, angle={self.angle:g})"

    @property
    def radius(self) -> float:
        """Half-width along the rectangle's x axis [µm] (the plugin's ``radius``)."""
        return 0.5 * self.width

    @property
    def aspect(self) -> float:
        """``height / width``."""
        return self.height / self.width

    @property
    def area(self) -> float:
        return self.width * self.height

    @property
    def length_scale(self) -> float:
        return 0.5 * math.hypot(self.width, self.height)

    def kernel_terms(self):
        """The shape's closed-form outline(s) for the render kernel (:mod:`corona.mitsuba.kernels`)."""
        if type(self).amplitude is not Rectangle.amplitude:      # a subclass with a form factor of its own
            return None
        return [Term("rect", {"width": self.width, "height": self.height, "angle": math.radians(self.angle)},
                     1.0, self.area, shape=self)]

    def signed_distance(self, x, y) -> np.ndarray:
        """Signed distance [µm] of the points (x, y) [µm] to the outline (negative inside)."""
        c, s = math.cos(math.radians(self.angle)), math.sin(math.radians(self.angle))
        x, y = c * x + s * y, -s * x + c * y
        dx = np.abs(x) - 0.5 * self.width
        dy = np.abs(y) - 0.5 * self.height
        return np.hypot(np.maximum(dx, 0.0), np.maximum(dy, 0.0)) + np.minimum(np.maximum(dx, dy), 0.0)

    def amplitude(self, q) -> np.ndarray:
        q = _q_array(q)
        qx, qy = _rotate(q, math.radians(self.angle))
        a = self.area * _sinc(0.5 * qx * self.width) * _sinc(0.5 * qy * self.height)
        return a.astype(np.complex128)

    def form_factor(self, q) -> np.ndarray:
        q = _q_array(q)
        qx, qy = _rotate(q, math.radians(self.angle))
        return self.area * (_sinc(0.5 * qx * self.width) * _sinc(0.5 * qy * self.height)) ** 2

    def _overlap_sum(self, widths, coeffs) -> float:
        # separable: ∫(box_L * g_w)² dx = ∫ (L - |r|)_+ g_{√2 w}(r) dr
        s = math.sqrt(2.0) * np.asarray(widths, dtype=np.float64).ravel()
        c = np.asarray(coeffs, dtype=np.float64).ravel()
        pos = s > 0
        phi0 = 1.0 / math.sqrt(2 * math.pi)

        def one(L):
            t = L / s[pos]
            return 2.0 * (L * (scipy.special.ndtr(t) - 0.5)
                          - s[pos] * phi0 * (1.0 - np.exp(-0.5 * t * t)))
        blurred = np.sum(c[pos] * one(self.width) * one(self.height))
        return float(np.sum(c[~pos]) * self.area + blurred)


class Square(Rectangle):
    """A square aperture or particle of half-width ``radius`` [µm], rotated by ``angle`` [degree].

    ``Â(q) = s² sinc(q'_x s/2) sinc(q'_y s/2)`` with the side ``s = 2 radius``
    (see :class:`Rectangle`); ``length_scale = s/√2``.  ``Square(r, angle=a)``
    is the plugin's ``{"shape": "square", "radius": r, "angle": a}``.

    Parameters
    ----------
    radius : float
        Half the side, s/2 > 0 [µm] (the plugin's ``radius``).
    angle : float, default 0
        Rotation [degree], counter-clockwise (the plugin's ``angle``).

    Examples
    --------
    Along an edge normal, ``P/|A| = sinc²(q s/2)``: 1 at q = 0, ``(2/π)²`` at
    ``q s/2 = π/2``, 0 at the first zero ``q s/2 = π``:

    >>> import numpy as np, corona
    >>> sq = corona.Square(1.5)                          # side 3 µm
    >>> sq.area, round(sq.length_scale, 4)                 # s², s/√2
    (9.0, 2.1213)
    >>> q = np.array([[0.0, 0.0], [np.pi / 3, 0.0], [2 * np.pi / 3, 0.0]])
    >>> (sq.form_factor(q) / sq.area).round(4)
    array([1.    , 0.4053, 0.    ])
    """

    _symmetry = 4

    def __init__(self, radius: float | None = None, *, angle: float = 0.0):
        r = check_positive("radius", radius, "µm")
        self._set(2.0 * r, 2.0 * r, _check_finite("angle", angle, "degree"))

    def __repr__(self):
        return f"Square(radius={self.radius:g}, angle={self.angle:g})"

    def key(self) -> dict:
        return {"type": "Square", "side": self.width, "angle": self.angle}


# --- the families (corona.model.registry): shape=circle, ellipse, square, rectangle --------------
_R = ("radius",) + registry.FLAT
registry.add_shape(registry.ShapeFamily("circle", lambda p: Circle(p["radius"]), _R, cls=Circle,
                                        mixable=True))
registry.add_shape(registry.ShapeFamily(
    "ellipse", lambda p: Ellipse(p["radius"], aspect=p["aspect"], angle=p["angle"]),
    _R + ("aspect", "angle") + registry.ROTATABLE, cls=Ellipse, mixable=True))
registry.add_shape(registry.ShapeFamily("square", lambda p: Square(p["radius"], angle=p["angle"]),
                                        _R + ("angle",) + registry.ROTATABLE, cls=Square, mixable=True))
registry.add_shape(registry.ShapeFamily(
    "rectangle", lambda p: Rectangle(p["radius"], aspect=p["aspect"], angle=p["angle"]),
    _R + ("aspect", "angle") + registry.ROTATABLE, cls=Rectangle, mixable=True))
