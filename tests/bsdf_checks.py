"""Helpers that drive the plugin the way Mitsuba's own tests do."""
import contextlib
import shutil
import tempfile

import drjit as dr
import mitsuba as mi
import numpy as np


def jit_array(cls, values, shape=None):
    """``cls`` (``mi.Float``, ``mi.Point2f``, ``mi.Vector3f``: one row of numpy ``values`` per
    component; ``mi.TensorXf`` of ``shape``, by default the values') in memory Dr.Jit allocated itself.  A Dr.Jit array made straight from numpy maps
    numpy's memory, whose alignment (64 bytes or not) varies from run to run and is compiled into
    each kernel that reads it (an aligned or an unaligned load): such a kernel missed Dr.Jit's
    kernel cache at random and was compiled anew, warm runs too."""
    from corona.mitsuba.common import array
    a = np.ascontiguousarray(values, np.float32)
    if cls is mi.TensorXf:
        return mi.TensorXf(array(mi.Float, a.ravel()), shape=a.shape if shape is None else shape)
    if cls is mi.Float:
        return array(mi.Float, a.ravel())
    return cls(*[array(mi.Float, row) for row in a])


def interaction(n, wi, wavelengths=(450.0, 520.0, 600.0, 700.0)):
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(*[float(x) for x in wi])
    if mi.is_spectral:
        si.wavelengths = mi.Spectrum(*wavelengths)
    return si


def uv_interaction(n, wi, uv, wavelengths=(450.0, 520.0, 600.0, 700.0)):
    """:func:`interaction` at the texture coordinates ``uv`` (a textured layer's texel)."""
    si = interaction(n, wi, wavelengths)
    si.uv = mi.Point2f(float(uv[0]), float(uv[1]))
    return si


def bitmap_texture(values):
    """A ``bitmap`` texture of a 2-D array of raw values, read at the nearest texel."""
    return {"type": "bitmap", "bitmap": mi.Bitmap(np.asarray(values, np.float32)[..., None]),
            "raw": True, "filter_type": "nearest"}


def chi2_test(params, theta_deg, ctx=None, **kwargs):
    """Run mitsuba.chi2 on the corona BSDF with the given parameters (see :func:`chi2_bsdf`)."""
    return chi2_bsdf(mi.load_dict({"type": "corona", **params}), theta_deg, ctx, **kwargs)


def chi2_bsdf(bsdf, theta_deg, ctx=None, uv=None, wavelengths=(450.0, 520.0, 600.0, 700.0),
              sample_count=1_000_000, res=101, ires=16):
    """Run mitsuba.chi2 on a loaded BSDF, at the shading point ``uv`` (textured layers).

    Like ``mitsuba.chi2.BSDFAdapter`` but with chosen wavelengths (the
    stock adapter leaves them zero).  ``ires=16`` sub-samples per histogram
    bin: with the default 4, the test's own integration of the pdf is too
    coarse in the polar cap (|wo.xy| = sqrt(1 - z²) has an infinite slope
    there), which shows up as false rejections for lobes steep near the pole
    (e.g. the square at 30°, 4M samples) that vanish at ires=16.
    """
    from mitsuba.chi2 import ChiSquareTest, SphericalDomain
    th = np.radians(theta_deg)
    wi = (np.sin(th), 0.0, np.cos(th))
    if ctx is None:
        ctx = mi.BSDFContext()

    def si_of(n):
        si = interaction(n, wi, wavelengths)
        if uv is not None:
            si.uv = mi.Point2f(float(uv[0]), float(uv[1]))
        return si

    def sample(s, *args):
        bs, w = bsdf.sample(ctx, si_of(dr.width(s)), s[0], mi.Point2f(s[1], s[2]))
        return bs.wo, dr.select(dr.all(w == 0), 0.0, 1.0)

    def pdf(wo, *args):
        return bsdf.pdf(ctx, si_of(dr.width(wo)), wo)

    test = ChiSquareTest(domain=SphericalDomain(), sample_func=sample, pdf_func=pdf,
                         sample_dim=3, sample_count=sample_count, res=res, ires=ires)
    return run_chi2(test), test


