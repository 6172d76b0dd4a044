"""Fuzz test over XML scenes and CLI arguments (issue 15).

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
import os
import random
import re
import warnings

import numpy as np
import pytest
from click.testing import CliRunner

import corona
from corona.cli import main as cli_main
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

