"""Droplet volumes in Mitsuba: the media dicts of droplets with the ``corona_mie`` phase function
(docs/volumes.md), and a slab test scene.

The physics (size distributions, the size-averaged Mie intensities, the phase function's
tables :class:`~corona.model.mie.volume.MieVolume`, number densities and coefficients) is
:mod:`corona.model.mie.volume`; this module turns it into Mitsuba's ``homogeneous`` and
``heterogeneous`` media (spectra, grids, the phase dict of :mod:`corona.mitsuba.phase`).
"""
from __future__ import annotations

import math

import numpy as np

from corona.model import tabulated
from corona.model.mie.volume import medium_coefficients
from corona._validation import CoronaError, short_repr, check_range

__all__ = ["homogeneous_medium", "heterogeneous_medium", "slab_scene", "radial_profile", "spectrum_dict"]


# ----------------------------------------------------------------------
# media
# ----------------------------------------------------------------------
def spectrum_dict(wavelengths, values):
    """A Mitsuba spectrum dict: irregular in spectral variants, the channel means in RGB / mono."""
    import mitsuba as mi
    lam = np.asarray(wavelengths, dtype=np.float64)
    val = np.asarray(values, dtype=np.float64)
    order = np.argsort(lam)
    lam, val = lam[order], val[order]
    if mi.is_spectral:
        return {"type": "irregular", "wavelengths": ", ".join(f"{x:.6g}" for x in lam),
                "values": ", ".join(f"{x:.8g}" for x in val)}
    from corona.mitsuba.common import channel_response
    cl, cw = channel_response()
    rgb = [float(np.sum(w * np.interp(c, lam, val))) for c, w in zip(cl, cw)]
    if mi.is_monochromatic:
        return {"type": "uniform", "value": rgb[0]}
    return {"type": "rgb", "value": rgb}


#: Largest σ_t [1/scene unit] a medium may have (float32 holds 3.4e38; Mitsuba multiplies σ_t by
#: distances and sums optical depths in float32).
SIGMA_T_MAX = 1e30


def _medium_parts(radius, lwc, number_density, number_density_cm3, distribution, variance,
                  gamma_exponent, ior, ior_imag, scene_unit, correlated, use_cache, host_ior=1.0,
                  truncation=0.0):
    info = medium_coefficients(radius, lwc, number_density, number_density_cm3, distribution, variance,
                               gamma_exponent, ior, ior_imag, scene_unit, correlated, use_cache, host_ior,
                               truncation)
    vol, sigma_t = info["volume"], info["sigma_t"]
    phase = {"type": "corona_mie", "radius": float(radius), "distribution": distribution,
             "variance": float(variance or 0.0), "ior_imag": float(ior_imag),
             "volume_fraction": vol.volume_fraction}
    if distribution == "modified_gamma":
        phase["gamma_exponent"] = float(gamma_exponent)
    phase["ior"] = ior if isinstance(ior, str) else float(ior)
    if vol.host_ior != 1.0:
        phase["host_ior"] = vol.host_ior
    if vol.truncation > 0:
        phase["truncation"] = vol.truncation
    if not np.all(np.isfinite(sigma_t)) or float(np.max(sigma_t)) > SIGMA_T_MAX:
        raise CoronaError(f"scene_unit={scene_unit!r} is out of range with this density: σ_t would be "
                          f"{float(np.max(sigma_t)):.3g} per scene unit; allowed at most {SIGMA_T_MAX:g} "
                          "(a smaller scene_unit or density)")
    return phase, info


