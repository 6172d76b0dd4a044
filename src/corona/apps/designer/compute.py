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

from corona import tables
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

#: Kernel (PSF) export options.
KERNEL_PARAMETERS: tuple[Parameter, ...] = (
    Parameter("pixel_scale", "float", "degree", 0.02, "angle per pixel of the kernel",
              low=1e-4, high=1.0),
    Parameter("kernel_size", "int", "pixel", 255, "width and height of the kernel (odd)",
              low=3, high=1023),
)
KERNEL_SPEC = {p.name: p for p in KERNEL_PARAMETERS}
#: Largest half-width of a kernel [degree] (a tangent plane beyond it distorts too much).
KERNEL_MAX_HALF_WIDTH = 60.0

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
    "voile fabric": {
        "about": "square pores of 40 µm on a jittered lattice: a curtain (scenes/fabric.xml)",
        "material": {"shape": "square", "radius": 20.0, "area_fraction": 0.25,
                     "process": "lattice-square", "jitter": 4.0, "mode": "aperture"},
        "view": {"temperature": 3000.0, "light_size": 0.18, "field": 3.0}},
}

#: Wavelengths of the pictures [nm] (the visible range of the CIE functions).
N_WAVELENGTHS = 48
WAVELENGTHS = np.linspace(max(380.0, tables.WAVELENGTH_MIN), 780.0, N_WAVELENGTHS)
N_WAVELENGTHS_2D = 24          # anisotropic pictures evaluate the 2-D table per pixel and λ
RING_WAVELENGTHS = (450.0, 550.0, 650.0)
PROFILE_WAVELENGTH = 550.0

#: Uploads are referred to by this id (a content hash and a kind-dependent suffix).
UPLOAD_ID = re.compile(r"^[0-9a-f]{32}\.(png|jpg|txt|csv|npy)$")


def _limit_error(p: Parameter, value, limit) -> CoronaError:
    unit = f" {p.unit}" if p.unit else ""
    lo = p.allowed.split(",")[0]
    return CoronaError(f"{p.name}={value!r} is out of range for the designer; allowed {lo}, {limit:g}]{unit}")


