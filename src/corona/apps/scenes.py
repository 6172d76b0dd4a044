"""Scene dictionaries for ``mi.load_dict`` (used by the demo, tests and benchmarks),
and black-body emitters that every Mitsuba variant renders.

Units of the scene are metres; the corona BSDF's own lengths stay in µm.

Mitsuba's ``blackbody`` spectrum renders in spectral variants only; a
spectrum given as wavelength:value pairs is used as such by spectral
variants and converted to linear sRGB (against the CIE 1931 matching
functions, like a spectral render) by the RGB and mono variants.  The scenes
of ``scenes/`` give their lamps that way (:func:`blackbody_text`).
"""
from __future__ import annotations

import numpy as np

#: Wavelengths [nm] at which black bodies are listed: Mitsuba's visible range in 10 nm steps.
BLACKBODY_WAVELENGTHS = np.arange(360.0, 831.0, 10.0)


def blackbody_radiance(temperature: float, wavelength=BLACKBODY_WAVELENGTHS) -> np.ndarray:
    """Planck's law, spectral radiance [W / (m² sr nm)] (the unit of Mitsuba's ``blackbody``).

    ``B(λ, T) = 2 h c² / λ⁵ / (exp(h c / (λ k T)) - 1)``, with λ in m, times
    1e-9 per nm (M. Planck, 1901; CODATA constants from :mod:`scipy.constants`).
    """
    from scipy.constants import Boltzmann, Planck, speed_of_light
    from corona._validation import check_positive
    t = check_positive("temperature", temperature, "K")
    lam = np.asarray(wavelength, dtype=np.float64) * 1e-9
    hc = Planck * speed_of_light
    return 1e-9 * 2 * hc * speed_of_light / lam**5 / np.expm1(hc / (lam * Boltzmann * t))


def blackbody_text(temperature: float, scale: float = 1.0, per_line: int = 6, indent: str = "") -> str:
    """The ``value`` of ``<spectrum name="radiance" value="..."/>`` for a black body:
    ``"360:32.27, 370:..., ..."`` (4 significant digits, :data:`BLACKBODY_WAVELENGTHS`),
    times ``scale`` (a lamp brighter or dimmer than a black body of its colour)."""
    values = scale * blackbody_radiance(temperature)
    pairs = [f"{lam:g}:{v:.4g}" for lam, v in zip(BLACKBODY_WAVELENGTHS, values)]
    lines = [", ".join(pairs[i:i + per_line]) for i in range(0, len(pairs), per_line)]
    return (",\n" + indent).join(lines)


def blackbody_spectrum(temperature: float) -> dict:
    """A black body for ``mi.load_dict`` that renders in spectral, RGB and mono variants."""
    return {"type": "spectrum",
            "value": [(float(lam), float(v))
                      for lam, v in zip(BLACKBODY_WAVELENGTHS, blackbody_radiance(temperature))]}


