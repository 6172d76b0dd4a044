"""`corona designer` with shape=sphere: every endpoint answers, with the sphere layer's own
physics (Mie theory from corona.mie, the layer's white-furnace energies)."""
from __future__ import annotations

import io
import math
import warnings

import numpy as np
import pytest

pytest.importorskip("starlette")

from PIL import Image  # noqa: E402
from starlette.testclient import TestClient  # noqa: E402

from corona import mie  # noqa: E402
from corona.parameters import material_from_parameters  # noqa: E402

SPHERES = [
    {"shape": "sphere", "radius": 2.0, "area_fraction": 0.2},
    {"shape": "sphere", "radius": 0.8, "area_fraction": 0.3, "process": "hard-disk", "size_spread": 0.05},
    {"shape": "sphere", "radius": 3.0, "area_fraction": 0.05, "process": "poisson", "ior": 1.5},
]


@pytest.fixture(scope="module")
def client():
    from corona.designer import create_app
    # a cold Mie table of a size distribution takes seconds, more on a loaded machine; the test
    # is about the answers (timings are benchmarks' business)
    with TestClient(create_app(timeout=600.0), base_url="http://127.0.0.1") as c:
        yield c


def _material(params):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return material_from_parameters(**params)


@pytest.mark.parametrize("params", SPHERES, ids=["water", "hard-disk-spread", "glass"])
def test_every_endpoint_answers(client, params):
    res = client.get("/api/corona.png", params={**params, "size": 48})
    assert res.status_code == 200, res.text
    img = np.asarray(Image.open(io.BytesIO(res.content)))
    assert img.shape == (48, 48, 3) and img.std() > 1
    for fmt in ("png", "exr"):
        res = client.get(f"/api/kernel.{fmt}", params={**params, "kernel_size": 33, "pixel_scale": 0.2})
        assert res.status_code == 200, res.text
    for ep in ("/api/profiles", "/api/material"):
        res = client.get(ep, params=params)
        assert res.status_code == 200, res.text


def test_energy_split_is_the_white_furnace(client):
    params = SPHERES[1]
    got = client.get("/api/material", params=params).json()
    m = _material(params)
    e = m.directional_albedo(1.0, 550.0)          # integral of eval over the sphere of directions
    assert got["coherent_transmittance"] == pytest.approx(e["coherent"], rel=1e-9)
    assert got["diffuse_transmittance"] == pytest.approx(e["lobe_transmission"], rel=5e-3)
    assert got["reflectance"] == pytest.approx(e["lobe_reflection"], rel=5e-3)
    total = got["coherent_transmittance"] + got["diffuse_transmittance"] + got["reflectance"] + got["absorbed"]
    assert total == pytest.approx(1.0)
    assert got["absorbed"] >= 0


def test_profiles_are_mie(client):
    # a dilute Poisson layer: T_a is one sphere's dσ/dΩ / (π r²) and the lobe F_a T_a (S = 1, the
    # cap inactive up to O(F_a²)); the rings at 550 nm are the maxima of Mie's pattern
    params = SPHERES[2]
    p = client.get("/api/profiles", params=params).json()
    theta = np.radians(p["angle"])
    r = 3.0
    ref = mie.differential_cross_section(1.5, r, 0.55, np.cos(theta)) / (math.pi * r * r)
    np.testing.assert_allclose(p["T_a"], ref, rtol=1e-6)
    m = _material(params)
    w = float(m.energies(1.0, 550.0)["weight"])
    top = max(p["lobe"])
    np.testing.assert_allclose(p["lobe"], 0.05 * w * ref, rtol=0, atol=2e-3 * top)
    th = np.radians(np.linspace(0.05, 25.0, 200001))
    v = mie.differential_cross_section(1.5, r, 0.55, np.cos(th))
    i = np.nonzero((v[1:-1] > v[:-2]) & (v[1:-1] >= v[2:]))[0] + 1
    expected = np.degrees(th[i][:3])
    np.testing.assert_allclose(p["rings"]["550"][:3], expected, rtol=2e-3)
