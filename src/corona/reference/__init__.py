"""The reference tier: what makes and checks the runtime's tables.

Needs the extra ``pip install corona-bsdf[reference]`` (numba, matplotlib,
scikit-image); the runtime (shapes, processes, material, tables, the
plugin, the CLI's ``render`` and ``lobe``) never imports it.

* :mod:`corona.reference.hard_disk` — event-chain Monte Carlo of hard disks,
  Percus–Yevick, the smoothing that makes the shipped S(q) table;
* :mod:`corona.reference.rsa` — runs of the random-sequential-adsorption generator
  (:func:`corona.model.processes.rsa.rsa_configuration`) turned into the shipped S(q) table;
* :mod:`corona.reference.breath_figure` — breath figures: droplets that nucleate,
  grow, coalesce and evaporate on a plane;
* :mod:`corona.reference.breath_figure_optics` — their exact far field and the approximations of
  a polydisperse layer; the table of ``process=breath-figure``;
* :mod:`corona.reference.wave` — the brute-force wave-optics reference
  (random screens, FFT);
* :mod:`corona.reference.validate` — ``corona validate``: model vs brute force,
  a report with figures.
"""
