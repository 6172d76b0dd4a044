"""The ``corona`` command line (click).

    corona render SCENE.xml [--spp N] [--variant V] [--out DIR] [--name NAME] [--exposure E] [-D key=value ...]
    corona sweep SCENE.xml -D name=v1,v2,... [-D ...] [--spp N] [--out DIR] [--workers N | --scheduler ADDRESS] [--force]
    corona lobe [material options] [--out FILE.png] [--json]
    corona tables info | clear
    corona doctor
    corona validate [--out DIR] [--quick] [--cases A,B] [--realisations N] [--workers N | --scheduler ADDRESS]
    corona fit IMAGE (--fov DEG | --deg-per-pixel DEG) [--temperature K] [--json] ...
    corona designer [--host 127.0.0.1] [--port 8765] [--open]
    corona post IMAGE --fov DEG [-D name=value ...] [--colorspace srgb|acescg] [--srgb-input] --out OUT

Errors are one line on stderr and exit code 2.
"""
from __future__ import annotations

import contextlib
import json
import os
import sys

import click

from corona._validation import CoronaError
from corona.apps.fit import FIT_PROCESSES, FIT_SHAPES
from corona.parameters import PARAMETERS


class CoronaUsageError(click.ClickException):
    exit_code = 2

    def show(self, file=None):
        click.echo(f"corona: error: {self.format_message()}", err=True, file=file)


def _fail(err) -> None:
    from corona._validation import one_line_error  # Mitsuba wraps plugin errors in a traceback
    raise CoronaUsageError(one_line_error(err))


class Interrupted(click.ClickException):
    """Ctrl-C: one line, exit code 130 (128 + SIGINT), as shells report it."""
    exit_code = 130

    def __init__(self):
        super().__init__("interrupted")

    def show(self, file=None):
        click.echo("\ncorona: interrupted", err=True, file=file)


class OneLineErrorGroup(click.Group):
    """Usage errors (bad option values, unknown choices or commands) as one
    line on stderr, exit code 2, like every other corona error; Ctrl-C exits
    130 wherever it lands; warnings are one line too (``corona: warning: ...``)."""

    def make_context(self, *args, **kwargs):
        with _one_line_usage_errors():
            return super().make_context(*args, **kwargs)

    def invoke(self, ctx):
        with _one_line_usage_errors(), _one_line_warnings():
            try:
                out = super().invoke(ctx)
            except KeyboardInterrupt:
                raise Interrupted() from None
            _flush_warnings()
            return out


_pending_warnings: list = []


@contextlib.contextmanager
def _one_line_warnings():
    """Python warnings (e.g. CoronaWarning about unused parameters) as one line each on
    stderr, ``corona: warning: ...``, shown once the input is accepted (before a render
    starts, or at the end): a command that fails prints its one error line only."""
    import warnings
    old = warnings.showwarning

    def show(message, category, filename, lineno, file=None, line=None):
        _pending_warnings.append(" ".join(str(message).split()))
    warnings.showwarning = show
    _pending_warnings.clear()
    try:
        yield
    finally:
        warnings.showwarning = old
        _pending_warnings.clear()


def _flush_warnings() -> None:
    for text in _pending_warnings:
        click.echo(f"corona: warning: {text}", err=True)
    _pending_warnings.clear()


@contextlib.contextmanager
def _one_line_usage_errors():
    try:
        yield
    except click.exceptions.NoArgsIsHelpError:
        raise
    except click.UsageError as err:
        raise CoronaUsageError(err.format_message().strip().splitlines()[0]) from None


