"""The one parameter specification of a corona layer, and the material it builds.

:data:`PARAMETERS` lists every parameter once: name, type, unit, default,
allowed values and a one-line meaning.  The Mitsuba plugin reads its
properties through it (and its docstring table is generated from it), the
CLI's ``corona lobe`` options are generated from it, and the README's table
is checked against it by the tests (``python -m corona.parameters`` prints
the Markdown table).  :func:`material_from_parameters` validates each value
here, at the boundary, with one clear error (name, value, allowed range).

{table}
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from ._validation import CoronaError, check_choice, check_positive, check_range


@dataclass(frozen=True)
class Parameter:
    """One parameter of a corona layer.

    Attributes
    ----------
    name : str
        Name in XML / ``load_dict`` / Python (``--name-with-dashes`` on the CLI).
    kind : {"float", "int", "choice", "string", "file"}
    unit : str
        Unit of a number ("" when dimensionless).
    default : object
        Value when not given (None: not set; ``meaning`` says what happens).
    meaning : str
        One line for tables and ``--help``.
    choices : tuple of str
        Allowed values of a ``choice``.
    low, high : float
        Allowed range of a number; ``low_open`` / ``high_open`` exclude the ends.
    plugin_only : bool
        A rendering option of the Mitsuba plugin, not a property of the material.
    """

    name: str
    kind: str
    unit: str
    default: object
    meaning: str
    choices: tuple = ()
    low: float = -math.inf
    high: float = math.inf
    low_open: bool = False
    high_open: bool = False
    plugin_only: bool = False

    @property
    def allowed(self) -> str:
        """The allowed values as a short text (``(0, 1)``, ``circle, ellipse``, ``file``)."""
        if self.kind == "choice":
            return ", ".join(self.choices)
        if self.kind in ("float", "int"):
            lb = "(" if self.low_open else "["
            rb = ")" if self.high_open else "]"
            fmt = (lambda v: "∞" if v == math.inf else ("-∞" if v == -math.inf else f"{v:g}"))
            return f"{lb}{fmt(self.low)}, {fmt(self.high)}{rb}" + (" integer" if self.kind == "int" else "")
        return "file path" if self.kind == "file" else "text"

    def check(self, value):
        """``value`` converted to this parameter's type and checked, or one :class:`CoronaError`."""
        unit = f" {self.unit}" if self.unit else ""
        if self.kind == "choice":
            return check_choice(self.name, value, self.choices)
        if self.kind in ("string", "file"):
            if not isinstance(value, (str, bytes)) and not hasattr(value, "__fspath__"):
                raise CoronaError(f"{self.name}={value!r} is not a text; expected a {self.allowed}")
            return value
        if self.kind == "int":
            ok = not isinstance(value, bool)
            try:
                ok = ok and float(value).is_integer() and self.low <= float(value) <= self.high
            except (TypeError, ValueError, OverflowError):
                ok = False
            if not ok:
                raise CoronaError(f"{self.name}={value!r} is out of range; allowed integers "
                                  f">= {self.low:g} and <= {self.high:g}")
            return int(value)
        if isinstance(value, bool):
            raise CoronaError(f"{self.name}={value!r} is not a number; allowed {self.allowed}{unit}")
        if self.low == 0.0 and self.low_open and self.high == math.inf:
            return check_positive(self.name, value, self.unit)        # "a finite value > 0"
        return check_range(self.name, value, self.low, self.high, lo_open=self.low_open,
                           hi_open=self.high_open, unit=self.unit)


SHAPES = ("circle", "ellipse", "square", "rectangle", "polygon", "mask", "mixture", "sphere")
PROCESSES = ("poisson", "hard-disk", "rsa", "lattice-square", "lattice-hex", "points")
ORIENTATIONS = ("fixed", "random")
SIZE_DISTRIBUTIONS = ("lognormal", "schulz")
MODES = ("aperture", "particle")
SAMPLINGS = ("lobe", "cosine")
SUBSTRATES = ("none", "glass")
SUBSTRATE_SIDES = ("front", "back")
MAX_SIDES = 100_000

