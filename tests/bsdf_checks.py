"""Helpers that drive the plugin the way Mitsuba's own tests do."""
import drjit as dr
import mitsuba as mi
import numpy as np


def interaction(n, wi, wavelengths=(450.0, 520.0, 600.0, 700.0)):
    si = dr.zeros(mi.SurfaceInteraction3f, n)
    si.wi = mi.Vector3f(*[float(x) for x in wi])
    if mi.is_spectral:
        si.wavelengths = mi.Spectrum(*wavelengths)
    return si


def chi2_test(params, theta_deg, ctx=None, wavelengths=(450.0, 520.0, 600.0, 700.0),
              sample_count=1_000_000, res=101, ires=16):
    """Run mitsuba.chi2 on the corona BSDF with the given parameters.

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
    bsdf = mi.load_dict({"type": "corona", **params})

    def sample(s, *args):
        bs, w = bsdf.sample(ctx, interaction(dr.width(s), wi, wavelengths), s[0], mi.Point2f(s[1], s[2]))
        return bs.wo, dr.select(dr.all(w == 0), 0.0, 1.0)

    def pdf(wo, *args):
        return bsdf.pdf(ctx, interaction(dr.width(wo), wi, wavelengths), wo)

    test = ChiSquareTest(domain=SphericalDomain(), sample_func=sample, pdf_func=pdf,
                         sample_dim=3, sample_count=sample_count, res=res, ires=ires)
    ok = test.run()
    return ok, test


def smooth_context():
    """A context that leaves out the delta components (the chi-square test needs densities)."""
    ctx = mi.BSDFContext()
    ctx.type_mask = (mi.BSDFFlags.GlossyTransmission | mi.BSDFFlags.DiffuseReflection
                     | mi.BSDFFlags.GlossyReflection)
    return ctx
