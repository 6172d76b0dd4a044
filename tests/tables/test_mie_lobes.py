"""The renderer's sphere lobes against Mie theory at radii and wavelengths between the table rows.

The reference is ``corona.model.mie.theory.differential_cross_section`` evaluated at each direction (checked
against miepython in model/test_mie.py), not the table builder: a dilute Poisson layer at normal
incidence, where ``eval / (F_s w) = P = n dσ/dΩ / F_a``.  Per lobe: the energy-weighted RMS of
``P_table / P_mie - 1``, the overall scale, and (forward) the positions of the first three
minima and maxima of the lobe.
"""
import warnings

import numpy as np
import pytest

import corona
from corona.model.mie import theory as mie


def _lobe(material, theta, lam, exact):
    wi = np.array([0.0, 0.0, 1.0])
    wo = np.stack([np.sin(theta), 0 * theta, -np.cos(theta)], -1)
    zf, zb, fwd = material._lobes(wi, wo, lam, exact=exact)
    return np.where(fwd, zf, zb)


def _mie_P(sphere, theta, lam):
    """P = dσ/dΩ / (π r²) from corona.model.mie.theory directly."""
    m = complex(sphere.index(lam))
    return mie.differential_cross_section(m, sphere.radius, lam * 1e-3, np.cos(theta)) / (np.pi * sphere.radius**2)


def _extrema(theta, p, n=3):
    d = np.diff(p)
    idx = np.concatenate([np.where((d[:-1] < 0) & (d[1:] >= 0))[0][:n], np.where((d[:-1] > 0) & (d[1:] <= 0))[0][:n]]) + 1
    out = []
    for i in np.sort(idx):
        y0, y1, y2 = p[i - 1], p[i], p[i + 1]
        den = y0 - 2 * y1 + y2
        out.append(theta[i] + (0.5 * (y0 - y2) / den if den != 0 else 0.0) * (theta[1] - theta[0]))
    return np.array(out)


CASES = [(1.3, None, 487.3), (1.3, None, 611.9), (4.7, None, 533.3), (4.7, None, 402.9),
         (2.3, 1.5, 702.1),
         # near a narrow resonance (x = 42.76, m = 1.45): the rows crowd there
         (3.1, 1.45, 455.5),
         # a resonance narrower than ROW_DX_MIN (x = 17.4): the rows go on to ROW_DX_FINE there
         (1.0, 1.5, 361.3)]


@pytest.mark.parametrize("radius,ior,lam", CASES)
def test_lobes_between_rows_match_mie(radius, ior, lam):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mat = corona.Material(corona.Sphere(radius, ior=ior), corona.Poisson(0.01))
    r = mat.rows
    # the wavelength halfway between the two rows around ``lam`` (the lookup's worst spot)
    x = 2 * np.pi * radius / (lam * 1e-3)
    j = np.searchsorted(r["x"], x)
    lam = 2 * np.pi * radius / (0.5 * (r["x"][j - 1] + r["x"][j]) * 1e-3)
    n = 40000
    th = (np.arange(n) + 0.5) * (0.5 * np.pi / n)
    for name, ang in (("forward", th), ("backward", np.pi - th)):
        tab = _lobe(mat, ang, lam, exact=False)
        ref = _mie_P(mat.sphere, ang, lam)
        w = ref * np.sin(th)
        rms = np.sqrt(np.sum(w * (tab / ref - 1) ** 2) / np.sum(w))
        scale = np.sum(tab * np.sin(th)) / np.sum(w) - 1
        assert rms < 0.01, (name, rms)
        assert abs(scale) < 0.005, (name, scale)
        if name == "forward":
            e_tab, e_ref = _extrema(th, tab), _extrema(th, ref)
            assert e_tab.size == e_ref.size == 6
            assert np.max(np.abs(e_tab / e_ref - 1)) < 0.002, (e_tab, e_ref)


def test_negative_control_detects_a_shifted_lobe():
    # the same checks see a 1 % change of the radius (the rings move by 1 %)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mat = corona.Material(corona.Sphere(4.7 * 1.01), corona.Poisson(0.01))
    th = (np.arange(40000) + 0.5) * (0.5 * np.pi / 40000)
    tab = _lobe(mat, th, 533.3, exact=False)
    ref = _mie_P(corona.Sphere(4.7), th, 533.3)
    e_tab, e_ref = _extrema(th, tab), _extrema(th, ref)
    assert np.max(np.abs(e_tab / e_ref - 1)) > 0.005
    w = ref * np.sin(th)
    assert np.sqrt(np.sum(w * (tab / ref - 1) ** 2) / np.sum(w)) > 0.01


