"""What the designer computes: parameters from a query, the corona around a light,
the T_a / T_s / lobe profiles, the energy split, the exports and the kernel (PSF).

Web-free (numpy, the corona package, Pillow for PNG): the server in
:mod:`corona.apps.designer.app` only parses requests and calls these functions, so
they are tested and benchmarked without a server.

The picture (docs/physics.md, the model): a light of black-body spectrum
``L_s(λ)``, scaled to luminance 1, of angular diameter ``a``, is seen through
the layer at normal incidence.  In the small-angle approximation the radiance
around it, relative to the light's own, is

    L(ω) / L_s = T_c · 1[ω ∈ disk] + (f ⊛ 1_disk)(ω),     f = F_a T_a T_s,

with ``T_c`` the coherent transmittance and ``f`` the lobe [1/sr] at
``d = ω``.  Each pixel integrates its spectrum against the CIE 1931 colour
matching functions to linear sRGB (:mod:`corona.color`); the exposure in
stops scales it before the sRGB transfer curve (0 EV: the light's own
radiance, without the layer, is white).
"""
from __future__ import annotations

import io
import math
import os
import re
import shlex
import threading
import weakref
from collections import OrderedDict

import numpy as np
from scipy import special

from corona.model import tabulated
from corona._validation import CoronaError
from corona.color import blackbody, spectrum_to_linear_srgb, tonemap_srgb
from corona.parameters import DEFAULTS, PARAMETERS, SPEC, Parameter, material_from_parameters

# ----------------------------------------------------------------------
# the designer's own parameters: the light and the view
# ----------------------------------------------------------------------
#: The light and the view (same fields as :data:`corona.parameters.PARAMETERS`).
VIEW_PARAMETERS: tuple[Parameter, ...] = (
    Parameter("temperature", "float", "K", 3000.0, "colour temperature of the light (black body)",
              low=1000.0, high=40000.0),
    Parameter("light_size", "float", "degree", 0.3, "angular diameter of the light",
              low=0.0, high=10.0, low_open=True),
    Parameter("exposure", "float", "EV", None, "exposure in stops (0: the light itself is white); "
              "empty: automatic", low=-20.0, high=40.0),
    Parameter("field", "float", "degree", None, "half-width of the view; empty: the first rings",
              low=0.01, high=60.0),
    Parameter("size", "int", "pixel", 256, "width and height of the picture", low=32, high=512),
    Parameter("preview", "int", "", 0, "1: while a slider moves, an anisotropic (2-D) picture at half "
              "the pixels per axis (the page scales it up and says so; the exact picture follows "
              "when the slider is let go); 0: the exact picture", low=0, high=1),
)
VIEW_SPEC = {p.name: p for p in VIEW_PARAMETERS}

#: Kernel (PSF) export options (empty: sized from the lobe, :func:`kernel_plan`).
KERNEL_PARAMETERS: tuple[Parameter, ...] = (
    Parameter("pixel_scale", "float", "degree", None, "angle per pixel of the kernel; empty: sized from "
              "the lobe", low=1e-4, high=1.0),
    Parameter("kernel_size", "int", "pixel", None, "width and height of the kernel (odd); empty: sized "
              "from the lobe", low=3, high=1023),
)
KERNEL_SPEC = {p.name: p for p in KERNEL_PARAMETERS}
#: Largest half-width of a kernel [degree] (its pixels are even in angle; beyond, grazing directions).
KERNEL_MAX_HALF_WIDTH = 80.0
#: Share of the lobe's energy a kernel should hold: below it the page warns.
KERNEL_SHARE_MIN = 0.99
#: Share a kernel sized from the lobe aims at (a margin over :data:`KERNEL_SHARE_MIN` for the
#: pixel quadrature), its smallest and largest default size [pixel], and its pixels per ring.
KERNEL_SHARE_TARGET = 0.995
KERNEL_SIZE_MIN, KERNEL_SIZE_MAX = 255, 1023
KERNEL_PIXELS_PER_RING = 8

#: Upper bounds the designer adds to the specification's ranges, so that no
#: request can ask for unbounded work (a server must answer every request in time).
LIMITS = {"radius": 1000.0, "exclusion_diameter": 4000.0, "jitter": 1000.0, "edge_width": 100.0,
          "pixel_size": 100.0, "sides": 64, "aspect": 100.0}
MIXTURE_MAX_CHARS = 400

#: Slider ranges of the page (the number boxes accept the whole allowed range).
SLIDERS = {
    "radius": (0.2, 100.0, True), "aspect": (0.1, 10.0, True), "sides": (3, 24, False),
    "angle": (-180.0, 180.0, False), "pixel_size": (0.01, 10.0, True), "edge_width": (0.0, 5.0, False),
    "size_spread": (0.0, 0.5, False), "area_fraction": (0.01, 0.9, False),
    "exclusion_diameter": (0.4, 200.0, True), "jitter": (0.0, 20.0, False), "albedo": (0.0, 1.0, False),
    "temperature": (1500.0, 12000.0, False), "light_size": (0.01, 5.0, True),
    "exposure": (-5.0, 25.0, False), "field": (0.1, 45.0, True), "size": (64, 512, False),
    "pixel_scale": (0.001, 0.2, True), "kernel_size": (33, 1023, False),
    "breath_time": (5.0, 80.0, True), "contact_angle": (10.0, 90.0, False), "dry_time": (0.0, 60.0, False),
    "evaporation_rate": (0.01, 10.0, True),
}

#: Looks to start from (the scenes of scenes/ they come from).
PRESETS = {
    "fogged window": {
        "about": "water droplets of 5 µm on a window pane (scenes/teaser.xml)",
        "material": {"shape": "circle", "radius": 5.0, "area_fraction": 0.4, "process": "hard-disk",
                     "mode": "particle"},
        "view": {"temperature": 3000.0, "light_size": 0.3, "field": 10.0}},
    "lycopodium 10×": {
        "about": "lycopodium spores of 30 µm on a glass slide, 16° across (scenes/lycopodium.xml)",
        "material": {"shape": "circle", "radius": 15.0, "size_spread": 0.05, "area_fraction": 0.35,
                     "process": "rsa", "mode": "particle"},
        "view": {"temperature": 3200.0, "light_size": 0.12, "field": 8.0}},
    "breath on a pane": {
        "about": "a breath figure 20 s after the breath: droplets grown and merged (scenes/breath_figure.xml)",
        "material": {"shape": "circle", "process": "breath-figure", "breath_time": 20.0, "mode": "particle"},
        "view": {"temperature": 2100.0, "light_size": 0.3, "field": 10.0}},
    "voile fabric": {
        "about": "square pores of 40 µm on a jittered lattice: a curtain (scenes/fabric.xml)",
        "material": {"shape": "square", "radius": 20.0, "area_fraction": 0.25,
                     "process": "lattice-square", "jitter": 4.0, "mode": "aperture"},
        "view": {"temperature": 3000.0, "light_size": 0.18, "field": 3.0}},
}

#: Wavelengths of the pictures [nm] (the visible range of the CIE functions).
N_WAVELENGTHS = 48
WAVELENGTHS = np.linspace(max(380.0, tabulated.WAVELENGTH_MIN), 780.0, N_WAVELENGTHS)
N_WAVELENGTHS_2D = 24          # anisotropic pictures evaluate the 2-D table per pixel and λ
RING_WAVELENGTHS = (450.0, 550.0, 650.0)
PROFILE_WAVELENGTH = 550.0

#: Uploads are referred to by this id (a content hash and a kind-dependent suffix).
UPLOAD_ID = re.compile(r"^[0-9a-f]{32}\.(png|jpg|txt|csv|npy)$")


def _limit_error(p: Parameter, value, limit) -> CoronaError:
    unit = f" {p.unit}" if p.unit else ""
    lo = p.allowed.split(",")[0]
    return CoronaError(f"{p.name}={value!r} is out of range for the designer; allowed {lo}, {limit:g}]{unit}")


def _number(x):
    """A number for JSON: ±inf as None (JSON has no infinity)."""
    return None if isinstance(x, float) and math.isinf(x) else x


