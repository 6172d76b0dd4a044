"""The previous release's module names, kept for one release.

The modules moved into tier folders (``corona.model``, ``corona.tables``,
``corona.mitsuba``, ``corona.apps``). ``import corona.mitsuba_bsdf`` and the
other old names still work: they give the moved module itself (the same
object, so attributes set on it are seen everywhere) and warn once with a
``DeprecationWarning`` naming the new one. ``python -m corona.cli`` runs the
CLI as before.
"""
from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import importlib.util
import sys
import warnings

#: old name -> new name
MOVED = {
    "corona.shapes": "corona.model.shapes",
    "corona.processes": "corona.model.processes",
    "corona.mie": "corona.model.mie.theory",
    "corona.sphere_material": "corona.model.mie.layer",
    "corona.layer": "corona.model.layer",
    "corona.material": "corona.model.material",
    "corona.substrate": "corona.model.substrate",
    "corona.render_lobe": "corona.tables.lobe",
    "corona.mitsuba_common": "corona.mitsuba.common",
    "corona.mitsuba_bsdf": "corona.mitsuba.bsdf",
    "corona.mitsuba_sphere": "corona.mitsuba.sphere",
    "corona.mitsuba_phase": "corona.mitsuba.phase",
    "corona.lobe_kernels": "corona.mitsuba.kernels",
    "corona.volume": "corona.mitsuba.volume",
    "corona.cli": "corona.apps.cli",
    "corona.render": "corona.apps.render",
    "corona.sweep": "corona.apps.sweep",
    "corona.fit": "corona.apps.fit",
    "corona.designer": "corona.apps.designer",
    "corona.pictures": "corona.apps.pictures",
    "corona.post": "corona.apps.post",
    "corona.scenes": "corona.apps.scenes",
    "corona.micrograph": "corona.apps.micrograph",
}


def new_name(old: str) -> str | None:
    """The module's new name (``corona.shapes.base`` -> ``corona.model.shapes.base``), or None."""
    if old in MOVED:
        return MOVED[old]
    head, _, tail = old.rpartition(".")
    while head:
        if head in MOVED:
            return MOVED[head] + old[len(head):]
        head, _, _ = head.rpartition(".")
    return None


class _Alias(importlib.abc.Loader):
    def __init__(self, old: str, new: str):
        self.old, self.new = old, new

    def create_module(self, spec):
        warnings.warn(f"{self.old} moved to {self.new}; the old name goes in the next release",
                      DeprecationWarning, stacklevel=3)
        module = importlib.import_module(self.new)
        self._spec = module.__spec__
        return module

    def exec_module(self, module):
        # the moved module is already executed: the old name points at it, and the import
        # system's stamp of the alias's spec on it is undone
        module.__spec__ = self._spec
        sys.modules[self.old] = module

    def get_code(self, fullname):
        # `python -m corona.cli`: runpy runs the moved module's code as __main__
        return importlib.util.find_spec(self.new).loader.get_code(self.new)


class _Finder(importlib.abc.MetaPathFinder):
    def find_spec(self, fullname, path=None, target=None):
        new = new_name(fullname)
        if new is None:
            return None
        real = importlib.util.find_spec(new)
        spec = importlib.machinery.ModuleSpec(fullname, _Alias(fullname, new),
                                              origin=real.origin if real else None)
        spec.submodule_search_locations = real.submodule_search_locations if real else None
        return spec


def install() -> None:
    """Put the finder of old names on ``sys.meta_path`` (idempotent)."""
    if not any(isinstance(f, _Finder) for f in sys.meta_path):
        sys.meta_path.insert(0, _Finder())
