"""The shell every ``corona`` BSDF family shares (the flat layer, :mod:`corona.mitsuba.bsdf`; Mie
spheres, :mod:`corona.mitsuba.sphere`): Mitsuba's ``eval``, ``pdf``, ``eval_pdf`` and ``sample``, the
component list and its flags, the selection of a component ∝ its energy honouring the context, and
the update protocol of ``parameters_changed``.

A family is a mixin on :class:`PluginCore` that, at load, calls :meth:`PluginCore.set_components` and
holds a substrate component (``substrate``: its ``energies(layer, cos_i)`` are the components'
energies in :meth:`PluginCore.set_components`'s order), and supplies

- ``_eval_pdf(ctx, si, wo, active)``: ``(f |cos θo|, pdf)``;
- ``_sample(ctx, si, sample1, sample2, active)``: ``(BSDFSample3f, weight)`` (with the shell's
  ``_new_sample``, ``_sample_weight`` and ``_accepted``);
- ``_checked_ranges()``: the textures' current ranges, checked (one :class:`corona.CoronaError`
  naming a bad one); ``_outside(ranges)``: whether they leave what the tables cover;
  ``_rebuild(ranges)``: new tables about them; ``_recentre(ranges)``: the tables moved without a new
  kernel (a uniform layer's centred rows; nothing else).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from corona.mitsuba.common import positive, selection

__all__ = ["PluginCore"]


class PluginCore:
    """The shared shell of the ``corona`` BSDF families (see the module docstring)."""

    def set_components(self, components, selected):
        """The BSDF's components (``m_components``, their union ``m_flags``) and the flag each
        component is selected under (``selected``, in the order of the substrate's ``energies``)."""
        self.m_components = list(components)
        flags = mi.BSDFFlags.Empty
        for c in self.m_components:
            flags = flags | c
        self.m_flags = flags
        #: the flags :meth:`_selection` asks the context about, component by component
        self.selection_flags = tuple(selected)

    def _selection(self, ctx, layer, cos_i=None):
        """Per-lane probabilities of the components ∝ their energies (the substrate's
        ``energies(layer, cos_i)``), 0 for those the context disables."""
        energies = self.substrate.energies(layer, cos_i)
        return selection(energies, [ctx.is_enabled(fl, i) for i, fl in enumerate(self.selection_flags)])

    def eval(self, ctx, si, wo, active=True):
        return self._eval_pdf(ctx, si, wo, active)[0]

    def pdf(self, ctx, si, wo, active=True):
        return self._eval_pdf(ctx, si, wo, active)[1]

    def eval_pdf(self, ctx, si, wo, active=True):
        return self._eval_pdf(ctx, si, wo, active)

    def sample(self, ctx, si, sample1, sample2, active=True):
        return self._sample(ctx, si, sample1, sample2, active)

    # what every family's sample shares
    @staticmethod
    def _new_sample():
        """A zeroed ``BSDFSample3f`` (``eta`` 1: the layer does not refract)."""
        bs = dr.zeros(mi.BSDFSample3f)
        bs.eta = 1.0
        return bs

    @staticmethod
    def _sample_weight(value, pdf):
        """``value / pdf`` where ``pdf > 0``, else 0 (no 0/0, scalar variants too)."""
        return dr.select(pdf > 0, value / positive(pdf), 0.0)

    @staticmethod
    def _accepted(bs, weight, pick_delta, smooth):
        """``(bs, weight)`` with the weight kept where a delta component was picked or a smooth one
        has a density, 0 elsewhere."""
        ok = pick_delta | (smooth & (bs.pdf > 0))
        return bs, dr.select(ok, mi.Spectrum(weight), 0.0)

    def parameters_changed(self, keys):
        # new values: check them; rebuild the tables only when they leave what the tables cover
        ranges = self._checked_ranges()
        if self._outside(ranges):
            self._rebuild(ranges)
        else:
            self._recentre(ranges)
