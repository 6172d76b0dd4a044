"""One registry of families (corona.model.registry): every registered shape and process appears
the same everywhere (spec, CLI, fitter, kernel, brute-force reference, docs), and a bad family
or a taken name is one clear error."""
from __future__ import annotations

import os
import re

import numpy as np
import pytest

import corona
from corona import parameters
from corona._validation import CoronaError
from corona.model import registry
from corona.parameters import DEFAULTS, SPEC, Parameter, material_from_parameters

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def _choices(command, name):
    return tuple({p.name: p for p in command.params}[name].type.choices)


def test_every_family_is_in_the_spec_the_cli_and_the_docs():
    from corona.apps import cli
    shapes, processes = tuple(registry.SHAPE_FAMILIES), tuple(registry.PROCESS_FAMILIES)
    assert shapes == parameters.SHAPES == SPEC["shape"].choices
    assert processes == parameters.PROCESSES == SPEC["process"].choices
    assert _choices(cli.lobe, "shape") == shapes and _choices(cli.lobe, "process") == processes
    # the docs' parameter table (docs/parameters.md, generated from the spec) and the plugin's
    # docstring list each family
    readme = open(os.path.join(ROOT, "docs", "parameters.md"), encoding="utf-8").read()
    row = re.search(r"^\| `shape` \|.*$", readme, re.M).group(0)
    prow = re.search(r"^\| `process` \|.*$", readme, re.M).group(0)
    from corona.mitsuba import bsdf
    for name in shapes:
        assert name in row and name in bsdf.__doc__, name
    for name in processes:
        assert name in prow, name


def test_each_parameter_applies_exactly_where_a_family_reads_it():
    """``applies`` is derived from the families' lists: a parameter of families is used by the
    families that read it (a mixture: its components' too, but radius) and by no other."""
    for name, p in SPEC.items():
        scoped = [c for c in p.applies if c.startswith(("shape=", "process="))]
        if not scoped:
            continue
        for fam in registry.SHAPE_FAMILIES.values():
            parts = fam.of_components and name != "radius" and any(
                name in f.parameters for f in registry.SHAPE_FAMILIES.values() if f.mixable)
            assert (f"shape={fam.name}" in p.applies) == (name in fam.parameters or parts), (name, fam.name)
        for fam in registry.PROCESS_FAMILIES.values():
            assert (f"process={fam.name}" in p.applies) == (name in fam.parameters), (name, fam.name)
    for fam in (*registry.SHAPE_FAMILIES.values(), *registry.PROCESS_FAMILIES.values()):
        assert all(n in SPEC for n in fam.parameters), fam.name


def test_the_fitter_fits_registered_families_only():
    from corona.apps import cli
    from corona.apps.fit import FIT_PROCESSES, FIT_SHAPES
    assert set(FIT_SHAPES) <= set(registry.SHAPE_FAMILIES)
    assert set(FIT_PROCESSES) <= set(registry.PROCESS_FAMILIES)
    assert _choices(cli.fit, "shape") == tuple(FIT_SHAPES)
    assert _choices(cli.fit, "process") == tuple(FIT_PROCESSES)


def test_every_kernel_term_has_a_kernel_and_every_outline_a_rasteriser():
    """Each family's instance at the defaults: its kernel terms (if any) are kinds the kernel
    evaluates, and the brute-force reference rasterises it (the Mie sphere is refused there in one
    line: tests/reference/test_wave.py)."""
    pytest.importorskip("numba")
    from corona.mitsuba.kernels import TERM_KINDS
    from corona.reference import wave
    for fam in registry.SHAPE_FAMILIES.values():
        if fam.cls is None or fam.name == "mask":       # composites; a mask's image is its rasteriser
            continue
        shape = fam.factory(parameters._checked(fam, {**DEFAULTS, "shape": fam.name, "radius": 2.0}))
        terms = shape.kernel_terms()
        assert terms is None or {t.kind for t in terms} <= set(TERM_KINDS), fam.name
        if fam.name == "sphere":
            continue
        assert wave._leaves_of(shape) == [shape], fam.name
        x = np.linspace(-3.0, 3.0, 61)
        sd = shape.signed_distance(x[:, None], x[None, :])
        assert sd.shape == (61, 61) and np.all(np.isfinite(sd)) and sd.min() < 0 < sd.max(), fam.name
        # the area inside the outline is the shape's area (1 % on this grid)
        assert np.isclose(np.sum(sd < 0) * (x[1] - x[0]) ** 2, shape.area, rtol=0.05), fam.name


