#!/usr/bin/python3
"""`isotrace view` in a real browser: Debian's chromium, headless, driven by chromium-driver
through python3-selenium (Debian's python, which has selenium).

Checks: the page loads with no console errors; the image appears; moving an iso slider changes
the surface and the image, which refines in steps (the page's log of the frames it received
shows every pass of the new version, in order, up to the scene's spp); the integrator switch
works; the surface's colour map, the slice's position and a clip plane change the server's scene; a
scene whose volume changes over time has a time slider that shows another step; Save writes
files that `isotrace render` turns into the same picture. Nothing waits for
a time: every wait is for an event the page shows, with a generous limit as a safety net.
Usage: tests/view_browser.py ISOTRACE_BINARY [--screenshot FILE.png]
"""
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile

from selenium import webdriver
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import Select, WebDriverWait

SCENE = {
    "camera": {"position": [0, 1.5, 4], "look_at": [0, 0.5, 0]},
    "film": {"width": 320, "height": 240},
    "integrator": {"type": "direct", "spp": 64},
    "meshes": [{"shape": "quad", "transform": {"scale": 3}, "material": "floor"}],
    "volumes": [{"procedural": {"field": "sphere", "resolution": [32, 32, 32]}, "transform": {"translate": [0, 1, 0]},
                 "isosurfaces": [{"value": 0.6, "inside": "below", "material": "ball",
                                  "color_by": {"field": "gradient_magnitude", "map": "plasma", "range": [0, 2]}}],
                 "slices": [{"axis": "x", "position": -0.8, "map": "viridis"}]}],
    "materials": {"floor": {"type": "diffuse", "color": 0.7}, "ball": {"type": "diffuse", "color": [0.8, 0.3, 0.2]}},
    "lights": [{"type": "point", "position": [2, 4, 2], "intensity": 30}, {"type": "environment", "radiance": 0.3}],
}


def ball_steps(folder):
    """Two time steps of a ball (radius 3 and 6 samples in a 16^3 float32 grid) as raw files; the
    scene of the series."""
    import array
    import math
    files = []
    for k, radius in enumerate((3, 6)):
        values = array.array("f", [radius - math.sqrt((x - 7.5) ** 2 + (y - 7.5) ** 2 + (z - 7.5) ** 2)
                                   for z in range(16) for y in range(16) for x in range(16)])
        name = os.path.join(folder, "step%d_16x16x16_float32.raw" % k)
        with open(name, "wb") as f:
            values.tofile(f)
        files.append(name)
    scene = os.path.join(folder, "series.json")
    with open(scene, "w") as f:
        json.dump({"camera": {"position": [7.5, 7.5, 40], "look_at": [7.5, 7.5, 7.5]}, "film": {"width": 160, "height": 120},
                   "integrator": {"type": "eyelight", "spp": 4},
                   "volumes": [{"file": files, "isosurfaces": [{"value": 0}]}]}, f)
    return scene


def check_time_slider(binary, work, driver, wait):
    """A second server, of a time series: its page's time slider moves the server to step 1, and
    the picture changes."""
    server = subprocess.Popen([binary, "view", ball_steps(work), "--port", "0"], stdout=subprocess.PIPE,
                              stderr=subprocess.PIPE, text=True)
    try:
        url = server.stdout.readline().strip()
        driver.get(url)
        state = lambda: driver.execute_script("return fetch('/api/state').then(r => r.json());")
        wait.until(lambda d: d.find_elements(By.ID, "time-step") and d.find_element(By.ID, "view").get_attribute("src"))
        first = driver.find_element(By.ID, "view").get_attribute("src")
        if state()["time"] != {"step": 0, "steps": 2}:
            fail("the time series' state: %s" % state().get("time"))
        slider = driver.find_element(By.ID, "time-step")
        driver.execute_script("const r = arguments[0]; r.value = 1; r.dispatchEvent(new Event('input', {bubbles: true}));",
                              slider)
        wait.until(lambda d: state()["time"]["step"] == 1)
        wait.until(lambda d: d.find_element(By.ID, "view").get_attribute("src") != first)
        # (Leaving the first page cut its event stream, which the browser logs as a failed load of
        # /api/events; this page's own errors count.)
        errors = [e for e in driver.get_log("browser") if e["level"] in ("SEVERE", "ERROR") and
                  not ("/api/events" in e["message"] and "ERR_INCOMPLETE_CHUNKED_ENCODING" in e["message"])]
        if errors:
            fail("console errors on the time series' page: %s" % errors)
    finally:
        server.send_signal(2)
        server.wait(timeout=60)


