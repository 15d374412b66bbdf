"""Screenshots for the documentation, taken in a headless Chromium (not part of the site's build, which needs no
browser; run by hand when what they show changes):

    python docs/screenshots.py tensorboard      # docs/assets/tensorboard.png, for the Monte Carlo how-to
    python docs/screenshots.py site SITE OUT    # the built site's main pages as PNGs in OUT, to look at

``tensorboard`` runs a Monte Carlo study of the paper's Example 1 (100 realisations, seed 1) into a temporary
folder, serves it with TensorBoard on a free local port and photographs its CUSTOM SCALARS tab (the fan charts).
``site`` serves a built site (``mkdocs build --site-dir SITE``) on a free local port and photographs each page named
in :data:`PAGES`, the full width of a laptop's screen. Chromium: ``chromium`` on the PATH, or ``--chromium PATH``.
"""
from __future__ import annotations

import argparse
import functools
import http.server
import shutil
import socket
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
#: The pages of the built site photographed by ``site``: (file name, path on the site, window height in pixels).
PAGES = [("home", "", 1400), ("tutorial", "tutorial/", 2600), ("check-guide", "guide/check/", 2600),
         ("export-guide", "guide/export/", 2600), ("effects", "reference/effects/", 2000),
         ("cli", "reference/cli/", 1400), ("model", "explanation/model/", 2000), ("bag", "howto/bag-to-kalibr/", 2600),
         ("montecarlo", "howto/montecarlo/", 1800), ("studies", "studies/", 1400), ("check-study", "studies/check/", 2000)]
#: What Chromium needs to start headless on a machine with no network and no screen, as root too.
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
         "--disable-background-networking", "--disable-component-update", "--disable-sync", "--hide-scrollbars"]


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def wait_for(url: str, seconds: float = 60.0) -> None:
    """Until ``url`` answers (a server just started), or a RuntimeError after ``seconds``."""
    end = time.monotonic() + seconds
    while True:
        try:
            with urllib.request.urlopen(url, timeout=2):
                return
        except OSError:
            if time.monotonic() > end:
                raise RuntimeError(f"{url} did not answer within {seconds:g} s") from None
            time.sleep(0.5)


def shoot(chromium: str, url: str, out: Path, width: int, height: int, wait_ms: int) -> None:
    """A PNG of ``url`` as a window of ``width`` × ``height`` shows it, after ``wait_ms`` of the page's own time (its
    scripts run, its charts drawn)."""
    with tempfile.TemporaryDirectory() as profile:
        run = subprocess.run([chromium, *FLAGS, f"--user-data-dir={profile}", f"--window-size={width},{height}",
                              f"--virtual-time-budget={wait_ms}", f"--screenshot={out}", url],
                             capture_output=True, text=True, timeout=120)
    if run.returncode or not out.is_file():
        raise RuntimeError(f"chromium could not photograph {url}: {run.stderr.strip()[-500:]}")


def tensorboard(chromium: str, out: Path) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as work:
        subprocess.run([sys.executable, "-c", "import sys; from torchtea.cli import main; sys.exit(main())", "montecarlo", "--preset", "paper-example1",
                        "--realisations", "100", "--seed", "1", "--logdir", "runs/ex1"], cwd=work, check=True,
                       stdout=subprocess.DEVNULL)
        port = free_port()
        server = subprocess.Popen([sys.executable, "-m", "tensorboard.main", "--logdir", "runs", "--host",
                                   "127.0.0.1", "--port", str(port)], cwd=work, stdout=subprocess.DEVNULL,
                                  stderr=subprocess.DEVNULL)
        try:
            wait_for(f"http://127.0.0.1:{port}/")
            shoot(chromium, f"http://127.0.0.1:{port}/?darkMode=false#custom_scalars", out, 1400, 1000, 30000)
        finally:
            server.terminate()
            server.wait(timeout=30)
    print(f"wrote {out}")


def site(chromium: str, built: Path, out: Path) -> None:
    if not (built / "index.html").is_file():
        raise SystemExit(f"{built}: no built site there (mkdocs build --site-dir {built})")
    out.mkdir(parents=True, exist_ok=True)
    class Quiet(http.server.SimpleHTTPRequestHandler):
        def log_message(self, *args) -> None:  # (no line per request)
            pass

    handler = functools.partial(Quiet, directory=str(built))
    with http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler) as server:
        threading.Thread(target=server.serve_forever, daemon=True).start()
        port = server.server_address[1]
        for name, path, height in PAGES:
            shoot(chromium, f"http://127.0.0.1:{port}/{path}", out / f"{name}.png", 1280, height, 5000)
            print(f"wrote {out / name}.png ({path or 'home'})")
        server.shutdown()


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("what", choices=["tensorboard", "site"])
    parser.add_argument("paths", nargs="*", help="site: the built site's folder and the folder for the PNGs")
    parser.add_argument("--chromium", default=shutil.which("chromium") or shutil.which("chromium-browser"))
    args = parser.parse_args(argv)
    if not args.chromium:
        raise SystemExit("no Chromium found: install it (Debian: apt install chromium) or give --chromium PATH")
    if args.what == "tensorboard":
        tensorboard(args.chromium, ROOT / "docs" / "assets" / "tensorboard.png")
    else:
        if len(args.paths) != 2:
            raise SystemExit("site needs two paths: the built site's folder and the folder for the PNGs")
        site(args.chromium, Path(args.paths[0]), Path(args.paths[1]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