def _spread_reference(radius, spread, lam, theta, distribution, dX=0.01, ior=None):
    """⟨|S1|² + |S2|²⟩ / (2π ⟨x²⟩) of a size distribution by brute force: Mie theory on a
    grid of size parameters ``dX`` apart, weighted by scipy.stats' density.  At 0.01 it is within 0.08 %
    RMS of sizes 0.0025 apart for the 1-3 µm spreads of 10-50 % below (0.04 apart was 0.34 % RMS and
    0.22 % in scale off in the backward lobe of 2.1 µm / 10 %, a third of the tests' tolerance); narrow
    spreads pass a finer ``dX``, 20 µm / 10 % a coarser one (0.04: within 0.06 % of 0.01 there).

    The amplitudes are ``S1 = Σ c_n (a_n π_n + b_n τ_n)``, ``S2 = Σ c_n (a_n τ_n + b_n π_n)``,
    ``c_n = (2n+1) / (n(n+1))`` (Bohren & Huffman eq. 4.74) from corona.model.mie.theory's
    ``coefficients`` and ``angular_functions`` (both checked against miepython through
    ``amplitudes`` in model/test_mie.py), summed here in real arithmetic: the same values as
    ``theory.amplitudes`` (to rounding) at half its cost (a complex-by-real product there is four real
    ones), and nothing of the table builder.  Pass the forward and backward angles in one call: the
    coefficients of each size are computed once."""
    from scipy import stats
    x0 = 2 * np.pi * radius / (lam * 1e-3)
    if distribution == "lognormal":
        s2 = np.log1p(spread**2)
        dist = stats.lognorm(np.sqrt(s2), scale=np.exp(-0.5 * s2))
    else:
        k = 1.0 / spread**2
        dist = stats.gamma(k, scale=1.0 / k)
    lo, hi = dist.ppf(1e-7), dist.ppf(1 - 1e-9)
    X = np.arange(x0 * lo, x0 * hi, dX)
    w = dist.pdf(X / x0)
    m = complex(corona.Sphere(radius, ior=ior).index(lam))
    mu = np.cos(theta)
    P = np.zeros(theta.size)
    chunk = 128                     # sizes a product: (4 chunk, M) results of a few MB
    for c in range(0, X.size, chunk):
        a, b = mie.coefficients(np.full(X[c:c + chunk].size, m), X[c:c + chunk])
        B, N = a.shape
        n = np.arange(1, N + 1)
        cn = (2 * n + 1) / (n * (n + 1.0))
        pi, tau = mie.angular_functions(mu, N)                       # (N, M)
        ab = np.concatenate([(a * cn).real, (a * cn).imag, (b * cn).real, (b * cn).imag])   # (4B, N)
        sp, st = ab @ pi, ab @ tau
        re1, im1 = sp[:B] + st[2 * B:3 * B], sp[B:2 * B] + st[3 * B:]       # S1 = Σ c (a π + b τ)
        re2, im2 = st[:B] + sp[2 * B:3 * B], st[B:2 * B] + sp[3 * B:]       # S2 = Σ c (a τ + b π)
        P += w[c:c + chunk] @ (re1**2 + im1**2 + re2**2 + im2**2)
    return P / (2 * np.pi * np.sum(w * X**2))


def _both_lobes(reference, th):
    """(forward, backward) halves of ``reference(angles)`` at ``th`` and ``π - th`` in one call."""
    P = reference(np.concatenate([th, np.pi - th]))
    return {"forward": P[:th.size], "backward": P[th.size:]}


def test_spread_reference_is_mie_theorys_amplitudes():
    """The reference's own sum of the series against theory.amplitudes (complex arithmetic) on a
    spread of a few sizes: the same |S1|² + |S2|² to rounding."""
    from scipy import stats
    th = np.linspace(0.0, np.pi, 181)
    radius, spread, lam = 1.3, 0.3, 487.3
    got = _spread_reference(radius, spread, lam, th, "lognormal", dX=0.5)
    x0 = 2 * np.pi * radius / (lam * 1e-3)
    s2 = np.log1p(spread**2)
    dist = stats.lognorm(np.sqrt(s2), scale=np.exp(-0.5 * s2))
    X = np.arange(x0 * dist.ppf(1e-7), x0 * dist.ppf(1 - 1e-9), 0.5)
    w = dist.pdf(X / x0)
    S1, S2 = mie.amplitudes(np.full(X.size, complex(corona.Sphere(radius).index(lam))), X, np.cos(th))
    want = w @ (np.abs(S1) ** 2 + np.abs(S2) ** 2) / (2 * np.pi * np.sum(w * X**2))
    np.testing.assert_allclose(got, want, rtol=1e-10)


@pytest.mark.parametrize("radius,spread,distribution,lam", [
    pytest.param(2.1, 0.1, "lognormal", 517.7, marks=pytest.mark.slow),   # the brute-force average: 1.4 s CPU
    # (slow: 6 s of CPU with the table cached, the brute-force average over the wide spread)
    pytest.param(3.3, 0.25, "schulz", 633.1, marks=pytest.mark.slow)])
