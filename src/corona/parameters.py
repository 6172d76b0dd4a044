"""Build a :class:`corona.Material` from flat, named parameters.

One vocabulary serves the Mitsuba plugin (XML / ``load_dict``), the CLI and
scripts.  Every parameter is validated here with one clear error.

======================  ==========  ===========  =============================================
name                    unit        default      meaning
======================  ==========  ===========  =============================================
shape                   —           circle       circle, ellipse, square, rectangle, polygon, mask,
                                                 mixture
radius                  µm          0.5          circle radius; ellipse semi-axis along x;
                                                 square / rectangle half-width; polygon
                                                 circumradius
aspect                  —           1.0          ellipse / rectangle: extent along y over x
sides                   —           6            polygon: number of sides (>= 3)
angle                   degree      0            rotation of anisotropic shapes
filename                —           —            mask: image file; process=points: point file
                                                 (when the shape is not a mask)
points_filename         —           —            process=points: point file (needed with
                                                 shape=mask, where filename is the image)
pixel_size              µm          —            mask: size of one image pixel
edge_width              µm          0            soft edge: std of the Gaussian apodisation
orientation             —           fixed        fixed, random (rotational average)
size_spread             —           0            relative std of the scatterer size
size_distribution       —           lognormal    lognormal, schulz
area_fraction           —           0.3          F_a = n |A|
process                 —           hard-disk    poisson, hard-disk, rsa, lattice-square,
                                                 lattice-hex, points
exclusion_diameter      µm          shape's      hard-core diameter σ (hard-disk, rsa)
jitter                  µm          0            lattice: rms displacement per axis
mode                    —           aperture     aperture, particle
albedo                  —           0            diffuse reflectance of the opaque part
mixture                 —           —            shape=mixture: 'SHAPE:RADIUS:WEIGHT, ...' (shapes
                                                 circle…polygon, radius µm, number weights);
                                                 decoupling approximation (DESIGN §3)
======================  ==========  ===========  =============================================
"""
from __future__ import annotations

import math

from ._validation import CoronaError, check_choice, check_positive, check_range

SHAPES = ("circle", "ellipse", "square", "rectangle", "polygon", "mask", "mixture")
PROCESSES = ("poisson", "hard-disk", "rsa", "lattice-square", "lattice-hex", "points")
ORIENTATIONS = ("fixed", "random")
SIZE_DISTRIBUTIONS = ("lognormal", "schulz")

DEFAULTS = {
    "shape": "circle", "radius": 0.5, "aspect": 1.0, "sides": 6, "angle": 0.0,
    "filename": None, "points_filename": None, "pixel_size": None, "edge_width": 0.0, "orientation": "fixed",
    "size_spread": 0.0, "size_distribution": "lognormal", "area_fraction": 0.3,
    "process": "hard-disk", "exclusion_diameter": None, "jitter": 0.0,
    "mode": "aperture", "albedo": 0.0, "mixture": None,
}


MIXTURE_SHAPES = ("circle", "ellipse", "square", "rectangle", "polygon")


def _outline(kind: str, r: float, p: dict):
    """The bare shape ``kind`` of size ``r`` [µm] (aspect, sides, angle from ``p``)."""
    from . import shapes
    angle = math.radians(check_range("angle", p["angle"], -360.0, 360.0, unit="degree"))
    aspect = check_positive("aspect", p["aspect"])
    if kind == "circle":
        return shapes.Circle(r)
    if kind == "ellipse":
        return shapes.Ellipse(r, r * aspect, angle=angle)
    if kind == "square":
        return shapes.Square(2 * r, angle=angle)
    if kind == "rectangle":
        return shapes.Rectangle(2 * r, 2 * r * aspect, angle=angle)
    sides = p["sides"]
    if int(sides) != sides or int(sides) < 3:
        raise CoronaError(f"sides={sides!r} is out of range; allowed integers >= 3")
    return shapes.RegularPolygon(int(sides), r, angle=angle)


def parse_mixture(spec) -> list[tuple[str, float, float]]:
    """``"circle:5:0.5, square:4.43:0.5"`` -> [(shape, radius µm, number weight), ...]."""
    form = "mixture='SHAPE:RADIUS:WEIGHT, ...' (e.g. 'circle:5:0.5, square:4.43:0.5')"
    if not isinstance(spec, str) or not spec.strip():
        raise CoronaError(f"shape='mixture' needs {form}")
    out = []
    for item in spec.split(","):
        parts = [x.strip() for x in item.split(":")]
        if len(parts) != 3:
            raise CoronaError(f"mixture item {item.strip()!r} is malformed; expected {form}")
        kind = check_choice("mixture shape", parts[0], MIXTURE_SHAPES)
        try:
            r, w = float(parts[1]), float(parts[2])
        except ValueError:
            raise CoronaError(f"mixture item {item.strip()!r}: radius and weight must be numbers; "
                              f"expected {form}") from None
        out.append((kind, check_positive("mixture radius", r, "µm"),
                    check_range("mixture weight", w, 0.0, math.inf, hi_open=True)))
    if sum(w for _, _, w in out) <= 0:
        raise CoronaError(f"mixture={spec!r}: the number weights are all 0; at least one must be > 0")
    return out


