"""The distribution others install: corona-bsdf (import name corona).

Builds the wheel and the sdist with the standard front end (python -m build; its
isolated build environment comes from the package index), checks their metadata
(twine) and lists what the wheel holds.  Installing the wheel into a fresh
environment and rendering from it is `make wheel-check` (CI).
"""
import email.parser
import os
import subprocess
import sys
import tarfile
import zipfile

import pytest

import corona

pytestmark = [pytest.mark.slow]

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), os.pardir, os.pardir))


@pytest.fixture(scope="module")
def dist(tmp_path_factory):
    out = tmp_path_factory.mktemp("dist")
    r = subprocess.run([sys.executable, "-m", "build", "--outdir", str(out), ROOT],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout[-2000:] + r.stderr[-2000:]
    wheels, sdists = list(out.glob("*.whl")), list(out.glob("*.tar.gz"))
    assert len(wheels) == 1 and len(sdists) == 1
    return wheels[0], sdists[0]


def _tracked(prefix):
    r = subprocess.run(["git", "ls-files", prefix], capture_output=True, text=True, cwd=ROOT)
    if r.returncode:
        pytest.fail("git ls-files failed: the packaging test needs the source checkout")
    return [p for p in r.stdout.splitlines() if "__pycache__" not in p]


def test_wheel_holds_every_module_table_and_static_file(dist):
    wheel, _ = dist
    names = set(zipfile.ZipFile(wheel).namelist())
    shipped = [p[len("src/"):] for p in _tracked("src/corona")]
    assert any(p.startswith("corona/data/") and p.endswith(".npz") for p in shipped)
    assert any(p.startswith("corona/apps/designer/static/") for p in shipped)
    missing = [p for p in shipped if p not in names]
    assert not missing, f"not in the wheel: {missing}"
    assert not [n for n in names if n.startswith(("tests/", "scripts/", "benchmarks/"))]


def test_metadata_name_version_and_entry_point(dist):
    wheel, sdist = dist
    z = zipfile.ZipFile(wheel)
    meta_name = next(n for n in z.namelist() if n.endswith(".dist-info/METADATA"))
    meta = email.parser.Parser().parsestr(z.read(meta_name).decode())
    assert meta["Name"] == "corona-bsdf"
    assert meta["Version"] == corona.__version__            # the version's one home
    assert meta["Requires-Python"] == ">=3.11"
    assert any(r.startswith("mitsuba") for r in meta.get_all("Requires-Dist"))
    entry = z.read(meta_name.replace("METADATA", "entry_points.txt")).decode()
    assert "corona = corona.apps.cli:main" in entry
    assert os.path.basename(wheel).startswith(f"corona_bsdf-{corona.__version__}-py3-none-any")
    with tarfile.open(sdist) as t:
        members = t.getnames()
    top = f"corona_bsdf-{corona.__version__}"
    assert f"{top}/pyproject.toml" in members and f"{top}/src/corona/data/hard_disk_structure_factor.npz" in members


def test_twine_check(dist):
    r = subprocess.run([sys.executable, "-m", "twine", "check", "--strict", *map(str, dist)],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr


def test_version_has_one_home():
    """`corona --version` and the docs read corona.__version__ (no distribution named corona)."""
    r = subprocess.run([sys.executable, "-m", "corona.apps.cli", "--version"], capture_output=True, text=True)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == f"corona, version {corona.__version__}"
    pyproject = open(os.path.join(ROOT, "pyproject.toml"), encoding="utf-8").read()
    assert 'dynamic = ["version"]' in pyproject and 'attr = "corona.__version__"' in pyproject