def street_light_scene(resolution: int = 256, bsdf: dict | None = None, *, fov: float = 20.0,
                       pane_distance: float = 0.5, light_distance: float = 20.0,
                       light_radius: float = 0.05, temperature: float = 3000.0,
                       max_depth: int = 4,
                       integrator: str = "path", incidence_deg: float = 0.0) -> dict:
    """A small bright emitter seen at night through a pane carrying ``bsdf``.

    Parameters
    ----------
    resolution : int
        Image width and height [pixels].
    bsdf : dict, optional
        The pane's BSDF (default: water droplets, ``corona`` hard disks, 5 µm).
    fov : float
        Horizontal field of view [degree].
    pane_distance, light_distance, light_radius : float
        Camera-to-pane and camera-to-light distances and the light's radius [m].
    temperature : float
        Black-body temperature of the light [K].
    incidence_deg : float
        Tilt of the pane about the vertical axis [degree] (0: facing the camera).
    """
    import mitsuba as mi
    if bsdf is None:
        bsdf = {"type": "corona", "radius": 5.0, "area_fraction": 0.4, "process": "hard-disk",
                "mode": "particle"}
    half = 0.5 * pane_distance * 2.0  # pane much larger than the view
    T = mi.ScalarTransform4f
    pane_to_world = (T().translate([0, 0, pane_distance]).rotate([0, 1, 0], incidence_deg)
                     .scale([half, half, 1]))
    return {
        "type": "scene",
        "integrator": {"type": integrator, "max_depth": max_depth},
        "sensor": {
            "type": "perspective", "fov": fov, "fov_axis": "x",
            "to_world": T().look_at(origin=[0, 0, 0], target=[0, 0, 1], up=[0, 1, 0]),
            "film": {"type": "hdrfilm", "width": resolution, "height": resolution,
                     "rfilter": {"type": "box"}, "pixel_format": "rgb"},
            "sampler": {"type": "independent"},
        },
        "pane": {"type": "rectangle", "to_world": pane_to_world, "bsdf": bsdf},
        "light": {
            "type": "sphere", "center": [0, 0, light_distance], "radius": light_radius,
            "emitter": {"type": "area", "radiance": blackbody_spectrum(temperature)},
        },
    }


def lamp_photograph_scene(resolution: int = 128, bsdf: dict | None = None, *, fov: float = 20.0,
                          source_deg=(0.0, 0.0), source_radius_deg: float = 0.1,
                          temperature: float = 3000.0) -> dict:
    """A distant black-body lamp photographed through a layer facing the camera.

    The geometry :func:`corona.apps.fit.fit_photograph` assumes: a pinhole camera
    at the origin looking along +z (horizontal field of view ``fov``), the
    layer ``bsdf`` parallel to the sensor 0.1 m in front of it (beyond the
    perspective sensor's near clip of 0.01 m) and 20 m wide, and a spherical
    lamp 1 km away, so that the parallax between pane points is below 1e-4 of
    an angle (the far field).

    Parameters
    ----------
    resolution : int
        Image width and height [pixels].
    bsdf : dict, optional
        The layer (default: ``corona`` droplets, hard disks, 5 µm, F_a 0.4).
    fov : float
        Horizontal field of view [degree].
    source_deg : (float, float)
        Direction of the lamp: angles [degree] about the camera's y and x axes
        (tan of each is the offset per unit depth).
    source_radius_deg : float
        Angular radius of the lamp [degree].
    temperature : float
        Black-body temperature of the lamp [K].
    """
    import math

    import mitsuba as mi
    if bsdf is None:
        bsdf = {"type": "corona", "radius": 5.0, "area_fraction": 0.4, "process": "hard-disk",
                "mode": "particle"}
    distance = 1000.0
    tx, ty = (math.tan(math.radians(a)) for a in source_deg)
    norm = math.sqrt(tx * tx + ty * ty + 1.0)
    centre = [distance * tx / norm, distance * ty / norm, distance / norm]
    T = mi.ScalarTransform4f
    return {
        "type": "scene",
        "integrator": {"type": "path", "max_depth": 3},
        "sensor": {
            "type": "perspective", "fov": fov, "fov_axis": "x",
            "to_world": T().look_at(origin=[0, 0, 0], target=[0, 0, 1], up=[0, 1, 0]),
            "film": {"type": "hdrfilm", "width": resolution, "height": resolution,
                     "rfilter": {"type": "box"}, "pixel_format": "rgb"},
            "sampler": {"type": "independent"},
        },
        "pane": {"type": "rectangle", "to_world": T().translate([0, 0, 0.1]).scale([10, 10, 1]),
                 "bsdf": bsdf},
        "light": {
            "type": "sphere", "center": centre,
            "radius": distance * math.tan(math.radians(source_radius_deg)),
            "emitter": {"type": "area", "radiance": {"type": "blackbody", "temperature": temperature}},
        },
    }
