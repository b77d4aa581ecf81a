"""`drovisio serve`: run the web tool with uvicorn and say where to open it."""

from __future__ import annotations

import argparse
import socket
import sys
import threading
from pathlib import Path
from typing import TYPE_CHECKING

from drovisio.errors import InputError
from drovisio.pipeline import STOP_WAIT_S
from drovisio.resources import sample_sessions_dir, user_data_dir
from drovisio.startup import check_pipeline_options
from webtool.access import access_lines, install_log_redaction
from webtool.settings import Settings, is_loopback

if TYPE_CHECKING:
    from fastapi import FastAPI


def _url_host(host: str) -> str:
    return f"[{host}]" if ":" in host and not host.startswith("[") else host


def _lan_address() -> str | None:
    """This machine's address on its default route, without sending anything."""
    try:
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.connect(("192.0.2.1", 9))  # TEST-NET-1: UDP connect sends no packet
            addr = s.getsockname()[0]
    except OSError:
        return None
    return None if addr.startswith("127.") or addr == "0.0.0.0" else addr


def open_lines(settings: Settings) -> list[str]:
    """What to print so that a person knows which URL to open."""
    port = settings.port
    query = f"?token={settings.token}" if settings.token else ""
    if settings.host in ("0.0.0.0", "::", ""):
        lines = [f"Drovisio web tool: open http://127.0.0.1:{port}/ on this machine"]
        hosts = [socket.gethostname()]
        lan = _lan_address()
        if lan:
            hosts.append(lan)
        for h in hosts:
            lines.append(f"  from another device on the network: http://{_url_host(h)}:{port}/{query}")
    else:
        lines = [f"Drovisio web tool: open http://{_url_host(settings.host)}:{port}/{query}"]
    if settings.token and not is_loopback(settings.host):
        lines.append("  (listening beyond this machine: other devices need a token link; a "
                     "phone can scan a code below)")
        if settings.host in ("0.0.0.0", "::", ""):
            lan = _lan_address()
            base = f"http://{_url_host(lan or socket.gethostname())}:{port}/"
        else:
            base = f"http://{_url_host(settings.host)}:{port}/"
        lines.extend(access_lines(base, settings.token, settings.viewer_token))
    return lines


def _warm_up_in_background() -> threading.Thread:
    """Load (or, the first time on a machine, compile) the detectors' kernels while the
    server starts, so that the live view's first frame does not wait for them."""

    def work() -> None:
        try:
            # deferred: loading the detectors is the slow part this thread takes off the start
            from drovisio.detect.warmup import warm_up

            warm_up()
        except Exception as e:  # noqa: BLE001 - the detectors then compile on first use
            print(f"  (detector warm-up failed: {e}; they will compile on first use)",
                  flush=True)

    th = threading.Thread(target=work, name="detector-warm-up", daemon=True)
    th.start()
    return th


def _finish_warm_up(th: threading.Thread) -> None:
    """Wait for a warm-up still compiling when the server stops: a thread left in native
    code while the interpreter exits aborts the process."""
    if not th.is_alive():
        return
    print("  waiting for the detectors' kernels to finish compiling (the first time on this "
          "machine)...", flush=True)
    th.join(STOP_WAIT_S)
    if th.is_alive():
        print(f"  (the detectors' kernels did not finish compiling within {STOP_WAIT_S:.0f} s; "
              "exiting without them)", flush=True)


def _check_inputs(args: argparse.Namespace) -> None:
    """Bad set-up is said before the server starts (one line, exit 2), not on a page later:
    the pipeline's options through the one check ``run`` uses (sinks opened and closed)."""
    check_pipeline_options(args)
    if getattr(args, "replay_dir", None) and not Path(args.replay_dir).is_dir():
        raise InputError(f"{args.replay_dir}: --replay-dir: no such folder")


def _sample_missions() -> Path | None:
    """The shipped demo mission's folder (the replay panel's default), if installed."""
    d = sample_sessions_dir() / "missions"
    return d if d.is_dir() else None


