"""Does `sebvs view --serve` work on a headless machine? Serve a replayed nav episode, open
the web viewer's page in headless Chromium, wait until the viewer has started, and save a
screenshot (docs/figures/view_web.png); print JSON.

    python tools/checks/view_web_check.py [--episode EP.h5] [--out docs/figures/view_web.png]

Without --episode it records one short nav episode first (`sebvs record
topologies/nav_record.toml`, a few seconds). Needs Chromium and its driver, which `make
test` and CI do not: on Debian `apt-get install chromium chromium-driver`. The browser is
driven through chromedriver's WebDriver HTTP API (the standard library is enough), with a
fresh profile and no network: the page, its wasm and the data all come from the
`sebvs view --serve` process on 127.0.0.1.

What counts: the page reports the app started (the viewer's `window._handle`), no panic or
load error is shown, and the screenshot is not the loading screen. That the entities are
listed is read off the screenshot (the viewer draws into a canvas: there is no DOM to
query); the JSON says which renderer the browser offered.
"""
from __future__ import annotations

import argparse
import base64
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from sebvs.runtime.ports import free_port_block  # noqa: E402

CHROMIUM = ("/usr/lib/chromium/chromium", "chromium", "chromium-browser", "google-chrome")
# a headless browser on a box without network. WebGL2 comes from SwiftShader: Chromium
# 156 falls back to it even without the last two flags (tried), older ones need them
BROWSER_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                "--no-first-run", "--disable-background-networking",
                "--disable-component-update", "--disable-sync", "--window-size=1400,900",
                "--use-angle=swiftshader", "--enable-unsafe-swiftshader"]
STARTED_JS = "return Boolean(window._handle)"
ERROR_JS = ("var t = document.getElementById('center_text');"
            "return t ? t.innerText : ''")
GL_JS = """
var c = document.createElement('canvas');
var out = {webgpu: Boolean(navigator.gpu)};
for (var kind of ['webgl2', 'webgl']) {
  var gl = c.getContext(kind);
  if (!gl) { out[kind] = null; continue; }
  var ext = gl.getExtension('WEBGL_debug_renderer_info');
  out[kind] = ext ? gl.getParameter(ext.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER);
}
return out;
"""


def find_browser() -> str:
    for name in CHROMIUM:
        path = shutil.which(name) or (name if os.access(name, os.X_OK) else None)
        if path:
            return path
    raise SystemExit("no Chromium found: apt-get install chromium chromium-driver")


def record_episode(workdir: Path) -> Path:
    out = workdir / "ds"
    subprocess.run([sys.executable, "-m", "sebvs.cli", "record", "topologies/nav_record.toml",
                    "--episodes", "1", "--out", str(out), "--runs-dir", str(workdir / "runs"),
                    "--quiet", "--set", "sim.episode_s=4.0", "--set", "sim.randomise={}"],
                   cwd=ROOT, check=True, env={**os.environ, "MUJOCO_GL": "egl"})
    return out / "episode_0000.h5"


class WebDriver:
    """The few WebDriver commands this check needs, over chromedriver's HTTP API."""

    def __init__(self, port: int, browser: str, profile: Path) -> None:
        self.base = f"http://127.0.0.1:{port}"
        self.session = ""
        self.proc = subprocess.Popen([shutil.which("chromedriver") or "chromedriver",
                                      f"--port={port}"], stdout=subprocess.DEVNULL,
                                     stderr=subprocess.DEVNULL)
        deadline = time.monotonic() + 20
        while True:
            try:
                self._call("GET", "/status")
                break
            except OSError:
                if time.monotonic() > deadline or self.proc.poll() is not None:
                    raise SystemExit("chromedriver did not start")
                time.sleep(0.2)
        caps = {"browserName": "chrome",
                "goog:chromeOptions": {"binary": browser,
                                       "args": BROWSER_ARGS + [f"--user-data-dir={profile}"]},
                "goog:loggingPrefs": {"browser": "ALL"}}
        try:
            self.session = self._call("POST", "/session",
                                      {"capabilities": {"alwaysMatch": caps}})["sessionId"]
        except OSError:
            self.proc.terminate()
            raise

    def _call(self, method: str, path: str, body: dict | None = None):
        data = None if body is None else json.dumps(body).encode()
        req = urllib.request.Request(self.base + path, data=data, method=method,
                                     headers={"Content-Type": "application/json"})
        with urllib.request.urlopen(req, timeout=120) as resp:
            return json.loads(resp.read())["value"]

    def cmd(self, method: str, path: str, body: dict | None = None):
        return self._call(method, f"/session/{self.session}{path}", body)

    def run_js(self, script: str):
        return self.cmd("POST", "/execute/sync", {"script": script, "args": []})

    def close(self) -> None:
        try:
            self.cmd("DELETE", "")
        except OSError:
            pass
        self.proc.terminate()
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            self.proc.kill()


