"""katana-calibrate: overhead camera pose from blocks or markers at known table positions.

Writes the standard ROS camera_info YAML (intrinsics) and an extrinsics YAML (pose of
camera_optical_frame in world) that perception_node, block_memory_node and fovea_node read
through their `extrinsics_file` parameter. Intrinsics must be known (from the ROS
camera_calibration tool's YAML or given focal length): a straight-down view of a flat table
cannot tell a long focal length from a far camera.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np
import yaml
from katana_common.cli_args import (
    CommandLineError,
    float_in,
    parse_command_line,
    positive_number,
    readable_file,
    writable_folder,
)
from katana_description.models import BLOCK_SIZE

from .core.calibration import Calibration, load_camera_info_yaml, solve_extrinsics
from .core.colors import DEFAULT_COLOR_TABLE, parse_color_table
from .core.segmentation import Segmenter

USAGE_EXAMPLE = """\
points file (YAML, metres, frame world = table surface under the pan axis):
  block_size: [0.04, 0.04, 0.03]     # optional
  blocks:                            # centre x, y of each visible block [, level]
    red: [0.18, 0.08]                #   level 1 (default): lying on the table
    green: [0.26, -0.10]
    blue: [0.16, -0.06]
    yellow: [0.27, 0.09, 2]          #   level 2: on another block (hidden under it)
  markers:                           # optional: points whose pixels you read off yourself
    - {world: [0.30, 0.0, 0.0], pixel: [319.5, 159.5]}

example (two views of the blocks at different places pool their points):
  katana-calibrate --image a.png --points a.yaml --image b.png --points b.yaml \\
      --camera-info camera.yaml --out-dir ~/.ros/katana_camera
  then run the nodes with extrinsics_file:=~/.ros/katana_camera/extrinsics.yaml

