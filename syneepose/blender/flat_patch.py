"""`python -m syneepose.blender.flat_patch`: is the simulated stereo depth as noisy as a D435, no more and
no less? A grey wall facing the camera at several distances, its sensed depth over the central ROI
fitted with a plane; the residual RMS is compared with Intel's published model for the D4xx family,
RMS = z^2 x subpixel / (f x baseline) (Intel, "Tuning depth cameras for best performance", subpixel
RMS about 0.08 px on a well-textured wall), at our IR focal length and baseline.

Prints one row per distance and writes them to --out as JSON.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

from kernel.cli import run_command
from kernel.errors import UserError
from kernel.files import write_atomic
from kernel.transforms import make_T
from syneepose.ir_shading import Lighting
from syneepose.scene.spec import IR_RENDERS, Plane, Surface
from syneepose.stereo import INTEL_SUBPIXEL, load_profile, plane_rms, stereo_depth, to_rgb_camera

def measure(distances: list[float], width: int, height: int, profile_name: str, roi: float,
            ir_render: str | None = None) -> list[dict]:
    from syneepose.blender import scene as bscene
    from syneepose.blender.stereo import IrRig

    profile = load_profile(profile_name, ir_render)
    world = (0.3, 0.3, 0.3)
    f = width / 2 / np.tan(np.deg2rad(30))
    K = np.array([[f, 0, (width - 1) / 2], [0, f, (height - 1) / 2], [0, 0, 1.0]])
    grey = Surface("plain", (0.5, 0.5, 0.5), (0.5, 0.5, 0.5), 1.0)
    rows = []
    with tempfile.TemporaryDirectory() as work:
        for z in distances:
            bscene.reset(width, height, 4, False, 4, world, 1.0)
            bscene.set_camera(K, width, height, np.eye(4))
            bscene.add_planes([Plane(make_T(np.diag([1.0, -1.0, -1.0]), [0, 0, z]), (20.0, 20.0), grey)])
            rig = IrRig(profile, width, height, seed=0, lighting=Lighting.of([], world, 1.0, profile.ambient))
            left, right = rig.render_pair(np.eye(4), Path(work))
            sensed = to_rgb_camera(stereo_depth(left, right, profile, rig.K_ir), rig.K_ir, profile.T_rgb_irleft,
                                   K, width, height)
            rms, robust, median, fill = plane_rms(sensed, K, roi)
            f_ir = float(rig.K_ir[0, 0])
            intel = z**2 * INTEL_SUBPIXEL / (f_ir * profile.baseline)
            rows.append({"z_m": z, "rms_mm": 1e3 * rms, "robust_sigma_mm": 1e3 * robust, "intel_rms_mm": 1e3 * intel,
                         "subpixel_px": rms * f_ir * profile.baseline / z**2, "bias_mm": 1e3 * (median - z),
                         "fill": fill, "f_ir_px": f_ir})
            print(f"z {z:.2f} m: plane-fit RMS {1e3 * rms:.2f} mm (robust sigma {1e3 * robust:.2f} mm), Intel model "
                  f"{1e3 * intel:.2f} mm "
                  f"(subpixel {rows[-1]['subpixel_px']:.3f} vs {INTEL_SUBPIXEL}), median bias "
                  f"{rows[-1]['bias_mm']:+.2f} mm, fill {100 * fill:.1f} %", flush=True)
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m syneepose.blender.flat_patch", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--distances", default="0.5,0.75,1.0,1.5,2.0", help="wall distances, metres")
    parser.add_argument("--resolution", default="320x240", help="RGB size WxH (the IR pair is the profile's scale)")
    parser.add_argument("--profile", default="d435")
    parser.add_argument("--sensor-render", choices=IR_RENDERS, help="the profile's IR rendering unless given")
    parser.add_argument("--roi", type=float, default=0.8, help="central fraction of the image fitted")
    parser.add_argument("--out", required=True, type=Path, help="JSON file of the rows")
    args = parser.parse_args(argv)

    def action() -> str:
        try:
            distances = [float(v) for v in args.distances.split(",")]
            width, height = (int(v) for v in args.resolution.lower().split("x"))
        except ValueError:
            raise UserError(f"--distances {args.distances!r} / --resolution {args.resolution!r}: give e.g. "
                            "0.5,1.0 and 320x240") from None
        if min(distances) <= 0 or not 0 < args.roi <= 1 or min(width, height) < 16 or max(width, height) > 4096:
            raise UserError("--distances must be > 0, --roi in (0, 1], --resolution 16..4096 px a side")
        rows = measure(distances, width, height, args.profile, args.roi, args.sensor_render)
        write_atomic(args.out, json.dumps(rows, indent=1).encode())
        return f"flat_patch: {len(rows)} distances; {args.out}"

    return run_command(action)


if __name__ == "__main__":
    sys.exit(main())
