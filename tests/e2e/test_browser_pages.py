"""The viewer and the API docs in a real headless browser: Debian's Chromium driven by Playwright,
against a real uvicorn server (conftest ``live_url``), with every request to another host cut off
and recorded (the pages must work offline: three.js and Swagger UI are served by the service).

No Chromium at ``/usr/bin/chromium`` (or ``CAPSULE_RT_CHROMIUM``): the tests skip and say so, except
in CI (``.ci/run`` installs the browser, and there a skip is a failure: tests/conftest.py). Playwright
never downloads a browser here: it only drives the system's.

``CAPSULE_RT_VIEWER_SCREENSHOT=docs/img/viewer.png`` also writes the viewer's screenshot there
(the README's picture); otherwise it goes to the test's temporary directory.
"""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path
from urllib.parse import urlparse

import httpx
import numpy as np
import pytest
from playwright.sync_api import TimeoutError as PlaywrightTimeout
from playwright.sync_api import sync_playwright
from scipy.stats import chi2

from tests.conftest import HANG_GUARD_S, glb_bytes, nested_phantom_meshes, phantom_manifest

#: Playwright's waits take milliseconds: the hang guard (tests.conftest), never a verdict on speed.
GUARD_MS = HANG_GUARD_S * 1000

pytestmark = [pytest.mark.e2e, pytest.mark.browser]

CHROMIUM = os.environ.get("CAPSULE_RT_CHROMIUM", "/usr/bin/chromium")
# as root and headless; no background connections (the machine has no network but localhost)
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
        "--disable-background-networking", "--disable-component-update", "--disable-sync"]
BACKGROUND = (0x14, 0x17, 0x1C)  # scene.js BACKGROUND

# pixels of the scene's canvas that differ from the background (channel sum > 24), read back in the
# page (the renderer keeps its drawing buffer); `window.__pixels` keeps them to diff a later frame
COUNT_PIXELS = """([r, g, b]) => {
  const canvas = document.querySelector('#scene canvas');
  const copy = Object.assign(document.createElement('canvas'), {width: canvas.width, height: canvas.height});
  const ctx = copy.getContext('2d');
  ctx.drawImage(canvas, 0, 0);
  const data = ctx.getImageData(0, 0, copy.width, copy.height).data;
  let drawn = 0, changed = 0;
  for (let i = 0; i < data.length; i += 4) {
    if (Math.abs(data[i] - r) + Math.abs(data[i + 1] - g) + Math.abs(data[i + 2] - b) > 24) drawn++;
    if (window.__pixels && Math.abs(data[i] - window.__pixels[i]) + Math.abs(data[i + 1] - window.__pixels[i + 1])
        + Math.abs(data[i + 2] - window.__pixels[i + 2]) > 24) changed++;
  }
  window.__pixels = data;
  return {drawn, changed, total: data.length / 4};
}"""


@pytest.fixture(scope="module")
def browser():
    if shutil.which(CHROMIUM) is None:
        reason = (f"no Chromium at {CHROMIUM}: the browser tests need Debian's package (apt-get install chromium; "
                  ".ci/run installs it)")
        pytest.skip(reason)
    with sync_playwright() as p:
        chromium = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        yield chromium
        chromium.close()


@pytest.fixture
def page(browser, live_url):
    """A page whose requests to any host but the server's are aborted and recorded; console errors and
    uncaught exceptions recorded too. Yields (page, errors, external_requests)."""
    context = browser.new_context(viewport={"width": 1400, "height": 820})
    server = urlparse(live_url).netloc
    external: list[str] = []

    def only_the_server(route):
        if urlparse(route.request.url).netloc == server:
            route.continue_()
        else:
            external.append(route.request.url)
            route.abort()

    context.route("**/*", only_the_server)
    page = context.new_page()
    errors: list[str] = []
    page.on("console", lambda msg: errors.append(f"console.{msg.type}: {msg.text}") if msg.type == "error" else None)
    page.on("pageerror", lambda exc: errors.append(f"uncaught: {exc}"))
    yield page, errors, external
    context.close()


