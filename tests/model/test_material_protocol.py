"""One material protocol: a layer of Mie spheres is a Material with the same methods,
signatures and result keys; what means nothing for spheres says so in one line."""
import inspect
import warnings

import numpy as np
import pytest

import corona
from corona.model.material import Material, MieMembers
from corona.model.mie.layer import SphereMaterial

COMPONENTS = ("coherent", "specular", "lobe_transmission", "lobe_reflection", "diffuse")
KEYS = set(COMPONENTS) | {"total", "forward", "backward"}


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


def _public_methods(cls):
    return {name for name, member in inspect.getmembers(cls)
            if not name.startswith("_") and inspect.isfunction(member)}


@pytest.mark.slow
def test_a_sphere_layer_is_a_material(layers):
    assert issubclass(SphereMaterial, Material)
    for name in ("sphere", "sphere on glass"):
        assert type(layers[name]) is SphereMaterial and isinstance(layers[name], corona.Material)
    assert type(layers["circle"]) is Material


def test_every_method_has_the_same_signature():
    """Every public method of Material exists on SphereMaterial with the identical signature
    (names, kinds, defaults, annotations), the refusals included."""
    shared = _public_methods(Material)
    assert shared <= _public_methods(SphereMaterial)
    assert {"eval", "lobe", "directional_albedo", "coherent_transmission", "specular_reflection",
            "diffuse_transmittance", "lobe_dimensionless", "lobe_tabulated"} <= shared
    differ = {name: (str(inspect.signature(getattr(Material, name))),
                     str(inspect.signature(getattr(SphereMaterial, name))))
              for name in sorted(shared)
              if inspect.signature(getattr(Material, name)) != inspect.signature(getattr(SphereMaterial, name))}
    assert not differ, differ


def test_every_property_is_there_for_both():
    props = {name for name, m in inspect.getmembers(Material) if isinstance(m, (property,))}
    for name in props:
        assert hasattr(SphereMaterial, name), name


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


REFUSED = [("table", None), ("render_lobe", None), ("analytic_terms", None), ("double_pass_visibility", None),
           ("tabulated_transmittance", None), ("lobe_terms", ([1.0, 2.0],)), ("radial_s_minus_one", ()),
           ("area_fraction_rows", ()), ("sample", ([[0.5, 0.5]], 550.0)), ("pdf", ([[0.01, 0.0]], 550.0))]


@pytest.mark.slow
@pytest.mark.parametrize("member, args", REFUSED)
def test_what_means_nothing_for_spheres_is_refused_in_one_line(layers, member, args):
    m = layers["sphere"]
    with pytest.raises(corona.CoronaError) as err:
        value = getattr(m, member)
        if args is not None:
            value(*args)
    text = str(err.value)
    assert f"SphereMaterial.{member} is not available for shape='sphere'" in text and "\n" not in text


def test_every_refusal_is_listed():
    """Each member MieMembers replaces is tested above, and the flat layer keeps them all."""
    own = {name for name in vars(MieMembers) if not name.startswith("_")} - {"render_kind", "opaque_fraction"}
    assert own == {name for name, _ in REFUSED}
    flat = corona.Material(corona.Circle(2.0), corona.Poisson(0.2))
    assert flat.render_kind == "radial" and flat.table.total > 0 and flat.opaque_fraction == pytest.approx(0.8)


@pytest.mark.slow
def test_a_sphere_layer_says_what_it_is(layers):
    m = layers["sphere"]
    assert m.render_kind == "mie" and m.opaque_fraction == 0.0
    assert MieMembers._layer_class is SphereMaterial


def test_material_of_a_sphere_runs_the_constructor_once(monkeypatch):
    calls = []
    init = SphereMaterial.__init__

    def counted(self, *args, **kwargs):
        calls.append(args)
        init(self, *args, **kwargs)
    monkeypatch.setattr(SphereMaterial, "__init__", counted)
    m = corona.Material(corona.Sphere(2.0), corona.Poisson(0.1))
    assert type(m) is SphereMaterial and len(calls) == 1
