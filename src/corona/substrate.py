"""The pane under a layer: a thin, non-absorbing glass sheet (numpy reference).

A fogged window is droplets on glass, and glass reflects.  :class:`GlassPane`
is the sheet of glass the corona layer sits on; :class:`corona.Material`
combines the two (see ``docs/physics.md#the-layer-on-glass-substrateglass`` for which inter-reflections the
combination keeps and which it drops).
"""
from __future__ import annotations

import numpy as np

from ._validation import CoronaError, check_choice, check_range

SIDES = ("front", "back")
#: Index of refraction of window (soda-lime) glass at 550 nm.
GLASS_IOR = 1.52


def fresnel_dielectric(cos_theta_i, eta) -> np.ndarray:
    """Unpolarised Fresnel reflectance of one air → dielectric interface.

    Parameters
    ----------
    cos_theta_i : array
        Cosine of the angle of incidence, |cos| is used (the interface is
        entered from the air side, so there is no total internal reflection).
    eta : float
        Relative index of refraction ``n_glass / n_air`` (>= 1).

    Returns
    -------
    R = (r_s² + r_p²) / 2 with ``r_s = (cos_i - η cos_t) / (cos_i + η cos_t)``,
    ``r_p = (η cos_i - cos_t) / (η cos_i + cos_t)`` and Snell's
    ``sin_t = sin_i / η`` (M. Born, E. Wolf, *Principles of Optics*, §1.5.2).
    """
    ci = np.clip(np.abs(np.asarray(cos_theta_i, dtype=np.float64)), 0.0, 1.0)
    st2 = (1.0 - ci * ci) / (eta * eta)
    ct = np.sqrt(np.maximum(0.0, 1.0 - st2))
    with np.errstate(divide="ignore", invalid="ignore"):
        rs = (ci - eta * ct) / (ci + eta * ct)
        rp = (eta * ci - ct) / (eta * ci + ct)
        r = 0.5 * (rs * rs + rp * rp)
    return np.where(ci > 0, r, 1.0)


class GlassPane:
    """A thin, flat, non-absorbing pane (the substrate of a layer).

    Parameters
    ----------
    ior : float >= 1, default 1.52
        Index of refraction of the glass (the surroundings are air, n = 1).
    side : {"front", "back"}
        The face of the pane that carries the layer, in the layer's local
        frame: ``front`` is the +z face (the side the shading normal points
        to), ``back`` the -z face.

    Notes
    -----
    The pane is thin: a ray leaves it parallel to the way it entered (the
    two faces are parallel), so it only splits light into a specular
    reflection and an undeviated transmission.  Summing the incoherent
    bounces between its two faces (R, TRT, TR³T, ...), with the same
    single-face reflectance R on both faces (Stokes relations),

        R' = R + T² R / (1 - R²) = 2R / (1 + R),       T' = 1 - R' = (1 - R) / (1 + R),

    applied to the polarisation-averaged Fresnel reflectance R, the way
    Mitsuba 3's ``thindielectric`` plugin does.  The pane is dispersion-free
    (one index for every wavelength).
    """

    def __init__(self, ior: float = GLASS_IOR, side: str = "front"):
        self.ior = check_range("substrate_ior", ior, 1.0, np.inf, hi_open=True)
        self.side = check_choice("substrate_side", side, SIDES)

    def __repr__(self):
        return f"GlassPane(ior={self.ior:g}, side={self.side!r})"

    def key(self) -> dict:
        return {"ior": self.ior, "side": self.side}

    def face_reflectance(self, cos_theta) -> np.ndarray:
        """Fresnel reflectance R of one face at incidence ``cos_theta``."""
        return fresnel_dielectric(cos_theta, self.ior)

    def reflectance(self, cos_theta) -> np.ndarray:
        """Specular reflectance of the whole pane, ``R' = 2R / (1 + R)``."""
        r = self.face_reflectance(cos_theta)
        return 2.0 * r / (1.0 + r)

    def transmittance(self, cos_theta) -> np.ndarray:
        """Undeviated transmittance of the pane, ``T' = 1 - R'`` (no absorption)."""
        return 1.0 - self.reflectance(cos_theta)

    def layer_first(self, cos_theta_i) -> np.ndarray:
        """True where light arriving from the direction ``wi`` (signed ``cos θi``
        in the layer's frame) meets the layer before the glass."""
        c = np.asarray(cos_theta_i, dtype=np.float64)
        return c > 0 if self.side == "front" else c < 0


def make_substrate(kind: str, ior=None, side: str = "front") -> GlassPane | None:
    """The substrate of ``substrate=kind`` (None for ``none``), with one clear error."""
    kind = check_choice("substrate", kind, ("none", "glass"))
    if kind == "none":
        if ior is not None:
            raise CoronaError(f"substrate_ior={ior!r} needs substrate='glass' (got substrate='none')")
        return None
    return GlassPane(GLASS_IOR if ior is None else ior, side)
