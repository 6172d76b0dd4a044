"""Fuzz test over XML scenes and CLI arguments.

A fixed, derandomized set of cases (``random.Random(15)``): corona BSDF
properties of random types and values in a tiny scene (sometimes without its
integrator, emitter or sensor, with an empty film, cut in half),
``corona lobe`` options,
``corona render`` options (``--spp --seed --exposure --name --out -D``) and the
table cache.  Whatever the input:

* the exit code is 0 or 2 (never a traceback's 1, a crash's 136);
* with 2, stderr is exactly one line, ``corona: error: ...``; with 0, every
  line on stderr (but the progress bar) starts with ``corona:`` (the variant,
  a warning: one line each);
* no file appears outside ``--out`` (the test's folder is watched; the
  command runs in a folder of its own);
* images and numbers that come back are finite and non-negative (for the
  linear sRGB image: its luminance; a single spectral sample's colour can lie
  outside the sRGB gamut, a channel below 0).
"""
from __future__ import annotations

import json
import math
import os
import random
import re
import warnings

import numpy as np
import pytest
from click.testing import CliRunner

import corona
from corona.apps.cli import main as cli_main
from corona.parameters import PARAMETERS

from bsdf_checks import layer_scene

N_CASES = 60

FLOATS = ["0", "-1", "1e-300", "0.001", "0.05", "0.3", "0.5", "1", "5", "24.9", "1000", "1000.5", "1e20",
          "1e308", "nan", "inf", "-inf", "abc", "", "0x10", "1,5"]
INTS = ["2", "3", "6", "50", "51", "0", "-5", "1e9", "nan", "7.5", "abc"]
TEXTS = ["", "/dev/zero", "@dir", "@missing", "@points", "@mask", "@secret", "../../x",
         "circle:5:1, square:4:1", "circle:5:1e308, circle:6:1e308", "x:1:1", "circle:1e20:1", "circle:5"]
SPP = ["0", "1", "2", "-3", "1e3", "65537", "abc", "1000000000000"]
SEEDS = ["0", "1", "4294967", "4294968", "-1", "x"]
EXPOSURES = ["1", "0", "-1", "nan", "inf", "1e-30", "abc"]
NAMES = ["x", "../x", "/abs/x", "", ".", "a/b", "ok_name", "..", "n\\x"]
OUTS = ["@out", "", "@file", "@file/sub", "/proc/x", "@out/deeper"]
DEFINES = ["spp=0", "spp=1", "res=0", "res=4", "radius=abc", "nope=1", "radius", "=1", "r=1e20"]



def _valid(p, rng):
    """A value inside the documented range (small sizes: the tables stay quick)."""
    if p.kind in ("float", "int"):
        lo, hi = max(p.low, 1e-3 if p.unit == "µm" else p.low), min(p.high, 20.0 if p.unit == "µm" else p.high)
        v = lo + (hi - lo) * rng.random() ** 2
        return str(int(round(v))) if p.kind == "int" else f"{v:.4g}"
    if p.kind == "choice":
        return rng.choice(p.choices)
    return rng.choice(["@points", "@mask", "circle:5:1, square:4:1"])


def _value(p, rng):
    if rng.random() < 0.7:
        return _valid(p, rng)
    if p.kind == "float":
        return rng.choice(FLOATS)
    if p.kind == "int":
        return rng.choice(INTS)
    if p.kind == "choice":
        return rng.choice(list(p.choices) * 3 + ["", "blob", "CIRCLE"])
    return rng.choice(TEXTS)


