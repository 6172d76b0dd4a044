"""Spheres on a point file (process=points): the centres' measured S(q) is radial (an isotropic
corona.PointSet), so the sphere layer carries it as it carries a hard core's: the plugin against
the numpy reference, its chi-square and its furnace; and that the renderer takes a fixed lattice
(its own path, test_sphere_lattice_plugin.py)."""
import warnings

import numpy as np
import pytest

from bsdf_checks import assert_eval_matches, chi2_bsdf, furnace


@pytest.fixture(scope="module")
def points_file(tmp_path_factory):
    from corona.reference.rsa import rsa_configuration
    pts = rsa_configuration(60.0, 0.3, sigma=2.0, seed=5)       # 1 µm spheres: σ = 2r
    path = tmp_path_factory.mktemp("points") / "centres.csv"
    np.savetxt(path, pts, delimiter=",")
    return str(path)


@pytest.fixture(scope="module")
def bsdf(points_file, mi_variant):
    import mitsuba as mi
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return mi.load_dict({"type": "corona", "shape": "sphere", "radius": 1.0, "process": "points",
                             "filename": points_file})


def test_points_layer_is_the_point_sets(bsdf, points_file):
    from corona.model.processes import PointSet
    m = bsdf.material
    assert isinstance(m.process, PointSet) and m.process.isotropic
    assert 0.2 < m.area_fraction < 0.4
    # the measured S(q) enters the forward lobe: it differs from Poisson centres' at the first ring
    st = m.structure_table
    assert st is not None and np.min(st[1][: int(2.0 / st[0])]) < 0.7


@pytest.mark.parametrize("deg", [0.0, 40.0, 150.0])
def test_eval_matches_numpy(bsdf, deg):
    rng = np.random.default_rng(1)
    wi = np.array([np.sin(np.radians(deg)), 0.0, np.cos(np.radians(deg))])
    wo = rng.normal(size=(3000, 3))
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    near = -wi + 0.15 * rng.normal(size=(3000, 3))
    wo = np.concatenate([wo, near / np.linalg.norm(near, axis=1, keepdims=True)])
    assert_eval_matches(bsdf, bsdf.material.eval, wi, wo, rtol=2e-3, atol=2e-5)


@pytest.mark.slow
@pytest.mark.chi2
# 30° merged into 60°: the sphere plugin branches on the side of wi only, not its angle
@pytest.mark.parametrize("deg", [0.0, 60.0])
def test_chi2(bsdf, deg):
    from bsdf_checks import smooth_context
    ok, test = chi2_bsdf(bsdf, deg, smooth_context(), sample_count=300_000, res=101, ires=32)
    assert ok, test.messages


def test_furnace(bsdf):
    for deg in (0.0, 60.0, 170.0):
        mean, err = furnace(bsdf, deg, n=100_000)
        assert np.all(mean <= 1.0 + 3 * err), (deg, mean)


def test_renderer_takes_a_lattice(mi_variant):
    # the lattice path's physics: tests/plugin/test_sphere_lattice_plugin.py
    import mitsuba as mi
    bsdf = mi.load_dict({"type": "corona", "shape": "sphere", "radius": 1.0, "process": "lattice-hex",
                         "area_fraction": 0.2})
    assert bsdf.lattice is not None and bsdf.lobe.lattice.kind == "hexagonal"
    # the numpy model takes it from the same parameters
    from corona.parameters import material_from_parameters
    m = material_from_parameters(shape="sphere", radius=1.0, process="lattice-hex", area_fraction=0.2)
    assert m.lattice is not None and m.lattice.kind == "hexagonal"


@pytest.mark.slow
@pytest.mark.parametrize("fa", [0.12, 0.04])
def test_sparse_point_file_loads_and_matches_numpy(mi_variant, tmp_path, fa):
    """A sparse point file (F_a at most ~0.12; issue 47, item 7: IndexError at load, the plugin's F_a
    rows were built about the area_fraction default 0.3, above the file's own): loads as the flat
    circle does, eval is the numpy reference's, and the white furnace ≤ 1 and the model's albedo."""
    import mitsuba as mi
    from corona.reference.rsa import rsa_configuration
    path = tmp_path / "sparse.csv"
    np.savetxt(path, rsa_configuration(60.0, fa, sigma=2.0, seed=5), delimiter=",")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        mi.load_dict({"type": "corona", "shape": "circle", "radius": 1.0, "process": "points",
                      "filename": str(path)})
        bsdf = mi.load_dict({"type": "corona", "shape": "sphere", "radius": 1.0, "process": "points",
                             "filename": str(path)})
    m = bsdf.material
    assert abs(m.area_fraction - fa) < 0.02 and m.structure_table is not None
    rng = np.random.default_rng(3)
    wi = np.array([np.sin(0.5), 0.0, np.cos(0.5)])
    wo = rng.normal(size=(2000, 3))
    near = -wi + 0.15 * rng.normal(size=(2000, 3))
    wo = np.concatenate([wo, near]) / np.linalg.norm(np.concatenate([wo, near]), axis=1, keepdims=True)
    assert_eval_matches(bsdf, m.eval, wi, wo, rtol=2e-3, atol=2e-5)
    lams = (450.0, 520.0, 600.0, 700.0)
    for deg in (0.0, 85.0):
        mean, err = furnace(bsdf, deg, lams, n=100_000)
        ref = np.array([m.directional_albedo(np.cos(np.radians(deg)), lam, n_phi=96)["total"] for lam in lams])
        assert np.all(mean <= 1.0 + 4 * err), (deg, mean, err)
        assert np.all(np.abs(mean - ref) <= 0.01 * ref), (deg, mean, ref)
