"""Spheres as one scatterer family of the layer: on glass, the unused parameters, the refusals,
the material protocol and the decoupling rule."""
import inspect
import re
import warnings

import numpy as np
import pytest

from bsdf_checks import assert_eval_matches, chi2_bsdf, interaction

WAVELENGTHS = (450.0, 520.0, 600.0, 700.0)
BASE = {"type": "corona", "shape": "sphere", "radius": 2.0, "area_fraction": 0.3, "process": "hard-disk"}


def _load(**extra):
    import mitsuba as mi
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return mi.load_dict({**BASE, **extra})


@pytest.fixture(scope="module")
def panes(mi_variant):
    return {side: _load(substrate="glass", substrate_side=side) for side in ("front", "back")}


def _directions(wi, rng, n=2000):
    """Random directions plus many near the forward, backward and mirrored-forward peaks."""
    from corona.model.mie.layer import frame
    v = rng.normal(size=(n, 3))
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    out = [v]
    for axis, spread in ((-wi, 0.15), (wi, 0.3), (wi * np.array([-1.0, -1.0, 1.0]), 0.15)):
        th = rng.uniform(0, spread, n)
        ph = rng.uniform(0, 2 * np.pi, n)
        e1, e2 = frame(axis)
        out.append(np.cos(th)[:, None] * axis + np.sin(th)[:, None] * (np.cos(ph)[:, None] * e1
                                                                      + np.sin(ph)[:, None] * e2))
    return np.concatenate(out)


@pytest.mark.parametrize("side", ["front", "back"])
def test_glass_eval_matches_numpy_reference(panes, side):
    bsdf = panes[side]
    m = bsdf.material
    assert m.substrate is not None and m.substrate.side == side
    rng = np.random.default_rng(3)
    for deg in (0, 30, 60, 120, 160):            # > 90: light from the back (-z) side
        wi = np.array([np.sin(np.radians(deg)), 0.0, np.cos(np.radians(deg))])
        wo = _directions(wi, rng)
        val, ref, _ = assert_eval_matches(bsdf, m.eval, wi, wo, WAVELENGTHS, rtol=0.0, atol=1e-4, peak="all")
    # negative control: the pane changes the value (the layer alone is another BSDF)
    alone = np.stack([m._layer_eval(wi, wo, lam)[0] for lam in WAVELENGTHS])
    assert np.max(np.abs(val - alone)) > 1e-2 * ref.max()


@pytest.mark.parametrize("side", ["front", pytest.param("back", marks=pytest.mark.slow)])   # 1.3 s CPU each
def test_glass_white_furnace_by_sampling(panes, side):
    # E[weight] of sample() is the directional albedo of the numpy reference (its own
    # quadrature of eval plus the delta weights) and <= 1
    import mitsuba as mi
    bsdf = panes[side]
    n = 400_000
    rng = np.random.default_rng(5)
    for deg in (0, 50, 130):
        wi = (np.sin(np.radians(deg)), 0.0, np.cos(np.radians(deg)))
        bs, w = bsdf.sample(mi.BSDFContext(), interaction(n, wi), mi.Float(rng.random(n).astype(np.float32)),
                            mi.Point2f(rng.random((2, n)).astype(np.float32)))
        mean = np.asarray(w).mean(axis=-1)
        ref = np.array([bsdf.material.directional_albedo(wi[2], lam, n_phi=128)["total"] for lam in WAVELENGTHS])
        assert np.all(mean <= 1.0 + 3e-3), (deg, mean)
        assert mean == pytest.approx(ref, abs=5e-3), (deg, mean, ref)
        comps = np.asarray(bs.sampled_component)
        assert set(np.unique(comps)) <= {0, 1, 2, 3, 4}
        if (wi[2] > 0) == (side == "front"):     # light meets the layer first: all five components
            assert set(np.unique(comps)) == {0, 1, 2, 3, 4}


@pytest.mark.slow
@pytest.mark.chi2
@pytest.mark.parametrize("component,deg", [(1, 30), (2, 30), (4, 0), (4, 40), (1, 140)])
def test_glass_chi2_per_component(panes, component, deg):
    import mitsuba as mi
    ctx = mi.BSDFContext()
    ctx.type_mask = mi.BSDFFlags.GlossyTransmission | mi.BSDFFlags.GlossyReflection
    ctx.component = component
    ok, test = chi2_bsdf(panes["front"], deg, ctx, sample_count=300_000, res=101, ires=32)
    assert ok, test.messages


