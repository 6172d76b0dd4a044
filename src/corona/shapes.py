"""Form factors of single scatterers (DESIGN §3).

Every shape is a transmission profile ``A(x)`` in the layer plane, lengths in
micrometres, centred on its centroid.  Its Fourier transform
``Â(q) = ∫ A(x) exp(-i q·x) dx`` is taken at wave vectors ``q`` in rad/µm,
given as arrays of shape ``(..., 2)``.

A shape provides

* ``area`` — ``|A| = ∫ A dx`` [µm²] (the mean ``⟨|A|⟩`` for random shapes);
* ``length_scale`` — the length ``R`` [µm] of the dimensionless variable
  ``u = q R = 2π R |d| / λ``: the circumradius (largest distance from the
  centroid to the boundary; the radius for a circle);
* ``exclusion_diameter`` — the default hard-core diameter σ [µm] of the
  point process, ``2 · length_scale`` (the circumscribed diameter);
* ``amplitude(q)`` — ``Â(q)`` [µm²]; for random shapes (random orientation,
  size distribution, mixture) the ensemble mean ``⟨Â(q)⟩``;
* ``form_factor(q)`` — ``⟨|Â(q)|²⟩ / ⟨|A|⟩`` [µm²] (averaged over orientation
  and size where the shape is random);
* ``coherent_form_factor(q)`` — ``|⟨Â(q)⟩|² / ⟨|A|⟩`` [µm²], which equals
  ``form_factor`` for a deterministic shape and enters the decoupling rule
  ``I ∝ n [⟨|Â|²⟩ + |⟨Â⟩|² (S - 1)]`` for random ones.  By Cauchy–Schwarz
  ``coherent_form_factor <= form_factor``;
* ``isotropic`` — True when the form factor depends on ``|q|`` only; those
  shapes also give ``form_factor_radial``, ``coherent_form_factor_radial`` and
  ``amplitude_radial`` of ``|q|``;
* ``self_overlap`` — ``⟨∫A²⟩ / ⟨∫A⟩`` (1 for binary shapes, < 1 for soft
  profiles): the value of ``∫ T_a d²d`` by Parseval.

Shapes: :class:`Circle`, :class:`Ellipse`, :class:`Rectangle`, :class:`Square`,
:class:`Polygon`, :class:`RegularPolygon` (closed-form transforms),
:class:`Mask` (image, FFT); modifiers and ensembles: :class:`SoftEdge`
(Gaussian-blurred edge), :class:`RandomOrientation`, :class:`SizeDistribution`,
:class:`Mixture`.  Composites nest freely, e.g.
``SizeDistribution(RandomOrientation(SoftEdge(Square(1.0), 0.05)), 0.2)``.

The normalised form factor of DESIGN §3 is
``T_a(d) = form_factor(2π d/λ) / λ²``; it integrates to ``self_overlap``
(= 1 for binary shapes) over the d plane.  ``table(u)`` / ``table_radial(u)``
give the dimensionless ``form_factor(u/R)/R²`` with ``R = length_scale``, so
``T_a(d) = (R²/λ²) · table(2π R d / λ)`` for every wavelength and size.

References
----------
M. Born, E. Wolf, *Principles of Optics*, 7th ed., §8.5 (Fraunhofer
diffraction by circular and rectangular apertures).
J. W. Goodman, *Introduction to Fourier Optics*, 3rd ed., ch. 4.
"""
from __future__ import annotations

import math
import os
from functools import reduce

import numpy as np
from scipy import fft as sp_fft
from scipy import ndimage, special

from ._validation import CoronaError, check_choice, check_positive, check_range

_TWO_PI = 2.0 * np.pi


# --------------------------------------------------------------------------
# input helpers
# --------------------------------------------------------------------------
def _q_array(q) -> np.ndarray:
    try:
        q = np.asarray(q, dtype=np.float64)
    except (TypeError, ValueError):
        raise CoronaError(f"q={q!r} is not a numeric array of shape (..., 2) rad/µm") from None
    if q.ndim == 0 or q.shape[-1] != 2:
        raise CoronaError(f"q must have shape (..., 2) [rad/µm], got shape {q.shape}")
    return q


def _radial_array(q_abs) -> np.ndarray:
    try:
        return np.asarray(q_abs, dtype=np.float64)
    except (TypeError, ValueError):
        raise CoronaError(f"q_abs={q_abs!r} is not a numeric array [rad/µm]") from None


def _check_finite(name: str, value, unit: str = "") -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise CoronaError(f"{name}={value!r} is not a number; expected a finite value"
                          + (f" {unit}" if unit else "")) from None
    if not math.isfinite(v):
        raise CoronaError(f"{name}={value!r} is out of range; expected a finite value"
                          + (f" {unit}" if unit else ""))
    return v


def _check_int(name: str, value, lo: int, hi: int) -> int:
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        if isinstance(value, (float, np.floating)) and float(value).is_integer():
            value = int(value)
        else:
            raise CoronaError(f"{name}={value!r} is not an integer; allowed {lo}..{hi}")
    v = int(value)
    if v < lo or v > hi:
        raise CoronaError(f"{name}={value!r} is out of range; allowed integers {lo}..{hi}")
    return v


def _check_shape(name: str, value) -> "Shape":
    if not isinstance(value, Shape):
        raise CoronaError(f"{name}={value!r} is not a corona Shape (Circle, Polygon, Mask, ...)")
    return value


def _rotate(q: np.ndarray, angle: float):
    """Components of ``q`` in a frame rotated by ``angle`` (i.e. ``R(-angle) q``)."""
    if angle == 0.0:
        return q[..., 0], q[..., 1]
    c, s = math.cos(angle), math.sin(angle)
    return c * q[..., 0] + s * q[..., 1], -s * q[..., 0] + c * q[..., 1]


def _sinc(x):
    """``sin(x)/x`` with the limit 1 at 0."""
    return np.sinc(np.asarray(x) / np.pi)


