"""Every public entry point rejects bad input with one clear line.

Each row names the bad input and the fragments its message must contain:
the parameter, the bad value and the allowed range (or, for files, the file
and what is wrong with it).  The Python API raises :class:`corona.CoronaError`
with a one-line message; Mitsuba wraps an error raised while loading a plugin
in its own message plus the Python traceback, whose last line must then be
that one-line ``CoronaError``; the CLI prints one line on stderr and exits 2.
"""
import math
import os
import subprocess
import sys
import warnings

import numpy as np
import pytest
from click.testing import CliRunner

import corona
from corona.model import material as material_module
from corona.apps.cli import main as cli_main
from corona.parameters import material_from_parameters


# --------------------------------------------------------------------------
# bad files
# --------------------------------------------------------------------------
@pytest.fixture(scope="module")
def files(tmp_path_factory):
    import imageio.v3 as iio
    d = tmp_path_factory.mktemp("bad-files")
    out = {"missing_png": str(d / "missing.png"), "missing_txt": str(d / "missing.txt"),
           "dir": str(d)}
    (d / "empty.png").write_bytes(b"")
    out["empty_png"] = str(d / "empty.png")
    (d / "corrupt.png").write_bytes(b"\x89PNG\r\n\x1a\n" + b"not really a png" * 4)
    out["corrupt_png"] = str(d / "corrupt.png")
    iio.imwrite(d / "black.png", np.zeros((16, 16), np.uint8))
    out["black_png"] = str(d / "black.png")
    img = np.zeros((16, 16), np.uint8)
    img[4:12, 4:12] = 255
    iio.imwrite(d / "square.png", img)
    out["mask_png"] = str(d / "square.png")
    (d / "empty.txt").write_text("")
    out["empty_txt"] = str(d / "empty.txt")
    (d / "header.csv").write_text("x,y\n# nothing else\n")
    out["header_csv"] = str(d / "header.csv")
    (d / "garbage.txt").write_text("1.0 2.0\nthree four\n")
    out["garbage_txt"] = str(d / "garbage.txt")
    (d / "binary.txt").write_bytes(bytes(range(256)) * 4)
    out["binary_txt"] = str(d / "binary.txt")
    (d / "broken.npy").write_bytes(b"\x93NUMPY garbage")
    out["broken_npy"] = str(d / "broken.npy")
    rng = np.random.default_rng(0)
    np.savetxt(d / "points.csv", rng.uniform(0, 40, (60, 2)), delimiter=",")
    out["points_csv"] = str(d / "points.csv")
    (d / "empty.xml").write_text("")
    out["empty_xml"] = str(d / "empty.xml")
    (d / "corrupt.xml").write_text('<scene version="3.0.0"><bsdf type="corona"')
    out["corrupt_xml"] = str(d / "corrupt.xml")
    (d / "bad_bsdf.xml").write_text(
        '<scene version="3.0.0">\n'
        '  <shape type="rectangle">\n'
        '    <bsdf type="corona"><float name="radius" value="-1"/></bsdf>\n'
        '  </shape>\n'
        '</scene>\n')
    out["bad_bsdf_xml"] = str(d / "bad_bsdf.xml")
    return out


def _check_line(msg: str, fragments) -> None:
    assert msg == msg.strip() and "\n" not in msg, f"not one line: {msg!r}"
    for f in fragments:
        assert f in msg, f"{f!r} missing from {msg!r}"


# --------------------------------------------------------------------------
# Python API
# --------------------------------------------------------------------------
C1 = corona.Circle(1.0)
NAN, INF = float("nan"), float("inf")