def settings_from(args: argparse.Namespace) -> Settings:
    """The app's settings from ``drovisio serve``'s arguments."""
    return Settings(
        host=args.host,
        port=args.port,
        source=args.source,
        camera=Path(args.camera) if args.camera else None,
        layouts=[Path(x) for x in (getattr(args, "layout", None) or [])],
        mount=Path(args.mount) if getattr(args, "mount", None) else None,
        sinks=list(getattr(args, "sink", None) or []),
        target=getattr(args, "target", "nearest"),
        autopilot=getattr(args, "autopilot", "ardupilot"),
        record=Path(args.record) if getattr(args, "record", None) else None,
        record_images=getattr(args, "record_images", "jpeg"),
        drone_id=getattr(args, "drone_id", None),
        send_held_targets=bool(getattr(args, "send_held_targets", False)),
        max_age=getattr(args, "max_age", 0.5),
        data_dir=Path(args.data) if getattr(args, "data", None) else None,
        replay_dir=(Path(args.replay_dir) if getattr(args, "replay_dir", None)
                    else _sample_missions()),
    )


def run(args: argparse.Namespace) -> int:
    # deferred: the app loads only when serving (settings_from does not need it)
    from webtool.app import create_app

    _check_inputs(args)
    settings = settings_from(args)
    # A busy port is said before any address is printed (nothing to open there).
    _check_port(settings.host, settings.port)
    app = create_app(settings)
    src = settings.source_label
    print("\n".join(open_lines(settings)), flush=True)
    print(f"  source: {src}" + ("" if settings.source else "  (no --source given)"), flush=True)
    print(f"  data folder: {settings.data_dir or user_data_dir()}", flush=True)
    print("  stop with Ctrl+C", flush=True)
    warm_up = _warm_up_in_background()
    try:
        return _serve(app, settings)
    finally:
        _finish_warm_up(warm_up)


def _serve(app: FastAPI, settings: Settings) -> int:
    """Run the app with uvicorn until Ctrl+C or SIGTERM."""
    import uvicorn  # deferred: the server loads only when serving

    install_log_redaction()
    # a request still running at SIGTERM (a client that stalls, a slow route) delays the end
    # by at most this many seconds: uvicorn's default waits for it for ever
    server = uvicorn.Server(uvicorn.Config(app, host=settings.host, port=settings.port,
                                           log_level="info", timeout_graceful_shutdown=5))
    app.state.uvicorn_server = server  # the lifespan ends the server, never raises to it
    server.run()
    error = getattr(app.state, "startup_error", None)
    if error:
        raise InputError(error)
    return 0


def _check_zenoh_listen(endpoints: list[str]) -> None:
    """Say in one line that a station's Zenoh port is taken (Zenoh would log and go on deaf)."""
    for ep in endpoints:
        proto, _, addr = ep.partition("/")
        host, _, port = addr.rpartition(":")
        if proto not in ("tcp", "tls"):
            continue
        try:
            _check_port(host.strip("[]"), int(port))
        except InputError:
            raise InputError(f"--listen {ep}: cannot listen there: is another station "
                             "running? choose another port (the drones' zenoh:connect= "
                             "must name it)") from None


def run_station(args: argparse.Namespace) -> int:
    """``drovisio station``: the web tool as a ground station (its Fleet page)."""
    listen = list(args.listen or []) or (["tcp/0.0.0.0:7447"] if not args.connect else [])
    settings = Settings(host=args.host, port=args.port,
                        data_dir=Path(args.data) if args.data else None,
                        station_listen=listen, station_connect=list(args.connect or []),
                        station_domain=args.domain)
    _check_port(settings.host, settings.port)
    _check_zenoh_listen(listen)
    from webtool.app import create_app  # deferred: the app loads only when serving

    app = create_app(settings)
    lines = open_lines(settings)
    lines[0] = lines[0].replace("Drovisio web tool", "Drovisio station")
    print("\n".join(lines), flush=True)
    print(f"  the Fleet page: /fleet; drones connect to {', '.join(listen or args.connect)} "
          "(drovisio run ... --drone-id ID --sink zenoh:connect=tcp/THIS-MACHINE:PORT)",
          flush=True)
    print("  stop with Ctrl+C", flush=True)
    return _serve(app, settings)


def _check_port(host: str, port: int) -> None:
    """Say in one line that the port is taken (uvicorn would log and exit)."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)
    except socket.gaierror as e:
        raise InputError(f"--host {host}: not an address of this machine ({e})") from None
    family, kind, proto, _, addr = infos[0]
    with socket.socket(family, kind, proto) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(addr)
        except OSError as e:
            raise InputError(f"--host {host} --port {port}: cannot listen ({e.strerror or e});"
                             " is another drovisio serve running? choose another --port") \
                from None


if __name__ == "__main__":  # pragma: no cover
    from drovisio.cli import main  # deferred: the command line imports this module

    sys.exit(main(["serve", *sys.argv[1:]]))
