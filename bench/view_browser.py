"""Drives headless Chromium (through chromedriver, Python's standard library
only) on a session's browser view: waits until the page holds the session's
final triangles, measures the page's drawing rate while the camera orbits,
and saves a screenshot. Prints one JSON line.

Usage: view_browser.py VIEW_URL TRIANGLES SCREENSHOT.png [SECONDS]
"""
import base64
import json
import socket
import subprocess
import sys
import tempfile
import time
import urllib.request


def call(base, method, path, body=None):
    data = None if body is None else json.dumps(body).encode()
    req = urllib.request.Request(base + path, data=data, method=method,
                                 headers={"Content-Type": "application/json"})
    return json.loads(urllib.request.urlopen(req, timeout=600).read())["value"]


def main():
    url, triangles, shot = sys.argv[1], sys.argv[2], sys.argv[3]
    seconds = int(sys.argv[4]) if len(sys.argv) > 4 else 10
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    driver = subprocess.Popen(["chromedriver", f"--port={port}"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    base = f"http://127.0.0.1:{port}"
    profile = tempfile.mkdtemp()
    try:
        for _ in range(100):
            try:
                socket.create_connection(("127.0.0.1", port), 0.2).close()
                break
            except OSError:
                time.sleep(0.1)
        args = ["--headless", "--no-sandbox", "--disable-gpu", "--use-angle=swiftshader",
                "--enable-unsafe-swiftshader", "--no-first-run",
                "--disable-background-networking", "--disable-component-update",
                "--disable-sync", "--disable-quic", "--window-size=1280,800",
                f"--user-data-dir={profile}"]
        session = call(base, "POST", "/session", {"capabilities": {"alwaysMatch": {
            "browserName": "chrome",
            "goog:chromeOptions": {"binary": "/usr/bin/chromium", "args": args}}}})["sessionId"]
        s = f"/session/{session}"
        started = time.time()
        call(base, "POST", s + "/url", {"url": url})
        script = ("return [document.getElementById('triangles').textContent, "
                  "window.depthmeshView ? window.depthmeshView.received : 0]")
        while True:
            shown, received = call(base, "POST", s + "/execute/sync", {"script": script, "args": []})
            if shown == triangles:
                break
            if time.time() - started > 600:
                raise SystemExit(f"the page shows {shown} of {triangles} triangles after 600 s")
            time.sleep(0.5)
        loaded = time.time() - started
        # Orbit the whole map, as a person looking around would.
        call(base, "POST", s + "/execute/sync", {"script": (
            "const v = window.depthmeshView; v.setFollow(false); v.frameAll(); "
            "v.controls.autoRotate = true; v.controls.autoRotateSpeed = 6;"), "args": []})
        time.sleep(2)
        rates = []
        for _ in range(seconds):
            time.sleep(1)
            rates.append(int(call(base, "POST", s + "/execute/sync", {
                "script": "return document.getElementById('drawfps').textContent", "args": []})))
        png = call(base, "GET", s + "/screenshot")
        with open(shot, "wb") as f:
            f.write(base64.b64decode(png))
        call(base, "DELETE", s)
        rates.sort()
        print(json.dumps({"triangles": int(triangles), "page_bytes": received,
                          "load_seconds": round(loaded, 1),
                          "draw_fps_median": rates[len(rates) // 2],
                          "draw_fps_min": rates[0], "draw_fps_max": rates[-1]}))
    finally:
        driver.kill()
        subprocess.run(["rm", "-rf", profile])


main()
