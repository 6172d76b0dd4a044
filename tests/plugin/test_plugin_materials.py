"""Every shape and process through the plugin: chi-square and agreement with the reference."""
import numpy as np
import pytest

from corona.parameters import material_from_parameters

from bsdf_checks import assert_eval_matches, chi2_test, smooth_context, transmitted_lobe


@pytest.fixture(scope="module")
def data_files(tmp_path_factory):
    """A mask image (a cross) and a point file (an RSA configuration)."""
    import imageio.v3 as iio

    from corona.reference.rsa import rsa_configuration
    folder = tmp_path_factory.mktemp("data")
    img = np.zeros((24, 24), dtype=np.uint8)
    img[9:15, 3:21] = 255
    img[3:21, 9:15] = 255
    mask = folder / "cross.png"
    iio.imwrite(mask, img)
    pts = rsa_configuration(40.0, 0.3, sigma=1.0, seed=3)
    points = folder / "points.csv"
    np.savetxt(points, pts, delimiter=",")
    return {"mask": str(mask), "points": str(points)}


CONFIGS = {
    "ellipse": {"shape": "ellipse", "radius": 0.3, "aspect": 1.6, "angle": 20, "process": "poisson"},
    "square": {"shape": "square", "radius": 0.3, "process": "poisson"},
    "rectangle": {"shape": "rectangle", "radius": 0.25, "aspect": 1.5, "process": "poisson"},
    "hexagon": {"shape": "polygon", "sides": 6, "radius": 0.35, "process": "poisson"},
    "square-random": {"shape": "square", "radius": 0.3, "orientation": "random", "process": "poisson"},
    "circle-soft-spread": {"radius": 0.35, "edge_width": 0.03, "size_spread": 0.2, "process": "poisson"},
    "mask": {"shape": "mask", "pixel_size": 0.03, "process": "poisson", "area_fraction": 0.2},
    "annulus": {"shape": "annulus", "radius": 0.4, "inner_ratio": 0.5, "process": "hard-disk", "area_fraction": 0.3},
    "hard-disk": {"radius": 0.35, "process": "hard-disk", "area_fraction": 0.5},
    "rsa": {"radius": 0.35, "process": "rsa", "area_fraction": 0.4},
    "lattice-square": {"radius": 0.3, "process": "lattice-square", "area_fraction": 0.3, "jitter": 0.1},
    "lattice-hex": {"radius": 0.3, "process": "lattice-hex", "area_fraction": 0.3, "jitter": 0.1},
    "points": {"radius": 0.35, "process": "points", "area_fraction": 0.3},
    "mixture": {"shape": "mixture", "mixture": "circle:0.35:0.6, square:0.3:0.4", "process": "hard-disk",
                "area_fraction": 0.3},
}


def _params(name, files):
    p = dict(CONFIGS[name])
    if name == "mask":
        p["filename"] = files["mask"]
    if name == "points":
        p["filename"] = files["points"]
        p.pop("area_fraction")  # a measured point set fixes its own area fraction
    return p


#: The chi-square test calls only ``sample`` and ``pdf`` (bsdf_checks.chi2_bsdf), so one family
#: per path through them is enough: the anisotropic closed-form kernels (ellipse, hexagon; square
#: and rectangle take the same path: kind "analytic", one row, not centred, no warp, the same
#: 256² sampling table code), the form-factor grid (mask), the centred anisotropic lobe with S
#: (mixture), the radial rows of a hard core, zero at u = 0 (hard-disk; rsa the same), the radial
#: rows not centred (points), and the lattice's own bilinear table (lattice-square; lattice-hex the
#: same kind "table" on its own 512² nodes).  The centred one-row radial rows peaked at u = 0
#: (circle-soft-spread, square-random) are test_plugin.py::test_chi2_lobe_circle_poisson's path at
#: the same three incidences.  Every family's eval is checked against the model below, all 13.
CHI2_CONFIGS = ["ellipse", "hexagon", "mask", "mixture", "hard-disk", "points", "lattice-square"]


@pytest.mark.slow
@pytest.mark.chi2
# 30° merged into 60°: the same path through sample/pdf (test_plugin.py ANGLES says why)
@pytest.mark.parametrize("theta", [0, 60, 80])
@pytest.mark.parametrize("name", CHI2_CONFIGS)
def test_chi2(mi_variant, data_files, name, theta):
    # Bragg spots are about one histogram bin wide: the test's own integration
    # of the pdf needs more sub-samples per bin there (ires=16 under-integrates)
    ires = 48 if name.startswith("lattice") else 16
    # the test's random numbers are fixed: some fifty chi-square runs at a 1 %
    # level give about one unlucky draw; the mixture at 60° is one (p = 0.0095 at
    # 1M samples, p = 0.15 at 4M, where a real mismatch would only grow)
    n = 4_000_000 if name == "mixture" else 1_000_000
    ok, test = chi2_test(_params(name, data_files), theta, smooth_context(), ires=ires, sample_count=n)
    assert ok, test.messages


@pytest.mark.parametrize("name", list(CONFIGS))
def test_eval_matches_reference_table_and_model(mi_variant, data_files, name):
    """eval = the reference's tabulated lobe · |cos θo| (float32), and ≈ the exact model."""
    import mitsuba as mi
    params = _params(name, data_files)
    bsdf = mi.load_dict({"type": "corona", **params})
    m = material_from_parameters(**params)
    rng = np.random.default_rng(0)
    wi = np.array([np.sin(0.4), 0.0, np.cos(0.4)])
    d = m.sample(rng.random((3000, 2)), 550.0)
    wo_xy = d - wi[:2]
    keep = np.hypot(wo_xy[:, 0], wo_xy[:, 1]) < 0.99
    wo_xy, d = wo_xy[keep], d[keep]
    wo = np.column_stack([wo_xy, -np.sqrt(1 - (wo_xy**2).sum(1))])
    val = assert_eval_matches(bsdf, transmitted_lobe(m, tabulated=True), wi, wo, (550.0,) * 4,
                              rtol=1e-4, atol=1e-5)[0][0]
    exact = m.lobe(d, 550.0) * np.abs(wo[:, 2])
    sel = exact > 1e-3 * exact.max()
    err = np.abs(val - exact)[sel] / exact[sel]
    rms = float(np.sqrt(np.mean(err**2)))
    # radial tables: du = 0.01 in u; 2D lobes: closed forms or cubic form-factor
    # grids × the radial S table (the goal: <= 0.5 % RMS, <= 2 % max)
    limit = (1e-4, 1e-3) if m.isotropic else (5e-3, 2e-2)
    if name == "points":
        limit = (5e-3, 2e-2)  # the measured S is itself interpolated from a q grid with kinks
    if name == "annulus":
        # a ring's dark rings lie closer together than a disk's: the radial table's linear
        # interpolation (du = 0.01) reaches 1.7e-3 relative just beside them (rms unchanged)
        limit = (1e-4, 2.5e-3)
    if name.startswith("lattice"):
        limit = None  # tables hold cell means of the Bragg peaks, not point values
    if limit is not None:
        assert rms < limit[0] and err.max() < limit[1], \
            f"{name}: relative error of the plugin's lobe rms {rms:.2e}, max {err.max():.2e}"
