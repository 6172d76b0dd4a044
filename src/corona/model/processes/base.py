"""The base class of a point process of scatterer centres."""
from __future__ import annotations

import json
import os

import numpy as np

from corona._validation import CoronaError


#: The folder of the tables corona ships (corona/data).
DATA = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), "data")


def shipped_table(filename: str, format_version: int, what: str, script: str) -> dict:
    """A table shipped in :data:`DATA`: an ``.npz`` whose ``metadata`` is JSON, its arrays and that
    metadata (a dict) checked against ``format_version``; one ``CoronaError`` naming ``what`` when the
    file is missing (made by ``script``) or of another format."""
    path = os.path.join(DATA, filename)
    if not os.path.exists(path):
        raise CoronaError(f"{what} table {path} is missing; reinstall corona or run {script}")
    with np.load(path, allow_pickle=False) as z:
        t = {k: z[k] for k in z.files}
    t["metadata"] = json.loads(str(t["metadata"]))
    if t["metadata"].get("format_version") != format_version:
        raise CoronaError(f"{path}: format version {t['metadata'].get('format_version')} != "
                          f"{format_version}; reinstall corona")
    return t


class Process:
    """Base class of a point process of scatterer centres."""

    isotropic: bool = True

    def area_fraction(self, shape) -> float:
        raise NotImplementedError

    def structure_factor_at(self, q, shape) -> np.ndarray:
        """``S(q)`` at ``q`` [rad/µm] of shape (..., 2)."""
        q = np.asarray(q, dtype=np.float64)
        return self.structure_factor_radial(np.hypot(q[..., 0], q[..., 1]), shape)

    def structure_factor_radial(self, q_abs, shape) -> np.ndarray:
        """``S(|q|)`` for isotropic processes, ``q_abs`` in rad/µm."""
        raise NotImplementedError

    def validate(self, shape) -> None:
        """Raise a clear error if this process cannot hold ``shape`` as given."""

    def layer_shape(self, shape):
        """The layer's scatterers: ``shape`` as given, or the process's own population when the
        process sets the sizes too (a breath figure's droplets)."""
        return shape

    #: True when :meth:`lobe_intensity_radial` gives the layer's lobe (not the decoupling rule).
    own_lobe: bool = False

    def lobe_intensity_radial(self, q_abs, shape):
        """``⟨|Â|² S⟩/⟨|A|⟩`` [µm²] at ``|q|`` when the process sets the layer's lobe beyond the
        decoupling rule (a breath figure's local monodisperse approximation); None: the rule."""
        return None

    def layer_area_fraction(self, shape) -> float:
        """The area fraction of a layer of ``shape`` on this process, checked: :meth:`validate`,
        then one clear error unless it lies in (0, 1) (what every material needs)."""
        self.validate(shape)
        fa = float(self.area_fraction(shape))
        if not (0.0 < fa < 1.0):
            raise CoronaError(f"area_fraction={fa:g} (from {self!r} with {shape!r}) is out of range; "
                              "allowed (0, 1)")
        return fa

    # --- a varying area fraction (textured layers) -----------------------------
    #: True when ``S`` depends on the area fraction only through a table or a
    #: formula, so that the layer's ``F_a`` may vary over a surface.
    varying_area_fraction: bool = False

    def with_area_fraction(self, area_fraction: float) -> "Process":
        """The same process at another area fraction."""
        raise CoronaError(f"{type(self).__name__}: the area fraction fixes its geometry and cannot "
                          "vary over the layer; use process poisson, hard-disk or rsa")

    def area_fraction_limit(self, shape) -> float:
        """The largest area fraction this process reaches with ``shape``."""
        return self.area_fraction(shape)

    def area_fraction_nodes(self, shape):
        """Area fractions at which ``S`` is tabulated (rows of interpolation), within the limit."""
        return np.zeros(0)

    def key(self) -> dict:
        from corona.model.shapes.base import keyable
        return {"type": type(self).__name__, **{k: keyable(v) for k, v in vars(self).items()
                                                if not k.startswith("_")}}


def _check_exclusion(process_name, sigma, shape):
    sd = shape.exclusion_diameter
    if sigma < sd * (1.0 - 1e-9):
        raise CoronaError(f"{process_name}: exclusion_diameter={sigma:g} µm is out of range; "
                          f"expected >= the shape's exclusion diameter {sd:g} µm "
                          "(smaller values let scatterers overlap)")