def wait_state(page, condition: str, errors: list[str], external: list[str],
               timeout_s: float = HANG_GUARD_S) -> dict:
    """window.viewerState once ``condition`` holds; on a timeout, fail saying what the page logged."""
    try:
        page.wait_for_function(f"() => window.viewerState && ({condition})", timeout=timeout_s * 1000)
    except PlaywrightTimeout:
        state = page.evaluate("() => window.viewerState || null")
        pytest.fail(f"viewer never got to {condition!r} in {timeout_s} s; state {state}; console errors "
                    f"{errors}; requests to other hosts {external}")
    return page.evaluate("() => window.viewerState")


def test_viewer_shows_the_torso_and_a_trace(page, live_url, tmp_path):
    page, errors, external = page
    page.goto(f"{live_url}/viewer")
    state = wait_state(page, "window.viewerState.ready", errors, external)
    assert state["phantom"] == "torso" and state["organs"] == 15 and state["sites"] == 18, state
    pixels = page.evaluate(COUNT_PIXELS, list(BACKGROUND))
    # the torso fills a good part of the view; a blank or failed WebGL canvas has ~0 such pixels
    assert pixels["drawn"] > 0.10 * pixels["total"], pixels
    legend = page.locator("#legend li").all_inner_texts()
    assert any(t.startswith("liver") for t in legend) and any(t.startswith("muscle") for t in legend)
    assert not page.is_visible("#capsule-position") and not page.is_visible("#gain-scale")  # until asked for
    # the 6 capsule sites and the entry for a typed position; the 12 sensor sites, all picked
    assert page.locator("#capsule option").count() == 7 and page.locator("#sensors input:checked").count() == 12

    assert page.input_value("#rays") == "20000"  # the page's default
    assert not page.is_enabled("#locate")  # nothing to locate from before a trace
    with page.expect_response(lambda r: urlparse(r.url).path == "/v1/channel", timeout=GUARD_MS) as traced:
        page.click("#trace")
    state = wait_state(page, "window.viewerState.traces === 1 && !window.viewerState.tracing "
                       "&& window.viewerState.pdp !== null", errors, external)
    assert state["error"] is None, state["error"]
    receivers = state["receivers"]
    assert len(receivers) == 12
    # every sensor site sees every capsule site directly (README), so each has at least one path
    assert all(r["paths"] >= 1 for r in receivers), receivers
    assert state["paths"] == sum(r["paths"] for r in receivers)  # one polyline per path in the scene
    assert page.is_visible("#gain-scale")
    after = page.evaluate(COUNT_PIXELS, list(BACKGROUND))
    assert after["changed"] > 500, after  # the polylines were drawn over the organs
    pdp = page.evaluate("() => { const img = document.getElementById('pdp'); "
                        "return [img.naturalWidth, img.naturalHeight]; }")
    assert pdp[0] > 300 and pdp[1] > 200, pdp
    rows = page.locator("#paths tbody tr")
    first = next(r for r in receivers if r["paths"])
    assert rows.count() == first["paths"]
    rows.first.click()  # outline one path; must not disturb anything
    assert page.locator("#paths tbody tr.picked").count() == 1

    check_locate(page, errors, external, traced.value.json())

    shot = Path(os.environ.get("CAPSULE_RT_VIEWER_SCREENSHOT") or tmp_path / "viewer.png")
    page.screenshot(path=str(shot))
    assert shot.stat().st_size > 20_000
    assert errors == [] and external == [], (errors, external)


