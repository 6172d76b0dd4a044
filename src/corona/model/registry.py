"""The one registry of scatterer families: every shape and every process, by name.

Each family registers itself once, where it is defined (``corona.model.shapes.*``,
``corona.model.processes.*``, ``corona.model.mie.sphere``), with

* its ``name`` (the value of the ``shape`` / ``process`` parameter in XML, ``load_dict``,
  Python and on the command line);
* the ``parameters`` it reads (names of :data:`corona.parameters.PARAMETERS`, or new
  :class:`corona.parameters.Parameter` objects a user's family brings): a parameter's
  ``applies`` conditions ``shape=<name>`` / ``process=<name>`` are derived from these lists;
* its ``factory``: the :class:`~corona.Shape` (or :class:`~corona.Process`) built from the
  checked parameters (a dict holding every parameter; the family's own ones checked);
* where it has one, its closed-form kernel term (the shape's ``kernel_terms()``) and its
  rasteriser for the brute-force reference (the shape's ``signed_distance()``): methods of
  the class, found there by :mod:`corona.model.render_lobe` and :mod:`corona.reference.wave`.

Everything that lists families reads this registry: the spec (:data:`corona.parameters.SHAPES`
and the ``applies`` of each parameter), the plugin, the CLI's choices, the fitter's check, the
brute-force reference and the docs' parameter tables.  A user's family is registered the same
way (:func:`register_shape`, :func:`register_process`; ``corona.register_shape``) and reaches
the plugin by name with its own, checked parameters (docs/adding_a_scatterer.md).
"""
from __future__ import annotations

import inspect
import re
from dataclasses import dataclass, field
from typing import Callable

from corona._validation import CoronaError

#: Parameters every flat (Fraunhofer) shape reads: the soft edge and the opaque part's albedo.
FLAT = ("edge_width", "albedo")
#: Parameters a shape that is not isotropic reads as well (a random orientation).
ROTATABLE = ("orientation",)

_NAME = re.compile(r"^[a-z][a-z0-9_-]*$")


@dataclass(frozen=True)
class ShapeFamily:
    """One shape family (see the module docstring).

    Attributes
    ----------
    name : str
        The value of ``shape``.
    factory : callable
        ``factory(p) -> Shape`` from the parameters ``p`` (a dict; the family's own checked).
    parameters : tuple of str
        The names of the parameters it reads (``radius``, ``aspect``, ...).
    new_parameters : tuple of Parameter
        Parameters it brings that the spec does not hold yet (a user's family).
    cls : type or None
        Its :class:`~corona.Shape` class (None for composite families such as ``mixture``).
    mixable : bool
        A component of ``shape=mixture`` (``factory`` with the component's ``radius``).
    bsdf : str
        ``"module:function"`` returning the plugin class when the family has its own
        (the Mie sphere), else "".
    material : callable or None
        ``material(shape, process, p, given, substrate) -> Material`` when the layer is not a
        plain :class:`~corona.Material` (the Mie sphere), else None.
    layer : type or None
        The layer class ``corona.Material(shape, ...)`` builds for a shape of this family (or a
        shape holding one) when it is not the flat :class:`~corona.Material`: the Mie sphere's
        :class:`~corona.model.mie.material.SphereMaterial`, a :class:`~corona.model.material.Layer`.
    of_components : bool
        It holds mixable shapes (``mixture``) and reads their parameters too (but ``radius``).
    """

    name: str
    factory: Callable
    parameters: tuple = ()
    new_parameters: tuple = ()
    cls: type | None = None
    mixable: bool = False
    bsdf: str = ""
    material: Callable | None = None
    of_components: bool = False
    layer: type | None = None


@dataclass(frozen=True)
class ProcessFamily:
    """One point-process family.

    Attributes
    ----------
    name : str
        The value of ``process``.
    factory : callable
        ``factory(p, shape) -> Process`` from the parameters ``p`` (the family's own checked).
    parameters : tuple of str
        The names of the parameters it reads.
    new_parameters : tuple of Parameter
        Parameters it brings that the spec does not hold yet.
    cls : type or None
        Its :class:`~corona.Process` class.
    absolute : bool
        Its positions are absolute (a point file): they do not scale with ``radius``.
    """

    name: str
    factory: Callable
    parameters: tuple = ()
    new_parameters: tuple = ()
    cls: type | None = None
    absolute: bool = False


SHAPE_FAMILIES: dict[str, ShapeFamily] = {}
PROCESS_FAMILIES: dict[str, ProcessFamily] = {}
#: Called with the new family after each registration (the spec keeps its tables in step).
_LISTENERS: list[Callable] = []


def listen(callback: Callable) -> None:
    """Call ``callback(family)`` after every later registration."""
    _LISTENERS.append(callback)


