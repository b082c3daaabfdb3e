#!/usr/bin/env python3
"""Screenshot a (WebGL2) web page with Debian's headless Chromium. Python 3 standard library only.

usage: browser.py URL [--out shot.png] [--width 960 --height 540] [--timeout 60]
                  [--ready-expr JS] [--error-expr JS] [--status-expr JS] [--wait-expr JS]
                  [--status-json out.json] [--expect-error SUBSTRING] [--browser PATH]

Browser: Debian package `chromium-headless-shell` (apt-get install -y chromium-headless-shell; tried
with 156.0.8078.129-1~deb12u1 on bookworm-security). The full `chromium` package works too (then
`--headless` selects its new headless mode); $RELIEF_CHROMIUM, or --browser, names another binary.
The binaries under /usr/lib/chromium are preferred to Debian's /usr/bin wrappers (`sh` scripts
that do not always exec); the browser runs in a process group of its own, killed whole at the end,
so a wrapper would do no harm either.

How it talks to the browser: the DevTools protocol over a pipe (--remote-debugging-pipe: the browser
reads commands on fd 3 and writes replies and events on fd 4, each a JSON message ended by a NUL
byte). No websockets, no network port. Target.createTarget + Target.attachToTarget(flatten) give a
sessionId; Page/Runtime/Log are enabled on it and Page.navigate loads the URL.

WebGL: `--use-angle=swiftshader --enable-unsafe-swiftshader --ignore-gpu-blocklist --enable-webgl`
gives a software WebGL2 context (ANGLE on SwiftShader's Vulkan, a CPU rasteriser).
gl.getParameter(gl.RENDERER) says only "WebKit WebGL" and VERSION "WebGL 2.0 (OpenGL ES 3.0
Chromium)"; the WEBGL_debug_renderer_info extension's UNMASKED_RENDERER_WEBGL says
"ANGLE (Google, Vulkan 1.3.0 (SwiftShader Device (Subzero) (0x0000C0DE)), SwiftShader driver)",
MAX_TEXTURE_SIZE 8192. `--disable-gpu` must NOT be given: it takes WebGL away.
Viewport: Emulation.setDeviceMetricsOverride(width, height, scale 1) makes the screenshot exactly
width x height for both binaries (new-headless `chromium` refuses width/height in createTarget).
Timing (2-core box, trivial page): a whole run, browser start to profile removed, is ~0.4 s with
the headless shell (navigation to ready ~150 ms), ~1.7 s with the full `chromium` (~550-800 ms;
it also fetches /favicon.ico, a harmless 404 in the console lines). requestAnimationFrame runs at
about 60 Hz in both.

preserveDrawingBuffer: NOT needed. Page.captureScreenshot grabs the composited page, and the
compositor keeps the last frame a canvas presented, so a page that draws once (from a plain script,
not even in requestAnimationFrame) with preserveDrawingBuffer: false shows its drawing in the
screenshot, also seconds later. What the page must do is finish drawing before it says it is ready
(the ready expression), or the shot may hold an older frame. (canvas.toDataURL()/readPixels from a
later task are another matter: those do need preserveDrawingBuffer or a same-task read.)

Protocol of a run: navigate; every 100 ms evaluate --error-expr, --ready-expr and --status-expr;
  - error expr gives a non-empty string  -> print `page error: MSG`, exit 2 (with --expect-error SUB:
    exit 0 if MSG contains SUB, else exit 2);
  - ready expr is true -> (with --expect-error: exit 1, no error came) evaluate --wait-expr if given
    (a promise is awaited), write the status to --status-json, take the PNG, print
    `PATH BYTES bytes, ready in MS ms`, exit 0;
  - --timeout seconds pass -> print `timeout ... status: LAST`, exit 1.
Console messages, uncaught exceptions and browser log entries go to stderr, each line prefixed
`console:`. The browser is always killed and its temporary profile removed, and a watchdog kills it
at a hard deadline (timeout + 30 s) whatever happens, so a run never hangs.

Python API: run(url, out, width, height, timeout, ...) -> dict (see run's docstring)."""

import argparse
import base64
import fcntl
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time

DEFAULT_READY = "window.relief && window.relief.status && window.relief.status().complete === true"
DEFAULT_ERROR = "window.relief && window.relief.status && window.relief.status().error"
DEFAULT_STATUS = "JSON.stringify(window.relief ? window.relief.status() : null)"

