import os
import sys

# scripts/ (gallery, demo) need a source checkout; the tests run from one
sys.path.insert(0, os.path.join(os.path.dirname(__file__), os.pardir, "scripts"))

# the private table cache and `import corona` before drjit: ../conftest.py
import corona  # noqa: E402,F401
import pytest  # noqa: E402


@pytest.fixture(scope="session")
def mi_variant():
    """The default variant (llvm_ad_spectral here), with the plugin registered."""
    import mitsuba as mi
    variant = corona.default_variant(prefer_gpu=False)
    mi.set_variant(variant)
    corona.register()
    return variant