def test_size_distribution_lobes_match_brute_force_mie(radius, spread, distribution, lam):
    # the rows average one shared grid of sizes (and index nodes for water's dispersion); the
    # reference averages Mie theory at the wavelength itself on a finer grid of sizes
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sd = corona.SizeDistribution(corona.Sphere(radius), spread, distribution=distribution)
        mat = corona.Material(sd, corona.Poisson(0.01))
        mono = corona.Material(corona.Sphere(radius), corona.Poisson(0.01))
    n = 3000
    th = (np.arange(n) + 0.5) * (0.5 * np.pi / n)
    refs = _both_lobes(lambda a: _spread_reference(radius, spread, lam, a, distribution), th)
    for name, ang in (("forward", th), ("backward", np.pi - th)):
        ref = refs[name]
        w = ref * np.sin(th)
        for layer, good in ((mat, True), (mono, False)):       # the one-size table: negative control
            tab = _lobe(layer, ang, lam, exact=False)
            rms = np.sqrt(np.sum(w * (tab / ref - 1) ** 2) / np.sum(w))
            scale = np.sum(tab * np.sin(th)) / np.sum(w) - 1
            if good:
                assert rms < 0.01 and abs(scale) < 0.005, (name, rms, scale)
            else:
                assert rms > 0.03, (name, rms)


@pytest.mark.slow
@pytest.mark.parametrize("ior,lam", [(None, 551.9), (1.5, 452.7)])
def test_large_droplet_spread_matches_brute_force_mie(ior, lam):
    # 20 µm, 10 % lognormal (a cloud's droplets): the rows are Mie theory on a subset of the chord
    # nodes with a cubic between (SPREAD_CHORD_SMOOTH) and, for water, index nodes SIZE_DM apart;
    # the reference averages Mie theory at the wavelength itself on a finer grid of sizes
    radius, spread = 20.0, 0.1
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sd = corona.SizeDistribution(corona.Sphere(radius, ior=ior), spread)
        mat = corona.Material(sd, corona.Poisson(0.01))
    n = 3000
    th = (np.arange(n) + 0.5) * (0.5 * np.pi / n)
    # sizes 0.04 apart: within 0.06 % RMS of 0.01 apart here (a wide spread of large x)
    refs = _both_lobes(lambda a: _spread_reference(radius, spread, lam, a, "lognormal", dX=0.04, ior=ior), th)
    for name, ang in (("forward", th), ("backward", np.pi - th)):
        ref = refs[name]
        w = ref * np.sin(th)
        tab = _lobe(mat, ang, lam, exact=False)
        rms = np.sqrt(np.sum(w * (tab / ref - 1) ** 2) / np.sum(w))
        scale = np.sum(tab * np.sin(th)) / np.sum(w) - 1
        assert rms < 0.01 and abs(scale) < 0.005, (name, rms, scale)
        # negative control: one droplet of the mean radius is far from the average
        one = _mie_P(corona.Sphere(radius, ior=ior), ang, lam)
        assert np.sqrt(np.sum(w * (one / ref - 1) ** 2) / np.sum(w)) > 0.05, name


@pytest.mark.slow     # the brute-force averages over a 50 % spread: 8 and 25 s of CPU with the tables cached
@pytest.mark.parametrize("radius,spread", [(2.0, 0.5), (1.0, 0.5)])
def test_wide_spread_between_rows_matches_brute_force_mie(radius, spread):
    # half-way between the two rows about 551.9 nm, where a blend of rows read at the chord scaled
    # by x / x_j is furthest from either row: the backward lobe's rainbow sits at a fixed angle for
    # any spread, and rows 12 % apart in x (before SIZE_ROW_DLNX) were 1.7-2.2 % RMS here
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sd = corona.SizeDistribution(corona.Sphere(radius), spread)
        mat = corona.Material(sd, corona.Poisson(0.01))
    x = mat.rows["x"]
    j = int(np.searchsorted(x, 2 * np.pi * radius / 0.5519)) - 1
    lam = 2 * np.pi * radius / (0.5 * (x[j] + x[j + 1])) * 1e3
    n = 1500
    th = (np.arange(n) + 0.5) * (0.5 * np.pi / n)
    refs = _both_lobes(lambda a: _spread_reference(radius, spread, lam, a, "lognormal"), th)
    for name, ang in (("forward", th), ("backward", np.pi - th)):
        ref = refs[name]
        w = ref * np.sin(th)
        tab = _lobe(mat, ang, lam, exact=False)
        rms = np.sqrt(np.sum(w * (tab / ref - 1) ** 2) / np.sum(w))
        scale = np.sum(tab * np.sin(th)) / np.sum(w) - 1
        assert rms < 0.01 and abs(scale) < 0.005, (name, lam, rms, scale)