def homogeneous_medium(radius, *, lwc=None, number_density=None, number_density_cm3=None,
                       distribution="mono", variance=0.0, gamma_exponent=1.0, ior="water",
                       ior_imag=0.0, scene_unit=1.0, correlated=True, use_cache=True,
                       return_info=False, host_ior=1.0, truncation=0.0):
    """A Mitsuba ``homogeneous`` medium dict of droplets with the ``corona_mie`` phase function.

    Parameters
    ----------
    radius : float
        Droplet (effective) radius [µm].
    lwc : float, optional
        Liquid water content [g/m³] (water droplets): ``N = lwc / (ρ_w ⟨4π r³/3⟩)``.
    number_density : float, optional
        Droplets per m³.
    number_density_cm3 : float, optional
        Droplets per cm³ (cloud physics' unit; 1/cm³ = 10⁶/m³).  Exactly one of the three.
    distribution, variance, gamma_exponent
        The size distribution (:func:`~corona.model.mie.volume.size_nodes`).
    ior, ior_imag
        The particles' index (relative to air; :func:`~corona.model.mie.volume.droplet_index`).
    host_ior : float
        The host's index in [1, 3] (1: air; water 1.33, a resin 1.5): relative index
        ``m = (ior + i ior_imag) / host_ior``, wavelength in the host ``λ / host_ior``.
    truncation : float
        Forward-peak truncation angle [degrees] (0: none; [0.5, 30]): the part ``f`` of the
        forward peak inside it counts as unscattered, ``σ_s → (1 - f) σ_s``, ``σ_t → σ_t - f σ_s``
        (:func:`~corona.model.mie.volume.truncate_table`); exact outside the cone, far less noise in thick media lit by
        a small light (docs/volumes.md#forward-peak-truncation).
    scene_unit : float
        Metres per scene length unit (1: the scene is in metres; 1e-3: millimetres), in
        [1e-9, 1e9] (:data:`~corona.model.mie.volume.SCENE_UNIT_RANGE`).
    correlated : bool
        Apply the hard-sphere structure factor at the droplets' volume fraction (negligible
        below ~1e-3; docs/volumes.md#dense-media).
    return_info : bool
        Also return a dict with ``number_density`` [1/m³], ``volume_fraction``, ``wavelength``
        [nm], ``sigma_t`` [1/scene unit], ``albedo`` (per table row) and the :class:`~corona.model.mie.volume.MieVolume`.

    Returns
    -------
    dict
        ``{"type": "homogeneous", "sigma_t": spectrum, "scale": float, "albedo": spectrum,
        "phase": {...}}``, ``σ_t = scale × sigma_t = N ⟨C_ext⟩`` per scene unit (``sigma_t``
        normalised to a peak of 1, as Mitsuba's RGB spectra must be), ``albedo = ⟨C_sca⟩ / ⟨C_ext⟩`` (spectra over the table's
        wavelengths in spectral variants; channel means in RGB and mono variants).  Needs
        ``corona.register()`` before ``mi.load_dict``.

    Examples
    --------
    Fog of 5 µm droplets at 0.1 g/m³: 191 droplets per cm³, visibility (``3.9/σ_t`` at 550 nm)
    about 124 m:

    >>> import mitsuba as mi
    >>> mi.set_variant("scalar_rgb")
    >>> med, info = homogeneous_medium(5.0, lwc=0.1, return_info=True)
    >>> c_ext = info["volume"].cross_sections(550.0)["c_ext"]           # µm²
    >>> round(info["number_density"] * 1e-6), round(3.9 / (info["number_density"] * c_ext * 1e-12))
    (191, 124)
    """
    phase, info = _medium_parts(radius, lwc, number_density, number_density_cm3, distribution,
                                variance, gamma_exponent, ior, ior_imag, scene_unit, correlated,
                                use_cache, host_ior, truncation)
    lam = info["wavelength"]
    scale = float(np.max(info["sigma_t"]))          # RGB spectra must lie in [0, 1]: σ_t = scale × shape
    med = {"type": "homogeneous", "sigma_t": spectrum_dict(lam, info["sigma_t"] / scale), "scale": scale,
           "albedo": spectrum_dict(lam, info["albedo"]), "phase": phase}
    return (med, info) if return_info else med


def heterogeneous_medium(radius, density, *, lwc=None, number_density=None, number_density_cm3=None,
                         bbox=None, distribution="mono", variance=0.0, gamma_exponent=1.0,
                         ior="water", ior_imag=0.0, scene_unit=1.0, reference_wavelength=550.0,
                         use_cache=True, return_info=False, host_ior=1.0, truncation=0.0):
    """A Mitsuba ``heterogeneous`` medium dict: droplets with a density grid.

    ``density`` (Z, Y, X) >= 0 multiplies the number density given by ``lwc``,
    ``number_density`` or ``number_density_cm3`` (the value where density is 1).
    Mitsuba's grid is scalar: ``σ_t = density × N ⟨C_ext(λ_ref)⟩`` at
    ``reference_wavelength`` [nm] for all wavelengths (the spectral ``albedo``
    is kept); ``info["sigma_t_spread"]`` is the range of ``⟨C_ext⟩`` over
    360–830 nm relative to its value at ``reference_wavelength`` (the interference
    structure of Q_ext: about 0.2 for one droplet size of a few µm, less for broad
    size distributions and large droplets).  No structure factor (the density varies).

    Other parameters (``host_ior``, ``truncation`` too) as :func:`homogeneous_medium`; ``bbox`` ((3,), (3,)) places the grid
    (Mitsuba's default: the unit cube).
    """
    import mitsuba as mi
    raw = np.asarray(density)
    if raw.dtype.kind not in "biuf":     # complex would lose its imaginary part, strings fail late
        raise CoronaError(f"density of dtype {raw.dtype} is out of range; allowed a real (Z, Y, X) "
                          "array of finite values >= 0")
    grid = raw.astype(np.float64)
    if bbox is not None:
        try:
            box = np.asarray(bbox, dtype=np.float64)
        except (TypeError, ValueError):
            box = None
        if box is None or box.shape != (2, 3) or not np.all(np.isfinite(box)) or np.any(box[1] <= box[0]):
            raise CoronaError(f"bbox={short_repr(bbox)} is out of range; allowed ((x0, y0, z0), (x1, y1, z1)), "
                              "finite, each x1 > x0")
    if grid.ndim != 3 or min(grid.shape) < 2 or not np.all(np.isfinite(grid)) or np.any(grid < 0):
        raise CoronaError(f"density of shape {grid.shape} is out of range; allowed a (Z, Y, X) array, "
                          "each side >= 2, finite values >= 0")
    phase, info = _medium_parts(radius, lwc, number_density, number_density_cm3, distribution,
                                variance, gamma_exponent, ior, ior_imag, scene_unit, False,
                                use_cache, host_ior, truncation)
    peak = info["number_density"] * float(grid.max())
    if peak * info["volume"].mean_volume * 1e-18 >= 0.494:
        raise CoronaError(f"density max {grid.max():g} is out of range: the droplets would fill a "
                          "volume fraction >= 0.494")
    lam_ref = check_range("reference_wavelength", reference_wavelength, tabulated.WAVELENGTH_MIN,
                          tabulated.WAVELENGTH_MAX, unit="nm")
    s_ref = float(np.interp(lam_ref, info["wavelength"][::-1], info["sigma_t"][::-1]))
    if not float(grid.max()) * s_ref <= SIGMA_T_MAX:
        raise CoronaError(f"density max {grid.max():g} is out of range with this number density: σ_t "
                          f"would reach {float(grid.max()) * s_ref:.3g} per scene unit; allowed at most "
                          f"{SIGMA_T_MAX:g}")
    info["sigma_t_spread"] = float(np.ptp(info["sigma_t"]) / s_ref)
    vol = {"type": "gridvolume", "grid": mi.VolumeGrid(grid.astype(np.float32)[..., None])}
    if bbox is not None:
        lo, hi = box
        vol["to_world"] = mi.ScalarTransform4f().translate(lo.tolist()).scale((hi - lo).tolist())
    med = {"type": "heterogeneous", "sigma_t": vol, "scale": s_ref,
           "albedo": spectrum_dict(info["wavelength"], info["albedo"]), "phase": phase}
    return (med, info) if return_info else med