@pytest.mark.slow     # the reference tier (numba), a table per process: 6 s of CPU cold
@pytest.mark.reference
def test_every_process_has_a_reference_position_source(tmp_path):
    pytest.importorskip("numba")
    from corona.reference import wave
    pts = tmp_path / "p.txt"
    np.savetxt(pts, np.random.default_rng(1).uniform(0, 40, (30, 2)))
    for fam in registry.PROCESS_FAMILIES.values():
        m = material_from_parameters(shape="circle", radius=1.0, process=fam.name,
                                     **({"filename": str(pts)} if fam.name == "points" else {"area_fraction": 0.2}))
        src = wave.positions_source(m.process, m.shape, n_scatterers=64)
        assert all(L > 0 for L in src.box), fam.name


class _Blob(corona.Shape):
    isotropic = True

    def __init__(self, radius=1.0, wobble=0.1):
        self.radius, self.wobble = radius, wobble

    @property
    def area(self):
        return np.pi * self.radius**2

    @property
    def length_scale(self):
        return self.radius

    def amplitude(self, q):
        qa = np.hypot(*np.moveaxis(np.asarray(q, dtype=float), -1, 0))
        return (self.area * np.exp(-0.5 * (1.0 + self.wobble) * (qa * self.radius) ** 2)).astype(complex)


def _one_line_error(call, *words):
    with pytest.raises(CoronaError) as err:
        call()
    text = str(err.value)
    assert "\n" not in text and all(w in text for w in words), text


def test_a_bad_family_or_a_taken_name_is_one_clear_error(restored_registry):
    _one_line_error(lambda: corona.register_shape("circle", _Blob, ["radius"]), "name='circle'", "taken", "Circle")
    _one_line_error(lambda: corona.register_process("poisson", corona.Poisson), "name='poisson'", "taken")
    _one_line_error(lambda: corona.register_shape("Bad Name", _Blob), "name='Bad Name'", "lower-case")
    _one_line_error(lambda: corona.register_shape("blob", dict), "not a corona.Shape subclass")
    _one_line_error(lambda: corona.register_process("blobs", _Blob), "not a corona.Process subclass")

    class NoAmplitude(corona.Shape):
        area = 1.0
        length_scale = 1.0
    _one_line_error(lambda: corona.register_shape("blob", NoAmplitude), "does not implement amplitude")
    # the class does not take a parameter given by name
    _one_line_error(lambda: corona.register_shape("blob", _Blob, ["radius", "aspect"]), "takes no parameter",
                    "aspect")
    # a new parameter whose name the spec holds with another meaning
    clash = Parameter("radius", "float", "mm", 1.0, "another radius", low=0.0, high=5.0)
    _one_line_error(lambda: corona.register_shape("blob", _Blob, [clash]), "'radius'", "clashes")
    # a parameter name the spec does not hold, given without its Parameter
    _one_line_error(lambda: corona.register_shape("blob", _Blob, ["radius", "wobble"]), "'wobble'",
                    "not in the spec")
    # nothing of the failed registrations stayed
    assert "blob" not in registry.SHAPE_FAMILIES and "blob" not in SPEC["shape"].choices