CANDIDATES = [
    "/usr/lib/chromium/chromium-headless-shell",
    "/usr/lib/chromium/chromium",
    "chromium-headless-shell",
    "chromium",
    "chromium-browser",
    "google-chrome",
]

# Extra time, past the page timeout, for launching and tearing down the browser; the watchdog
# kills the browser when it runs out.
STARTUP_SLACK_S = 30.0


def find_browser(explicit=None):
    """The browser binary to run: explicit, $RELIEF_CHROMIUM, or the first of CANDIDATES found."""
    asked = explicit or os.environ.get("RELIEF_CHROMIUM")
    for c in [asked] if asked else CANDIDATES:
        p = c if os.sep in c else shutil.which(c)
        if p and os.path.isfile(p) and os.access(p, os.X_OK):
            return p
    if asked:
        raise FileNotFoundError(f"browser {asked!r} not found or not executable")
    raise FileNotFoundError(
        "no Chromium found (apt-get install -y chromium-headless-shell, or set RELIEF_CHROMIUM)")


def browser_flags(width, height, profile):
    return [
        "--headless",
        "--no-sandbox",
        "--use-angle=swiftshader",
        "--enable-unsafe-swiftshader",
        "--ignore-gpu-blocklist",
        "--enable-webgl",
        f"--user-data-dir={profile}",
        f"--window-size={width},{height}",
        "--hide-scrollbars",
        "--mute-audio",
        "--no-first-run",
        "--no-default-browser-check",
        "--remote-debugging-pipe",
        # keep the browser quiet on the network and steady in timing
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--disable-default-apps",
        "--disable-extensions",
        "--disable-domain-reliability",
        "--disable-client-side-phishing-detection",
        "--disable-breakpad",
        "--no-pings",
        "--disable-background-timer-throttling",
        "--disable-renderer-backgrounding",
        "--disable-backgrounding-occluded-windows",
        "--force-device-scale-factor=1",
    ] + [f for f in os.environ.get("RELIEF_CHROMIUM_FLAGS", "").split() if f] + [
        "about:blank",
    ]


class CDPError(RuntimeError):
    pass