def _check_name(kind: str, name, table: dict, allow_replace: bool = False) -> str:
    if not isinstance(name, str) or not _NAME.match(name):
        raise CoronaError(f"register_{kind}: name={name!r} is not a valid {kind} name; allowed lower-case "
                          "letters, digits, '-' and '_', starting with a letter")
    if name in table and not allow_replace:
        raise CoronaError(f"register_{kind}: name={name!r} is taken by {table[name].cls or table[name].factory!r}; "
                          f"registered {kind}s: {', '.join(table)}")
    return name


def _split_parameters(kind: str, name: str, parameters) -> tuple[tuple, tuple]:
    """(names, new Parameter objects) of a family's ``parameters`` (names or Parameter objects)."""
    if isinstance(parameters, str):
        parameters = (parameters,)
    names, new = [], []
    for p in parameters:
        if isinstance(p, str):
            names.append(p)
        elif all(hasattr(p, a) for a in ("name", "kind", "default", "check", "applies")):
            names.append(p.name)
            new.append(p)
        elif isinstance(p, dict) and isinstance(p.get("name"), str):   # Parameter's fields
            names.append(p["name"])
            new.append(p)
        else:
            raise CoronaError(f"register_{kind}({name!r}): parameter {p!r} is neither a parameter name nor a "
                              "corona.parameters.Parameter (nor a dict of its fields)")
    return tuple(dict.fromkeys(names)), tuple(new)


def _notify(family) -> None:
    for callback in _LISTENERS:
        callback(family)


def _add(kind: str, table: dict, family):
    """Register ``family`` in ``table`` and tell the spec; a refusal leaves nothing registered."""
    _check_name(kind, family.name, table)
    table[family.name] = family
    try:
        _notify(family)
    except Exception:         # refused by the spec (a clashing parameter): nothing of it stays
        del table[family.name]
        raise
    return family


def add_shape(family: ShapeFamily) -> ShapeFamily:
    """Register a built-in shape family (its module calls this once, at import)."""
    return _add("shape", SHAPE_FAMILIES, family)


def add_process(family: ProcessFamily) -> ProcessFamily:
    """Register a built-in process family (its module calls this once, at import)."""
    return _add("process", PROCESS_FAMILIES, family)


def _class_factory(kind: str, name: str, cls, names: tuple, with_shape: bool = False) -> Callable:
    """``cls(**{n: p[n] for n in names})`` (the class takes the parameters by their names)."""
    try:
        sig = inspect.signature(cls)
    except (TypeError, ValueError):
        sig = None
    if sig is not None:
        takes_any = any(q.kind is inspect.Parameter.VAR_KEYWORD for q in sig.parameters.values())
        missing = [n for n in names if n not in sig.parameters and not takes_any]
        if missing:
            raise CoronaError(f"register_{kind}({name!r}, {cls.__name__}): {cls.__name__}() takes no "
                              f"parameter(s) {', '.join(missing)}; give factory=... or parameters it takes "
                              f"({', '.join(q for q in sig.parameters if q != 'self')})")

    def factory(p, *shape):
        return cls(**{n: p[n] for n in names if p.get(n) is not None})
    return factory


def register_shape(name: str, cls, parameters=(), *, factory: Callable | None = None,
                   mixable: bool = False) -> ShapeFamily:
    """Make a :class:`~corona.Shape` class a shape family: ``shape=name`` everywhere.

    Parameters
    ----------
    name : str
        The new value of ``shape`` (lower-case letters, digits, ``-``, ``_``; not taken).
    cls : type
        A subclass of :class:`corona.Shape` implementing the numpy form factor (``area``,
        ``length_scale``, ``amplitude``; ``isotropic = True`` when it is).  The plugin tabulates
        it as it tabulates a mask (it has no kernel term unless it defines ``kernel_terms``).
    parameters : sequence of str or Parameter
        What ``cls`` takes, by the spec's names (``"radius"``) or as new
        :class:`corona.parameters.Parameter` objects (their name, unit, default and range:
        every value given is checked with the usual one-line error).  The soft edge
        (``edge_width``), ``albedo``, ``size_spread`` and, for an anisotropic class,
        ``orientation`` come with every flat shape.
    factory : callable, optional
        ``factory(p) -> Shape`` from the parameters; default ``cls(**{name: p[name]})``.
    mixable : bool
        Allowed as a component of ``shape=mixture`` (then it must read ``radius``).

    Examples
    --------
    A ring with a parameter of its own (docs/adding_a_scatterer.md shows it whole)::

        corona.register_shape("ring", Ring, ["radius", Parameter("hole", "float", "", 0.5,
                              "ring: inner radius over radius", low=0.0, high=0.9)])
        mi.load_dict({"type": "corona", "shape": "ring", "radius": 4.0, "hole": 0.6})

    A name is registered once: a second ``register_shape("ring", ...)`` (or a built-in's name)
    is one :class:`~corona.CoronaError` naming the family that holds it.
    """
    from corona.model.shapes.base import Shape
    _check_name("shape", name, SHAPE_FAMILIES)
    if not (isinstance(cls, type) and issubclass(cls, Shape)):
        raise CoronaError(f"register_shape({name!r}, {cls!r}): not a corona.Shape subclass; a shape family "
                          "is a class deriving from corona.Shape that implements area, length_scale and "
                          "amplitude (the numpy form factor)")
    missing = [m for m in ("area", "length_scale", "amplitude") if getattr(cls, m) is getattr(Shape, m)]
    if missing:
        raise CoronaError(f"register_shape({name!r}, {cls.__name__}): {cls.__name__} does not implement "
                          f"{', '.join(missing)} (the numpy form factor needs them)")
    names, new = _split_parameters("shape", name, parameters)
    if mixable and "radius" not in names:
        raise CoronaError(f"register_shape({name!r}): mixable=True needs the parameter 'radius' (a mixture "
                          "gives each component its radius)")
    if factory is None:
        factory = _class_factory("shape", name, cls, names)
    uses = names + FLAT + (() if getattr(cls, "isotropic", False) else ROTATABLE)
    return add_shape(ShapeFamily(name, factory, tuple(dict.fromkeys(uses)), new, cls, mixable=mixable))