def test_glass_furnace_numpy():
    from corona.parameters import material_from_parameters
    for side in ("front", "back"):
        m = material_from_parameters(shape="sphere", radius=2.0, area_fraction=0.7, process="hard-disk",
                                     substrate="glass", substrate_side=side, substrate_ior=1.9)
        for ci in (1.0, 0.5, 0.1, -0.3, -1.0):
            e = m.directional_albedo(ci, 450.0, n_phi=96)
            assert e["total"] <= 1.0 + 1e-4, (side, ci, e)
            assert e["specular"] > 0


@pytest.mark.parametrize("extra", [{"orientation": "random"}, {"edge_width": 0.1}, {"angle": 30.0},
                                   {"aspect": 0.5}, {"albedo": 0.4}], ids=lambda e: next(iter(e)))
def test_parameters_meaningless_for_a_sphere_warn_once_and_are_ignored(mi_variant, extra):
    import mitsuba as mi

    from corona import CoronaWarning
    plain = _load()
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        layer = mi.load_dict({**BASE, **extra})
    unused = [w for w in caught if issubclass(w.category, CoronaWarning) and "unused parameter" in str(w.message)]
    assert len(unused) == 1 and next(iter(extra)) in str(unused[0].message), [str(w.message) for w in caught]
    wi = np.array([0.5, 0.0, np.sqrt(0.75)])
    wo = _directions(wi, np.random.default_rng(1), n=300)
    args = (mi.BSDFContext(), interaction(len(wo), wi), mi.Vector3f(wo.T.astype(np.float32)))
    np.testing.assert_array_equal(np.asarray(layer.eval(*args)), np.asarray(plain.eval(*args)))


def test_albedo_texture_is_unused(mi_variant):
    import mitsuba as mi

    from bsdf_checks import bitmap_texture
    from corona import CoronaWarning
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        mi.load_dict({**BASE, "albedo": bitmap_texture([[0.1, 0.4], [0.6, 0.3]])})
    assert sum("unused parameter" in str(w.message) and "albedo" in str(w.message) for w in caught
               if issubclass(w.category, CoronaWarning)) == 1


@pytest.mark.parametrize("extra,line", [
    ({"process": "lattice-hex", "area_fraction": 0.2, "substrate": "glass"},
     r"substrate='glass' is out of range for shape='sphere' with process='lattice-hex' in the renderer; "
     r"allowed none"),
    ({"radius": "tex"}, r"radius=1 … 3 is out of range for shape='sphere' with a dispersive ior \(water\): "
                        r"one table of rows holds the index of one radius"),
    ({"substrate": "mirror"}, r"substrate=Mirror\(.*\) is out of range for shape='sphere'; allowed none or an "
                              r"incoherent glass pane"),
    ({"substrate": "glass", "substrate_thickness": 1000.0}, r"substrate=GlassPane\(.*\) is out of range"),
], ids=["lattice-on-glass", "radius-texture", "mirror", "thick-glass"])
def test_refusals_are_one_line(mi_variant, extra, line):
    import mitsuba as mi

    from bsdf_checks import bitmap_texture
    extra = {k: (bitmap_texture([[1.0, 2.0], [3.0, 2.0]]) if v == "tex" else v) for k, v in extra.items()}
    with pytest.raises(Exception) as err:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            mi.load_dict({**BASE, **extra})
    lines = [ln for ln in str(err.value).splitlines() if "CoronaError" in ln or "out of range" in ln]
    assert lines and any(re.search(line, ln) for ln in lines), str(err.value)


def test_sphere_material_satisfies_the_material_protocol():
    # docs/layer.md's protocol: the same members, the same parameter names (a sphere's extras
    # only after them, with defaults), the same result keys
    import corona
    from corona.parameters import material_from_parameters
    sphere = material_from_parameters(shape="sphere", radius=2.0, area_fraction=0.3, process="hard-disk")
    flat = corona.Material(corona.Circle(2.0), corona.HardDisk(0.3))
    for name in ("lobe", "eval", "coherent_transmission", "diffuse_transmittance", "directional_albedo",
                 "table_params", "specular_reflection"):
        a = list(inspect.signature(getattr(flat, name)).parameters.values())
        b = list(inspect.signature(getattr(sphere, name)).parameters.values())
        assert [p.name for p in b[:len(a)]] == [p.name for p in a], name
        assert [p.default for p in b[:len(a)]] == [p.default for p in a], name
        assert all(p.default is not inspect.Parameter.empty for p in b[len(a):]), name
    for name in ("shape", "process", "mode", "albedo", "substrate", "use_cache", "area_fraction",
                 "length_scale", "isotropic", "coherent_transmittance", "reflectance", "lobe_weight"):
        assert hasattr(sphere, name), name
    e_flat = flat.directional_albedo(0.8, 550.0)
    e_sphere = sphere.directional_albedo(0.8, 550.0)
    assert set(e_flat) == set(e_sphere)            # forward and backward: every material's own lobes
    assert e_sphere["total"] == pytest.approx(sum(e_sphere[k] for k in e_flat
                                                  if k not in ("total", "forward", "backward")))
    assert sphere.diffuse_transmittance() == pytest.approx(sphere.directional_albedo(1.0, 550.0)["lobe_transmission"],
                                                           rel=1e-3)