class Browser:
    """A Chromium process driven over --remote-debugging-pipe."""

    def __init__(self, binary, width, height, deadline, log=None):
        self.log = log or (lambda line: print(line, file=sys.stderr, flush=True))
        self.deadline = deadline  # time.monotonic() value; the watchdog kills the browser then
        self.next_id = 0
        self.replies = {}
        self.cond = threading.Condition()
        self.closed = False
        self.console = []  # every console:/exception/log line, as printed
        self.exceptions = []
        self.proc = None
        self.write_lock = threading.Lock()
        self.profile = tempfile.mkdtemp(prefix="relief-chromium-")
        self.stderr_path = os.path.join(self.profile, "browser-stderr.txt")
        try:
            self._start(binary, width, height)
        except BaseException:
            self.kill()
            shutil.rmtree(self.profile, ignore_errors=True)
            raise

    def _start(self, binary, width, height):

        # two pipes: commands (we write, browser reads fd 3), replies (browser writes fd 4).
        # Moved to fds >= 10 so that dup2 to 3 and 4 in the child cannot clobber one another.
        cmd_r, cmd_w = os.pipe()
        rep_r, rep_w = os.pipe()
        hi = [fcntl.fcntl(fd, fcntl.F_DUPFD_CLOEXEC, 10) for fd in (cmd_r, rep_w)]
        for fd in (cmd_r, rep_w):
            os.close(fd)
        child_cmd_r, child_rep_w = hi

        def in_child():
            os.dup2(child_cmd_r, 3)  # dup2 clears close-on-exec on the new fd
            os.dup2(child_rep_w, 4)

        err = open(self.stderr_path, "wb")
        try:
            self.proc = subprocess.Popen(
                [binary] + browser_flags(width, height, self.profile),
                stdin=subprocess.DEVNULL, stdout=err, stderr=err,
                close_fds=False,  # Python's own fds are close-on-exec (PEP 446); 3 and 4 stay
                preexec_fn=in_child, start_new_session=True)
        finally:
            err.close()
            os.close(child_cmd_r)
            os.close(child_rep_w)
        self.wfile = os.fdopen(cmd_w, "wb", buffering=0)
        self.rfile = os.fdopen(rep_r, "rb", buffering=0)
        self.reader = threading.Thread(target=self._read_loop, daemon=True)
        self.reader.start()
        self.watchdog = threading.Thread(target=self._watchdog, daemon=True)
        self.watchdog.start()

    # --- plumbing -------------------------------------------------------------------------------
    def _watchdog(self):
        while not self.closed:
            left = self.deadline - time.monotonic()
            if left <= 0:
                self.log("browser.py: hard deadline reached, killing the browser")
                self.kill()
                return
            time.sleep(min(left, 0.5))

    def _read_loop(self):
        buf = b""
        try:
            while True:
                chunk = self.rfile.read(1 << 16)
                if not chunk:
                    break
                buf += chunk
                while b"\0" in buf:
                    raw, buf = buf.split(b"\0", 1)
                    if raw:
                        self._dispatch(json.loads(raw))
        except (OSError, ValueError):
            pass
        finally:
            with self.cond:
                self.closed = True
                self.cond.notify_all()

    def _dispatch(self, msg):
        if "id" in msg:
            with self.cond:
                self.replies[msg["id"]] = msg
                self.cond.notify_all()
            return
        method, p = msg.get("method"), msg.get("params", {})
        if method == "Runtime.consoleAPICalled":
            parts = [_remote_object_text(a) for a in p.get("args", [])]
            self._console(f"[{p.get('type', 'log')}] " + " ".join(parts))
        elif method == "Runtime.exceptionThrown":
            d = p.get("exceptionDetails", {})
            exc = d.get("exception") or {}
            text = exc.get("description") or d.get("text", "exception")
            where = d.get("url", "")
            if where and where not in text:
                text += f" ({where}:{d.get('lineNumber', 0) + 1}:{d.get('columnNumber', 0) + 1})"
            self.exceptions.append(text)
            self._console("[uncaught] " + text)
        elif method == "Log.entryAdded":
            e = p.get("entry", {})
            text = e.get("text", "")
            if e.get("url"):
                text += f" ({e['url']})"
            self._console(f"[{e.get('source', 'log')}.{e.get('level', 'info')}] {text}")

    def _console(self, text):
        for line in text.splitlines() or [""]:
            line = "console: " + line
            self.console.append(line)
            self.log(line)

    def call(self, method, params=None, session=None, timeout=30.0):
        """Send one command and wait for its reply; returns its result or raises CDPError."""
        with self.cond:
            self.next_id += 1
            mid = self.next_id
        msg = {"id": mid, "method": method, "params": params or {}}
        if session:
            msg["sessionId"] = session
        data = json.dumps(msg).encode() + b"\0"
        try:
            with self.write_lock:
                self.wfile.write(data)
        except OSError as e:
            raise CDPError(f"{method}: browser pipe closed ({e})")
        end = min(time.monotonic() + timeout, self.deadline)
        with self.cond:
            while mid not in self.replies:
                left = end - time.monotonic()
                if self.closed:
                    raise CDPError(f"{method}: browser went away")
                if left <= 0:
                    raise CDPError(f"{method}: no reply in time")
                self.cond.wait(min(left, 0.5))
            reply = self.replies.pop(mid)
        if "error" in reply:
            raise CDPError(f"{method}: {reply['error'].get('message')} {reply['error'].get('data', '')}".strip())
        return reply.get("result", {})

    def stderr_tail(self, n=20):
        try:
            with open(self.stderr_path, "rb") as f:
                lines = f.read().decode("utf-8", "replace").splitlines()
            return "\n".join(lines[-n:])
        except OSError:
            return ""

    def kill(self):
        p = self.proc
        if p is None or p.poll() is not None:
            return
        try:
            os.killpg(p.pid, signal.SIGKILL)
        except OSError:
            pass

    def close(self):
        """Stop the browser (politely, then by force) and remove the profile. Never raises."""
        try:
            if self.proc is not None and self.proc.poll() is None and not self.closed:
                try:
                    self.call("Browser.close", timeout=2.0)
                except CDPError:
                    pass
                try:
                    self.proc.wait(2.0)
                except subprocess.TimeoutExpired:
                    pass
        except Exception:
            pass
        finally:
            # the whole process group: renderer, GPU and zygote children too
            if self.proc is not None:
                try:
                    os.killpg(self.proc.pid, signal.SIGKILL)
                except OSError:
                    pass
                try:
                    self.proc.wait(5.0)
                except subprocess.TimeoutExpired:
                    pass
            self.closed = True
            for f in ("wfile", "rfile"):
                try:
                    getattr(self, f).close()
                except Exception:
                    pass
            for _ in range(3):
                shutil.rmtree(self.profile, ignore_errors=True)
                if not os.path.exists(self.profile):
                    break
                time.sleep(0.2)


