"""Sweeps: many independent jobs (renders, validation cases, table rows) on Dask.

A *sweep* renders a scene at every point of the Cartesian product of ``-D``
value lists (``corona sweep scenes/sweep_radius.xml -D radius=2.5,5,10``),
one EXR (linear sRGB) + PNG (tonemapped sRGB) per point, named by its
parameters, plus a contact sheet and a JSON index.  The jobs run through one
:class:`Executor` (:mod:`corona._executor`), which is also what ``corona validate`` (one
case per task), the table generators of the reference tier (one row or one chunk of runs
per task) and ``make gallery`` use:

* ``workers=0``: in this process, one job after the other (no Dask needed);
* no ``scheduler``: a ``distributed.LocalCluster`` on this machine, one worker
  process per job slot, each running one job at a time (one thread per
  worker) with Dr.Jit's thread pool set to ``cores // workers_on_the_host``
  so that the workers together use the cores once, not ``workers`` times;
* ``scheduler="tcp://host:8786"``: an existing Dask cluster (``dask
  scheduler`` + ``dask worker`` on several machines; docs/cli.md "Sweeps on
  several machines").  The same thread rule applies per host.

Workers compute and send results back; only this process writes files, so
the workers need the corona installation and the *inputs* (scene files at
the same path, e.g. a shared directory), not write access to ``--out``.
Every worker process sets the Mitsuba variant and registers the plugin
itself before its first render (Mitsuba's variant is per process).

Dask's ``distributed`` is the ``sweep`` extra (``pip install
'corona-bsdf[sweep]'``); ``import corona`` never imports it.
"""
from __future__ import annotations

import collections
import dataclasses
import itertools
import json
import os
import re
import socket
import tempfile
import time

import numpy as np

from corona._executor import WORKER, Executor, Outcome
from corona._validation import CoronaError

_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")


# ==========================================================================
# the sweep's points
# ==========================================================================
def parse_defines(defines) -> dict:
    """``["radius=2.5,5", "fov=16"]`` → ``{"radius": ["2.5", "5"], "fov": ["16"]}``.

    Each item is ``NAME=V1,V2,...``: ``NAME`` a scene parameter (``$NAME`` /
    ``<default name="NAME">`` of the XML), the values non-empty and distinct.
    Raises :class:`CoronaError` naming the offending item.
    """
    grid = {}
    for item in defines or []:
        if "=" not in item:
            raise CoronaError(f"-D {item!r}: expected NAME=V1,V2,... (e.g. -D radius=2.5,5,10)")
        name, values = (s.strip() for s in item.split("=", 1))
        if not _NAME.match(name):
            raise CoronaError(f"-D {item!r}: parameter name {name!r} must be a letter or _ followed by "
                              "letters, digits or _")
        if name in grid:
            raise CoronaError(f"-D {item!r}: parameter {name!r} is given twice; list all its values "
                              f"in one -D {name}=V1,V2,...")
        vals = [v.strip() for v in values.split(",")]
        if any(not v for v in vals):
            raise CoronaError(f"-D {item!r}: empty value in the list; expected {name}=V1,V2,... "
                              "with no empty entries")
        dup = sorted({v for v in vals if vals.count(v) > 1})
        if dup:
            raise CoronaError(f"-D {item!r}: value {dup[0]!r} appears twice")
        grid[name] = vals
    return grid


def sweep_points(grid: dict) -> list:
    """The Cartesian product of ``grid`` (``{name: [values]}``) as a list of
    ``{name: value}`` dicts, the last parameter varying fastest."""
    names = list(grid)
    return [dict(zip(names, combo)) for combo in itertools.product(*(grid[n] for n in names))]


def _safe(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9.+\-]", "_", str(text))


def point_name(stem: str, point: dict) -> str:
    """File stem of one point: ``stem_radius=2.5_fov=16`` (characters other than
    letters, digits, ``.``, ``+``, ``-`` replaced by ``_``)."""
    return "_".join([stem] + [f"{_safe(k)}={_safe(v)}" for k, v in point.items()])


def point_label(point: dict) -> str:
    """``radius=2.5, fov=16`` (how a point is named in messages and on the contact sheet)."""
    return ", ".join(f"{k}={v}" for k, v in point.items()) or "(scene defaults)"


def scene_parameters(path: str) -> set:
    """Names a scene file takes: its ``<default name=...>`` and every ``$NAME`` it uses."""
    with open(path, encoding="utf-8", errors="replace") as f:
        text = f.read()
    text = re.sub(r"<!--.*?-->", "", text, flags=re.S)     # comments mention $names too
    return set(re.findall(r"\$([A-Za-z_]\w*)", text)) | set(
        re.findall(r"<default\s+name\s*=\s*[\"']([^\"']+)[\"']", text))


