"""Derivatives of sphere layers against central finite differences of the same loaded BSDF.

A layer of Mie spheres with Poisson centres exposes ``area_fraction`` to
``mi.traverse`` (``area_fraction.value``, or a bitmap's ``area_fraction.data``):
it enters the shadow fraction ``F_s = min(F_a/μ_i, 1)``, the coherent beam
``|1 - F_s s₀|²``, the lobe weight's cap ``w`` and, through the components'
energies, the selection probabilities in the pdf.  Reverse and forward
derivatives of ``eval``, ``pdf`` and the sample weights agree with
``(q(x + h) - q(x - h)) / 2h``, ``q(x)`` the same BSDF after
``params[key] = x; params.update()``, within 1 % at several incidences, on
its own and on a glass pane.  The sample weights are taken with the forward
lobe alone enabled (the sampled direction then does not depend on F_a: no
component flips between ``x ± h``).

With hard-disk or rsa centres ``S(q)`` and the cap's energies are cubic
Hermite interpolations between F_a rows (continuously differentiable): ``x``
sits 35 % into a row interval and ``h`` keeps ``x ± h`` inside it.

``radius`` (``radius.value``, or a bitmap's ``radius.data``) sets the size
parameter ``x = 2π r/λ`` of every wavelength: the rows are linear in x between
them (the derivative jumps at a row), so the radius sits mid-row for every test
wavelength and ``h`` keeps ``r ± h`` between the same rows.  ``albedo`` means
nothing for a sphere: it is not exposed, which the second test checks.

Each test runs some cases in both of the plugin's backend branches (fixture ``upload_branch``:
LLVM's tables written in place, CUDA's uploaded).  With the upload branch on in an LLVM
variant, a bitmap's texels are also written in place into the texture's memory, as
``params.update()`` does on CUDA (``dr.Texture.set_value``: ``jit_tex_memcpy_d2t`` into the
hardware texture, no copy): a computation still pending from before the update reads the new
texels there, so the sample weights at ``x + h`` are evaluated before ``x - h`` is set.
"""
import warnings

import drjit as dr
import numpy as np
import pytest

LAMS = (450.0, 520.0, 600.0, 700.0)
THETAS = (0.0, 30.0, 60.0)