def parameter_json(p: Parameter) -> dict:
    """One :class:`corona.parameters.Parameter` whole, as JSON: every field of the dataclass
    (``applies`` the conditions of :meth:`corona.parameters.Parameter.applies_to`), plus its
    ``allowed`` and ``used_with`` texts."""
    import dataclasses
    d = {f.name: getattr(p, f.name) for f in dataclasses.fields(p)}
    d.update(choices=list(p.choices), applies=list(p.applies), low=_number(p.low), high=_number(p.high),
             allowed=p.allowed, used_with=p.used_with)
    return d


def spec_json() -> dict:
    """The parameters of the page: the material's (from the one specification), the
    light and view, the kernel export, slider ranges and presets (GET /api/parameters)."""
    def one(p: Parameter, group: str) -> dict:
        d = {"name": p.name, "kind": p.kind, "unit": p.unit, "default": p.default,
             "meaning": p.meaning, "allowed": p.allowed, "group": group,
             "choices": list(p.choices) if p.kind == "choice" else None,
             "applies": list(p.applies), "used_with": p.used_with}
        if p.name in TEXT_OR_NUMBER:
            from corona.model.substrate import METALS
            d["text"] = TEXT_OR_NUMBER[p.name].format(metals=", ".join(METALS))
            d["suggestions"] = list(dict.fromkeys(METALS))
        if p.kind in ("float", "int"):
            lo = None if p.low == -math.inf else p.low
            hi = None if p.high == math.inf else p.high
            if p.name in LIMITS and (hi is None or LIMITS[p.name] < hi):
                hi = LIMITS[p.name]
            d.update(low=lo, high=hi, low_open=p.low_open, high_open=p.high_open and hi == p.high)
            if p.name in SLIDERS:
                lo_s, hi_s, log = SLIDERS[p.name]
                d["slider"] = {"low": lo_s, "high": hi_s, "log": log}
        return d

    out = [one(p, "material") for p in PARAMETERS if not p.plugin_only]
    out += [one(p, "light") for p in VIEW_PARAMETERS if p.name != "preview"]   # the page sets preview itself
    out += [one(p, "kernel") for p in KERNEL_PARAMETERS]
    return {"parameters": out, "spec": [parameter_json(p) for p in PARAMETERS], "presets": PRESETS,
            "ring_wavelengths": list(RING_WAVELENGTHS), "profile_wavelength": PROFILE_WAVELENGTH}


# ----------------------------------------------------------------------
# parsing
# ----------------------------------------------------------------------
def parse(query: dict, upload_dir: str | None = None) -> tuple[dict, dict, dict]:
    """Split a request's parameters into (material, view, kernel) values, each checked.

    ``query`` maps names to strings (or values); an empty string means "not
    given".  Material values are checked against :data:`corona.parameters.PARAMETERS`
    and the designer's :data:`LIMITS`; ``filename`` / ``points_filename`` are
    upload ids, resolved inside ``upload_dir`` only.  Unknown names raise
    :class:`corona.CoronaError`.
    """
    material, view, kernel = {}, {}, {}
    known = set(DEFAULTS) | set(VIEW_SPEC) | set(KERNEL_SPEC)
    unknown = sorted(set(query) - known)
    if unknown:
        raise CoronaError(f"unknown parameter(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}")
    for name, raw in query.items():
        if raw is None or (isinstance(raw, str) and raw.strip() == ""):
            continue
        value = raw.strip() if isinstance(raw, str) else raw
        spec = VIEW_SPEC.get(name) or KERNEL_SPEC.get(name) or SPEC[name]
        if spec.kind in ("float", "int") and isinstance(value, str):
            try:
                value = float(value)          # messages then show the number, not its text
            except ValueError:
                pass
        if name in VIEW_SPEC:
            view[name] = VIEW_SPEC[name].check(value)
        elif name in KERNEL_SPEC:
            kernel[name] = KERNEL_SPEC[name].check(value)
        else:
            p = SPEC[name]
            if p.kind == "file":
                material[name] = _upload_path(name, value, upload_dir)
                continue
            if p.kind == "string" and len(str(value)) > MIXTURE_MAX_CHARS:
                raise CoronaError(f"{name} is {len(str(value))} characters long; allowed at most "
                                  f"{MIXTURE_MAX_CHARS} for the designer")
            if name in TEXT_OR_NUMBER and isinstance(value, str):
                material[name] = _text_value(name, value)
                continue
            v = p.check(value)
            if name in LIMITS and v > LIMITS[name]:
                raise _limit_error(p, value, LIMITS[name])
            material[name] = v
    if "kernel_size" in kernel and kernel["kernel_size"] % 2 == 0:
        raise CoronaError(f"kernel_size={kernel['kernel_size']} is even; allowed odd integers in [3, 1023] "
                          "(the light sits on the centre pixel)")
    return material, view, kernel


#: Numbers that may also be a text (as the plugin takes them): a metal's name or a spectrum.
TEXT_OR_NUMBER = {"mirror_reflectance": "a number in [0, 1], a metal ({metals}) or a spectrum "
                                        "'nm:value, ...'"}


def _text_value(name: str, value: str) -> str:
    """``mirror_reflectance`` as text: a metal of :data:`corona.model.substrate.METALS` or a
    ``'nm:value, ...'`` spectrum, checked here as :class:`corona.Mirror` will read it."""
    from corona.model.substrate import METALS, Mirror
    if len(value) > MIXTURE_MAX_CHARS:
        raise CoronaError(f"{name} is {len(value)} characters long; allowed at most {MIXTURE_MAX_CHARS} "
                          "for the designer")
    Mirror(reflectance=value.strip().lower() if value.strip().lower() in METALS else value)   # one line if bad
    return value


def check_fov(fov) -> float:
    """The horizontal field of view of a photograph [degree], in (0, 180)."""
    from corona._validation import check_range
    if fov is None or fov == "":
        raise CoronaError("fov is missing; give the photograph's horizontal field of view in degrees, in (0, 180)")
    return check_range("fov", fov, 0.0, 180.0, lo_open=True, hi_open=True, unit="degree")


def _upload_path(name: str, value, upload_dir: str | None) -> str:
    value = str(value)
    if upload_dir is None or not UPLOAD_ID.match(value):
        raise CoronaError(f"{name}={value!r} is not an uploaded file; upload it first "
                          "(POST /api/upload) and pass the id it returns")
    path = os.path.join(upload_dir, value)
    if not os.path.isfile(path):
        raise CoronaError(f"{name}={value!r}: no such upload (uploads live as long as the cache)")
    return path


# ----------------------------------------------------------------------
# materials (kept in memory: moving a slider back costs nothing)
# ----------------------------------------------------------------------
class _LRU:
    def __init__(self, size: int):
        self.size, self.data, self.lock = size, OrderedDict(), threading.Lock()

    def get(self, key, make):
        with self.lock:
            if key in self.data:
                self.data.move_to_end(key)
                return self.data[key]
        value = make()
        with self.lock:
            self.data[key] = value
            while len(self.data) > self.size:
                self.data.popitem(last=False)
        return value


_materials = _LRU(24)
_profiles: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()   # material -> _LRU
_profiles_lock = threading.Lock()


def material(params: dict):
    """The :class:`corona.Material` of checked ``params`` (memory LRU; its tables
    stay out of the on-disk cache, which a slider would fill with one table per step)."""
    key = tuple(sorted((k, v) for k, v in params.items()))

    def make():
        m = material_from_parameters(**params)
        m.use_cache = False
        return m
    return _materials.get(key, make)


# ----------------------------------------------------------------------
# a new sphere radius: a preview at once, the exact Mie table in the background
# ----------------------------------------------------------------------
_previews = _LRU(8)
_preview_lock = threading.Lock()        # previews are built one at a time (a fraction of a second each)
_exact_locks: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()   # material -> Lock


