#!/usr/bin/env python3
"""Regenerate the docs' browser pictures (docs/browser_*.png) from today's recordings.

    python analysis/recording_pictures.py                     # every picture, into docs/
    python analysis/recording_pictures.py --only browser_recording_lego --out /tmp/pictures

Each picture of :data:`PICTURES` runs a shipped scene (``python -m godobject_drake run SCENE
--record FILE`` with the picture's flags), opens the recording in headless Chromium (Playwright;
``CHROMIUM=/path`` picks the browser, ``/usr/bin/chromium`` by default), seeks it, paused, to the
picture's times and writes the screenshot (several times: side by side, halved). The live page's
picture runs the brick scene live (``--device meshcat``), grasps, lifts and stops it.

Each PNG carries what it was made from, as text chunks: ``godobject:scene_sha256`` (the scene
file's SHA-256), ``godobject:flags`` and ``godobject:legend`` (the legend's lines the recording
drew, each with its swatches' styles: their colours and shapes). tests/test_legend.py checks that
every ``browser_*.png`` the docs embed is listed here and that each one's scene file and legend
are today's.
"""

import argparse
import dataclasses
import hashlib
import io
import json
import os
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
CHROMIUM = os.environ.get("CHROMIUM", "/usr/bin/chromium")
ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking"]
VIEW = {"width": 1280, "height": 800}
PUSH_LOG = "models/lego/push_and_return.csv"
# The legend as the page draws it: each line's text and its swatches' styles (their colours and shapes).
ROWS = "#godobject-legend .row"
LEGEND_JS = """(rows) => rows.map((r) => [r.innerText.trim(),
    Array.from(r.querySelectorAll('.swatch')).map((s) => s.getAttribute('style'))])"""
PRESS = ("--set", "organs.model=fem", "--set", "device.path=models/laparoscopy/deep_press_path.yaml")


@dataclasses.dataclass(frozen=True)
class Picture:
    """docs/NAME.png: the shipped ``scene`` run for ``duration_s`` with ``flags``, shown at each
    of ``at_s`` (recording time; None: the end), side by side; ``live``: the live page instead."""

    name: str
    scene: str
    duration_s: float = 5.0
    flags: tuple[str, ...] = ()
    at_s: tuple[float | None, ...] = (None,)
    live: bool = False


MOUSE = ("--device", "relative", "--device-log", PUSH_LOG)  # a mouse pushes the brick through the wall
PICTURES = (
    Picture("browser_recording_lego", "lego", 3.2, at_s=(3.1,)),
    Picture("browser_recording_laparoscopy", "laparoscopy", 4.0, at_s=(3.5,)),
    Picture("browser_recording_deformable_probe", "deformable_probe", 3.5, at_s=(3.0,)),
    # the two hands apart (1 s: the right hand lifts brick_1 over), then the right's brick laid on the left's
    Picture("browser_recording_two_hands", "lego_two_hands", 3.6, at_s=(1.0, 3.5)),
    Picture("browser_recording_tissue", "laparoscopy", 0.9, PRESS, at_s=(0.0, None)),
    # the left grasper lifting the first ring, then the right one lowering it onto its peg
    Picture("browser_recording_peg_transfer", "peg_transfer", 5.2, at_s=(2.6, 5.0)),
    Picture("browser_force_cue_tracking", "lego", 4.0, at_s=(1.0,)),
    Picture("browser_force_cue_at_wall", "lego", 4.0, at_s=(3.1,)),
    Picture("browser_mouse_untethered", "lego", 2.2, MOUSE, (2.0,)),
    Picture("browser_mouse_tethered", "lego", 2.2, (*MOUSE, "--tether", "0.002"), (2.0,)),
    Picture("browser_live_lego", "lego", 60.0, ("--device", "meshcat"), live=True),
)


def scene_file(scene: str) -> Path:
    return REPO / "diagrams" / f"{scene}.yaml"


def scene_sha256(scene: str) -> str:
    return hashlib.sha256(scene_file(scene).read_bytes()).hexdigest()


def record(picture: Picture, folder: Path) -> Path:
    """Run the picture's scene into a recording; its path."""
    html = folder / f"{picture.name}.html"
    command = [sys.executable, "-m", "godobject_drake", "run", str(scene_file(picture.scene)), "--duration",
               f"{picture.duration_s:g}", "--record", str(html), "--no-progress", *picture.flags]  # fmt: skip
    subprocess.run(command, cwd=REPO, check=True, stdout=subprocess.DEVNULL)
    return html