#: Every parameter of a corona layer, in the order of the tables.
PARAMETERS: tuple[Parameter, ...] = (
    Parameter("shape", "choice", "", "circle", "scatterer shape", SHAPES),
    Parameter("radius", "float", "µm", 0.5, "circle / sphere radius; ellipse semi-axis x; square/rectangle "
              "half-width; polygon circumradius", low=0.0, low_open=True, high_open=True),
    Parameter("ior", "float", "", None, "shape=sphere: refractive index n of the droplets relative to "
              "air; default water at 20 °C with its dispersion (Daimon & Masumura 2007)",
              low=0.0, low_open=True, high_open=True),
    Parameter("ior_imag", "float", "", 0.0, "shape=sphere: absorption index κ (m = n + iκ; needs ior)",
              low=0.0, high_open=True),
    Parameter("aspect", "float", "", 1.0, "ellipse / rectangle: extent along y over x",
              low=0.0, low_open=True, high_open=True),
    Parameter("sides", "int", "", 6, "polygon: number of sides", low=3, high=MAX_SIDES),
    Parameter("angle", "float", "degree", 0.0, "rotation of anisotropic shapes", low=-360.0, high=360.0),
    Parameter("filename", "file", "", None, "mask image (shape=mask), or point file (process=points "
              "with any other shape)"),
    Parameter("points_filename", "file", "", None, "point file of process=points; needed with "
              "shape=mask, where filename is the image"),
    Parameter("pixel_size", "float", "µm", None, "mask: size of one image pixel",
              low=0.0, low_open=True, high_open=True),
    Parameter("edge_width", "float", "µm", 0.0, "soft edge: std of a Gaussian apodisation",
              low=0.0, high_open=True),
    Parameter("orientation", "choice", "", "fixed", "fixed, or random (rotational average: radial lobe)",
              ORIENTATIONS),
    Parameter("size_spread", "float", "", 0.0, "relative std of the scatterer size", low=0.0, high=1.0),
    Parameter("size_distribution", "choice", "", "lognormal", "distribution of the size (with "
              "size_spread > 0)", SIZE_DISTRIBUTIONS),
    Parameter("area_fraction", "float", "", 0.3, "F_a = n |A|, the fraction of the layer covered",
              low=0.0, high=1.0, low_open=True, high_open=True),
    Parameter("process", "choice", "", "hard-disk", "point process of the centres", PROCESSES),
    Parameter("exclusion_diameter", "float", "µm", None, "hard-core diameter σ (hard-disk, rsa); "
              "default the shape's circumscribed diameter", low=0.0, low_open=True, high_open=True),
    Parameter("jitter", "float", "µm", 0.0, "lattice: rms displacement per axis", low=0.0, high_open=True),
    Parameter("mode", "choice", "", "aperture", "aperture: scatterers transmit in an opaque screen; "
              "particle: they block light in a clear layer", MODES),
    Parameter("albedo", "float", "", 0.0, "diffuse reflectance of the opaque part", low=0.0, high=1.0),
    Parameter("mixture", "string", "", None, "shape=mixture: 'SHAPE:RADIUS:WEIGHT, ...' (radius µm, "
              "number weights; decoupling approximation)"),
    Parameter("substrate", "choice", "", "none", "none, or glass: the layer sits on a thin "
              "non-absorbing pane (Fresnel reflection of both faces, thin-slab inter-reflections)",
              SUBSTRATES),
    Parameter("substrate_ior", "float", "", None, "index of refraction of the pane (substrate=glass); "
              "default 1.52", low=1.0, high_open=True),
    Parameter("substrate_side", "choice", "", "front", "face of the pane that carries the layer: front "
              "(+z, where the shading normal points) or back (-z)", SUBSTRATE_SIDES),
    Parameter("sampling", "choice", "", "lobe", "how the lobe is sampled: lobe (T_a T_s exactly) or "
              "cosine (for comparisons only)", SAMPLINGS, plugin_only=True),
)