def check_locate(page, errors, external, channel: dict) -> None:
    """Locate after the trace (model-based, the page's default; 95 % ellipsoid): the page posts every sensor's
    first-path delay, and draws the API's answer: the marker at position_m, the ellipsoid's semi-axes the square
    roots of the covariance's eigenvalues times the 95 % scale, turned onto its eigenvectors."""
    assert page.is_enabled("#locate") and not page.is_visible("#fix")
    assert page.input_value("#locate-method") == "model_based"
    page.select_option("#locate-confidence", "p95")
    page.evaluate(COUNT_PIXELS, list(BACKGROUND))  # the frame before: the fix must add to it
    # the first model-based fix builds the 12 sensors' travel-time fields (docs/localization.md, ~5-20 s)
    with page.expect_response(lambda r: urlparse(r.url).path == "/v1/localize", timeout=GUARD_MS) as answered:
        page.click("#locate")
    state = wait_state(page, "window.viewerState.locates === 1 && !window.viewerState.locating", errors, external)
    assert answered.value.status == 200 and state["error"] is None, (answered.value.status, state["error"])
    fix = answered.value.json()

    # what was asked: each sensor's earliest traced path (oracle: the /v1/channel answer itself)
    sent = answered.value.request.post_data_json
    assert sent["method"] == "model_based" and sent["phantom"] == "torso" and sent["frequency_hz"] == 402e6
    profiles = [p for p in channel["profiles"] if p["paths"]]
    assert [s["position_m"] for s in sent["sensors"]] == [p["position_m"] for p in profiles]
    assert [s["delay_s"] for s in sent["sensors"]] == [min(q["delay_s"] for q in p["paths"]) for p in profiles]
    assert all(s["sigma_m"] == pytest.approx(0.005) for s in sent["sensors"])  # the page's default 5 mm

    # what was drawn, read back from the three.js objects. numpy's eigvalsh and scipy's chi-square quantile
    # are the oracle (the page runs its own Jacobi rotations and a constant). Everything is float64 on both
    # sides and the Jacobi sweeps stop at 1e-15 of the norm: 1e-9 relative leaves room for the conditioning.
    drawn = state["fix"]["drawn"]
    position = np.array(fix["position_m"])
    truth = np.array(channel["transmitter"]["position_m"])
    cov = np.array(fix["covariance_m2"])
    k = np.sqrt(chi2.ppf(0.95, 3))
    assert state["fix"]["scale"] == pytest.approx(k, rel=1e-12)
    assert np.allclose(drawn["marker_m"], position, rtol=0, atol=1e-12)
    assert np.allclose(drawn["ellipsoid_centre_m"], position, rtol=0, atol=1e-12)
    assert np.allclose(drawn["truth_m"], truth, rtol=0, atol=1e-12)
    axes = np.sort(drawn["ellipsoid_scale_m"])
    assert np.allclose(axes, k * np.sqrt(np.linalg.eigvalsh(cov)), rtol=1e-9, atol=0), (axes, cov)
    # orientation too: the matrix A taking the unit sphere to the ellipsoid has A A^T = k^2 C
    a = np.array(drawn["ellipsoid_matrix"]).reshape(4, 4).T[:3, :3]
    assert np.allclose(a @ a.T, k**2 * cov, rtol=0, atol=1e-9 * k**2 * np.abs(cov).max()), (a @ a.T, k**2 * cov)
    assert drawn["ellipsoid_visible"]
    # a sane fix of the stomach site: the model-based fix from exact first-path delays errs 4.8 mm there at
    # 1e5 rays (docs/localization.md); 20 mm says the delays, positions and frames are wired right
    error_m = float(np.linalg.norm(position - truth))
    assert state["fix"]["error_m"] == pytest.approx(error_m, rel=1e-12) and error_m < 0.020, error_m
    assert page.is_visible("#fix")
    assert page.inner_text("#fix .error-mm").startswith(f"{error_m * 1000:.1f} "), page.inner_text("#fix")
    assert drawn["objects"] == 4  # ellipsoid, marker, true position, error vector
    after = page.evaluate(COUNT_PIXELS, list(BACKGROUND))
    assert after["changed"] > 200, after  # marker, ellipsoid, ring and error vector over the scene

    # again at a constant velocity and 1 sigma: the new fix replaces the old one
    page.select_option("#locate-method", "nonlinear")
    page.select_option("#locate-confidence", "sigma")
    with page.expect_response(lambda r: urlparse(r.url).path == "/v1/localize", timeout=GUARD_MS) as answered:
        page.click("#locate")
    state = wait_state(page, "window.viewerState.locates === 2 && !window.viewerState.locating", errors, external)
    sent, fix, drawn = answered.value.request.post_data_json, answered.value.json(), state["fix"]["drawn"]
    assert sent["method"] == "nonlinear" and sent["relative_permittivity"] == 27.9 and state["error"] is None
    assert drawn["objects"] == 4 and np.allclose(drawn["marker_m"], fix["position_m"], rtol=0, atol=1e-12)
    assert np.allclose(np.sort(drawn["ellipsoid_scale_m"]), np.sqrt(np.linalg.eigvalsh(fix["covariance_m2"])),
                       rtol=1e-9, atol=0)
    page.select_option("#locate-method", "model_based")  # the README's screenshot shows the model-based fix
    page.select_option("#locate-confidence", "p95")
    page.click("#locate")  # the fields are cached now
    wait_state(page, "window.viewerState.locates === 3 && !window.viewerState.locating", errors, external)


