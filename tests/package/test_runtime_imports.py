"""The light runtime: importing corona, registering the plugin and loading every kind of
material imports none of the reference tier's heavy dependencies."""
import subprocess
import sys

import pytest

pytestmark = [pytest.mark.slow]

HEAVY = ("numba", "llvmlite", "matplotlib", "skimage", "dask", "distributed", "starlette", "uvicorn")

SCRIPT = r"""
import sys, warnings
warnings.simplefilter("ignore")
import numpy as np
import corona, mitsuba as mi
mi.set_variant(corona.default_variant(prefer_gpu=False))
corona.register()
pts = "{pts}"
np.savetxt(pts, np.random.default_rng(0).uniform(0, 60, (80, 2)))
for extra in [dict(process="poisson"), dict(process="hard-disk"), dict(process="rsa"),
              dict(process="lattice-hex"), dict(process="points", filename=pts),
              dict(shape="square", process="hard-disk"), dict(shape="polygon", sides=5),
              dict(size_spread=0.1), dict(substrate="glass")]:
    b = mi.load_dict({{"type": "corona", "radius": 2.0, **extra}})
print(" ".join(k for k in {heavy!r} if k in sys.modules))
"""


def test_runtime_never_imports_the_heavy_tier(tmp_path):
    code = SCRIPT.format(pts=str(tmp_path / "pts.txt"), heavy=HEAVY)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "", f"imported: {out.stdout.strip()}"


#: scipy's submodules that cost a process most at import (their docstring parsing): loaded where used
SCIPY_LAZY = ("scipy.ndimage", "scipy.interpolate", "scipy.optimize", "scipy.stats", "scipy.special")


def test_the_cli_starts_without_scipys_heavy_submodules():
    """``corona --help`` (importing corona and its CLI) loads none of :data:`SCIPY_LAZY`; a
    negative control imports one through the same check."""
    check = "import sys; {extra}import corona, corona.apps.cli; print(' '.join(k for k in {lazy!r} if k in sys.modules))"
    for extra in ("", "import scipy.ndimage; "):
        out = subprocess.run([sys.executable, "-c", check.format(extra=extra, lazy=SCIPY_LAZY)],
                             capture_output=True, text=True, timeout=600)
        assert out.returncode == 0, out.stderr[-2000:]
        loaded = out.stdout.split()
        assert ("scipy.ndimage" in loaded) if extra else not loaded, f"imported: {loaded}"
