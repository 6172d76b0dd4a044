"""corona — a wave-optics BSDF for layers of correlated scatterers.

The model (DESIGN §3): the diffraction lobe of a layer is
``F_a · T_a(d) · T_s(d)`` with ``T_a`` the normalised form factor of one
scatterer and ``T_s`` the structure factor of their positions.
"""
from . import _environment  # noqa: F401  (must come first: sets DRJIT_LIBLLVM_PATH)
from ._environment import default_variant, set_default_variant
from ._validation import CoronaError, CoronaWarning
from .shapes import (Shape, Circle, Ellipse, Rectangle, Square, Polygon, RegularPolygon, Mask,
                     SoftEdge, RandomOrientation, SizeDistribution, Mixture)
from .processes import Process, Poisson, SequentialAdsorption, Lattice, PointSet
from .material import Material
from .micrograph import from_micrograph

__version__ = "0.1.0"

__all__ = ["CoronaError", "CoronaWarning",
           "Shape", "Circle", "Ellipse", "Rectangle", "Square", "Polygon", "RegularPolygon", "Mask",
           "SoftEdge", "RandomOrientation", "SizeDistribution", "Mixture",
           "Process", "Poisson", "SequentialAdsorption", "Lattice", "PointSet", "HardDisk",
           "Material", "from_micrograph", "default_variant", "set_default_variant", "register"]


def __getattr__(name):
    # HardDisk loads its shipped table lazily; import on first use
    if name == "HardDisk":
        from .hard_disk import HardDisk
        return HardDisk
    raise AttributeError(f"module 'corona' has no attribute {name!r}")


def register() -> None:
    """Register the ``corona`` BSDF plugin for the active Mitsuba variant (idempotent)."""
    from .mitsuba_bsdf import register as _register
    _register()
