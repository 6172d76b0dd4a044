"""Derivatives of the corona BSDF and of renders through it against central finite differences,
and an inverse rendering built on them.

The BSDF
--------
Derivatives of the corona BSDF against central finite differences of the same loaded BSDF.

For every opaque scatterer family (circle, ellipse, square, polygon, mixture),
with respect to ``area_fraction``, ``radius`` and ``albedo``, each uniform
(``<name>.value``) and textured (one texel of a 2×2 bitmap, ``<name>.data``):
reverse and forward derivatives of ``eval``, ``pdf`` and the sample weights,
at normal and oblique incidence, agree with ``(q(x + h) - q(x - h)) / 2h``
where ``q(x)`` is the same BSDF after ``params[key] = x; params.update()``.

Where the finite differences are reliable:

* the lobe is a cubic Hermite in ``F_a`` between its rows (continuously
  differentiable), the sampling a mixture of two rows linear in ``F_a``
  (a kink at each row): ``x`` sits 35 % into a row interval and
  ``h = 2 %`` of it, so ``x ± h`` stays inside;
* with fixed random numbers the sampled component and row must not flip
  between ``x - h`` and ``x + h``: the sample weights are taken with one
  component enabled (the lobe for ``F_a`` and ``radius``, the diffuse
  reflection for ``albedo``) and ``sample1`` in the first 40 % of each
  wavelength's share (the row then is the lower one, ``rest < 1 - t``);
* ``radius`` moves ``u = 2π L d / λ`` across the radial tables' nodes (step
  0.01 in u, linear between): ``h = 1e-3 x`` shifts ``u`` by less than a step
  for ``|u| < 10``, and a kink crossed by a few of the 600 directions changes
  the sum by far less than 1 %;
* the albedo enters linearly: ``h = 0.01``;
* a quantity whose relative change is below 1e-3 of the parameter's relative
  change counts as independent of it (the pdf of the albedo with the lobe on;
  the lobe's sample weights of the radius: the lobe is sampled in ``u``, so
  ``eval / pdf`` does not depend on ``L``, and the FD there is directions
  leaving the propagating disk); its derivatives must be as small.

Renders
-------
Derivatives of renders with Mitsuba's ``prb`` integrator against central finite differences.

A lamp 20 m behind a fogged pane (droplets of radius 3 µm, hard disks,
F_a = 0.3, albedo 0.5) and a small room lamp behind the camera that the pane
reflects diffusely; 16×16 pixels, 128 spp.  For each parameter the statistic
is ``S = Σ_pixels W · image`` with a fixed weight image ``W``:

* the angular distance from the lamp, for the area fraction and the albedo;
* for the radius, a matched filter: ``∂/∂R`` of the numpy reference lobe
  (:class:`corona.Material`) at each pixel's angle from the lamp, because the
  halo's total energy does not depend on R (only its size does), so a
  plain sum would carry almost no signal.

``W`` is zero on the few pixels that see the lamp itself through the
coherent beam: Mitsuba's PRB differentiates a path by re-evaluating
``bsdf.eval`` along it, which is 0 along a delta component's direction, so
the derivative of the coherent weight (1 - F_a)² is not part of any ``prb``
gradient (for any delta BSDF, not only this one).  Everything else (the
lobe, the diffuse reflection, textured or not) is.  The last test adds the
coherent beam's derivative by hand in front of a bright sky, where every
pixel sees through it.

The finite differences use the same seed at ``x ± h`` (correlated
sampling); the area-fraction steps stay inside one interval between the
layer's F_a table rows (the lobe is linear in F_a there, so the central
difference is the interval's slope exactly).  ``K = 4`` seeds give each
estimate's mean and its standard error.  Measured (this machine, Mitsuba
3.9.1, llvm_ad_spectral): the standard error of AD − FD is 0.3 % (F_a), 0.4 %
(albedo), 0.9 % (the texel) and 1.8 % (radius) of the derivative; with 16
seeds (standard errors 0.2–0.7 %) AD and FD agree to 0.6 % and 1.6 standard
errors in all four cases.  The test asks for agreement within 3 standard
errors plus 0.5 % (float32, the radial table's interpolation in u) and for a
standard error below 5 % of the derivative; with the standard errors
above the bound is at most 6 %, so a gradient 10 % off fails.

Reverse mode runs in the default spectral variant for all four
parameters, forward mode (to keep the file fast) for the radius and the
texel only, in ``llvm_ad_rgb`` (which also covers the RGB evaluation):
Mitsuba 3.9.1's ``prb.render_forward`` fails in spectral variants for every BSDF ("the type of state variable 'δL' changed from
'mitsuba.Spectrum' to 'drjit.llvm.ad.Array4f'", reproduced with
``roughdielectric``), an upstream problem.

Inverse rendering
-----------------
``examples/fit_window.py``, reduced (its ``quick()``): Adam on ``prb`` renders recovers the layer.

The targets are renders at the true values (more samples than each step);
the goals are the issue's: droplet radius within 2 %, area fraction within
5 %, each texel of an area-fraction bitmap within 10 % (a 4×4 bitmap here,
8×8 in the full example).
"""
from __future__ import annotations