def test_viewer_works_for_an_uploaded_phantom_in_mm(page, live_url):
    page, errors, external = page
    meshes = nested_phantom_meshes()
    for mesh in meshes.values():
        mesh.apply_scale(1000.0)  # a 200 mm box holding a 40 mm sphere, in millimetres
    manifest = phantom_manifest(name="browser box", units="mm", sites={
        "capsule": {"kind": "capsule", "position_m": [0.0, 0.0, 0.010]},
        "side": {"kind": "sensor", "position_m": [0.099, 0.0, 0.0]}})
    r = httpx.post(f"{live_url}/v1/phantoms", timeout=HANG_GUARD_S, files={
        "mesh": ("box.glb", glb_bytes(meshes), "model/gltf-binary"),
        "manifest": ("manifest.json", json.dumps(manifest), "application/json")})
    assert r.status_code == 201, r.text
    phantom_id = r.json()["id"]
    try:
        page.goto(f"{live_url}/viewer")
        wait_state(page, "window.viewerState.ready", errors, external)
        assert phantom_id in page.locator("#phantom option").evaluate_all("opts => opts.map(o => o.value)")
        page.select_option("#phantom", phantom_id)
        state = wait_state(page, f"window.viewerState.ready && window.viewerState.phantom === '{phantom_id}'",
                           errors, external)
        assert state["organs"] == 2 and state["sites"] == 2
        pixels = page.evaluate(COUNT_PIXELS, list(BACKGROUND))
        # scaled mm -> m and framed: the box covers much of the view (unscaled it would be 1000x too big)
        assert 0.05 * pixels["total"] < pixels["drawn"] < 0.95 * pixels["total"], pixels
        # the capsule at a typed position (mm) instead of a site: inside the sphere, 20 mm off its centre
        page.select_option("#capsule", "(a position)")
        assert page.is_visible("#capsule-position")
        assert page.input_value("#capsule-z") == "10.0"  # prefilled from the site
        for axis, value in zip("xyz", ["0", "20", "0"]):
            page.fill(f"#capsule-{axis}", value)
        page.click("#trace")
        state = wait_state(page, "window.viewerState.traces === 1 && !window.viewerState.tracing "
                           "&& window.viewerState.pdp !== null", errors, external)
        assert state["transmitter"] == pytest.approx([0.0, 0.02, 0.0])
        assert state["receivers"][0]["receiver"] == "side" and state["paths"] == state["receivers"][0]["paths"] > 0
        assert errors == [] and external == [], (errors, external)
    finally:
        httpx.delete(f"{live_url}/v1/phantoms/{phantom_id}", timeout=HANG_GUARD_S)


