"""One layer protocol: a flat layer and a layer of Mie spheres are both a
:class:`corona.model.material.Layer`, with the same methods, signatures and result keys; the
members built on a flat layer's one table of v(u) a Mie layer does not have at all."""
import inspect
import warnings

import numpy as np
import pytest

import corona
from corona.model import registry
from corona.model.material import Layer, Material
from corona.model.mie.material import SphereMaterial

COMPONENTS = ("coherent", "specular", "lobe_transmission", "lobe_reflection", "diffuse")
KEYS = set(COMPONENTS) | {"total", "forward", "backward"}
#: the members of a flat layer's one table of v(u): meaningless for a Mie layer, which has none
FLAT_ONLY = ("table", "render_lobe", "analytic_terms", "double_pass_visibility", "tabulated_transmittance",
             "lobe_terms", "radial_s_minus_one", "area_fraction_rows", "sample", "pdf")


@pytest.fixture(scope="module")
def layers():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", corona.CoronaWarning)
        pane = corona.GlassPane()
        return {
            "circle": corona.Material(corona.Circle(2.0), corona.HardDisk(0.3)),
            "square on glass": corona.Material(corona.Square(2.0), corona.HardDisk(0.3), substrate=pane),
            "sphere": corona.Material(corona.Sphere(2.0), corona.HardDisk(0.3)),
            "sphere on glass": corona.Material(corona.Sphere(2.0), corona.HardDisk(0.3), substrate=pane),
        }


def _public(cls):
    return {name for name, member in inspect.getmembers(cls)
            if not name.startswith("_") and inspect.isfunction(member)}


def test_both_layers_are_layers_and_the_constructor_builds_the_registered_one():
    assert issubclass(Material, Layer) and issubclass(SphereMaterial, Layer)
    assert not issubclass(SphereMaterial, Material)        # a sibling, not a flat layer that refuses
    pane = corona.GlassPane()
    for kwargs in ({}, {"substrate": pane}):
        assert type(corona.Material(corona.Sphere(2.0), corona.Poisson(0.1), **kwargs)) is SphereMaterial
        assert type(corona.Material(shape=corona.Sphere(2.0), process=corona.Poisson(0.1), **kwargs)) is SphereMaterial
        assert type(corona.Material(corona.Circle(2.0), corona.Poisson(0.1), **kwargs)) is Material
    assert registry.layer_class(corona.Sphere(2.0)) is SphereMaterial
    assert registry.layer_class(corona.SizeDistribution(corona.Sphere(2.0), 0.1)) is SphereMaterial
    assert registry.layer_class(corona.Circle(2.0)) is None
    with pytest.raises(TypeError):
        Layer()                                            # the protocol alone is not a layer


def test_every_protocol_method_has_the_same_signature():
    """Every method of the protocol exists on both layers under the identical signature
    (names, kinds, defaults, annotations)."""
    shared = _public(Layer)
    assert {"eval", "lobe", "directional_albedo", "coherent_transmission", "specular_reflection",
            "diffuse_transmittance", "lobe_dimensionless", "lobe_tabulated", "coherent_weight"} <= shared
    for cls in (Material, SphereMaterial):
        assert shared <= _public(cls), cls
        differ = {name: (str(inspect.signature(getattr(Layer, name))), str(inspect.signature(getattr(cls, name))))
                  for name in sorted(shared)
                  if inspect.signature(getattr(Layer, name)) != inspect.signature(getattr(cls, name))}
        assert not differ, (cls, differ)


def test_every_property_is_there_for_both():
    props = {name for name, m in inspect.getmembers(Layer) if isinstance(m, property)}
    assert {"length_scale", "coherent_transmittance", "reflectance", "lobe_weight", "opaque_fraction",
            "render_kind"} <= props
    for name in props:
        assert hasattr(Material, name) and hasattr(SphereMaterial, name), name


@pytest.mark.slow
@pytest.mark.parametrize("cos_i", [1.0, 0.6, -0.8])
def test_directional_albedo_has_the_same_keys_for_every_layer(layers, cos_i):
    for name, m in layers.items():
        e = m.directional_albedo(cos_i, 550.0, n_phi=64)
        assert set(e) == KEYS, name
        assert e["total"] == pytest.approx(sum(e[k] for k in COMPONENTS), rel=1e-12), name
        assert e["total"] <= 1.0 + 1e-3, name
        assert all(np.isfinite(v) and v >= -1e-12 for v in e.values()), (name, e)