def _modified(base, p: dict):
    """``base`` with the soft edge, size spread and random orientation of ``p``."""
    from . import shapes
    w = check_range("edge_width", p["edge_width"], 0.0, math.inf, hi_open=True, unit="µm")
    if w > 0:
        base = shapes.SoftEdge(base, w)
    spread = check_range("size_spread", p["size_spread"], 0.0, 1.0, unit="(relative std)")
    if spread > 0:
        dist = check_choice("size_distribution", p["size_distribution"], SIZE_DISTRIBUTIONS)
        base = shapes.SizeDistribution(base, spread, distribution=dist)
    if check_choice("orientation", p["orientation"], ORIENTATIONS) == "random" and not base.isotropic:
        base = shapes.RandomOrientation(base)
    return base


def make_shape(p: dict):
    from . import shapes
    kind = check_choice("shape", p["shape"], SHAPES)
    check_range("angle", p["angle"], -360.0, 360.0, unit="degree")
    if kind == "mixture":
        # each component carries the edge / spread / orientation modifiers; the
        # layer's lobe follows the decoupling approximation (DESIGN §3)
        # (types of weight 0 are left out: they would still set the exclusion diameter)
        return shapes.Mixture([(_modified(_outline(k, r, p), p), w)
                               for k, r, w in parse_mixture(p["mixture"]) if w > 0])
    if p.get("mixture"):
        raise CoronaError(f"mixture={p['mixture']!r} needs shape='mixture' (got shape={kind!r})")
    if kind == "mask":
        if not p.get("filename"):
            raise CoronaError("shape='mask' needs filename=<image file>")
        if p.get("pixel_size") is None:
            raise CoronaError("shape='mask' needs pixel_size=<µm per pixel>")
        base = shapes.Mask(p["filename"], check_positive("pixel_size", p["pixel_size"], "µm"))
    else:
        base = _outline(kind, check_positive("radius", p["radius"], "µm"), p)
    return _modified(base, p)


def make_process(p: dict, shape):
    from . import processes
    kind = check_choice("process", p["process"], PROCESSES)
    fa = check_range("area_fraction", p["area_fraction"], 0.0, 1.0, lo_open=True, hi_open=True)
    sigma = p.get("exclusion_diameter")
    if sigma is not None:
        sigma = check_positive("exclusion_diameter", sigma, "µm")
    if kind == "poisson":
        return processes.Poisson(fa)
    if kind == "hard-disk":
        return processes.HardDisk(fa, exclusion_diameter=sigma)
    if kind == "rsa":
        return processes.SequentialAdsorption(fa, exclusion_diameter=sigma)
    if kind in ("lattice-square", "lattice-hex"):
        jitter = check_range("jitter", p["jitter"], 0.0, math.inf, hi_open=True, unit="µm")
        # spacing from the area fraction: cell area = |A| / F_a; neighbours at
        # the shape's exclusion diameter σ give the largest F_a without overlaps
        sd = shape.exclusion_diameter
        fmax = shape.area / (sd * sd) if kind == "lattice-square" else 2 * shape.area / (math.sqrt(3) * sd * sd)
        if fa > fmax * (1.0 + 1e-12):
            raise CoronaError(f"area_fraction={fa:g} is out of range for process={kind!r} with this shape; "
                              f"allowed (0, {fmax:.4g}] (neighbours would overlap)")
        cell = shape.area / fa
        if kind == "lattice-square":
            return processes.Lattice("square", math.sqrt(cell), jitter=jitter)
        return processes.Lattice("hexagonal", math.sqrt(2 * cell / math.sqrt(3)), jitter=jitter)
    return processes.PointSet.from_file(points_file(p))


def points_file(p: dict) -> str:
    """The point file of process='points': ``points_filename``, else ``filename``
    unless that names the mask image of shape='mask'."""
    if p.get("points_filename"):
        return p["points_filename"]
    if p.get("shape") == "mask":
        raise CoronaError("process='points' with shape='mask' needs points_filename=<point file> "
                          "(filename is the mask image)")
    if not p.get("filename"):
        raise CoronaError("process='points' needs filename=<point file> (or points_filename=)")
    return p["filename"]


def material_from_parameters(**params):
    """A :class:`corona.Material` from the named parameters of the module table.

    Unknown names raise a :class:`corona.CoronaError` listing the known ones.
    """
    from .material import Material
    unknown = sorted(set(params) - set(DEFAULTS))
    if unknown:
        raise CoronaError(f"unknown parameter(s) {', '.join(unknown)}; known: {', '.join(sorted(DEFAULTS))}")
    p = {**DEFAULTS, **{k: v for k, v in params.items() if v is not None}}
    shape = make_shape(p)
    process = make_process(p, shape)
    mode = check_choice("mode", p["mode"], ("aperture", "particle"))
    return Material(shape, process, mode=mode, albedo=p["albedo"])