def test_forward_lobe_is_the_decoupling_rule():
    # the sphere's forward lobe is corona.model.layer.decoupled_lobe of its P, C and S (a size spread:
    # C < P), and S - 1 matters (negative control: S = 1 gives another lobe)
    from corona.model.layer import decoupled_lobe
    from corona.parameters import material_from_parameters
    m = material_from_parameters(shape="sphere", radius=1.5, area_fraction=0.4, process="hard-disk",
                                 size_spread=0.2)
    wi = np.array([0.0, 0.0, 1.0])
    th = np.linspace(0.001, 0.6, 200)
    wo = np.stack([np.sin(th), 0 * th, -np.cos(th)], -1)
    Z_f, _, forward = m._lobes(wi, wo, 550.0)
    assert np.all(forward)
    j, t = m._row(550.0)
    x = m._x(550.0)
    s = np.linalg.norm(wo + wi, axis=-1)
    P, C = m._blend("P_f", j, t, x, s), m._blend("C_f", j, t, x, s)
    S = m.structure_factor(2 * np.pi * 1.5 * np.sin(th) / 0.55)
    np.testing.assert_allclose(Z_f, decoupled_lobe(P, C, S), rtol=1e-12)
    assert np.max(np.abs(Z_f - decoupled_lobe(P, C, 1.0))) > 0.05 * np.max(Z_f)


@pytest.mark.parametrize("process", ["hard-disk", "rsa"])
def test_area_fraction_texture_with_a_hard_core(mi_variant, process):
    # each texel is the numpy layer of its F_a (S(q) and the cap's energies at that F_a): exact on
    # the F_a rows, the Hermite between them within 2e-3 of the peak; negative control: the
    # layer of another F_a differs; and no texel returns more than it receives
    import mitsuba as mi

    from bsdf_checks import bitmap_texture
    from corona.parameters import material_from_parameters
    texels = {(0.25, 0.25): 0.12, (0.75, 0.25): 0.3, (0.25, 0.75): 0.2}
    layer = _load(process=process, area_fraction=bitmap_texture([[0.12, 0.3], [0.2, 0.3]]))
    assert layer.fa_rows_np[0] == pytest.approx(0.12) and layer.fa_rows_np[-1] == pytest.approx(0.3)
    rng = np.random.default_rng(6)
    wi = np.array([0.5, 0.0, np.sqrt(0.75)])
    wo = _directions(wi, rng, n=1000)
    for uv, fa in texels.items():
        si = interaction(len(wo), wi)
        si.uv = mi.Point2f(*uv)
        val = np.asarray(layer.eval(mi.BSDFContext(), si, mi.Vector3f(wo.T.astype(np.float32))))
        m = _same_rows(layer, material_from_parameters(shape="sphere", radius=2.0, process=process,
                                                       area_fraction=fa))
        ref = np.stack([m.eval(wi, wo, lam) for lam in WAVELENGTHS])
        on_row = np.min(np.abs(layer.fa_rows_np - fa)) < 1e-6
        assert np.max(np.abs(val - ref)) < (1e-4 if on_row else 2e-3) * ref.max(), (fa, on_row)
        other = _same_rows(layer, material_from_parameters(shape="sphere", radius=2.0, process=process,
                                                           area_fraction=fa + 0.04))
        ref2 = np.stack([other.eval(wi, wo, lam) for lam in WAVELENGTHS])
        assert np.max(np.abs(val - ref2)) > 1e-2 * ref.max()
        n = 200_000
        bs, w = layer.sample(mi.BSDFContext(), _uv(n, wi, uv),
                             mi.Float(rng.random(n).astype(np.float32)),
                             mi.Point2f(rng.random((2, n)).astype(np.float32)))
        assert np.all(np.asarray(w).mean(axis=-1) <= 1.0 + 3e-3), fa


def _same_rows(layer, m):
    """The numpy layer ``m`` on rows in x over the plugin layer's radii (``radius_cover``)."""
    from corona.model.mie.material import SphereMaterial
    return SphereMaterial(m.shape, m.process, substrate=m.substrate, radius_cover=layer.radius_cover)


def _uv(n, wi, uv):
    import mitsuba as mi
    si = interaction(n, wi)
    si.uv = mi.Point2f(*uv)
    return si