API_CASES = {
    # non-positive / non-finite sizes
    "circle-negative": (lambda f: corona.Circle(radius=-1), ["radius=-1", "> 0", "µm"]),
    "circle-zero": (lambda f: corona.Circle(radius=0), ["radius=0", "> 0"]),
    "circle-nan": (lambda f: corona.Circle(radius=NAN), ["radius=nan", "> 0"]),
    "circle-inf": (lambda f: corona.Circle(radius=INF), ["radius=inf", "> 0"]),
    "circle-string": (lambda f: corona.Circle(radius="big"), ["radius='big'", "> 0"]),
    "ellipse-negative": (lambda f: corona.Ellipse(-1.0, aspect=1.0), ["radius=-1", "> 0"]),
    "square-zero": (lambda f: corona.Square(0.0), ["radius=0", "> 0"]),
    "polygon-two-sides": (lambda f: corona.RegularPolygon(2, 1.0), ["sides=2", "3.."]),
    "soft-edge-negative": (lambda f: corona.SoftEdge(C1, -0.1), ["edge_width=-0.1", "[0, inf]"]),
    "spread-too-wide": (lambda f: corona.SizeDistribution(C1, 1.5), ["spread=1.5", "[0, 1]"]),
    # area fractions beyond what each process reaches
    "poisson-zero": (lambda f: corona.Poisson(0.0), ["area_fraction=0", "(0, 1)"]),
    "poisson-one": (lambda f: corona.Poisson(1.0), ["area_fraction=1", "(0, 1)"]),
    "poisson-negative": (lambda f: corona.Poisson(-0.1), ["area_fraction=-0.1", "(0, 1)"]),
    "poisson-nan": (lambda f: corona.Poisson(NAN), ["area_fraction=nan", "(0, 1)"]),
    "hard-disk-one": (lambda f: corona.HardDisk(1.0), ["area_fraction=1", "(0, 1)"]),
    "hard-disk-beyond-eta": (lambda f: corona.Material(C1, corona.HardDisk(0.75)),
                             ["area_fraction=0.75", "0.72", "allowed area_fraction ≤ 0.72"]),
    "hard-disk-square-beyond-eta": (lambda f: corona.Material(corona.Square(1.0), corona.HardDisk(0.5)),
                                    ["area_fraction=0.5", "allowed area_fraction ≤ 0.4584"]),
    "hard-disk-overlapping-sigma": (
        lambda f: corona.Material(C1, corona.HardDisk(0.3, exclusion_diameter=1.0)),
        ["exclusion_diameter=1", ">= the shape's exclusion diameter 2"]),
    "rsa-beyond-jamming": (lambda f: corona.SequentialAdsorption(0.6),
                           ["area_fraction=0.6", "(0, 0.547]"]),
    "rsa-square-beyond-jamming": (
        lambda f: corona.Material(corona.Square(1.0), corona.SequentialAdsorption(0.5)),
        ["area_fraction=0.5", "allowed area_fraction <= 0.3482"]),
    # wavelengths outside the tables
    "lobe-short-wavelength": (lambda f: corona.Material(C1).lobe([[0.1, 0.0]], 359.9),
                              ["wavelength=359.9", "[360, 830] nm"]),
    "lobe-long-wavelength": (lambda f: corona.Material(C1).lobe([[0.1, 0.0]], 830.5),
                             ["wavelength=830.5", "[360, 830] nm"]),
    "lobe-nan-wavelength": (lambda f: corona.Material(C1).lobe([[0.1, 0.0]], NAN),
                            ["wavelength=nan", "[360, 830] nm"]),
    "lobe-one-bad-of-many": (lambda f: corona.Material(C1).lobe(np.zeros((3, 2)), [400.0, 0.0, 500.0]),
                             ["wavelength=0.0", "[360, 830] nm"]),
    "sample-wavelength": (lambda f: corona.Material(C1).sample([[0.5, 0.5]], 900.0),
                          ["wavelength=900.0", "[360, 830] nm"]),
    "pdf-wavelength": (lambda f: corona.Material(C1).pdf([[0.0, 0.0]], -550.0),
                       ["wavelength=-550.0", "[360, 830] nm"]),
    "transmittance-wavelength": (lambda f: corona.Material(C1).diffuse_transmittance(1000.0, 1.0),
                                 ["wavelength=1000.0", "[360, 830] nm"]),
    "lobe-nan-offset": (lambda f: corona.Material(C1).lobe([[NAN, 0.0]], 550.0), ["d contains nan", "finite"]),
    "sample-xi-outside": (lambda f: corona.Material(C1).sample([[0.5, 1.5]], 550.0), ["xi=1.5", "[0, 1]"]),
    "cos-theta-outside": (lambda f: corona.Material(C1).diffuse_transmittance(550.0, 1.5),
                          ["cos_theta_i=1.5", "[0, 1]"]),
    # unknown names
    "unknown-mode": (lambda f: corona.Material(C1, mode="sideways"),
                     ["mode='sideways'", "'aperture', 'particle'"]),
    "not-a-shape": (lambda f: corona.Material("circle"), ["shape='circle'", "corona.Circle"]),
    "not-a-process": (lambda f: corona.Material(C1, "poisson"), ["process='poisson'", "corona.Poisson"]),
    "unknown-distribution": (lambda f: corona.SizeDistribution(C1, 0.1, distribution="gauss"),
                             ["distribution='gauss'", "'lognormal', 'schulz'"]),
    "unknown-lattice": (lambda f: corona.Lattice("triangular"), ["kind='triangular'", "'square', 'hexagonal'"]),
    "albedo": (lambda f: corona.Material(C1, albedo=1.2), ["albedo=1.2", "[0, 1]"]),
    # files
    "mask-missing": (lambda f: corona.Mask(f["missing_png"], 0.1), ["missing.png", "no such file"]),
    "mask-empty": (lambda f: corona.Mask(f["empty_png"], 0.1), ["empty.png", "empty file"]),
    "mask-corrupt": (lambda f: corona.Mask(f["corrupt_png"], 0.1), ["corrupt.png", "could not be read"]),
    "mask-no-opening": (lambda f: corona.Mask(f["black_png"], 0.1),
                        ["black.png", "no transmitting pixel", "at least one opening"]),
    "mask-array-no-opening": (lambda f: corona.Mask(np.zeros((8, 8)), 0.1), ["no transmitting pixel"]),
    "mask-pixel-size": (lambda f: corona.Mask(f["mask_png"], 0.0), ["pixel_size=0", "> 0"]),
    "points-missing": (lambda f: corona.PointSet.from_file(f["missing_txt"]), ["missing.txt", "does not exist"]),
    "points-directory": (lambda f: corona.PointSet.from_file(f["dir"]), ["is a directory"]),
    "points-empty": (lambda f: corona.PointSet.from_file(f["empty_txt"]), ["empty.txt", "contains no points"]),
    "points-header-only": (lambda f: corona.PointSet.from_file(f["header_csv"]),
                           ["header.csv", "contains no points"]),
    "points-garbage": (lambda f: corona.PointSet.from_file(f["garbage_txt"]),
                       ["garbage.txt", "line 2"]),
    "points-binary": (lambda f: corona.PointSet.from_file(f["binary_txt"]), ["binary.txt", "not a text file"]),
    "points-broken-npy": (lambda f: corona.PointSet.from_file(f["broken_npy"]),
                          ["broken.npy", "not a readable .npy"]),
}