#: The parameters by name.
SPEC: dict[str, Parameter] = {p.name: p for p in PARAMETERS}
#: Defaults of the material parameters (the plugin-only ones left out).
DEFAULTS = {p.name: p.default for p in PARAMETERS if not p.plugin_only}


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def markdown_table(plugin: bool = True) -> str:
    """The parameter table in Markdown (the README's)."""
    rows = ["| parameter | unit | default | allowed | meaning |", "|---|---|---|---|---|"]
    for p in PARAMETERS:
        if p.plugin_only and not plugin:
            continue
        default = "—" if p.default is None else f"`{p.default}`"
        rows.append(f"| `{p.name}` | {p.unit or '—'} | {default} | {_cell(p.allowed)} | {_cell(p.meaning)} |")
    return "\n".join(rows)


def rst_table() -> str:
    """The parameter table as a reStructuredText list-table (docstrings)."""
    lines = [".. list-table::", "   :header-rows: 1", "", "   * - parameter", "     - unit",
             "     - default", "     - allowed", "     - meaning"]
    for p in PARAMETERS:
        default = "—" if p.default is None else f"``{p.default}``"
        lines += [f"   * - ``{p.name}``", f"     - {p.unit or '—'}", f"     - {default}",
                  f"     - {p.allowed}", f"     - {p.meaning}"]
    return "\n".join(lines)


__doc__ = __doc__.replace("{table}", rst_table())


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
        # layer's lobe follows the decoupling approximation (docs/physics.md#the-model)
        # (types of weight 0 are left out: they would still set the exclusion diameter)
        return shapes.Mixture([(_modified(_outline(k, r, p), p), w)
                               for k, r, w in parse_mixture(p["mixture"]) if w > 0])
    if p.get("mixture"):
        raise CoronaError(f"mixture={p['mixture']!r} needs shape='mixture' (got shape={kind!r})")
    if kind != "sphere" and (p.get("ior") is not None or p.get("ior_imag")):
        raise CoronaError(f"ior={p.get('ior')!r}, ior_imag={p.get('ior_imag')!r} need shape='sphere' "
                          f"(got shape={kind!r})")
    if kind == "sphere":
        if p.get("ior") is None and p.get("ior_imag"):
            raise CoronaError(f"ior_imag={p['ior_imag']!r} needs ior=<real part> (the default, water, "
                              "does not absorb)")
        for name, off in (("edge_width", 0.0), ("orientation", "fixed")):
            if p[name] != off:
                raise CoronaError(f"{name}={p[name]!r} is out of range for shape='sphere'; allowed {off!r}")
        ior = None if p.get("ior") is None else complex(p["ior"], p.get("ior_imag") or 0.0)
        return _modified(shapes.Sphere(check_positive("radius", p["radius"], "µm"), ior=ior), p)
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
    """A :class:`corona.Material` from the named parameters of :data:`PARAMETERS`.

    Each value is checked against its specification (type, allowed values or
    range); None means "not given" (the default).

    Unknown names raise a :class:`corona.CoronaError` listing the known ones.
    """
    from .material import Material
    unknown = sorted(set(params) - set(DEFAULTS))
    if unknown:
        raise CoronaError(f"unknown parameter(s) {', '.join(unknown)}; known: {', '.join(sorted(DEFAULTS))}")
    p = {**DEFAULTS, **{k: SPEC[k].check(v) for k, v in params.items() if v is not None}}
    from .substrate import make_substrate
    substrate = make_substrate(p["substrate"], p["substrate_ior"], p["substrate_side"])
    shape = make_shape(p)
    process = make_process(p, shape)
    if p["shape"] == "sphere":   # droplets in air: particles; the mode given must say so
        from .sphere_material import SphereMaterial
        if p["process"] not in ("poisson", "hard-disk", "rsa"):
            raise CoronaError(f"process={p['process']!r} is out of range for shape='sphere'; allowed "
                              "poisson, hard-disk, rsa")
        return SphereMaterial(shape, process, mode=params.get("mode") or "particle", albedo=p["albedo"],
                              substrate=substrate)
    return Material(shape, process, mode=p["mode"], albedo=p["albedo"], substrate=substrate)


if __name__ == "__main__":   # python -m corona.parameters: the README's table
    print(markdown_table())