@pytest.mark.slow     # two size-spread tables each (one of the old size grid) and a brute-force average 0.0025 apart: 10-18 s of CPU cold
@pytest.mark.parametrize("radius,spread,lam", [(2.0, 0.02, 361.3), (5.0, 0.01, 829.1)])
def test_narrow_spread_at_short_wavelength_matches_brute_force_mie(radius, spread, lam, monkeypatch):
    # half-way between two rows at x = 35-38 (water): a narrow spread averages few of the sharp Mie
    # resonances there, and a size grid 0.06 apart samples them at random.  That grid (the step
    # before SIZE_RES_DX, the negative control) is 3.8 % RMS / +2.2 % (2 µm / 2 %) and 4.2 % / +2.0 %
    # (5 µm / 1 %) off in the backward lobe here; the table 0.18 % / +0.09 % and 0.23 % / -0.06 %.
    # The reference: sizes 0.0025 apart (0.02 apart is itself 1.2 % off at 2 µm / 2 %, 361 nm)
    from corona.model.mie import layer
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sd = corona.SizeDistribution(corona.Sphere(radius), spread)
        mat = corona.Material(sd, corona.Poisson(0.01))
        x = mat.rows["x"]                           # built before the patch
        monkeypatch.setattr(layer, "SIZE_RES_DX", np.inf)
        old = corona.Material(corona.SizeDistribution(corona.Sphere(radius), spread), corona.Poisson(0.01))
        old.rows
    assert np.array_equal(old.rows["x"], x)
    j = int(np.searchsorted(x, 2 * np.pi * radius / (lam * 1e-3))) - 1
    lam = 2 * np.pi * radius / (0.5 * (x[j] + x[j + 1])) * 1e3
    n = 1500
    th = (np.arange(n) + 0.5) * (0.5 * np.pi / n)
    refs = _both_lobes(lambda a: _spread_reference(radius, spread, lam, a, "lognormal", dX=0.0025), th)
    for name, ang in (("forward", th), ("backward", np.pi - th)):
        ref = refs[name]
        w = ref * np.sin(th)
        for layer_, good in ((mat, True), (old, False)):
            tab = _lobe(layer_, ang, lam, exact=False)
            rms = np.sqrt(np.sum(w * (tab / ref - 1) ** 2) / np.sum(w))
            scale = np.sum(tab * np.sin(th)) / np.sum(w) - 1
            if good:
                assert rms < 0.01 and abs(scale) < 0.005, (name, lam, rms, scale)
            elif name == "backward":
                assert rms > 0.02, (lam, rms)


@pytest.mark.slow     # two 20 µm / 1 % water tables (one of the old index nodes): 80 s of CPU cold
def test_narrow_spread_of_large_drops_forward_lobe_matches_brute_force_mie(monkeypatch):
    # water 20 µm / 1 %: the forward lobe holds the interference of the diffracted and the
    # transmitted light (phase 2 x (m - 1), x ~ 230), which a narrow spread leaves coherent; the
    # rows' cubics in the index on nodes 0.004 apart missed it by about 1 % RMS near 552 nm (the
    # negative control), nodes SIZE_DM_PHASE / (2 x_top) apart do not.  Reference: sizes 0.005
    # apart (0.02 apart is within 0.01 % of it here), 0.05-20 degrees, where the fringes are.
    from corona.model.mie import layer
    radius, spread = 20.0, 0.01
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mat = corona.Material(corona.SizeDistribution(corona.Sphere(radius), spread), corona.Poisson(0.01))
        x = mat.rows["x"]
        monkeypatch.setattr(layer, "SIZE_DM_SMOOTH", 0.0)         # the index nodes of before
        old = corona.Material(corona.SizeDistribution(corona.Sphere(radius), spread), corona.Poisson(0.01))
        old.rows
    assert np.array_equal(old.rows["x"], x)
    j = int(np.searchsorted(x, 2 * np.pi * radius / 0.552)) - 1
    lam = 2 * np.pi * radius / (0.5 * (x[j] + x[j + 1])) * 1e3
    th = np.radians(np.linspace(0.05, 20.0, 400))
    ref = _spread_reference(radius, spread, lam, th, "lognormal", dX=0.005)
    w = ref * np.sin(th)
    errs = []
    for layer_ in (mat, old):
        tab = _lobe(layer_, th, lam, exact=False)
        errs.append((np.sqrt(np.sum(w * (tab / ref - 1) ** 2) / np.sum(w)), np.sum(tab * np.sin(th)) / np.sum(w) - 1))
    (rms, scale), (rms_old, _) = errs
    assert rms < 0.004 and abs(scale) < 0.002, (lam, rms, scale)
    assert rms_old > 0.008, (lam, rms_old)
