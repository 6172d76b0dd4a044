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
them (the derivative jumps at a row), so each lane's wavelengths sit mid-row and
``h`` keeps ``r ± h`` between the same rows.  A relative step of 1e-5 is a few
hundred float32 steps of x: with the same wavelengths in every lane their
roundings were one offset of the central difference (0.5-1 %, a sample weight's
-577.6 against -581.9); lane by lane they average out, and the comparison holds
to 0.3 %.  ``albedo`` means nothing for a sphere: it is not exposed, which the
second test checks.

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

from bsdf_checks import jit_array

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


def _si(n, wi, lams=None):
    """``n`` lanes at ``wi``: the wavelengths :data:`LAMS` in every lane, or lane i's from ``lams[:, i]``."""
    import mitsuba as mi
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(*[float(x) for x in wi])
    si.uv = mi.Point2f(0.25, 0.25)                       # the bitmap's first texel
    si.wavelengths = (mi.Spectrum(*LAMS) if lams is None else
                      jit_array(mi.Spectrum, np.asarray(lams)[:, :n]))
    return si


def _quantity(bsdf, what, theta, lams=None, n_dirs=400):
    """``what`` (eval, pdf or the sample weight) lane by lane: the test sums it in float64
    (:func:`_total`; a float32 sum of thousands of lanes would round away the central difference)."""
    import mitsuba as mi
    wi, wo = _directions(theta, n_dirs)
    ctx = mi.BSDFContext()
    ctx.type_mask = mi.BSDFFlags.GlossyTransmission | mi.BSDFFlags.GlossyReflection
    if what == "eval":
        return dr.sum(bsdf.eval(ctx, _si(len(wo), wi, lams), jit_array(mi.Vector3f, wo.T)))
    if what == "pdf":   # every component on: the lobes' share of the selection depends on F_a
        return bsdf.pdf(mi.BSDFContext(), _si(len(wo), wi, lams), jit_array(mi.Vector3f, wo.T))
    n = 500
    rng = np.random.default_rng(7)
    one = mi.BSDFContext()
    one.type_mask = mi.BSDFFlags.GlossyTransmission        # the forward lobe alone
    bs, w = bsdf.sample(one, _si(n, wi, lams), jit_array(mi.Float, rng.random(n)),
                        jit_array(mi.Point2f, rng.random((2, n))))
    return dr.sum(w)


def _total(values):
    """The float64 sum of per-lane values."""
    return float(np.sum(np.asarray(values, dtype=np.float64)))


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


def _assert_ad_matches(put, quantity, x, h, up, down, label, rtol=0.01):
    """Reverse and forward derivatives of the sum over the lanes of ``quantity()`` at ``x`` within
    ``rtol`` of the central difference ``(up - down) / 2h``, which must not vanish (the parameter
    matters)."""
    import mitsuba as mi
    fd = (up - down) / (2 * h)
    xr = mi.Float(x)
    dr.enable_grad(xr)
    put(xr)
    dr.backward(quantity())                 # every lane seeded with 1: the sum's derivative
    rev = float(np.asarray(dr.grad(xr)).ravel()[0])
    xf = mi.Float(x)
    dr.enable_grad(xf)
    put(xf)
    y = quantity()
    dr.forward(xf)
    fwd = _total(dr.grad(y))
    label = (*label, rev, fwd, fd)
    assert abs(fd) > 1e-2 * abs(up + down) * 0.5 / x, label
    assert abs(rev - fd) < rtol * abs(fd), label
    assert abs(fwd - fd) < rtol * abs(fd), label


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
            up = _total(quantity())
            put(mi.Float(x - h))
            down = _total(quantity())
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


