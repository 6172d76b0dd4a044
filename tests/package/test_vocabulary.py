"""One vocabulary: the same number means the same scatterer in Python and in the plugin.

The size every shape class takes first is the plugin's flat ``radius`` (circle radius,
ellipse semi-axis x, square and rectangle half-width, polygon circumradius) and angles are
degrees in both.  The previous release's spellings were removed in 0.2.0.
"""
import math
import warnings

import numpy as np
import pytest

import corona
from corona.parameters import material_from_parameters

from bsdf_checks import assert_eval_matches, transmitted_lobe

#: (Python shape, the plugin's flat parameters for the same scatterer)
PAIRS = {
    "circle": (lambda: corona.Circle(2.0), {"shape": "circle", "radius": 2.0}),
    "ellipse": (lambda: corona.Ellipse(2.0, aspect=0.5, angle=30.0),
                {"shape": "ellipse", "radius": 2.0, "aspect": 0.5, "angle": 30}),
    "square": (lambda: corona.Square(2.0, angle=30.0), {"shape": "square", "radius": 2.0, "angle": 30}),
    "rectangle": (lambda: corona.Rectangle(2.0, aspect=0.6, angle=-25.0),
                  {"shape": "rectangle", "radius": 2.0, "aspect": 0.6, "angle": -25}),
    "polygon": (lambda: corona.RegularPolygon(5, 2.0, angle=12.0),
                {"shape": "polygon", "radius": 2.0, "sides": 5, "angle": 12}),
    "mixture": (lambda: corona.Mixture([(corona.Square(2.0, angle=30.0), 1.0), (corona.Circle(1.5), 1.0)]),
                {"shape": "mixture", "mixture": "square:2:1, circle:1.5:1", "angle": 30}),
}

D = np.array([[0.0, 0.0], [0.03, 0.01], [-0.02, 0.05], [0.08, -0.06], [0.15, 0.11]])


@pytest.mark.parametrize("name", sorted(PAIRS))
def test_python_shape_is_the_plugin_parameters_shape(name):
    make, params = PAIRS[name]
    process = corona.Poisson(0.2)
    with warnings.catch_warnings():
        warnings.simplefilter("error", DeprecationWarning)   # the new spelling never warns
        py = corona.Material(make(), process)
    flat = material_from_parameters(**params, process="poisson", area_fraction=0.2)
    assert flat.shape.key() == py.shape.key()
    assert repr(flat.shape) == repr(py.shape)
    for lam in (450.0, 600.0):
        np.testing.assert_array_equal(flat.lobe(D, lam), py.lobe(D, lam))


def test_the_readme_sizes():
    """radius: the circumscribing length the README's parameter table names, per shape."""
    assert corona.Square(2.0).area == pytest.approx(16.0)                       # side 4
    assert corona.Square(2.0).length_scale == pytest.approx(2.0 * math.sqrt(2.0))
    assert corona.Rectangle(2.0, aspect=0.5).area == pytest.approx(4.0 * 2.0)
    assert corona.Ellipse(2.0, aspect=0.5).area == pytest.approx(math.pi * 2.0 * 1.0)
    assert corona.RegularPolygon(6, 2.0).length_scale == pytest.approx(2.0)


def test_angles_are_degrees():
    q = np.array([[1.3, 0.2], [0.4, -0.9]])
    # a square is symmetric under 90°, not under 90 rad
    np.testing.assert_allclose(corona.Square(1.0, angle=90.0).form_factor(q),
                               corona.Square(1.0).form_factor(q), rtol=1e-12)
    assert not np.allclose(corona.Square(1.0, angle=30.0).form_factor(q), corona.Square(1.0).form_factor(q))
    lat = corona.Lattice("square", 2.0, angle=90.0)                  # counter-clockwise
    np.testing.assert_allclose(lat.lattice_vectors, [[0.0, 2.0], [-2.0, 0.0]], atol=1e-12)


#: 0.1.0's spellings (full lengths or semi-axes, radians, positionally or by the old keywords),
#: removed in 0.2.0: each is a TypeError now, not a shape built under another reading
OLD = [
    lambda: corona.Square(side=2.0, angle=0.5),
    lambda: corona.Square(2.0, 0.5),
    lambda: corona.Rectangle(2.0, 1.0, 0.3),
    lambda: corona.Rectangle(width=2.0, height=1.0),
    lambda: corona.Ellipse(2.0, 1.0, 0.3),
    lambda: corona.Ellipse(semi_axis_x=2.0, semi_axis_y=1.0),
    lambda: corona.RegularPolygon(5, 2.0, 0.3),
]


@pytest.mark.parametrize("old", OLD, ids=range(len(OLD)))
def test_old_spellings_are_gone(old):
    with pytest.raises(TypeError):
        old()


@pytest.mark.parametrize("name", ["square", "ellipse"])
def test_plugin_eval_matches_the_python_material(mi_variant, name):
    """The plugin loaded from the flat parameters evaluates the Python class's lobe."""
    import mitsuba as mi
    make, params = PAIRS[name]
    m = corona.Material(make(), corona.HardDisk(0.3))
    bsdf = mi.load_dict({"type": "corona", **params, "process": "hard-disk", "area_fraction": 0.3})
    wi = np.array([0.0, 0.0, 1.0])
    lams = (450.0, 520.0, 600.0, 700.0)
    # offsets across the lobe's anisotropic core, where a rotation or a factor 2 in size shows
    R = m.length_scale
    u = np.array([[1.0, 0.3], [0.4, 1.6], [-2.1, 0.7], [2.8, -1.9], [0.2, -3.3]])
    d = u * 0.55 / (2 * np.pi * R)
    wo = np.concatenate([d - wi[:2], -np.sqrt(1 - np.sum((d - wi[:2]) ** 2, 1))[:, None]], 1)
    _, refs, _ = assert_eval_matches(bsdf, transmitted_lobe(m), wi, wo, lams, rtol=2e-3, atol=1e-4)
    for ref, lam in zip(refs, lams):
        # negative control: the previous release's reading (side 2 µm, 30 rad) is another lobe
        old_shape = {"square": lambda: corona.Square(1.0, angle=math.degrees(30.0)),
                     "ellipse": lambda: corona.Ellipse(2.0, aspect=0.5, angle=math.degrees(30.0))}[name]()
        other = corona.Material(old_shape, corona.HardDisk(0.3)).lobe(d, lam) * np.abs(wo[:, 2])
        assert np.max(np.abs(other - ref)) > 0.1 * ref.max()