#: Chi-square runs of a full session, an upper bound (114 at the time of writing: every test marked
#: ``chi2`` runs one).  Each run tests at the Šidák-corrected level
#: ``1 - (1 - CHI2_SIGNIFICANCE) ** (1 / count)`` (Mitsuba's ``test_count``), so that a correct
#: plugin fails any chi-square test of the session with probability at most CHI2_SIGNIFICANCE.
CHI2_TEST_COUNT = 128
CHI2_SIGNIFICANCE = 0.01
#: The chi-square tests collected in this session (set by conftest.py); the count used is the larger.
CHI2_SESSION_COUNT = 0


def chi2_test_count() -> int:
    """The ``test_count`` every chi-square run of the session passes (Šidák correction)."""
    return max(CHI2_TEST_COUNT, CHI2_SESSION_COUNT)


def run_chi2(test) -> bool:
    """``test.run()`` in a fresh temporary directory, with the session's ``test_count``.

    A failing ``mitsuba.chi2.ChiSquareTest`` writes ``chi2_data.py`` (the
    histogram and the density) into the working directory; here it lands in
    a temporary directory, kept and named in ``test.messages`` on failure,
    removed on success.
    """
    folder = tempfile.mkdtemp(prefix="corona-chi2-")
    with contextlib.chdir(folder):
        ok = test.run(significance_level=CHI2_SIGNIFICANCE, test_count=chi2_test_count())
    if ok:
        shutil.rmtree(folder, ignore_errors=True)
    else:
        test.messages += f"\n(histogram and density: {folder}/chi2_data.py)"
    return ok


def smooth_context():
    """A context that leaves out the delta components (the chi-square test needs densities)."""
    ctx = mi.BSDFContext()
    ctx.type_mask = (mi.BSDFFlags.GlossyTransmission | mi.BSDFFlags.DiffuseReflection
                     | mi.BSDFFlags.GlossyReflection)
    return ctx


#: A tiny scene: a corona layer filling the view of a perspective camera, a white sky behind
#: (``-D spp=N -D res=N -D radius=R``); ``{props}`` holds the layer's properties.
LAYER_SCENE = """<scene version="3.0.0">
    <default name="spp" value="{spp}"/>
    <default name="res" value="{res}"/>
    <default name="radius" value="5"/>
    <integrator type="path"><integer name="max_depth" value="3"/></integrator>
    <sensor type="perspective">
        <float name="fov" value="20"/>
        <transform name="to_world"><lookat origin="0, 0, 0" target="0, 0, 1" up="0, 1, 0"/></transform>
        <sampler type="independent"><integer name="sample_count" value="$spp"/></sampler>
        <film type="hdrfilm">
            <integer name="width" value="$res"/><integer name="height" value="$res"/>
            <string name="pixel_format" value="rgb"/><rfilter type="box"/>
        </film>
    </sensor>
    <shape type="rectangle">
        <transform name="to_world"><scale value="2"/><translate z="1"/></transform>
        <bsdf type="corona">
{props}
        </bsdf>
    </shape>
    <emitter type="constant"><rgb name="radiance" value="1"/></emitter>
</scene>
"""


def layer_scene(props: str = '            <float name="radius" value="$radius"/>'
                             '<float name="area_fraction" value="0.3"/>', spp: int = 4, res: int = 8) -> str:
    """:data:`LAYER_SCENE` with the layer's ``props`` (XML) and the default spp and resolution."""
    return LAYER_SCENE.replace("{props}", props).replace("{spp}", str(spp)).replace("{res}", str(res))


def png_claiming(width: int, height: int) -> bytes:
    """A PNG file whose header claims ``width`` × ``height`` RGB pixels but that holds no
    pixel data (a decompression bomb's header: readers that trust it allocate the whole image)."""
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(b""))
            + chunk(b"IEND", b""))