@pytest.mark.parametrize("name", list(API_CASES))
def test_python_api_rejects(files, name):
    call, fragments = API_CASES[name]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", corona.CoronaWarning)
        with pytest.raises(corona.CoronaError) as info:
            call(files)
    assert isinstance(info.value, ValueError)
    _check_line(str(info.value), fragments)


# --------------------------------------------------------------------------
# flat parameters: material_from_parameters (plugin and CLI vocabulary)
# --------------------------------------------------------------------------
PARAM_CASES = {
    "radius-negative": ({"radius": -1.0}, ["radius=-1.0", "[0.001, 1000] µm"]),
    "radius-zero": ({"radius": 0.0}, ["radius=0.0", "[0.001, 1000] µm"]),
    "radius-nan": ({"radius": NAN}, ["radius=nan", "[0.001, 1000] µm"]),
    "radius-inf": ({"radius": INF}, ["radius=inf", "[0.001, 1000] µm"]),
    "aspect-negative": ({"shape": "ellipse", "aspect": -1.0}, ["aspect=-1.0", "[0.2, 5]"]),
    "sides-two": ({"shape": "polygon", "sides": 2}, ["sides=2", ">= 3"]),
    "sides-fraction": ({"shape": "polygon", "sides": 3.5}, ["sides=3.5", ">= 3"]),
    "angle-huge": ({"shape": "square", "angle": 1e9}, ["angle=1000000000.0", "[-360, 360]"]),
    "edge-width-negative": ({"edge_width": -0.1}, ["edge_width=-0.1", "[0, 1000] µm"]),
    "size-spread": ({"size_spread": 2.0}, ["size_spread=2.0", "[0, 0.5]"]),
    "poisson-zero": ({"process": "poisson", "area_fraction": 0.0}, ["area_fraction=0.0", "(0, 1)"]),
    "poisson-one": ({"process": "poisson", "area_fraction": 1.0}, ["area_fraction=1.0", "(0, 1)"]),
    "hard-disk-eta": ({"process": "hard-disk", "area_fraction": 0.8}, ["area_fraction=0.8", "≤ 0.72"]),
    "hard-disk-square": ({"process": "hard-disk", "shape": "square", "area_fraction": 0.5},
                         ["area_fraction=0.5", "≤ 0.4584"]),
    "hard-disk-sigma": ({"process": "hard-disk", "exclusion_diameter": 0.5},
                        ["exclusion_diameter=0.5", ">= the shape's exclusion diameter 1"]),
    "rsa-jamming": ({"process": "rsa", "area_fraction": 0.6}, ["area_fraction=0.6", "(0, 0.547]"]),
    "rsa-sigma": ({"process": "rsa", "exclusion_diameter": 0.1}, ["exclusion_diameter=0.1", ">= "]),
    "lattice-square-overlap": ({"process": "lattice-square", "area_fraction": 0.8},
                               ["area_fraction=0.8", "lattice-square", "(0, 0.7854]"]),
    "lattice-hex-overlap": ({"process": "lattice-hex", "area_fraction": 0.95},
                            ["area_fraction=0.95", "lattice-hex", "(0, 0.9069]"]),
    "jitter-negative": ({"process": "lattice-square", "jitter": -1.0}, ["jitter=-1.0", "[0, 2000] µm"]),
    "albedo": ({"albedo": 2.0}, ["albedo=2.0", "[0, 1]"]),
    "unknown-shape": ({"shape": "blob"}, ["shape='blob'", "'circle'"]),
    "unknown-process": ({"process": "blob"}, ["process='blob'", "'poisson'", "'hard-disk'"]),
    "unknown-mode": ({"mode": "sideways"}, ["mode='sideways'", "'aperture', 'particle'"]),
    "unknown-orientation": ({"orientation": "tilted"}, ["orientation='tilted'", "'fixed', 'random'"]),
    "unknown-size-distribution": ({"size_spread": 0.1, "size_distribution": "gauss"},
                                  ["size_distribution='gauss'", "'lognormal'"]),
    "mask-without-file": ({"shape": "mask", "pixel_size": 0.1}, ["shape='mask' needs filename"]),
    "mask-without-pixel-size": ({"shape": "mask", "filename": "@mask_png"}, ["needs pixel_size"]),
    "mask-missing": ({"shape": "mask", "filename": "@missing_png", "pixel_size": 0.1},
                     ["missing.png", "no such file"]),
    "mask-empty": ({"shape": "mask", "filename": "@empty_png", "pixel_size": 0.1}, ["empty.png", "empty file"]),
    "mask-corrupt": ({"shape": "mask", "filename": "@corrupt_png", "pixel_size": 0.1},
                     ["corrupt.png", "could not be read"]),
    "mask-no-opening": ({"shape": "mask", "filename": "@black_png", "pixel_size": 0.1},
                        ["black.png", "no transmitting pixel"]),
    "points-without-file": ({"process": "points"}, ["process='points' needs filename"]),
    "points-missing": ({"process": "points", "filename": "@missing_txt"}, ["missing.txt", "does not exist"]),
    "points-empty": ({"process": "points", "filename": "@empty_txt"}, ["empty.txt", "contains no points"]),
    "points-with-mask-need-own-file": (
        {"shape": "mask", "filename": "@mask_png", "pixel_size": 0.1, "process": "points"},
        ["points_filename", "filename is the mask image"]),
    "points-filename-missing": ({"process": "points", "points_filename": "@missing_txt"},
                                ["missing.txt", "does not exist"]),
}