def screenshots(browser, html: Path, times) -> tuple[list[bytes], list]:
    """The recording at each of ``times`` (paused, sought; the deforming surfaces' script
    ready), and the legend's lines: each ``[text, [swatch style, ...]]``."""
    page = browser.new_page(viewport=VIEW)
    page.goto(html.as_uri())
    page.wait_for_function("() => viewer.animator.duration > 0", timeout=60_000)
    end = page.evaluate("() => viewer.animator.duration")
    shots = []
    for t in times:
        page.evaluate("(t) => { viewer.animator.pause(); viewer.animator.seek(t); viewer.set_dirty(); }",
                      end if t is None else t)  # fmt: skip
        page.wait_for_function("() => !window.godobjectSurfaces || window.godobjectSurfaces.ready")
        time.sleep(0.8)
        shots.append(page.screenshot())
    legend = page.eval_on_selector_all(ROWS, LEGEND_JS)
    page.close()
    return shots, legend


def live_screenshot(browser, picture: Picture) -> bytes:
    """The brick scene live: open the controls, grasp, raise the target (the O key), shoot, Stop."""
    command = [sys.executable, "-m", "godobject_drake", "run", str(scene_file(picture.scene)), "--duration",
               f"{picture.duration_s:g}", "--no-progress", *picture.flags]  # fmt: skip
    proc = subprocess.Popen(command, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        url, deadline = None, time.monotonic() + 60
        while url is None and time.monotonic() < deadline:
            found = re.search(r"(http://localhost:\d+)", proc.stderr.readline())
            url = found.group(1) if found else None
        if url is None:
            raise RuntimeError("the live run printed no Meshcat URL within 60 s")
        page = browser.new_page(viewport=VIEW)
        page.goto(url)
        page.get_by_text("Open Controls").click()
        page.get_by_text("Grasp / release").click()
        time.sleep(0.5)
        page.mouse.click(640, 700)  # focus the view: the keys go to the page
        for _ in range(20):
            page.keyboard.press("o")
            time.sleep(0.05)
        time.sleep(1.0)
        png = page.screenshot()
        page.get_by_text("Stop").click()
        proc.wait(timeout=60)
        return png
    finally:
        if proc.poll() is None:
            proc.kill()


def side_by_side(pngs: list[bytes]):
    """One image: each screenshot halved, left to right (one screenshot: as it is)."""
    from PIL import Image

    images = [Image.open(io.BytesIO(p)).convert("RGB") for p in pngs]
    if len(images) == 1:
        return images[0]
    half = [im.resize((im.width // 2, im.height // 2)) for im in images]
    out = Image.new("RGB", (sum(im.width for im in half) + 8 * (len(half) - 1), half[0].height), "white")
    x = 0
    for im in half:
        out.paste(im, (x, 0))
        x += im.width + 8
    return out


def save(image, path: Path, picture: Picture, legend: list) -> None:
    """Write the PNG with what it was made from (module docstring)."""
    from PIL.PngImagePlugin import PngInfo

    info = PngInfo()
    info.add_text("godobject:scene_sha256", scene_sha256(picture.scene))
    info.add_text("godobject:flags", json.dumps([f"--duration={picture.duration_s:g}", *picture.flags]))
    info.add_text("godobject:legend", json.dumps(legend))
    image.save(path, pnginfo=info, optimize=True)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("--out", type=Path, default=REPO / "docs", help="the folder for the pictures")
    parser.add_argument("--only", nargs="*", default=None, help="these pictures only (NAME, no .png)")
    args = parser.parse_args(argv)
    from PIL import Image
    from playwright.sync_api import sync_playwright

    chosen = [p for p in PICTURES if args.only is None or p.name in args.only]
    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory() as folder, sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM, args=ARGS)
        for picture in chosen:
            if picture.live:
                image, legend = Image.open(io.BytesIO(live_screenshot(browser, picture))).convert("RGB"), []
            else:
                shots, legend = screenshots(browser, record(picture, Path(folder)), picture.at_s)
                image = side_by_side(shots)
            save(image, args.out / f"{picture.name}.png", picture, legend)
            print(f"wrote {args.out / picture.name}.png", flush=True)
        browser.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