def _cases():
    rng = random.Random(15)
    specs = [p for p in PARAMETERS]
    cases = []
    for i in range(N_CASES):
        kind = ["scene", "scene", "lobe", "lobe", "render", "tables"][i % 6]
        if kind == "scene":
            props = {}
            for p in rng.sample(specs, rng.randint(1, 4)):
                tag = rng.choice(["float", "integer", "string", "boolean"] if rng.random() < 0.3 else
                                 [{"float": "float", "int": "integer"}.get(p.kind, "string")])
                props[p.name] = (tag, _value(p, rng))
            mutation = rng.choice(["", "", "", "", "no-integrator", "no-emitter", "no-sensor", "film-0",
                                   "not-xml", "wrong-version"])
            cases.append(("scene", props, (rng.choice(["1", "2"]), mutation)))
        elif kind == "lobe":
            opts = {p.name: _value(p, rng) for p in rng.sample([p for p in specs if not p.plugin_only],
                                                               rng.randint(1, 4))}
            cases.append(("lobe", opts, rng.random() < 0.9))   # --json, or a picture
        elif kind == "render":
            opts = {}
            for flag, pool in (("--spp", SPP), ("--seed", SEEDS), ("--exposure", EXPOSURES),
                               ("--name", NAMES), ("--out", OUTS), ("-D", DEFINES)):
                if rng.random() < 0.45:
                    opts[flag] = rng.choice(pool)
            cases.append(("render", opts, None))
        else:
            cases.append(("tables", rng.choice(["info", "clear"]), rng.choice(["@cache", "@file", "@newdir"])))
    return cases


CASES = _cases()


@pytest.fixture(scope="module")
def inputs(tmp_path_factory):
    """Files the fuzzed values point at (a mask, a point file, a secret, a folder)."""
    import imageio.v3 as iio
    d = tmp_path_factory.mktemp("fuzz-inputs")
    img = np.zeros((24, 24), np.uint8)
    img[4:20, 6:18] = 255
    iio.imwrite(d / "mask.png", img)
    rng = np.random.default_rng(0)
    np.savetxt(d / "points.txt", rng.random((40, 2)) * 200.0)
    (d / "secret.txt").write_text("root:x:0:0:hunter2:/root:/bin/sh\n")
    return {"@dir": str(d), "@missing": str(d / "missing.png"), "@points": str(d / "points.txt"),
            "@mask": str(d / "mask.png"), "@secret": str(d / "secret.txt")}


def _tree(folder):
    out = set()
    for root, dirs, files in os.walk(folder):
        out.update(os.path.join(root, f) for f in files + dirs)
    return out


def _stderr_lines(text: str):
    """Lines on stderr without the progress bar (tqdm redraws with carriage returns)."""
    lines = []
    for chunk in re.split(r"[\r\n]", text):
        if not chunk.strip() or re.match(r"^\s*render \S*:\s*\d+%\|", chunk):
            continue
        lines.append(chunk)
    return lines


