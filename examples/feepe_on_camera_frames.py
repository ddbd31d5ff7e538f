"""FEEPE on a folder of RGB-D frames from a camera, with only `kernel` and `feepe` installed (no Blender).

Usage: python examples/feepe_on_camera_frames.py FRAMES TEMPLATE_SET
FRAMES holds, per frame N: N.json ({"K": 3x3, "T_base_ee": 4x4 from the robot's FK in metres, "depth_scale":
mm per depth unit}), N_rgb.png, N_depth.png (uint16) and N_mask.png (the end-effector, e.g. from SAM).
TEMPLATE_SET is one end-effector's template folder (`python -m syneepose templates`, rendered once anywhere).
"""
import json, sys
from pathlib import Path

import cv2
import numpy as np

from feepe import Estimator

frames, templates = Path(sys.argv[1]), Path(sys.argv[2])
estimator = Estimator.from_templates(templates)  # variant D on the weight-free default backbone
for record in sorted(frames.glob("*.json")):
    frame = json.loads(record.read_text())
    image = lambda kind: cv2.imread(str(frames / f"{record.stem}_{kind}.png"), cv2.IMREAD_UNCHANGED)
    result = estimator.step(image("rgb")[..., ::-1], image("depth") * frame["depth_scale"] / 1000.0,
                            image("mask") > 127, np.array(frame["K"]), np.array(frame["T_base_ee"]))
    print(record.stem, json.dumps(None if result.T_cam_base is None else result.T_cam_base.tolist()))