def test_a_users_family_by_name_reads_its_own_checked_parameter(restored_registry):
    wobble = Parameter("wobble", "float", "", 0.1, "blob: wobble", low=0.0, high=0.5)
    corona.register_shape("blob", _Blob, ["radius", wobble])
    assert "blob" in parameters.SHAPES and "blob" in SPEC["shape"].choices
    assert SPEC["wobble"].applies == ("shape=blob",) and "shape=blob" in SPEC["radius"].applies
    assert "shape=blob" in SPEC["edge_width"].applies and "shape=blob" not in SPEC["orientation"].applies
    m = material_from_parameters(shape="blob", radius=2.0, wobble=0.3, area_fraction=0.2)
    assert isinstance(m.shape, _Blob) and m.shape.radius == 2.0 and m.shape.wobble == 0.3
    _one_line_error(lambda: material_from_parameters(shape="blob", wobble=0.7), "wobble=0.7", "[0, 0.5]")
    with pytest.warns(corona.CoronaWarning, match="wobble"):
        material_from_parameters(shape="circle", wobble=0.2)
    # the spec's other parameters are unchanged
    assert SPEC["radius"].meaning == parameters.PARAMETERS[1].meaning


def _plugin_vs_model(bsdf, material, rtol):
    """The plugin's eval against Material.lobe · |cos θo| about the lobe (550 nm)."""
    from bsdf_checks import assert_eval_matches
    wi = np.array([np.sin(0.3), 0.0, np.cos(0.3)])
    d = material.sample(np.random.default_rng(0).random((2000, 2)), 550.0)
    wo_xy = d - wi[:2]
    keep = np.hypot(wo_xy[:, 0], wo_xy[:, 1]) < 0.99
    wo_xy, d = wo_xy[keep], d[keep]
    wo = np.column_stack([wo_xy, -np.sqrt(1 - (wo_xy**2).sum(1))])
    exact = lambda wi_, wo_, lam: material.lobe((wo_ + wi_)[:, :2], lam) * np.abs(wo_[:, 2])
    assert_eval_matches(bsdf, exact, wi, wo, (550.0,) * 4, rtol=rtol, atol=1e-4)


def test_a_users_family_reaches_the_plugin_by_name_and_as_an_instance(mi_variant, restored_registry):
    import mitsuba as mi
    wobble = Parameter("wobble", "float", "", 0.1, "blob: wobble", low=0.0, high=0.5)
    corona.register_shape("blob", _Blob, ["radius", wobble])
    given = {"shape": "blob", "radius": 2.0, "wobble": 0.3, "process": "poisson", "area_fraction": 0.2}
    # against the model built without the registry: the plugin reads the family's own parameter
    _plugin_vs_model(mi.load_dict({"type": "corona", **given}), corona.Material(_Blob(2.0, 0.3), corona.Poisson(0.2)),
                     rtol=2e-3)
    with pytest.raises(Exception, match=r"CoronaError: wobble=0.9 is out of range; allowed \[0, 0.5\]"):
        mi.load_dict({"type": "corona", **given, "wobble": 0.9})     # (Mitsuba wraps it, the line stays)
    # an instance of a class registered nowhere (corona.scatterer: Mitsuba's properties hold its types only)
    blob = _Blob(1.5, 0.2)
    bsdf = mi.load_dict({"type": "corona", "shape": corona.scatterer(blob), "process": "poisson",
                         "area_fraction": 0.2})
    _plugin_vs_model(bsdf, corona.Material(blob, corona.Poisson(0.2)), rtol=2e-3)
    _one_line_error(lambda: corona.scatterer("circle"), "'circle' is neither a corona.Shape nor a corona.Process")


class _Softened(corona.HardDisk):
    """Hard disks whose correlations are weakened: ``S = 1 + (1 - softness) (S_hd - 1)``."""

    def __init__(self, area_fraction, softness=0.5):
        super().__init__(area_fraction)
        self.softness = softness

    def structure_factor_radial(self, q_abs, shape):
        return 1.0 + (1.0 - self.softness) * (super().structure_factor_radial(q_abs, shape) - 1.0)

    def structure_factor_at(self, q, shape):
        q = np.asarray(q, dtype=np.float64)
        return self.structure_factor_radial(np.hypot(q[..., 0], q[..., 1]), shape)

    def with_area_fraction(self, area_fraction):
        return _Softened(area_fraction, self.softness)


