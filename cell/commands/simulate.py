"""``weldcell simulate``: render a synthetic weldment to a capture folder with exact ground truth."""

from __future__ import annotations

import argparse
import time
from typing import Literal


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "simulate",
        help="render a synthetic weldment (RGB-D capture + ground truth)",
        description="Render a synthetic weldment to a capture folder: color.png, depth, camera.json, "
        "prompts.json, ground_truth.json (and pose.json with --with-pose).",
    )
    p.add_argument("scene", nargs="?", help="scene name (see --list)")
    p.add_argument("--list", action="store_true", help="list the scenes and the zoo's families and exit")
    p.add_argument(
        "--random",
        metavar="FAMILY|all",
        help="draw a random weldment of a zoo family instead of a fixed scene (all: one of each family, "
        "written to OUT/FAMILY-SEED); its sensor, view and prompts are drawn too",
    )
    p.add_argument(
        "--split",
        choices=("dev", "test"),
        default="dev",
        help="with --random: the split the seed counts in (dev seeds start at 0, test seeds at 1,000,000)",
    )
    p.add_argument("--out", help="output capture folder")
    p.add_argument("--noise", choices=("stereo", "structured", "none"), default="stereo")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--with-pose", action="store_true", help="also write pose.json (robot pose and hand-eye)")
    p.add_argument(
        "--resolution",
        default="1280x720",
        help="image size WxH; the focal length scales with the width so the view stays the same",
    )
    p.add_argument(
        "--depth-format",
        choices=("png", "npy"),
        default=None,
        help="depth file format (default: png at 0.1 mm, npy for --noise none so depth stays exact)",
    )
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from sim_fakes.scenes import SCENES, get_scene, with_resolution

    if args.list:
        from sim_fakes.zoo import FAMILIES, HELD_OUT

        for name, factory in SCENES.items():
            scene = factory()
            print(f"{name:15s} {len(scene.seams):2d} seam(s)  {scene.description}")
        print(f"zoo families (--random): {', '.join(FAMILIES)}")
        print(f"held-out zoo families (never tuned on; --random NAME): {', '.join(HELD_OUT)}")
        return 0
    if args.random:
        return _random(args)
    if not args.scene or not args.out:
        print("weldcell simulate: give a SCENE and --out DIR (or --list)")
        return 2
    if args.scene not in SCENES:
        print(f"weldcell simulate: unknown scene {args.scene!r}; choose one of: {', '.join(SCENES)}")
        return 2

    from perception.capture import save_capture
    from sim_fakes.render import render

    try:
        width, height = (int(x) for x in args.resolution.lower().split("x"))
        if not (16 <= width <= 8192 and 16 <= height <= 8192):
            raise ValueError
    except ValueError:
        print(f"weldcell simulate: --resolution must look like 1280x720, got {args.resolution!r}")
        return 2
    scene = with_resolution(get_scene(args.scene), width, height)
    t0 = time.perf_counter()
    result = render(scene, noise=args.noise, seed=args.seed, with_pose=args.with_pose)
    t_render = time.perf_counter() - t0
    fmt: Literal["png", "npy"] = args.depth_format or ("npy" if args.noise == "none" else "png")
    folder = save_capture(result.capture, args.out, depth_format=fmt)
    cap = result.capture
    print(
        f"{args.scene}: {cap.intrinsics.width}x{cap.intrinsics.height}, noise={args.noise}, seed={args.seed}, "
        f"rendered in {t_render:.2f} s -> {folder}"
    )
    print(f"  {len(result.surfaces)} prompted surfaces, {len(result.ground_truth)} visible seam(s):")
    for g in result.ground_truth:
        length = float(((g.points_world[1:] - g.points_world[:-1]) ** 2).sum(axis=1).__pow__(0.5).sum())
        print(f"    {g.name:16s} {g.kind:7s} {length * 1000:7.1f} mm")
    return 0


def _random(args: argparse.Namespace) -> int:
    from perception.capture import save_capture
    from sim_fakes.zoo import ALL_FAMILIES, FAMILIES, SPLIT_BASE, draw_capture

    if not args.out:
        print("weldcell simulate: give --out DIR with --random")
        return 2
    families = list(FAMILIES) if args.random == "all" else [args.random]
    if families[0] not in ALL_FAMILIES:
        print(f"weldcell simulate: unknown zoo family {args.random!r}; choose one of: {', '.join(ALL_FAMILIES)}, "
              "all")
        return 2
    if args.seed < 0 or args.seed >= SPLIT_BASE["test"]:
        print(f"weldcell simulate: --seed counts within the split, 0 to {SPLIT_BASE['test'] - 1}")
        return 2
    seed = SPLIT_BASE[args.split] + args.seed
    from pathlib import Path

    for family in families:
        t0 = time.perf_counter()
        z = draw_capture(family, seed)
        out = Path(args.out) if len(families) == 1 else Path(args.out) / f"{family}-{seed}"
        folder = save_capture(z.result.capture, out, depth_format="png")
        prompts = z.result.capture.prompts_px
        print(
            f"{family} seed {seed} ({args.split}): {z.sensor}, camera at {z.camera_distance_m:.2f} m, "
            f"{'no prompts' if prompts is None else f'{len(prompts)} prompts'}, {z.clutter} clutter box(es), "
            f"rendered in {time.perf_counter() - t0:.2f} s -> {folder}"
        )
        for g in z.result.ground_truth:
            length = float(((g.points_world[1:] - g.points_world[:-1]) ** 2).sum(axis=1).__pow__(0.5).sum())
            print(f"    {g.name:24s} {g.joint:13s} {g.kind:7s} {length * 1000:7.1f} mm")
    return 0
