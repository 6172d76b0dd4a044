"""Structure factors of the scatterers' centres (docs/physics.md#the-model).

A point process provides

* ``area_fraction(shape)`` — ``F_a = n |A|``;
* ``structure_factor_at(q, shape)`` — ``S(q)`` at wave vectors ``q``
  [rad/µm] of shape (..., 2), without the forward delta, ``S → 1`` at large q;
* ``structure_factor_radial(q_abs, shape)`` for isotropic processes;
* ``isotropic`` — True when S depends on ``|q|`` only;
* ``validate(shape)`` — a :class:`~corona.CoronaError` naming the parameter,
  its value and the allowed range when the process cannot hold ``shape``;
* ``key()`` — the parameters that identify it (for table caching).

Processes, one module each:

* :class:`Poisson` — independent centres, ``S = 1`` (dilute limit only);
* :class:`HardDisk` — the equilibrium hard-disk fluid, ``S(qσ, η)`` from a
  shipped event-chain Monte Carlo table;
* :class:`SequentialAdsorption` — random sequential adsorption (RSA) of
  disks, ``S(qσ, η)`` from a shipped Monte Carlo table;
* :class:`Lattice` — square / hexagonal lattices with Gaussian jitter
  (Debye–Waller background plus broadened Bragg peaks);
* :class:`PointSet` — measured centres, ``S`` estimated by a tapered
  periodogram;
* :class:`BreathFigure` — condensed droplets at a time after the breath (sizes and positions
  from a shipped simulation table; the local monodisperse approximation).

Every lookup here is numpy/scipy only; the simulations that make the tables
live in :mod:`corona.reference` (extra ``corona-bsdf[reference]``).
"""
from corona.model.processes.base import Process
# in the order of the families' registration (corona.model.registry), the order of the spec's list
from corona.model.processes.poisson import Poisson
from corona.model.processes.hard_disk import HardDisk
from corona.model.processes.rsa import RSA_JAMMING_LIMIT, RSA_SATURATION, SequentialAdsorption, rsa_structure_factor
from corona.model.processes.lattice import Lattice
from corona.model.processes.point_set import PointSet
from corona.model.processes.hard_sphere import percus_yevick_3d
from corona.model.processes.breath_figure import BreathFigure

__all__ = ["Process", "Poisson", "HardDisk", "SequentialAdsorption", "Lattice", "PointSet", "BreathFigure",
           "rsa_structure_factor", "RSA_JAMMING_LIMIT", "RSA_SATURATION"]
