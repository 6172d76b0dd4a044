"""corona — a wave-optics BSDF for layers of correlated scatterers.

The model (docs/physics.md#the-model): the diffraction lobe of a layer is
``F_a · T_a(d) · T_s(d)`` with ``T_a`` the normalised form factor of one
scatterer and ``T_s`` the structure factor of their positions.

Data flows one way: :mod:`corona.shapes` + :mod:`corona.processes` →
:class:`corona.Material` → :mod:`corona.tables` → the Mitsuba plugin
(:mod:`corona.mitsuba_bsdf`) → the CLI (:mod:`corona.cli`).  The reference
tier (:mod:`corona.reference`: simulations, brute force, validation) needs
the ``reference`` extra and is never imported from here.
"""
# _environment must come first: when DRJIT_LIBLLVM_PATH is unset it points it at
# a libLLVM >= 16 before Dr.Jit loads (a user's own setting is left alone)
from . import _environment  # noqa: F401
from ._environment import default_variant, set_default_variant
from ._validation import CoronaError, CoronaWarning
from .fit import fit_photograph
from .material import Material
from .micrograph import from_micrograph
from .processes import HardDisk, Lattice, PointSet, Poisson, Process, SequentialAdsorption
from .shapes import (Circle, Ellipse, Mask, Mixture, Polygon, RandomOrientation, Rectangle,
                     RegularPolygon, Shape, SizeDistribution, SoftEdge, Square)

__version__ = "0.1.0"

__all__ = ["CoronaError", "CoronaWarning",
           "Shape", "Circle", "Ellipse", "Rectangle", "Square", "Polygon", "RegularPolygon", "Mask",
           "SoftEdge", "RandomOrientation", "SizeDistribution", "Mixture",
           "Process", "Poisson", "SequentialAdsorption", "Lattice", "PointSet", "HardDisk",
           "Material", "from_micrograph", "fit_photograph", "default_variant", "set_default_variant", "register"]


def register() -> None:
    """Register the ``corona`` BSDF plugin for the active Mitsuba variant (idempotent)."""
    from .mitsuba_bsdf import register as _register
    _register()
