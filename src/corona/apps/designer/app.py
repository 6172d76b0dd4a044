"""The designer's web server: a Starlette app (served by uvicorn) around
:mod:`corona.apps.designer.compute`, and the page in ``static/``.

Every computation runs in a thread of its own under a time limit, at most
:data:`MAX_CONCURRENT` at any time: a request past the limit is answered 503
at once, but its computation keeps its slot until it really ends (a numpy
computation cannot be stopped from outside), so clients that time out cannot
pile up running computations; a request that finds every slot taken waits for
one until its own time limit, then is answered 503.  Bad parameters are HTTP
400 with ``{"error": "<one line naming the parameter>"}``.  The app reads no
files but its own page, the uploads it stored, and the table cache.
"""
from __future__ import annotations

import hashlib
import io
import json
import logging
import math
import os
import time

import asyncio
import threading

from starlette.applications import Starlette
from starlette.middleware import Middleware
from starlette.middleware.trustedhost import TrustedHostMiddleware
from starlette.requests import Request
from starlette.responses import FileResponse, JSONResponse, Response
from starlette.routing import Mount, Route
from starlette.staticfiles import StaticFiles

from corona._validation import CoronaError
from corona.apps.fit import MAX_PIXELS as MAX_FIT_PIXELS
from corona.apps.designer import compute

log = logging.getLogger("corona.apps.designer")

STATIC = os.path.join(os.path.dirname(os.path.abspath(__file__)), "static")

#: Longest query string accepted [characters].
MAX_QUERY = 4096
#: Largest upload [bytes]: photographs; masks and point files have their own limits.
MAX_UPLOAD = 16 * 2**20
MAX_MASK_PIXELS = 1024 * 1024
MAX_PHOTO_PIXELS = MAX_FIT_PIXELS      # what corona.apps.fit takes
MAX_POINTS = 5000
MAX_POINTS_BYTES = 512 * 1024
#: Uploads kept (the oldest go first).
MAX_UPLOADS = 64
#: Longest computation of one request [s], and how many run at once.
COMPUTE_TIMEOUT = 20.0
MAX_CONCURRENT = 2

LOOPBACK = ("127.0.0.1", "localhost", "[::1]")


def _error(status: int, message: str) -> JSONResponse:
    return JSONResponse({"error": _scrub(" ".join(str(message).split()))}, status_code=status)


def _scrub(message: str) -> str:
    """The server's folders out of a message for the client: an upload is named by its id,
    anything else inside the table cache as ``<cache>/...``."""
    from corona.model.tabulated import cache_dir
    try:
        root = cache_dir()
    except Exception:  # noqa: BLE001 - an unusable cache: nothing to hide then
        return message
    for base in sorted({root, os.path.realpath(root)}, key=len, reverse=True):
        message = message.replace(os.path.join(base, "designer", "uploads") + os.sep, "")
        message = message.replace(base, "<cache>")
    return message


def designer_dir(*parts: str) -> str:
    """A folder of the designer inside the table cache (``corona.model.tabulated.cache_dir``)."""
    from corona.model.tabulated import cache_dir
    path = os.path.join(cache_dir(), "designer", *parts)
    os.makedirs(path, exist_ok=True)
    return path