def test_a_users_process_reaches_the_plugin_by_name_and_as_an_instance(mi_variant, restored_registry):
    """A process of the user's (a subclass with its own S) through mi.load_dict: by a registered
    name with its own checked parameter, and as an instance (corona.scatterer), registered or not;
    each against Material.lobe of the same layer built without the plugin or the registry."""
    import mitsuba as mi
    softness = Parameter("softness", "float", "", 0.5, "softened: 1 - the hard-disk correlation kept",
                         low=0.0, high=1.0)
    corona.register_process("softened", _Softened, ["area_fraction", softness])
    reference = corona.Material(corona.Circle(3.0), _Softened(0.35, 0.3))
    by_name = mi.load_dict({"type": "corona", "shape": "circle", "radius": 3.0, "process": "softened",
                            "area_fraction": 0.35, "softness": 0.3})
    _plugin_vs_model(by_name, reference, rtol=2e-3)
    # negative control: the plain hard disks' lobe (softness 0) is not what the plugin evaluates
    with pytest.raises(AssertionError, match="reference"):
        _plugin_vs_model(by_name, corona.Material(corona.Circle(3.0), corona.HardDisk(0.35)), rtol=2e-3)
    with pytest.raises(Exception, match=r"CoronaError: softness=1.5 is out of range; allowed \[0, 1\]"):
        mi.load_dict({"type": "corona", "process": "softened", "softness": 1.5})
    # instances: the user's (isotropic and with an anisotropic shape instance), complete as given
    instance = mi.load_dict({"type": "corona", "shape": "circle", "radius": 3.0,
                             "process": corona.scatterer(_Softened(0.35, 0.3))})
    _plugin_vs_model(instance, reference, rtol=2e-3)
    # its area fraction and lengths are its own: neither is a parameter of the scene
    assert not {"radius.value", "area_fraction.value"} & set(mi.traverse(instance).keys())
    import warnings
    with warnings.catch_warnings():        # its description warns of no unused area_fraction
        warnings.simplefilter("error", corona.CoronaWarning)
        assert "Circle(radius=3)" in str(instance)
    ellipse = corona.Ellipse(3.0, aspect=0.5)
    both = mi.load_dict({"type": "corona", "shape": corona.scatterer(ellipse),
                         "process": corona.scatterer(_Softened(0.3, 0.6))})
    _plugin_vs_model(both, corona.Material(ellipse, _Softened(0.3, 0.6)), rtol=2e-3)
    # a given area_fraction is the instance's own, not the plugin's: unused, one warning
    with pytest.warns(corona.CoronaWarning, match="area_fraction"):
        bsdf = mi.load_dict({"type": "corona", "shape": "circle", "radius": 3.0, "area_fraction": 0.1,
                             "process": corona.scatterer(_Softened(0.35, 0.3))})
    _plugin_vs_model(bsdf, reference, rtol=2e-3)


@pytest.mark.slow
def test_a_built_in_process_instance_is_the_named_process(mi_variant):
    """An instance of a built-in process evaluates as the same process by name, for the flat layer
    (a mixture and an aperture too) and the Mie sphere (the lattice of spheres too: its own code path)."""
    import mitsuba as mi
    from bsdf_checks import plugin_eval
    wi = np.array([np.sin(0.3), 0.0, np.cos(0.3)])
    wo_xy = -wi[:2] + np.random.default_rng(0).uniform(-0.3, 0.3, (200, 2))
    wo = np.column_stack([wo_xy, -np.sqrt(1 - (wo_xy**2).sum(1))])
    for given in ({"shape": "circle", "radius": 2.0, "process": "lattice-hex", "area_fraction": 0.3},
                  {"shape": "mixture", "mixture": "circle:3:1, square:2:1", "process": "hard-disk", "area_fraction": 0.3},
                  {"shape": "circle", "radius": 3.0, "mode": "aperture", "process": "rsa", "area_fraction": 0.3},
                  {"shape": "sphere", "radius": 2.0, "process": "hard-disk", "area_fraction": 0.3},
                  {"shape": "sphere", "radius": 2.0, "process": "lattice-hex", "area_fraction": 0.3}):
        process = material_from_parameters(**given).process
        named = plugin_eval(mi.load_dict({"type": "corona", **given}), wi, wo)[0]
        rest = {k: v for k, v in given.items() if k not in ("process", "area_fraction")}
        held = plugin_eval(mi.load_dict({"type": "corona", **rest, "process": corona.scatterer(process)}), wi, wo)[0]
        assert np.max(named) > 0 and np.allclose(held, named, rtol=1e-6, atol=1e-6 * np.max(named)), given