def _resolve(params, files):
    return {k: (files[v[1:]] if isinstance(v, str) and v.startswith("@") else v) for k, v in params.items()}


@pytest.mark.parametrize("name", list(PARAM_CASES))
def test_parameters_reject(files, name):
    params, fragments = PARAM_CASES[name]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", corona.CoronaWarning)
        with pytest.raises(corona.CoronaError) as info:
            material_from_parameters(**_resolve(params, files))
    _check_line(str(info.value), fragments)


def test_parameters_unknown_name():
    with pytest.raises(corona.CoronaError) as info:
        material_from_parameters(radius=1.0, bogus=3)
    _check_line(str(info.value), ["bogus", "known:", "radius"])


def test_mask_and_point_file_together(files):
    """``filename`` is the mask image; ``points_filename`` the point file."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", corona.CoronaWarning)
        m = material_from_parameters(shape="mask", filename=files["mask_png"], pixel_size=0.05,
                                     process="points", points_filename=files["points_csv"])
        assert isinstance(m.shape, corona.Mask) and isinstance(m.process, corona.PointSet)
        assert len(m.process.points) == 60
        # the old meaning of `filename` (point file for a non-mask shape) still works
        m2 = material_from_parameters(radius=0.3, process="points", filename=files["points_csv"])
        assert len(m2.process.points) == 60


# --------------------------------------------------------------------------
# plugin parameters through mi.load_dict
# --------------------------------------------------------------------------
def _corona_line(err: Exception) -> str:
    """The one-line CoronaError inside Mitsuba's wrapped plugin-load error."""
    lines = [ln for ln in str(err).splitlines() if ln.strip()]
    assert lines and lines[-1].startswith("CoronaError: "), str(err)
    assert sum(ln.startswith("CoronaError: ") for ln in lines) == 1
    return lines[-1][len("CoronaError: "):]