# ----------------------------------------------------------------------
# a test scene: looking at a distant light through a slab
# ----------------------------------------------------------------------
def slab_scene(medium=None, *, layer=None, thickness=0.01, fov=20.0, size=64, spp=256,
               max_depth=-1, integrator="volpath", irradiance=1.0):
    """A Mitsuba scene dict: a camera on the axis looking through a slab at a distant light.

    The slab fills ``|x|, |y| < 50`` and ``|z| < thickness / 2`` (scene units), the light is a
    ``directional`` emitter travelling along ``-z`` (irradiance ``irradiance`` on a plane normal
    to it), the camera sits at ``z = -1`` looking along ``+z`` (``fov`` degrees, ``size``² pixels,
    box filter), so pixel directions are the scattering angles.  ``medium``: a medium dict filling
    the slab (``null`` boundary); ``layer``: a BSDF dict on the plane ``z = 0`` instead (the
    corona layer).  The coherent (unscattered) beam never reaches the camera.
    """
    import mitsuba as mi
    T = mi.ScalarTransform4f
    scene = {"type": "scene",
             "integrator": {"type": integrator, "max_depth": int(max_depth)},
             "sensor": {"type": "perspective", "fov": float(fov),
                        "to_world": T().look_at(origin=[0, 0, -1], target=[0, 0, 0], up=[0, 1, 0]),
                        "film": {"type": "hdrfilm", "width": int(size), "height": int(size),
                                 "rfilter": {"type": "box"}, "pixel_format": "rgb"},
                        "sampler": {"type": "independent", "sample_count": int(spp)}},
             "sun": {"type": "directional", "direction": [0, 0, -1],
                     "irradiance": {"type": "uniform", "value": float(irradiance)}}}
    if medium is not None:
        scene["slab"] = {"type": "cube", "to_world": T().scale([50.0, 50.0, 0.5 * float(thickness)]),
                         "bsdf": {"type": "null"}, "interior": medium}
    if layer is not None:
        # the rectangle's normal faces the light (+z); the camera sees its transmission
        scene["layer"] = {"type": "rectangle", "to_world": T().scale([50.0, 50.0, 1.0]), "bsdf": layer}
    return scene


def radial_profile(image, fov, bins):
    """Mean of ``image`` (H, W[, C]) over rings of the angle from the view axis [rad].

    ``bins``: ring edges [rad].  Returns (centres, means (n[, C]), pixel counts)."""
    img = np.asarray(image, dtype=np.float64)
    H, W = img.shape[:2]
    f = 0.5 * W / math.tan(math.radians(fov) / 2)        # focal length in pixels (fov along x)
    yy, xx = np.mgrid[0:H, 0:W]
    ang = np.arctan(np.hypot(xx + 0.5 - W / 2, yy + 0.5 - H / 2) / f)
    idx = np.digitize(ang.ravel(), bins) - 1
    flat = img.reshape(H * W, -1)
    n = len(bins) - 1
    means = np.array([flat[idx == k].mean(axis=0) if np.any(idx == k) else np.full(flat.shape[1], np.nan)
                      for k in range(n)])
    counts = np.array([np.sum(idx == k) for k in range(n)])
    return 0.5 * (np.asarray(bins[1:]) + np.asarray(bins[:-1])), means, counts