def _mid_row_lams(bsdf, r, h, n, seed=5):
    """Wavelengths [nm], (4, n): lane i's ``lams[:, i]``, each drawn in 420-690 nm and moved so that its
    ``x = 2π r/λ`` sits between 20 % and 80 % of a row interval of the loaded layer's rows with
    ``r ± h`` spanning at most 10 % of it.  The lookup is linear in x between rows (its derivative
    jumps at the rows), so a central difference across a row would not be the derivative AD takes;
    the lobe weight is a ratio of quantities linear in x, whose central difference over a large part
    of a narrow interval at a resonance (rows 0.0015-0.005 apart) is off by O(Δt²).  Each lane has
    wavelengths of its own: the float32 roundings of ``x(r ± h)`` (``2h/r = 2e-5``: a rounding of x,
    of ``x/x_row`` or of r ± h is up to 0.3-0.7 % of the step) then differ lane by lane and average
    out in the sums, where with the same wavelengths in every lane they are one offset of the
    central difference (with :data:`LAMS`: 0.5-1 %)."""
    xr = bsdf.material.rows["x"]
    rng = np.random.default_rng(seed)
    lam = rng.uniform(420.0, 690.0, (4, n))
    while True:
        x = 2 * np.pi * r / (lam * 1e-3)
        j = np.searchsorted(xr, x, side="right") - 1
        width = xr[j + 1] - xr[j]
        bad = 2 * np.pi * 2 * h / (lam * 1e-3) > 0.1 * width
        if not bad.any():
            break
        lam[bad] = rng.uniform(420.0, 690.0, int(bad.sum()))
    x = xr[j] + rng.uniform(0.2, 0.8, lam.shape) * width
    return 2 * np.pi * r / (x * 1e-3)


def _samples(bsdf, theta, n=500, lams=None):
    """(directions, weights) of ``sample`` with the forward lobe alone (per sample)."""
    import mitsuba as mi
    wi, _ = _directions(theta)
    rng = np.random.default_rng(7)
    one = mi.BSDFContext()
    one.type_mask = mi.BSDFFlags.GlossyTransmission
    bs, w = bsdf.sample(one, _si(n, wi, lams), jit_array(mi.Float, rng.random(n)),
                        jit_array(mi.Point2f, rng.random((2, n))))
    return bs.wo, dr.sum(w)


RADIUS_CASES = ([("poisson", tex, pane) for tex in (False, True) for pane in (False, True)]
                + [("hard-disk", tex, pane) for tex in (False, True) for pane in (False, True)])


@pytest.mark.slow     # reverse-mode AD of a sphere layer, a kernel compiled per case: 6-28 s of CPU each, cold
@pytest.mark.parametrize("process,textured,pane,upload_branch", _BRANCHES(RADIUS_CASES), ids=lambda v: str(v),
                         indirect=["upload_branch"])
