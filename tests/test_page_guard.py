"""The live page and other pages (issue 45): Drake's Meshcat takes a websocket from any page open on
the machine (no Origin check, no secret: it serves ``/*`` with no upgrade handler), so a run that
serves the page says so first, and a haptic device (a simulated one, or one that renders the
feedback) runs with a live page only with the opt-in ``--trust-local-pages``. The browser test
shows, in real Chromium, what a ``file://`` page does to a live run."""

import json
import re
import time

import pytest
from conftest import REPO, scenario

from godobject_drake import cli
from godobject_drake.config.scenario import ScenarioError
from godobject_drake.station.build import make_meshcat

OPT_IN = r"opt in with --trust-local-pages \(visualization\.trust_local_pages: true\)"


@pytest.mark.parametrize(
    "flags, named",
    [
        (("--meshcat", "--haptic", "impedance"), r"--haptic impedance \(haptic\.mode\)"),
        (("--meshcat", "--haptic", "admittance"), r"--haptic admittance \(haptic\.mode\)"),
        (("--device", "meshcat", "--haptic", "impedance"), r"--haptic impedance \(haptic\.mode\)"),
        (("--device", "lcm", "--lcm-url", "memq://", "--meshcat"), r"!Lcm renders the feedback \(device\)"),
    ],
)
def test_a_haptic_device_with_a_live_page_needs_the_opt_in(flags, named):
    """Before: served, and any page could move the target a hand feels. Now refused, naming the
    haptic device, what any page can do, and the opt-in; with it, served."""
    with pytest.raises(ScenarioError) as refused:
        make_meshcat(scenario("lego", *flags))
    message = str(refused.value)
    assert re.search(r"a live page with a haptic device \(" + named, message), message
    assert "any web page open on this machine can connect to the page's websocket" in message
    assert re.search(OPT_IN, message), message
    meshcat = make_meshcat(scenario("lego", *flags, "--trust-local-pages"))
    assert meshcat is not None and meshcat.port() > 0


def test_a_haptic_run_without_a_page_needs_no_opt_in():
    assert make_meshcat(scenario("lego", "--haptic", "impedance")) is None
    assert make_meshcat(scenario("lego", "--device", "lcm", "--lcm-url", "memq://")) is None


def test_the_opt_in_is_a_scenario_field_too(tmp_path):
    text = (REPO / "diagrams" / "lego.yaml").read_text()
    file = tmp_path / "haptic_live.yaml"
    file.write_text(
        text.replace("visualization:\n", "visualization:\n  serve: true\n  trust_local_pages: true\n")
        + "haptic:\n  mode: impedance\n"
    )
    s = cli.load_with_sets(file, [])
    assert s.visualization.trust_local_pages is True and make_meshcat(s) is not None
    refused = cli.load_with_sets(file, ["visualization.trust_local_pages=false"])
    with pytest.raises(ScenarioError, match=OPT_IN):
        make_meshcat(refused)


def test_a_run_that_serves_the_page_says_first_what_any_page_can_do(capsys):
    assert cli.main(["run", "lego", "--meshcat", "--duration", "0.05", "--no-progress"]) == 0
    first = capsys.readouterr().err.splitlines()[0]
    assert first.startswith("WARNING: the live page takes commands from ANY web page open on this machine")
    assert (
        "a page from a file or from another local site can read the scene, stop the run and, with a " in first
    )


def test_a_run_without_a_page_says_nothing_of_pages(capsys):
    assert cli.main(["run", "lego", "--duration", "0.05", "--no-progress"]) == 0
    assert "ANY web page" not in capsys.readouterr().err


# A page from nowhere near the live page: a file on disk. It connects to the live page's websocket,
# counts what the server sends (the scene), then sends what the page's own controls send (msgpack,
# encoded by hand): Grasp, the z slider up, then Stop.
ATTACK = """<!DOCTYPE html><html><body><script>
function str(s) { const b = new TextEncoder().encode(s); return [0xa0 | b.length, ...b]; }
function f64(x) {
  const v = new DataView(new ArrayBuffer(8)); v.setFloat64(0, x); return [0xcb, ...new Uint8Array(v.buffer)];
}
function pack(o) {
  const keys = Object.keys(o); let out = [0x80 | keys.length];
  for (const k of keys) out = out.concat(str(k), typeof o[k] === "number" ? f64(o[k]) : str(o[k]));
  return new Uint8Array(out);
}
window.received = 0; window.opened = false; window.error = null;
const ws = new WebSocket("ws://localhost:PORT/");
ws.binaryType = "arraybuffer";
ws.onmessage = () => { window.received += 1; };
ws.onerror = (e) => { window.error = "error"; };
ws.onopen = () => { window.opened = true; };
window.send = (o) => ws.send(pack(o));
</script></body></html>"""


@pytest.mark.browser
@pytest.mark.slow(seconds=60)
def test_a_file_page_reads_grasps_lifts_and_stops_a_live_run(tmp_path):
    """What a ``file://`` page can do to the live page, in headless Chromium: connect to its
    websocket, receive the scene, grasp the nearest brick, raise the z slider and stop the run. The
    run ends stopped by that page with the brick lifted; its first line had said any page can."""
    from test_browser import ARGS, CHROMIUM, start_live_lego

    playwright = pytest.importorskip("playwright.sync_api")
    if not __import__("pathlib").Path(CHROMIUM).is_file():
        pytest.skip(f"no Chromium at {CHROMIUM}")
    proc, metrics, lines, url = start_live_lego(tmp_path)
    try:
        assert url, f"the live run never printed its Meshcat URL: {lines}"
        port = url.rsplit(":", 1)[1]
        assert lines[0].startswith("WARNING: the live page takes commands from ANY web page"), lines
        attack = tmp_path / "elsewhere.html"
        attack.write_text(ATTACK.replace("PORT", port))
        with playwright.sync_playwright() as p:
            browser = p.chromium.launch(executable_path=CHROMIUM, args=ARGS)
            page = browser.new_page()
            page.goto(attack.as_uri())  # origin "null": a file, not the live page
            page.wait_for_function("() => window.opened && window.received > 10", timeout=30_000)
            scene_messages = page.evaluate("() => window.received")
            page.evaluate("() => send({type: 'button', name: 'Grasp / release'})")
            time.sleep(0.5)
            for z in (0.03, 0.05, 0.07):
                page.evaluate(f"() => send({{type: 'slider', name: 'z', value: {z}}})")
                time.sleep(0.5)
            time.sleep(1.0)
            page.evaluate("() => send({type: 'button', name: 'Stop'})")
            proc.wait(timeout=60)
            browser.close()
    finally:
        if proc.poll() is None:
            proc.kill()
    m = json.loads(metrics.read_text())
    assert scene_messages > 10  # it read the scene: every object, transform and control
    assert m["stopped_by_user"] is True and m["sim_time_s"] < 60.0, m  # it stopped the run
    assert m["free_space_samples"] > 0  # it grasped a brick and lifted it into free space