def register_process(name: str, cls, parameters=("area_fraction",), *, factory: Callable | None = None,
                     absolute: bool = False) -> ProcessFamily:
    """Make a :class:`~corona.Process` class a process family: ``process=name`` everywhere.

    ``parameters`` as in :func:`register_shape` (default: the area fraction alone);
    ``factory(p, shape) -> Process`` defaults to ``cls(**{name: p[name]})``.  A class whose
    ``S`` the area fraction moves (``varying_area_fraction = True``: the plugin builds rows over
    F_a, textures and differentiates it) defines its own ``with_area_fraction``.
    """
    from corona.model.processes.base import Process
    _check_name("process", name, PROCESS_FAMILIES)
    if not (isinstance(cls, type) and issubclass(cls, Process)):
        raise CoronaError(f"register_process({name!r}, {cls!r}): not a corona.Process subclass; a process "
                          "family is a class deriving from corona.Process (structure_factor_at, "
                          "area_fraction, isotropic)")
    if cls.varying_area_fraction and "with_area_fraction" not in vars(cls):
        # the plugin builds rows over F_a with it: an inherited one makes the parent's process
        owner = next(c for c in cls.__mro__ if "with_area_fraction" in vars(c))
        raise CoronaError(f"register_process({name!r}, {cls.__name__}): {cls.__name__} has varying_area_fraction = "
                          f"True but inherits with_area_fraction from {owner.__name__} (the plugin's rows over "
                          f"the area fraction would be {owner.__name__}'s); define {cls.__name__}.with_area_fraction "
                          "or set varying_area_fraction = False")
    names, new = _split_parameters("process", name, parameters)
    if factory is None:
        factory = _class_factory("process", name, cls, names, with_shape=True)
    return add_process(ProcessFamily(name, factory, names, new, cls, absolute=absolute))


def shape_family(name: str) -> ShapeFamily:
    """The shape family ``name``, or one :class:`CoronaError` listing the registered ones."""
    try:
        return SHAPE_FAMILIES[name]
    except (KeyError, TypeError):
        raise CoronaError(f"shape={name!r} is not a registered shape; allowed "
                          f"{', '.join(SHAPE_FAMILIES)}") from None


def process_family(name: str) -> ProcessFamily:
    """The process family ``name``, or one :class:`CoronaError` listing the registered ones."""
    try:
        return PROCESS_FAMILIES[name]
    except (KeyError, TypeError):
        raise CoronaError(f"process={name!r} is not a registered process; allowed "
                          f"{', '.join(PROCESS_FAMILIES)}") from None


def family_of_shape(shape) -> ShapeFamily | None:
    """The family whose class ``shape`` is exactly (None for modifiers, mixtures, unregistered)."""
    for fam in SHAPE_FAMILIES.values():
        if fam.cls is not None and type(shape) is fam.cls:
            return fam
    return None


def layer_class(shape) -> type | None:
    """The layer class a family registers (:attr:`ShapeFamily.layer`) for ``shape``: its own
    family's, or that of a shape it holds (wrapped by a modifier, a component of a mixture: that
    class then says what it takes); None for a flat layer (:class:`corona.Material`)."""
    from corona.model.shapes.base import Shape
    if not isinstance(shape, Shape):
        return None
    fam = family_of_shape(shape)
    if fam is not None and fam.layer is not None:
        return fam.layer
    inner = [getattr(shape, "shape", None)]
    inner += [c[0] if isinstance(c, tuple) else c for c in getattr(shape, "components", ()) or ()]
    for s in inner:
        found = layer_class(s) if s is not shape else None
        if found is not None:
            return found
    return None