class _App:
    def __init__(self, timeout: float):
        self.timeout = timeout
        self.slots = _Slots(MAX_CONCURRENT)
        self.jobs: dict[int, tuple[str, float]] = {}      # running computations: id -> (what, start)
        self._job_ids = iter(range(1, 2**62))
        self._jobs_lock = threading.Lock()

    # -- helpers ------------------------------------------------------------
    def _query(self, request: Request) -> dict:
        if len(request.url.query) > MAX_QUERY:
            raise CoronaError(f"the query is {len(request.url.query)} characters long; allowed at most {MAX_QUERY}")
        q = {}
        for k, v in request.query_params.multi_items():
            if k in q:
                raise CoronaError(f"parameter {k} is given twice")
            q[k] = v
        return q

    async def _run(self, fn, *args, what: str = "computing"):
        """``fn(*args)`` in a thread of its own holding one of the slots; one-line errors; a time limit.

        The slot is taken here (waiting for one at most until the time limit) and given back
        by the thread when ``fn`` returns, not when the request gives up on it."""
        loop = asyncio.get_running_loop()
        deadline = loop.time() + self.timeout
        while not self.slots.take():
            if loop.time() >= deadline:
                raise _Timeout(f"the designer is busy ({MAX_CONCURRENT} computations running) and none "
                               f"ended within {self.timeout:g} s; try again later")
            await asyncio.sleep(0.01)
        future = loop.create_future()

        def settle(result, error):
            if future.cancelled() or future.done():
                return
            if error is not None:
                future.set_exception(error)
            else:
                future.set_result(result)

        def job():
            result = error = None
            with self._jobs_lock:
                job_id = next(self._job_ids)
                self.jobs[job_id] = (what, time.monotonic())
            try:
                result = fn(*args)
            except BaseException as err:  # noqa: BLE001 - handed to the request that waits
                error = err
            finally:
                with self._jobs_lock:
                    self.jobs.pop(job_id, None)
                self.slots.give_back()
            try:
                loop.call_soon_threadsafe(settle, result, error)
            except RuntimeError:   # the server stopped meanwhile
                pass
        threading.Thread(target=job, name="corona-designer-compute", daemon=True).start()
        try:
            return await asyncio.wait_for(asyncio.shield(future), max(deadline - loop.time(), 0.0))
        except TimeoutError:
            future.cancel()          # nobody waits for it: its result is dropped, its slot kept until it ends
            raise _Timeout(f"the computation took longer than {self.timeout:g} s; "
                           "choose smaller values (radius, sides, image or kernel size)") from None

    async def _guard(self, fn):
        try:
            return await fn()
        except CoronaError as err:
            return _error(400, err)
        except _Timeout as err:
            return _error(503, err)
        except (ValueError, OSError, MemoryError) as err:
            from corona._validation import one_line_error
            return _error(400, one_line_error(err))

    # -- routes -------------------------------------------------------------
    async def index(self, request: Request):
        return FileResponse(os.path.join(STATIC, "index.html"), headers={"Cache-Control": "no-store"})

    async def favicon(self, request: Request):
        return FileResponse(os.path.join(STATIC, "favicon.svg"), media_type="image/svg+xml")

    async def parameters(self, request: Request):
        return JSONResponse(compute.spec_json())

    async def progress(self, request: Request):
        """What the server computes now (GET /api/progress, polled by the page while it waits):
        ``jobs`` (what, seconds), ``builds`` (the exact tables of new sphere radii building in the
        background while the page shows their previews: what, state, seconds; the page asks again
        when none is left, :func:`compute.shown_material`) and ``bars``, the progress bars of the
        table builds running in this process (every ``tqdm`` bar: description, count, total or
        null, unit, seconds)."""
        now = time.monotonic()
        with self._jobs_lock:
            jobs = [{"what": w, "seconds": round(now - t0, 2)} for w, t0 in self.jobs.values()]
        builds = compute.builds.status()
        jobs += [{"what": b["what"], "seconds": b["seconds"]} for b in builds if b["state"] == "running"]
        return JSONResponse({"jobs": jobs, "builds": builds, "bars": _progress_bars()},
                            headers={"Cache-Control": "no-store"})

    async def kernel_info(self, request: Request):
        async def go():
            material, _, opts = compute.parse(self._query(request), designer_dir("uploads"))
            return JSONResponse(await self._run(compute.kernel_plan, material, opts, True, what="sizing the kernel"))
        return await self._guard(go)

    async def corona_png(self, request: Request):
        async def go():
            material, view, _ = compute.parse(self._query(request), designer_dir("uploads"))
            t0 = time.perf_counter()
            png, used = await self._run(compute.corona_png, material, view, True, what="the corona picture")
            headers = {"X-Corona-Exposure": f"{used['exposure']:.4f}", "X-Corona-Field": f"{used['field']:.6g}",
                       "X-Corona-Seconds": f"{time.perf_counter() - t0:.4f}", "Cache-Control": "no-store",
                       "X-Corona-Preview": "1" if used.get("preview") else "0",
                       "X-Corona-Building": "1" if used.get("building") else "0",
                       "Access-Control-Expose-Headers": "X-Corona-Exposure, X-Corona-Field, X-Corona-Seconds, "
                                                        "X-Corona-Preview, X-Corona-Building"}
            return Response(png, media_type="image/png", headers=headers)
        return await self._guard(go)

    async def profiles(self, request: Request):
        async def go():
            material, view, _ = compute.parse(self._query(request), designer_dir("uploads"))
            return JSONResponse(await self._run(compute.profiles, material, view, 400, True, what="the profiles"))
        return await self._guard(go)

    async def material(self, request: Request):
        async def go():
            material, view, _ = compute.parse(self._query(request), designer_dir("uploads"))

            def both():
                return {**compute.energy(material, preview=True), **compute.exports(material, view),
                        "parameters": {k: os.path.basename(v) if compute.SPEC[k].kind == "file" else v
                                       for k, v in material.items()}}
            return JSONResponse(await self._run(both, what="the energy split"))
        return await self._guard(go)

    async def kernel(self, request: Request):
        fmt = request.path_params["fmt"]
        if fmt not in ("png", "exr"):
            return _error(404, f"no such page: {request.url.path} (the kernel is kernel.png or kernel.exr)")

        async def go():
            material, _, opts = compute.parse(self._query(request), designer_dir("uploads"))

            def make():
                plan = compute.kernel_plan(material, opts)
                k = compute.kernel(material, opts, plan)
                return (compute.kernel_png(k) if fmt == "png" else compute.kernel_exr(k, designer_dir("tmp"))), plan
            data, plan = await self._run(make, what="the kernel")
            media = "image/png" if fmt == "png" else "image/x-exr"
            return Response(data, media_type=media, headers={
                "Content-Disposition": f'attachment; filename="corona_kernel.{fmt}"',
                "X-Corona-Kernel-Share": ",".join(f"{x:.5f}" for x in plan["share"]),
                "X-Corona-Pixel-Scale": f"{plan['pixel_scale']:.6g}",
                "Access-Control-Expose-Headers": "X-Corona-Kernel-Share, X-Corona-Pixel-Scale"})
        return await self._guard(go)

    async def upload(self, request: Request):
        async def go():
            kind = request.query_params.get("kind", "photo")
            if kind not in ("photo", "mask", "points"):
                raise CoronaError(f"kind={kind!r} is not one of 'photo', 'mask', 'points'")
            limit = MAX_POINTS_BYTES if kind == "points" else MAX_UPLOAD
            size = request.headers.get("content-length")
            if size is not None and size.isdigit() and int(size) > limit:
                return _error(413, f"the upload is {int(size)} bytes; allowed at most {limit} for a {kind}")
            chunks, n = [], 0
            async for chunk in request.stream():
                n += len(chunk)
                if n > limit:
                    return _error(413, f"the upload is larger than {limit} bytes; allowed at most {limit} for a {kind}")
                chunks.append(chunk)
            data = b"".join(chunks)
            name = request.query_params.get("name", "")
            info = await self._run(_check_upload, kind, data, name, what="checking the upload")
            upload_id = hashlib.sha256(data).hexdigest()[:32] + "." + info.pop("suffix")
            folder = designer_dir("uploads")
            path = os.path.join(folder, upload_id)
            if not os.path.exists(path):
                tmp = path + ".part"
                with open(tmp, "wb") as f:
                    f.write(data)
                os.replace(tmp, path)
                _prune(folder, MAX_UPLOADS)
            return JSONResponse({"id": upload_id, "kind": kind, "bytes": len(data), **info})
        return await self._guard(go)

    async def fit(self, request: Request):
        async def go():
            body = await request.body()
            if len(body) > 65536:
                return _error(413, f"the fit request is {len(body)} bytes; allowed at most 65536")
            try:
                req = json.loads(body or b"{}")
            except (ValueError, RecursionError):      # RecursionError: nested too deeply
                raise CoronaError("the fit request is not JSON (or nested too deeply); expected "
                                  '{"photo": "<upload id>", "fov": <degree>}') from None
            if not isinstance(req, dict):
                raise CoronaError('the fit request must be a JSON object {"photo": ..., "fov": ...}')
            from corona.apps.fit import fit_photograph
            photo = compute._upload_path("photo", req.get("photo", ""), designer_dir("uploads"))
            fov = compute.check_fov(req.get("fov"))
            result = (await self._run(lambda: fit_photograph(photo, fov_deg=fov), what="fitting")).to_dict()
            fitted = {k: v for k, v in result.items() if k in compute.DEFAULTS}
            return JSONResponse({"parameters": fitted, "result": _jsonable(result)})
        return await self._guard(go)


