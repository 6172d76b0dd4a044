"""Derivatives of the corona BSDF against central finite differences of the same loaded BSDF.

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
"""
import drjit as dr
import numpy as np
import pytest

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


def _si(n, wi, uv):
    import mitsuba as mi
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(*[float(x) for x in wi])
    si.uv = mi.Point2f(float(uv[0]), float(uv[1]))
    si.wavelengths = mi.Spectrum(*LAMS)
    return si


def _context(flags):
    import mitsuba as mi
    ctx = mi.BSDFContext()
    ctx.type_mask = flags
    return ctx


def _quantity(bsdf, what, key, theta):
    """The scalar q(bsdf) whose derivative is tested: a sum over directions or samples."""
    import mitsuba as mi
    wi, wo = _directions(theta)
    uv = (0.25, 0.25)                                   # the first texel
    smooth = _context(mi.BSDFFlags.GlossyTransmission | mi.BSDFFlags.DiffuseReflection)
    if what == "eval":
        return dr.sum(dr.sum(bsdf.eval(smooth, _si(len(wo), wi, uv), mi.Vector3f(wo.T))))
    if what == "pdf":
        return dr.sum(bsdf.pdf(smooth, _si(len(wo), wi, uv), mi.Vector3f(wo.T)))
    n = 400
    rng = np.random.default_rng(7)
    # sample1 in the first 40 % of each of the 4 wavelengths' shares: no row or component flips
    s1 = (rng.integers(0, 4, n) + 0.4 * rng.random(n)) / 4.0
    s2 = rng.random((2, n))
    one = mi.BSDFFlags.DiffuseReflection if key.startswith("albedo") else mi.BSDFFlags.GlossyTransmission
    bs, w = bsdf.sample(_context(one), _si(n, wi, uv), mi.Float(s1.astype(np.float32)),
                        mi.Point2f(s2.astype(np.float32)))
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


def _bitmap(values):
    import mitsuba as mi
    first, other = values
    return {"type": "bitmap", "bitmap": mi.Bitmap(np.array([[first, other], [other, other]], np.float32)[..., None]),
            "raw": True, "filter_type": "nearest"}


CASES = [(f, k, tex) for f in FAMILIES for k in ("area_fraction", "radius", "albedo") for tex in (False, True)
         if not (f == "mixture" and k == "radius" and not tex)]     # a mixture's float radius is unused


@pytest.mark.parametrize("family,key,textured", CASES)
def test_derivatives_match_central_differences(mi_variant, family, key, textured):
    import mitsuba as mi
    base = {"type": "corona", "process": "hard-disk", "area_fraction": 0.3, "albedo": 0.4, **FAMILIES[family]}
    load = {"area_fraction": (0.32, 0.2), "radius": (base.get("radius", 1.5), 1.0), "albedo": (0.4, 0.6)}[key]
    if textured:
        base[key] = _bitmap(load)
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
            put(mi.Float(x + h))
            up = float(_quantity(bsdf, what, key, theta)[0])
            put(mi.Float(x - h))
            down = float(_quantity(bsdf, what, key, theta)[0])
            fd = (up - down) / (2 * h)
            # reverse mode
            xr = mi.Float(x)
            dr.enable_grad(xr)
            put(xr)
            y = _quantity(bsdf, what, key, theta)
            dr.backward(y)
            rev = float(np.asarray(dr.grad(xr)).ravel()[0])
            # forward mode
            xf = mi.Float(x)
            dr.enable_grad(xf)
            put(xf)
            y = _quantity(bsdf, what, key, theta)
            dr.forward(xf)
            fwd = float(np.asarray(dr.grad(y)).ravel()[0])
            scale = abs(up + down) * 0.5 / max(abs(x), 1e-3)       # q / x: a derivative's natural size
            label = (family, key, textured, what, theta, rev, fwd, fd)
            if abs(fd) < 1e-3 * scale:                  # no dependence (see the module docstring)
                assert abs(rev) < 1e-3 * scale and abs(fwd) < 1e-3 * scale, label
                continue
            assert abs(rev - fd) < 0.01 * abs(fd), label
            assert abs(fwd - fd) < 0.01 * abs(fd), label