def furnace(bsdf, theta_deg: float, wavelengths=(550.0,) * 4, n: int = 200_000, seed: int = 3,
            ctx=None, uv=None, phi_deg: float = 0.0, components=None):
    """White furnace by sampling: the mean of ``sample``'s weights per wavelength lane (the
    directional albedo: what the layer returns of what it receives, all components) and the
    standard error of each mean.

    Parameters
    ----------
    bsdf : mitsuba.BSDF
        A loaded BSDF.
    theta_deg, phi_deg : float
        Incidence [degrees]: ``wi = (sin|θ| cos φ, sin|θ| sin φ, cos θ)``; a negative ``θ`` or one
        above 90° comes from the back side.
    wavelengths : 4 floats
        The interaction's wavelengths [nm] (spectral variants).
    n, seed : int
        Samples, and the seed of their random numbers.
    ctx : mitsuba.BSDFContext, optional
        Default: every component.
    uv : 2 floats, optional
        The shading point's texture coordinates (a textured layer's texel).
    components : sequence of int, optional
        Also return, per component index ``c``, the mean of the weights of the samples that chose
        it (``E[w · 1{component = c}]``: that component's share of the energy).

    Returns
    -------
    mean, stderr : arrays (lanes,)
        A layer that keeps energy has ``mean <= 1`` per lane.
    shares : array (len(components), lanes)
        Only with ``components``.

    Every weight is checked finite and non-negative.
    """
    th, ph = np.radians(theta_deg), np.radians(phi_deg)
    wi = (np.sin(abs(th)) * np.cos(ph), np.sin(abs(th)) * np.sin(ph), np.cos(th))
    rng = np.random.default_rng(seed)
    si = interaction(n, wi, wavelengths) if uv is None else uv_interaction(n, wi, uv, wavelengths)
    bs, w = bsdf.sample(ctx or mi.BSDFContext(), si, jit_array(mi.Float, rng.random(n)),
                        jit_array(mi.Point2f, rng.random((2, n))))
    w = np.asarray(w, dtype=np.float64).reshape(-1, n)
    assert np.all(np.isfinite(w)), "sample() returned a non-finite weight"
    assert np.all(w >= 0), "sample() returned a negative weight"
    out = (w.mean(axis=1), w.std(axis=1) / np.sqrt(n))
    if components is None:
        return out
    comp = np.asarray(bs.sampled_component).reshape(n)
    return out + (np.stack([np.mean(w * (comp == c), axis=1) for c in components]),)


def plugin_eval(bsdf, wi, wo, wavelengths=(450.0, 520.0, 600.0, 700.0), uv=None, ctx=None):
    """``eval_pdf`` of a loaded BSDF for many directions in one Dr.Jit call.

    ``wi``: one direction (3,) or one per ``wo`` (n, 3); ``wo``: (n, 3); ``uv``: the shading
    point's texture coordinates.  Returns ``eval`` (lanes, n) and ``pdf`` (n,) as numpy arrays.
    """
    wo = np.asarray(wo, dtype=np.float64)
    wi = np.asarray(wi, dtype=np.float64)
    n = len(wo)
    si = interaction(n, (0.0, 0.0, 1.0), wavelengths)
    si.wi = jit_array(mi.Vector3f, np.broadcast_to(wi, (n, 3)).T)
    if uv is not None:
        si.uv = mi.Point2f(float(uv[0]), float(uv[1]))
    e, pdf = bsdf.eval_pdf(ctx or mi.BSDFContext(), si, jit_array(mi.Vector3f, wo.T))
    return np.asarray(e, dtype=np.float64).reshape(-1, n), np.asarray(pdf, dtype=np.float64).reshape(n)


def transmitted_lobe(material, tabulated: bool = False):
    """The reference ``(wi, wo, λ) -> f(d) |cos θo|`` of a numpy material's lobe alone
    (``d = (wi + wo).xy``): the plugin's ``eval`` on the transmitted side of a bare layer.
    ``tabulated``: the lobe as the material's tables hold it (``lobe_tabulated``), else the
    exact model (``lobe``)."""
    lobe = material.lobe_tabulated if tabulated else material.lobe

    def reference(wi, wo, lam):
        return lobe(wo[:, :2] + np.asarray(wi)[..., :2], lam) * np.abs(wo[:, 2])
    return reference