Put at least one block on another (level 2 or 3): points all on one plane leave the camera's
tilt and shift confused, which costs several mm at other heights.
"""


_pixels = float_in(0.0, what="a pixel coordinate")


def _color_entry(text: str) -> str:
    try:
        parse_color_table([text])
    except ValueError as err:
        raise argparse.ArgumentTypeError(f"NAME:LO-HI[,LO-HI] with hues 0..179 ({err})") from None
    return text


def _name(text: str) -> str:
    if not text.strip():
        raise argparse.ArgumentTypeError("a non-empty name")
    return text


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="katana-calibrate",
        description="Calibrate the overhead camera from >= 4 blocks/markers at known places "
                    "(cv2.solvePnP).",
        epilog=USAGE_EXAMPLE, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--image", required=True, type=readable_file, action="append",
                    help="overhead image (PNG/JPG) with the arm out of view; repeat with "
                         "--points for more views (more points: a better pose)")
    ap.add_argument("--points", required=True, type=readable_file, action="append",
                    help="YAML file of the known points of the matching --image")
    ap.add_argument("--camera-info", type=readable_file,
                    help="intrinsics: ROS camera_info YAML (camera_calibration output)")
    ap.add_argument("--fx", type=positive_number,
                    help="focal length in px, when no --camera-info")
    ap.add_argument("--fy", type=positive_number, help="default: fx")
    ap.add_argument("--cx", type=_pixels, help="default: (width - 1) / 2")
    ap.add_argument("--cy", type=_pixels, help="default: (height - 1) / 2")
    ap.add_argument("--color-table", nargs="+", metavar="NAME:LO-HI", type=_color_entry,
                    help="colour table entries, as perception_node's color_table parameter")
    ap.add_argument("--out-dir", type=writable_folder, default=Path("."),
                    help="where camera_info.yaml and extrinsics.yaml go (default: .)")
    ap.add_argument("--camera-name", default="overhead_camera", type=_name)
    ap.add_argument("--max-rms", type=positive_number, default=2.0,
                    help="fail when the RMS reprojection error exceeds this, px (default 2)")
    return ap


def read_points(path: Path) -> tuple[dict[str, tuple[float, float]], list, list, tuple]:
    data = yaml.safe_load(path.read_text()) or {}
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a mapping with 'blocks' and/or 'markers'")
    size = tuple(float(v) for v in data.get("block_size", BLOCK_SIZE))
    if len(size) != 3 or min(size) <= 0:
        raise ValueError(f"{path}: block_size must be three positive numbers")
    blocks = {}
    for name, xy in (data.get("blocks") or {}).items():
        if not (isinstance(xy, list | tuple) and len(xy) in (2, 3)):
            raise ValueError(f"{path}: block {name!r} needs [x, y] or [x, y, level]")
        level = int(xy[2]) if len(xy) == 3 else 1
        if level < 1:
            raise ValueError(f"{path}: block {name!r} has level {level}; levels start at 1")
        blocks[str(name)] = (float(xy[0]), float(xy[1]), level)
    world, pixel = [], []
    for i, m in enumerate(data.get("markers") or []):
        try:
            w, p = [float(v) for v in m["world"]], [float(v) for v in m["pixel"]]
        except (KeyError, TypeError, ValueError) as err:
            raise ValueError(f"{path}: marker {i} needs world [x, y, z] and pixel [u, v]") from err
        if len(w) != 3 or len(p) != 2:
            raise ValueError(f"{path}: marker {i} needs world [x, y, z] and pixel [u, v]")
        world.append(w)
        pixel.append(p)
    return blocks, world, pixel, size


def calibrate(views: list[tuple[np.ndarray, dict, list, list]], K: np.ndarray, D: np.ndarray,
              segmenter: Segmenter, size: tuple
              ) -> tuple[Calibration, float, list[tuple[str, float]]]:
    """Pose from one or more views (image, blocks, marker world points, marker pixels).

    Solved once from blob centres, then again from top-face centres, which need the pose.
    """
    h, w = views[0][0].shape[:2]
    calib = None
    for _ in range(2):
        names, world, pixel = [], [], []
        for v, (rgb, blocks, marker_world, marker_pixel) in enumerate(views):
            if rgb.shape[:2] != (h, w):
                raise ValueError(f"image {v + 1} is {rgb.shape[1]}x{rgb.shape[0]}, "
                                 f"the first is {w}x{h}")
            levels = {name: lv for name, (_, _, lv) in blocks.items()}
            dets = {d.color: d for d in segmenter.segment(rgb, calib, levels)}
            missing = [b for b in blocks if b not in dets]
            if missing:
                raise ValueError(f"image {v + 1}: blocks not found: {', '.join(missing)} "
                                 f"(found: {', '.join(dets) or 'none'})")
            tag = f"{v + 1}:" if len(views) > 1 else ""
            names += [tag + b for b in blocks]
            names += [f"{tag}marker {i}" for i in range(len(marker_world))]
            world += [[x, y, lv * size[2]] for x, y, lv in blocks.values()] + marker_world
            pixel += [[dets[b].u, dets[b].v] for b in blocks] + marker_pixel
        calib, rms, err = solve_extrinsics(np.array(world), np.array(pixel), K, D, w, h)
    return calib, rms, list(zip(names, err.tolist(), strict=True))


def _check(args) -> None:
    """Across options (cli_args.parse_command_line, before any work)."""
    if len(args.image) != len(args.points):
        raise CommandLineError("--points", f"{len(args.image)} --image but {len(args.points)} "
                               "--points; give one points file per image")
    if args.camera_info is None and args.fx is None:
        raise CommandLineError("--camera-info/--fx", "intrinsics needed: --camera-info FILE or "
                               "--fx PX (> 0)")


def main(argv: list[str] | None = None) -> int:
    args = parse_command_line(build_parser(), argv, [_check])
    try:
        images = []
        for path in args.image:
            bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
            if bgr is None:
                raise ValueError(f"cannot read image {path}")
            images.append(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
        h, w = images[0].shape[:2]
        if args.camera_info is not None:
            K, D, cw, ch = load_camera_info_yaml(args.camera_info)
            if (cw, ch) != (w, h):
                raise ValueError(f"camera_info is for {cw}x{ch} but the image is {w}x{h}")
        elif args.fx is not None:
            fy = args.fy if args.fy is not None else args.fx
            cx = args.cx if args.cx is not None else (w - 1) / 2.0
            cy = args.cy if args.cy is not None else (h - 1) / 2.0
            K, D = np.array([[args.fx, 0, cx], [0, fy, cy], [0, 0, 1.0]]), np.zeros(5)
        views, sizes = [], set()
        for rgb, path in zip(images, args.points, strict=True):
            blocks, mw, mp, size = read_points(path)
            views.append((rgb, blocks, mw, mp))
            sizes.add(size)
        if len(sizes) != 1:
            raise ValueError("the points files disagree on block_size")
        n = sum(len(v[1]) + len(v[2]) for v in views)
        if n < 4:
            raise ValueError(f"need at least 4 known points, got {n}")
        table = parse_color_table(args.color_table) if args.color_table else DEFAULT_COLOR_TABLE
        seg = Segmenter(table, block_size=size)
        calib, rms, per_point = calibrate(views, K, D, seg, size)
    except (ValueError, OSError, yaml.YAMLError) as err:
        print(f"katana-calibrate: {err}", file=sys.stderr)
        return 1
    for name, e in per_point:
        print(f"  {name:>12}: {e:6.2f} px")
    heights = {lv * size[2] for v in views for _, _, lv in v[1].values()}
    heights |= {m[2] for v in views for m in v[2]}
    if len(heights) < 2:
        print("katana-calibrate: warning: every point is at one height; put a block on a block "
              "(level 2) for a well-conditioned pose", file=sys.stderr)
    print(f"RMS reprojection error {rms:.2f} px; camera at {np.round(calib.centre, 4).tolist()}")
    if rms > args.max_rms:
        print(f"katana-calibrate: RMS {rms:.2f} px exceeds --max-rms {args.max_rms}: check the "
              "positions in the points file", file=sys.stderr)
        return 1
    args.out_dir.mkdir(parents=True, exist_ok=True)
    info, extr = args.out_dir / "camera_info.yaml", args.out_dir / "extrinsics.yaml"
    calib.save(info, extr, rms_px=rms, camera_name=args.camera_name)
    print(f"wrote {info} and {extr}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
