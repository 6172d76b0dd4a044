"""Form factors of single scatterers (DESIGN §3).

Every shape is a transmission profile ``A(x)`` in the layer plane, lengths in
micrometres.  Its Fourier transform ``Â(q) = ∫ A(x) exp(-i q·x) dx`` is taken
at wave vectors ``q`` in rad/µm, given as arrays of shape ``(..., 2)``.

A shape provides

* ``area`` — ``|A| = ∫ A dx`` [µm²];
* ``length_scale`` — the length ``R`` [µm] of the dimensionless variable
  ``u = q R = 2π R |d| / λ`` (the radius for a circle);
* ``form_factor(q)`` — ``⟨|Â(q)|²⟩ / ⟨|A|⟩`` [µm²] (averaged over orientation
  and size where the shape is random);
* ``coherent_form_factor(q)`` — ``|⟨Â(q)⟩|² / ⟨|A|⟩`` [µm²], which equals
  ``form_factor`` for a deterministic shape and enters the decoupling rule
  ``I ∝ n [⟨|Â|²⟩ + |⟨Â⟩|² (S - 1)]`` for random ones;
* ``isotropic`` — True when the form factor depends on ``|q|`` only;
* ``exclusion_diameter`` — the default hard-core diameter σ [µm] of the
  point process (the circumscribed diameter).

The normalised form factor of DESIGN §3 is
``T_a(d) = form_factor(2π d/λ) / λ²`` and integrates to 1 over the d plane.
"""
from __future__ import annotations

import numpy as np
from scipy import special

from ._validation import check_positive


def _q_array(q) -> np.ndarray:
    q = np.asarray(q, dtype=np.float64)
    if q.ndim == 0 or q.shape[-1] != 2:
        raise ValueError(f"q must have shape (..., 2), got {q.shape}")
    return q


class Shape:
    """Base class of a scatterer's transmission profile."""

    isotropic: bool = False

    @property
    def area(self) -> float:
        raise NotImplementedError

    @property
    def length_scale(self) -> float:
        raise NotImplementedError

    @property
    def exclusion_diameter(self) -> float:
        raise NotImplementedError

    def amplitude(self, q) -> np.ndarray:
        """Complex Fourier transform ``Â(q)`` [µm²] at ``q`` [rad/µm], shape (..., 2)."""
        raise NotImplementedError

    def form_factor(self, q) -> np.ndarray:
        """``⟨|Â(q)|²⟩ / ⟨|A|⟩`` [µm²] at ``q`` [rad/µm] of shape (..., 2)."""
        return np.abs(self.amplitude(q)) ** 2 / self.area

    def coherent_form_factor(self, q) -> np.ndarray:
        """``|⟨Â(q)⟩|² / ⟨|A|⟩`` [µm²]; equals :meth:`form_factor` for a fixed shape."""
        return self.form_factor(q)

    # --- radial helpers (isotropic shapes only) -------------------------
    def form_factor_radial(self, q_abs) -> np.ndarray:
        """Form factor at ``|q|`` [rad/µm] for isotropic shapes."""
        q_abs = np.asarray(q_abs, dtype=np.float64)
        q = np.stack([q_abs, np.zeros_like(q_abs)], axis=-1)
        return self.form_factor(q)

    def coherent_form_factor_radial(self, q_abs) -> np.ndarray:
        q_abs = np.asarray(q_abs, dtype=np.float64)
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


def _keyable(v):
    if isinstance(v, Shape):
        return v.key()
    if isinstance(v, np.ndarray):
        import hashlib
        return "sha256:" + hashlib.sha256(np.ascontiguousarray(v).tobytes()).hexdigest()
    if isinstance(v, (list, tuple)):
        return [_keyable(x) for x in v]
    if isinstance(v, (np.floating, np.integer)):
        return v.item()
    return v


class Circle(Shape):
    """A circular aperture or particle of radius ``radius`` [µm].

    ``Â(q) = π R² · 2 J1(qR)/(qR)``, so ``T_a = (π R²/λ²) (2 J1(u)/u)²``
    with ``u = 2π R |d| / λ`` (Airy pattern).
    """

    isotropic = True

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

    def form_factor(self, q) -> np.ndarray:
        q = _q_array(q)
        return self.form_factor_radial(np.hypot(q[..., 0], q[..., 1]))

    def form_factor_radial(self, q_abs) -> np.ndarray:
        u = np.asarray(q_abs, dtype=np.float64) * self.radius
        return self.area * self.airy(u) ** 2

    coherent_form_factor_radial = form_factor_radial