def check_out_dir(out_dir: str) -> str:
    """Create ``out_dir`` if needed and check that a file can be written there."""
    try:
        os.makedirs(out_dir, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=out_dir, prefix=".corona-write-test-"):
            pass
    except OSError as err:
        raise CoronaError(f"--out {out_dir!r} is not a writable folder ({err.strerror or err})") from None
    return out_dir


# ==========================================================================
# rendering one point (runs on a worker)
# ==========================================================================
def _prepare_renderer(variant: str | None) -> str:
    """Set Dr.Jit's thread count (on a worker), the variant, and register the plugin
    in this process (once per variant)."""
    if "threads" in WORKER and not WORKER.get("threads_set"):
        from corona import _environment  # noqa: F401  (libLLVM before drjit)
        import drjit as dr
        dr.set_thread_count(WORKER["threads"])
        WORKER["threads_set"] = True
    key = variant or "<default>"
    if WORKER.get("variant_key") != key:
        from corona.apps.render import setup_variant
        WORKER["variant"] = setup_variant(variant)
        WORKER["variant_key"] = key
    else:
        import mitsuba as mi
        if mi.variant() != WORKER["variant"]:   # someone switched it since
            from corona.apps.render import setup_variant
            setup_variant(WORKER["variant"])
    return WORKER["variant"]


def render_point(scene: str, defines: dict, spp: int | None, seed: int, variant: str | None,
                 label: str = "render") -> dict:
    """Load ``scene`` with ``defines`` and render it; the linear sRGB image and facts.

    Runs on a worker: returns ``{"rgb", "seconds", "spp", "variant", "host",
    "threads"}`` and writes nothing.
    """
    import drjit as dr

    from corona.apps.render import load_scene, render_linear, scene_spp
    if not os.path.isfile(scene):
        raise CoronaError(f"scene file {scene!r} does not exist on worker {socket.gethostname()} "
                          "(workers need the scene files at the same path, e.g. a shared folder)")
    v = _prepare_renderer(variant)
    loaded = load_scene(scene, defines)
    spp = int(spp or scene_spp(loaded))
    rgb, seconds = render_linear(loaded, spp, seed=seed, progress=False, desc=label)
    del loaded
    return {"rgb": rgb, "seconds": seconds, "spp": spp, "variant": v, "host": socket.gethostname(),
            "threads": dr.thread_count()}


@dataclasses.dataclass
class RenderJob:
    """One render: the scene file, its ``-D`` parameters, and how."""
    scene: str
    defines: dict
    label: str
    spp: int | None = None
    seed: int = 0
    variant: str | None = None

    def args(self) -> tuple:
        return (os.path.abspath(self.scene), dict(self.defines), self.spp, self.seed, self.variant,
                self.label)


def render_jobs(jobs, executor: Executor, *, desc: str = "render", progress: bool = True,
                on_result=None) -> list:
    """Render every :class:`RenderJob` through ``executor``; a list of :class:`Outcome`
    whose values are :func:`render_point`'s dicts."""
    jobs = list(jobs)
    return executor.map(render_point, [j.args() for j in jobs], [j.label for j in jobs], desc=desc,
                        progress=progress, on_result=on_result)


# ==========================================================================
# contact sheet
# ==========================================================================
def label_font(size: int):
    """DejaVu Sans (shipped with matplotlib: has µ, ×, °), else Pillow's default.  The file is
    found from matplotlib's package folder (importing matplotlib's font manager cost a sweep
    more than its contact sheet)."""
    import importlib.util

    from PIL import ImageFont
    try:
        spec = importlib.util.find_spec("matplotlib")
        return ImageFont.truetype(os.path.join(spec.submodule_search_locations[0], "mpl-data", "fonts",
                                               "ttf", "DejaVuSans.ttf"), size)
    except Exception:  # noqa: BLE001
        try:
            return ImageFont.load_default(size=size)
        except TypeError:  # Pillow < 10.1
            return ImageFont.load_default()


