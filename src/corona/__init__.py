"""corona — a wave-optics BSDF for layers of correlated scatterers.

The model (docs/physics.md#the-model): the diffraction lobe of a layer is
``F_a · T_a(d) · T_s(d)`` with ``T_a`` the normalised form factor of one
scatterer and ``T_s`` the structure factor of their positions.

Data flows one way: :mod:`corona.model.shapes` + :mod:`corona.model.processes` →
:class:`corona.Material` → :mod:`corona.model.tabulated` → the Mitsuba plugin
(:mod:`corona.mitsuba.bsdf`) → the applications (:mod:`corona.apps`).  The reference
tier (:mod:`corona.reference`: simulations, brute force, validation) needs
the ``reference`` extra and is never imported from here.

Importing ``corona`` (or any ``corona.model`` module) imports the model only: the
applications' names here (:func:`fit_photograph`, :func:`from_micrograph`) are
loaded on first use (PEP 562), and the plugin by :func:`register`.
"""
# _environment must come first: when DRJIT_LIBLLVM_PATH is unset it points it at
# a libLLVM >= 16 before Dr.Jit loads (a user's own setting is left alone)
from corona import _environment  # noqa: F401
from corona._environment import default_variant, set_default_variant
from corona._validation import CoronaError, CoronaWarning
from corona.model.material import Material
from corona.model.mie import material as _mie_material  # noqa: F401  (the sphere family: Material(corona.Sphere(r)) builds its layer)
from corona.model.registry import register_process, register_shape
from corona.model.processes import BreathFigure, HardDisk, Lattice, PointSet, Poisson, Process, SequentialAdsorption
from corona.model.shapes import (Circle, Ellipse, Mask, Mixture, Polygon, RandomOrientation, Rectangle,
                     RegularPolygon, Shape, SizeDistribution, SoftEdge, Sphere, Square)
from corona.model.substrate import GlassPane, Mirror

__version__ = "0.2.0"

#: Names of the applications tier, imported on first use (PEP 562): ``import corona`` stays the model.
_LAZY = ("fit_photograph", "from_micrograph")


def __getattr__(name: str):
    if name == "fit_photograph":
        from corona.apps.fit import fit_photograph as value
    elif name == "from_micrograph":
        from corona.apps.micrograph import from_micrograph as value
    else:
        raise AttributeError(f"module 'corona' has no attribute {name!r}")
    globals()[name] = value           # later look-ups skip this function
    return value


def __dir__():
    return sorted(set(globals()) | set(_LAZY))

__all__ = ["CoronaError", "CoronaWarning",
           "Shape", "Circle", "Ellipse", "Rectangle", "Square", "Polygon", "RegularPolygon", "Mask",
           "SoftEdge", "RandomOrientation", "SizeDistribution", "Mixture", "Sphere",
           "Process", "Poisson", "SequentialAdsorption", "Lattice", "PointSet", "HardDisk", "BreathFigure",
           "Material", "GlassPane", "Mirror", "from_micrograph", "fit_photograph", "default_variant",
           "set_default_variant", "register", "register_shape", "register_process", "scatterer"]


def scatterer(value):
    """``value`` (a :class:`corona.Shape` or :class:`corona.Process` instance, a user's subclass
    too) as the value of the plugin's ``shape`` or ``process`` property:
    ``mi.load_dict({'type': 'corona', 'shape': corona.scatterer(s), 'process': corona.scatterer(p)})``
    (:func:`corona.mitsuba.common.scatterer`; docs/adding_a_scatterer.md)."""
    from corona.mitsuba.common import scatterer as _scatterer
    return _scatterer(value)


def register() -> None:
    """Register the ``corona`` BSDF plugin for the active Mitsuba variant (idempotent).

    Examples
    --------
    Load the plugin in a spectral variant and evaluate it 0.01 rad off the
    direction opposite to ``wi`` (exactly there lives the coherent beam, a
    delta component, and ``eval`` is 0): ``eval`` is the lobe at
    ``d = (wo + wi).xy`` times ``|cos θo|`` (up to the table's float32
    rounding and its linear interpolation in u):

    >>> import mitsuba as mi, corona
    >>> mi.set_variant("scalar_spectral")
    >>> corona.register()
    >>> bsdf = mi.load_dict({"type": "corona", "radius": 5.0, "area_fraction": 0.3})
    >>> si = mi.SurfaceInteraction3f()
    >>> si.wi = mi.Vector3f(0.0, 0.0, 1.0)
    >>> si.wavelengths = mi.Spectrum(550.0, 550.0, 550.0, 550.0)
    >>> cos_o = (1 - 0.01**2) ** 0.5
    >>> value = bsdf.eval(mi.BSDFContext(), si, mi.Vector3f(0.01, 0.0, -cos_o))
    >>> from corona.parameters import material_from_parameters
    >>> f = material_from_parameters(radius=5.0, area_fraction=0.3).lobe([[0.01, 0.0]], 550.0)[0]
    >>> round(float(value[0] / (f * cos_o)), 3)
    1.0
    """
    from corona.mitsuba.bsdf import register as _register
    _register()
    from corona.mitsuba.phase import register as _register_phase   # the corona_mie phase function
    _register_phase()
