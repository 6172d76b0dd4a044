"""The base class of every scatterer shape, and shared helpers.

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

The normalised form factor of docs/physics.md#form-factor is
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
from dataclasses import dataclass, field

import numpy as np
import scipy   # scipy.special: loaded on first use (scipy imports its submodules lazily)

from corona._validation import CoronaError

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
@dataclass
class Term:
    """One deterministic outline of the render kernel (:mod:`corona.mitsuba.kernels`), as a
    shape's ``kernel_terms`` give it (:mod:`corona.model.render_lobe`).

    ``kind`` is ``"circle"`` (``radius``), ``"ellipse"`` (semi-axes ``a``,
    ``b``, ``angle``), ``"rect"`` (``width``, ``height``, ``angle``; the
    kernel's ``angle`` in radians) or
    ``"polygon"`` (``vertices`` (n, 2), centred on the centroid,
    counter-clockwise); ``weight`` is the number weight, ``area`` [µm²] the
    outline's area, ``blur`` [µm] the rms width of the Gaussian soft edge
    (``Â`` times ``exp(-q² blur² / 2)``), ``shape`` the outline (a :class:`corona.Shape`).
    """

    kind: str
    params: dict
    weight: float = 1.0
    area: float = 0.0
    blur: float = 0.0
    #: the outline itself (its numpy ``amplitude`` is the kernel's twin; not part of the key)
    shape: object = field(default=None, compare=False, repr=False)

    def key(self):
        p = {k: (np.asarray(v).tolist() if isinstance(v, np.ndarray) else v) for k, v in self.params.items()}
        return {"kind": self.kind, "params": p, "weight": self.weight, "blur": self.blur}


class Shape:
    """Base class of a scatterer's transmission profile (see the module docstring)."""

    isotropic: bool = False
    #: order m of the rotational symmetry (Â(R_{2π/m} q) = Â(q)); 0 = continuous.
    _symmetry: int = 1
    #: True when the profile is fixed (no orientation / size / type average).
    _deterministic: bool = True
    #: Relative cost of one evaluation of Â (1: one Bessel or exponential; a
    #: polygon's edge count); bounds the work of size averages (corona.parameters).
    _cost: float = 1.0

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

    def kernel_terms(self):
        """The shape as closed-form outlines for the render kernel (a list of
        :class:`Term`), or None: then the renderer tabulates the numpy
        form factor (a radial table, or the B-spline grid of a 2D one), as for a mask."""
        return None

    def signed_distance(self, x, y) -> np.ndarray:
        """Signed distance [µm] of the points (x, y) [µm] to the outline, negative inside.

        Optional: a binary shape that defines it can be rasterised by the brute-force reference
        (:mod:`corona.reference.wave`, antialiased over a pixel).  Random shapes and masks do not.
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
        return {"type": type(self).__name__, **{k: keyable(v) for k, v in vars(self).items()
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
            inten = _orientation_average(self, qs)[0]          # the angle average
        g = np.exp(-(qs[:, None] * widths[None, :]) ** 2) @ coeffs
        total += float(np.sum(ws * qs * inten * g)) / _TWO_PI
        if q_end > Q:
            sel = qs > 0.75 * Q
            c = float(np.sum(ws[sel] * inten[sel] * qs[sel] ** 3) / np.sum(ws[sel]))
            tail = (np.exp(-(widths * Q) ** 2) / Q
                    - widths * math.sqrt(math.pi) * scipy.special.erfc(widths * Q)) @ coeffs
            total += c / _TWO_PI * float(tail)
        return total


def _groups(levels: np.ndarray):
    """Yield (level, indices) for each distinct value of ``levels``."""
    order = np.argsort(levels, kind="stable")
    lv = levels[order]
    cuts = np.nonzero(np.diff(lv))[0] + 1
    for idx in np.split(order, cuts):
        if len(idx):
            yield int(levels[idx[0]]), idx


#: Largest number of (|q|, angle) points of one vectorised orientation-average pass.
_ORIENTATION_MAX_POINTS = 2_000_000


def _orientation_average(shape: "Shape", q_abs, max_points: int = _ORIENTATION_MAX_POINTS):
    """(⟨|Â|²⟩, ⟨Â⟩) of ``shape`` over a uniformly random rotation, at ``|q|``.

    The trapezoidal rule in φ over one symmetry period ``2π/m`` with
    ``N = ⌈(2.2 |q| R + 24)/m⌉`` angles rounded up to a multiple of 8
    (:class:`corona.RandomOrientation` explains the count).
    """
    qa = np.abs(_radial_array(q_abs))
    if shape.isotropic:
        return shape._both_radial(qa)
    flat = qa.ravel()
    inten = np.empty(flat.shape)
    amp = np.empty(flat.shape, dtype=np.complex128)
    m = max(int(shape._symmetry), 1)
    R = shape._support
    need = np.ceil((2.2 * flat * R + 24.0) / m / 8.0).astype(np.int64) * 8
    for N, idx in _groups(need):
        phi = (_TWO_PI / m) * np.arange(N) / N
        rot = np.stack([np.cos(phi), np.sin(phi)], axis=-1)          # (N, 2)
        step = max(1, max_points // N)
        for s in range(0, len(idx), step):
            sub = idx[s:s + step]
            pts = flat[sub, None, None] * rot[None, :, :]           # (k, N, 2)
            I, a = shape._both(pts)
            inten[sub] = I.mean(axis=1)
            amp[sub] = a.mean(axis=1)
    return inten.reshape(qa.shape), amp.reshape(qa.shape)


_GL_CACHE: dict = {}


def _gauss_legendre(n: int):
    """Cached Gauss–Legendre nodes and weights on [-1, 1]."""
    if n not in _GL_CACHE:
        _GL_CACHE[n] = scipy.special.roots_legendre(n)
    return _GL_CACHE[n]


def keyable(v):
    """A cache-key value of the attribute ``v``: shapes by their identity, arrays by a digest,
    sequences element-wise, numpy scalars as Python scalars (Shape.key and Process.key)."""
    if isinstance(v, Shape):
        from corona.model.tabulated import identity
        return identity(v)
    if isinstance(v, np.ndarray):
        import hashlib
        a = np.ascontiguousarray(v)
        h = hashlib.sha256(f"{a.dtype.str}{a.shape}".encode())
        h.update(a.tobytes())
        return "sha256:" + h.hexdigest()
    if isinstance(v, (list, tuple)):
        return [keyable(x) for x in v]
    if isinstance(v, (np.floating, np.integer, np.bool_)):
        return v.item()
    return v


