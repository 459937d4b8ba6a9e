"""A headless Chromium driven over the DevTools protocol through a pipe (``--remote-debugging-pipe``).

Why a pipe: the protocol's messages go over two inherited file descriptors (3: commands in, 4: replies
out, each message JSON ended by a NUL byte), so there is no port to pick or race for, no websocket
client to depend on, and nothing listens on the network. The same protocol gives what the tests need:
console messages and uncaught exceptions as events, every request the page makes (to prove it stays
offline), ``Runtime.evaluate`` to read the DOM after the page's scripts ran, and screenshots.

The browser is Debian's ``chromium`` (``apt-get install -y chromium``); ``find_chromium`` looks for it.
"""

import base64
import json
import os
import shutil
import subprocess
import tempfile
import time

#: Flags for a quiet, offline, throw-away browser: no sandbox (tests run as root in CI), no GPU, no
#: background traffic (component updates, sync, safe browsing...), a fresh profile every launch.
FLAGS = (
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
    "--disable-component-update", "--disable-sync", "--no-first-run", "--no-default-browser-check",
    "--disable-extensions", "--disable-default-apps", "--mute-audio", "--hide-scrollbars",
    "--remote-debugging-pipe",
)
CANDIDATES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


def find_chromium():
    """Path of a Chromium binary (``$FACECAP_CHROMIUM`` first), or None."""
    env = os.environ.get("FACECAP_CHROMIUM")
    if env:
        return env if os.path.isfile(env) else None
    return next((p for p in map(shutil.which, CANDIDATES) if p), None)


class BrowserError(RuntimeError):
    pass