# --------------------------------------------------------------------------
# base class
# --------------------------------------------------------------------------
class Shape:
    """Base class of a scatterer's transmission profile (see the module docstring)."""

    isotropic: bool = False
    #: order m of the rotational symmetry (Â(R_{2π/m} q) = Â(q)); 0 = continuous.
    _symmetry: int = 1
    #: True when the profile is fixed (no orientation / size / type average).
    _deterministic: bool = True

    @property
    def area(self) -> float:
        raise NotImplementedError

    @property
    def length_scale(self) -> float:
        raise NotImplementedError

    @property
    def exclusion_diameter(self) -> float:
        """Default hard-core diameter σ [µm]: ``2 · length_scale``."""
        return 2.0 * self.length_scale

    @property
    def _support(self) -> float:
        """Radius [µm] about the centroid holding (nearly) all of A: bounds the
        angular bandwidth of Â (harmonics up to order ≈ |q| · _support)."""
        return self.length_scale

    @property
    def self_overlap(self) -> float:
        """``⟨∫A²⟩ / ⟨∫A⟩`` (dimensionless); 1 for binary shapes.

        By Parseval this is ``∫ T_a d²d``, the integral of the normalised lobe.
        """
        return 1.0

    def amplitude(self, q) -> np.ndarray:
        """Complex Fourier transform ``Â(q)`` [µm²] at ``q`` [rad/µm], shape (..., 2).

        For random shapes this is the ensemble mean ``⟨Â(q)⟩``.
        """
        raise NotImplementedError

    def form_factor(self, q) -> np.ndarray:
        """``⟨|Â(q)|²⟩ / ⟨|A|⟩`` [µm²] at ``q`` [rad/µm] of shape (..., 2)."""
        return np.abs(self.amplitude(q)) ** 2 / self.area

    def coherent_form_factor(self, q) -> np.ndarray:
        """``|⟨Â(q)⟩|² / ⟨|A|⟩`` [µm²]; equals :meth:`form_factor` for a fixed shape."""
        return np.abs(self.amplitude(q)) ** 2 / self.area

    # --- radial helpers (isotropic shapes only) -------------------------
    def amplitude_radial(self, q_abs) -> np.ndarray:
        """``⟨Â⟩`` [µm²] at ``|q|`` [rad/µm] for isotropic shapes."""
        q_abs = _radial_array(q_abs)
        q = np.stack([q_abs, np.zeros_like(q_abs)], axis=-1)
        return self.amplitude(q)

    def form_factor_radial(self, q_abs) -> np.ndarray:
        """Form factor at ``|q|`` [rad/µm] for isotropic shapes."""
        q_abs = _radial_array(q_abs)
        q = np.stack([q_abs, np.zeros_like(q_abs)], axis=-1)
        return self.form_factor(q)

    def coherent_form_factor_radial(self, q_abs) -> np.ndarray:
        """Coherent form factor at ``|q|`` [rad/µm] for isotropic shapes."""
        q_abs = _radial_array(q_abs)
        q = np.stack([q_abs, np.zeros_like(q_abs)], axis=-1)
        return self.coherent_form_factor(q)

    def table(self, u) -> np.ndarray:
        """Dimensionless form factor ``form_factor(u/R) / R²`` at ``u`` (..., 2)."""
        R = self.length_scale
        return self.form_factor(np.asarray(u, dtype=np.float64) / R) / R**2

    def table_radial(self, u) -> np.ndarray:
        """Dimensionless radial form factor ``form_factor(|u|/R) / R²`` (isotropic)."""
        R = self.length_scale
        return self.form_factor_radial(np.asarray(u, dtype=np.float64) / R) / R**2

    def key(self) -> dict:
        """Parameters that identify this shape (for table caching)."""
        return {"type": type(self).__name__, **{k: _keyable(v) for k, v in vars(self).items()
                                                if not k.startswith("_")}}

    # --- internal ---------------------------------------------------------
    def _intensity(self, q) -> np.ndarray:
        """``⟨|Â(q)|²⟩`` [µm⁴]."""
        return self.form_factor(q) * self.area

    def _intensity_radial(self, q_abs) -> np.ndarray:
        return self.form_factor_radial(q_abs) * self.area

    def _both(self, q):
        """(``⟨|Â|²⟩``, ``⟨Â⟩``) at q (..., 2) in one pass where possible."""
        a = self.amplitude(q)
        return (np.abs(a) ** 2 if self._deterministic else self._intensity(q)), a

    def _both_radial(self, q_abs):
        """(``⟨|Â|²⟩``, ``⟨Â⟩``) at ``|q|`` (isotropic shapes)."""
        a = self.amplitude_radial(q_abs)
        return (np.abs(a) ** 2 if self._deterministic else self._intensity_radial(q_abs)), a

    def _blurred_overlap(self, w: float) -> float:
        """``⟨∫ (A * G_w)²⟩`` [µm²] for a normalised Gaussian ``G_w`` of std ``w`` [µm]."""
        return self._overlap_sum(np.array([float(w)]), np.ones(1))

    def _overlap_sum(self, widths, coeffs) -> float:
        """``Σ_k c_k ⟨∫ (A * G_{v_k})²⟩`` [µm²] for widths ``v_k`` >= 0 [µm].

        Subclasses with a closed form override this; the default evaluates
        Parseval, ``(2π)⁻² ∫ ⟨|Â|²⟩ Σ_k c_k e^{-q² v_k²} d²q``, in polar
        coordinates (angle average by :class:`RandomOrientation`, composite
        8-point Gauss–Legendre in |q|) up to ``q R = 200`` and Porod's law
        ``⟨|Â|²⟩_θ ≈ c/q³`` (c fitted on the last quarter of the range) beyond.
        """
        widths = np.asarray(widths, dtype=np.float64).ravel()
        coeffs = np.asarray(coeffs, dtype=np.float64).ravel()
        zero = widths <= 0.0
        total = float(np.sum(coeffs[zero])) * self.self_overlap * self.area
        widths, coeffs = widths[~zero], coeffs[~zero]
        if not len(widths):
            return total
        R = self._support
        q_end = 8.0 / float(widths.min())
        Q = min(q_end, 200.0 / R)
        n_pan = max(32, int(math.ceil(Q * R)))
        x, wt = _gauss_legendre(8)
        lo = np.linspace(0.0, Q, n_pan + 1)
        h = np.diff(lo)
        qs = (lo[:-1, None] + 0.5 * h[:, None] * (x[None, :] + 1.0)).ravel()
        ws = (0.5 * h[:, None] * wt[None, :]).ravel()
        if self.isotropic:
            inten = self._intensity_radial(qs)
        else:
            inten = RandomOrientation(self)._intensity_radial(qs)
        g = np.exp(-(qs[:, None] * widths[None, :]) ** 2) @ coeffs
        total += float(np.sum(ws * qs * inten * g)) / _TWO_PI
        if q_end > Q:
            sel = qs > 0.75 * Q
            c = float(np.sum(ws[sel] * inten[sel] * qs[sel] ** 3) / np.sum(ws[sel]))
            tail = (np.exp(-(widths * Q) ** 2) / Q
                    - widths * math.sqrt(math.pi) * special.erfc(widths * Q)) @ coeffs
            total += c / _TWO_PI * float(tail)
        return total


_GL_CACHE: dict = {}


def _gauss_legendre(n: int):
    """Cached Gauss–Legendre nodes and weights on [-1, 1]."""
    if n not in _GL_CACHE:
        _GL_CACHE[n] = special.roots_legendre(n)
    return _GL_CACHE[n]


def _keyable(v):
    if isinstance(v, Shape):
        return v.key()
    if isinstance(v, np.ndarray):
        import hashlib
        a = np.ascontiguousarray(v)
        h = hashlib.sha256(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
        return "sha256:" + h.hexdigest()
    if isinstance(v, (list, tuple)):
        return [_keyable(x) for x in v]
    if isinstance(v, (np.floating, np.integer, np.bool_)):
        return v.item()
    return v


# --------------------------------------------------------------------------
# analytic shapes
# --------------------------------------------------------------------------
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

    @property
    def exclusion_diameter(self) -> float:
        return 2.0 * self.radius

    @staticmethod
    def airy(u) -> np.ndarray:
        """``2 J1(u)/u`` with its limit 1 at u = 0."""
        u = np.asarray(u, dtype=np.float64)
        out = np.ones_like(u)
        nz = np.abs(u) > 1e-8
        out[nz] = 2.0 * special.j1(u[nz]) / u[nz]
        return out

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
    """An elliptical aperture or particle.

    With ``q'`` the wave vector in the ellipse's frame (rotated by ``angle``),
    ``Â(q) = π a b · 2 J1(v)/v``, ``v = √((a q'_x)² + (b q'_y)²)``: the Airy
    pattern with anisotropically scaled q (the ellipse is an affine image of
    the unit disk).

    Parameters
    ----------
    semi_axis_x, semi_axis_y : float
        Semi-axes a, b > 0 [µm] along the ellipse's own x and y axes.
    angle : float, default 0
        Rotation of the ellipse's x axis from the layer's x axis [rad].

    ``length_scale = max(a, b)`` (circumradius), ``exclusion_diameter = 2 max(a, b)``.
    Isotropic only when a == b.

    References
    ----------
    Born & Wolf, *Principles of Optics*, §8.5.2; Goodman, *Introduction to
    Fourier Optics*, §2.1 (similarity theorem).
    """

    _symmetry = 2

    def __init__(self, semi_axis_x: float, semi_axis_y: float, angle: float = 0.0):
        self.semi_axis_x = check_positive("semi_axis_x", semi_axis_x, "µm")
        self.semi_axis_y = check_positive("semi_axis_y", semi_axis_y, "µm")
        self.angle = _check_finite("angle", angle, "rad")

    def __repr__(self):
        return (f"Ellipse(semi_axis_x={self.semi_axis_x:g}, semi_axis_y={self.semi_axis_y:g}, "
                f"angle={self.angle:g})")

    @property
    def isotropic(self) -> bool:
        return self.semi_axis_x == self.semi_axis_y

    @property
    def area(self) -> float:
        return np.pi * self.semi_axis_x * self.semi_axis_y

    @property
    def length_scale(self) -> float:
        return max(self.semi_axis_x, self.semi_axis_y)

    def amplitude(self, q) -> np.ndarray:
        q = _q_array(q)
        qx, qy = _rotate(q, self.angle)
        v = np.hypot(self.semi_axis_x * qx, self.semi_axis_y * qy)
        return (self.area * Circle.airy(v)).astype(np.complex128)

    def form_factor(self, q) -> np.ndarray:
        q = _q_array(q)
        qx, qy = _rotate(q, self.angle)
        v = np.hypot(self.semi_axis_x * qx, self.semi_axis_y * qy)
        return self.area * Circle.airy(v) ** 2


class Rectangle(Shape):
    """A rectangular aperture or particle.

    ``Â(q) = W H · sinc(q'_x W/2) · sinc(q'_y H/2)`` with ``sinc(x) = sin(x)/x``
    and ``q'`` the wave vector in the rectangle's frame (rotated by ``angle``).

    Parameters
    ----------
    width, height : float
        Side lengths W, H > 0 [µm] along the rectangle's own x and y axes.
    angle : float, default 0
        Rotation of the rectangle's x axis from the layer's x axis [rad].

    ``length_scale = √(W² + H²)/2`` (circumradius, half the diagonal).

    References
    ----------
    Born & Wolf, *Principles of Optics*, §8.5.1.
    """

    _symmetry = 2

    def __init__(self, width: float, height: float, angle: float = 0.0):
        self.width = check_positive("width", width, "µm")
        self.height = check_positive("height", height, "µm")
        self.angle = _check_finite("angle", angle, "rad")

    def __repr__(self):
        return f"Rectangle(width={self.width:g}, height={self.height:g}, angle={self.angle:g})"

    @property
    def area(self) -> float:
        return self.width * self.height

    @property
    def length_scale(self) -> float:
        return 0.5 * math.hypot(self.width, self.height)

    def amplitude(self, q) -> np.ndarray:
        q = _q_array(q)
        qx, qy = _rotate(q, self.angle)
        a = self.area * _sinc(0.5 * qx * self.width) * _sinc(0.5 * qy * self.height)
        return a.astype(np.complex128)

    def form_factor(self, q) -> np.ndarray:
        q = _q_array(q)
        qx, qy = _rotate(q, self.angle)
        return self.area * (_sinc(0.5 * qx * self.width) * _sinc(0.5 * qy * self.height)) ** 2

    def _overlap_sum(self, widths, coeffs) -> float:
        # separable: ∫(box_L * g_w)² dx = ∫ (L - |r|)_+ g_{√2 w}(r) dr
        s = math.sqrt(2.0) * np.asarray(widths, dtype=np.float64).ravel()
        c = np.asarray(coeffs, dtype=np.float64).ravel()
        pos = s > 0
        phi0 = 1.0 / math.sqrt(2 * math.pi)

        def one(L):
            t = L / s[pos]
            return 2.0 * (L * (special.ndtr(t) - 0.5)
                          - s[pos] * phi0 * (1.0 - np.exp(-0.5 * t * t)))
        blurred = np.sum(c[pos] * one(self.width) * one(self.height))
        return float(np.sum(c[~pos]) * self.area + blurred)


class Square(Rectangle):
    """A square aperture or particle of side ``side`` [µm], rotated by ``angle`` [rad].

    ``Â(q) = s² sinc(q'_x s/2) sinc(q'_y s/2)`` (see :class:`Rectangle`);
    ``length_scale = s/√2``.
    """

    _symmetry = 4

    def __init__(self, side: float, angle: float = 0.0):
        side = check_positive("side", side, "µm")
        super().__init__(side, side, angle)

    def __repr__(self):
        return f"Square(side={self.width:g}, angle={self.angle:g})"

    def key(self) -> dict:
        return {"type": "Square", "side": self.width, "angle": self.angle}


# --------------------------------------------------------------------------
# polygons
# --------------------------------------------------------------------------
def _orient(ax, ay, bx, by, cx, cy):
    return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)


