#!/usr/bin/env python3
"""Render the brick scene's Diagram (``GetGraphvizString``) to a PNG for the README.

    python analysis/render_diagram.py [--out docs/lego_diagram.png]

Needs Graphviz's ``dot`` (Debian: ``apt-get install graphviz``).
"""

import argparse
import shutil
import subprocess
from pathlib import Path

from godobject_drake.config.scenario import shipped_scenario
from godobject_drake.station.build import build_station

REPO = Path(__file__).resolve().parent.parent


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--out", type=Path, default=REPO / "docs" / "lego_diagram.png")
    args = parser.parse_args(argv)
    dot = shutil.which("dot")
    if dot is None:
        raise SystemExit("Graphviz's `dot` is not on PATH; install it (Debian: apt-get install graphviz)")
    diagram = build_station(shipped_scenario("lego")).diagram
    graph = diagram.GetGraphvizString(max_depth=1)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    subprocess.run([dot, "-Tpng", "-Gdpi=110", "-o", str(args.out)], input=graph.encode(), check=True)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