def exact_ready(m) -> bool:
    """Whether ``m``'s tables are ready for an exact answer at once: always, except for a sphere
    layer whose exact Mie rows (:meth:`corona.model.mie.material.SphereMaterial.rows_cached`) and their
    totals are not built yet (a new radius: seconds to a minute)."""
    return not _is_sphere(m) or (m.rows_cached() and "_derived" in m.__dict__)


def wait_exact(m):
    """Build the exact tables of ``m`` in this thread (or wait for the thread building them) and
    return ``m``; one build per material however many threads ask."""
    if not _is_sphere(m):
        return m
    with _profiles_lock:
        lock = _exact_locks.setdefault(m, threading.Lock())
    with lock:
        if "rows" not in m.__dict__ and not m.use_cache:
            _read_cached_rows(m)
        _ = m.rows, m.row_totals
    return m


def _read_cached_rows(m) -> None:
    """The exact rows of ``m`` from the on-disk table cache when another command (corona render,
    corona lobe) has built them: read, not rebuilt.  The designer itself writes none (a sphere
    table is tens of MB; :func:`material`)."""
    import copy
    twin = copy.copy(m)
    twin.__dict__ = {k: v for k, v in m.__dict__.items() if k != "rows"}
    twin.use_cache = True
    if twin.rows_cached():
        m.__dict__["rows"] = twin.rows


class _ExactBuilds:
    """The exact Mie tables of new sphere radii, built on one thread of their own while the
    requests answer with previews: one build at a time, the newest wish first; at most
    :attr:`keep` wishes wait (older ones are dropped: a radius slider passes through many radii,
    and the page asks again for the one it shows).  A build that fails is remembered and its
    error given to the next request for that material."""

    keep = 2

    def __init__(self):
        self.lock = threading.Lock()
        self.waiting: list = []                     # materials, newest last
        self.running = None                         # (material, start time)
        self.failed: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()   # material -> message
        self.thread = None

    def want(self, m) -> None:
        with self.lock:
            if self.running is not None and self.running[0] is m:
                return
            self.waiting = [w for w in self.waiting if w is not m][-(self.keep - 1):] + [m]
            if self.thread is None:
                self.thread = threading.Thread(target=self._work, name="corona-designer-tables", daemon=True)
                self.thread.start()

    def _work(self) -> None:
        import time
        while True:
            with self.lock:
                if not self.waiting:
                    self.thread = None
                    return
                m = self.waiting.pop()
                self.running = (m, time.monotonic())
            try:
                wait_exact(m)
            except Exception as err:  # noqa: BLE001 - told to the next request for this material
                from corona._validation import one_line_error
                self.failed[m] = one_line_error(err)
            finally:
                with self.lock:
                    self.running = None

    def status(self) -> list[dict]:
        """The builds running and waiting: ``what``, ``state`` and ``seconds`` (running ones)."""
        import time
        with self.lock:
            out = []
            if self.running is not None:
                m, t0 = self.running
                out.append({"what": f"the exact Mie table of {m.length_scale:g} µm spheres", "state": "running",
                            "seconds": round(time.monotonic() - t0, 2)})
            out += [{"what": f"the exact Mie table of {m.length_scale:g} µm spheres", "state": "waiting",
                     "seconds": 0.0} for m in reversed(self.waiting)]
        return out

    def idle(self) -> bool:
        with self.lock:
            return self.running is None and not self.waiting


#: The exact tables building in the background (GET /api/progress lists them).
builds = _ExactBuilds()


def shown_material(params: dict, preview: bool = True) -> tuple:
    """The material to answer a request with and whether it is a preview.

    ``preview`` False: the material of ``params`` with its exact tables (built here or waited for).
    Else the material of ``params`` when its tables are ready (:func:`exact_ready`); otherwise (a new
    sphere radius) its coarse preview (:meth:`corona.model.mie.material.SphereMaterial.preview`, a
    fraction of a second) while the exact table is built in the background (:data:`builds`): the
    page shows the preview and asks again when GET /api/progress lists no build."""
    m = material(params)
    if not preview:
        return wait_exact(m), False
    if exact_ready(m):
        return m, False
    failed = builds.failed.get(m)
    if failed is not None:
        raise CoronaError(f"the exact Mie table of radius={m.length_scale:g} µm could not be built: {failed}")
    key = tuple(sorted((k, v) for k, v in params.items()))

    def make():
        p = m.preview()
        _ = p.rows, p.row_totals
        return p
    with _preview_lock:
        preview = _previews.get(key, make)
    if exact_ready(m):           # built meanwhile
        return m, False
    builds.want(m)
    return preview, True


def exact_material(params: dict):
    """The material of ``params`` with its exact tables (built here, or waited for)."""
    return wait_exact(material(params))


def _is_sphere(m) -> bool:
    """Whether ``m`` is a layer of Mie spheres (its lobe depends on λ beyond ``u``)."""
    from corona.model.mie.material import SphereMaterial
    return isinstance(m, SphereMaterial)


def _uses_table_weight(m) -> bool:
    """Whether the lobe weight needs the table (processes that allow overlaps).

    For hard-core processes (hard-disk, rsa, lattices) the lobe's plane
    integral ``F_a (1 - F_a)`` stays below ``1 - coherent_transmittance``
    for both modes, so :attr:`corona.Material.lobe_weight` is ``F_a``
    (tests/apps/test_designer.py checks it); Poisson layers and measured point
    sets may overlap and need the table's integral.
    """
    from corona.model.processes import PointSet, Poisson
    return isinstance(m.process, (Poisson, PointSet))


#: Margin on Parseval's plane integral within which a Poisson layer's lobe weight is read from
#: its table (the table's integral exceeds ``4π² self_overlap`` by its interpolation error, < 1 %).
PLANE_MARGIN = 1.05


def lobe_weight(m) -> float:
    """The lobe's prefactor ``F_a`` (or the lowered one, :attr:`corona.Material.lobe_weight`).

    Poisson layers need the table's plane integral only near the budget: by Parseval the whole
    plane's ``∫ v d²u / 4π²`` is the shape's ``self_overlap`` (``S = 1``), so while
    ``F_a self_overlap`` with :data:`PLANE_MARGIN` stays within ``1 - coherent_transmittance``
    the weight is ``F_a`` without building the table (what :attr:`corona.Material.lobe_weight`
    finds there too)."""
    from corona.model.processes import Poisson
    if not _uses_table_weight(m):
        return float(m.area_fraction)
    if isinstance(m.process, Poisson) and "lobe_weight" not in m.__dict__:
        fa = float(m.area_fraction)
        if fa * float(m.shape.self_overlap) * PLANE_MARGIN <= 1.0 - m.coherent_transmittance:
            return fa
    return float(m.lobe_weight)


def auto_field(m) -> float:
    """Half-width of a view [degree] that shows the first few rings: ``u ≈ 14`` at 550 nm
    (as :func:`corona.apps.pictures.lobe_figure`), between 0.05° and 45°."""
    s = 14 * 0.55 / (2 * np.pi * m.length_scale)
    return float(np.clip(np.degrees(np.arcsin(min(1.0, s))), 0.05, 45.0))


#: Step in u of the designer's radial profiles: rings are ~π apart in u, so
#: linear interpolation errs by ~(Δu)²/8 ≈ 2e-4 relative (the renderer's tables use 0.01).
PREVIEW_DU = 0.04


def _radial_v(m, u_top: float, n_max: int = 16384) -> tuple[np.ndarray, np.ndarray]:
    """Exact ``v(u) = [P + C (S - 1)] / R²`` of a radial material on ``[0, u_top]``
    (step :data:`PREVIEW_DU`, coarser beyond ``n_max`` nodes), memoised per material and range."""
    n = int(min(n_max, max(64, math.ceil(u_top / PREVIEW_DU) + 1)))
    u_top = float(u_top)

    def make():
        u = np.linspace(0.0, u_top, n)
        return u, m.lobe_dimensionless_radial(u)
    with _profiles_lock:
        per_material = _profiles.setdefault(m, _LRU(4))
    return per_material.get((round(u_top, 9), n), make)


