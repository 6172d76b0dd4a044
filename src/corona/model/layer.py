"""The decoupling rule: how the form factor and the structure factor of a layer combine.

Every numpy model of a layer (:class:`corona.Material`, the fit's
:class:`corona.apps.fit.CircleLayer`, the Mie sphere's forward lobe) combines its
scatterers' form factors with their centres' structure factor through
:func:`decoupled_lobe`; it is the one place the rule is written
(docs/physics.md#mixtures-and-size-distributions).
"""
from __future__ import annotations

import numpy as np


def decoupled_lobe(form_factor, coherent_form_factor, structure_factor, length_scale: float = 1.0,
                   bragg=0.0) -> np.ndarray:
    """The dimensionless lobe ``v = max(P + C (S - 1) + B, 0) / R²`` of the decoupling rule.

    With ``P = ⟨|Â(q)|²⟩/⟨|A|⟩`` and ``C = |⟨Â(q)⟩|²/⟨|A|⟩`` the number-weighted
    form factors of the scatterer population [µm²] (``C = P`` for identical
    scatterers, ``C <= P`` by Cauchy–Schwarz) and ``S(q)`` the structure factor
    of the centres, the diffuse intensity of the layer is ``n [P + C (S - 1)] ⟨|A|⟩``
    per unit ``d²q/(2π)²`` (Kotlarchyk and Chen 1983).  Dividing by ``R²``
    makes it the dimensionless ``v(u)``, ``u = q R``, of the tables; the BSDF's
    lobe is ``F_a (R/λ)² v``.  The clip at 0 removes the small negative values
    that an approximate ``S`` or a coarse size average can produce where
    ``P ≈ C (1 - S)``.

    Parameters
    ----------
    form_factor, coherent_form_factor : array_like
        ``P`` and ``C`` [µm², or µm²/R² when ``length_scale`` is 1].
    structure_factor : array_like
        ``S`` (dimensionless, without the forward delta), broadcastable to ``P``.
    length_scale : float, default 1
        ``R`` [µm] of the dimensionless offset ``u = q R``.
    bragg : array_like, default 0
        Extra coherent intensity that does not go through ``S`` (the cell
        means ``Σ_G C(G) W_G ⟨g_G⟩`` of a fixed lattice's Bragg peaks) [µm²].

    Returns
    -------
    ndarray
        ``v`` (dimensionless), of the broadcast shape of the inputs.

    Examples
    --------
    Identical scatterers (``C = P``) without correlations (``S = 1``) give the
    form factor alone; a perfectly anticorrelated ``S = 0`` cancels it:

    >>> from corona.model.layer import decoupled_lobe
    >>> float(decoupled_lobe(2.0, 2.0, 1.0)), float(decoupled_lobe(2.0, 2.0, 0.0))
    (2.0, 0.0)
    >>> float(decoupled_lobe(8.0, 4.0, 0.5, length_scale=2.0))   # (8 + 4 (0.5 - 1)) / 2²
    1.5
    """
    P = np.asarray(form_factor, dtype=np.float64)
    C = np.asarray(coherent_form_factor, dtype=np.float64)
    return np.maximum(P + C * (np.asarray(structure_factor, dtype=np.float64) - 1.0) + bragg,
                      0.0) / float(length_scale) ** 2
