"""Template benchmark: in-plane templates rolled from one render per view (`--inplane-by rotated`, the
default) against every template rendered (`--inplane-by rendered`), side by side in one run: wall time of
each and the ratio, and how closely the rolled templates match the rendered ones (mask IoU, depth error on
the common mask, RGB PSNR), split into rolls by multiples of 90 deg (pixel permutations) and the others.

Prints figures, asserts nothing: `make bench` or
`.venv/bin/python benchmarks/templates.py [--ee robotiq_2f85,shadow_hand] [--views 4] [--resolution 128]`.
"""

import argparse
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from kernel.template_set import read_index, read_template, set_dir
from syneepose.preset import load_preset


def make(out: Path, ee: str, views: int, inplane: int, resolution: int, samples: int, how: str) -> float:
    start = time.perf_counter()
    subprocess.run([sys.executable, "-m", "syneepose", "templates", "--out", str(out), "--ee", ee, "--views",
                    str(views), "--inplane", str(inplane), "--resolution", str(resolution), "--samples",
                    str(samples), "--inplane-by", how], check=True, capture_output=True)
    return time.perf_counter() - start


def compare(rendered: Path, rotated: Path, inplane: int) -> dict[str, list[tuple[float, float, float, float]]]:
    """(IoU, share of common-mask depths within 1 mm, their 95th percentile error in mm, PSNR) per template."""
    rows = {"90-degree": [], "other": []}
    for key, rec in read_index(rendered).items():
        a, b = read_template(rendered, int(key)), read_template(rotated, int(key))
        both = a.mask & b.mask
        error_mm = np.abs(a.depth[both] - b.depth[both]) * 1000.0
        iou = both.sum() / (a.mask | b.mask).sum()
        kind = "90-degree" if rec["inplane"] % max(inplane // 4, 1) == 0 and inplane % 4 == 0 else "other"
        rows[kind].append((iou, (error_mm <= 1.0).mean(), np.percentile(error_mm, 95), cv2.PSNR(a.rgb, b.rgb)))
    return rows


def main() -> None:
    mini = load_preset("mini").templates
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--ee", default="robotiq_2f85,shadow_hand")
    parser.add_argument("--views", type=int, default=4)
    parser.add_argument("--inplane", type=int, default=mini.inplane)
    parser.add_argument("--resolution", type=int, default=mini.resolution)
    parser.add_argument("--samples", type=int, default=mini.samples)
    args = parser.parse_args()
    print(f"{args.views} views x {args.inplane} in-plane, {args.resolution} px, {args.samples} spp")
    for ee in args.ee.split(","):
        with tempfile.TemporaryDirectory() as tmp:
            seconds = {how: make(Path(tmp) / how, ee, args.views, args.inplane, args.resolution, args.samples, how)
                       for how in ("rendered", "rotated")}
            folders = [set_dir(Path(tmp) / how, ee, args.views, args.inplane, args.resolution)
                       for how in ("rendered", "rotated")]
            rows = compare(*folders, args.inplane)
        print(f"{ee}: rendered {seconds['rendered']:.1f} s, rotated {seconds['rotated']:.1f} s "
              f"(x{seconds['rendered'] / seconds['rotated']:.1f}, whole processes)")
        for kind, values in rows.items():
            if values:
                v = np.array(values)
                print(f"  {kind:9s} rolls ({len(v):3d}): IoU min {v[:, 0].min():.3f} mean {v[:, 0].mean():.3f}; "
                      f"depth within 1 mm {100 * v[:, 1].mean():.1f} % (min {100 * v[:, 1].min():.1f} %), "
                      f"p95 {v[:, 2].mean():.2f} mm; PSNR min {v[:, 3].min():.1f} dB")


if __name__ == "__main__":
    main()