def assert_eval_matches(bsdf, reference, wi, wo, wavelengths=(450.0, 520.0, 600.0, 700.0), *,
                        rtol: float, atol: float, peak: str = "lane", uv=None, ctx=None):
    """The plugin's ``eval`` against the numpy reference, lane by lane.

    ``reference(wi, wo, λ)`` gives the expected ``eval`` (n,) at one wavelength [nm]: a numpy
    material's ``eval`` (``f_s |cos θo|``, every smooth component) or :func:`transmitted_lobe`.
    Asserts, per lane ``k``, ``|eval_k - ref_k| <= rtol |ref_k| + atol · peak`` with ``peak`` the
    largest reference value of that lane (``peak="lane"``) or of all lanes (``"all"``).

    Returns ``eval`` (lanes, n), the reference (lanes, n) and ``pdf`` (n,).
    """
    val, pdf = plugin_eval(bsdf, wi, wo, wavelengths, uv=uv, ctx=ctx)
    ref = np.stack([np.asarray(reference(np.asarray(wi, dtype=np.float64), np.asarray(wo, dtype=np.float64),
                                         lam), dtype=np.float64) for lam in wavelengths])
    assert np.all(np.isfinite(val)), "eval() returned a non-finite value"
    peaks = ref.max(axis=1, keepdims=True) if peak == "lane" else np.full((len(ref), 1), ref.max())
    excess = np.abs(val - ref) - (rtol * np.abs(ref) + atol * peaks)
    worst = np.unravel_index(np.argmax(excess), excess.shape)
    assert excess[worst] <= 0, (f"eval at {wavelengths[worst[0]]} nm, wo = {np.asarray(wo)[worst[1]]}: "
                                f"{val[worst]:.6g}, reference {ref[worst]:.6g} (peak {peaks[worst[0], 0]:.3g})")
    return val, ref, pdf


def assert_finite_at_a_zero_interaction(bsdf):
    """sample / eval / pdf / eval_pdf at a zero-initialised interaction (wavelengths 0, as
    mitsuba.chi2's adapters pass) and without ``active``: finite, eval >= 0, at a smooth,
    the grazing, the exactly opposite and the exactly equal directions."""
    si = dr.zeros(mi.SurfaceInteraction3f, 16)
    si.wi = mi.Vector3f(0, 0, 1)
    ctx = mi.BSDFContext()
    _, w = bsdf.sample(ctx, si, mi.Float(np.linspace(0, 0.99, 16)),
                       mi.Point2f(np.linspace(0, 0.99, 16), np.linspace(0.1, 0.9, 16)))
    assert np.all(np.isfinite(np.array(w)))
    for wo in [(0.1, 0.0, -0.99), (1.0, 0.0, 0.0), (0.0, 0.0, -1.0), (0.0, 0.0, 1.0)]:
        v = mi.Vector3f(*wo)
        e, p = bsdf.eval_pdf(ctx, si, v)
        for x in (e, p, bsdf.eval(ctx, si, v), bsdf.pdf(ctx, si, v)):
            assert np.all(np.isfinite(np.array(x))), wo
        assert np.all(np.array(e) >= 0), wo


def one_line_error(result, *words) -> str:
    """A ``click.testing.CliRunner`` result that failed the corona way: exit code 2, exactly one
    ``corona: error: ...`` line on stderr holding each of ``words``, any other stderr line a
    ``corona: ...`` notice (the variant, a warning, a capped worker count; progress bars aside),
    no traceback.  Returns the error line."""
    import re
    assert result.exit_code == 2, (result.exit_code, result.output, result.exception)
    lines = [c for c in re.split(r"[\r\n]", result.stderr) if c.strip() and not re.match(r"^\s*\S.*\d+%\|", c)]
    errors = [ln for ln in lines if ln.startswith("corona: error: ")]
    assert len(errors) == 1, result.stderr
    assert all(ln.startswith("corona: ") for ln in lines), result.stderr
    assert "Traceback" not in result.output, result.output
    for w in words:
        assert w in errors[0], (w, errors[0])
    return errors[0]
