#!/usr/bin/env python3
"""Opens a report page in headless Chromium (Debian's `chromium`, DevTools protocol over a pipe)
and fails when it is broken: any uncaught exception, console error or error log entry, any
resource that fails to load (script, image, ...), an image that did not decode, a first screen
(the viewport screenshot) that is blank, expected text that is not rendered, an element that is
not on the first screen; optionally it clicks elements (--click) and checks expressions (--js-true).

    check_report_page.py out/demo/report.html --screenshot out/report_screenshot.png \
        --expect "Cells within" --first-screen "#verdict"

Prints one JSON object (errors, screenshot, pixel_std, elapsed_s, ...); exit 0 when the page is
right, 1 when it is broken (each problem is one line on stderr), 2 when Chromium cannot run.
"""
from __future__ import annotations

import argparse
import base64
import io
import json
import os
import select
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

# Below this standard deviation of the grey levels (0..1) the first screen counts as blank: a
# white page with one heading is ~0.02; an empty page is 0.
BLANK_STD = 0.01


class Browser:
    """Chromium with --remote-debugging-pipe: commands on its fd 3, answers and events on its fd 4,
    each a JSON message ended by a NUL byte."""

    def __init__(self, exe: str, width: int, height: int):
        self.profile = tempfile.mkdtemp(prefix="report-check-")
        cmd_r, self.cmd_w = os.pipe()
        self.ev_r, ev_w = os.pipe()

        def fds():  # in the child: the pipe ends as fds 3 and 4 (dup2 clears close-on-exec)
            a, b = os.dup(cmd_r), os.dup(ev_w)
            os.dup2(a, 3)
            os.dup2(b, 4)

        args = [exe, "--headless", "--no-sandbox", "--disable-gpu", "--remote-debugging-pipe",
                f"--user-data-dir={self.profile}", "--no-first-run", "--no-default-browser-check",
                "--disable-extensions", "--disable-background-networking", "--hide-scrollbars",
                # WebGL (the 3-D view) on the CPU: no GPU in CI.
                "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
                f"--window-size={width},{height}", "about:blank"]
        # Its own log to a file: a pipe nobody reads would fill up and stall it.
        self.log = open(Path(self.profile) / "chromium.log", "w+b")
        self.proc = subprocess.Popen(args, preexec_fn=fds, close_fds=False, stdin=subprocess.DEVNULL,
                                     stdout=subprocess.DEVNULL, stderr=self.log)
        os.close(cmd_r)
        os.close(ev_w)
        self.buf = b""
        self.next_id = 0
        self.events: list[dict] = []

    def close(self) -> None:
        try:
            self.send("Browser.close")
            self.proc.wait(timeout=5)
        except Exception:  # noqa: BLE001 - a dead browser is closed too
            self.proc.kill()
            self.proc.wait()
        for fd in (self.cmd_w, self.ev_r):
            try:
                os.close(fd)
            except OSError:
                pass
        self.log.close()
        shutil.rmtree(self.profile, ignore_errors=True)

    def send(self, method: str, params: dict | None = None, session: str | None = None) -> int:
        self.next_id += 1
        msg = {"id": self.next_id, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        os.write(self.cmd_w, json.dumps(msg).encode() + b"\0")
        return self.next_id

    def _read(self, timeout_s: float) -> dict | None:
        while b"\0" not in self.buf:
            ready, _, _ = select.select([self.ev_r], [], [], timeout_s)
            if not ready:
                return None
            chunk = os.read(self.ev_r, 1 << 16)
            if not chunk:
                self.proc.wait(timeout=5)
                self.log.seek(0)
                raise RuntimeError("chromium closed the DevTools pipe: " + self.log.read().decode(errors="replace")[-500:])
            self.buf += chunk
        raw, self.buf = self.buf.split(b"\0", 1)
        return json.loads(raw)

    def call(self, method: str, params: dict | None = None, session: str | None = None, timeout_s: float = 30.0) -> dict:
        want = self.send(method, params, session)
        deadline = time.monotonic() + timeout_s
        while True:
            msg = self._read(max(0.0, deadline - time.monotonic()))
            if msg is None:
                raise TimeoutError(f"no answer to {method} within {timeout_s} s")
            if msg.get("id") == want:
                if "error" in msg:
                    raise RuntimeError(f"{method}: {msg['error'].get('message')}")
                return msg.get("result", {})
            if "method" in msg:
                self.events.append(msg)

    def pump(self, seconds: float) -> None:
        """Collects events for ``seconds``."""
        deadline = time.monotonic() + seconds
        while (left := deadline - time.monotonic()) > 0:
            msg = self._read(left)
            if msg is None:
                return
            if "method" in msg:
                self.events.append(msg)

    def wait_event(self, name: str, timeout_s: float) -> bool:
        """Waits for an event ``name`` (or finds it among those already collected)."""
        deadline = time.monotonic() + timeout_s
        while not any(e["method"] == name for e in self.events):
            msg = self._read(max(0.0, deadline - time.monotonic()))
            if msg is None:
                return False
            if "method" in msg:
                self.events.append(msg)
        return True


def _errors(events: list[dict]) -> list[str]:
    """One line per problem the page reported: exceptions, console errors, error log entries
    (failed loads among them), failed requests."""
    urls, out = {}, []
    for e in events:
        m, p = e["method"], e.get("params", {})
        if m == "Network.requestWillBeSent":
            urls[p["requestId"]] = p["request"]["url"]
        elif m == "Runtime.exceptionThrown":
            d = p["exceptionDetails"]
            text = (d.get("exception") or {}).get("description") or d.get("text", "")
            out.append(f"uncaught exception: {text.splitlines()[0] if text else '?'} ({d.get('url', '')}:{d.get('lineNumber', '')})")
        elif m == "Runtime.consoleAPICalled" and p["type"] in ("error", "assert"):
            args = " ".join(str(a.get("value", a.get("description", ""))) for a in p.get("args", []))
            out.append(f"console.{p['type']}: {args}")
        elif m == "Log.entryAdded" and p["entry"]["level"] == "error":
            entry = p["entry"]
            out.append(f"{entry.get('source', 'log')} error: {entry.get('text', '')} {entry.get('url', '')}".rstrip())
        elif m == "Network.loadingFailed" and not p.get("canceled"):
            out.append(f"failed to load {urls.get(p['requestId'], p['requestId'])}: {p.get('errorText', '')}")
        elif m == "Network.responseReceived" and p["response"].get("status", 200) >= 400:
            out.append(f"HTTP {p['response']['status']} for {p['response']['url']}")
    return list(dict.fromkeys(out))  # a failed load is reported by the log and the network: once


def _pixel_std(png: bytes) -> float:
    import matplotlib.image as mpimg

    img = mpimg.imread(io.BytesIO(png), format="png")
    grey = img[..., :3].mean(axis=2) if img.ndim == 3 else img
    return float(grey.std())


EVAL_JS = """(() => {
  const vh = window.innerHeight;
  const broken = Array.from(document.images).filter(i => !i.complete || i.naturalWidth === 0).map(i => i.getAttribute('src'));
  const first = {};
  for (const sel of SELECTORS) {
    const el = document.querySelector(sel);
    if (!el) { first[sel] = 'missing'; continue; }
    const r = el.getBoundingClientRect();
    first[sel] = (r.height > 0 && r.top < vh && r.bottom > 0) ? 'visible' : `not on the first screen (top ${Math.round(r.top)} px)`;
  }
  const webgl = Array.from(document.querySelectorAll('canvas')).length;
  return {text: document.body ? document.body.innerText : '', broken, first, canvases: webgl, title: document.title};
})()"""


CLICK_JS = """(() => {
  const els = Array.from(document.querySelectorAll(%s));
  for (const el of els) el.dispatchEvent(new MouseEvent('click', {bubbles: true, cancelable: true, view: window}));
  return els.length;
})()"""


def check(page: Path, screenshot: Path | None, expect: list[str], first_screen: list[str], width: int, height: int,
          settle_s: float, exe: str, clicks: list[str] = (), js_true: list[str] = ()) -> dict:
    t0 = time.monotonic()
    b = Browser(exe, width, height)
    try:
        target = b.call("Target.createTarget", {"url": "about:blank"})["targetId"]
        session = b.call("Target.attachToTarget", {"targetId": target, "flatten": True})["sessionId"]
        for domain in ("Page", "Runtime", "Log", "Network"):
            b.call(f"{domain}.enable", session=session)
        b.call("Emulation.setDeviceMetricsOverride",
               {"width": width, "height": height, "deviceScaleFactor": 1, "mobile": False}, session=session)
        nav = b.call("Page.navigate", {"url": page.resolve().as_uri()}, session=session)
        errors = [f"navigation failed: {nav['errorText']}"] if nav.get("errorText") else []
        if not b.wait_event("Page.loadEventFired", 60.0):
            errors.append("the page did not finish loading within 60 s")
        # Two animation frames and a short wait: scripts that draw after load (plotly) have drawn.
        b.call("Runtime.evaluate", {"expression": "new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))",
                                    "awaitPromise": True}, session=session)
        b.pump(settle_s)
        state = b.call("Runtime.evaluate", {"expression": EVAL_JS.replace("SELECTORS", json.dumps(first_screen)),
                                            "returnByValue": True}, session=session)["result"]["value"]
        shot = base64.b64decode(b.call("Page.captureScreenshot", {"format": "png"}, session=session)["data"])
        # Then what a reader does: click (every element matching each selector, in page order),
        # and the page must still hold what it should (each expression true).
        for sel in clicks:
            n = b.call("Runtime.evaluate", {"expression": CLICK_JS % json.dumps(sel), "returnByValue": True},
                       session=session)["result"].get("value", 0)
            if not n:
                state["first"][sel] = "missing (nothing to click)"
        b.pump(settle_s if clicks else 0.1)
        for expr in js_true:
            got = b.call("Runtime.evaluate", {"expression": expr, "returnByValue": True}, session=session)
            if got["result"].get("value") is not True:
                state.setdefault("false", []).append(expr)
    finally:
        b.close()
    errors += _errors(b.events)
    errors += [f"image did not load: {src}" for src in state["broken"]]
    errors += [f"'{sel}' {where}" for sel, where in state["first"].items() if where != "visible"]
    errors += [f"text not rendered: {t!r}" for t in expect if t not in state["text"]]
    errors += [f"not true: {expr}" for expr in state.get("false", [])]
    std = _pixel_std(shot)
    if std < BLANK_STD:
        errors.append(f"the first screen is blank (grey level std {std:.4f} < {BLANK_STD})")
    if screenshot is not None:
        screenshot.parent.mkdir(parents=True, exist_ok=True)
        screenshot.write_bytes(shot)
    return {"page": str(page), "errors": errors, "screenshot": str(screenshot) if screenshot else None,
            "pixel_std": round(std, 4), "canvases": state["canvases"], "title": state["title"],
            "elapsed_s": round(time.monotonic() - t0, 2)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("page", type=Path)
    ap.add_argument("--screenshot", type=Path, help="write the first screen (PNG) here")
    ap.add_argument("--expect", action="append", default=[], help="text the rendered page must contain")
    ap.add_argument("--first-screen", action="append", default=[], help="CSS selector that must be on the first screen")
    ap.add_argument("--click", action="append", default=[], help="after the screenshot, click every element matching this CSS selector")
    ap.add_argument("--js-true", action="append", default=[], help="a JavaScript expression that must be true at the end")
    ap.add_argument("--width", type=int, default=1280)
    ap.add_argument("--height", type=int, default=900)
    ap.add_argument("--settle-s", type=float, default=1.0, help="wait after load for late drawing and errors")
    ap.add_argument("--chromium", default=os.environ.get("CHROMIUM", "chromium"))
    args = ap.parse_args()
    exe = shutil.which(args.chromium)
    if exe is None:
        print(f"error: {args.chromium} not found (Debian package chromium; scripts/setup.sh installs it)", file=sys.stderr)
        return 2
    if not args.page.is_file():
        print(f"error: {args.page} is not a file", file=sys.stderr)
        return 2
    try:
        result = check(args.page, args.screenshot, args.expect, args.first_screen, args.width, args.height,
                       args.settle_s, exe, args.click, args.js_true)
    except (RuntimeError, TimeoutError, OSError) as e:
        print(f"error: chromium: {e}", file=sys.stderr)
        return 2
    print(json.dumps(result))
    for line in result["errors"]:
        print(f"page error: {line}", file=sys.stderr)
    return 1 if result["errors"] else 0


if __name__ == "__main__":
    sys.exit(main())