PLUGIN_CASES = dict(PARAM_CASES)
PLUGIN_CASES.update({
    "radius-not-a-number": ({"radius": "big"}, ["radius='big'", "not a number"]),
    "unknown-parameter": ({"bogus": 1.0}, ["unknown parameter 'bogus'", "known:"]),
})


@pytest.mark.parametrize("name", list(PLUGIN_CASES))
def test_plugin_rejects(mi_variant, files, name):
    import mitsuba as mi
    params, fragments = PLUGIN_CASES[name]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", corona.CoronaWarning)
        with pytest.raises(Exception) as info:
            mi.load_dict({"type": "corona", **_resolve(params, files)})
    _check_line(_corona_line(info.value), fragments)


def test_plugin_accepts_mask_with_points(mi_variant, files):
    import mitsuba as mi
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", corona.CoronaWarning)
        b = mi.load_dict({"type": "corona", "shape": "mask", "filename": files["mask_png"], "pixel_size": 0.05,
                          "process": "points", "points_filename": files["points_csv"]})
    assert "Mask" in str(b) and "PointSet" in str(b)


# --------------------------------------------------------------------------
# CLI
# --------------------------------------------------------------------------
# (tests/apps/test_cli.py covers: --radius -2, unknown options and commands, a
# missing scene file, bad -D values and plugin parameters inside a scene)
CLI_CASES = {
    "radius-nan": (["lobe", "--radius", "nan"], ["radius=nan", "[0.001, 1000] µm"]),
    "radius-not-a-number": (["lobe", "--radius", "big"], ["--radius", "'big'", "not a valid float"]),
    "unknown-process": (["lobe", "--process", "blob"], ["--process", "'blob'", "'poisson'"]),
    "unknown-shape": (["lobe", "--shape", "blob"], ["--shape", "'blob'", "'circle'"]),
    "hard-disk-eta": (["lobe", "--area-fraction", "0.9"], ["area_fraction=0.9", "≤ 0.72"]),
    "rsa-jamming": (["lobe", "--process", "rsa", "--area-fraction", "0.6"], ["area_fraction=0.6", "(0, 0.547]"]),
    "wavelength": (["lobe", "--json", "--wavelength", "nan"], ["wavelength=nan", "[360, 830] nm"]),
    "mask-missing": (["lobe", "--shape", "mask", "--filename", "@missing_png", "--pixel-size", "0.1"],
                     ["missing.png", "no such file"]),
    "mask-empty": (["lobe", "--shape", "mask", "--filename", "@empty_png", "--pixel-size", "0.1"],
                   ["empty.png", "empty file"]),
    "mask-corrupt": (["lobe", "--shape", "mask", "--filename", "@corrupt_png", "--pixel-size", "0.1"],
                     ["corrupt.png", "could not be read"]),
    "mask-no-opening": (["lobe", "--shape", "mask", "--filename", "@black_png", "--pixel-size", "0.1"],
                        ["black.png", "no transmitting pixel"]),
    "points-missing": (["lobe", "--process", "points", "--filename", "@missing_txt"],
                       ["missing.txt", "does not exist"]),
    "points-empty": (["lobe", "--process", "points", "--filename", "@empty_txt"],
                     ["empty.txt", "contains no points"]),
    "points-header-only": (["lobe", "--process", "points", "--filename", "@header_csv"],
                           ["header.csv", "contains no points"]),
    "scene-empty": (["render", "@empty_xml"], ["empty.xml", "is empty"]),
}