def _u_top(m, rho_top: float) -> float:
    """Largest u of a view reaching ``|d| = rho_top``, at the shortest wavelength."""
    return 2 * np.pi * m.length_scale * float(rho_top) / (WAVELENGTHS[0] * 1e-3) * 1.0001


def _rho_top(field_deg: float) -> float:
    """``|d|`` at the corner of a picture of half-width ``field_deg`` (:func:`_pixel_offsets`)."""
    r = float(np.radians(field_deg))
    return float(np.hypot(np.sin(r) * np.cos(r), np.sin(r)))


def _light_spectrum(temperature: float, lams: np.ndarray) -> np.ndarray:
    """Black body at ``temperature`` scaled to luminance Y = 1 (CIE 1931)."""
    spd = blackbody(lams, temperature)
    y = spectrum_to_linear_srgb(spd, lams) @ np.array([0.2126, 0.7152, 0.0722])
    return spd / y


def lobe_rgb(m, d: np.ndarray, spectrum: np.ndarray, lams: np.ndarray) -> np.ndarray:
    """``∫ f(d, λ) s(λ) x̄ȳz̄(λ) dλ`` in linear sRGB at offsets ``d`` (..., 2).

    Radial materials: the exact lobe on one radial profile of 2048 points in
    ``|d|`` per wavelength, interpolated per pixel (cost independent of the
    image size); anisotropic ones: the renderer's 2-D table at each point.
    """
    d = np.asarray(d, dtype=np.float64)
    R = m.length_scale
    w = lobe_weight(m)
    if _is_sphere(m):     # Mie: the pattern is no function of u alone; the lobe at each λ
        rho = np.hypot(d[..., 0], d[..., 1])
        rho_grid = np.linspace(0.0, max(float(rho.max()) if rho.size else 0.0, 1e-12), 2048)
        dg = np.stack([rho_grid, 0 * rho_grid], -1)
        f = np.stack([m.lobe(dg, lam) for lam in lams], -1)                     # (K, nλ)
        prof = spectrum_to_linear_srgb(f * spectrum, lams)
        x = rho * ((rho_grid.size - 1) / rho_grid[-1])
        i = np.minimum(x.astype(np.intp), rho_grid.size - 2)
        frac = (x - i)[..., None]
        return prof[i] * (1.0 - frac) + prof[i + 1] * frac
    if m.isotropic:
        rho = np.hypot(d[..., 0], d[..., 1])
        rho_top = float(rho.max()) if rho.size else 0.0
        rho_grid = np.linspace(0.0, max(rho_top, 1e-12), 2048)
        u, v = _radial_v(m, _u_top(m, rho_grid[-1]))
        lam_um = lams * 1e-3
        ug = 2 * np.pi * R * rho_grid[:, None] / lam_um[None, :]               # (K, nλ)
        f = w * (R / lam_um) ** 2 * np.interp(ug, u, v, right=0.0)              # F_a (R/λ)² v(u)
        prof = spectrum_to_linear_srgb(f * spectrum, lams)                      # (K, 3)
        # linear interpolation on the uniform grid: one index, three channels
        x = rho * ((rho_grid.size - 1) / rho_grid[-1])
        i = np.minimum(x.astype(np.intp), rho_grid.size - 2)
        frac = (x - i)[..., None]
        return prof[i] * (1.0 - frac) + prof[i + 1] * frac
    # anisotropic: the renderer's lobe F_a (R/λ)² v(2π R d / λ) at each pixel and λ, then one
    # matrix (nλ, 3) from the spectrum to linear sRGB (the integral is linear in the spectrum)
    if d.ndim == 3 and min(d.shape[:2]) > 1 and np.allclose(d[::-1, ::-1], -d, rtol=1e-12, atol=0.0):
        # every lobe is even, v(-u) = v(u) (real profiles and point patterns; the tables are built
        # so): on a grid symmetric about its centre the lower rows are the upper ones turned round
        n = d.shape[0]
        rows = (n + 1) // 2
        top = lobe_rgb(m, d[:rows], spectrum, lams)
        return np.concatenate([top, top[:n - rows][::-1, ::-1]])
    to_rgb = spectrum_to_linear_srgb(np.diag(spectrum), lams)                 # (nλ, 3)
    if m.render_kind == "table":    # the bilinear table itself: every wavelength in one pass
        if (d.ndim == 3 and d.shape[1] > 1 and _mirrored_x(m)
                and np.allclose(d[:, ::-1, 0], -d[..., 0], rtol=1e-12, atol=0.0)
                and np.allclose(d[:, ::-1, 1], d[..., 1], rtol=1e-12, atol=0.0)):
            # a lobe even in u_x too (a square lattice of upright squares, the voile): the right
            # columns are the left ones mirrored
            n = d.shape[1]
            cols = (n + 1) // 2
            left = lobe_rgb(m, d[:, :cols], spectrum, lams)
            return np.concatenate([left, left[:, :n - cols][:, ::-1]], axis=1)
        lam_um = lams * 1e-3
        v = m.render_lobe.table.eval_scaled(d, 2 * np.pi * R / lam_um)          # (..., nλ)
        return v @ (w * (R / lam_um)[:, None] ** 2 * to_rgb)
    lam_um = lams * 1e-3
    rl = _render_lobe(m)
    if rl.kind == "analytic" and all(t.kind in ("circle", "ellipse") for t in rl.terms):
        v = _disk_terms_lobe(rl, d, 2 * np.pi / lam_um)                           # (..., nλ)
    else:
        v = np.stack([rl.eval(d * (2 * np.pi * R / lam)) for lam in lam_um], -1)  # (..., nλ)
    return v @ (w * (R / lam_um)[:, None] ** 2 * to_rgb)


_mirror_checks: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()   # material -> bool


def _mirrored_x(m) -> bool:
    """Whether the 2-D table of ``m`` (:class:`corona.model.tabulated.GridTable`, no warp) is even in
    ``u_x``, ``v(-u_x, u_y) = v(u_x, u_y)`` to 1e-12 of its peak (its vertices are symmetric
    about 0), checked once per material."""
    with _profiles_lock:
        known = _mirror_checks.get(m)
    if known is None:
        table = m.render_lobe.table
        v = table.values
        known = bool(table.warp == 0 and v.size and np.allclose(v, v[:, ::-1], rtol=0.0,
                                                                 atol=1e-12 * float(np.abs(v).max())))
        with _profiles_lock:
            _mirror_checks[m] = known
    return known


def _disk_terms_lobe(rl, d: np.ndarray, k: np.ndarray) -> np.ndarray:
    """``rl.eval(d k R)`` (:meth:`corona.model.render_lobe.RenderLobe.eval`) at every wavenumber ``k``
    [rad/µm] (nλ,), shape (..., nλ), for analytic terms that are circles and ellipses.

    Their amplitudes are real, ``|A| · 2 J1(t)/t`` with ``t = k |M d|`` (``M`` the outline's
    semi-axes in its own frame), so ``|M d|`` is found once per point and one Bessel call
    serves every wavelength; ``P = Σ w |Â|² / (|A| R²)``, ``C = (Σ w Â)² / (|A| R²)``.
    """
    k = np.asarray(k, dtype=np.float64)
    dx, dy = d[..., 0, None], d[..., 1, None]
    rho = np.hypot(dx, dy)                                   # |d| (..., 1)
    norm = 1.0 / (rl.area * rl.R**2)
    one = len(rl.terms) == 1 and rl.s_minus_one is None
    inten = amp = None
    for t in rl.terms:
        p = t.params
        if t.kind == "circle":
            r = rho * p["radius"]
        else:
            c, s = math.cos(p["angle"]), math.sin(p["angle"])
            r = np.hypot(p["a"] * (c * dx + s * dy), p["b"] * (c * dy - s * dx))   # |M d| (..., 1)
        x = r * k                                            # (..., nλ)
        a = special.j1(x)                                    # 2 J1(x)/x, 1 at x = 0 (Circle.airy)
        a *= 2.0
        np.divide(a, x, out=a, where=x > 1e-8)
        small = (r[..., 0] * k.max() <= 1e-8)
        if np.any(small):
            a[small] = np.where(x[small] > 1e-8, a[small], 1.0)
        a *= t.area
        if t.blur > 0:
            a *= np.exp(-0.5 * (rho * k * t.blur) ** 2)
        if one:                                              # one outline over Poisson: P only
            a *= a
            a *= t.weight * norm
            return a
        inten = t.weight * a * a if inten is None else inten + t.weight * a * a
        amp = t.weight * a if amp is None else amp + t.weight * a
    P = inten * norm
    if rl.s_minus_one is None:
        return np.maximum(P, 0.0)
    return np.maximum(P + amp * amp * norm * rl.s1(rho * k * rl.R), 0.0)