def _check_simple(v: np.ndarray) -> None:
    """Raise CoronaError if the closed polygon ``v`` (n, 2) self-intersects.

    Edges are sorted by their smallest x; only pairs whose x and y extents
    overlap get the exact orientation test (vectorised, in bounded chunks).
    """
    n = len(v)
    a = v
    b = np.roll(v, -1, axis=0)
    scale = float(np.max(np.abs(v))) or 1.0
    eps = 1e-12 * scale**2
    e = b - a
    # adjacent edges folding back onto each other
    nxt = np.roll(e, -1, axis=0)
    cr = e[:, 0] * nxt[:, 1] - e[:, 1] * nxt[:, 0]
    dt = e[:, 0] * nxt[:, 0] + e[:, 1] * nxt[:, 1]
    bad = (np.abs(cr) <= eps) & (dt < 0)
    if np.any(bad):
        i = int(np.argmax(bad))
        raise CoronaError(f"vertices: polygon folds back on itself at vertex {(i + 1) % n}; "
                          "expected a simple polygon")
    if n <= 3:
        return
    tol = 1e-12 * scale
    xlo = np.minimum(a[:, 0], b[:, 0]) - tol
    xhi = np.maximum(a[:, 0], b[:, 0]) + tol
    ylo = np.minimum(a[:, 1], b[:, 1]) - tol
    yhi = np.maximum(a[:, 1], b[:, 1]) + tol
    order = np.argsort(xlo, kind="stable")
    xs = xlo[order]
    hi = np.searchsorted(xs, xhi[order], side="right")
    counts = np.maximum(hi - np.arange(n) - 1, 0)
    budget = 4_000_000
    start = 0
    while start < n:
        stop = start + 1
        acc = counts[start]
        while stop < n and acc + counts[stop] <= budget:
            acc += counts[stop]
            stop += 1
        c = counts[start:stop]
        tot = int(c.sum())
        start_i = start
        start = stop
        if tot == 0:
            continue
        pos = np.repeat(np.arange(start_i, stop), c)
        first = np.repeat(np.cumsum(c) - c, c)
        pj = pos + 1 + (np.arange(tot) - first)
        i = order[pos]
        j = order[pj]
        keep = (ylo[i] <= yhi[j]) & (ylo[j] <= yhi[i])
        d = (j - i) % n
        keep &= (d != 1) & (d != n - 1)
        i, j = i[keep], j[keep]
        if not len(i):
            continue
        ax, ay, bx, by = a[i, 0], a[i, 1], b[i, 0], b[i, 1]
        cx, cy, dx, dy = a[j, 0], a[j, 1], b[j, 0], b[j, 1]
        o1 = _orient(ax, ay, bx, by, cx, cy)
        o2 = _orient(ax, ay, bx, by, dx, dy)
        o3 = _orient(cx, cy, dx, dy, ax, ay)
        o4 = _orient(cx, cy, dx, dy, bx, by)
        z1, z2, z3, z4 = (np.abs(o) <= eps for o in (o1, o2, o3, o4))
        s1 = np.where(z1, 0, np.sign(o1))
        s2 = np.where(z2, 0, np.sign(o2))
        s3 = np.where(z3, 0, np.sign(o3))
        s4 = np.where(z4, 0, np.sign(o4))
        cross = (s1 * s2 <= 0) & (s3 * s4 <= 0)
        colin = z1 & z2 & z3 & z4
        if np.any(colin):
            # collinear segments intersect only if their projections overlap
            ex, ey = bx - ax, by - ay
            L2 = ex * ex + ey * ey
            t1 = ((cx - ax) * ex + (cy - ay) * ey) / L2
            t2 = ((dx - ax) * ex + (dy - ay) * ey) / L2
            overlap = (np.maximum(t1, t2) >= 0) & (np.minimum(t1, t2) <= 1)
            cross = np.where(colin, overlap, cross)
        if np.any(cross):
            k = int(np.argmax(cross))
            e1, e2 = sorted((int(i[k]), int(j[k])))
            raise CoronaError(f"vertices: polygon is not simple (edges {e1} and {e2} "
                              "intersect); expected a simple polygon")


