"""The Mitsuba plugin with process=breath-figure (issue 46): its sample against its pdf (Mitsuba's
chi-square test) and its white furnace against the numpy model's directional albedo."""
import numpy as np
import pytest

from corona.parameters import material_from_parameters

#: Breath times [s]: early (⟨a³⟩/⟨a²⟩ = 3.6 µm) and late (17 µm, a lobe a hundredth of a radian wide).
TIMES = [10.0, 80.0]
ANGLES = [0.0, 60.0]
LAMS = (420.0, 520.0, 640.0, 780.0)


def _turned(v):
    """(x, y, z) -> (x, -z, y): a rotation that takes the pole to the equator."""
    return v[0], -v[2], v[1]


def _unturned(v):
    return v[0], v[2], -v[1]


def _chi2_turned(bsdf, theta_deg, res=101, ires=32, sample_count=1_000_000):
    """mitsuba.chi2 of ``sample`` against ``pdf`` with every direction turned by :func:`_turned`.

    The forward lobe of droplets of 17 µm is 0.01 rad wide: around the pole the histogram's
    cells (0.02 in cos θ) hold it in their first row and the test's integration of the pdf
    misses it (its sum moves with ``ires``).  A rotation keeps solid angle, so the density of the
    turned directions is the pdf at the unturned ones; at the equator the cells resolve it, with
    32² sub-samples per cell for the pdf's integral (at 16², 80 s at 0° sums 1.5 % short).
    """
    import drjit as dr
    import mitsuba as mi
    from mitsuba.chi2 import ChiSquareTest, SphericalDomain

    from bsdf_checks import interaction, run_chi2, smooth_context
    th = np.radians(theta_deg)
    wi = (np.sin(th), 0.0, np.cos(th))
    ctx = smooth_context()

    def sample(s, *args):
        bs, w = bsdf.sample(ctx, interaction(dr.width(s), wi), s[0], mi.Point2f(s[1], s[2]))
        dead = dr.all(w == 0)      # a sample with no weight may carry any wo (not a unit vector)
        wo = dr.select(dead, mi.Vector3f(0, 0, 1), mi.Vector3f(*_turned(bs.wo)))
        return wo, dr.select(dead, 0.0, 1.0)

    def pdf(wo, *args):
        return bsdf.pdf(ctx, interaction(dr.width(wo), wi), mi.Vector3f(*_unturned(wo)))

    test = ChiSquareTest(domain=SphericalDomain(), sample_func=sample, pdf_func=pdf, sample_dim=3,
                         sample_count=sample_count, res=res, ires=ires)
    return run_chi2(test), test


@pytest.mark.slow
@pytest.mark.chi2
@pytest.mark.parametrize("theta", ANGLES)
@pytest.mark.parametrize("t", TIMES)
def test_chi2(mi_variant, t, theta):
    import mitsuba as mi
    bsdf = mi.load_dict({"type": "corona", "process": "breath-figure", "breath_time": t})
    ok, test = _chi2_turned(bsdf, theta)
    assert ok, test.messages


@pytest.mark.slow
@pytest.mark.chi2
def test_chi2_turned_rejects_a_wrong_pdf(mi_variant):
    """Negative control: the same test with the pdf of the layer 10 s later is rejected."""
    import mitsuba as mi
    early = mi.load_dict({"type": "corona", "process": "breath-figure", "breath_time": 10.0})
    late = mi.load_dict({"type": "corona", "process": "breath-figure", "breath_time": 20.0})

    class Mixed:
        sample = early.sample
        pdf = late.pdf
    ok, _ = _chi2_turned(Mixed(), 0.0)
    assert not ok


@pytest.mark.slow
@pytest.mark.parametrize("t", [5.0, 20.0, 80.0])
def test_furnace_matches_the_model(mi_variant, t):
    """The plugin's mean sample weight (coherent beam + lobe) ≤ 1 within 4 standard errors and
    within 0.5 % of the numpy model's directional albedo, at 0°, 60° and 85°."""
    import mitsuba as mi

    from bsdf_checks import furnace
    params = {"process": "breath-figure", "breath_time": t}
    bsdf = mi.load_dict({"type": "corona", **params})
    model = material_from_parameters(**params)
    for deg in (0.0, 60.0, 85.0):
        mean, err = furnace(bsdf, deg, LAMS, n=200_000, seed=5)
        ref = np.array([model.directional_albedo(np.cos(np.radians(deg)), lam)["total"] for lam in LAMS])
        assert np.all(mean <= 1.0 + 4 * err), (deg, mean, err)
        assert np.all(np.abs(mean - ref) <= 0.005 * ref + 4 * err), (deg, mean, ref, err)
