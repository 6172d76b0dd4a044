"""``corona designer``: a look-development page in the browser.

    corona designer [--host 127.0.0.1] [--port 8765]

A local web server (Starlette + uvicorn, the ``designer`` extra:
``pip install 'corona-bsdf[designer]'``) and a static page with plain
JavaScript: controls for every material parameter of
:data:`corona.parameters.PARAMETERS`, the light, live views (the far-field
corona, T_a / T_s / lobe profiles, the energy split, a comparison of two
materials), a photograph with the ring radii, and exports (XML, ``load_dict``,
``corona lobe``, the corona kernel as PNG/EXR).  The HTTP API is documented
in docs/designer.md ("The HTTP API").

``import corona`` does not import this package; this package imports the web
libraries only in :func:`create_app` and :func:`serve`.
"""
from __future__ import annotations

import socket

__all__ = ["create_app", "serve", "bind", "running"]


def create_app(*args, **kwargs):
    """The Starlette app (see :func:`corona.apps.designer.app.create_app`)."""
    from corona.apps.designer.app import create_app as _create_app
    return _create_app(*args, **kwargs)


def bind(host: str = "127.0.0.1", port: int = 8765) -> socket.socket:
    """A listening socket on ``host:port`` (port 0: any free port); OSError if taken."""
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
        sock.listen(64)
    except OSError:
        sock.close()
        raise
    return sock


def allowed_hosts_for(host: str) -> list[str]:
    """Host headers to answer when listening on ``host``: the loopback names, plus
    ``host`` itself; everything when listening on all interfaces."""
    if host in ("0.0.0.0", "::", ""):
        return ["*"]
    host = host.strip("[]")
    return sorted({"127.0.0.1", "localhost", "[::1]", f"[{host}]" if ":" in host else host})


def warm_up() -> None:
    """Compute the first preset once in a background thread: imports, shipped
    tables and the first material are then ready when the page asks."""
    import threading

    def go():
        from corona.apps.designer import compute
        pr = next(iter(compute.PRESETS.values()))
        try:
            compute.corona_png(pr["material"], {**pr["view"], "size": 64})
            compute.profiles(pr["material"], pr["view"])
        except Exception:  # noqa: BLE001 - only a warm-up; the request will report it
            pass
    threading.Thread(target=go, name="corona-designer-warm-up", daemon=True).start()


def serve(sock: socket.socket, host: str = "127.0.0.1") -> None:
    """Serve the designer on the bound ``sock`` until interrupted (uvicorn)."""
    import uvicorn
    warm_up()
    app = create_app(allowed_hosts=allowed_hosts_for(host))
    config = uvicorn.Config(app, log_level="warning", limit_concurrency=32, timeout_keep_alive=5)
    uvicorn.Server(config).run(sockets=[sock])


class running:
    """Context manager: the designer served from a background thread (tests, scripts).

    ``with running() as url: ...`` listens on 127.0.0.1 at a free port and
    stops the server (and waits at most ``stop_timeout`` s for it) on exit.
    """

    def __init__(self, host: str = "127.0.0.1", port: int = 0, start_timeout: float = 30.0,
                 stop_timeout: float = 10.0):
        self.host, self.port = host, port
        self.start_timeout, self.stop_timeout = start_timeout, stop_timeout

    def __enter__(self) -> str:
        import threading
        import time

        import uvicorn
        self.sock = bind(self.host, self.port)
        warm_up()
        app = create_app(allowed_hosts=allowed_hosts_for(self.host))
        self.server = uvicorn.Server(uvicorn.Config(app, log_level="warning", limit_concurrency=32))
        self.thread = threading.Thread(target=self.server.run, kwargs={"sockets": [self.sock]},
                                       name="corona-designer", daemon=True)
        self.thread.start()
        t_end = time.monotonic() + self.start_timeout
        while not self.server.started:
            if time.monotonic() > t_end or not self.thread.is_alive():
                self.__exit__(None, None, None)
                raise RuntimeError("the designer server did not start")
            time.sleep(0.02)
        return f"http://{self.host}:{self.sock.getsockname()[1]}/"

    def __exit__(self, *exc):
        self.server.should_exit = True
        self.thread.join(timeout=self.stop_timeout)
        self.sock.close()
        return False