@click.group(cls=OneLineErrorGroup, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(version=__import__("corona").__version__, prog_name="corona")
def main():
    """corona: a wave-optics BSDF for layers of correlated scatterers."""


# ----------------------------------------------------------------------
# render
# ----------------------------------------------------------------------
#: Largest samples per pixel (``--spp`` or the scene's ``sample_count``).
SPP_MAX = 1 << 16
#: Largest ``--seed``: the passes use the seeds ``seed·1000 + i`` (i < 256 passes), a uint32.
SEED_MAX = (2**32 - 1 - 255) // 1000


def _finite_positive(ctx, param, value):
    """``--exposure``: a finite number > 0 (click's FloatRange lets nan and inf through)."""
    import math
    if value is not None and not (math.isfinite(value) and value > 0):
        raise click.BadParameter(f"{value!r} is out of range; allowed a finite value > 0", ctx, param)
    return value


def _plain_name(name: str) -> str:
    """``--name``: a plain file name (no folder part), else one error line."""
    bad = (not name or name in (".", "..") or "/" in name or (os.altsep and os.altsep in name)
           or os.sep in name or "\0" in name)
    if bad:
        _fail(f"--name {name!r} is not a plain file name; expected a name without a folder "
              "(the files go into --out)")
    return name


def _output_folder(out_dir: str) -> str:
    """``--out``: created if missing and writable, else one error line."""
    if not out_dir:
        _fail("--out '' is empty; expected a folder")
    if os.path.exists(out_dir) and not os.path.isdir(out_dir):
        _fail(f"--out {out_dir!r} is a file, not a folder")
    try:
        os.makedirs(out_dir, exist_ok=True)
        import tempfile
        with tempfile.TemporaryFile(dir=out_dir):
            pass
    except OSError as err:
        _fail(f"--out {out_dir!r} is not a writable folder: {err.strerror or err}")
    return out_dir


@main.command()
@click.argument("scene", type=click.Path(dir_okay=False))
@click.option("--spp", type=click.IntRange(min=1, max=SPP_MAX), default=None,
              help="Samples per pixel (default: the scene's sample_count, e.g. -D spp=N).")
@click.option("--variant", default=None, help="Mitsuba variant (default: the fastest, cuda > llvm > scalar spectral).")
@click.option("--out", "out_dir", default="out", show_default=True, help="Output folder.")
@click.option("--name", default=None, help="Output file stem (default: the scene file's name).")
@click.option("--exposure", type=float, default=None, callback=_finite_positive,
              help="PNG: scale of the linear values before the highlight roll-off (default: the glow "
                   "around the lamps maps to 1; corona.apps.pictures.display_srgb).")
@click.option("-D", "defines", multiple=True, metavar="KEY=VALUE", help="Scene parameter ($KEY in the XML).")
@click.option("--seed", type=click.IntRange(0, SEED_MAX), default=0, show_default=True)
def render(scene, spp, variant, out_dir, name, exposure, defines, seed):
    """Render SCENE.xml to EXR (linear sRGB) and PNG (tonemapped sRGB), with a progress bar."""
    if not os.path.isfile(scene):
        _fail(f"scene file {scene!r} does not exist")
    if os.path.getsize(scene) == 0:
        _fail(f"scene file {scene!r} is empty")
    kv = {}
    for d in defines:
        if "=" not in d or not d.split("=", 1)[0].strip():
            _fail(f"-D {d!r}: expected KEY=VALUE")
        k, v = d.split("=", 1)
        kv[k.strip()] = v.strip()
    name = _plain_name(name if name is not None else os.path.splitext(os.path.basename(scene))[0])
    _output_folder(out_dir)
    try:
        from corona.apps.render import load_scene, render_to_files, scene_spp, setup_variant
        v = setup_variant(variant)
        loaded = load_scene(scene, kv)
        if spp is None:
            spp = scene_spp(loaded)
            if not 1 <= spp <= SPP_MAX:
                _fail(f"{scene}: the scene's sample_count={spp} is out of range; allowed [1, {SPP_MAX}] "
                      "(or pass --spp N)")
        how = "" if variant else " (the fastest available: cuda > llvm > scalar)"
        _flush_warnings()
        click.echo(f"corona: rendering with variant {v}{how}", err=True)  # after loading: errors stay one line
        res = render_to_files(loaded, out_dir, name, spp=spp, seed=seed, exposure=exposure)
    except (CoronaError, RuntimeError, ValueError, OSError) as err:
        from corona.apps.render import is_interrupt
        if is_interrupt(err):
            raise KeyboardInterrupt from None
        _fail(err)
    click.echo(f"{res['png']}  ({res['exr']}, {res['seconds']:.1f} s, {spp} spp, {res['variant']})")


# ----------------------------------------------------------------------
# sweep
# ----------------------------------------------------------------------
def _timeout_seconds(ctx, param, value):
    """--timeout: a finite number of seconds in (0, TIMEOUT_MAX] (click's FloatRange lets inf through)."""
    import math

    from corona._executor import TIMEOUT_MAX
    if value is not None and not (math.isfinite(value) and 0 < value <= TIMEOUT_MAX):
        raise click.BadParameter(f"{value!r} is out of range; allowed a finite number of seconds in "
                                 f"(0, {TIMEOUT_MAX:g}]", ctx, param)
    return value


def executor_options(f):
    """--workers / --scheduler / --timeout: where the jobs run (corona._executor.Executor)."""
    f = click.option("--timeout", type=float, default=10.0, callback=_timeout_seconds,
                     show_default=True, help="Seconds to wait for --scheduler and its first worker.")(f)
    f = click.option("--scheduler", default=None, metavar="ADDRESS",
                     help="An existing Dask scheduler (tcp://host:8786) instead of a local cluster.")(f)
    return f


@main.command()
@click.argument("scene", type=click.Path(dir_okay=False))
@click.option("-D", "defines", multiple=True, metavar="NAME=V1,V2,...",
              help="A scene parameter and its values; the sweep is the product of all -D lists.")
@click.option("--spp", type=click.IntRange(min=1), default=None,
              help="Samples per pixel (default: the scene's sample_count).")
@click.option("--out", "out_dir", default="out/sweep", show_default=True, help="Output folder.")
@click.option("--workers", type=click.IntRange(min=0), default=None,
              help="Local cluster of N worker processes [default: sized to the machine]; "
                   "0: one render after the other in this process.")
@executor_options
@click.option("--force", is_flag=True, help="Render points whose EXR and PNG already exist again.")
@click.option("--variant", default=None, help="Mitsuba variant (default: each worker's fastest).")
@click.option("--exposure", type=click.FloatRange(min=0, min_open=True), default=None,
              help="PNG: scale of the linear values before the highlight roll-off (default: one "
                   "exposure for every point, the brightest point's glow around the lamps to 1).")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--no-progress", is_flag=True, help="No progress bar.")
def sweep(scene, defines, spp, out_dir, workers, scheduler, timeout, force, variant, exposure, seed,
          no_progress):
    """Render SCENE.xml at every combination of the -D value lists, on a Dask cluster.

    One EXR + PNG per point (named by its parameters), a contact sheet
    SCENE_sheet.png and an index SCENE_index.json in --out.  Points already
    rendered are skipped (--force renders them again); a failed point is
    reported with its parameters and the others still finish (exit code 2).
    """
    if not defines:
        _fail("no -D NAME=V1,V2,... given; a sweep needs at least one parameter list")
    try:
        from corona._executor import Executor
        from corona.apps.sweep import parse_defines, point_label, run_sweep
        grid = parse_defines(defines)
        log = (lambda s: click.echo(s, err=True))
        with Executor(workers, scheduler, timeout=timeout, log=log) as ex:
            index = run_sweep(scene, grid, out_dir, executor=ex, spp=spp, seed=seed, variant=variant,
                              exposure=exposure, force=force, progress=not no_progress, log=log)
    except (CoronaError, ValueError, OSError) as err:
        _fail(err)
    pts = index["points"]
    count = {s: sum(1 for p in pts if p["status"] == s) for s in ("rendered", "existing", "failed")}
    click.echo(f"{index['sheet']}  ({count['rendered']} rendered, {count['existing']} existing, "
               f"{count['failed']} failed; {index['index']})")
    failed = [p for p in pts if p["status"] == "failed"]
    if failed:
        _fail(f"{len(failed)} of {len(pts)} point(s) failed: "
              + "; ".join(f"{point_label(p['parameters'])}: {p['error']}" for p in failed[:3])
              + (" ..." if len(failed) > 3 else "") + f" (all in {index['index']})")


# ----------------------------------------------------------------------
# lobe
# ----------------------------------------------------------------------
def _spec_option(p):
    """The ``--name`` option of one :data:`corona.parameters.PARAMETERS` entry."""
    kind = {"float": float, "int": int, "choice": click.Choice(p.choices)}.get(p.kind, str)
    if p.name == "mirror_reflectance":      # a number, a metal or a spectrum (checked by the material)
        kind = str
    unit = f" [{p.unit}]" if p.unit else ""
    return click.option(f"--{p.name.replace('_', '-')}", p.name, type=kind, default=p.default,
                        show_default=p.default is not None, help=f"{p.meaning}{unit}")


def material_options(f):
    """Every material parameter of the plugin as an option (from the one specification)."""
    for p in reversed([p for p in PARAMETERS if not p.plugin_only]):
        f = _spec_option(p)(f)
    return f


@main.command()
@material_options
@click.option("--out", "out_path", default="lobe.png", show_default=True,
              help="PNG file to write (with --json: only when given).")
@click.option("--json", "as_json", is_flag=True, help="Print the numbers as JSON (and write the picture only "
              "when --out is given).")
@click.option("--wavelength", type=float, default=550.0, show_default=True, help="nm (for --json)")
def lobe(out_path, as_json, wavelength, **params):
    """Pictures (or numbers) of a material's form factor, structure factor, lobe and corona.

    Every shape: a picture (``--out``), the numbers (``--json``) or both (``--json --out``).  A new
    sphere radius builds its Mie table first (seconds to a minute; a progress bar on stderr).
    """
    import numpy as np
    ctx = click.get_current_context()
    picture = not as_json or ctx.get_parameter_source("out_path") != click.core.ParameterSource.DEFAULT
    # only the options given on the command line count as given (the others keep their
    # defaults, and a parameter the shape or process does not use is warned about)
    params = {k: v for k, v in params.items()
              if ctx.get_parameter_source(k) != click.core.ParameterSource.DEFAULT}
    if picture:
        if not out_path or os.path.isdir(out_path):
            _fail(f"--out {out_path!r} is {'a folder' if out_path else 'empty'}; expected a file path "
                  f"such as {os.path.join(out_path, 'lobe.png')!r}")
        if not os.path.splitext(out_path)[1]:
            out_path += ".png"          # what matplotlib would write: say so
    try:
        from corona.parameters import material_from_parameters
        m = material_from_parameters(**params)
        from corona.model.mie.material import SphereMaterial
        sphere = isinstance(m, SphereMaterial)
        if as_json:
            from corona._validation import check_range
            from corona.model.tabulated import WAVELENGTH_MAX, WAVELENGTH_MIN
            wavelength = check_range("wavelength", wavelength, WAVELENGTH_MIN, WAVELENGTH_MAX, unit="nm")
        if as_json and sphere:       # the Mie lobe along d_x and its energies
            d = np.linspace(0.0, 0.999, 201)
            e = m.directional_albedo(1.0, wavelength, n_phi=4)
            out = {
                "material": repr(m), "area_fraction": m.area_fraction, "wavelength_nm": wavelength,
                "coherent_transmittance": e["coherent"], "diffuse_transmittance": e["lobe_transmission"],
                "reflectance": e["lobe_reflection"], "length_scale_um": m.length_scale,
                "d": d.tolist(), "lobe": m.lobe(np.stack([d, 0 * d], -1), wavelength).tolist()}
        elif as_json:
            R = m.length_scale
            from corona.apps.pictures import _u_extent
            u = np.linspace(0, _u_extent(m), 201)  # a cut along u_x (radial tables: the profile)
            lam_um = wavelength * 1e-3
            terms = m.lobe_terms(np.stack([u, 0 * u], -1))
            # lobe = F_a (R/λ)² v(u) = F_a [T_a + T_c (T_s - 1)] (T_c = T_a for identical scatterers)
            lobe = m.lobe_weight * (R / lam_um) ** 2 * terms["v"]
            out = {
                "material": repr(m), "area_fraction": m.area_fraction,
                "coherent_transmittance": m.coherent_transmittance,
                "diffuse_transmittance": m.diffuse_transmittance(),
                "reflectance": m.reflectance, "length_scale_um": R, "wavelength_nm": wavelength,
                "u": u.tolist(),
                "form_factor_Ta": (terms["P"] / lam_um**2).tolist(),
                "coherent_form_factor_Tc": (terms["C"] / lam_um**2).tolist(),
                "structure_factor_Ts": terms["S"].tolist(),
                "d": (u * lam_um / (2 * np.pi * R)).tolist(), "lobe": lobe.tolist(),
            }
        if picture:
            from corona.apps.pictures import lobe_figure, sphere_lobe_figure
            os.makedirs(os.path.dirname(out_path) or ".", exist_ok=True)   # as render's --out: made if new
            path = (sphere_lobe_figure if sphere else lobe_figure)(m, out_path)
    except (CoronaError, ValueError, OSError) as err:
        _fail(err)
    click.echo(json.dumps(out) if as_json else path)     # with --json, stdout holds the JSON alone


# ----------------------------------------------------------------------
# tables
# ----------------------------------------------------------------------
@main.group()
def tables():
    """The on-disk table cache."""


@tables.command("info")
def tables_info():
    """Show where the cache is, how many tables and how big."""
    from corona.model import tabulated as t
    try:
        info = t.cache_info()
    except CoronaError as err:
        _fail(err)
    click.echo(f"cache: {info['path']}\ntables: {info['tables']}\nsize: {info['bytes'] / 1e6:.2f} MB\n"
               f"format: {info['format']}")


@tables.command("clear")
def tables_clear():
    """Delete every cached table (only the files the cache wrote)."""
    from corona.model import tabulated as t
    try:
        n = t.cache_clear()
        folder = t.cache_dir()
    except CoronaError as err:
        _fail(err)
    click.echo(f"removed {n} table(s) from {folder}")


# ----------------------------------------------------------------------
# doctor
# ----------------------------------------------------------------------
@main.command()
def doctor():
    """Report the environment (for bug reports)."""
    import platform

    from corona import __version__, _environment
    from corona.model import tabulated as t
    lines = [f"corona {__version__}", f"python {platform.python_version()} on {platform.platform()}"]
    try:
        import drjit as dr
        import mitsuba as mi
        lines.append(f"mitsuba {mi.__version__}, drjit {dr.__version__}")
        lines.append(f"variants: {', '.join(mi.variants())}")
    except Exception as err:  # pragma: no cover
        lines.append(f"mitsuba: NOT importable ({err})")
    lib = os.environ.get("DRJIT_LIBLLVM_PATH")
    lines.append(f"libLLVM: {lib or 'not found (' + _environment.FIX_HINT + ')'}")
    lines.append(f"LLVM backend usable: {_environment.has_llvm()}")
    lines.append(f"GPU (CUDA backend): {_environment.has_cuda()}")
    lines.append(f"default variant: {_environment.default_variant()}")
    try:
        info = t.cache_info()
        lines.append(f"table cache: {info['path']} ({info['tables']} tables, {info['bytes'] / 1e6:.2f} MB, "
                     f"format {info['format']})")
    except (OSError, CoronaError) as err:
        lines.append(f"table cache: NOT usable ({err})")
    click.echo("\n".join(lines))


# ----------------------------------------------------------------------
# validate
# ----------------------------------------------------------------------
@main.command()
@click.option("--out", "out_dir", default="out/validate", show_default=True, help="Report folder.")
@click.option("--quick", is_flag=True, help="Reduced matrix (circle and hexagon at F_a 0.3, 3 extras).")
@click.option("--cases", default=None, metavar="A,B,...",
              help="Keep cases whose name contains one of these (comma-separated).")
@click.option("--realisations", type=click.IntRange(min=1), default=None,
              help="Screens per ensemble [default: 64, --quick 16].")
@click.option("--scatterers", type=click.IntRange(min=16), default=None,
              help="Scatterers per screen [default: 2000].")
@click.option("--seed", type=int, default=0, show_default=True)
@click.option("--no-progress", is_flag=True, help="No progress bars.")
@click.option("--workers", type=click.IntRange(min=0), default=0, show_default=True,
              help="0: the cases one after the other in this process; N: a local Dask cluster of N "
                   "workers, one case per task.")
@executor_options
def validate(out_dir, quick, cases, realisations, scatterers, seed, no_progress, workers, scheduler,
             timeout):
    """Compare the model with a brute-force wave-optics reference; write a report folder."""
    try:
        from corona.reference import validate as v
        from corona._executor import Executor
        log = (lambda s: click.echo(s, err=True))
        with Executor(None if scheduler else workers, scheduler, timeout=timeout, log=log) as ex:
            summary = v.run(out_dir, quick=quick, cases=cases.split(",") if cases else None,
                            realisations=realisations, n_scatterers=scatterers, seed=seed,
                            progress=not no_progress, echo=log, executor=ex)
    except (CoronaError, ValueError, OSError, MemoryError) as err:
        _fail(err)
    n = sum(1 for c in summary["cases"] if "skipped" not in c)
    click.echo(f"{os.path.join(out_dir, 'README.md')}  ({n} case(s), {summary['seconds']:.0f} s)")


# ----------------------------------------------------------------------
# fit
# ----------------------------------------------------------------------
@main.command()
@click.argument("image", type=click.Path(dir_okay=False))
@click.option("--fov", "fov", type=float, default=None,
              help="Horizontal field of view of the (pinhole) image [degree], in (0, 180).")
@click.option("--deg-per-pixel", type=float, default=None,
              help="Instead of --fov: the angle one pixel spans at the image centre [degree].")
@click.option("--temperature", type=float, default=None,
              help="Colour temperature of the light [K] (black body); fitted when not given.")
@click.option("--area-fraction", type=float, default=None, help="Hold the area fraction F_a fixed.")
@click.option("--size-spread", type=float, default=None, help="Hold the relative size spread fixed.")
@click.option("--process", type=click.Choice(FIT_PROCESSES), default="hard-disk",
              show_default=True, help="Point process of the scatterers.")
@click.option("--mode", type=click.Choice(["particle", "aperture"]), default="particle", show_default=True,
              help="Written to the material (the lobe is the same, by Babinet's principle).")
@click.option("--shape", type=click.Choice(tuple(FIT_SHAPES)), default="circle", show_default=True,
              help="Scatterer model (sphere: transparent droplets, planned).")
@click.option("--source-diameter", type=float, default=0.0, show_default=True,
              help="Angular diameter of the light [degree] (the moon: 0.52).")
@click.option("--no-background", is_flag=True, help="Do not fit a constant background per channel.")
@click.option("--bootstrap", type=int, default=0, show_default=True,
              help="Uncertainties from N refits over resampled azimuthal sectors (0: fit covariance).")
@click.option("--saturation", type=float, default=None,
              help="Clipping level of a linear (EXR) image (default: a channel maximum shared by several pixels).")
@click.option("--out", "out_dir", default="out", show_default=True,
              help="Folder for IMAGE-STEM_fit.png (diagnostic) and IMAGE-STEM_fit.xml (the material).")
@click.option("--no-diagnostic", is_flag=True, help="Skip the diagnostic PNG.")
@click.option("--json", "as_json", is_flag=True, help="Print one JSON object on stdout.")
def fit(image, fov, deg_per_pixel, temperature, area_fraction, size_spread, process, mode, shape,
        source_diameter, no_background, bootstrap, saturation, out_dir, no_diagnostic, as_json):
    """Fit a layer of scatterers (radius, size spread, area fraction) and the light's
    temperature to a photograph of a corona around a light.

    IMAGE: an 8-/16-bit sRGB PNG/JPEG/TIFF or a linear EXR, with the light inside the frame.
    """
    try:
        from corona.apps.fit import fit_photograph
        stem = os.path.splitext(os.path.basename(image))[0]
        diag = None if no_diagnostic else os.path.join(out_dir, f"{stem}_fit.png")
        res = fit_photograph(image, fov, deg_per_pixel=deg_per_pixel, temperature=temperature,
                             area_fraction=area_fraction, size_spread=size_spread, process=process,
                             mode=mode, shape=shape, source_diameter_deg=source_diameter,
                             background=not no_background, bootstrap=bootstrap, saturation=saturation,
                             diagnostic=diag)
        os.makedirs(out_dir, exist_ok=True)
        xml_path = os.path.join(out_dir, f"{stem}_fit.xml")
        with open(xml_path, "w", encoding="utf-8") as f:
            f.write(res.xml() + "\n")
    except (CoronaError, ValueError, OSError) as err:
        _fail(err)
    if res.diagnostic_note:
        click.echo(f"corona: note: {res.diagnostic_note}", err=True)
    if as_json:
        click.echo(json.dumps({**res.to_dict(), "xml_file": xml_path}))
        return
    click.echo(res.summary())
    click.echo(res.xml())
    click.echo(f"{xml_path}" + (f"  {res.diagnostic}" if res.diagnostic else "") + f"  ({res.seconds:.1f} s)")
# designer
# ----------------------------------------------------------------------
@main.command()
@click.option("--host", default="127.0.0.1", show_default=True,
              help="Address to listen on (loopback by default: only this computer can connect).")
@click.option("--port", type=click.IntRange(0, 65535), default=8765, show_default=True,
              help="TCP port (0: any free port).")
@click.option("--open", "open_browser", is_flag=True, help="Open the page in the web browser.")
def designer(host, port, open_browser):
    """A look-development page in the browser: knobs for every material parameter, the
    corona, profiles, energy split, comparison, photograph overlay and exports."""
    try:
        import starlette  # noqa: F401
        import uvicorn  # noqa: F401
    except ImportError:
        _fail("corona designer needs the 'designer' extra: pip install 'corona-bsdf[designer]'")
    from corona.apps import designer as d
    try:
        sock = d.bind(host, port)
    except OSError as err:
        _fail(f"cannot listen on {host}:{port} ({err.strerror or err}); choose another --port or --host")
    real_port = sock.getsockname()[1]
    url = f"http://{'[' + host + ']' if ':' in host else host}:{real_port}/"
    if host not in ("127.0.0.1", "localhost", "::1"):
        click.echo(f"corona designer: listening on {host}, reachable from other computers", err=True)
    click.echo(f"corona designer: {url}  (Ctrl-C to stop)", err=True)
    if open_browser:
        import webbrowser
        webbrowser.open(url)
    try:
        d.serve(sock, host)
    except KeyboardInterrupt:  # pragma: no cover - interactive
        pass


# ----------------------------------------------------------------------
# post
# ----------------------------------------------------------------------
@main.command()
@click.argument("image", type=click.Path(dir_okay=False))
@click.option("--fov", type=float, required=True,
              help="Horizontal field of view of the (pinhole) image [degree], in (0, 176].")
@click.option("-D", "defines", multiple=True, metavar="NAME=VALUE",
              help="A layer parameter (the plugin's names: radius=5, area_fraction=0.3, mode=particle, ...).")
@click.option("--out", "out_path", required=True, help="Output image: .exr (linear float) or .png (8-bit sRGB).")
@click.option("--colorspace", type=click.Choice(["srgb", "acescg"]), default="srgb", show_default=True,
              help="Linear primaries of the image's channels.")
@click.option("--srgb-input", is_flag=True,
              help="Accept an 8-/16-bit sRGB image (PNG/JPEG), decoded to linear values; without it only "
                   "float images (linear HDR: EXR) are accepted.")
@click.option("--exposure", type=float, default=None, callback=_finite_positive,
              help="PNG output: scale of the linear values before the highlight roll-off (default: "
                   "the glow around the lamps maps to 1, as corona render).")
@click.option("--workers", type=click.IntRange(min=1), default=None,
              help="FFT threads (default: the CPUs this process may use).")
@click.option("--no-progress", is_flag=True, help="No progress bar.")
def post(image, fov, defines, out_path, colorspace, srgb_input, exposure, workers, no_progress):
    """IMAGE seen through a uniform layer at the camera: the coherent part times the image
    plus the image convolved, in direction space, with the layer's lobe (corona.apps.post)."""
    params = {}
    for d in defines:
        if "=" not in d or not d.split("=", 1)[0].strip():
            _fail(f"-D {d!r}: expected NAME=VALUE")
        k, v = d.split("=", 1)
        params[k.strip()] = v.strip()
    try:
        from corona.apps import post as p
        from corona.parameters import SPEC
        unknown = sorted(k for k in params if k not in SPEC or SPEC[k].plugin_only)
        if unknown:
            known = sorted(q.name for q in PARAMETERS if not q.plugin_only)
            _fail(f"unknown parameter(s) {', '.join(unknown)}; known: {', '.join(known)}")
        res = p.apply_file(image, out_path, fov, params, colorspace=colorspace, srgb_input=srgb_input,
                           exposure=exposure, workers=workers, progress=not no_progress)
    except (CoronaError, ValueError, OSError, MemoryError) as err:
        _fail(err)
    click.echo(f"{res['out']}  (T_c = {res['coherent_transmittance']:.4g}, {res['seconds']:.1f} s)")


def run() -> int:  # pragma: no cover - console entry
    return main(standalone_mode=True)


if __name__ == "__main__":
    sys.exit(main())
