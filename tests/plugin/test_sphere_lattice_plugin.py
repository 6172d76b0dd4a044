"""Spheres on a fixed lattice in Dr.Jit: the closed-form S(q) per lane
(corona.mitsuba.sphere_lattice.LatticeS) against the numpy lattice's structure_factor_at, on the
peaks, between them and through the Debye–Waller background (the renderer's one-line refusal,
which stays until the cap's per-lane bound is tight, is tested in test_sphere_points.py)."""
import numpy as np
import pytest

import corona


@pytest.mark.parametrize("kind, a, jitter, angle", [("square", 3.0, 0.0, 0.0), ("hexagonal", 4.0, 0.0, 0.0),
                                                    ("square", 3.0, 0.15, 20.0), ("hexagonal", 2.2, 0.15, 0.0)])
def test_structure_factor_matches_numpy(mi_variant, kind, a, jitter, angle):
    import mitsuba as mi
    from corona.mitsuba.sphere_lattice import LatticeS
    lat = corona.Lattice(kind, a, jitter=jitter, angle=angle)
    rng = np.random.default_rng(7)
    G, _ = lat.bragg_peaks(20.0)
    w = lat.peak_width
    # on the peaks, within two widths of them, and anywhere up to |q| = 25 rad/µm
    q = np.concatenate([G[:40], G[:200] + rng.normal(0.0, w, (min(200, len(G)), 2)),
                        rng.uniform(-25.0, 25.0, (2000, 2))])
    ref = lat.structure_factor_at(q)
    got = np.asarray(LatticeS(lat)(mi.Float(q[:, 0]), mi.Float(q[:, 1])), dtype=np.float64)
    peak = (2 * np.pi) ** 2 * lat.number_density / (2 * np.pi * w * w)
    assert np.max(np.abs(got - ref)) < 1e-4 * peak      # float32: q - G at |q| ~ 20 rad/µm
    assert np.max(np.abs(got - ref) / np.maximum(ref, 1e-3)) < 1e-3
    assert ref[:40].min() > 0.5 * peak * np.exp(-(np.hypot(G[:40, 0], G[:40, 1]).max() * jitter) ** 2)


def test_negative_control_a_shifted_lattice_fails(mi_variant):
    import mitsuba as mi
    from corona.mitsuba.sphere_lattice import LatticeS
    lat = corona.Lattice("hexagonal", 4.0)
    G, _ = lat.bragg_peaks(10.0)
    wrong = LatticeS(corona.Lattice("hexagonal", 4.0 * 1.01))(mi.Float(G[:, 0]), mi.Float(G[:, 1]))
    assert not np.allclose(np.asarray(wrong), lat.structure_factor_at(G), rtol=0.1)
