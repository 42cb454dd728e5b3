#!/usr/bin/env python3
"""The brick scene: grasp a 2x4 brick with a god-object and build with it.

    python diagrams/lego.py --metrics m.json --record r.html

The layout is fixed (README "Brick scene"): models/lego/lego.dmd.yaml; the
device path is models/lego/default_path.yaml, or any CSV log with
``--device replay --device-log FILE.csv``.
"""

import argparse
import sys

from pydrake.systems.framework import DiagramBuilder

from godobject_drake.coupling import CouplingGainError, GodObjectCoupling
from godobject_drake.runner import (
    add_common_arguments,
    add_loggers,
    add_visualization,
    connect_device,
    gains_from_args,
    make_device,
    make_meshcat,
    report,
    simulate,
)
from godobject_drake.scenes import APPROXIMATIONS, CONTACT_MODELS, MODELS_DIR, add_scene_from_directives

SCENE = "lego"
DIRECTIVES = "package://godobject_models/lego/lego.dmd.yaml"
DEFAULT_PATH = MODELS_DIR / "lego" / "default_path.yaml"


# Where the live device may go (m): the table's area, up to 12 cm high.
LIVE_WORKSPACE = ([-0.15, -0.10, 0.0], [0.15, 0.10, 0.12])


def build(args):
    """Compose the whole diagram: device → coupling → plant, coupling → feedback."""
    builder = DiagramBuilder()
    scene = add_scene_from_directives(
        builder, DIRECTIVES, args.time_step, contact=args.contact, approximation=args.contact_approximation
    )
    plant = scene.plant
    meshcat = make_meshcat(args)
    device = builder.AddNamedSystem("device", make_device(args, DEFAULT_PATH, meshcat, LIVE_WORKSPACE))
    coupling = builder.AddNamedSystem(
        "coupling",
        GodObjectCoupling(plant, gains_from_args(args), device_period_s=device.period_s),
    )
    coupling.validate_grasp_names(device.grasp_names(args.duration))
    chain = connect_device(builder, args, device, plant, coupling)
    loggers = add_loggers(builder, plant, coupling)
    meshcat = add_visualization(builder, args, plant, scene.scene_graph, coupling, meshcat)
    return builder.Build(), scene, coupling, loggers, meshcat, chain


def run(args):
    diagram, scene, coupling, loggers, meshcat, chain = build(args)
    return simulate(
        diagram, scene.plant, scene.scene_graph, coupling, loggers,
        scene=SCENE, mode=args.mode, duration=args.duration, meshcat=meshcat, record=args.record,
        realtime=args.meshcat or args.device == "meshcat", progress=not args.no_progress, chain=chain,
        extra={"contact": args.contact, "contact_approximation": args.contact_approximation,
               "device": args.device, "device_rate_hz": args.device_rate,
               "haptic": args.haptic, "omega_n_rad_s": args.omega_n,
               "omega_n_rot_rad_s": gains_from_args(args).omega_r, "zeta": args.zeta, "seed": args.seed},
    )  # fmt: skip


def make_parser():
    """The scene's command line: the common flags and ``--contact``."""
    parser = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    add_common_arguments(parser, default_duration=8.5)
    parser.add_argument("--contact", choices=CONTACT_MODELS, default="proxies", help="collision geometry")
    parser.add_argument(
        "--contact-approximation", choices=APPROXIMATIONS, default="sap",
        help="Drake's discrete contact approximation (README 'Speed against error')",
    )  # fmt: skip
    return parser


def main(argv=None):
    parser = make_parser()
    args = parser.parse_args(argv)
    try:
        result = run(args)
    except (CouplingGainError, ValueError, FileNotFoundError) as e:
        parser.error(str(e))
    report([result.metrics], args.metrics)
    if args.record:
        print(f"recording written to {args.record}")
    if (args.meshcat or args.device == "meshcat") and sys.stdin.isatty():
        input("Meshcat is still serving the scene; press Enter to exit.")
    return 1 if result.metrics["diverged"] else 0


if __name__ == "__main__":
    sys.exit(main())