def test_a_bad_process_for_the_plugin_is_one_clear_error(mi_variant, restored_registry):
    import mitsuba as mi
    from corona._validation import one_line_error

    def refused(props, *words):
        with pytest.raises(Exception) as err:
            mi.load_dict({"type": "corona", **props})
        text = one_line_error(err.value)
        assert "CoronaError" in str(err.value) and all(w in text for w in words), text
    refused({"process": corona.scatterer(corona.Circle(1.0))}, "process=corona.scatterer(Circle(radius=1))",
            "allowed a registered process name", "hard-disk", "corona.Process instance")
    refused({"shape": corona.scatterer(corona.HardDisk(0.3))}, "shape=corona.scatterer(HardDisk(area_fraction=0.3))",
            "corona.Shape instance")
    refused({"process": mi.load_dict({"type": "uniform", "value": 0.3})}, "process=a Texture", "allowed")
    refused({"process": "softened"}, "process='softened'", "poisson")
    refused({"shape": "circle", "radius": {"type": "checkerboard"}, "process": corona.scatterer(corona.HardDisk(0.3))},
            "radius cannot be a texture", "a process instance")
    _one_line_error(lambda: corona.scatterer(3), "3 is neither a corona.Shape nor a corona.Process")

    class Inherits(corona.HardDisk):          # S of its own, but the parent's with_area_fraction
        def structure_factor_radial(self, q_abs, shape):
            return np.ones_like(np.asarray(q_abs, dtype=np.float64))
    _one_line_error(lambda: corona.register_process("inherits", Inherits), "inherits with_area_fraction from HardDisk",
                    "define Inherits.with_area_fraction")
    assert "inherits" not in registry.PROCESS_FAMILIES


_TWEAK = '''
import numpy as np, corona

class Tweak(corona.HardDisk):
    def structure_factor_radial(self, q_abs, shape):
        return 1.0 + FACTOR * (super().structure_factor_radial(q_abs, shape) - 1.0)

    def structure_factor_at(self, q, shape):
        q = np.asarray(q, dtype=np.float64)
        return self.structure_factor_radial(np.hypot(q[..., 0], q[..., 1]), shape)
'''


def test_an_edited_user_class_is_not_served_its_old_table(mi_variant):
    """A user's class of the same module, name and attributes whose code changed between two
    loads (an edit between runs) gets a table of its own: the plugin evaluates the new one."""
    import mitsuba as mi
    from corona.model import tabulated
    classes = []
    for factor in ("0.2", "0.9"):
        ns = {"__name__": "users_module"}
        exec(compile(_TWEAK.replace("FACTOR", factor), "users_module.py", "exec"), ns)
        classes.append(ns["Tweak"])
    first, second = classes[0](0.35), classes[1](0.35)
    assert first.key() == second.key()        # the same name and attributes: only the code differs
    assert tabulated.identity(first) != tabulated.identity(second)
    assert tabulated.identity(corona.HardDisk(0.35)) == corona.HardDisk(0.35).key()   # built-ins as before
    for process in (first, second):
        bsdf = mi.load_dict({"type": "corona", "shape": "circle", "radius": 3.0,
                             "process": corona.scatterer(process)})
        _plugin_vs_model(bsdf, corona.Material(corona.Circle(3.0), process), rtol=2e-3)