def test_viewer_reports_a_bad_trace_on_the_page(page, live_url):
    page, errors, external = page
    page.goto(f"{live_url}/viewer")
    wait_state(page, "window.viewerState.ready", errors, external)
    page.fill("#rays", "0")
    page.click("#trace")
    state = wait_state(page, "window.viewerState.error !== null && !window.viewerState.tracing", errors, external)
    assert "body.rays" in state["error"], state  # the API's 422 names the field; the page shows it
    assert page.locator("#status.error").count() == 1
    # the 422 itself is the one console error Chromium logs for a failed fetch; nothing else
    assert all("422" in e for e in errors) and external == [], (errors, external)


def test_swagger_ui_renders_offline(page, live_url):
    page, errors, external = page
    page.goto(f"{live_url}/docs")
    page.wait_for_selector(".swagger-ui .info .title", timeout=GUARD_MS)
    assert "CapsuleRT" in page.inner_text(".swagger-ui .info .title")
    page.wait_for_function("() => document.querySelectorAll('.opblock').length >= 20", timeout=GUARD_MS)
    summaries = page.locator(".opblock-summary-path").all_inner_texts()
    assert "/v1/channel" in [s.strip() for s in summaries] and any("/v1/plots/pdp" in s for s in summaries)
    assert errors == [] and external == [], (errors, external)


def test_viewer_colours_the_skin_with_a_coverage(page, live_url):
    """The design layer (docs/design.md): a coverage job made on the server, then shown in the viewer: one
    disc per candidate (the count the map endpoint gives), drawn over the torso, its scale shown; clear
    removes it."""
    import time

    page, errors, external = page
    spec = {"positions": {"sites": ["stomach"]},
            "candidates": {"spacing_m": 0.08, "region": {"min_m": [-1, -1, 0.0], "max_m": [1, 1, 0.15]}},
            "channel": {"rays": 2000, "max_interactions": 2, "dynamic_range_db": 30}, "cell_size_m": 0.01}
    r = httpx.post(f"{live_url}/v1/design/coverage", json=spec, timeout=HANG_GUARD_S)
    assert r.status_code == 202, r.text
    job = r.json()
    deadline = time.monotonic() + HANG_GUARD_S  # a wait for the job, never a verdict on speed
    while job["state"] in ("queued", "running") and time.monotonic() < deadline:
        time.sleep(0.5)
        job = httpx.get(f"{live_url}/v1/design/coverage/{job['id']}", timeout=HANG_GUARD_S).json()
    assert job["state"] == "done", job
    try:
        m = httpx.get(f"{live_url}/v1/design/coverage/{job['id']}/map?metric=direct_path", timeout=HANG_GUARD_S)
        candidates = len(m.json()["candidates_m"])
        assert candidates > 12
        page.goto(f"{live_url}/viewer")
        wait_state(page, "window.viewerState.ready", errors, external)
        assert not page.is_visible("#coverage-scale")
        page.evaluate(COUNT_PIXELS, list(BACKGROUND))  # the frame before the layer
        page.fill("#coverage-id", job["id"])
        page.select_option("#coverage-metric", "direct_path")
        page.click("#coverage-show")
        state = wait_state(page, "window.viewerState.coverage > 0", errors, external)
        assert state["coverage"] == candidates
        assert page.is_visible("#coverage-scale") and page.inner_text("#coverage-max") == "1.00"
        after = page.evaluate(COUNT_PIXELS, list(BACKGROUND))
        assert after["changed"] > 200, after  # the discs were drawn over the skin
        page.click("#coverage-clear")
        assert not page.is_visible("#coverage-scale")
        assert errors == [] and external == [], (errors, external)
    finally:
        httpx.delete(f"{live_url}/v1/design/coverage/{job['id']}", timeout=HANG_GUARD_S)