def _progress_bars() -> list[dict]:
    """The ``tqdm`` progress bars alive in this process (the table builds report through them:
    :mod:`corona.model.mie.layer`, :mod:`corona.model.material`), read without touching them."""
    import sys
    if "tqdm" not in sys.modules:
        return []
    from tqdm import tqdm
    out = []
    with tqdm.get_lock():
        bars = list(tqdm._instances)
    for bar in bars:
        try:
            total = bar.total
            out.append({"desc": str(bar.desc or "").rstrip(": "), "n": float(bar.n), "unit": str(bar.unit),
                        "total": float(total) if total else None,
                        "seconds": round(max(0.0, bar._time() - bar.start_t), 2)})
        except Exception:  # noqa: BLE001 - a bar closing meanwhile: left out
            continue
    return out


class _Timeout(Exception):
    pass


class _Slots:
    """At most ``n`` computations at a time: :meth:`take` before one starts, :meth:`give_back`
    when it has ended.  ``running`` and ``peak`` count them (the tests read them)."""

    def __init__(self, n: int):
        self.n = n
        self.running = 0
        self.peak = 0
        self._lock = threading.Lock()

    def take(self) -> bool:
        with self._lock:
            if self.running >= self.n:
                return False
            self.running += 1
            self.peak = max(self.peak, self.running)
            return True

    def give_back(self) -> None:
        with self._lock:
            self.running -= 1