def test_radius_derivatives_match_central_differences(mi_variant, upload_branch, process, textured, pane):
    # radius.value (uniform) or radius.data (a bitmap's texel under the shading point): x = 2π r/λ
    # moves every wavelength along the rows (linear in x between them), the chord scale x_row/x of
    # both rows and S(q r) with a hard core.  Each lane's wavelengths sit mid-row (_mid_row_lams)
    # and h ≈ 1e-5 r keeps r ± 2h in those row intervals; r ± h are float32 values (the step taken
    # is 2h exactly) and every lane is summed in float64.  The sample weights are compared on the
    # samples whose direction moves continuously between r ± h: a sample whose row (picked with
    # probability ∝ t T_j+1) flips between them jumps (often by less than the continuous move: the
    # rows' chords line up at a fixed x·s) and has no derivative there.  Within 0.3 % (the
    # reference is good to about 0.05 % here): a term of 1 % missing from the derivative fails.
    import mitsuba as mi
    lo, hi = 1.97, 2.03                                     # the texture's other texels (water: within its span)
    x = 2.0
    base = {"type": "corona", "shape": "sphere", "process": process, "area_fraction": 0.2,
            "radius": _bitmap(x, lo, hi) if textured else x}
    bsdf, params, key = _loaded(base, pane, "radius", textured)
    h = 84 * 2.0 ** -22                                     # ≈ 2e-5: x ± h, x ± 2h exact in float32
    assert float(np.float32(x + h)) - float(np.float32(x - h)) == 2 * h
    assert float(np.float32(x + 2 * h)) - float(np.float32(x - 2 * h)) == 4 * h
    n_dirs = 1600                                           # 4000 directions (_directions)
    lams = _mid_row_lams(bsdf, x, 2 * h, 4 * n_dirs)        # r ± 2h: at most 10 % of a row interval

    put = _setter(params, key, textured, lo, hi, _in_place_texels(mi_variant, upload_branch))

    material = bsdf.material
    for what in ("eval", "pdf", "weight"):
        for theta in THETAS:
            wi, wo = _directions(theta, n_dirs)
            if what == "weight":
                lanes = lambda: _samples(bsdf, theta, lams=lams)
            else:
                lanes = lambda: (None, _quantity(bsdf, what, theta, lams, n_dirs))
            # each evaluated before the next update: on CUDA a pending kernel reads a bitmap's
            # texels as they are when it runs (the module docstring)
            at = {}
            for r in (x + 2 * h, x - 2 * h, x + h, x - h):
                put(mi.Float(r))
                at[r] = [None if v is None else np.asarray(v, np.float64) for v in lanes()]
            (wo_up, q_up), (wo_down, q_down) = at[x + h], at[x - h]
            if what == "weight":
                # a continuous sample keeps its row's chord: its chord |wo + wi| scales as 1/r
                chord_up, chord_down = (np.linalg.norm(v + wi[:, None], axis=0) for v in (wo_up, wo_down))
                off = np.abs(chord_up * (x + h) / (chord_down * (x - h)) - 1.0) / (2 * h / x)
                keep = off < 0.1                            # off the 1/r law by < 10 % of the move
                assert keep.mean() > 0.8, np.sort(off)[::25]
            else:
                # the lobes' chord rows end just past 90° from their axes (chord √2), read at the
                # chord scaled by x/x_row: that end moves with r and the value jumps to 0 there, so
                # the directions within 0.6° of 90° from wi (or, on the pane, from wi's mirror
                # image: component 4's lookups) have no central difference
                keep = (np.abs(wo @ wi) > 0.01) & (np.abs(wo @ (wi * [1.0, 1.0, -1.0])) > 0.01)
            # each lane weighted by the sign of its central difference over r ± 2h (fixed weights, their
            # float32 roundings not those of r ± h): the lanes' derivatives add up instead of
            # cancelling, so the tolerance is a share of all of them
            weights = keep * np.sign(at[x + 2 * h][1] - at[x - 2 * h][1])
            up, down = _total(weights * q_up), _total(weights * q_down)
            mask = jit_array(mi.Float, weights)
            quantity = lambda: lanes()[1] * mask
            _assert_ad_matches(put, quantity, x, h, up, down, (process, textured, pane, what, theta), rtol=0.003)
    assert bsdf.material is material                          # no rebuild: r ± h inside the rows' radii