import os
import sys

import drjit as dr
import numpy as np
import pytest

from bsdf_checks import bitmap_texture, jit_array, uv_interaction

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), os.pardir, os.pardir))


# --------------------------------------------------------------------------------------------------
# the BSDF: eval, pdf and sample weights against central differences of the same BSDF
# --------------------------------------------------------------------------------------------------
FAMILIES = {
    "circle": {"radius": 2.0},
    "ellipse": {"shape": "ellipse", "radius": 2.0, "aspect": 0.6, "angle": 20.0},
    "square": {"shape": "square", "radius": 1.5},
    "polygon": {"shape": "polygon", "sides": 5, "radius": 1.8},
    "mixture": {"shape": "mixture", "mixture": "circle:1.5:0.5, square:1.2:0.5"},
}
LAMS = (450.0, 520.0, 600.0, 700.0)
THETAS = (0.0, 30.0)


def _directions(theta, n=300, seed=2):
    """Transmitted directions around the beam (the lobe) and reflected ones (the diffuse part)."""
    rng = np.random.default_rng(seed)
    th = np.radians(theta)
    wi = np.array([np.sin(th), 0.0, np.cos(th)])
    d = rng.normal(0.0, 0.05, (n, 2))
    wo_xy = d - wi[:2]
    wo_xy = wo_xy[np.sum(wo_xy**2, 1) < 0.99]
    t = np.column_stack([wo_xy, -np.sqrt(1 - np.sum(wo_xy**2, 1))])
    r = t * np.array([1.0, 1.0, -1.0])
    return wi, np.concatenate([t, r[: n // 3]])


def _context(flags):
    import mitsuba as mi
    ctx = mi.BSDFContext()
    ctx.type_mask = flags
    return ctx


def _quantity(bsdf, what, key, theta, keep=None):
    """The scalar q(bsdf) whose derivative is tested: a sum over directions or samples (with
    ``keep``, a bool per sample, only those); ``what="keep"``: the samples whose direction lies
    away from grazing exit (``|wo_xy|² < 0.98``: the evanescent cut is a jump of the weight, and a
    step in the radius moves a direction sampled there across it)."""
    import mitsuba as mi
    wi, wo = _directions(theta)
    uv = (0.25, 0.25)                                   # the first texel
    smooth = _context(mi.BSDFFlags.GlossyTransmission | mi.BSDFFlags.DiffuseReflection)
    if what == "eval":
        return dr.sum(dr.sum(bsdf.eval(smooth, uv_interaction(len(wo), wi, uv, LAMS), jit_array(mi.Vector3f, wo.T))))
    if what == "pdf":
        return dr.sum(bsdf.pdf(smooth, uv_interaction(len(wo), wi, uv, LAMS), jit_array(mi.Vector3f, wo.T)))
    n = 400
    rng = np.random.default_rng(7)
    # sample1 in the first 40 % of each of the 4 wavelengths' shares: no row or component flips
    s1 = (rng.integers(0, 4, n) + 0.4 * rng.random(n)) / 4.0
    s2 = rng.random((2, n))
    one = mi.BSDFFlags.DiffuseReflection if key.startswith("albedo") else mi.BSDFFlags.GlossyTransmission
    bs, w = bsdf.sample(_context(one), uv_interaction(n, wi, uv, LAMS), jit_array(mi.Float, s1),
                        jit_array(mi.Point2f, s2))
    if what == "keep":
        return np.asarray(dr.detach(dr.square(bs.wo.x) + dr.square(bs.wo.y))) < 0.98
    if keep is not None:
        w = w * jit_array(mi.Float, keep)
    return dr.sum(dr.sum(w))


def _setter(params, key, textured, other):
    """x -> params[...] = x (a 2×2 bitmap's first texel when textured, the others at ``other``)."""
    import mitsuba as mi

    def put(x):
        if textured:
            data = dr.select(dr.arange(mi.UInt32, 4) == 0, x, mi.Float(float(other)))
            params[key + ".data"] = mi.TensorXf(data, shape=(2, 2, 1))
        else:
            params[key + ".value"] = x
        params.update()
    return put


CASES = [(f, k, tex) for f in FAMILIES for k in ("area_fraction", "radius", "albedo") for tex in (False, True)
         if not (f == "mixture" and k == "radius" and not tex)]     # a mixture's float radius is unused


@pytest.mark.slow
@pytest.mark.parametrize("family,key,textured", CASES)
def test_derivatives_match_central_differences(mi_variant, family, key, textured):
    import mitsuba as mi
    base = {"type": "corona", "process": "hard-disk", "area_fraction": 0.3, "albedo": 0.4, **FAMILIES[family]}
    load = {"area_fraction": (0.32, 0.2), "radius": (base.get("radius", 1.5), 1.0), "albedo": (0.4, 0.6)}[key]
    if textured:
        base[key] = bitmap_texture([[load[0], load[1]], [load[1], load[1]]])
    bsdf = mi.load_dict(base)
    params = mi.traverse(bsdf)
    if key == "area_fraction":
        rows = bsdf.fa_rows_np
        j = int(np.searchsorted(rows, 0.28)) - 1
        x, h = rows[j] + 0.35 * (rows[j + 1] - rows[j]), 0.02 * (rows[j + 1] - rows[j])
    elif key == "radius":
        x = 0.95 * load[0]
        h = 1e-3 * x
    else:
        x, h = 0.45, 0.01
    put = _setter(params, key, textured, load[1])
    for what in ("eval", "pdf", "weight"):
        for theta in THETAS:
            if key == "albedo" and what == "weight" and theta:
                continue                             # the diffuse weight does not depend on θ
            keep = None
            if what == "weight":                     # the samples away from grazing exit at x
                put(mi.Float(x))
                keep = _quantity(bsdf, "keep", key, theta)
            put(mi.Float(x + h))
            up = float(_quantity(bsdf, what, key, theta, keep)[0])
            put(mi.Float(x - h))
            down = float(_quantity(bsdf, what, key, theta, keep)[0])
            fd = (up - down) / (2 * h)
            # reverse mode
            xr = mi.Float(x)
            dr.enable_grad(xr)
            put(xr)
            y = _quantity(bsdf, what, key, theta, keep)
            dr.backward(y)
            rev = float(np.asarray(dr.grad(xr)).ravel()[0])
            # forward mode
            xf = mi.Float(x)
            dr.enable_grad(xf)
            put(xf)
            y = _quantity(bsdf, what, key, theta, keep)
            dr.forward(xf)
            fwd = float(np.asarray(dr.grad(y)).ravel()[0])
            scale = abs(up + down) * 0.5 / max(abs(x), 1e-3)       # q / x: a derivative's natural size
            label = (family, key, textured, what, theta, rev, fwd, fd)
            if abs(fd) < 1e-3 * scale:                  # no dependence (see the module docstring)
                assert abs(rev) < 1e-3 * scale and abs(fwd) < 1e-3 * scale, label
                continue
            assert abs(rev - fd) < 0.01 * abs(fd), label
            assert abs(fwd - fd) < 0.01 * abs(fd), label


# --------------------------------------------------------------------------------------------------
# renders: Mitsuba's prb against central differences of renders
# --------------------------------------------------------------------------------------------------
RES, SPP, K = 16, 128, 4        # tracing dominates the cost: many samples, few renders
RADIUS, FA, ALBEDO = 3.0, 0.3, 0.5
FOV = 20.0                                  # degrees, horizontal = vertical (square film)
LAMP_DEG, LAMP_RADIUS, LAMP_DISTANCE = (0.5, 1.0), 0.15, 20.0
FA_MAP = [[0.2, 0.31], [0.35, 0.4]]         # texel (0, 1) is differentiated


def _pixel_angles():
    """Angle [degree] between each pixel's centre direction and the lamp's centre."""
    t = np.tan(np.radians(FOV / 2)) * ((np.arange(RES) + 0.5) / RES * 2 - 1)
    dx, dy = np.meshgrid(-t, -t)            # Mitsuba's camera: image x runs along world -x
    lx, ly = (np.tan(np.radians(a)) for a in LAMP_DEG)
    cos = (dx * lx + dy * ly + 1) / np.sqrt((dx**2 + dy**2 + 1) * (lx**2 + ly**2 + 1))
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


def _weights():
    """{"moment": W for F_a / albedo, "radius": the matched filter}, zero where the lamp is seen."""
    from corona.parameters import material_from_parameters
    ang = _pixel_angles()
    lamp = np.degrees(LAMP_RADIUS / LAMP_DISTANCE) + 0.75 * FOV / RES   # the lamp and its pixel's reach
    off = ang > lamp
    d = np.sin(np.radians(ang)).ravel()[:, None] * np.array([[1.0, 0.0]])

    def halo(r):
        m = material_from_parameters(radius=r, process="hard-disk", mode="particle", area_fraction=FA)
        return sum(m.lobe(d, lam) for lam in np.linspace(420.0, 680.0, 14)).reshape(RES, RES)

    g = halo(1.01 * RADIUS) - halo(0.99 * RADIUS)
    return {"moment": off * ang / ang.max(), "radius": off * g / np.abs(g[off]).max()}


def _scene(area_fraction):
    import mitsuba as mi
    T = mi.ScalarTransform4f
    lx, ly = (LAMP_DISTANCE * np.tan(np.radians(a)) for a in LAMP_DEG)
    return mi.load_dict({
        "type": "scene", "integrator": {"type": "prb", "max_depth": 3},
        "sensor": {"type": "perspective", "fov": FOV, "fov_axis": "x",
                   "to_world": T().look_at([0, 0, 0], [0, 0, 1], [0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": RES, "height": RES, "rfilter": {"type": "box"},
                            "pixel_format": "rgb"},
                   "sampler": {"type": "independent", "sample_count": SPP}},
        "pane": {"type": "rectangle", "to_world": T().translate([0, 0, 0.5]).scale(0.2),
                 "bsdf": {"type": "corona", "radius": RADIUS, "process": "hard-disk", "mode": "particle",
                          "area_fraction": area_fraction, "albedo": ALBEDO}},
        "lamp": {"type": "sphere", "radius": LAMP_RADIUS, "center": [lx, ly, LAMP_DISTANCE],
                 "emitter": {"type": "area", "radiance": {"type": "uniform", "value": 100.0}}},
        "room": {"type": "sphere", "radius": 0.1, "center": [0.3, 0.3, -0.5],
                 "emitter": {"type": "area", "radiance": {"type": "uniform", "value": 5.0}}},
    })


def _corona(scene):
    return next(s.bsdf() for s in scene.shapes() if hasattr(s.bsdf(), "fa_rows_np"))


def _fa_step(scene, near):
    """A point inside the F_a row interval that holds ``near``, and a step that stays inside it."""
    rows = _corona(scene).fa_rows_np
    j = int(np.searchsorted(rows, near)) - 1
    lo, hi = rows[j], rows[j + 1]
    return 0.5 * (lo + hi), 0.3 * (hi - lo)


class Setup:
    """A loaded scene, the parameters to differentiate and their values, FD steps and weight images.

    ``entries``: ``{name: (key, value, h, weight name, texel or None)}``.  All
    of a scene's parameters are differentiated together (one AD kernel per
    scene and mode, which keeps the JIT compilation, most of this file's
    time, down); each weight image is one backward pass or one statistic.
    """

    def __init__(self, scene, entries, weights):
        import mitsuba as mi
        self.scene, self.entries = scene, entries
        self.params = mi.traverse(scene)
        self.weights = {k: jit_array(mi.TensorXf, np.repeat(w[..., None], 3, 2))
                        for k, w in weights.items()}
        self.base = {name: np.array(self.params[key]) for name, (key, *_) in entries.items()}

    def value_of(self, name, v=None):
        """The parameter's value with the differentiated entry set to v (a Float, or the bitmap's tensor)."""
        import mitsuba as mi
        key, value, h, w, texel = self.entries[name]
        v = value if v is None else v
        if texel is None:
            return mi.Float(v)
        a = self.base[name].copy()
        a[texel] = v
        return jit_array(mi.TensorXf, a)

    def set(self, values):
        for name, value in values.items():
            self.params[self.entries[name][0]] = value
        self.params.update()

    def finite_differences(self, name):
        """K central differences of the statistic of ``name`` (each pair with one seed)."""
        import mitsuba as mi
        key, value, h, w, texel = self.entries[name]
        out = []
        for s in range(K):
            stats = []
            for v in (value + h, value - h):
                self.set({name: self.value_of(name, v)})
                stats.append(float(dr.sum(mi.render(self.scene, seed=s) * self.weights[w], axis=None).array[0]))
            out.append((stats[0] - stats[1]) / (2 * h))
        self.set({name: self.value_of(name)})
        return np.array(out)

    def derivatives(self, mode):
        """{name: K derivatives of its statistic} in ``reverse`` or ``forward`` mode."""
        import mitsuba as mi
        names = list(self.entries)
        out = {name: [] for name in names}
        for s in range(K):
            xs = {name: self.value_of(name) for name in names}
            for x in xs.values():
                dr.enable_grad(x)
            self.set(xs)
            if mode == "reverse":
                for w in sorted({self.entries[n][3] for n in names}):
                    img = mi.render(self.scene, self.params, seed=1000 + s, seed_grad=2000 + s)
                    dr.backward(dr.sum(img * self.weights[w], axis=None))
                    for name in names:
                        if self.entries[name][3] == w:
                            g, texel = np.array(dr.grad(xs[name])), self.entries[name][4]
                            out[name].append(float(g[texel] if texel is not None else g.ravel()[0]))
                    for x in xs.values():
                        dr.clear_grad(x)
            else:
                for name in names:                      # a tangent along one parameter (one texel)
                    img = mi.render(self.scene, self.params, seed=1000 + s, seed_grad=2000 + s)
                    y = dr.sum(img * self.weights[self.entries[name][3]], axis=None)
                    for other, x in xs.items():
                        texel = self.entries[other][4]
                        e = np.zeros(np.shape(self.base[other]) if texel is not None else 1, np.float32)
                        if other == name:
                            e[texel if texel is not None else 0] = 1.0
                        dr.set_grad(x, jit_array(mi.TensorXf, e) if texel is not None else dr.opaque(mi.Float, float(e[0])))
                        dr.enqueue(dr.ADMode.Forward, x)
                    dr.traverse(dr.ADMode.Forward)
                    out[name].append(float(dr.grad(y).array[0]))
            # detached values back in the scene, so that later traversals start clean
            self.set({name: dr.detach(x) for name, x in xs.items()})
        return {name: np.array(v) for name, v in out.items()}


def _setups():
    """The uniform layer (F_a, radius, albedo) and the textured one (one texel of F_a, and radius)."""
    weights = _weights()
    uniform, textured = _scene(FA), _scene(bitmap_texture(FA_MAP))
    fa, h_fa = _fa_step(uniform, FA + 1e-3)
    fa_t, h_t = _fa_step(textured, FA_MAP[0][1])
    return (Setup(uniform, {"area_fraction": ("pane.bsdf.area_fraction.value", fa, h_fa, "moment", None),
                            "radius": ("pane.bsdf.radius.value", RADIUS, 0.01 * RADIUS, "radius", None),
                            "albedo": ("pane.bsdf.albedo.value", ALBEDO, 0.05, "moment", None)}, weights),
            Setup(textured, {"area_fraction texel": ("pane.bsdf.area_fraction.data", fa_t, h_t, "moment",
                                                     (0, 1, 0)),
                             "radius": ("pane.bsdf.radius.value", RADIUS, 0.01 * RADIUS, "radius", None)},
                  weights))


def _agree(name, fd, ad):
    se = np.hypot(fd.std(ddof=1), ad.std(ddof=1)) / np.sqrt(K)
    diff = ad.mean() - fd.mean()
    info = (f"{name}: AD {ad.mean():.4g}, FD {fd.mean():.4g}, difference {diff / fd.mean():+.3f} "
            f"of FD = {diff / se:+.2f} standard errors (standard error {se / abs(fd.mean()):.3f} of FD)")
    assert se < 0.05 * abs(fd.mean()), "too noisy to test: " + info
    assert abs(diff) < 3 * se + 0.005 * abs(fd.mean()), info


@pytest.fixture(scope="module")
def reverse(mi_variant):
    """Reverse-mode derivatives and finite differences, default (spectral) variant."""
    uniform, textured = _setups()
    ad = {**uniform.derivatives("reverse"), "area_fraction texel": textured.derivatives("reverse")["area_fraction texel"]}
    return ad, {"area_fraction": uniform, "radius": uniform, "albedo": uniform, "area_fraction texel": textured}


@pytest.mark.slow
@pytest.mark.parametrize("name", ["area_fraction", "radius", "albedo", "area_fraction texel"])
def test_reverse_mode_render_gradient_matches_finite_differences(reverse, name):
    ad, setups = reverse
    _agree(name, setups[name].finite_differences(name), ad[name])


@pytest.fixture(scope="module")
def forward(mi_variant):
    """Forward-mode derivatives (radius and one texel of F_a, textured layer) and finite
    differences in ``llvm_ad_rgb``."""
    import mitsuba as mi

    import corona
    from corona.apps.render import setup_variant
    setup_variant("llvm_ad_rgb")
    corona.register()
    try:
        _, textured = _setups()
        ad = textured.derivatives("forward")
        yield {name: (textured.finite_differences(name), ad[name]) for name in ad}
    finally:
        mi.set_variant(mi_variant)


@pytest.mark.slow
@pytest.mark.parametrize("name", ["radius", "area_fraction texel"])
def test_forward_mode_render_gradient_matches_finite_differences(forward, name):
    fd, ad = forward[name]
    _agree(name, fd, ad)


@pytest.mark.slow
@pytest.mark.render
def test_coherent_paths_add_nothing_spurious(mi_variant):
    """The pane against a uniformly bright sky: every pixel sees the sky through the coherent beam.

    ``prb`` leaves the derivative of the delta paths out entirely, so its
    gradient plus the coherent beam's own derivative, ``∂(1 - F_a)²/∂F_a · B``
    (B the sky as the camera sees it without the pane), must equal the finite
    differences of the renders: about -1 per unit F_a, the layer transmitting
    ``1 - F_a``.  Before the plugin returned 0 for ``eval`` along the delta
    directions, ``prb`` re-evaluated the lobe there and added ``L ∂ ln f(0)/∂F_a``
    along every coherent path: 7× the true lobe derivative at F_a = 0.1.
    """
    import mitsuba as mi
    T = mi.ScalarTransform4f
    sky = {"type": "constant", "radiance": {"type": "uniform", "value": 1.0}}
    sensor = {"type": "perspective", "fov": FOV, "to_world": T().look_at([0, 0, 0], [0, 0, 1], [0, 1, 0]),
              "film": {"type": "hdrfilm", "width": RES, "height": RES, "rfilter": {"type": "box"},
                       "pixel_format": "rgb"},
              "sampler": {"type": "independent", "sample_count": SPP}}
    clear = mi.load_dict({"type": "scene", "integrator": {"type": "prb"}, "sensor": sensor, "sky": sky})
    b = float(dr.mean(mi.render(clear, spp=4 * SPP), axis=None).array[0])
    scene = mi.load_dict({"type": "scene", "integrator": {"type": "prb", "max_depth": 3}, "sensor": sensor,
                          "sky": sky, "pane": {"type": "rectangle", "to_world": T().translate([0, 0, 0.5]),
                                               "bsdf": {"type": "corona", "radius": RADIUS, "process": "hard-disk",
                                                        "mode": "particle", "area_fraction": 0.1}}})
    fa, h = _fa_step(scene, 0.1 + 1e-3)
    setup = Setup(scene, {"area_fraction": ("pane.bsdf.area_fraction.value", fa, h, "all", None)},
                  {"all": np.ones((RES, RES)) / (RES * RES * 3)})
    fd = setup.finite_differences("area_fraction")
    ad = setup.derivatives("reverse")["area_fraction"] - 2 * (1 - fa) * b
    _agree("area_fraction against the sky", fd, ad)
    assert abs(fd.mean() / b + 1) < 0.03          # the layer transmits 1 - F_a (hard disks)


# --------------------------------------------------------------------------------------------------
# inverse rendering: examples/fit_window.py, reduced
# --------------------------------------------------------------------------------------------------
@pytest.mark.slow
def test_fit_window_recovers_radius_area_fraction_and_bitmap(mi_variant):
    sys.path.insert(0, os.path.join(ROOT, "examples"))
    try:
        import fit_window
    finally:
        sys.path.pop(0)
    res = fit_window.quick(log=lambda *a: None)
    u, b = res["uniform"], res["bitmap"]
    assert abs(u["radius_error"]) < 0.02, u
    assert abs(u["area_fraction_error"]) < 0.05, u
    assert b["max_texel_error"] < 0.10, {k: v for k, v in b.items() if k not in ("truth", "fit")}
    # and it did fit: the start was 10 % / 20 % off, the bitmap's start 0.3 everywhere
    assert u["loss_last"] < 0.5 * u["loss_first"] and b["loss_last"] < 0.5 * b["loss_first"]


@pytest.mark.slow     # forward-mode AD, a kernel compiled per case
@pytest.mark.parametrize("key", ["area_fraction", "albedo"])
def test_derivative_at_a_texture_least_value(mi_variant, key):
    # the texel under the shading point holds the texture's least value: the start of the F_a rows'
    # cover (area_fraction) or 0 (albedo). The lane's value is clipped to the range; on the bound
    # itself the derivative is the texel's (Dr.Jit's clip passes the bound's, 0: such a texel had
    # none, AD 0 against a finite difference). Against the one-sided difference of second order
    # (x + h and x + 2h stay in the texture's range: the other texels hold the larger value).
    import mitsuba as mi
    x, hi, h, what = {"area_fraction": (0.2, 0.35, 2e-4, "eval"), "albedo": (0.0, 0.6, 1e-2, "eval")}[key]
    base = {"type": "corona", "process": "hard-disk", "area_fraction": 0.3, "albedo": 0.4, "radius": 2.0,
            key: bitmap_texture([[x, hi], [hi, hi]])}
    bsdf = mi.load_dict(base)
    params = mi.traverse(bsdf)
    put = _setter(params, key, True, hi)
    q = []
    for k in (0, 1, 2):
        put(mi.Float(x + k * h))
        q.append(float(_quantity(bsdf, what, key, 30.0)[0]))
    fd = (4.0 * q[1] - 3.0 * q[0] - q[2]) / (2.0 * h)
    xf = mi.Float(x)
    dr.enable_grad(xf)
    put(xf)
    y = _quantity(bsdf, what, key, 30.0)
    dr.forward(xf)
    ad = float(np.asarray(dr.grad(y)).ravel()[0])
    assert abs(fd) > 1e-3 * abs(q[0]) and abs(ad - fd) < 0.01 * abs(fd), (ad, fd)


def test_hermite_rows_reproduce_a_parabola(mi_variant):
    # a uniform layer's rows recentred at F_a on each update (corona.mitsuba.common.hermite_rows):
    # the slopes are the parabola's through each row and its neighbours (one-sided at the ends), so
    # rows of a quadratic in x are interpolated exactly, value and derivative, in every interval
    # of uneven rows (the first and the last too, and just outside, clamped to the end row); two
    # rows: a straight line.  A slope taken from the wrong rows fails this by far more than 1e-9.
    from corona.mitsuba.common import hermite_rows
    rng = np.random.default_rng(3)
    for n in (2, 3, 4, 7, 40):
        x = np.sort(rng.uniform(0.0, 1.0, n))
        c = rng.normal(size=(3, 2, 3))                       # a quadratic per entry of a (2, 3) row
        quad = 0.0 if n == 2 else 1.0
        f = lambda v: c[0] + c[1] * v + quad * c[2] * v * v
        df = lambda v: c[1] + 2 * quad * c[2] * v
        rows = np.stack([f(v) for v in x])
        for at in np.concatenate([x, 0.5 * (x[1:] + x[:-1]), rng.uniform(x[0], x[-1], 20)]):
            v, dv = hermite_rows(x, rows, at)
            assert np.allclose(v, f(at), rtol=0, atol=1e-9) and np.allclose(dv, df(at), rtol=0, atol=1e-7), (n, at)
        for at, end in ((x[0] - 0.1, x[0]), (x[-1] + 0.1, x[-1])):
            v, dv = hermite_rows(x, rows, at)
            assert np.allclose(v, f(end), rtol=0, atol=1e-9), (n, at)