def contact_sheet(images, labels, columns: int | None = None, gap: int = 4, band: int = 26,
                  font_size: int = 15):
    """8-bit RGB images in a grid (``columns`` per row), each with its label under it.

    Cells are as large as the largest image; a ``None`` image is a grey cell
    (a failed point).  Returns a PIL image.
    """
    from PIL import Image, ImageDraw
    images, labels = list(images), [str(t) for t in labels]
    font = label_font(font_size)
    probe = ImageDraw.Draw(Image.new("RGB", (1, 1)))
    text_w = max([probe.textlength(t, font=font) for t in labels] + [0])
    shapes = [im.shape[:2] for im in images if im is not None] or [(64, 64)]
    ch = max(s[0] for s in shapes)
    cw = max(max(s[1] for s in shapes), int(np.ceil(text_w)) + 8)
    n = len(images)
    cols = max(1, min(columns or int(np.ceil(np.sqrt(n))), n))
    rows = int(np.ceil(n / cols))
    canvas = Image.new("RGB", (cols * cw + gap * (cols - 1), rows * (ch + band) + gap * (rows - 1)),
                       (255, 255, 255))
    draw = ImageDraw.Draw(canvas)
    for k, (im, label) in enumerate(zip(images, labels)):
        x, y = (k % cols) * (cw + gap), (k // cols) * (ch + band + gap)
        if im is None:
            draw.rectangle([x, y, x + cw - 1, y + ch - 1], fill=(160, 160, 160))
        else:
            canvas.paste(Image.fromarray(np.ascontiguousarray(im[..., :3])), (x + (cw - im.shape[1]) // 2, y))
        tw = draw.textlength(label, font=font)
        draw.text((x + (cw - tw) / 2, y + ch + 4), label, fill=(0, 0, 0), font=font)
    return canvas


def _sheet_columns(grid: dict) -> int | None:
    """One row per value of the other parameters: the last swept parameter runs along a row."""
    swept = [len(v) for v in grid.values() if len(v) > 1]
    if not swept:
        return None
    return swept[-1] if swept[-1] <= 8 else None


# ==========================================================================
# the sweep
# ==========================================================================
def _thumbnail(img8: np.ndarray, size: int = 256) -> np.ndarray:
    h, w = img8.shape[:2]
    if max(h, w) <= size:
        return img8
    from PIL import Image
    s = size / max(h, w)
    return np.asarray(Image.fromarray(img8).resize((max(1, round(w * s)), max(1, round(h * s))),
                                                   Image.Resampling.LANCZOS))


def _shared_exposure(entries, files, exposures, thumbs) -> float | None:
    """The sweep's exposure (the smallest automatic one: the brightest point's glow at 1);
    every point's PNG and thumbnail rewritten at it from its EXR.  None when no point has
    an image."""
    import mitsuba as mi

    from corona.apps.pictures import display_exposure, display_srgb
    images = {}
    for i, e in enumerate(entries):
        if e["status"] == "failed":
            continue
        try:
            images[i] = np.array(mi.Bitmap(files[i]["exr"]), dtype=np.float32)[..., :3]
        except Exception:  # noqa: BLE001  (an unreadable old file keeps its PNG)
            continue
        if i not in exposures:
            exposures[i] = display_exposure(images[i])
    if not exposures:
        return None
    shared = min(exposures.values())
    for i, rgb in images.items():
        img8 = display_srgb(rgb, shared)
        mi.Bitmap(np.ascontiguousarray(img8), pixel_format=mi.Bitmap.PixelFormat.RGB).write(files[i]["png"])
        thumbs[i] = _thumbnail(img8)
    return shared


def _sweep_plan(scene: str, grid: dict, out_dir: str) -> tuple:
    """The checked sweep: (its points, the scene's stem, each point's file name); a CoronaError for
    a missing or empty scene, a parameter the scene does not take, two points sharing a name, or an
    output folder that cannot be written."""
    if not os.path.isfile(scene):
        raise CoronaError(f"scene file {scene!r} does not exist")
    if os.path.getsize(scene) == 0:
        raise CoronaError(f"scene file {scene!r} is empty")
    known = scene_parameters(scene)
    for name in grid:
        if name not in known:
            raise CoronaError(f"-D {name}=...: {scene} has no parameter {name!r} (it takes "
                              f"{', '.join(sorted(known)) or 'none'})")
    points = sweep_points(grid)
    stem = os.path.splitext(os.path.basename(scene))[0]
    names = [point_name(stem, p) for p in points]
    clash = [n for n, c in collections.Counter(names).items() if c > 1]
    if clash:
        raise CoronaError(f"two points would share the file name {clash[0]!r} (values that differ only "
                          "in characters other than letters, digits, '.', '+', '-')")
    check_out_dir(out_dir)
    return points, stem, names


def _sheet_images(entries: list, files: list, thumbs: dict) -> list:
    """The contact sheet's cells: each point's thumbnail (rendered now, or read from its PNG), None
    (a grey cell) for a failed point or an unreadable old file."""
    import imageio.v3 as iio
    images = []
    for i, e in enumerate(entries):
        if e["status"] == "failed":
            images.append(None)
        elif i in thumbs:
            images.append(thumbs[i])
        else:
            try:
                images.append(_thumbnail(np.asarray(iio.imread(files[i]["png"]))[..., :3]))
            except Exception:  # noqa: BLE001  (an unreadable old file: a grey cell)
                images.append(None)
    return images


def run_sweep(scene: str, grid: dict, out_dir: str, *, executor: Executor, spp: int | None = None,
              seed: int = 0, variant: str | None = None, exposure: float | None = None,
              force: bool = False, progress: bool = True, log=None) -> dict:
    """Render ``scene`` at every point of ``grid`` into ``out_dir``; returns the index.

    For each point ``NAME.exr`` (linear sRGB) and ``NAME.png`` (8-bit sRGB by
    :func:`corona.apps.pictures.display_srgb` at one exposure for every point: ``exposure``,
    or the brightest point's automatic one, so that brighter points look brighter), ``NAME``
    from :func:`point_name`; then ``STEM_sheet.png`` (every point, labelled)
    and ``STEM_index.json`` (every point: parameters, files, status
    ``rendered`` / ``existing`` / ``failed`` with the error, seconds, spp,
    variant, host).  Points whose EXR and PNG exist are skipped unless
    ``force``.  All input is checked before any render starts.
    """
    from corona.apps.pictures import display_exposure, display_srgb
    from corona.apps.render import write_images
    log = log or (lambda s: None)
    points, stem, names = _sweep_plan(scene, grid, out_dir)
    files = [{"exr": os.path.join(out_dir, n + ".exr"), "png": os.path.join(out_dir, n + ".png")}
             for n in names]
    entries = [{"name": n, "parameters": p, "exr": os.path.basename(f["exr"]),
                "png": os.path.basename(f["png"]), "status": "existing"}
               for n, p, f in zip(names, points, files)]
    todo = [i for i, f in enumerate(files)
            if force or not (os.path.isfile(f["exr"]) and os.path.isfile(f["png"]))]
    if len(todo) < len(points):
        log(f"corona: {len(points) - len(todo)} of {len(points)} point(s) already rendered in {out_dir} "
            "(skipped; --force renders them again)")
    thumbs = {}
    exposures = {}          # each rendered point's automatic exposure (the sweep takes the smallest)
    t0 = time.perf_counter()

    def store(o: Outcome):
        i = todo[o.index]
        e = entries[i]
        if not o.ok:
            e.update(status="failed", error=o.error)
            return
        r = o.value
        try:
            write_images(r["rgb"], out_dir, names[i], exposure)
        except OSError as err:
            e.update(status="failed", error=f"could not write {files[i]['exr']}: {err.strerror or err}")
            return
        thumbs[i] = _thumbnail(display_srgb(r["rgb"], exposure))
        exposures[i] = display_exposure(r["rgb"])
        e.update(status="rendered", seconds=round(r["seconds"], 3), spp=r["spp"], variant=r["variant"],
                 host=r["host"], drjit_threads=r["threads"])

    jobs = [RenderJob(scene, points[i], point_label(points[i]), spp, seed, variant) for i in todo]
    render_jobs(jobs, executor, desc=f"sweep {stem}", progress=progress, on_result=store)
    wall = time.perf_counter() - t0
    used = exposure
    if exposure is None:      # one exposure for the sweep: every PNG again from its EXR
        used = _shared_exposure(entries, files, exposures, thumbs)
    # contact sheet: every point whose PNG exists (rendered now or before)
    images = _sheet_images(entries, files, thumbs)
    swept = [k for k, v in grid.items() if len(v) > 1] or list(grid)   # fixed ones: in the index
    labels = [point_label({k: p[k] for k in swept}) + (" (failed)" if e["status"] == "failed" else "")
              for p, e in zip(points, entries)]
    sheet = os.path.join(out_dir, f"{stem}_sheet.png")
    contact_sheet(images, labels, columns=_sheet_columns(grid)).save(sheet, optimize=True)
    index = {
        "scene": os.path.abspath(scene), "grid": grid, "spp": spp, "seed": seed, "variant": variant,
        "exposure": used, "executor": executor.describe(),
        "executor_startup_seconds": round(executor.startup_seconds, 3),
        "wall_seconds": round(wall, 3),      # from the first job to the last (includes the start-up)
        "contact_sheet": os.path.basename(sheet), "points": entries,
    }
    path = os.path.join(out_dir, f"{stem}_index.json")
    with open(path, "w", encoding="utf-8") as f:
        json.dump(index, f, indent=1, ensure_ascii=False)
    index["index"] = path
    index["sheet"] = sheet
    return index
