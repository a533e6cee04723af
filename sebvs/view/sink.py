"""Where the viewer's recording goes: a file, a web viewer served from here, or a native
viewer window.

The web viewer is the rerun command line's own (`rerun --serve-web`), run as a child
process bound to loopback: rerun's Python `serve_grpc` / `serve_web_viewer` listen on
every interface and take no bind address. The page and its wasm come from that child
(shipped inside rerun-sdk), so a machine without network serves it whole.
"""
from __future__ import annotations

import importlib.util
import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from urllib.parse import quote

LOOPBACK = "127.0.0.1"
START_TIMEOUT_S = 30.0      # the rerun binary is ~300 MB: its first start reads it all


class ViewerError(RuntimeError):
    """A sink that cannot be opened; the message is the one line the user sees."""


def rerun_executable() -> str:
    """The `rerun` binary of the installed rerun-sdk (rerun_cli), else one on PATH."""
    spec = importlib.util.find_spec("rerun_cli")
    if spec and spec.origin:
        exe = Path(spec.origin).parent / "rerun"
        if exe.is_file() and os.access(exe, os.X_OK):
            return str(exe)
    found = shutil.which("rerun")
    if found:
        return found
    raise ViewerError("the rerun viewer binary (package rerun-sdk's rerun_cli) is not "
                      "installed: pip install 'sebvs[view]'")


def save_to(rec, path: str | Path) -> None:
    path = Path(path)
    if not path.parent.is_dir():
        raise ViewerError(f"--save {path}: directory {path.parent} does not exist")
    try:
        rec.save(str(path))
    except RuntimeError as exc:     # rerun's error when it cannot create the file
        raise ViewerError(f"--save {path}: {str(exc).splitlines()[0]}") from None


def spawn_native(rec) -> None:
    """A native viewer window (rerun.spawn), or ViewerError where there is no display."""
    if sys.platform.startswith("linux") and not (os.environ.get("DISPLAY")
                                                 or os.environ.get("WAYLAND_DISPLAY")):
        raise ViewerError("no display for the native viewer (DISPLAY and WAYLAND_DISPLAY "
                          "are unset): write a file with --save FILE.rrd, or serve the "
                          "web viewer with --serve")
    try:
        rec.spawn(executable_path=rerun_executable())
    except RuntimeError as exc:
        raise ViewerError(f"cannot start the native viewer: {str(exc).splitlines()[0]}") \
            from None


def _accepts(port: int) -> bool:
    with socket.socket() as s:
        s.settimeout(0.5)
        return s.connect_ex((LOOPBACK, port)) == 0


class WebViewer:
    """`rerun --serve-web` on loopback: a gRPC proxy the recording streams into (it keeps
    the data for viewers that open the page later) and the web viewer's page."""

    def __init__(self, grpc_port: int = 9876, web_port: int = 9090) -> None:
        self.grpc_port, self.web_port = grpc_port, web_port
        self.proc: subprocess.Popen | None = None
        self.log = None

    @property
    def grpc_url(self) -> str:
        return f"rerun+http://{LOOPBACK}:{self.grpc_port}/proxy"

    @property
    def page_url(self) -> str:
        return f"http://{LOOPBACK}:{self.web_port}/?url={quote(self.grpc_url, safe='')}"

    def start(self) -> "WebViewer":
        from sebvs.runtime.ports import bindable
        for flag, port in (("--grpc-port", self.grpc_port), ("--web-port", self.web_port)):
            if not bindable(LOOPBACK, range(port, port + 1)):
                raise ViewerError(f"port {port} on {LOOPBACK} is in use: choose another "
                                  f"with {flag}")
        self.log = tempfile.TemporaryFile()
        cmd = [rerun_executable(), "--serve-web", "--bind", LOOPBACK,
               "--port", str(self.grpc_port), "--web-viewer-port", str(self.web_port)]
        # RERUN_APP_ONLY: what rerun.spawn sets for the viewers it starts (no opt-in prompt)
        self.proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=self.log,
                                     stderr=subprocess.STDOUT,
                                     env={**os.environ, "RERUN_APP_ONLY": "true"})
        deadline = time.monotonic() + START_TIMEOUT_S
        while not (_accepts(self.grpc_port) and _accepts(self.web_port)):
            if self.proc.poll() is not None or time.monotonic() > deadline:
                tail = self._log_tail()
                self.stop()
                raise ViewerError(f"rerun --serve-web did not start: {tail}")
            time.sleep(0.1)
        return self

    def _log_tail(self) -> str:
        if self.log is None:
            return ""
        self.log.seek(0)
        lines = [l for l in self.log.read().decode("utf-8", "replace").splitlines() if l.strip()]
        return lines[-1].strip() if lines else "(no output)"

    def stop(self) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.proc = None
        if self.log is not None:
            self.log.close()
            self.log = None
