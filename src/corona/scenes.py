"""Scene dictionaries for ``mi.load_dict`` (used by the demo, tests and benchmarks).

Units of the scene are metres; the corona BSDF's own lengths stay in µm.
"""
from __future__ import annotations


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
            "emitter": {"type": "area",
                        "radiance": {"type": "blackbody", "temperature": temperature}},
        },
    }
