"""The one parameter specification of a corona layer, and the material it builds.

:data:`PARAMETERS` lists every parameter once: name, type, unit, default,
allowed values and a one-line meaning.  The Mitsuba plugin reads its
properties through it (and its docstring table is generated from it), the
CLI's ``corona lobe`` options are generated from it, and the table of docs/parameters.md
is checked against it by the tests (``python -m corona.parameters`` prints
the Markdown table).  :func:`material_from_parameters` validates each value
here, at the boundary, with one clear error (name, value, allowed range).

{table}
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, replace

import corona.model.mie.material  # noqa: F401  (the built-in families register themselves at import)
import corona.model.processes  # noqa: F401
import corona.model.shapes  # noqa: F401
from corona._validation import CoronaError, check_choice, check_range
from corona.model import registry


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
    applies : tuple of str
        When the parameter is used: any one of the conditions ``"shape=ellipse"``,
        ``"process=points"``, ``"size_spread>0"`` suffices; empty: always.  A
        parameter given where none holds is ignored, with one
        :class:`corona.CoronaWarning` naming it (as Mitsuba warns about unused
        properties).
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
    applies: tuple = ()

    def applies_to(self, params: dict) -> bool:
        """True when this parameter is used by the layer described by ``params``."""
        for cond in self.applies:
            if ">" in cond:
                name, limit = cond.split(">")
                try:
                    if float(params.get(name) or 0.0) > float(limit):
                        return True
                except (TypeError, ValueError):
                    return True     # a bad value is reported by its own check
            else:
                name, value = cond.split("=")
                if params.get(name) == value:
                    return True
        return not self.applies

    @property
    def used_with(self) -> str:
        """The conditions of :attr:`applies` as a short text (``shape: ellipse, rectangle``)."""
        if not self.applies:
            return "all"
        groups: dict[str, list] = {}
        for cond in self.applies:
            if ">" in cond:
                groups.setdefault(cond.replace(">", " > "), [])
            else:
                name, value = cond.split("=")
                groups.setdefault(name, []).append(value)
        return "; ".join(f"{k}: {', '.join(v)}" if v else k for k, v in groups.items())

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
            ok = not _is_bool(value)
            try:
                ok = ok and float(value).is_integer() and self.low <= float(value) <= self.high
            except (TypeError, ValueError, OverflowError):
                ok = False
            if not ok:
                raise CoronaError(f"{self.name}={value!r} is out of range; allowed integers "
                                  f">= {self.low:g} and <= {self.high:g}")
            return int(value)
        if _is_bool(value):
            raise CoronaError(f"{self.name}={value!r} is not a number; allowed {self.allowed}{unit}")
        return check_range(self.name, value, self.low, self.high, lo_open=self.low_open,
                           hi_open=self.high_open, unit=self.unit)


def _is_bool(value) -> bool:
    import numpy as np
    return isinstance(value, (bool, np.bool_))


def _mixture_from(p: dict):
    """The factory of ``shape=mixture``: each component carries the edge / spread / orientation
    modifiers; the layer's lobe follows the decoupling approximation (docs/physics.md#the-model)
    (types of weight 0 are left out: they would still set the exclusion diameter)."""
    from corona.model import shapes
    comps = [(_check_size(_outline(k, r, p), {**p, "shape": k, "radius": r}), w)
             for k, r, w in parse_mixture(p["mixture"]) if w > 0]
    return shapes.Mixture([(_modified(sh, p), w) for sh, w in comps])


# the mixture of outlines is defined here, with its 'SHAPE:RADIUS:WEIGHT, ...' text
registry.add_shape(registry.ShapeFamily("mixture", _mixture_from, ("mixture",) + registry.FLAT + registry.ROTATABLE,
                                        of_components=True))


def _uses(name: str) -> tuple:
    """The ``applies`` conditions of a parameter of families: ``shape=X`` / ``process=Y`` for each
    registered family that reads ``name`` (:mod:`corona.model.registry`)."""
    shapes = registry.SHAPE_FAMILIES.values()
    # a mixture reads its components' parameters (their sizes are its own text's radii)
    of_parts = name != "radius" and any(name in f.parameters for f in shapes if f.mixable)
    return (tuple(f"shape={f.name}" for f in shapes if name in f.parameters or (f.of_components and of_parts))
            + tuple(f"process={f.name}" for f in registry.PROCESS_FAMILIES.values() if name in f.parameters))


#: The registered shape and process families (corona.model.registry), in their order of registration.
SHAPES = tuple(registry.SHAPE_FAMILIES)
PROCESSES = tuple(registry.PROCESS_FAMILIES)
ORIENTATIONS = ("fixed", "random")
SIZE_DISTRIBUTIONS = ("lognormal", "schulz")
MODES = ("aperture", "particle")
SAMPLINGS = ("lobe", "cosine")
SUBSTRATES = ("none", "glass", "mirror")
#: Largest refractive (and absorption) index accepted: above any dielectric at visible
#: wavelengths (diamond 2.42, rutile 2.9; silicon's n ≈ 4 is not transparent there).
IOR_MAX = 5.0
SUBSTRATE_SIDES = ("front", "back")
#: Largest circumradius of a scatterer [µm] (the length R of ``u = 2π R |d| / λ``).
#: The radial table (``tabulated.RADIAL_MAX_SAMPLES`` samples up to |d| = 2 at 360 nm)
#: has a step of 0.14 in u there, which resolves the Airy core (first zero at
#: u = 3.83) to 0.1 % in energy; at 1 mm the diffraction lobe is already narrower
#: than 0.03°, below what a render resolves (docs/physics.md).
RADIUS_MAX = 1000.0
#: Smallest radius [µm] (1 nm, far below where scalar diffraction means anything):
#: below ~1e-90 µm the area R² underflows and the lobe turns NaN.
RADIUS_MIN = 1e-3
#: Ellipse / rectangle aspect ratios: the 2D table spans |u| <= 64 along the
#: long axis, so more elongated shapes lose more of their lobe's energy outside
#: it than a square does (3 %; 6 % at aspect 10, 67 % at 100).
ASPECT_MIN, ASPECT_MAX = 0.2, 5.0
#: More sides than this: the regular polygon is the circle of equal area within the 2D table's
#: range (|u| <= 64) to 3.5e-4 of the lobe (L1 norm; 6e-3 at 20 sides): use shape=circle.
MAX_SIDES = 50
#: Relative std of the size: the s⁴-weighted sizes that dominate the lobe reach
#: 45 × the mean at 0.5 (lognormal, 1 - 1e-10 quantile), where a hard core built on
#: the mean shape no longer keeps them apart, and the table cost grows with them.
SIZE_SPREAD_MAX = 0.5
#: orientation=random: largest scatterer [µm] (circumradius × s_top, the 1 - 1e-7 quantile
#: of s p(s) up to which the size average resolves the lobe; 1 without a size spread): the
#: rotation average needs ~2.2 u R / symmetry angles at each of the radial table's u, a cost
#: ∝ (R_max / λ)² (benchmarks/bench_slow_inputs.py: about a minute for a mask here).
ROTATION_RADIUS_MAX = 25.0
#: size_spread > 0 with a fixed anisotropic shape (a 2D table): the size average at each
#: of the table's 131072 independent vertices costs (quadrature nodes) × (the shape's
#: cost: its number of edges, 1 for an ellipse, 2 for a rectangle, 8 for a mask);
#: above this many terms it is refused: about a minute of CPU at most (7e-8 s a term), half
#: that on two cores (the quadrature runs on every core; benchmarks/results/spread_limit.json).
SIZE_AVERAGE_WORK_MAX = 8e8
#: Largest lengths of the layer that are not sizes of the scatterer [µm].
LENGTH_MAX = 2 * RADIUS_MAX

_SHAPES_WITH_RADIUS = _uses("radius")
_ORIENTED = _uses("angle")
#: Every flat (Fraunhofer) scatterer: all but the Mie sphere.
_FLAT = _uses("edge_width")
_ANISOTROPIC = _uses("orientation")

#: Every parameter of a corona layer, in the order of the tables.
PARAMETERS: tuple[Parameter, ...] = (
    Parameter("shape", "choice", "", "circle", "scatterer shape", SHAPES),
    Parameter("radius", "float", "µm", 5.0, "circle / sphere radius; ellipse semi-axis x; square/rectangle "
              "half-width; polygon circumradius (the scatterer's circumradius must stay <= "
              f"{RADIUS_MAX:g} µm; a sphere's radius <= 25 µm, the Mie tables' range)", low=RADIUS_MIN, high=RADIUS_MAX, applies=_SHAPES_WITH_RADIUS),
    Parameter("ior", "float", "", None, "shape=sphere: refractive index n of the droplets relative to "
              "air; default water at 20 °C with its dispersion (Daimon & Masumura 2007)",
              low=0.0, high=IOR_MAX, low_open=True, applies=_uses("ior")),
    Parameter("ior_imag", "float", "", 0.0, "shape=sphere: absorption index κ (m = n + iκ; needs ior)",
              low=0.0, high=IOR_MAX, applies=_uses("ior_imag")),
    Parameter("aspect", "float", "", 1.0, "ellipse / rectangle: extent along y over x",
              low=ASPECT_MIN, high=ASPECT_MAX,
              applies=_uses("aspect")),
    Parameter("sides", "int", "", 6, "polygon: number of sides", low=3, high=MAX_SIDES,
              applies=_uses("sides")),
    Parameter("angle", "float", "degree", 0.0, "rotation of anisotropic shapes", low=-360.0, high=360.0,
              applies=_ORIENTED),
    Parameter("filename", "file", "", None, "mask image (shape=mask), or point file (process=points "
              "with any other shape)", applies=_uses("filename")),
    Parameter("points_filename", "file", "", None, "point file of process=points; needed with "
              "shape=mask, where filename is the image", applies=_uses("points_filename")),
    Parameter("pixel_size", "float", "µm", None, "mask: size of one image pixel",
              low=RADIUS_MIN, high=RADIUS_MAX, applies=_uses("pixel_size")),
    Parameter("edge_width", "float", "µm", 0.0, "soft edge: std of a Gaussian apodisation "
              "(at most the scatterer's circumradius)", low=0.0, high=RADIUS_MAX, applies=_FLAT),
    Parameter("orientation", "choice", "", "fixed", "fixed, or random (rotational average: radial lobe; "
              f"scatterers up to {ROTATION_RADIUS_MAX:g} µm including the largest of a size spread)",
              ORIENTATIONS, applies=_ANISOTROPIC),
    Parameter("size_spread", "float", "", 0.0, "relative std of the scatterer size", low=0.0,
              high=SIZE_SPREAD_MAX),
    Parameter("size_distribution", "choice", "", "lognormal", "distribution of the size (with "
              "size_spread > 0)", SIZE_DISTRIBUTIONS, applies=("size_spread>0",)),
    Parameter("area_fraction", "float", "", 0.4, "F_a = n |A|, the fraction of the layer covered",
              low=0.0, high=1.0, low_open=True, high_open=True,
              applies=_uses("area_fraction")),
    Parameter("process", "choice", "", "hard-disk", "point process of the centres", PROCESSES),
    Parameter("exclusion_diameter", "float", "µm", None, "hard-core diameter σ (hard-disk, rsa); "
              "default the shape's circumscribed diameter", low=0.0, high=LENGTH_MAX, low_open=True,
              applies=_uses("exclusion_diameter")),
    Parameter("jitter", "float", "µm", 0.0, "lattice: rms displacement per axis", low=0.0, high=LENGTH_MAX,
              applies=_uses("jitter")),
    Parameter("mode", "choice", "", "particle", "aperture: scatterers transmit in an opaque screen; "
              "particle: they block light in a clear layer", MODES),
    Parameter("albedo", "float", "", 0.0, "diffuse reflectance of the opaque part", low=0.0, high=1.0,
              applies=_uses("albedo")),
    Parameter("mixture", "string", "", None, "shape=mixture: 'SHAPE:RADIUS:WEIGHT, ...' (radius µm, "
              "number weights; decoupling approximation)", applies=_uses("mixture")),
    Parameter("substrate", "choice", "", "none", "none; glass: the layer sits on a thin non-absorbing pane "
              "(Fresnel reflection of both faces, thin-slab inter-reflections); mirror: on the front face of "
              "a back-silvered pane", SUBSTRATES),
    Parameter("substrate_ior", "float", "", None, "index of refraction of the pane (substrate=glass, "
              "mirror); default 1.52", low=1.0, high=IOR_MAX, applies=("substrate=glass", "substrate=mirror")),
    Parameter("substrate_side", "choice", "", "front", "face of the pane that carries the layer: front "
              "(+z, where the shading normal points) or back (-z)", SUBSTRATE_SIDES,
              applies=("substrate=glass",)),
    Parameter("substrate_thickness", "float", "µm", None, "thickness of the pane: the two passes through the "
              "layer interfere (Quetelet rings); default 4000 for mirror, none (incoherent) for glass",
              low=50.0, high=1.0e5, applies=("substrate=glass", "substrate=mirror")),
    Parameter("mirror_reflectance", "float", "", None, "reflectance of the silvering seen from inside the "
              "glass: a number, a metal (silver, aluminium, gold, copper: its tabulated spectrum) or a "
              "spectrum ('nm:value, ...' text, or in the plugin a <spectrum>); default 0.97 (silver "
              "behind glass at normal incidence)", low=0.0, high=1.0,
              applies=("substrate=mirror",)),
    Parameter("sampling", "choice", "", "lobe", "how the lobe is sampled: lobe (T_a T_s exactly) or "
              "cosine (for comparisons only)", SAMPLINGS, plugin_only=True),
)

#: The parameters by name.
SPEC: dict[str, Parameter] = {p.name: p for p in PARAMETERS}
#: Defaults of the material parameters (the plugin-only ones left out).
DEFAULTS = {p.name: p.default for p in PARAMETERS if not p.plugin_only}
#: The parameters whose ``applies`` name families: kept in step with the registry.
_FAMILY_SCOPED = {p.name for p in PARAMETERS if any(c.startswith(("shape=", "process=")) for c in p.applies)}


def _on_register(family) -> None:
    """Keep the spec in step with a family registered after this module (a user's): the shape /
    process choices, the ``applies`` of the parameters it reads, the parameters it brings."""
    global SHAPES, PROCESSES, PARAMETERS, MIXTURE_SHAPES
    news = tuple(q if isinstance(q, Parameter) else Parameter(**q) for q in family.new_parameters)
    for new in news:
        old = SPEC.get(new.name)
        if old is not None and replace(old, applies=()) != replace(new, applies=()):
            raise CoronaError(f"{family.name}: parameter {new.name!r} clashes with the spec's {new.name!r} "
                              f"({old.meaning}); give it another name, or the name alone to read the spec's")
    for name in family.parameters:
        if name not in SPEC and name not in {q.name for q in news}:
            raise CoronaError(f"{family.name}: parameter {name!r} is not in the spec; give a "
                              "corona.parameters.Parameter for it (known: " + ", ".join(sorted(SPEC)) + ")")
    PARAMETERS = PARAMETERS + tuple(q for q in news if q.name not in SPEC)
    _FAMILY_SCOPED.update(q.name for q in news)
    SHAPES, PROCESSES = tuple(registry.SHAPE_FAMILIES), tuple(registry.PROCESS_FAMILIES)
    MIXTURE_SHAPES = tuple(f.name for f in registry.SHAPE_FAMILIES.values() if f.mixable)
    fresh = []
    for p in PARAMETERS:
        if p.name == "shape":
            p = replace(p, choices=SHAPES)
        elif p.name == "process":
            p = replace(p, choices=PROCESSES)
        elif p.name in _FAMILY_SCOPED:
            own = tuple(c for c in p.applies if not c.startswith(("shape=", "process=")))
            p = replace(p, applies=own + _uses(p.name))
        fresh.append(p)
    PARAMETERS = tuple(fresh)
    SPEC.update((p.name, p) for p in PARAMETERS)      # in place: the modules holding SPEC see it
    DEFAULTS.update((p.name, p.default) for p in PARAMETERS if not p.plugin_only and p.name not in DEFAULTS)


registry.listen(_on_register)
for _family in (*registry.SHAPE_FAMILIES.values(), *registry.PROCESS_FAMILIES.values()):
    if _family.new_parameters:        # a user's family registered before this module was imported
        _on_register(_family)


def _cell(text: str) -> str:
    return text.replace("|", "\\|")


def markdown_table(plugin: bool = True) -> str:
    """The parameter table in Markdown (docs/parameters.md's)."""
    rows = ["| parameter | unit | default | allowed | used with | meaning |", "|---|---|---|---|---|---|"]
    for p in PARAMETERS:
        if p.plugin_only and not plugin:
            continue
        default = "—" if p.default is None else f"`{p.default}`"
        rows.append(f"| `{p.name}` | {p.unit or '—'} | {default} | {_cell(p.allowed)} | {_cell(p.used_with)} "
                    f"| {_cell(p.meaning)} |")
    return "\n".join(rows)


def rst_table() -> str:
    """The parameter table as a reStructuredText list-table (docstrings)."""
    lines = [".. list-table::", "   :header-rows: 1", "", "   * - parameter", "     - unit",
             "     - default", "     - allowed", "     - used with", "     - meaning"]
    for p in PARAMETERS:
        default = "—" if p.default is None else f"``{p.default}``"
        lines += [f"   * - ``{p.name}``", f"     - {p.unit or '—'}", f"     - {default}",
                  f"     - {p.allowed}", f"     - {p.used_with}", f"     - {p.meaning}"]
    return "\n".join(lines)


__doc__ = __doc__.replace("{table}", rst_table())


#: The shapes a mixture may hold (the families registered ``mixable``).
MIXTURE_SHAPES = tuple(f.name for f in registry.SHAPE_FAMILIES.values() if f.mixable)


def _checked(family, p: dict) -> dict:
    """``p`` with the values of the parameters ``family`` reads checked by their spec (None: not
    given, left as it is)."""
    return {**p, **{k: SPEC[k].check(p[k]) for k in family.parameters if p.get(k) is not None and k in SPEC
                    and k != "mirror_reflectance"}}


def _outline(kind: str, r: float, p: dict):
    """The bare shape ``kind`` of size ``r`` [µm] (aspect, sides, angle from ``p``)."""
    # the Python classes take the plugin's parameters as they are (radius, aspect, angle [degree])
    family = registry.shape_family(kind)
    return family.factory(_checked(family, {**p, "radius": r}))


def parse_mixture(spec) -> list[tuple[str, float, float]]:
    """``"circle:5:0.5, square:4.43:0.5"`` -> [(shape, radius µm, number weight), ...].

    The weights are returned relative to the largest (so that even weights near
    the float maximum sum to a finite total).
    """
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
        out.append((kind, check_range("mixture radius", r, RADIUS_MIN, RADIUS_MAX, unit="µm"),
                    check_range("mixture weight", w, 0.0, math.inf, hi_open=True)))
    top = max(w for _, _, w in out)
    if top <= 0:
        raise CoronaError(f"mixture={spec!r}: the number weights are all 0; at least one must be > 0")
    return [(k, r, w / top) for k, r, w in out]


def _modified(base, p: dict):
    """``base`` with the soft edge, random orientation and size spread of ``p``.

    The size average is outermost: averaging the rotated shape over sizes gives
    the same ensemble as rotating the size-averaged one (size and orientation are
    independent), and needs far fewer evaluations (the rotation average resolves
    the shape at its own size, not at the largest size of the distribution).
    """
    from corona.model import shapes
    w = SPEC["edge_width"].check(p["edge_width"])
    if w > base.length_scale * (1 + 1e-12):
        raise CoronaError(f"edge_width={p['edge_width']!r} µm is out of range for {base!r}; allowed "
                          f"[0, {base.length_scale:.4g}] µm (at most the circumradius: a wider blur is no "
                          "longer an edge)")
    if w > 0:
        base = shapes.SoftEdge(base, w)
    spread = SPEC["size_spread"].check(p["size_spread"])
    rotate = check_choice("orientation", p["orientation"], ORIENTATIONS) == "random" and not base.isotropic
    if rotate:
        base = shapes.RandomOrientation(base)
    if spread > 0:
        dist = check_choice("size_distribution", p["size_distribution"], SIZE_DISTRIBUTIONS)
        base = shapes.SizeDistribution(base, spread, distribution=dist)
    if rotate:
        largest = base.length_scale * (base._s_top if spread > 0 else 1.0)
        if largest > ROTATION_RADIUS_MAX * (1 + 1e-12):
            of = f" × {base._s_top:.3g} (size_spread={spread:g})" if spread > 0 else ""
            of = f"{of} = {largest:.4g} µm" if spread > 0 else ""
            raise CoronaError(f"orientation='random': the largest scatterers, circumradius {base.length_scale:.4g} µm"
                              f"{of}, are out of range; allowed <= {ROTATION_RADIUS_MAX:g} µm "
                              "(or orientation='fixed')")
    return base


def _check_size(shape, p: dict):
    """``shape`` if its circumradius is at most :data:`RADIUS_MAX`, else one clear error."""
    R = float(shape.length_scale)
    if not R <= RADIUS_MAX * (1 + 1e-12):
        given = {k: p[k] for k in ("radius", "aspect", "pixel_size", "mixture") if SPEC[k].applies_to(p)}
        what = ", ".join(f"{k}={v!r}" for k, v in given.items())
        raise CoronaError(f"shape={p['shape']!r} with {what}: the circumradius {R:.6g} µm is out of range; "
                          f"allowed <= {RADIUS_MAX:g} µm")
    return shape


def _size_average_work(shape) -> float:
    """Terms of the size averages over a 2D table (see :data:`SIZE_AVERAGE_WORK_MAX`)."""
    from corona.model import tabulated
    from corona.model import shapes
    if isinstance(shape, shapes.Mixture):
        return sum(_size_average_work(sh) for sh, _ in shape.components)
    if shape.isotropic:
        return 0.0              # a radial table: log-grid size average, cheap
    if isinstance(shape, shapes.SizeDistribution):
        R = shape.length_scale
        q_max = math.sqrt(2.0) * min(tabulated.u_max_for(R), 0.25 * tabulated.GRID2D_SIZE / 2) / R
        vertices = tabulated.GRID2D_SIZE ** 2 / 2
        return vertices * len(shape._nodes(q_max)[0]) * shape.shape._cost
    if isinstance(shape, shapes.SoftEdge):
        return _size_average_work(shape.shape)
    return 0.0


def make_shape(p: dict):
    shape = _make_shape(p)
    work = _size_average_work(shape)
    if work > SIZE_AVERAGE_WORK_MAX:
        what = ", ".join(f"{k}={p[k]!r}" for k in ("shape", "sides", "size_spread", "size_distribution")
                         if SPEC[k].applies_to(p))
        raise CoronaError(f"{what} with orientation='fixed': the size average over the 2D lobe table needs "
                          f"{work:.3g} terms; allowed <= {SIZE_AVERAGE_WORK_MAX:.3g} (use fewer sides, a smaller "
                          "size_spread, or orientation='random')")
    return shape


def _make_shape(p: dict):
    from corona.model import shapes
    if isinstance(p["shape"], shapes.Shape):    # an instance: complete as given (corona.scatterer)
        p = {**p, "edge_width": DEFAULTS["edge_width"], "orientation": DEFAULTS["orientation"]}
        return _modified(_check_size(p["shape"], p), p)
    kind = check_choice("shape", p["shape"], SHAPES)
    family = registry.shape_family(kind)
    SPEC["angle"].check(p["angle"])
    # values that only another family reads: an error (a warning would hide a wrong shape)
    for name, needs in (("mixture", p.get("mixture")), ("ior", p.get("ior") is not None or p.get("ior_imag"))):
        if needs and not SPEC[name].applies_to(p):
            given = (f"mixture={p['mixture']!r}" if name == "mixture"
                     else f"ior={p.get('ior')!r}, ior_imag={p.get('ior_imag')!r}")
            need = " or ".join(f"shape={c.split('=')[1]!r}" for c in SPEC[name].applies)
            raise CoronaError(f"{given} need{'s' if name == 'mixture' else ''} {need} (got shape={kind!r})")
    p = _checked(family, p)
    # the soft edge and the random orientation of a family that does not read them (a Mie sphere:
    # a sharp surface, the same from every side) are off: a given value got the unused warning
    p = {**p, **{k: DEFAULTS[k] for k in ("edge_width", "orientation") if not SPEC[k].applies_to(p)}}
    base = family.factory(p)
    if isinstance(base, shapes.Mixture):       # its components carry the modifiers
        return base
    return _modified(_check_size(base, p), p)


def make_process(p: dict, shape):
    from corona.model.processes import Process
    if isinstance(p["process"], Process):       # an instance, as given
        return p["process"]
    family = registry.process_family(check_choice("process", p["process"], PROCESSES))
    return family.factory(_checked(family, p), shape)


def unused_parameters(given, p: dict) -> list[str]:
    """The names in ``given`` that the layer ``p`` (all parameters) does not use."""
    # a shape instance (corona.scatterer) is complete; the layer's albedo still applies to it
    keep = () if isinstance(p.get("shape"), str) else ("albedo",)
    return [k for k in given if k in SPEC and not SPEC[k].applies_to(p) and k not in keep]


def warn_unused(given, p: dict, stacklevel: int = 3) -> None:
    """One :class:`corona.CoronaWarning` naming the parameters of ``given`` that
    the layer ``p`` ignores (e.g. ``aspect`` with a circle), as Mitsuba does for
    unused properties."""
    unused = unused_parameters(given, p)
    if unused:
        from corona._validation import CoronaWarning
        why = "; ".join(f"{k} (used with {SPEC[k].used_with})" for k in unused)
        warnings.warn(f"unused parameter(s) with shape={p['shape']!r}, process={p['process']!r}: {why}; "
                      "ignored", CoronaWarning, stacklevel=stacklevel)


def _check_given(name, value):
    """A given value checked by its spec; ``mirror_reflectance`` may also be a metal's name or a
    spectrum (``'λ:value, ...'`` text or a (wavelengths, values) pair: :class:`corona.Mirror`)."""
    import numpy as np
    from corona.model.processes import Process
    from corona.model.shapes import Shape
    if name == "mirror_reflectance" and (isinstance(value, str) or np.ndim(value) > 0):
        return value
    if name in ("shape", "process") and isinstance(value, Shape if name == "shape" else Process):
        return value              # an instance (corona.scatterer; the model's own classes)
    return SPEC[name].check(value)


def material_from_parameters(**params):
    """A :class:`corona.Material` from the named parameters of :data:`PARAMETERS`.

    Each value is checked against its specification (type, allowed values or
    range); None means "not given" (the default).  Given parameters that the
    chosen shape or process does not use (``aspect`` with a circle, ``jitter``
    with hard disks, ...) are ignored with one :class:`corona.CoronaWarning`
    naming them.

    Unknown names raise a :class:`corona.CoronaError` listing the known ones.
    """
    from corona.model.material import Material
    unknown = sorted(set(params) - set(DEFAULTS))
    if unknown:
        raise CoronaError(f"unknown parameter(s) {', '.join(unknown)}; known: {', '.join(sorted(DEFAULTS))}")
    given = {k: v for k, v in params.items() if v is not None}
    p = {**DEFAULTS, **{k: _check_given(k, v) for k, v in given.items()}}
    from corona.model.substrate import make_substrate
    substrate = make_substrate(p["substrate"], p["substrate_ior"], p["substrate_side"],
                               p["substrate_thickness"], p["mirror_reflectance"])
    shape = make_shape(p)
    process = make_process(p, shape)
    family = registry.shape_family(p["shape"]) if isinstance(p["shape"], str) else None
    if family is not None and family.material is not None:      # a layer of its own (the Mie sphere's)
        material = family.material(shape, process, p, params, substrate)
    else:
        material = Material(shape, process, mode=p["mode"], albedo=p["albedo"], substrate=substrate)
    warn_unused(given, p)
    return material


if __name__ == "__main__":   # python -m corona.parameters: docs/parameters.md's table
    print(markdown_table())
