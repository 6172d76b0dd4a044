"""Form factors of single scatterers (docs/physics.md#the-model).

Every shape is a transmission profile ``A(x)`` in the layer plane, lengths in
micrometres; :class:`Shape` documents the interface (``area``,
``length_scale``, ``amplitude``, ``form_factor``, ``coherent_form_factor``).

* :mod:`corona.model.shapes.analytic`: :class:`Circle`, :class:`Ellipse`,
  :class:`Rectangle`, :class:`Square` (closed-form transforms);
* :mod:`corona.model.shapes.polygon`: :class:`Polygon`, :class:`RegularPolygon`
  (edge sum);
* :mod:`corona.model.shapes.mask`: :class:`Mask` (any image, FFT);
* :mod:`corona.model.shapes.modifiers`: :class:`SoftEdge`,
  :class:`RandomOrientation`, :class:`SizeDistribution` (on the shared
  :class:`Modifier` base) and :class:`Mixture`.

The size every class takes first is the plugin's flat ``radius`` [µm] (circle
radius, ellipse semi-axis x, square and rectangle half-width, regular-polygon
circumradius), the second extent the plugin's ``aspect``, and angles are
degrees as in the plugin: ``Square(2.0, angle=30.0)`` is the plugin's
``{"shape": "square", "radius": 2.0, "angle": 30}``.
"""
import importlib
import pkgutil

# in the order of the families' registration (corona.model.registry), the order of the spec's list
from corona.model.shapes.analytic import Circle, Ellipse, Rectangle, Square
from corona.model.shapes.base import Shape
from corona.model.shapes.polygon import Polygon, RegularPolygon
from corona.model.shapes.mask import Mask
from corona.model.shapes.modifiers import Mixture, Modifier, RandomOrientation, SizeDistribution, SoftEdge
from corona.model.mie.sphere import Sphere

# every other module of this package is a shape family that registers itself (a new shape is
# one file here: docs/adding_a_scatterer.md)
for _module in pkgutil.iter_modules(__path__):
    importlib.import_module(f"{__name__}.{_module.name}")
del _module

__all__ = ["Shape", "Circle", "Ellipse", "Rectangle", "Square", "Polygon", "RegularPolygon",
           "Mask", "Modifier", "SoftEdge", "RandomOrientation", "SizeDistribution", "Mixture",
           "Sphere"]