@pytest.mark.slow
@pytest.mark.render
@pytest.mark.parametrize("case", range(N_CASES))
def test_fuzz(case, tmp_path, monkeypatch, inputs, mi_variant):
    import mitsuba as mi
    mi.set_variant(mi_variant)
    corona.register()
    kind, a, b = CASES[case]
    work = tmp_path / "cwd"
    work.mkdir()
    monkeypatch.chdir(work)
    out = tmp_path / "out"
    (tmp_path / "file").write_text("a file")
    fill = {**inputs, "@out": str(out), "@file": str(tmp_path / "file"), "@cache": str(tmp_path / "cache"),
            "@newdir": str(tmp_path / "cache" / "new")}

    def sub(v):
        v = str(v)
        for k in sorted(fill, key=len, reverse=True):
            v = v.replace(k, fill[k])
        return v

    out_dirs = [out]
    if kind == "scene":
        props = "\n".join(f'            <{tag} name="{name}" value="{sub(v)}"/>'
                          for name, (tag, v) in a.items())
        text = layer_scene(props, spp=1, res=4)
        spp, mutation = b
        text = {"no-integrator": lambda t: re.sub(r"<integrator.*?</integrator>", "", t, flags=re.S),
                "no-emitter": lambda t: re.sub(r"<emitter.*?</emitter>", "", t, flags=re.S),
                "no-sensor": lambda t: re.sub(r"<sensor.*?</sensor>", "", t, flags=re.S),
                "film-0": lambda t: t.replace('name="res" value="4"', 'name="res" value="0"'),
                "not-xml": lambda t: t[: len(t) // 2],
                "wrong-version": lambda t: t.replace('version="3.0.0"', 'version="9.9"')}.get(
            mutation, lambda t: t)(text)
        scene = tmp_path / "scene.xml"
        scene.write_text(text)
        args = ["render", str(scene), "--spp", spp, "--out", str(out), "--name", "img"]
    elif kind == "lobe":
        args = ["lobe"] + [x for k, v in a.items() for x in (f"--{k.replace('_', '-')}", sub(v))]
        args += ["--json"] if b else ["--out", str(out / "lobe.png")]
        out.mkdir()
    elif kind == "render":
        scene = tmp_path / "scene.xml"
        scene.write_text(layer_scene('            <float name="radius" value="$radius"/>', spp=1, res=4))
        args = ["render", str(scene)] + [x for k, v in a.items() for x in (k, sub(v))]
        if "--out" not in a:
            args += ["--out", str(out)]
        elif sub(a["--out"]).startswith(str(tmp_path)):
            out_dirs = [sub(a["--out"])]
        args += ["--spp", "1"] if "--spp" not in a else []
    else:
        monkeypatch.setenv("CORONA_CACHE_DIR", sub(b))
        os.makedirs(tmp_path / "cache", exist_ok=True)
        (tmp_path / "cache" / "user-data.npz").write_bytes(b"mine")
        args = ["tables", a]
        out_dirs = [tmp_path / "cache"]

    before = _tree(tmp_path)
    with warnings.catch_warnings():
        warnings.simplefilter("default")
        r = CliRunner().invoke(cli_main, args)
    where = f"case {case}: corona {' '.join(args)}"

    assert r.exit_code in (0, 2), (where, r.exit_code, r.output, r.exception)
    lines = _stderr_lines(r.stderr)
    if r.exit_code == 2:
        assert len(lines) == 1 and lines[0].startswith("corona: error: "), (where, r.stderr)
        assert "hunter2" not in lines[0]
    else:   # progress, the variant, and each distinct warning: one line each
        assert all(ln.startswith("corona: ") for ln in lines), (where, r.stderr)
    assert "Traceback" not in r.output

    new = _tree(tmp_path) - before
    stray = [f for f in new if not any(f == str(d) or f.startswith(str(d) + os.sep) for d in out_dirs)]
    assert not stray, (where, stray)
    assert not os.listdir(work), where
    if kind == "tables":
        assert (tmp_path / "cache" / "user-data.npz").read_bytes() == b"mine"

    if r.exit_code == 0 and kind in ("scene", "render"):
        exrs = [f for f in new if f.endswith(".exr")]
        assert len(exrs) == 1, (where, new)
        img = np.array(mi.Bitmap(exrs[0]), dtype=np.float64)
        assert np.all(np.isfinite(img)), where
        # linear sRGB keeps out-of-gamut colours of single spectral samples (a channel < 0);
        # the luminance, the CIE Y of non-negative spectra, cannot be negative
        Y = img @ np.array([0.2126, 0.7152, 0.0722])
        assert np.all(Y >= -1e-5 * max(1.0, img.max())), (where, Y.min())
    if r.exit_code == 0 and kind == "lobe" and b:
        o = json.loads(r.stdout)
        for key in ("lobe", "form_factor_Ta", "structure_factor_Ts", "diffuse_transmittance",
                    "coherent_transmittance", "reflectance"):
            v = np.asarray(o[key], dtype=np.float64)
            assert np.all(np.isfinite(v)) and np.all(v >= 0), (where, key)



# --------------------------------------------------------------------------
# the services: the designer's HTTP API, `corona sweep`'s executor options, `corona fit`
# on hostile images, and fresh-process scene loads in a scalar variant.  Each sweep is a
# fixed, derandomized set of cases bounded in time (docs/robustness.md lists the promises).
# --------------------------------------------------------------------------
N_DESIGNER, N_SWEEP, N_FIT, N_SCALAR = 30, 16, 20, 3


def _one_line(text: str) -> bool:
    return "\n" not in text.strip() and "Traceback" not in text


def _designer_cases():
    rng = random.Random(24)
    specs = [p for p in PARAMETERS if not p.plugin_only]
    view = {"size": ["16", "32", "0", "-1", "1e9", "abc"], "field": ["1", "5", "0", "nan", "90", "1e9"],
            "temperature": ["3000", "0", "nan", "1e9"], "exposure": ["1", "0", "nan", "inf", "-1"],
            "kernel_size": ["3", "9", "10", "1e6", "abc"], "pixel_scale": ["0.5", "5", "0", "nan"]}
    cases = []
    for i in range(N_DESIGNER):
        endpoint = ["/api/corona.png", "/api/profiles", "/api/material", "/api/kernel.png", "/api/fit",
                    "/api/upload"][i % 6]
        q = {p.name: _value(p, rng) for p in rng.sample(specs, rng.randint(0, 3))}
        for k in rng.sample(sorted(view), rng.randint(0, 2)):
            q[k] = rng.choice(view[k])
        q.setdefault("size", "16")
        cases.append((endpoint, q, rng.randrange(6)))
    return cases


DESIGNER_CASES = _designer_cases()


@pytest.fixture(scope="module")
def designer():
    pytest.importorskip("starlette")
    from starlette.testclient import TestClient

    from corona.apps.designer import create_app
    app = create_app(timeout=3.0)
    with TestClient(app, base_url="http://127.0.0.1", raise_server_exceptions=False) as c:
        yield c, app


@pytest.mark.slow
@pytest.mark.parametrize("case", range(N_DESIGNER))
def test_fuzz_designer(case, designer, inputs):
    """Every answer is 200, or 400/404/413/503 with one line that shows no server path; never
    500; never more than MAX_CONCURRENT computations at once."""
    from bsdf_checks import png_claiming

    from corona.apps.designer import app as app_module
    from corona.model.tabulated import cache_dir
    c, app = designer
    endpoint, q, variant = DESIGNER_CASES[case]
    q = {k: v for k, v in q.items() if not str(v).startswith("@")}       # files go through uploads
    if endpoint == "/api/upload":
        body = [png_claiming(30000, 30000), png_claiming(100, 100), b"", b"\x89PNG\r\n", b"1 2\n3 4\n" * 10,
                b"\x93NUMPY garbage"][variant]
        kind = ["photo", "mask", "points", "photo", "points", "points"][variant]
        res = c.post(f"/api/upload?kind={kind}&name=f.png", content=body)
    elif endpoint == "/api/fit":
        body = [b"[" * 60000, b"{", b"{}", json.dumps({"photo": "../../etc/passwd", "fov": 30}).encode(),
                json.dumps({"photo": "0" * 32 + ".png", "fov": "nan"}).encode(), b'"x"'][variant]
        res = c.post("/api/fit", content=body)
    else:
        res = c.get(endpoint, params=q)
    where = f"case {case}: {endpoint} {q}"
    assert res.status_code in (200, 400, 404, 413, 503), (where, res.status_code, res.text[:300])
    if res.status_code != 200:
        msg = res.json()["error"]
        assert _one_line(msg), (where, msg)
        assert cache_dir() not in msg and "Traceback" not in msg, (where, msg)
    elif res.headers["content-type"] == "application/json":
        json.loads(res.text)          # (no NaN: _jsonable writes null)
    assert app.state.slots.peak <= app_module.MAX_CONCURRENT


def _sweep_cases():
    rng = random.Random(240)
    schedulers = ["@silent", "@closed", "http://127.0.0.1:9", "tcp://h:port", "ws://", "127.0.0.1", None]
    cases = []
    for _ in range(N_SWEEP):
        opts = []
        s = rng.choice(schedulers)
        if s is not None:
            opts += ["--scheduler", s]
        else:
            opts += ["--workers", rng.choice(["0", "-1", "abc", "0"])]
        opts += ["--timeout", rng.choice(["inf", "nan", "0", "-1", "abc", "1", "1", "1", "1e308"])]
        # half the cases a valid grid: they reach the executor (the scheduler, the workers)
        opts += ["-D", rng.choice(["nosuch=1,2", "radius=", "radius", "=1", "radius=2,3", "radius=2,3"])]
        cases.append(opts)
    return cases


SWEEP_CASES = _sweep_cases()


@pytest.mark.render
@pytest.mark.slow
@pytest.mark.parametrize("case", range(N_SWEEP))
def test_fuzz_sweep(case, tmp_path):
    """Bad executor options and hostile schedulers: exit 2 with one line within --timeout
    (+ start-up), nothing rendered."""
    import socket
    import threading
    import time
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(8)
    held = []

    def accept():            # accept, hold, never answer
        try:
            while True:
                held.append(srv.accept()[0])
        except OSError:
            return
    threading.Thread(target=accept, daemon=True).start()
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        closed = s.getsockname()[1]
    fill = {"@silent": f"tcp://127.0.0.1:{srv.getsockname()[1]}", "@closed": f"tcp://127.0.0.1:{closed}"}
    opts = [fill.get(o, o) for o in SWEEP_CASES[case]]
    scene = tmp_path / "s.xml"
    scene.write_text(layer_scene(spp=1, res=4))
    t0 = time.monotonic()
    try:
        r = CliRunner().invoke(cli_main, ["sweep", str(scene), "--out", str(tmp_path / "o"), "--no-progress",
                                          *opts])
    finally:
        srv.close()
        for c in held:
            c.close()
    where = f"case {case}: corona sweep {' '.join(opts)}"
    if r.exit_code == 0:          # --workers 0 and a valid grid: rendered in this process
        assert "--workers" in opts and "radius=2,3" in opts, (where, r.output)
        assert len(list((tmp_path / "o").glob("*.exr"))) == 2, where
        return
    assert r.exit_code == 2, (where, r.exit_code, r.output, r.exception)
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("corona: error: "), (where, r.stderr)
    assert time.monotonic() - t0 < 1.0 + 5, where        # --timeout 1 (or refused), + start-up
    assert not list((tmp_path / "o").glob("*.exr"))


def _fit_images():
    """Hostile photographs: (name, array or bytes, fit options)."""
    from bsdf_checks import png_claiming
    rng = np.random.default_rng(24)
    h = w = 64
    yy, xx = np.mgrid[:h, :w]
    lamp = np.exp(-((xx - 30.0) ** 2 + (yy - 33.0) ** 2) / 8.0) * 20.0
    lamp_srgb = (np.clip(lamp, 0, 1) ** (1 / 2.2) * 255).astype(np.uint8)
    out = [
        ("zeros", np.zeros((h, w, 3), np.uint8), {}),
        ("white", np.full((h, w, 3), 255, np.uint8), {}),
        ("noise", rng.integers(0, 256, (h, w, 3)).astype(np.uint8), {}),
        ("nan", np.full((h, w, 3), np.nan, np.float32), {}),
        ("inf-lamp", np.where(lamp > 10, np.inf, lamp).astype(np.float32), {}),
        ("negative", -lamp.astype(np.float32), {}),
        ("tiny", lamp_srgb[:8, :8], {}),
        ("one-row", lamp_srgb[:1], {}),
        ("4d", lamp_srgb[None, None], {}),
        ("complex", lamp.astype(np.complex64), {}),
        ("bool", lamp > 1, {}),
        ("lamp", lamp_srgb, {"fov_deg": 30.0, "saturation": float("nan")}),
        ("lamp", lamp_srgb, {"fov_deg": float("inf")}),
        ("lamp", lamp_srgb, {"fov_deg": 30.0, "radius_range": (5.0, 1.0)}),
        ("lamp", lamp_srgb, {"fov_deg": 30.0, "bootstrap": -3}),
        ("lamp", lamp_srgb, {"fov_deg": 30.0, "temperature": float("nan")}),
        ("header-12000", png_claiming(12000, 12000), {}),
        ("header-30000", png_claiming(30000, 30000), {}),
        ("truncated", png_claiming(64, 64)[:20], {}),
        ("text", b"not an image at all", {}),
    ]
    return out[:N_FIT]


FIT_CASES = _fit_images()


@pytest.mark.slow
@pytest.mark.parametrize("case", range(N_FIT), ids=[c[0] for c in FIT_CASES])
def test_fuzz_fit(case, tmp_path):
    """A hostile photograph or option: a fit with finite numbers, or one CoronaError line."""
    from corona import CoronaError
    from corona.apps.fit import fit_photograph
    name, image, opts = FIT_CASES[case]
    if isinstance(image, bytes):
        path = tmp_path / f"{name}.png"
        path.write_bytes(image)
        image = str(path)
    opts = {"fov_deg": 30.0, **opts}
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            result = fit_photograph(image, **opts)
    except CoronaError as err:
        assert _one_line(str(err)) and str(err), (name, str(err))
        return
    d = result.to_dict()
    assert math.isfinite(d["radius"]) and d["radius"] > 0, (name, d)


_SCALAR_LOAD = """
import sys, corona, mitsuba as mi
mi.set_variant("scalar_spectral")
corona.register()
mi.load_file(sys.argv[1])
print("loaded")
"""


@pytest.mark.slow
@pytest.mark.parametrize("case", range(N_SCALAR))
def test_fuzz_scalar_scene_loads(case, tmp_path):
    """Accepted layers of random families in a scene with an area light and a constant sky
    written after them: each loads in a fresh scalar_spectral process with a fresh cache."""
    import subprocess
    import sys
    rng = random.Random(2400 + case)
    props = {"radius": f"{rng.uniform(0.5, 8):.3g}", "area_fraction": f"{rng.uniform(0.05, 0.5):.3g}",
             "shape": rng.choice(["circle", "square", "ellipse", "circle"]),
             "process": rng.choice(["poisson", "hard-disk", "rsa"])}
    if rng.random() < 0.5:
        props["substrate"] = "glass"
    xml = "".join(f'<{"float" if k in ("radius", "area_fraction") else "string"} name="{k}" value="{v}"/>'
                  for k, v in props.items())
    scene = tmp_path / "s.xml"
    scene.write_text(f"""<scene version="3.0.0"><integrator type="path"/>
<sensor type="perspective"><film type="hdrfilm"><integer name="width" value="4"/>
<integer name="height" value="4"/></film></sensor>
<shape type="rectangle"><bsdf type="corona">{xml}</bsdf></shape>
<shape type="rectangle"><transform name="to_world"><scale value="0.2"/><translate z="2"/></transform>
<emitter type="area"><rgb name="radiance" value="10"/></emitter></shape>
<emitter type="constant"><rgb name="radiance" value="1"/></emitter></scene>""")
    env = {**os.environ, "CORONA_CACHE_DIR": str(tmp_path / "cache")}
    p = subprocess.run([sys.executable, "-c", _SCALAR_LOAD, str(scene)], capture_output=True, text=True,
                       timeout=300, env=env)
    assert p.returncode == 0 and "loaded" in p.stdout, (props, p.stderr[-500:])