@pytest.mark.slow
def test_a_flat_layers_forward_lobe_is_its_transmitted_lobe_without_a_pane(layers):
    """forward: the lobe through the layer without the pane's factors; a planar screen has no
    backward lobe.  On a pane the transmitted lobe is the forward one times T' < 1."""
    e = layers["circle"].directional_albedo(0.8, 550.0)
    assert e["forward"] == pytest.approx(e["lobe_transmission"], rel=1e-12) and e["backward"] == 0.0
    g = layers["square on glass"].directional_albedo(0.8, 550.0)
    assert 0.8 * g["forward"] < g["lobe_transmission"] < g["forward"]


@pytest.mark.slow
def test_pane_false_is_the_layer_alone(layers):
    """Negative control included: with its pane the answer differs."""
    on_glass = layers["square on glass"]
    alone = corona.Material(on_glass.shape, on_glass.process)
    a, b = on_glass.directional_albedo(0.7, 500.0, pane=False), alone.directional_albedo(0.7, 500.0)
    assert a == pytest.approx(b, rel=1e-12)
    assert on_glass.directional_albedo(0.7, 500.0)["specular"] > 1e-3 and a["specular"] == 0.0
    assert on_glass.substrate is not None        # the pane of the material itself is kept


@pytest.mark.slow
def test_the_shared_parameters_a_flat_layer_does_not_need_change_nothing(layers):
    m = layers["circle"]
    wi = np.array([0.3, 0.0, np.sqrt(1 - 0.09)])
    wo = np.array([[-0.31, 0.01, -np.sqrt(1 - 0.31**2 - 0.01**2)]])
    assert np.array_equal(m.eval(wi, wo, 550.0, exact=True), m.eval(wi, wo, 550.0))
    u = np.array([[0.5, 0.2], [3.0, -1.0]])
    assert np.array_equal(m.lobe_dimensionless(u, 400.0), m.lobe_dimensionless(u))
    assert np.array_equal(m.lobe_dimensionless_radial([0.5, 3.0], 700.0), m.lobe_dimensionless_radial([0.5, 3.0]))
    assert m.coherent_transmission(0.5, 400.0) == m.coherent_transmission(0.5)
    assert m.directional_albedo(0.6) == m.directional_albedo(0.6, n_phi=512)
    assert m.directional_albedo(0.6, n_phi=8)["lobe_transmission"] != m.directional_albedo(0.6)["lobe_transmission"]


@pytest.mark.parametrize("member", FLAT_ONLY)
def test_what_means_nothing_for_spheres_is_not_there(member):
    """A Mie layer has no member built on a flat layer's one table of v(u) (its lobes are rows
    over the size parameter); the flat layer keeps each one (the negative control)."""
    assert hasattr(Material, member)
    assert not hasattr(SphereMaterial, member)


def test_the_flat_layer_keeps_its_table():
    flat = corona.Material(corona.Circle(2.0), corona.Poisson(0.2))
    assert flat.render_kind == "radial" and flat.table.total > 0 and flat.opaque_fraction == pytest.approx(0.8)


@pytest.mark.slow
def test_a_sphere_layer_says_what_it_is(layers):
    m = layers["sphere"]
    assert m.render_kind == "mie" and m.opaque_fraction == 0.0
    with pytest.raises(AttributeError):
        m.table


def test_a_sphere_in_a_mixture_is_refused_in_one_line():
    mix = corona.Mixture([(corona.Sphere(2.0), 0.5), (corona.Circle(2.0), 0.5)])
    with pytest.raises(corona.CoronaError) as err:
        corona.Material(mix, corona.Poisson(0.1))
    assert "size distribution" in str(err.value) and "\n" not in str(err.value)


def test_material_of_a_sphere_runs_the_constructor_once(monkeypatch):
    calls = []
    init = SphereMaterial.__init__

    def counted(self, *args, **kwargs):
        calls.append(args)
        init(self, *args, **kwargs)
    monkeypatch.setattr(SphereMaterial, "__init__", counted)
    m = corona.Material(corona.Sphere(2.0), corona.Poisson(0.1))
    assert type(m) is SphereMaterial and len(calls) == 1