def _jsonable(obj):
    if isinstance(obj, dict):
        return {str(k): _jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_jsonable(v) for v in obj]
    if isinstance(obj, (str, bool)) or obj is None:
        return obj
    try:
        x = float(obj)
        return x if math.isfinite(x) else None
    except (TypeError, ValueError):
        return str(obj)


def _check_upload(kind: str, data: bytes, name: str) -> dict:
    """Check an upload before it is stored: a PNG/JPEG image (photo, mask) within the
    pixel limits, or a point file (text or .npy) of at most :data:`MAX_POINTS` points."""
    if not data:
        raise CoronaError(f"the {kind} upload is empty")
    if kind in ("photo", "mask"):
        import warnings

        from PIL import Image, UnidentifiedImageError
        limit = MAX_MASK_PIXELS if kind == "mask" else MAX_PHOTO_PIXELS
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", Image.DecompressionBombWarning)   # the limit is ours
                with Image.open(io.BytesIO(data)) as im:
                    fmt, (w, h) = im.format, im.size
        except Image.DecompressionBombError:
            raise CoronaError(f"the {kind} upload {name!r} claims more pixels than Pillow opens; "
                              f"allowed at most {limit} pixels") from None
        except (UnidentifiedImageError, OSError, ValueError):
            raise CoronaError(f"the {kind} upload {name!r} is not a PNG or JPEG image") from None
        if fmt not in ("PNG", "JPEG"):
            raise CoronaError(f"the {kind} upload {name!r} is a {fmt} image; allowed PNG or JPEG")
        if w * h > limit:
            raise CoronaError(f"the {kind} upload is {w}×{h} pixels; allowed at most {limit} pixels")
        return {"suffix": "png" if fmt == "PNG" else "jpg", "width": w, "height": h}
    import numpy as np
    if data[:6] == b"\x93NUMPY":
        try:
            arr = np.load(io.BytesIO(data), allow_pickle=False)
        except Exception:  # noqa: BLE001 - any reader failure is a bad file
            raise CoronaError(f"the points upload {name!r} is not a readable .npy array") from None
        n, suffix = (arr.shape[0] if arr.ndim >= 1 else 0), "npy"
    else:
        try:
            text = data.decode("utf-8")
        except UnicodeDecodeError:
            raise CoronaError(f"the points upload {name!r} is neither UTF-8 text nor a .npy array") from None
        n = sum(1 for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#"))
        suffix = "csv" if "," in text else "txt"
    if n > MAX_POINTS:
        raise CoronaError(f"the points upload holds {n} points; allowed at most {MAX_POINTS} in the designer")
    return {"suffix": suffix, "points": int(n)}


def _prune(folder: str, keep: int) -> None:
    files = sorted((os.path.getmtime(os.path.join(folder, f)), f) for f in os.listdir(folder)
                   if compute.UPLOAD_ID.match(f))
    for _, f in files[:max(0, len(files) - keep)]:
        try:
            os.unlink(os.path.join(folder, f))
        except OSError:
            pass


def create_app(allowed_hosts=LOOPBACK, timeout: float = COMPUTE_TIMEOUT) -> Starlette:
    """The designer's Starlette app.

    ``allowed_hosts``: the Host headers answered (the loopback names by
    default: a page on another site cannot reach the server by DNS rebinding).
    ``timeout``: longest computation of one request [s] (then HTTP 503).
    """
    a = _App(timeout)
    routes = [
        Route("/", a.index),
        Route("/favicon.ico", a.favicon),
        Route("/api/parameters", a.parameters),
        Route("/api/corona.png", a.corona_png),
        Route("/api/profiles", a.profiles),
        Route("/api/material", a.material),
        Route("/api/kernel.{fmt:str}", a.kernel),
        Route("/api/kernel_info", a.kernel_info),
        Route("/api/progress", a.progress),
        Route("/api/upload", a.upload, methods=["POST"]),
        Route("/api/fit", a.fit, methods=["POST"]),
        Mount("/static", StaticFiles(directory=STATIC), name="static"),
    ]
    async def not_found(request, exc):
        return _error(404, f"no such page: {request.url.path}")

    async def bad_method(request, exc):
        return _error(405, f"{request.method} is not allowed on {request.url.path}")

    app = Starlette(routes=routes,
                    middleware=[Middleware(TrustedHostMiddleware, allowed_hosts=list(allowed_hosts))],
                    exception_handlers={404: not_found, 405: bad_method})
    app.state.slots = a.slots        # the computations running now, and the most at once
    return app