_render_lobes: "weakref.WeakKeyDictionary" = weakref.WeakKeyDictionary()   # material -> RenderLobe


def _render_lobe(m):
    """The renderer's lobe of ``m`` (:attr:`corona.Material.render_lobe`).  Closed-form shapes
    over an isotropic process need only their outlines and ``S - 1``
    (:meth:`corona.Material.radial_s_minus_one`): built so, without the sampling table, unless
    the material holds its table already."""
    if m.render_kind != "analytic" or "_arrays" in m.__dict__:
        return m.render_lobe
    with _profiles_lock:
        rl = _render_lobes.get(m)
    if rl is None:
        from corona.model.render_lobe import RenderLobe
        s_du, s1 = m.radial_s_minus_one()
        rl = RenderLobe("analytic", m.length_scale, float(m.shape.area), terms=m.analytic_terms,
                        s_du=s_du, s_minus_one=None if np.all(s1 == 0.0) else s1)
        with _profiles_lock:
            _render_lobes[m] = rl
    return rl


def _pixel_offsets(field_deg: float, size: int) -> tuple[np.ndarray, float]:
    """``d = (sin θx cos θy, sin θy)`` at the pixel centres of a square view of
    half-width ``field_deg`` (as :func:`corona.apps.pictures.far_field_corona`), and the pixel pitch [rad]."""
    t = np.radians(np.linspace(-field_deg, field_deg, size))
    tx, ty = np.meshgrid(t, t[::-1], indexing="xy")
    return np.stack([np.sin(tx) * np.cos(ty), np.sin(ty)], -1), float(t[1] - t[0])