def check(episode: Path, out: Path, wait_s: float) -> dict:
    ports = free_port_block(3)
    profile = Path(tempfile.mkdtemp(prefix="view-web-check-"))
    summary_json = profile / "summary.json"
    view = subprocess.Popen([sys.executable, "-m", "sebvs.cli", "view", str(episode),
                             "--serve", "--grpc-port", str(ports), "--web-port",
                             str(ports + 1), "--json", str(summary_json)], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    result: dict = {"episode": str(episode)}
    driver = None
    try:
        url, summary = None, []
        for line in view.stdout:
            summary.append(line.rstrip())
            if "web viewer at " in line:
                url = line.split("web viewer at ", 1)[1].strip()
            if "serving" in line:
                break
        if url is None:
            raise SystemExit("sebvs view --serve did not start:\n" + "\n".join(summary))
        result["url"] = url
        result["entities"] = json.loads(summary_json.read_text())["entities"]
        driver = WebDriver(ports + 2, find_browser(), profile)
        t0 = time.monotonic()
        driver.cmd("POST", "/url", {"url": url})
        started = False
        while time.monotonic() - t0 < wait_s:
            started = bool(driver.run_js(STARTED_JS))
            if started or "error" in driver.run_js(ERROR_JS).lower():
                break
            time.sleep(0.5)
        result["started"] = started
        result["seconds_to_start"] = round(time.monotonic() - t0, 1)
        if started:
            time.sleep(8)      # the data streams in and the views lay themselves out
        result["page_error"] = driver.run_js(ERROR_JS).strip()
        result["graphics"] = driver.run_js(GL_JS)
        png = base64.b64decode(driver.cmd("GET", "/screenshot"))
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_bytes(png)
        result["screenshot"] = str(out.relative_to(ROOT) if out.is_relative_to(ROOT) else out)
        result["screenshot_bytes"] = len(png)
        try:
            logs = driver.cmd("POST", "/se/log", {"type": "browser"})
        except OSError:
            logs = []
        result["console_errors"] = [l["message"][:200] for l in logs
                                    if l.get("level") == "SEVERE"][:10]
    finally:
        if driver is not None:
            driver.close()
        view.terminate()         # SIGTERM: sebvs view stops its rerun server and exits
        try:
            view.wait(15)
        except subprocess.TimeoutExpired:
            view.kill()
        shutil.rmtree(profile, ignore_errors=True)
    result["viewer_exit_code"] = view.returncode
    result["ok"] = bool(result.get("started")) and not result.get("page_error")
    return result


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--episode", type=Path, help="episode file (default: record one)")
    p.add_argument("--out", type=Path, default=ROOT / "docs" / "figures" / "view_web.png")
    p.add_argument("--wait", type=float, default=90.0,
                   help="seconds to wait for the viewer to start in the browser")
    args = p.parse_args()
    with tempfile.TemporaryDirectory(prefix="view-web-") as tmp:
        episode = args.episode or record_episode(Path(tmp))
        result = check(episode, args.out.resolve(), args.wait)
    print(json.dumps(result, indent=2))
    return 0 if result["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