@pytest.mark.slow     # forward-mode AD of a sphere layer (a kernel compiled): seconds of CPU, cold
def test_radius_derivative_on_a_chord_node(mi_variant):
    # eval reads a row of the lobe at the chord in node steps g = s x/(x_row ds), interpolated by
    # the fraction g - floor(g): a chord exactly on a node (g an integer, which float32 hits once in
    # some 10⁵ lookups) must keep the derivative of that fraction in r (a clip to [0, 1] there once
    # dropped it: Dr.Jit's maximum(v, 0) takes 0's derivative at v = 0, 29 % of this derivative).
    # The cubic rows are C1 in the chord, so the derivatives of lanes whose chords step through a
    # node one float32 step at a time agree to far better than 1 %.
    import mitsuba as mi
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        bsdf = mi.load_dict({"type": "corona", "shape": "sphere", "process": "poisson", "area_fraction": 0.2,
                             "radius": 2.0})
    params = mi.traverse(bsdf)
    rows = bsdf.material.rows
    xr, ds = rows["x"], float(rows["ds"])
    groups, wx, lam_lanes = [], [], []
    for lam in (450.0, 520.0, 600.0, 674.0):
        x = 2 * np.pi * 2.0 / (lam * 1e-3)
        x_row = xr[np.searchsorted(xr, x, side="right") - 1]
        for node in (40, 44, 48, 52, 56):
            s = node * ds * x_row / x                      # the chord of that node of row j (wi = +z)
            centre = np.float32(s * np.sqrt(1.0 - 0.25 * s * s))
            steps = [centre]
            for _ in range(64):
                steps = [np.nextafter(steps[0], np.float32(0))] + steps + [np.nextafter(steps[-1], np.float32(1))]
            wx += steps
            lam_lanes += [lam] * len(steps)
            groups.append(len(steps))
    wx = np.array(wx, np.float32)
    wo = jit_array(mi.Vector3f, [wx, np.zeros_like(wx), -np.sqrt(1.0 - wx.astype(np.float64) ** 2)])
    lams = np.array(lam_lanes)[None, :].repeat(4, 0)
    r = mi.Float(2.0)
    dr.enable_grad(r)
    params["radius.value"] = r
    params.update()
    ctx = mi.BSDFContext()
    ctx.type_mask = mi.BSDFFlags.GlossyTransmission
    y = dr.sum(bsdf.eval(ctx, _si(wx.size, np.array([0.0, 0.0, 1.0]), lams), wo))
    dr.forward(r)
    d = np.asarray(dr.grad(y), np.float64)
    start = 0
    for n in groups:
        g = d[start:start + n]
        mid = np.median(g)
        assert abs(mid) > 0.1, (start, mid)
        assert np.max(np.abs(g - mid)) < 0.01 * abs(mid), (start, mid, g[np.argmax(np.abs(g - mid))])
        start += n


@pytest.mark.slow     # forward-mode AD of a sphere layer, a kernel compiled per case: seconds of CPU, cold
@pytest.mark.parametrize("name", ["radius", "area_fraction"])
def test_derivative_at_a_texture_least_value(mi_variant, name):
    # the texel under the shading point holds the texture's least value: the end of the radii the rows
    # cover (radius) or of the F_a rows and range (area_fraction).  The lane's value is clipped to those
    # ends (a filter's overshoot); on the end itself the derivative is the texel's, not the bound's 0
    # (Dr.Jit's clip passes the lower bound's there: each texel at a texture's minimum had none).
    # Against the one-sided difference of second order (x + h, x + 2h keep the texture's range: the
    # other texels hold lo, hi).
    import mitsuba as mi
    lo, hi = (1.97, 2.03) if name == "radius" else (0.05, 0.35)
    x = float(np.float32(lo))
    other = {"area_fraction": 0.2} if name == "radius" else {"radius": 2.0}
    base = {"type": "corona", "shape": "sphere", "process": "hard-disk", name: _bitmap(x, lo, hi), **other}
    bsdf, params, key = _loaded(base, False, name, True)
    material = bsdf.material
    h = 168 * 2.0 ** -23 if name == "radius" else 2e-4      # radius: x + h, x + 2h exact in float32
    lams = _mid_row_lams(bsdf, x, 2 * h, 1000) if name == "radius" else None
    put = _setter(params, key, True, lo, hi)
    quantity = lambda: _quantity(bsdf, "eval", 0.0, lams)
    q = []
    for k in (0, 1, 2):
        put(mi.Float(x + k * h))
        q.append(_total(quantity()))
    h = float(np.float32(x + h)) - x
    fd = (4.0 * q[1] - 3.0 * q[0] - q[2]) / (2.0 * h)       # one-sided, second order
    xf = mi.Float(x)
    dr.enable_grad(xf)
    put(xf)
    y = quantity()
    dr.forward(xf)
    ad = _total(dr.grad(y))
    assert abs(fd) > 1.0 and abs(ad - fd) < 0.01 * abs(fd), (ad, fd)
    assert bsdf.material is material                        # no rebuild: the rows as loaded