def disk_cover(centres: np.ndarray, radius: float) -> np.ndarray:
    """Fraction of each pixel inside a disk of ``radius`` (pixel units) centred at 0.

    ``centres`` (n,) are the pixel centres along x and along y [pixels]; the
    disk is supersampled over the rows and columns it can touch.  When it
    lies wholly inside the grid the fractions are scaled to sum to ``π r²``
    exactly; a disk between all sample points (far below one pixel) goes to
    the pixels nearest its centre.
    """
    c = np.asarray(centres, dtype=np.float64)
    out = np.zeros((c.size, c.size))
    idx = np.nonzero(np.abs(c) < radius + 0.75)[0]
    area = np.pi * radius * radius
    if idx.size:
        ss = int(np.clip(4096 // idx.size, 1, 16))
        pts = (c[idx][:, None] + ((np.arange(ss) + 0.5) / ss - 0.5)[None, :]).ravel()
        inside = (pts[None, :] ** 2 + pts[:, None] ** 2) <= radius * radius
        out[np.ix_(idx, idx)] = inside.reshape(idx.size, ss, idx.size, ss).mean(axis=(1, 3))
    inner = radius + 1.0 < np.abs(c).max()
    if out.sum() == 0.0:
        near = np.nonzero(np.abs(c) <= np.abs(c).min() + 1e-9)[0]
        out[np.ix_(near, near)] = area / near.size**2
    elif inner:
        out *= area / out.sum()
    return out


def _fft_convolve_same(img: np.ndarray, k: np.ndarray) -> np.ndarray:
    """``img`` (n, n, c) convolved with the odd, centred kernel ``k`` (2h+1, 2h+1), zero
    outside, cropped to ``img``'s grid (scipy.fft; scipy.signal costs seconds to import)."""
    from scipy import fft as sfft
    n, h = img.shape[0], k.shape[0] // 2
    size = sfft.next_fast_len(n + 2 * h, real=True)
    planes = np.ascontiguousarray(np.moveaxis(img, -1, 0))           # (c, n, n): contiguous transforms
    spec = sfft.rfft2(planes, s=(size, size)) * sfft.rfft2(k, s=(size, size))
    full = sfft.irfft2(spec, s=(size, size))
    return np.moveaxis(full[:, h:h + n, h:h + n], 0, -1)


def corona_linear(m, view: dict) -> tuple[np.ndarray, dict]:
    """Linear sRGB radiance around the light, relative to the light's (size, size, 3).

    Returns the picture and a dict of what was used (``field`` [degree], ``pitch`` [degree/pixel],
    ``preview``: whether it is the half-size preview of a 2-D picture, ``view["preview"]``).
    """
    from scipy import ndimage
    field = view.get("field") or auto_field(m)
    size = int(view.get("size") or VIEW_SPEC["size"].default)
    preview = bool(view.get("preview")) and not m.isotropic    # radial pictures are exact at any speed
    if preview:
        size = max(32, size // 2)
    temperature = view.get("temperature") or VIEW_SPEC["temperature"].default
    diameter = math.radians(view.get("light_size") or VIEW_SPEC["light_size"].default)
    d, pitch = _pixel_offsets(field, size)
    lams = WAVELENGTHS if m.isotropic else np.linspace(WAVELENGTHS[0], WAVELENGTHS[-1], N_WAVELENGTHS_2D)
    spectrum = _light_spectrum(temperature, lams)
    f_rgb = lobe_rgb(m, d, spectrum, lams)                                  # 1/sr, per unit light
    r_pix = 0.5 * diameter / pitch
    h = int(min(math.ceil(r_pix + 1), size))
    K = disk_cover(np.arange(-h, h + 1.0), r_pix) * pitch * pitch          # sr per pixel
    if K.size <= 49:      # a light of a few pixels: direct convolution is cheaper than FFTs
        img = np.stack([ndimage.convolve(f_rgb[..., c], K, mode="constant") for c in range(3)], -1)
    else:
        img = _fft_convolve_same(f_rgb, K)
    # the light itself through the coherent part: the fraction of each pixel it covers
    direct = disk_cover(np.arange(size) - 0.5 * (size - 1), r_pix)
    light_rgb = spectrum_to_linear_srgb(spectrum, lams)                     # luminance 1
    img = img + m.coherent_transmittance * direct[..., None] * light_rgb
    img = np.maximum(np.nan_to_num(img, nan=0.0, posinf=0.0), 0.0)
    return img, {"field": float(field), "pitch": math.degrees(pitch), "preview": preview}


def exposure_of(img: np.ndarray, exposure, percentile: float = 99.5) -> float:
    """The exposure [EV] to use: ``exposure``, or automatic (the ``percentile`` of
    the luminance maps to white)."""
    if exposure is not None:
        return float(exposure)
    ref = float(np.percentile(img @ np.array([0.2126, 0.7152, 0.0722]), percentile))
    return float(np.clip(math.log2(1.0 / ref), -20.0, 40.0)) if ref > 0 else 0.0


def png_bytes(rgb8: np.ndarray, compress_level: int = 1) -> bytes:
    """PNG of an (h, w, 3) or (h, w) uint8 array (Pillow)."""
    from PIL import Image
    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(rgb8)).save(buf, format="PNG", compress_level=compress_level)
    return buf.getvalue()


def corona_png(params: dict, view: dict, preview: bool = False) -> tuple[bytes, dict]:
    """The corona PNG of GET /api/corona.png and what was used (``exposure`` [EV], ``field``,
    ``preview``: half the pixels or a coarse table, ``building``: the exact table of a new sphere
    radius is building and this picture is its preview).  ``preview``: a new sphere radius may be
    answered from its preview (:func:`shown_material`; the server's way), else it waits for the
    exact table."""
    m, building = shown_material(params, preview)
    img, used = corona_linear(m, view)
    used["building"] = building
    used["preview"] = used["preview"] or building
    ev = exposure_of(img, view.get("exposure"))
    used["exposure"] = ev
    return png_bytes(tonemap_srgb(img, exposure=2.0**ev)), used


# ----------------------------------------------------------------------
# profiles and rings
# ----------------------------------------------------------------------
def profiles(params: dict, view: dict, n: int = 400, preview: bool = False) -> dict:
    """T_a, T_s and the lobe along θ at 550 nm (GET /api/profiles).

    ``angle`` [degree] from 0 to the view's diagonal; ``T_a`` [1/sr] =
    ``P(q) / λ²`` (the single-scatterer lobe; P the form factor, T_a(0) = |A|/λ²),
    ``T_s`` the structure factor, ``lobe`` = ``F_a T_a T_s`` [1/sr] as the BSDF
    (decoupling rule for random shapes).  Anisotropic materials: cuts along
    x and along y (``*_y``).  Spheres: ``T_a`` = ``dσ/dΩ / (π r²)`` from Mie theory (on a fixed
    lattice the same along both cuts: the pattern at normal incidence is isotropic), ``T_s`` the
    lattice's ``S`` at the cut's ``q``, and ``lobe`` the layer's own per-direction lobe
    (:meth:`~corona.model.mie.material.SphereMaterial.lobe_dimensionless` at 550 nm: per unit ``d²d``,
    ``F_a w T_a T_s / cos θ`` with the lattice's energy cap ``w``).  ``rings`` [degree]: the first maxima of the
    lobe after the centre at 450, 550, 650 nm.  ``preview``: a new sphere radius may be answered
    from its preview (:func:`shown_material`), and the result's ``preview`` says whether it was.
    """
    m, preview = shown_material(params, preview)
    field = view.get("field") or auto_field(m)
    lam = PROFILE_WAVELENGTH * 1e-3
    R = m.length_scale
    rho_top = _rho_top(field)                       # the picture's corner
    theta = np.linspace(0.0, math.degrees(math.asin(min(1.0, rho_top))), n)
    rho = np.sin(np.radians(theta))
    q = 2 * np.pi * rho / lam                                               # rad/µm
    w = lobe_weight(m)
    out = {"angle": theta.tolist(), "wavelength": PROFILE_WAVELENGTH, "isotropic": m.isotropic,
           "field": float(field)}
    if m.isotropic:
        # the lobe from the picture's radial profile (same material, same range: computed once)
        u, v = _radial_v(m, _u_top(m, rho_top))
        if _is_sphere(m):
            out["T_a"] = _sphere_T_a(m, rho)
        else:
            out["T_a"] = _finite(m.shape.form_factor_radial(q) / lam**2)
        out["T_s"] = _finite(m.process.structure_factor_radial(q, m.shape))
        out["lobe"] = _finite(w * (R / lam) ** 2 * np.interp(q * R, u, v))
    else:
        sphere = _is_sphere(m)
        for suffix, qq in (("", np.stack([q, 0 * q], -1)), ("_y", np.stack([0 * q, q], -1))):
            # a sphere's pattern at normal incidence is isotropic: both cuts share Mie's T_a
            out["T_a" + suffix] = _sphere_T_a(m, rho) if sphere else _finite(m.shape.form_factor(qq) / lam**2)
            out["T_s" + suffix] = _finite(m.process.structure_factor_at(qq, m.shape))
            v = m.lobe_dimensionless(qq * R, PROFILE_WAVELENGTH) if sphere else m.lobe_dimensionless(qq * R)
            out["lobe" + suffix] = _finite(w * (R / lam) ** 2 * v)
    out["rings"] = ring_radii(m)
    out["preview"] = preview
    return out


def _sphere_T_a(m, rho) -> list:
    """One sphere's ``n dσ/dΩ / F_a = dσ/dΩ / (π r²)`` [1/sr] at normal incidence towards
    ``wo = (ρ, 0, -√(1 - ρ²))`` at :data:`PROFILE_WAVELENGTH`, from Mie theory (the layer's
    :meth:`~corona.model.mie.material.SphereMaterial.exact_parts`, a size distribution's average included)."""
    wi = np.array([0.0, 0.0, 1.0])
    wo = np.stack([rho, 0 * rho, -np.sqrt(np.maximum(1 - rho * rho, 0.0))], -1)
    P_f = m.exact_parts(np.linalg.norm(wo + wi, axis=-1), np.linalg.norm(wo - wi, axis=-1),
                   np.full(rho.shape, PROFILE_WAVELENGTH))[0]
    return _finite(P_f)


def _finite(a) -> list:
    a = np.nan_to_num(np.asarray(a, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
    return np.maximum(a, 0.0).tolist()


def ring_radii(m, n_rings: int = 4) -> dict:
    """Angular radii [degree] of the first ``n_rings`` bright rings (local maxima of
    the exact lobe along x after the central peak, refined by a parabola through
    the three nodes around each) at each of :data:`RING_WAVELENGTHS`."""
    R = m.length_scale
    du = 0.05
    u = np.arange(0.0, 40.0 + du / 2, du)

    def peaks_of(v):
        a, b, c = v[:-2], v[1:-1], v[2:]
        peaks = np.nonzero((b > a) & (b >= c) & (b > 1e-12 * max(v.max(), 1e-300)))[0] + 1
        peaks = peaks[u[peaks] > 1.0][:n_rings]
        curv = v[peaks - 1] - 2 * v[peaks] + v[peaks + 1]
        shift = np.where(curv < 0, 0.5 * (v[peaks - 1] - v[peaks + 1]) / np.where(curv < 0, curv, -1.0), 0.0)
        return u[peaks] + du * np.clip(shift, -0.5, 0.5)
    if _is_sphere(m):     # Mie rings move with x and m(λ) as well: found at each wavelength
        ux = np.stack([u, 0 * u], -1)       # a fixed lattice: along x, as the opaque shapes'
        per_lam = {lam: peaks_of(m.lobe_dimensionless_radial(u, lam) if m.isotropic
                                 else m.lobe_dimensionless(ux, lam)) for lam in RING_WAVELENGTHS}
    else:
        v = m.lobe_dimensionless_radial(u) if m.isotropic else m.lobe_dimensionless(np.stack([u, 0 * u], -1))
        per_lam = dict.fromkeys(RING_WAVELENGTHS, peaks_of(v))
    out = {}
    for lam in RING_WAVELENGTHS:
        s = per_lam[lam] * lam * 1e-3 / (2 * np.pi * R)
        out[f"{lam:g}"] = [float(np.degrees(np.arcsin(x))) for x in s if x < 1.0]
    return out


# ----------------------------------------------------------------------
# energy split and exports
# ----------------------------------------------------------------------
def energy(params: dict, preview: bool = False) -> dict:
    """Where the light of a light at normal incidence goes, at 550 nm: the model's white furnace
    (:meth:`corona.Material.directional_albedo`, the substrate included).

    ``coherent_transmittance`` (the delta beam through the layer and its pane),
    ``specular_reflection`` (the pane's or the mirror's mirror image), ``diffuse_transmittance``
    (the lobe through), ``lobe_reflection`` (the lobe back: off a pane or a mirror, a sphere's
    backward lobe), ``reflectance`` (the opaque part's diffuse reflection) and the ``absorbed``
    rest (what the model drops or the layer absorbs); every lobe over the propagating directions.
    ``preview``: a new sphere radius may be answered from its preview (:func:`shown_material`), and
    the result's ``preview`` says whether it was.
    """
    m, preview = shown_material(params, preview)
    e = m.directional_albedo(1.0, 550.0, n_phi=4 if m.isotropic else None)   # normal incidence: radial
    parts = {"coherent_transmittance": e["coherent"], "specular_reflection": e["specular"],
             "diffuse_transmittance": e["lobe_transmission"], "lobe_reflection": e["lobe_reflection"],
             "reflectance": e["diffuse"]}
    parts = {k: float(v) for k, v in parts.items()}
    return {**parts, "absorbed": float(max(0.0, 1.0 - sum(parts.values()))),
            "area_fraction": float(m.area_fraction), "length_scale": float(m.length_scale),
            "isotropic": bool(m.isotropic), "substrate": params.get("substrate") or "none",
            "material": repr(m), "preview": preview}


def _export_value(p: Parameter, v):
    if p.kind == "file":
        return os.fspath(v)
    return v


def exports(params: dict, view: dict) -> dict:
    """The material as a Mitsuba XML snippet, a ``mi.load_dict`` dict (and its Python
    text), the ``corona lobe`` command, and the kernel export URLs' parameters."""
    items = [(p, _export_value(p, params[p.name])) for p in PARAMETERS
             if p.name in params and params[p.name] != p.default]
    tag = {"float": "float", "int": "integer"}
    xml = ['<bsdf type="corona">']
    for p, v in items:
        value = f"{v:.10g}" if p.kind == "float" and not isinstance(v, str) else str(v)
        kind = "string" if isinstance(v, str) else tag.get(p.kind, "string")
        xml.append(f'    <{kind} name="{p.name}" value="{_xml_escape(value)}"/>')
    xml.append("</bsdf>")
    d = {"type": "corona", **{p.name: v for p, v in items}}
    cmd = ["corona", "lobe"]
    for p, v in items:
        cmd += [f"--{p.name.replace('_', '-')}", f"{v:.10g}" if p.kind == "float" and not isinstance(v, str)
                else str(v)]
    cmd += ["--out", "lobe.png"]      # every shape, spheres too (their Mie lobe and corona)
    return {"xml": "\n".join(xml), "load_dict": d, "load_dict_python": "mi.load_dict(" + repr(d) + ")",
            "command": " ".join(shlex.quote(c) for c in cmd)}


def _xml_escape(s: str) -> str:
    return (s.replace("&", "&amp;").replace('"', "&quot;").replace("<", "&lt;").replace(">", "&gt;"))


# ----------------------------------------------------------------------
# the kernel (point-spread function) for compositing
# ----------------------------------------------------------------------
def _channel_weights(lams: np.ndarray) -> np.ndarray:
    """(nλ, 3) weights of each wavelength in each linear sRGB channel for an equal-energy light,
    each column normalised to sum 1 (a wavelength-independent layer gives equal channels)."""
    w = spectrum_to_linear_srgb(np.eye(lams.size), lams)
    return w / w.sum(0)


def kernel_view(m) -> str:
    """What the kernel shows: the light seen through the layer (``transmission``), or its
    reflection in the layer on a mirror (``reflection``: a mirror transmits nothing)."""
    from corona.model.substrate import Mirror
    return "reflection" if isinstance(m.substrate, Mirror) else "transmission"


def _substrate_terms(m, lams: np.ndarray):
    """The kernel's delta weight on the centre pixel per channel (3,) and the substrate's factor on
    the lobe as a function of ``|cos θo|`` per channel (a callable, or None for 1), at normal
    incidence (the model's :meth:`corona.Material.eval` and delta weights):

    * no substrate: ``T_c`` (:meth:`corona.Material.coherent_transmission`: a Mie layer's at each
      wavelength), factor 1;
    * glass: ``T_c T'(0)``; the lobe times ``T'(θo)`` (layer on the lit face) or ``T'(0)``;
    * mirror (the reflection): the specular weight :meth:`corona.Material.specular_reflection`;
      the lobe times ``min(R(0), R(θo)) + T_c [P(0) + P(θo)]``.  The double pass's Quetelet
      fringes (``2 T_c V Q``) are finer than a pixel beyond a fraction of a degree and average
      out over one; the kernel holds the fringe-averaged lobe.

    Wavelength-dependent factors (a metal's or a spectrum's silvering) are averaged over each
    channel's equal-energy weights (:func:`_channel_weights`).
    """
    from corona.model.substrate import Mirror
    sub = m.substrate
    c = float(m.coherent_transmittance)
    wch = _channel_weights(lams)
    if not isinstance(sub, Mirror):          # the beam through (a Mie layer's depends on λ)
        through = np.array([float(np.asarray(m.coherent_transmission(1.0, float(lam))).ravel()[0])
                            for lam in lams]) @ wch
    if sub is None:
        return through, None
    if isinstance(sub, Mirror):
        if _is_sphere(m):
            raise CoronaError("the kernel of shape='sphere' on substrate='mirror' is not available")
        centre = np.asarray(m.specular_reflection(1.0, lams), dtype=np.float64) @ wch
        cos_grid = np.linspace(0.0, 1.0, 1025)
        front = np.minimum(sub.face_reflectance(1.0), sub.face_reflectance(cos_grid))
        p0 = np.asarray(sub.inner_reflectance(1.0, lams), dtype=np.float64)                 # (nλ,)
        po = sub.inner_reflectance(cos_grid[:, None], lams[None, :])                          # (n, nλ)
        table = front[:, None] + c * ((p0[None, :] + po) @ wch)                               # (n, 3)
    else:
        t0 = float(sub.transmittance(1.0))
        centre = through
        cos_grid = np.linspace(0.0, 1.0, 1025)
        first = bool(np.all(m.substrate_part.layer_first(1.0)))
        t = sub.transmittance(cos_grid) if first else np.full(cos_grid.shape, t0)
        table = np.repeat(t[:, None], 3, axis=1)

    def factor(cos_o):
        cos_o = np.asarray(cos_o, dtype=np.float64)
        return np.stack([np.interp(cos_o, cos_grid, table[:, k]) for k in range(3)], -1)
    return centre, factor


def _kernel_lobe(m, d: np.ndarray, lams: np.ndarray, factor) -> np.ndarray:
    """The lobe per channel at offsets ``d`` (..., 2) for an equal-energy light [1/sr] (..., 3),
    times the substrate's factor at ``cos θo = sqrt(1 - |d|²)``."""
    flat = np.ones_like(lams)
    white = spectrum_to_linear_srgb(flat, lams)
    f = lobe_rgb(m, d, flat, lams) / white
    if factor is not None:
        f = f * factor(np.sqrt(np.maximum(0.0, 1.0 - np.sum(d * d, -1))))
    return f


def _kernel_lams(m) -> np.ndarray:
    return WAVELENGTHS if m.isotropic else np.linspace(WAVELENGTHS[0], WAVELENGTHS[-1], N_WAVELENGTHS_2D)


def _lobe_square_energy(m):
    """The lobe's energy per channel leaving the layer at normal incidence, as a function of the
    half-width [degree] of a square kernel (``max(|θx|, |θy|) <= H``): (Θ sorted [degree],
    cumulative energy (n, 3), total (3,)), from the lobe on a polar grid in ``d`` over every
    propagating direction (``|d| <= 1``), ``∫ f d²d`` (the same lobe and substrate factor as the
    kernel, an independent quadrature)."""
    lams = _kernel_lams(m)
    _, factor = _substrate_terms(m, lams)
    # radial resolution: a quarter of the rings' spacing in |d| at the shortest wavelength
    step = 0.25 * lams[0] * 1e-3 / (2 * m.length_scale)
    n_rho = int(np.clip(math.ceil(1.0 / step) + 1, 1025 if m.isotropic else 513, 16385 if m.isotropic else 2049))
    rho = np.linspace(0.0, 1.0, n_rho)
    # azimuths: a 2-D table's narrow peaks (a lattice's orders) need many; closed-form outlines are smooth
    n_phi = 48 if not m.isotropic and m.render_kind != "table" else 128
    phi = (np.arange(n_phi) + 0.5) * (2 * np.pi / n_phi)
    if m.isotropic:
        f = _kernel_lobe(m, np.stack([rho, 0 * rho], -1), lams, factor)[:, None, :]   # (n_rho, 1, 3)
        f = np.broadcast_to(f, (n_rho, n_phi, 3))
    else:
        d = np.stack([rho[:, None] * np.cos(phi), rho[:, None] * np.sin(phi)], -1)
        f = _kernel_lobe(m, d, lams, factor)
    w = np.full(n_rho, rho[1] - rho[0])
    w[0] = w[-1] = 0.5 * (rho[1] - rho[0])
    w = (w * rho)[:, None] * (2 * np.pi / n_phi)                                         # d²d
    z = np.sqrt(np.maximum(1.0 - rho * rho, 1e-300))[:, None]
    big = np.degrees(np.maximum(np.abs(np.arctan2(rho[:, None] * np.cos(phi), z)),
                                np.abs(np.arctan2(rho[:, None] * np.sin(phi), z))))      # (n_rho, n_phi)
    e = (np.nan_to_num(f) * w[..., None]).reshape(-1, 3)
    order = np.argsort(big, axis=None, kind="stable")
    return big.ravel()[order], np.cumsum(e[order], axis=0), e.sum(0)


def kernel_plan(params: dict, opts: dict, preview: bool = False) -> dict:
    """The kernel's size and what it holds (GET /api/kernel_info; the kernel files use it too).

    ``pixel_scale`` [degree] and ``kernel_size`` [pixel] as given; either one left out is sized
    from the lobe: the square of half-width ``H`` holding :data:`KERNEL_SHARE_TARGET` of the lobe's
    energy in every channel (at most ±:data:`KERNEL_MAX_HALF_WIDTH`°), with
    :data:`KERNEL_PIXELS_PER_RING` pixels per ring at the shortest wavelength, between
    :data:`KERNEL_SIZE_MIN` and :data:`KERNEL_SIZE_MAX` pixels.  ``share``: the lobe's energy inside
    the kernel over its whole energy per channel (R, G, B); ``warning`` when the least is below
    :data:`KERNEL_SHARE_MIN`.  ``preview``: a new sphere radius may be sized from its preview
    (:func:`shown_material`; the page's kernel_info, not the kernel files), and the result's
    ``preview`` says whether it was.
    """
    m, preview = shown_material(params, preview)
    view = kernel_view(m)
    theta, cum, total = _lobe_square_energy(m)
    tot = np.where(total > 0, total, 1.0)

    def share(half):                          # the lobe's share inside max(|θx|, |θy|) <= half
        i = int(np.searchsorted(theta, half, side="right"))
        got = (cum[i - 1] if i else np.zeros(3)) / tot
        return np.where(total > 0, got, 1.0)  # no lobe in a channel: nothing to miss

    ok = np.all((cum / tot >= KERNEL_SHARE_TARGET) | (total <= 0), axis=1)
    needed = float(theta[np.argmax(ok)]) if ok.any() else math.inf
    half_needed = min(max(needed, 0.05), KERNEL_MAX_HALF_WIDTH)
    scale, n = opts.get("pixel_scale"), opts.get("kernel_size")
    lam0 = _kernel_lams(m)[0] * 1e-3
    fine = math.degrees(math.pi * lam0 / (2 * math.pi * m.length_scale)) / KERNEL_PIXELS_PER_RING
    if not m.isotropic and m.render_kind == "table":
        # a 2-D table's narrow peaks (a lattice's orders) are one cell wide: half a cell per pixel
        fine = min(fine, math.degrees(0.5 * m.render_lobe.table.cell * lam0 / (2 * math.pi * m.length_scale)))
    if scale is None and n is None:
        scale = fine
        n = 2 * math.ceil(half_needed / scale - 0.5) + 1
        n = int(np.clip(n, KERNEL_SIZE_MIN, KERNEL_SIZE_MAX))
        scale = half_needed / (n // 2 + 0.5)
    elif scale is None:
        scale = half_needed / (int(n) // 2 + 0.5)
    elif n is None:
        n = int(np.clip(2 * math.ceil(half_needed / scale - 0.5) + 1, 3, KERNEL_SIZE_MAX))
    n = int(n)
    h = n // 2
    if scale * h > KERNEL_MAX_HALF_WIDTH * (1 + 1e-9):
        raise CoronaError(f"pixel_scale={scale:g} degree with kernel_size={n} spans ±{scale * h:g}°; "
                          f"allowed at most ±{KERNEL_MAX_HALF_WIDTH:g}° (pixel_scale × (kernel_size - 1)/2)")
    got = share((h + 0.5) * scale)
    out = {"pixel_scale": float(scale), "kernel_size": n, "half_width": float((h + 0.5) * scale),
           "share": [float(x) for x in got], "share_min": float(got.min()),
           "needed_half_width": None if not math.isfinite(needed) else needed, "view": view,
           "lobe_energy": [float(x) for x in total], "preview": preview}
    if got.min() < KERNEL_SHARE_MIN:
        need = (f"±{needed:.3g}°" if math.isfinite(needed) and needed <= KERNEL_MAX_HALF_WIDTH
                else f"more than ±{KERNEL_MAX_HALF_WIDTH:g}°, the widest kernel")
        out["warning"] = (f"the kernel (±{out['half_width']:.3g}°) holds {100 * got.min():.1f} % of the lobe's "
                          f"energy; {100 * KERNEL_SHARE_MIN:g} % needs {need}")
    return out


def kernel(params: dict, opts: dict, plan: dict | None = None) -> np.ndarray:
    """The corona kernel: the image of a point light through the layer (or, on a mirror, in it),
    linear sRGB, float32, (n, n, 3), on a grid of ``pixel_scale`` [degree] per pixel along each
    axis (pixel ``(i, j)`` looks along ``(tan(i s), tan(j s), 1)``), sized by :func:`kernel_plan`.

    Each pixel holds the fraction of the light's energy it receives: the lobe at the pixel
    centre times the pixel's projected solid angle ``cos θ dΩ`` (the lobe ``f`` is per unit
    ``d²d = cos θ dΩ``), times the substrate's factor (:func:`_substrate_terms`); the centre
    pixel adds the delta weight (the coherent transmission, or the mirror's specular
    reflection).  Colour: each channel is normalised by an equal-energy light, so a
    wavelength-independent layer gives equal channels.  The sum over the kernel is the delta
    weight plus the lobe's energy inside it (``plan["share"]`` of the whole).
    """
    m = exact_material(params)
    plan = plan or kernel_plan(params, opts)
    scale = math.radians(plan["pixel_scale"])
    h = plan["kernel_size"] // 2
    t = np.arange(-h, h + 1) * scale
    tx, ty = np.meshgrid(t, t[::-1], indexing="xy")
    # direction (tan θx, tan θy, 1)/norm: d is its xy part; dΩ = sec²θx sec²θy dθx dθy / norm³
    x, y = np.tan(tx), np.tan(ty)
    norm = np.sqrt(1 + x * x + y * y)
    d = np.stack([x / norm, y / norm], -1)
    projected = scale * scale * (1 + x * x) * (1 + y * y) / norm**4          # cos θ dΩ of a pixel
    lams = _kernel_lams(m)
    centre, factor = _substrate_terms(m, lams)
    k = _kernel_lobe(m, d, lams, factor) * projected[..., None]
    k[h, h] += centre
    return np.nan_to_num(k, nan=0.0, posinf=0.0).astype(np.float32)


def kernel_png(k: np.ndarray) -> bytes:
    """A preview of the kernel: sRGB, the brightest lobe pixel white (the centre
    pixel clipped), 8 bit; the EXR holds the linear values."""
    h = k.shape[0] // 2
    lobe = k.copy()
    lobe[h, h] = 0.0
    top = float(lobe.max())
    return png_bytes(tonemap_srgb(k, exposure=1.0 / top if top > 0 else 1.0))


def kernel_exr(k: np.ndarray, folder: str) -> bytes:
    """The kernel as an OpenEXR file (float32 RGB), written by Mitsuba's Bitmap."""
    import tempfile

    import mitsuba as mi
    os.makedirs(folder, exist_ok=True)
    fd, path = tempfile.mkstemp(suffix=".exr", dir=folder)
    os.close(fd)
    try:
        mi.Bitmap(np.ascontiguousarray(k, dtype=np.float32), mi.Bitmap.PixelFormat.RGB).write(path)
        with open(path, "rb") as f:
            return f.read()
    finally:
        os.unlink(path)