def _remote_object_text(o):
    if "value" in o:
        v = o["value"]
        return v if isinstance(v, str) else json.dumps(v)
    if o.get("unserializableValue"):
        return o["unserializableValue"]
    return o.get("description") or o.get("type", "?")


def _poll_expr(ready, error, status):
    # one round trip per poll; each part guarded so a throwing status() cannot hide the others.
    # The newlines keep a trailing `//` comment in a user expression from eating the rest.
    return f"""(() => {{
  const out = {{}};
  try {{ const e = (
{error}
); out.error = (typeof e === 'string' && e.length) ? e : (e ? String(e) : null); }}
  catch (x) {{ out.errorThrew = String(x); }}
  try {{ out.ready = !!(
{ready}
); }} catch (x) {{ out.readyThrew = String(x); }}
  try {{ const s = (
{status}
); out.status = (typeof s === 'string') ? s : JSON.stringify(s); }}
  catch (x) {{ out.statusThrew = String(x); }}
  return out;
}})()"""


def _evaluate(b, session, expr, await_promise=False, timeout=10.0):
    r = b.call("Runtime.evaluate", {"expression": expr, "returnByValue": True,
                                    "awaitPromise": await_promise}, session, timeout=timeout)
    if "exceptionDetails" in r:
        d = r["exceptionDetails"]
        exc = d.get("exception") or {}
        raise CDPError("evaluate: " + (exc.get("description") or d.get("text", "exception")))
    return r.get("result", {}).get("value")


def run(url, out=None, width=960, height=540, timeout=60.0, ready_expr=DEFAULT_READY,
        error_expr=DEFAULT_ERROR, status_expr=DEFAULT_STATUS, wait_expr=None, status_json=None,
        expect_error=None, browser=None, poll_s=0.1, log=None):
    """Load url, wait for ready_expr, write the status and a PNG screenshot.

    Returns a dict: code (0 ok, 1 timeout / failure, 2 page error), message (the one line to print),
    out, bytes, ready_ms (navigation start to ready), status (the status expression's last string
    value), error (the page's error, if any), console (list of `console: ...` lines), exceptions,
    total_ms (the whole run, browser start and stop included), url."""
    t_start = time.monotonic()
    res = {"code": 1, "message": "", "out": out, "bytes": 0, "ready_ms": None, "status": None,
           "error": None, "console": [], "exceptions": [], "total_ms": None, "url": url}
    b = None
    try:
        binary = find_browser(browser)
        b = Browser(binary, width, height, t_start + timeout + STARTUP_SLACK_S, log=log)
        res["console"], res["exceptions"] = b.console, b.exceptions
        try:
            # (no width/height here: new-headless chromium refuses them for a tab; the metrics
            # override below sets the viewport for both kinds of browser)
            tid = b.call("Target.createTarget", {"url": "about:blank"}, timeout=20)["targetId"]
            sid = b.call("Target.attachToTarget", {"targetId": tid, "flatten": True})["sessionId"]
            for dom in ("Page.enable", "Runtime.enable", "Log.enable"):
                b.call(dom, session=sid)
            b.call("Emulation.setDeviceMetricsOverride", {"width": width, "height": height,
                                                          "deviceScaleFactor": 1, "mobile": False}, sid)
            t_nav = time.monotonic()
            nav = b.call("Page.navigate", {"url": url}, sid, timeout=timeout)
            if nav.get("errorText"):
                res["message"] = f"navigation to {url} failed: {nav['errorText']}"
                return res
            poll = _poll_expr(ready_expr, error_expr, status_expr)
            last, last_threw = None, None
            while True:
                try:
                    v = _evaluate(b, sid, poll, timeout=max(1.0, min(10.0, timeout)))
                except CDPError as e:
                    if "SyntaxError" in str(e):
                        res["message"] = f"bad expression: {e}"
                        return res
                    if b.closed:
                        raise
                    v, last_threw = None, str(e)  # e.g. context destroyed mid-navigation
                if isinstance(v, dict):
                    if v.get("status") is not None:
                        last = v["status"]
                    last_threw = v.get("readyThrew") or last_threw
                    if v.get("error"):
                        msg = v["error"]
                        res["error"], res["status"] = msg, last
                        _write_status(status_json, last)
                        if expect_error is not None:
                            if expect_error in msg:
                                if out:
                                    res["bytes"] = _shot(b, sid, out)
                                res["code"] = 0
                                res["message"] = f"expected page error: {msg}"
                            else:
                                res["code"] = 2
                                res["message"] = (f"page error: {msg} (expected one containing "
                                                  f"{expect_error!r})")
                            return res
                        res["code"] = 2
                        res["message"] = f"page error: {msg}"
                        return res
                    if v.get("ready"):
                        res["ready_ms"] = round((time.monotonic() - t_nav) * 1000)
                        if expect_error is not None:
                            res["status"] = last
                            _write_status(status_json, last)
                            res["message"] = (f"page became ready with no error; expected one "
                                              f"containing {expect_error!r} (status: {last})")
                            return res
                        break
                if time.monotonic() - t_nav > timeout:
                    res["status"] = last
                    extra = f"; ready expression threw: {last_threw}" if last_threw else ""
                    res["message"] = (f"timeout: not ready after {timeout:g} s at {url}; "
                                      f"status: {last}{extra}")
                    return res
                time.sleep(poll_s)
            if wait_expr:
                left = max(1.0, timeout - (time.monotonic() - t_nav))
                try:
                    _evaluate(b, sid, wait_expr, await_promise=True, timeout=left)
                except CDPError as e:
                    if b.closed:
                        raise
                    res["message"] = f"wait expression failed or did not settle in {left:.1f} s: {e}"
                    return res
            try:
                st = _evaluate(b, sid, status_expr)
                last = st if isinstance(st, str) or st is None else json.dumps(st)
            except CDPError as e:
                b.log(f"browser.py: status expression failed after ready: {e}")
            res["status"] = last
            _write_status(status_json, last)
            if out:
                res["bytes"] = _shot(b, sid, out)
                res["message"] = f"{out} {res['bytes']} bytes, ready in {res['ready_ms']} ms"
            else:
                res["message"] = f"ready in {res['ready_ms']} ms (no screenshot asked)"
            res["code"] = 0
            return res
        except CDPError as e:
            # the browser's stderr is mostly D-Bus noise; show it only when the browser died
            gone = b.closed or b.proc.poll() is not None
            tail = b.stderr_tail() if gone else ""
            res["code"] = 1
            res["message"] = f"browser failure: {e}" + (f"\nbrowser stderr:\n{tail}" if tail else "")
            return res
    except (OSError, FileNotFoundError) as e:
        res["code"] = 1
        res["message"] = f"browser.py: {e}"
        return res
    finally:
        if b is not None:
            b.close()
        res["total_ms"] = round((time.monotonic() - t_start) * 1000)