def spec_json() -> dict:
    """The parameters of the page: the material's (from the one specification), the
    light and view, the kernel export, slider ranges and presets (GET /api/parameters)."""
    def one(p: Parameter, group: str) -> dict:
        d = {"name": p.name, "kind": p.kind, "unit": p.unit, "default": p.default,
             "meaning": p.meaning, "allowed": p.allowed, "group": group,
             "choices": list(p.choices) if p.kind == "choice" else None}
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
    return {"parameters": out, "presets": PRESETS,
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
            v = p.check(value)
            if name in LIMITS and v > LIMITS[name]:
                raise _limit_error(p, value, LIMITS[name])
            material[name] = v
    if "kernel_size" in kernel and kernel["kernel_size"] % 2 == 0:
        raise CoronaError(f"kernel_size={kernel['kernel_size']} is even; allowed odd integers in [3, 1023] "
                          "(the light sits on the centre pixel)")
    return material, view, kernel


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


def _is_sphere(m) -> bool:
    """Whether ``m`` is a layer of Mie spheres (its lobe depends on λ beyond ``u``)."""
    from corona.model.mie.layer import SphereMaterial
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
    """Whether the 2-D table of ``m`` (:class:`corona.tables.GridTable`, no warp) is even in
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
    """``rl.eval(d k R)`` (:meth:`corona.tables.lobe.RenderLobe.eval`) at every wavenumber ``k``
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
        from corona.tables.lobe import RenderLobe
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


def corona_png(params: dict, view: dict) -> tuple[bytes, dict]:
    """The corona PNG of GET /api/corona.png and what was used (``exposure`` [EV], ``field``)."""
    m = material(params)
    img, used = corona_linear(m, view)
    ev = exposure_of(img, view.get("exposure"))
    used["exposure"] = ev
    return png_bytes(tonemap_srgb(img, exposure=2.0**ev)), used


# ----------------------------------------------------------------------
# profiles and rings
# ----------------------------------------------------------------------
def profiles(params: dict, view: dict, n: int = 400) -> dict:
    """T_a, T_s and the lobe along θ at 550 nm (GET /api/profiles).

    ``angle`` [degree] from 0 to the view's diagonal; ``T_a`` [1/sr] =
    ``P(q) / λ²`` (the single-scatterer lobe; P the form factor, T_a(0) = |A|/λ²),
    ``T_s`` the structure factor, ``lobe`` = ``F_a T_a T_s`` [1/sr] as the BSDF
    (decoupling rule for random shapes).  Anisotropic materials: cuts along
    x and along y (``*_y``).  ``rings`` [degree]: the first maxima of the
    lobe after the centre at 450, 550, 650 nm.
    """
    m = material(params)
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
        if _is_sphere(m):     # one sphere's n dσ/dΩ / F_a = dσ/dΩ / (π r²), from Mie theory
            wi = np.array([0.0, 0.0, 1.0])
            wo = np.stack([rho, 0 * rho, -np.sqrt(np.maximum(1 - rho * rho, 0.0))], -1)
            P_f = m._exact(np.linalg.norm(wo + wi, axis=-1), np.linalg.norm(wo - wi, axis=-1),
                           np.full(rho.shape, PROFILE_WAVELENGTH))[0]
            out["T_a"] = _finite(P_f)
        else:
            out["T_a"] = _finite(m.shape.form_factor_radial(q) / lam**2)
        out["T_s"] = _finite(m.process.structure_factor_radial(q, m.shape))
        out["lobe"] = _finite(w * (R / lam) ** 2 * np.interp(q * R, u, v))
    else:
        for suffix, qq in (("", np.stack([q, 0 * q], -1)), ("_y", np.stack([0 * q, q], -1))):
            out["T_a" + suffix] = _finite(m.shape.form_factor(qq) / lam**2)
            out["T_s" + suffix] = _finite(m.process.structure_factor_at(qq, m.shape))
            out["lobe" + suffix] = _finite(w * (R / lam) ** 2 * m.lobe_dimensionless(qq * R))
    out["rings"] = ring_radii(m)
    return out


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
        per_lam = {lam: peaks_of(m.lobe_dimensionless_radial(u, lam)) for lam in RING_WAVELENGTHS}
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
def energy(params: dict) -> dict:
    """Coherent, lobe (diffuse) and reflected fractions at normal incidence, and the
    absorbed rest (the energy of :class:`corona.Material`, from its table)."""
    m = material(params)
    c, t, r = m.coherent_transmittance, m.diffuse_transmittance(), m.reflectance
    return {"coherent_transmittance": float(c), "diffuse_transmittance": float(t),
            "reflectance": float(r), "absorbed": float(max(0.0, 1.0 - c - t - r)),
            "area_fraction": float(m.area_fraction), "length_scale": float(m.length_scale),
            "isotropic": bool(m.isotropic), "material": repr(m)}


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
        value = f"{v:.10g}" if p.kind == "float" else str(v)
        xml.append(f'    <{tag.get(p.kind, "string")} name="{p.name}" value="{_xml_escape(value)}"/>')
    xml.append("</bsdf>")
    d = {"type": "corona", **{p.name: v for p, v in items}}
    cmd = ["corona", "lobe"]
    for p, v in items:
        cmd += [f"--{p.name.replace('_', '-')}", f"{v:.10g}" if p.kind == "float" else str(v)]
    cmd += ["--out", "lobe.png"]
    return {"xml": "\n".join(xml), "load_dict": d, "load_dict_python": "mi.load_dict(" + repr(d) + ")",
            "command": " ".join(shlex.quote(c) for c in cmd)}


def _xml_escape(s: str) -> str:
    return (s.replace("&", "&amp;").replace('"', "&quot;").replace("<", "&lt;").replace(">", "&gt;"))


# ----------------------------------------------------------------------
# the kernel (point-spread function) for compositing
# ----------------------------------------------------------------------
def kernel(params: dict, opts: dict) -> np.ndarray:
    """The corona kernel: the image of a point light through the layer (linear sRGB,
    float32, (n, n, 3)), on a tangent-plane grid of ``pixel_scale`` [degree] per pixel.

    Each pixel holds the fraction of the light's energy it receives,
    ``f(d) Ω_pixel`` (the lobe at the pixel centre times its solid angle),
    and the centre pixel adds the coherent transmittance ``T_c``.  Colour: each
    channel is normalised by an equal-energy light, so a wavelength-independent
    layer gives equal channels; convolving a linear plate with the kernel
    puts the corona around every light of the plate.  Sum over the kernel:
    ``T_c`` + the lobe's energy within its field.
    """
    scale_deg = opts.get("pixel_scale") or KERNEL_SPEC["pixel_scale"].default
    n = int(opts.get("kernel_size") or KERNEL_SPEC["kernel_size"].default)
    h = n // 2
    if scale_deg * h > KERNEL_MAX_HALF_WIDTH:
        raise CoronaError(f"pixel_scale={scale_deg:g} degree with kernel_size={n} spans ±{scale_deg * h:g}°; "
                          f"allowed at most ±{KERNEL_MAX_HALF_WIDTH:g}° (pixel_scale × (kernel_size - 1)/2)")
    m = material(params)
    scale = math.radians(scale_deg)
    t = np.arange(-h, h + 1) * scale
    tx, ty = np.meshgrid(t, t[::-1], indexing="xy")
    # tangent plane x = tan θ: direction (x, y, 1)/|.|, d = its xy part
    norm = np.sqrt(1 + np.tan(tx) ** 2 + np.tan(ty) ** 2)
    d = np.stack([np.tan(tx) / norm, np.tan(ty) / norm], -1)
    solid = scale * scale / norm**3                          # Ω of a pixel of the tangent plane
    lams = WAVELENGTHS if m.isotropic else np.linspace(WAVELENGTHS[0], WAVELENGTHS[-1], N_WAVELENGTHS_2D)
    flat = np.ones_like(lams)
    white = spectrum_to_linear_srgb(flat, lams)              # equal-energy light, per channel
    k = lobe_rgb(m, d, flat, lams) / white * solid[..., None]
    k[h, h] += m.coherent_transmittance
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

