"""The tables tier: what the renderers read, above the model.

The lobe of a material is tabulated once in the dimensionless wave vector
``u = q R = 2π R d / λ`` (docs/physics.md#the-model, docs/tables.md):

    lobe(d, λ) = F_a · (R/λ)² · v(2π R d / λ),   v(u) = [P + C (S - 1)] / R²

The table types (:class:`RadialTable`, :class:`GridTable`), their grids and
the on-disk cache (:func:`cached`, :func:`cache_dir`, :func:`cache_info`,
:func:`cache_clear`) are used by the model itself (a material's lobe weight
is its table's integral; a Mie layer's lobe is read from its rows), so they
live in :mod:`corona.model.tabulated`; every name stays importable from here.
The renderer's rows over textured parameters are :mod:`corona.tables.lobe`.
"""
from corona.model.tabulated import (  # noqa: F401
    CACHE_FILE, D_MAX, FORMAT_VERSION, GRID2D_SIZE, PROGRESS_DELAY, RADIAL_DU, RADIAL_MAX_SAMPLES,
    RADIAL_MIN_UMAX, ROW_TOLERANCE, TABLE_FILE, WAVELENGTH_MAX, WAVELENGTH_MIN, GridTable,
    RadialTable, _cache_files, _checksum, _read, _remove_stale_temporaries, _warn_once,
    _warned_folders, _write_atomic, bisect_rows, cache_clear, cache_dir, cache_info, cache_key,
    cached, code_key, radial_cdfs, radial_totals, table_from_arrays, u_max_for, warp_for)