def fail(message):
    print("view_browser: FAIL: " + message, file=sys.stderr)
    sys.exit(1)


def main():
    binary = sys.argv[1]
    screenshot = sys.argv[sys.argv.index("--screenshot") + 1] if "--screenshot" in sys.argv else None
    work = tempfile.mkdtemp(prefix="isotrace_view_")
    scene = os.path.join(work, "ball.json")
    with open(scene, "w") as f:
        json.dump(SCENE, f)
    server = subprocess.Popen([binary, "view", scene, "--port", "0", "--resolution", "320x240"],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    driver = None
    try:
        url = server.stdout.readline().strip()
        if not re.match(r"^http://127\.0\.0\.1:\d+/$", url):
            fail("first line of stdout is not the URL: %r" % url)
        options = webdriver.ChromeOptions()
        options.binary_location = "/usr/bin/chromium"
        for flag in ("--headless=new", "--no-sandbox", "--disable-dev-shm-usage", "--window-size=1000,700"):
            options.add_argument(flag)
        options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
        # Chromium's temporary files (its profile singleton's folder, which it leaves behind in
        # TMPDIR on every run) go into the test's own folder, removed below.
        service = Service("/usr/bin/chromedriver", env=dict(os.environ, TMPDIR=work))
        driver = webdriver.Chrome(service=service, options=options)
        wait = WebDriverWait(driver, 120, poll_frequency=0.02)  # a safety net, not a pace
        driver.get(url)

        def spp():
            text = driver.find_element(By.ID, "spp").text
            return int(text) if text.isdigit() else -1

        def frames_of(version):
            """The frames the page received for `version`: [(spp, preview)] in order."""
            log = d_log()
            return [(f["spp"], f["preview"]) for f in log if f["version"] == version]

        def d_log():
            return driver.execute_script("return frameLog;")

        def server_state():
            return driver.execute_script("return fetch('/api/state').then(r => r.json());")

        def state_at(path):
            """A field of the server's state: a path such as 'surfaces[0].value'."""
            return driver.execute_script("return fetch('/api/state').then(r => r.json()).then(s => s.%s)" % path)

        def finished(version):
            """True once the page has the last frame (the scene's spp) of `version`."""
            return any(s >= 64 and not p for s, p in frames_of(version))

        # The image appears, and the first version renders to the scene's spp.
        wait.until(lambda d: (d.find_element(By.ID, "view").get_attribute("src") or "").startswith("data:image/jpeg"))
        wait.until(lambda d: finished(server_state()["version"]))
        first = driver.find_element(By.ID, "view").get_attribute("src")

        # An iso slider: the value moves, the image changes, the server has the new value.
        sliders = driver.find_elements(By.CSS_SELECTOR, "input[type=range].iso")
        if len(sliders) != 1:
            fail("expected one iso slider, found %d" % len(sliders))
        driver.execute_script(
            "const r = arguments[0]; r.value = 0.35; r.dispatchEvent(new Event('input', {bubbles: true}));", sliders[0])
        # (the slider snaps to its steps: 0.35 to within one)
        wait.until(lambda d: abs(state_at('surfaces[0].value') - 0.35) < 1e-3)
        slid = server_state()["version"]
        wait.until(lambda d: finished(slid))
        if d_log()[-1]["version"] != slid:
            fail("a frame of another version came after the slider's: %s" % d_log())
        passes = [s for s, p in frames_of(slid) if not p]
        if len(passes) < 2 or passes != sorted(set(passes)) or passes[-1] != 64:
            fail("the image did not refine in steps up to 64 spp: the page saw %s" % frames_of(slid))
        after_slider = driver.find_element(By.ID, "view").get_attribute("src")
        if after_slider == first:
            fail("the image did not change with the iso value")

        # The integrator switch.
        Select(driver.find_element(By.ID, "integrator")).select_by_value("normals")
        wait.until(lambda d: state_at('integrator') == "normals")
        wait.until(lambda d: finished(server_state()["version"]))
        if driver.find_element(By.ID, "view").get_attribute("src") == after_slider:
            fail("the image did not change with the integrator")

        # Colour by data: another map; a slice: another position.
        Select(driver.find_element(By.CSS_SELECTOR, "select.map")).select_by_value("cividis")
        wait.until(lambda d: state_at('surfaces[0].color_by.map') == "cividis")
        slices = driver.find_elements(By.CSS_SELECTOR, "input[type=range].slice")
        if len(slices) != 1:
            fail("expected one slice slider, found %d" % len(slices))
        driver.execute_script(
            "const r = arguments[0]; r.value = -0.5; r.dispatchEvent(new Event('input', {bubbles: true}));", slices[0])
        wait.until(lambda d: abs(state_at('slices[0].position') + 0.5) < 2e-3)
        wait.until(lambda d: finished(server_state()["version"]))

        # A clip plane across z: on (its checkbox), then moved (its slider), then flipped; the
        # server's scene holds the plane, and the picture changes.
        before_clip = driver.find_element(By.ID, "view").get_attribute("src")
        clip_on = driver.find_element(By.CSS_SELECTOR, "input.clip-on[data-axis=z]")
        clip_on.click()
        wait.until(lambda d: state_at('clip[2].on') is True)
        clip = driver.find_element(By.CSS_SELECTOR, "input[type=range].clip[data-axis=z]")
        driver.execute_script(
            "const r = arguments[0]; r.value = 0.1; r.dispatchEvent(new Event('input', {bubbles: true}));", clip)
        wait.until(lambda d: abs(state_at('clip[2].position') - 0.1) < 2e-3)
        driver.find_element(By.CSS_SELECTOR, "input.clip-flip[data-axis=z]").click()
        wait.until(lambda d: state_at('clip[2].flip') is True)
        wait.until(lambda d: finished(server_state()["version"]))
        if driver.find_element(By.ID, "view").get_attribute("src") == before_clip:
            fail("the image did not change with the clip plane")

        if screenshot:
            Select(driver.find_element(By.ID, "integrator")).select_by_value("direct")
            wait.until(lambda d: state_at('integrator') == "direct")
            wait.until(lambda d: finished(server_state()["version"]))
            driver.save_screenshot(screenshot)

        # Save: the scene and the images; `isotrace render` of the scene gives the same picture.
        driver.find_element(By.ID, "save").click()
        wait.until(lambda d: d.find_element(By.ID, "saved").text.startswith("saved "))
        files = driver.find_element(By.ID, "saved").text[len("saved "):].split(", ")
        saved_json = next(f for f in files if f.endswith(".json"))
        saved_exr = next(f for f in files if f.endswith(".exr"))
        rendered = os.path.join(work, "batch.exr")
        r = subprocess.run([binary, "render", saved_json, "-o", rendered, "--quiet"], capture_output=True, text=True)
        if r.returncode != 0:
            fail("isotrace render of the saved scene: " + r.stderr)
        diff = subprocess.run(["oiiotool", rendered, saved_exr, "--diff"], capture_output=True, text=True)
        if diff.returncode != 0 or "PASS" not in diff.stdout:
            fail("the saved scene renders another picture:\n" + diff.stdout)

        errors = [e for e in driver.get_log("browser") if e["level"] in ("SEVERE", "ERROR")]
        if errors:
            fail("console errors: %s" % errors)
        reached = spp()
        check_time_slider(binary, work, driver, wait)
        print("view_browser: ok (page, refinement to %d spp, slider, integrator, colour map, slice, clip, save, "
              "time slider)" % reached)
    finally:
        if driver:
            driver.quit()
        server.send_signal(2)
        try:
            server.wait(timeout=60)
        except subprocess.TimeoutExpired:
            server.kill()
            fail("the server did not stop on SIGINT within 60 s")
        if server.returncode != 0:
            fail("the server exited with %d: %s" % (server.returncode, server.stderr.read()))
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