class Browser:
    """One headless Chromium with one page (tab); use as a context manager.

    ``events`` collects every protocol event of the page's session (console calls, exceptions, log
    entries, requests) in arrival order.
    """

    def __init__(self, binary, *, width=1280, height=900, timeout=60.0):
        self.timeout = timeout
        self.profile = tempfile.mkdtemp(prefix="facecap-chromium-")
        self._log = open(os.path.join(self.profile, "stderr.log"), "w+b")  # a file: a full pipe would block it
        cmd_r, cmd_w = os.pipe()  # we write commands, the browser reads fd 3
        out_r, out_w = os.pipe()  # the browser writes replies on fd 4
        env = {k: v for k, v in os.environ.items() if k not in ("http_proxy", "https_proxy", "HTTP_PROXY",
                                                                  "HTTPS_PROXY")}

        def wire_fds():  # in the child, before exec: the protocol's descriptors are 3 and 4
            a, b = os.dup(cmd_r), os.dup(out_w)  # first out of the way: cmd_r or out_w may be 3 or 4
            os.dup2(a, 3)  # dup2 makes 3 and 4 inheritable
            os.dup2(b, 4)

        self.proc = subprocess.Popen(
            [binary, *FLAGS, f"--user-data-dir={self.profile}", f"--window-size={width},{height}", "about:blank"],
            stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=self._log,
            close_fds=False,  # Python's own descriptors are not inheritable (PEP 446): only 3 and 4 pass
            preexec_fn=wire_fds, env=env)
        os.close(cmd_r)
        os.close(out_w)
        self._send_fd, self._recv = cmd_w, os.fdopen(out_r, "rb", buffering=0)
        self._buffer, self._next_id, self.events = b"", 0, []
        self.session = None

    # -- protocol ------------------------------------------------------------------------------------
    def _read_message(self, deadline):
        while b"\0" not in self._buffer:
            if time.monotonic() > deadline:
                raise BrowserError("timed out waiting for the browser")
            chunk = self._recv.read(1 << 16)
            if not chunk:
                self._log.seek(0)
                err = self._log.read().decode(errors="replace")[-2000:]
                raise BrowserError(f"the browser closed its pipe (exit {self.proc.poll()}): {err}")
            self._buffer += chunk
        message, self._buffer = self._buffer.split(b"\0", 1)
        return json.loads(message)

    def call(self, method, params=None, *, session=True, timeout=None):
        """Send one command and return its result (events meanwhile go to ``events``)."""
        self._next_id += 1
        message = {"id": self._next_id, "method": method, "params": params or {}}
        if session and self.session:
            message["sessionId"] = self.session
        os.write(self._send_fd, json.dumps(message).encode() + b"\0")
        deadline = time.monotonic() + (timeout or self.timeout)
        while True:
            reply = self._read_message(deadline)
            if reply.get("id") == self._next_id:
                if "error" in reply:
                    raise BrowserError(f"{method}: {reply['error']}")
                return reply.get("result", {})
            if "method" in reply:
                self.events.append(reply)

    def wait_event(self, method, timeout=None):
        deadline = time.monotonic() + (timeout or self.timeout)
        seen = len(self.events)
        while True:
            for event in self.events[seen:]:
                if event["method"] == method:
                    return event
            seen = len(self.events)
            reply = self._read_message(deadline)
            if "method" in reply:
                self.events.append(reply)

    # -- page ----------------------------------------------------------------------------------------
    def __enter__(self):
        target = self.call("Target.createTarget", {"url": "about:blank"}, session=False)["targetId"]
        self.session = self.call("Target.attachToTarget", {"targetId": target, "flatten": True},
                                 session=False)["sessionId"]
        for domain in ("Page", "Runtime", "Log", "Network"):
            self.call(f"{domain}.enable")
        # no network at all: any request that is not file:, data: or blob: fails
        self.call("Network.emulateNetworkConditions", {"offline": True, "latency": 0, "downloadThroughput": -1,
                                                       "uploadThroughput": -1})
        return self

    def __exit__(self, *exc):
        try:
            self.call("Browser.close", session=False, timeout=10)
        except (BrowserError, OSError):
            pass
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        os.close(self._send_fd)
        self._recv.close()
        self._log.close()
        shutil.rmtree(self.profile, ignore_errors=True)

    def open(self, url, *, ready="window.facecapReady === true", timeout=None):
        """Navigate to ``url``, wait for its load event and then until the JS expression ``ready`` is true."""
        self.call("Page.navigate", {"url": url})
        self.wait_event("Page.loadEventFired", timeout)
        deadline = time.monotonic() + (timeout or self.timeout)
        while not self.evaluate(ready):
            if time.monotonic() > deadline:
                raise BrowserError(f"{url}: '{ready}' never became true; errors: {self.errors()}")
            time.sleep(0.05)

    def evaluate(self, expression, *, await_promise=False):
        """The value of a JS expression in the page (JSON-serialisable results)."""
        result = self.call("Runtime.evaluate", {"expression": expression, "returnByValue": True,
                                                "awaitPromise": await_promise})
        if "exceptionDetails" in result:
            raise BrowserError(f"{expression[:80]}: {result['exceptionDetails'].get('exception', {})}")
        return result["result"].get("value")

    def screenshot(self):
        """PNG bytes of the whole page (not just the window)."""
        metrics = self.call("Page.getLayoutMetrics")
        size = metrics.get("cssContentSize") or metrics["contentSize"]
        clip = {"x": 0, "y": 0, "width": size["width"], "height": size["height"], "scale": 1}
        data = self.call("Page.captureScreenshot", {"format": "png", "clip": clip, "captureBeyondViewport": True})
        return base64.b64decode(data["data"])

    def errors(self):
        """Console errors and warnings, uncaught exceptions and failed loads (one line each)."""
        out = []
        for event in self.events:
            method, params = event["method"], event.get("params", {})
            if method == "Runtime.exceptionThrown":
                details = params["exceptionDetails"]
                out.append(f"exception: {details.get('exception', {}).get('description') or details.get('text')}")
            elif method == "Runtime.consoleAPICalled" and params.get("type") in ("error", "warning", "assert"):
                text = " ".join(str(a.get("value", a.get("description", ""))) for a in params.get("args", []))
                out.append(f"console.{params['type']}: {text}")
            elif method == "Log.entryAdded" and params["entry"].get("level") in ("error", "warning"):
                out.append(f"log: {params['entry'].get('text')} {params['entry'].get('url', '')}")
            elif method == "Network.loadingFailed":
                out.append(f"load failed: {params.get('errorText')}")
        return out

    def requested_urls(self):
        return [e["params"]["request"]["url"] for e in self.events if e["method"] == "Network.requestWillBeSent"]