class Polygon(Shape):
    """An arbitrary simple polygon (convex or not), transmitting inside.

    Closed-form Fraunhofer transform by the divergence theorem
    (``e^{-iq·x} = ∇·(i q e^{-iq·x}/|q|²)``): with counter-clockwise edges
    ``e_k = v_{k+1} - v_k`` and midpoints ``m_k``,

        ``Â(q) = (i/|q|²) Σ_k (q × e_k) · sinc(q·e_k/2) · e^{-i q·m_k}``,

    ``q × e = q_x e_y - q_y e_x``, ``sinc(x) = sin(x)/x`` (finite for q
    parallel to an edge).  For ``|q| R < 0.02`` (R the circumradius), where
    the sum cancels to O(q²), the Taylor series ``Σ_n (-i)^n/n! ∫(q·x)^n dx``
    to order 7 is used instead, with the moments of the triangle fan from the
    centroid in closed form (``∫_T (q·x)^n = 2|T| n!/(n+2)! Σ_{i+j=n} α^i β^j``
    for a triangle (0, a, b), α = q·a, β = q·b).  Both branches agree to
    ~1e-13 at the switch, so the result is continuous and never NaN.

    Parameters
    ----------
    vertices : array_like, shape (n, 2)
        Vertices [µm] in either winding; a repeated closing vertex and
        repeated consecutive vertices are dropped.  The polygon is re-centred
        on its area centroid and stored counter-clockwise as ``vertices``.

    ``length_scale`` is the circumradius (largest vertex distance from the
    centroid); ``exclusion_diameter`` twice that.

    References
    ----------
    S.-W. Lee, R. Mittra, "Fourier transform of a polygonal shape function and
    its application in electromagnetics", IEEE Trans. Antennas Propag. 31(1),
    99–103 (1983); J. Wuttke, "Numerically stable form factor of any polygon
    and polyhedron", J. Appl. Cryst. 54, 580–587 (2021).
    """

    _TAYLOR_U = 0.02
    _TAYLOR_ORDER = 7
    _CHUNK = 4_000_000  # q points × edges per vectorised block

    def __init__(self, vertices):
        v = self._validated_vertices(vertices)
        _check_simple(v)
        self._set_vertices(v)

    # --- construction helpers ----------------------------------------------
    @staticmethod
    def _validated_vertices(vertices) -> np.ndarray:
        try:
            v = np.array(vertices, dtype=np.float64)
        except (TypeError, ValueError):
            raise CoronaError("vertices must be a numeric array of shape (n, 2) [µm]") from None
        if v.ndim != 2 or v.shape[1] != 2:
            raise CoronaError(f"vertices must have shape (n, 2) [µm], got shape {v.shape}")
        if not np.all(np.isfinite(v)):
            raise CoronaError("vertices contain non-finite values; expected finite µm")
        # drop consecutive duplicates (including the closing vertex)
        if len(v) > 1:
            keep = np.any(v != np.roll(v, -1, axis=0), axis=1)
            v = v[keep]
        if len(v) < 3:
            raise CoronaError("vertices: a polygon needs at least 3 distinct vertices, "
                              f"got {len(v)}")
        return v

    def _set_vertices(self, v: np.ndarray) -> None:
        w = np.roll(v, -1, axis=0)
        cr = v[:, 0] * w[:, 1] - v[:, 1] * w[:, 0]
        A2 = float(np.sum(cr))
        scale = float(np.max(np.ptp(v, axis=0)))
        if not abs(A2) > 1e-12 * scale**2:
            raise CoronaError("vertices: the polygon has zero area; expected a simple polygon "
                              "with area > 0")
        c = np.sum((v + w) * cr[:, None], axis=0) / (3.0 * A2)
        if A2 < 0:
            v = v[::-1]
        v = np.ascontiguousarray(v - c)
        v.setflags(write=False)
        self.vertices = v
        w = np.roll(v, -1, axis=0)
        self._edges = w - v
        self._mids = 0.5 * (w + v)
        self._cross = v[:, 0] * w[:, 1] - v[:, 1] * w[:, 0]
        self._area = 0.5 * float(np.sum(self._cross))
        self._radius = float(np.max(np.hypot(v[:, 0], v[:, 1])))

    def __repr__(self):
        return f"Polygon(n_vertices={len(self.vertices)}, area={self.area:g})"

    @property
    def area(self) -> float:
        return self._area

    @property
    def length_scale(self) -> float:
        return self._radius

    @property
    def perimeter(self) -> float:
        """Perimeter [µm]."""
        return float(np.sum(np.hypot(self._edges[:, 0], self._edges[:, 1])))

    def amplitude(self, q) -> np.ndarray:
        q = _q_array(q)
        shape = q.shape[:-1]
        qf = q.reshape(-1, 2)
        M = qf.shape[0]
        out = np.empty(M, dtype=np.complex128)
        qq = qf[:, 0] ** 2 + qf[:, 1] ** 2
        small = qq * self._radius**2 < self._TAYLOR_U**2
        big = ~small
        if np.any(big):
            out[big] = self._amplitude_edges(qf[big], qq[big])
        if np.any(small):
            out[small] = self._amplitude_taylor(qf[small])
        return out.reshape(shape)

    def _amplitude_edges(self, q, qq):
        ex, ey = self._edges[:, 0], self._edges[:, 1]
        mx, my = self._mids[:, 0], self._mids[:, 1]
        N = len(ex)
        out = np.empty(len(q), dtype=np.complex128)
        step = max(1, self._CHUNK // N)
        for s in range(0, len(q), step):
            qx = q[s:s + step, 0:1]
            qy = q[s:s + step, 1:2]
            w = (qx * ey - qy * ex) * np.sinc((qx * ex + qy * ey) / _TWO_PI)
            ph = qx * mx + qy * my
            re = np.sum(w * np.cos(ph), axis=1)
            im = -np.sum(w * np.sin(ph), axis=1)
            # i (re + i im) / |q|²
            out[s:s + step] = (-im + 1j * re) / qq[s:s + step]
        return out

    def _amplitude_taylor(self, q):
        step = max(1, self._CHUNK // len(self._cross))
        if len(q) > step:
            return np.concatenate([self._amplitude_taylor(q[s:s + step])
                                   for s in range(0, len(q), step)])
        v = self.vertices
        w = np.roll(v, -1, axis=0)
        alpha = q[:, 0:1] * v[:, 0] + q[:, 1:2] * v[:, 1]   # (M, N)
        beta = q[:, 0:1] * w[:, 0] + q[:, 1:2] * w[:, 1]
        c = self._cross
        h = np.ones_like(alpha)
        apow = np.ones_like(alpha)
        total = np.full(len(q), 0.5 * np.sum(c), dtype=np.complex128)
        for n in range(1, self._TAYLOR_ORDER + 1):
            apow = apow * alpha
            h = beta * h + apow                      # Σ_{i+j=n} α^i β^j
            mom = h @ c / math.factorial(n + 2)       # ∫(q·x)^n dx / n!
            total += (-1j) ** n * mom
        return total


class RegularPolygon(Polygon):
    """A regular polygon with ``sides`` vertices on a circle of radius ``radius``.

    Vertices at ``radius · (cos φ_k, sin φ_k)``, ``φ_k = angle + 2πk/sides``
    (``angle = 0`` puts a vertex on the +x axis).  Transform as for
    :class:`Polygon`; area ``(n/2) r² sin(2π/n)``.

    Parameters
    ----------
    sides : int
        Number of sides, 3 … 100000.
    radius : float
        Circumradius r > 0 [µm] (= ``length_scale``).
    angle : float, default 0
        Rotation [rad].
    """

    def __init__(self, sides: int, radius: float, angle: float = 0.0):
        self.sides = _check_int("sides", sides, 3, 100_000)
        self.radius = check_positive("radius", radius, "µm")
        self.angle = _check_finite("angle", angle, "rad")
        phi = self.angle + _TWO_PI * np.arange(self.sides) / self.sides
        v = self.radius * np.stack([np.cos(phi), np.sin(phi)], axis=-1)
        self._set_vertices(v)
        # the centroid is the centre: keep exact values (no round-off shift)
        v.setflags(write=False)
        self.vertices = v
        w = np.roll(v, -1, axis=0)
        self._edges = w - v
        self._mids = 0.5 * (w + v)
        self._cross = v[:, 0] * w[:, 1] - v[:, 1] * w[:, 0]
        self._area = 0.5 * float(np.sum(self._cross))
        self._radius = self.radius
        self._symmetry = self.sides

    def __repr__(self):
        return f"RegularPolygon(sides={self.sides}, radius={self.radius:g}, angle={self.angle:g})"

    def key(self) -> dict:
        return {"type": "RegularPolygon", "sides": self.sides, "radius": self.radius,
                "angle": self.angle}


# --------------------------------------------------------------------------
# image masks
# --------------------------------------------------------------------------
_LUMA = np.array([0.2126, 0.7152, 0.0722])


def _load_image(image) -> tuple[np.ndarray, str | None]:
    """Return a float64 2-D array in [0, 1] and the source path (or None)."""
    source = None
    if isinstance(image, (str, os.PathLike)):
        source = os.fspath(image)
        if not os.path.isfile(source):
            raise CoronaError(f"image={source!r}: no such file")
        if os.path.getsize(source) == 0:
            raise CoronaError(f"image={source!r} is an empty file")
        try:
            import warnings

            import imageio.v3 as iio
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", DeprecationWarning)
                arr = np.asarray(iio.imread(source))
        except Exception as exc:  # noqa: BLE001 - any reader failure is a bad file
            raise CoronaError(f"image={source!r} could not be read as an image ({exc})") from None
        if arr.ndim == 3 and arr.shape[-1] in (1, 2, 3, 4):
            arr = _normalise_levels(arr, source)
            if arr.shape[-1] >= 3:        # RGB(A): Rec. 709 luminance, alpha ignored
                arr = arr[..., :3] @ _LUMA
            else:                         # L or LA
                arr = arr[..., 0]
        elif arr.ndim == 2:
            arr = _normalise_levels(arr, source)
        else:
            raise CoronaError(f"image={source!r} has shape {arr.shape}; expected a single "
                              "2-D grey or RGB(A) image")
    else:
        try:
            arr = np.asarray(image)
        except Exception:  # noqa: BLE001
            raise CoronaError("image must be a 2-D array or a path to an image file") from None
        if arr.dtype == object or not (np.issubdtype(arr.dtype, np.number)
                                       or arr.dtype == np.bool_):
            raise CoronaError(f"image has dtype {arr.dtype}; expected a numeric 2-D array "
                              "with values in [0, 1] or a path to an image file")
        if arr.ndim != 2:
            raise CoronaError(f"image has shape {arr.shape}; expected a 2-D array "
                              "(rows, columns) with values in [0, 1]")
        arr = arr.astype(np.float64)
        if not np.all(np.isfinite(arr)) or (arr.size and (arr.min() < 0.0 or arr.max() > 1.0)):
            raise CoronaError("image values are out of range; expected finite values in [0, 1] "
                              "(1 = transmitting)")
    if arr.size == 0:
        raise CoronaError(f"image has shape {arr.shape}; expected a non-empty 2-D array")
    return np.array(arr, dtype=np.float64, order="C"), source


def _normalise_levels(arr: np.ndarray, source) -> np.ndarray:
    if arr.dtype == np.bool_:
        return arr.astype(np.float64)
    if np.issubdtype(arr.dtype, np.integer):
        out = arr.astype(np.float64) / float(np.iinfo(arr.dtype).max)
    else:
        out = arr.astype(np.float64)
    if out.size and (not np.all(np.isfinite(out)) or out.min() < 0.0 or out.max() > 1.0):
        raise CoronaError(f"image={source!r} has values outside [0, 1] after normalisation")
    return out


class Mask(Shape):
    """A transmission profile given as an image (binary or grey levels).

    The profile is the band-limited (sinc-interpolated) function through the
    pixel values ``a_ij ∈ [0, 1]`` at the pixel centres
    ``x = (j - c_j) p``, ``y = (c_i - i) p`` (row 0 at the top, y up, centred on
    the intensity-weighted centroid ``c``), so

        ``Â(q) = p² Σ_ij a_ij e^{-i q·x_ij}``  for ``|q_x|, |q_y| ≤ π/p``, 0 outside,

    and ``∫ T_a = Σ a² / Σ a`` exactly (1 for binary masks).  Â is computed by
    a zero-padded FFT (``scipy.fft``) of the opening's bounding box: each axis
    of n pixels is padded to ``next_fast_len(max(4n, min(8n, 2048)))``, a
    padding factor between 4 and 8, with the centroid pixel moved to the
    origin so that Â is smooth on the FFT grid; the residual sub-pixel shift is
    applied as an exact phase.  Â at arbitrary q is interpolated with periodic
    cubic splines (real and imaginary parts; the DTFT is periodic), and
    ``form_factor = |Â|²/|A|``, so ``coherent_form_factor == form_factor``
    exactly for this deterministic shape.  Interpolating Â (half the
    bandwidth of ``|Â|²``) is more accurate than interpolating ``|Â|²``.

    Parameters
    ----------
    image : array_like (rows, columns) or str / os.PathLike
        Values in [0, 1], 1 = transmitting; or a path to an image file read
        with ``imageio`` (RGB(A) converted to Rec. 709 luminance, alpha
        ignored; integer levels divided by the dtype's maximum).
    pixel_size : float
        Pixel pitch p > 0 [µm].
    threshold : float in (0, 1), optional
        If given, the image is binarised as ``image >= threshold``.

    ``length_scale`` is the largest distance from the centroid to a
    transmitting pixel centre plus half a pixel diagonal (``p/√2``).

    References
    ----------
    Goodman, *Introduction to Fourier Optics*, §2.4 and §4.2 (sampling and
    FFT evaluation of Fraunhofer patterns).
    """

    def __init__(self, image, pixel_size: float, threshold: float | None = None):
        self.pixel_size = check_positive("pixel_size", pixel_size, "µm")
        if threshold is not None:
            threshold = check_range("threshold", threshold, 0.0, 1.0, lo_open=True, hi_open=True)
        self.threshold = threshold
        img, self._source = _load_image(image)
        if threshold is not None:
            img = (img >= threshold).astype(np.float64)
        total = float(img.sum())
        if not total > 0.0:
            raise CoronaError(("image" if self._source is None else f"image={self._source!r}")
                              + " has no transmitting pixel (all values are 0"
                              + (f" below threshold={threshold:g}" if threshold is not None
                                 else "") + "); expected at least one opening")
        img.setflags(write=False)
        self.image = img
        self._prepare()

    def _prepare(self):
        img, p = self.image, self.pixel_size
        rows = np.nonzero(img.any(axis=1))[0]
        cols = np.nonzero(img.any(axis=0))[0]
        crop = img[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1]
        ny, nx = crop.shape
        total = float(crop.sum())
        ii, jj = np.indices(crop.shape)
        ci = float(np.sum(ii * crop)) / total
        cj = float(np.sum(jj * crop)) / total
        self._area = p * p * total
        self._overlap = float(np.sum(crop * crop)) / total
        nzr = crop > 0
        self._radius = p * float(np.max(np.hypot(ii[nzr] - ci, jj[nzr] - cj))) + p / math.sqrt(2.0)
        i0, j0 = int(round(ci)), int(round(cj))
        self._shift = (ci - i0, cj - j0)
        self._P = tuple(sp_fft.next_fast_len(max(4 * n, min(8 * n, 2048))) for n in (ny, nx))
        self._crop_info = (crop, i0, j0)
        F = self._fft()
        self._coef_re = ndimage.spline_filter(F.real, order=3, mode="grid-wrap")
        self._coef_im = ndimage.spline_filter(F.imag, order=3, mode="grid-wrap")

    def _fft(self) -> np.ndarray:
        crop, i0, j0 = self._crop_info
        Py, Px = self._P
        arr = np.zeros((Py, Px))
        arr[:crop.shape[0], :crop.shape[1]] = crop
        arr = np.roll(arr, (-i0, -j0), axis=(0, 1))
        return sp_fft.fft2(arr, workers=1)

    def __repr__(self):
        ny, nx = self.image.shape
        src = f"{self._source!r}" if self._source else f"<array {ny}x{nx}>"
        th = "" if self.threshold is None else f", threshold={self.threshold:g}"
        return f"Mask({src}, pixel_size={self.pixel_size:g}{th})"

    @property
    def area(self) -> float:
        return self._area

    @property
    def length_scale(self) -> float:
        return self._radius

    @property
    def self_overlap(self) -> float:
        """``Σ a² / Σ a`` (1 for a binary mask)."""
        return self._overlap

    @property
    def band_limit(self) -> float:
        """``π / pixel_size`` [rad/µm]: Â is 0 for ``|q_x|`` or ``|q_y|`` beyond it."""
        return np.pi / self.pixel_size

    def amplitude(self, q) -> np.ndarray:
        q = _q_array(q)
        shape = q.shape[:-1]
        qf = q.reshape(-1, 2)
        p = self.pixel_size
        Py, Px = self._P
        out = np.zeros(qf.shape[0], dtype=np.complex128)
        inb = (np.abs(qf[:, 0]) * p <= np.pi) & (np.abs(qf[:, 1]) * p <= np.pi)
        if np.any(inb):
            qx, qy = qf[inb, 0], qf[inb, 1]
            coords = np.stack([-qy * p * Py / _TWO_PI, qx * p * Px / _TWO_PI])
            re = ndimage.map_coordinates(self._coef_re, coords, order=3, mode="grid-wrap",
                                         prefilter=False)
            im = ndimage.map_coordinates(self._coef_im, coords, order=3, mode="grid-wrap",
                                         prefilter=False)
            di, dj = self._shift
            out[inb] = p * p * (re + 1j * im) * np.exp(1j * p * (qx * dj - qy * di))
        return out.reshape(shape)

    def _overlap_sum(self, widths, coeffs) -> float:
        # Parseval on the FFT grid: p² Σ |F|² e^{-q² w²} / (P_x P_y)
        p = self.pixel_size
        Py, Px = self._P
        power = None
        total = 0.0
        for w, c in zip(np.ravel(widths), np.ravel(coeffs)):
            if w <= 0.0:
                total += c * self._overlap * self._area
                continue
            if power is None:
                power = np.abs(self._fft()) ** 2
                qy2 = (_TWO_PI * sp_fft.fftfreq(Py, d=p)) ** 2
                qx2 = (_TWO_PI * sp_fft.fftfreq(Px, d=p)) ** 2
            g = np.exp(-qy2 * w * w)[:, None] * np.exp(-qx2 * w * w)[None, :]
            total += c * float(p * p * np.sum(power * g) / (Px * Py))
        return total


# --------------------------------------------------------------------------
# modifiers and ensembles
# --------------------------------------------------------------------------
class SoftEdge(Shape):
    """A shape whose profile is blurred by a normalised Gaussian.

    ``A = B * G_w`` with ``G_w(x) = exp(-|x|²/2w²)/(2πw²)``, so values stay in
    [0, 1], ``∫A = ∫B`` and

        ``Â(q) = B̂(q) · exp(-|q|² w² / 2)``,  ``form_factor = F_B · exp(-|q|² w²)``.

    The lobe integrates to ``self_overlap = ∫A²/∫A < 1`` (not 1): the soft
    edge removes energy from the diffraction.  ``self_overlap`` is evaluated
    in closed form for circles (covariogram integral) and rectangles (erf),
    on the FFT grid for masks, and by Parseval on the form factor otherwise.
    For small w, ``self_overlap ≈ 1 - w P / (√π |B|)`` (P the perimeter).

    Parameters
    ----------
    shape : Shape
        The sharp profile B (any shape, also random ones).
    edge_width : float
        Gaussian standard deviation w >= 0 [µm].

    ``length_scale`` and ``exclusion_diameter`` are those of ``shape`` (the
    blur tail extends a few w beyond).

    References
    ----------
    W. Ruland, "Small-angle scattering of two-phase systems: determination
    and significance of systematic deviations from Porod's law",
    J. Appl. Cryst. 4, 70–73 (1971) (Gaussian-smoothed interfaces).
    """

    def __init__(self, shape: Shape, edge_width: float):
        self.shape = _check_shape("shape", shape)
        self.edge_width = check_range("edge_width", edge_width, 0.0, math.inf, unit="µm")
        self._so = None

    def __repr__(self):
        return f"SoftEdge({self.shape!r}, edge_width={self.edge_width:g})"

    @property
    def isotropic(self) -> bool:
        return self.shape.isotropic

    @property
    def _symmetry(self):
        return self.shape._symmetry

    @property
    def _deterministic(self):
        return self.shape._deterministic

    @property
    def _support(self):
        return self.shape._support

    @property
    def area(self) -> float:
        return self.shape.area

    @property
    def length_scale(self) -> float:
        return self.shape.length_scale

    @property
    def exclusion_diameter(self) -> float:
        return self.shape.exclusion_diameter

    @property
    def self_overlap(self) -> float:
        if self._so is None:
            self._so = self.shape._blurred_overlap(self.edge_width) / self.shape.area
        return self._so

    def _overlap_sum(self, widths, coeffs) -> float:
        return self.shape._overlap_sum(np.hypot(self.edge_width, np.asarray(widths, float)), coeffs)

    def _gauss(self, q2):
        return np.exp(-0.5 * q2 * self.edge_width**2)

    def _both(self, q):
        q = _q_array(q)
        g = self._gauss(q[..., 0] ** 2 + q[..., 1] ** 2)
        i, a = self.shape._both(q)
        return i * g * g, a * g

    def _both_radial(self, q_abs):
        q_abs = _radial_array(q_abs)
        g = self._gauss(q_abs**2)
        i, a = self.shape._both_radial(q_abs)
        return i * g * g, a * g

    def amplitude(self, q) -> np.ndarray:
        q = _q_array(q)
        return self.shape.amplitude(q) * self._gauss(q[..., 0] ** 2 + q[..., 1] ** 2)

    def form_factor(self, q) -> np.ndarray:
        q = _q_array(q)
        return self.shape.form_factor(q) * self._gauss(q[..., 0] ** 2 + q[..., 1] ** 2) ** 2

    def coherent_form_factor(self, q) -> np.ndarray:
        q = _q_array(q)
        return (self.shape.coherent_form_factor(q)
                * self._gauss(q[..., 0] ** 2 + q[..., 1] ** 2) ** 2)

    def amplitude_radial(self, q_abs) -> np.ndarray:
        q_abs = _radial_array(q_abs)
        return self.shape.amplitude_radial(q_abs) * self._gauss(q_abs**2)

    def form_factor_radial(self, q_abs) -> np.ndarray:
        q_abs = _radial_array(q_abs)
        return self.shape.form_factor_radial(q_abs) * self._gauss(q_abs**2) ** 2

    def coherent_form_factor_radial(self, q_abs) -> np.ndarray:
        q_abs = _radial_array(q_abs)
        return self.shape.coherent_form_factor_radial(q_abs) * self._gauss(q_abs**2) ** 2


def _groups(levels: np.ndarray):
    """Yield (level, indices) for each distinct value of ``levels``."""
    order = np.argsort(levels, kind="stable")
    lv = levels[order]
    cuts = np.nonzero(np.diff(lv))[0] + 1
    for idx in np.split(order, cuts):
        if len(idx):
            yield int(levels[idx[0]]), idx


class RandomOrientation(Shape):
    """A shape in uniformly random orientation (isotropic).

        ``⟨|Â|²⟩(|q|) = (1/2π) ∫ |Â(R_φ q)|² dφ``,  ``⟨Â⟩(|q|) = (1/2π) ∫ Â(R_φ q) dφ``.

    Both are computed by the trapezoidal rule in φ, which converges
    spectrally for these periodic integrands.  Â(R_φ q) has angular harmonics
    up to order ≈ |q| R (R the circumradius) and |Â|² up to 2|q| R, so
    ``N = ⌈(2.2 |q| R + 24)/m⌉`` (rounded up to a multiple of 8) angles over one
    symmetry period ``2π/m`` are used, m the order of the shape's rotational
    symmetry (4 for a square, n for a regular n-gon, 2 for rectangles and
    ellipses, 1 otherwise).  For size distributions R is the radius of the
    1 - 1e-10 quantile of the ``s⁴``-weighted sizes.

    Parameters
    ----------
    shape : Shape
        The profile to rotate (an isotropic shape is returned unchanged in
        value).

    ``area``, ``length_scale``, ``exclusion_diameter`` and ``self_overlap``
    are those of ``shape``.

    References
    ----------
    J. S. Pedersen, "Analysis of small-angle scattering data from colloids and
    polymer solutions: modeling and least-squares fitting",
    Adv. Colloid Interface Sci. 70, 171–210 (1997).
    """

    isotropic = True
    _symmetry = 0
    _deterministic = False
    _MAX_POINTS = 2_000_000

    def __init__(self, shape: Shape):
        self.shape = _check_shape("shape", shape)

    def __repr__(self):
        return f"RandomOrientation({self.shape!r})"

    @property
    def area(self) -> float:
        return self.shape.area

    @property
    def length_scale(self) -> float:
        return self.shape.length_scale

    @property
    def exclusion_diameter(self) -> float:
        return self.shape.exclusion_diameter

    @property
    def self_overlap(self) -> float:
        return self.shape.self_overlap

    @property
    def _support(self):
        return self.shape._support

    def _overlap_sum(self, widths, coeffs) -> float:
        return self.shape._overlap_sum(widths, coeffs)

    def _average(self, q_abs):
        """(⟨|Â|²⟩, ⟨Â⟩) at ``|q|`` (any shape)."""
        base = self.shape
        qa = np.abs(_radial_array(q_abs))
        if base.isotropic:
            return base._both_radial(qa)
        flat = qa.ravel()
        inten = np.empty(flat.shape)
        amp = np.empty(flat.shape, dtype=np.complex128)
        m = max(int(base._symmetry), 1)
        R = base._support
        need = np.ceil((2.2 * flat * R + 24.0) / m / 8.0).astype(np.int64) * 8
        for N, idx in _groups(need):
            phi = (_TWO_PI / m) * np.arange(N) / N
            rot = np.stack([np.cos(phi), np.sin(phi)], axis=-1)          # (N, 2)
            step = max(1, self._MAX_POINTS // N)
            for s in range(0, len(idx), step):
                sub = idx[s:s + step]
                pts = flat[sub, None, None] * rot[None, :, :]           # (k, N, 2)
                I, a = base._both(pts)
                inten[sub] = I.mean(axis=1)
                amp[sub] = a.mean(axis=1)
        return inten.reshape(qa.shape), amp.reshape(qa.shape)

    def _intensity_radial(self, q_abs):
        base = self.shape
        if base.isotropic:
            return base._intensity_radial(q_abs)
        return self._average(q_abs)[0]

    def _intensity(self, q):
        q = _q_array(q)
        return self._intensity_radial(np.hypot(q[..., 0], q[..., 1]))

    def _both_radial(self, q_abs):
        return self._average(q_abs)

    def _both(self, q):
        q = _q_array(q)
        return self._average(np.hypot(q[..., 0], q[..., 1]))

    def amplitude_radial(self, q_abs) -> np.ndarray:
        if self.shape.isotropic:
            return self.shape.amplitude_radial(q_abs)
        return self._average(q_abs)[1]

    def form_factor_radial(self, q_abs) -> np.ndarray:
        return self._intensity_radial(q_abs) / self.area

    def coherent_form_factor_radial(self, q_abs) -> np.ndarray:
        return np.abs(self.amplitude_radial(q_abs)) ** 2 / self.area

    def amplitude(self, q) -> np.ndarray:
        q = _q_array(q)
        return self.amplitude_radial(np.hypot(q[..., 0], q[..., 1]))

    def form_factor(self, q) -> np.ndarray:
        q = _q_array(q)
        return self.form_factor_radial(np.hypot(q[..., 0], q[..., 1]))

    def coherent_form_factor(self, q) -> np.ndarray:
        q = _q_array(q)
        return self.coherent_form_factor_radial(np.hypot(q[..., 0], q[..., 1]))


class SizeDistribution(Shape):
    """A shape with a random scale factor s (number-weighted, mean 1, relative std ``spread``).

    The scaled profile ``A_s(x) = A(x/s)`` has ``Â_s(q) = s² Â(s q)`` and
    ``|A_s| = s² |A|``, so

        ``⟨|Â|²⟩ = ∫ p(s) s⁴ |Â(s q)|² ds``,  ``⟨Â⟩ = ∫ p(s) s² Â(s q) ds``,
        ``⟨|A|⟩ = |A| ⟨s²⟩``.

    Distributions of s (mean 1, std ``spread``):

    * ``"lognormal"``: ``ln s ~ N(μ, σ²)``, ``σ² = ln(1 + spread²)``, ``μ = -σ²/2``;
    * ``"schulz"`` (gamma): ``p(s) = k^k s^{k-1} e^{-ks} / Γ(k)``, ``k = 1/spread²``.

    Quadrature: the trapezoidal rule in ``y = ln s`` over the range holding
    all but 1e-16 of the number- and ``s⁴``-weighted distributions, which is
    spectrally accurate for these smooth, rapidly decaying integrands (it is
    the Gauss rule's equal for Gaussian weights and, unlike a fixed Gauss
    rule, can be refined).  The step is smooth in y and resolves both the
    distribution (``≤ σ_y/2.5``, σ_y the std of ln s) and the oscillation of
    ``Â(s q)`` in s (``≤ π/(2.2 q R s)`` up to the 1 - 1e-7 quantile of ``s p(s)``,
    R = ``length_scale``), so the number of nodes grows with ``q R · spread``
    above the minimum ``n_nodes``.

    Parameters
    ----------
    shape : Shape
        The mean shape (s = 1).
    spread : float
        Relative standard deviation of s, in [0, 1]; 0 gives ``shape``.
    distribution : {"lognormal", "schulz"}
    n_nodes : int, default 64
        Minimum number of quadrature nodes (8 … 100000).

    ``length_scale``, ``exclusion_diameter`` and ``self_overlap`` are those of
    the mean shape (s = 1): the tables stay in u = q R of the mean particle,
    and a hard-core process built on ``exclusion_diameter`` lets the largest
    particles overlap slightly — pass an explicit diameter to the process if
    that matters.

    References
    ----------
    M. Kotlarchyk, S.-H. Chen, "Analysis of small angle neutron scattering
    spectra from polydisperse interacting colloids", J. Chem. Phys. 79,
    2461–2469 (1983); Pedersen, Adv. Colloid Interface Sci. 70, 171 (1997).
    """

    _deterministic = False
    _MAX_POINTS = 4_000_000
    _RES_SIGMA = 2.5   # y step <= σ_y / _RES_SIGMA
    _RES_OSC = 2.2     # y step <= π / (_RES_OSC q R s)

    def __init__(self, shape: Shape, spread: float, distribution: str = "lognormal",
                 n_nodes: int = 64):
        self.shape = _check_shape("shape", shape)
        self.spread = check_range("spread", spread, 0.0, 1.0)
        self.distribution = check_choice("distribution", distribution, ("lognormal", "schulz"))
        self.n_nodes = _check_int("n_nodes", n_nodes, 8, 100_000)
        self._nodes_cache = {}
        self._setup()

    def __repr__(self):
        return (f"SizeDistribution({self.shape!r}, spread={self.spread:g}, "
                f"distribution={self.distribution!r}, n_nodes={self.n_nodes})")

    # --- distribution ------------------------------------------------------
    def _setup(self):
        sp = self.spread
        if sp == 0.0:
            self._m2 = self._m4 = 1.0
            self._s_big = 1.0
            return
        if self.distribution == "lognormal":
            s2 = math.log1p(sp * sp)
            sig = math.sqrt(s2)
            mu = -0.5 * s2
            self._sig_y = sig
            z16 = 8.3  # Φ(-8.3) ≈ 5e-17
            self._y_lo = mu - z16 * sig
            self._y_hi = mu + 4 * s2 + z16 * sig
            self._s_top = math.exp(mu + s2 + 5.3 * sig)        # 1 - 1e-7 of s p(s)
            self._s_big = math.exp(mu + 4 * s2 + 6.4 * sig)    # 1 - 1e-10 of s⁴ p(s)
            self._m2 = math.exp(2 * mu + 2 * s2)
            self._m4 = math.exp(4 * mu + 8 * s2)
            self._logpdf = lambda y: (-0.5 * ((y - mu) / sig) ** 2
                                      - math.log(sig * math.sqrt(_TWO_PI)))
        else:
            from scipy import stats
            k = 1.0 / (sp * sp)
            self._sig_y = math.sqrt(float(special.polygamma(1, k)))
            g = stats.gamma(k, scale=1.0 / k)
            g4 = stats.gamma(k + 4.0, scale=1.0 / k)
            g1 = stats.gamma(k + 1.0, scale=1.0 / k)
            self._y_lo = math.log(g.ppf(1e-17))
            self._y_hi = math.log(g4.isf(1e-17))
            self._s_top = float(g1.isf(1e-7))
            self._s_big = float(g4.isf(1e-10))
            self._m2 = (k + 1.0) / k
            self._m4 = (k + 1.0) * (k + 2.0) * (k + 3.0) / k**3
            lk = k * math.log(k) - math.lgamma(k)
            self._logpdf = lambda y: lk + k * y - k * np.exp(y)

    def _nodes(self, q_max: float):
        """Nodes s_j and weights (Σ = 1) resolving ``Â(s q)`` for ``|q| <= q_max``."""
        if self.spread == 0.0:
            return np.ones(1), np.ones(1)
        h1 = self._sig_y / self._RES_SIGMA
        c = self._RES_OSC * q_max * self.shape._support / np.pi
        st = self._s_top
        # smooth map t(y) with dt/dy = 1/h1 + c·e^y s_top/(e^y + s_top); nodes at unit t steps
        def t_of(y):
            return y / h1 + c * st * np.logaddexp(y, math.log(st))
        t_lo, t_hi = float(t_of(self._y_lo)), float(t_of(self._y_hi))
        n = max(self.n_nodes, int(math.ceil(t_hi - t_lo)) + 1)
        key = n
        if key in self._nodes_cache:
            return self._nodes_cache[key]
        t = np.linspace(t_lo, t_hi, n)
        dt = (t_hi - t_lo) / (n - 1)
        ygrid = np.linspace(self._y_lo, self._y_hi, 4 * n + 64)
        y = np.interp(t, t_of(ygrid), ygrid)
        for _ in range(6):   # Newton polish of t(y) = t
            es = np.exp(y)
            dty = 1.0 / h1 + c * es * st / (es + st)
            y = np.clip(y - (t_of(y) - t) / dty, self._y_lo - 1.0, self._y_hi + 1.0)
        es = np.exp(y)
        dty = 1.0 / h1 + c * es * st / (es + st)
        w = np.exp(self._logpdf(y)) * dt / dty
        w[0] *= 0.5
        w[-1] *= 0.5
        keep = w > 1e-18 * w.max()
        s, w = es[keep], w[keep]
        w = w / w.sum()
        if len(self._nodes_cache) > 64:
            self._nodes_cache.clear()
        self._nodes_cache[key] = (s, w)
        return s, w

    def _levels(self, qa: np.ndarray) -> np.ndarray:
        """Group |q| into levels of node count (geometric steps of 1.25 in q R)."""
        u = qa * self.shape.length_scale
        return np.where(u < 1.0, 0, np.ceil(np.log(np.maximum(u, 1.0)) / math.log(1.25)) + 1
                        ).astype(np.int64)

    def _level_qmax(self, level: int) -> float:
        if level == 0:
            return 1.0 / self.shape.length_scale
        return 1.25 ** (level - 1) / self.shape.length_scale

    def _average(self, q, radial: bool):
        """(⟨|Â|²⟩, ⟨Â⟩) at q (..., 2) or |q| (radial)."""
        base = self.shape
        if radial:
            qa = np.abs(_radial_array(q))
            flat = qa.ravel()
            qn = flat
            out_shape = qa.shape
        else:
            q = _q_array(q)
            out_shape = q.shape[:-1]
            flat = q.reshape(-1, 2)
            qn = np.hypot(flat[:, 0], flat[:, 1])
        inten = np.empty(qn.shape)
        amp = np.empty(qn.shape, dtype=np.complex128)
        for lev, idx in _groups(self._levels(qn)):
            s, w = self._nodes(self._level_qmax(lev))
            step = max(1, self._MAX_POINTS // len(s))
            for a0 in range(0, len(idx), step):
                sub = idx[a0:a0 + step]
                if radial:
                    I, A = base._both_radial(flat[sub, None] * s[None, :])
                else:
                    I, A = base._both(flat[sub, None, :] * s[None, :, None])
                inten[sub] = (I * (w * s**4)[None, :]).sum(axis=1)
                amp[sub] = (A * (w * s**2)[None, :]).sum(axis=1)
        return inten.reshape(out_shape), amp.reshape(out_shape)

    # --- Shape interface -------------------------------------------------------
    @property
    def isotropic(self) -> bool:
        return self.shape.isotropic

    @property
    def _symmetry(self):
        return self.shape._symmetry

    @property
    def _support(self):
        return self.shape._support * self._s_big

    @property
    def area(self) -> float:
        return self.shape.area * self._m2

    @property
    def length_scale(self) -> float:
        return self.shape.length_scale

    @property
    def exclusion_diameter(self) -> float:
        return self.shape.exclusion_diameter

    @property
    def self_overlap(self) -> float:
        return self.shape.self_overlap

    def _overlap_sum(self, widths, coeffs) -> float:
        # ∫(A_s * G_w)² = s² ∫(A * G_{w/s})²
        s, p = self._nodes(1.0 / self.shape.length_scale)
        widths = np.asarray(widths, dtype=np.float64).ravel()
        coeffs = np.asarray(coeffs, dtype=np.float64).ravel()
        return self.shape._overlap_sum(np.outer(widths, 1.0 / s).ravel(),
                                       np.outer(coeffs, p * s**2).ravel())

    def _both(self, q):
        return self._average(q, radial=False)

    def _both_radial(self, q_abs):
        return self._average(q_abs, radial=True)

    def _intensity(self, q):
        return self._average(q, radial=False)[0]

    def _intensity_radial(self, q_abs):
        return self._average(q_abs, radial=True)[0]

    def amplitude(self, q) -> np.ndarray:
        return self._average(q, radial=False)[1]

    def form_factor(self, q) -> np.ndarray:
        return self._average(q, radial=False)[0] / self.area

    def coherent_form_factor(self, q) -> np.ndarray:
        return np.abs(self.amplitude(q)) ** 2 / self.area

    def amplitude_radial(self, q_abs) -> np.ndarray:
        return self._average(q_abs, radial=True)[1]

    def form_factor_radial(self, q_abs) -> np.ndarray:
        return self._average(q_abs, radial=True)[0] / self.area

    def coherent_form_factor_radial(self, q_abs) -> np.ndarray:
        return np.abs(self.amplitude_radial(q_abs)) ** 2 / self.area


class Mixture(Shape):
    """A number-weighted mixture of scatterer types.

        ``⟨|Â|²⟩ = Σ w_i ⟨|Â_i|²⟩``,  ``⟨Â⟩ = Σ w_i ⟨Â_i⟩``,  ``⟨|A|⟩ = Σ w_i |A_i|``

    with the number weights normalised to ``Σ w_i = 1``.  With the decoupling
    approximation the layer's lobe is ``n [⟨|Â|²⟩ + |⟨Â⟩|² (S - 1)]``.

    Parameters
    ----------
    components : sequence of (Shape, float)
        Shapes and their number weights (>= 0, not all 0).

    ``isotropic`` if all components are.  ``length_scale`` and
    ``exclusion_diameter`` are the maxima over the components (the tables
    use u = q R of the largest, and a hard-core process keeps even the
    largest apart).  ``self_overlap = Σ w_i |A_i| so_i / Σ w_i |A_i|``.

    References
    ----------
    Kotlarchyk & Chen, J. Chem. Phys. 79, 2461 (1983) (decoupling approximation).
    """

    _deterministic = False

    def __init__(self, components):
        try:
            comps = list(components)
        except TypeError:
            raise CoronaError("components must be a list of (shape, number_weight) pairs") from None
        if not comps:
            raise CoronaError("components is empty; expected at least one (shape, weight) pair")
        shapes, weights = [], []
        for i, c in enumerate(comps):
            try:
                sh, wt = c
            except (TypeError, ValueError):
                raise CoronaError(f"components[{i}]={c!r} is not a (shape, number_weight) pair") \
                    from None
            shapes.append(_check_shape(f"components[{i}] shape", sh))
            weights.append(check_range(f"components[{i}] weight", wt, 0.0, math.inf))
        total = sum(weights)
        if not total > 0.0:
            raise CoronaError("components: all number weights are 0; expected a positive sum")
        self.components = [(sh, wt / total) for sh, wt in zip(shapes, weights)]

    def __repr__(self):
        inner = ", ".join(f"({sh!r}, {wt:g})" for sh, wt in self.components)
        return f"Mixture([{inner}])"

    @property
    def isotropic(self) -> bool:
        return all(sh.isotropic for sh, _ in self.components)

    @property
    def _symmetry(self):
        orders = [int(sh._symmetry) for sh, _ in self.components if not sh.isotropic]
        if not orders:
            return 0
        return max(1, reduce(math.gcd, orders))

    @property
    def _support(self):
        return max(sh._support for sh, _ in self.components)

    @property
    def area(self) -> float:
        return float(sum(wt * sh.area for sh, wt in self.components))

    @property
    def length_scale(self) -> float:
        return max(sh.length_scale for sh, _ in self.components)

    @property
    def exclusion_diameter(self) -> float:
        return max(sh.exclusion_diameter for sh, _ in self.components)

    @property
    def self_overlap(self) -> float:
        return float(sum(wt * sh.self_overlap * sh.area for sh, wt in self.components)) / self.area

    def _overlap_sum(self, widths, coeffs) -> float:
        coeffs = np.asarray(coeffs, dtype=np.float64)
        return float(sum(sh._overlap_sum(widths, wt * coeffs) for sh, wt in self.components))

    def _intensity(self, q):
        return sum(wt * sh._intensity(q) for sh, wt in self.components)

    def _intensity_radial(self, q_abs):
        return sum(wt * sh._intensity_radial(q_abs) for sh, wt in self.components)

    def _both(self, q):
        I, A = 0.0, 0.0
        for sh, wt in self.components:
            i, a = sh._both(q)
            I, A = I + wt * i, A + wt * a
        return I, A

    def _both_radial(self, q_abs):
        I, A = 0.0, 0.0
        for sh, wt in self.components:
            i, a = sh._both_radial(q_abs)
            I, A = I + wt * i, A + wt * a
        return I, A

    def amplitude(self, q) -> np.ndarray:
        q = _q_array(q)
        return sum(wt * sh.amplitude(q) for sh, wt in self.components)

    def amplitude_radial(self, q_abs) -> np.ndarray:
        q_abs = _radial_array(q_abs)
        return sum(wt * sh.amplitude_radial(q_abs) for sh, wt in self.components)

    def form_factor(self, q) -> np.ndarray:
        q = _q_array(q)
        return self._intensity(q) / self.area

    def form_factor_radial(self, q_abs) -> np.ndarray:
        return self._intensity_radial(_radial_array(q_abs)) / self.area

    def coherent_form_factor(self, q) -> np.ndarray:
        return np.abs(self.amplitude(q)) ** 2 / self.area

    def coherent_form_factor_radial(self, q_abs) -> np.ndarray:
        return np.abs(self.amplitude_radial(q_abs)) ** 2 / self.area