@pytest.mark.parametrize("name", list(CLI_CASES))
def test_cli_rejects(files, name):
    args, fragments = CLI_CASES[name]
    args = [files[a[1:]] if a.startswith("@") else a for a in args]
    result = CliRunner().invoke(cli_main, args)
    assert result.exit_code == 2, (result.output, result.exception)
    err = result.stderr.strip()
    assert err.startswith("corona: error: "), err
    _check_line(err, fragments)
    assert result.stdout == ""


@pytest.mark.slow
@pytest.mark.render
@pytest.mark.parametrize("scene,fragments", [
    ("corrupt_xml", ["corrupt.xml", "Error parsing"]),
    ("bad_bsdf_xml", ["bad_bsdf.xml (line 3", "radius=-1.0 is out of range", "[0.001, 1000] µm"]),
])
def test_cli_render_bad_scene_one_line(files, scene, fragments):
    """The real console entry point (a separate process): Mitsuba's errors come out as one line."""
    proc = subprocess.run([sys.executable, "-m", "corona.apps.cli", "render", files[scene], "--spp", "1",
                           "--out", os.path.join(files["dir"], "out")],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2, proc.stderr
    err = proc.stderr.strip()
    assert err.startswith("corona: error: "), err
    _check_line(err, fragments)


@pytest.mark.slow
@pytest.mark.render
def test_cli_unusable_variant_is_one_line(files):
    import corona._environment as env
    if env.has_cuda():
        pytest.skip("a CUDA GPU is usable here")
    result = CliRunner().invoke(cli_main, ["render", files["corrupt_xml"], "--variant", "cuda_ad_spectral"])
    assert result.exit_code == 2
    _check_line(result.stderr.strip(), ["variant='cuda_ad_spectral'", "needs a CUDA GPU"])


# --------------------------------------------------------------------------
# questionable but computable: warn once, don't fail
# --------------------------------------------------------------------------
def test_small_radius_warns_once_per_process(monkeypatch):
    monkeypatch.setattr(material_module, "_small_radius_warned", False)
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        corona.Material(corona.Circle(5.0), corona.Poisson(0.2))        # 5 µm: fine
        assert not [w for w in rec if issubclass(w.category, corona.CoronaWarning)]
        m = corona.Material(corona.Circle(0.3), corona.Poisson(0.2))    # 0.3 µm < 2 × 830 nm
        corona.Material(corona.Circle(0.2), corona.HardDisk(0.3))
        corona.Material(corona.Square(0.2), corona.Poisson(0.2))
    hits = [w for w in rec if issubclass(w.category, corona.CoronaWarning)]
    assert len(hits) == 1, [str(w.message) for w in hits]
    msg = str(hits[0].message)
    _check_line(msg, ["Circle(radius=0.3)", "0.3 µm", "2 wavelengths", "1.66 µm", "830 nm"])
    assert np.isfinite(m.lobe([[0.0, 0.0]], 550.0)).all()   # still computed


def test_small_radius_rule_uses_the_equivalent_radius(monkeypatch):
    limit = material_module.SMALL_RADIUS_WAVELENGTHS * 0.83
    assert limit == pytest.approx(1.66)
    for shape, warns in [(corona.Circle(1.65), True), (corona.Circle(1.67), False),
                         (corona.Square(0.5 * 1.66 * math.sqrt(math.pi) * 0.99), True),   # side √π × 1.66 µm
                         (corona.Square(0.5 * 1.66 * math.sqrt(math.pi) * 1.01), False)]:
        monkeypatch.setattr(material_module, "_small_radius_warned", False)
        with warnings.catch_warnings(record=True) as rec:
            warnings.simplefilter("always")
            corona.Material(shape, corona.Poisson(0.1))
        assert any(issubclass(w.category, corona.CoronaWarning) for w in rec) == warns, shape


def test_cli_doctor_reports_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("CORONA_CACHE_DIR", str(tmp_path))
    result = CliRunner().invoke(cli_main, ["doctor"])
    assert result.exit_code == 0, result.output
    out = result.stdout
    for key in ["corona ", "python ", "mitsuba ", "variants: ", "libLLVM: ", "LLVM backend usable: ",
                "GPU (CUDA backend): ", "default variant: ", "table cache: "]:
        assert any(line.startswith(key) for line in out.splitlines()), (key, out)
    assert "llvm_ad_spectral" in out
    assert str(tmp_path) in out and "0 tables" in out and "MB" in out


def test_cli_doctor_survives_an_unusable_cache(tmp_path, monkeypatch):
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    monkeypatch.setenv("CORONA_CACHE_DIR", str(blocker / "cache"))
    result = CliRunner().invoke(cli_main, ["doctor"])
    assert result.exit_code == 0, result.output
    assert "table cache: NOT usable" in result.stdout


def test_unusable_cache_folder_still_builds(tmp_path, monkeypatch):
    blocker = tmp_path / "a-file"
    blocker.write_text("")
    monkeypatch.setenv("CORONA_CACHE_DIR", str(blocker / "cache"))
    with pytest.warns(RuntimeWarning, match="table cache unusable"):
        m = corona.Material(corona.Circle(2.0), corona.Poisson(0.2))
        assert m.diffuse_transmittance() > 0