def _write_status(path, value):
    if path:
        with open(path, "w") as f:
            f.write(value if value is not None else "null")
            f.write("\n")


def _shot(b, sid, out):
    r = b.call("Page.captureScreenshot", {"format": "png", "fromSurface": True}, sid)
    data = base64.b64decode(r["data"])
    d = os.path.dirname(os.path.abspath(out))
    os.makedirs(d, exist_ok=True)
    tmp = out + ".part"
    with open(tmp, "wb") as f:
        f.write(data)
    os.replace(tmp, out)
    return len(data)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("url")
    ap.add_argument("--out", help="PNG to write (none: no screenshot)")
    ap.add_argument("--width", type=int, default=960)
    ap.add_argument("--height", type=int, default=540)
    ap.add_argument("--timeout", type=float, default=60.0, help="seconds from navigation to ready")
    ap.add_argument("--ready-expr", default=DEFAULT_READY)
    ap.add_argument("--error-expr", default=DEFAULT_ERROR)
    ap.add_argument("--status-expr", default=DEFAULT_STATUS)
    ap.add_argument("--wait-expr", help="JS awaited (a promise is ok) after ready, before the shot")
    ap.add_argument("--status-json", help="file to write the status expression's value to")
    ap.add_argument("--expect-error", metavar="SUBSTRING",
                    help="succeed only if the page reports an error containing SUBSTRING")
    ap.add_argument("--browser", help="Chromium binary (default: $RELIEF_CHROMIUM or found)")
    a = ap.parse_args(argv)
    r = run(a.url, a.out, a.width, a.height, a.timeout, ready_expr=a.ready_expr,
            error_expr=a.error_expr, status_expr=a.status_expr, wait_expr=a.wait_expr,
            status_json=a.status_json, expect_error=a.expect_error, browser=a.browser)
    print(r["message"], file=sys.stdout if r["code"] == 0 else sys.stderr, flush=True)
    return r["code"]


if __name__ == "__main__":
    sys.exit(main())