def _directions(theta, n=400, seed=2):
    """Directions around the forward and the backward peak, and scattered ones."""
    rng = np.random.default_rng(seed)
    th = np.radians(theta)
    wi = np.array([np.sin(th), 0.0, np.cos(th)])
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    fwd = -wi + rng.normal(0.0, 0.08, (n, 3))
    fwd /= np.linalg.norm(fwd, axis=1, keepdims=True)
    back = wi + rng.normal(0.0, 0.3, (n // 2, 3))
    back /= np.linalg.norm(back, axis=1, keepdims=True)
    return wi, np.concatenate([v, fwd, back])


def _si(n, wi):
    import mitsuba as mi
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(*[float(x) for x in wi])
    si.uv = mi.Point2f(0.25, 0.25)                       # the bitmap's first texel
    si.wavelengths = mi.Spectrum(*LAMS)
    return si


def _quantity(bsdf, what, theta):
    import mitsuba as mi
    wi, wo = _directions(theta)
    ctx = mi.BSDFContext()
    ctx.type_mask = mi.BSDFFlags.GlossyTransmission | mi.BSDFFlags.GlossyReflection
    if what == "eval":
        return dr.sum(dr.sum(bsdf.eval(ctx, _si(len(wo), wi), mi.Vector3f(wo.T))))
    if what == "pdf":   # every component on: the lobes' share of the selection depends on F_a
        return dr.sum(bsdf.pdf(mi.BSDFContext(), _si(len(wo), wi), mi.Vector3f(wo.T)))
    n = 500
    rng = np.random.default_rng(7)
    one = mi.BSDFContext()
    one.type_mask = mi.BSDFFlags.GlossyTransmission        # the forward lobe alone
    bs, w = bsdf.sample(one, _si(n, wi), mi.Float(rng.random(n).astype(np.float32)),
                        mi.Point2f(rng.random((2, n)).astype(np.float32)))
    return dr.sum(dr.sum(w))


def _bitmap(first, lo, hi):
    import mitsuba as mi
    return {"type": "bitmap", "bitmap": mi.Bitmap(np.array([[first, lo], [hi, lo]], np.float32)[..., None]),
            "raw": True, "filter_type": "nearest"}


def _loaded(base, pane, name, textured):
    """(bsdf, its parameters, the key of ``name`` in them: a bitmap's ``.data``, else ``.value``)."""
    import mitsuba as mi
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        bsdf = mi.load_dict({**base, **({"substrate": "glass"} if pane else {})})
    params = mi.traverse(bsdf)
    key = f"{name}.data" if textured else f"{name}.value"
    assert key in params
    return bsdf, params, key


def _setter(params, key, textured, lo, hi, in_place=False):
    """``put(v)``: the parameter ``key`` set to ``v`` (a bitmap: its first texel, the others
    ``lo``, ``hi``, ``lo``) and the scene updated.  ``in_place`` (a bitmap in an LLVM variant, ``v``
    without a gradient): the texels written into the texture's own memory, as CUDA's
    ``params.update()`` writes a hardware texture (see the module docstring)."""
    import mitsuba as mi

    def put(v):
        if textured:
            if in_place and not dr.grad_enabled(v):
                tensor = params[key]
                view = np.asarray(tensor.array)
                want = np.array([float(np.asarray(v).ravel()[0]), lo, hi, lo], np.float32)
                assert view.flags.writeable and view.size == 4, "the texture's memory is not writable here"
                view[:] = want
                assert np.array_equal(np.asarray(tensor.array + 0.0), want), "a copy, not the texture's memory"
                params.set_dirty(key)
            else:
                i = dr.arange(mi.UInt32, 4)
                data = dr.select(i == 0, v, dr.select(i == 2, mi.Float(hi), mi.Float(lo)))
                params[key] = mi.TensorXf(data, shape=(2, 2, 1))
        else:
            params[key] = v
        params.update()
    return put


def _in_place_texels(mi_variant, upload_branch):
    """Whether :func:`_setter` writes a bitmap's texels in place (the upload branch in LLVM)."""
    return upload_branch and mi_variant.startswith("llvm")


def _assert_ad_matches(put, quantity, x, h, up, down, label):
    """Reverse and forward derivatives of ``quantity()`` at ``x`` within 1 % of the central
    difference ``(up - down) / 2h``, which must not vanish (the parameter matters)."""
    import mitsuba as mi
    fd = (up - down) / (2 * h)
    xr = mi.Float(x)
    dr.enable_grad(xr)
    put(xr)
    dr.backward(quantity())
    rev = float(np.asarray(dr.grad(xr)).ravel()[0])
    xf = mi.Float(x)
    dr.enable_grad(xf)
    put(xf)
    y = quantity()
    dr.forward(xf)
    fwd = float(np.asarray(dr.grad(y)).ravel()[0])
    label = (*label, rev, fwd, fd)
    assert abs(fd) > 1e-2 * abs(up + down) * 0.5 / x, label
    assert abs(rev - fd) < 0.01 * abs(fd), label
    assert abs(fwd - fd) < 0.01 * abs(fd), label


CASES = ([("poisson", tex, pane) for tex in (False, True) for pane in (False, True)]
         + [("hard-disk", tex, False) for tex in (False, True)] + [("rsa", False, True)])
#: the cases run in the upload branch as well (each case costs seconds: two of each test)
UPLOAD_CASES = (("poisson", True, True), ("hard-disk", True, False))
_BRANCHES = lambda cases: [(*c, False) for c in cases] + [(*c, True) for c in cases if c in UPLOAD_CASES]


@pytest.mark.parametrize("process,textured,pane,upload_branch", _BRANCHES(CASES), ids=lambda v: str(v),
                         indirect=["upload_branch"])
def test_area_fraction_derivatives_match_central_differences(mi_variant, upload_branch, process, textured, pane):
    import mitsuba as mi
    # a hard core: x sits 35 % into an interval of the F_a rows (uniform: 0.2 ± 0.05; the texture:
    # 0.05 … 0.35), x ± h inside it
    x, h, lo, hi = (0.2, 0.002, 0.05, 0.35) if process == "poisson" else (0.2175, 0.001, 0.05, 0.35)
    base = {"type": "corona", "shape": "sphere", "radius": 2.0, "process": process,
            "area_fraction": _bitmap(x, lo, hi) if textured else (0.2 if process != "poisson" else x)}
    bsdf, params, key = _loaded(base, pane, "area_fraction", textured)

    put = _setter(params, key, textured, lo, hi, _in_place_texels(mi_variant, upload_branch))

    for what in ("eval", "pdf", "weight"):     # F_a matters for all three
        for theta in THETAS:
            quantity = lambda: _quantity(bsdf, what, theta)
            put(mi.Float(x + h))
            up = float(quantity()[0])
            put(mi.Float(x - h))
            down = float(quantity()[0])
            _assert_ad_matches(put, quantity, x, h, up, down, (textured, pane, what, theta))


def test_nothing_else_is_exposed(mi_variant):
    # the albedo is no parameter of a sphere layer: the scene's parameters do not hold it (a
    # derivative would be detached, not 0); area_fraction is checked on update
    import mitsuba as mi
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        hd = mi.load_dict({"type": "corona", "shape": "sphere", "radius": 2.0, "process": "hard-disk",
                           "area_fraction": 0.3, "albedo": 0.5})
        poisson = mi.load_dict({"type": "corona", "shape": "sphere", "radius": 2.0, "process": "poisson",
                                "area_fraction": 0.3})
    assert set(mi.traverse(hd).keys()) == {"area_fraction.value", "radius.value"}
    assert set(mi.traverse(poisson).keys()) == {"area_fraction.value", "radius.value"}
    params = mi.traverse(poisson)
    params["area_fraction.value"] = 1.5
    with pytest.raises(Exception, match=r"area_fraction=1.5 … 1.5 is out of range for shape='sphere'; allowed \(0, 1\)"):
        params.update()


def _mid_row_radius(bsdf, near, h):
    """A radius near ``near`` [µm] where every test wavelength's ``x = 2π r/λ`` sits between 20 % and
    80 % of a row interval of the loaded layer's rows and ``r ± h`` stays in that interval: the
    lookup is linear in x between rows (its derivative jumps at the rows), so a central difference
    across a row would not be the derivative AD takes.  ``r ± h`` also spans at most 10 % of each
    interval: the lobe weight is a ratio of quantities linear in x, whose central difference over a
    large part of a narrow interval at a resonance (rows 0.0015-0.005 apart) is off by O(Δt²)."""
    xr = bsdf.material.rows["x"]
    for r in near * (1.0 + np.linspace(0.0, 0.01, 2001)):
        ok = True
        for lam in LAMS:
            x = 2 * np.pi * r / (lam * 1e-3)
            j = np.searchsorted(xr, x, side="right") - 1
            t = (x - xr[j]) / (xr[j + 1] - xr[j])
            span = [np.searchsorted(xr, 2 * np.pi * rr / (lam * 1e-3), side="right") - 1 for rr in (r - h, r + h)]
            reach = 2 * np.pi * 2 * h / (lam * 1e-3) / (xr[j + 1] - xr[j])
            ok &= 0.2 < t < 0.8 and span == [j, j] and reach <= 0.1
        if ok:
            return float(np.float32(r))
    raise AssertionError("no radius with every wavelength mid-row")


def _samples(bsdf, theta, n=500):
    """(directions, weights) of ``sample`` with the forward lobe alone (per sample)."""
    import mitsuba as mi
    wi, _ = _directions(theta)
    rng = np.random.default_rng(7)
    one = mi.BSDFContext()
    one.type_mask = mi.BSDFFlags.GlossyTransmission
    bs, w = bsdf.sample(one, _si(n, wi), mi.Float(rng.random(n).astype(np.float32)),
                        mi.Point2f(rng.random((2, n)).astype(np.float32)))
    return bs.wo, dr.sum(w)


RADIUS_CASES = ([("poisson", tex, pane) for tex in (False, True) for pane in (False, True)]
                + [("hard-disk", tex, pane) for tex in (False, True) for pane in (False, True)])


@pytest.mark.slow     # reverse-mode AD of a sphere layer, a kernel compiled per case: 6-28 s of CPU each, cold
@pytest.mark.parametrize("process,textured,pane,upload_branch", _BRANCHES(RADIUS_CASES), ids=lambda v: str(v),
                         indirect=["upload_branch"])
def test_radius_derivatives_match_central_differences(mi_variant, upload_branch, process, textured, pane):
    # radius.value (uniform) or radius.data (a bitmap's texel under the shading point): x = 2π r/λ
    # moves every wavelength along the rows (linear in x between them), the chord scale x_row/x of
    # both rows and S(q r) with a hard core.  r sits mid-row for every wavelength (_mid_row_radius)
    # and h = 1e-5 r keeps r ± h in those row intervals.  The sample weights are compared on the
    # samples whose direction moves continuously between r ± h: a sample whose row (picked with
    # probability ∝ t T_j+1) flips between them jumps and has no derivative there.
    import mitsuba as mi
    lo, hi = 1.97, 2.03                                     # the texture's other texels (water: within its span)
    base = {"type": "corona", "shape": "sphere", "process": process, "area_fraction": 0.2,
            "radius": _bitmap(2.0, lo, hi) if textured else 2.0}
    bsdf, params, key = _loaded(base, pane, "radius", textured)
    h = 2e-5
    x = _mid_row_radius(bsdf, 2.0, h)

    put = _setter(params, key, textured, lo, hi, _in_place_texels(mi_variant, upload_branch))

    material = bsdf.material
    for what in ("eval", "pdf", "weight"):
        for theta in THETAS:
            if what == "weight":
                # each evaluated before the next update: on CUDA a pending kernel reads a bitmap's
                # texels as they are when it runs (the module docstring)
                put(mi.Float(x + h))
                wo_up, w_up = _samples(bsdf, theta)
                dr.eval(wo_up, w_up)
                put(mi.Float(x - h))
                wo_down, w_down = _samples(bsdf, theta)
                dr.eval(wo_down, w_down)
                # a continuous sample's chord |wo + wi| scales as 1/r: it moves by about chord · 2h/r
                wi = _directions(theta)[0]
                chord = np.linalg.norm(np.asarray(wo_up) + wi[:, None], axis=0)
                move = np.linalg.norm(np.asarray(wo_up) - np.asarray(wo_down), axis=0) / (chord * 2 * h / x)
                keep = move < 3.0
                assert keep.mean() > 0.8, np.sort(move)[::25]
                mask = mi.Float(keep.astype(np.float32))
                quantity = lambda: dr.sum(_samples(bsdf, theta)[1] * mask)
                up, down = float(np.sum(np.asarray(w_up) * keep)), float(np.sum(np.asarray(w_down) * keep))
            else:
                quantity = lambda: _quantity(bsdf, what, theta)
                put(mi.Float(x + h))
                up = float(quantity()[0])
                put(mi.Float(x - h))
                down = float(quantity()[0])
            _assert_ad_matches(put, quantity, x, h, up, down, (process, textured, pane, what, theta))
    assert bsdf.material is material                          # no rebuild: r ± h inside the rows' radii
