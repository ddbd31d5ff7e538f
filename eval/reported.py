"""The paper's reported figures (feepe-paper.tex), as data: AUC in %, ADD / ADD-S, speed in ms per frame.

Table I's columns are the six SynEEPose end-effectors, the real RealSense-Franka set (the paper spells
it "RealSense-Feanka") and their average (the mean of the seven columns, e.g. FEEPE 77.46/81.50)."""

# Table I column keys: our end-effector names, then the two columns that are not one end-effector.
TABLE1_COLUMNS = ("panda_hand", "kinova_3f", "shadow_hand", "robotiq_3f", "robotiq_2f85", "robotiq_2f140",
                  "realsense_franka", "average")
COLUMN_TITLES = {"panda_hand": "Franka Panda", "kinova_3f": "Kinova-3F", "shadow_hand": "Shadow Hand",
                 "robotiq_3f": "Robotiq-3F", "robotiq_2f85": "Robotiq-2F85", "robotiq_2f140": "Robotiq-2F140",
                 "realsense_franka": "RealSense-Franka", "average": "Average"}


def _pairs(text: str) -> dict[str, tuple[float, float]]:
    """'59.21/68.10 20.02/26.85 ...' in TABLE1_COLUMNS order -> {column: (ADD, ADD-S)}."""
    values = [tuple(float(v) for v in cell.split("/")) for cell in text.split()]
    assert len(values) == len(TABLE1_COLUMNS)
    return dict(zip(TABLE1_COLUMNS, values))


# Table I: AUC@1cm ADD/ADD-S; MegaPose = MegaPose-RGBD, MegaPose† = MegaPose-RGB + multi-hypothesis + ICP.
TABLE1 = {
    "MegaPose": (_pairs("59.21/68.10 20.02/26.85 2.89/9.29 29.66/37.98 22.79/51.80 22.12/52.29 0.19/1.03 "
                        "22.41/35.33"), 1230),
    "MegaPose†": (_pairs("65.09/70.63 46.29/50.58 45.01/46.03 63.62/66.88 23.42/56.63 42.85/64.05 13.88/38.11 "
                         "42.88/56.13"), 2980),
    "SAM6D": (_pairs("78.22/80.90 80.41/81.91 71.77/74.34 79.97/86.26 38.79/77.27 39.35/75.84 27.48/47.68 "
                     "59.43/74.89"), 57),
    "FoundationPose": (_pairs("81.48/83.79 87.13/87.69 59.51/65.99 82.83/87.85 41.12/79.41 35.96/69.54 "
                              "19.94/47.17 58.28/74.49"), 1760),
    "FEEPE": (_pairs("85.24/86.29 85.24/86.36 84.53/85.23 88.73/91.67 84.33/86.11 84.87/86.15 29.27/48.71 "
                     "77.46/81.50"), 67),
}

# Ablation (average AUC@1cm ADD, ADD-S). A: PnP on DINOv2 2D-3D matches; B: + single-frame optimisation;
# C: + key-frame optimisation; D: + symmetry disambiguation (the full method).
ABLATION = {"A": (7.50, 19.49), "B": (54.28, 70.67), "C": (74.40, 79.04), "D": (77.46, 81.50)}

# DINOv2 layer -> (ADD, ADD-S), average AUC@1cm.
LAYERS = {11: (73.05, 77.84), 19: (77.46, 81.50), 23: (67.86, 73.60)}

# Hyperparameter -> value -> (ADD, ADD-S, speed ms); the chosen values are 960 templates, K_r 5, K_f 8.
HYPERPARAMETERS = {
    "n_templates": {240: (73.08, 77.82, 63), 480: (75.06, 79.53, 65), 960: (77.46, 81.50, 67),
                    1920: (77.66, 81.64, 71)},
    "k_r": {1: (64.21, 69.10, 55), 3: (75.40, 79.57, 61), 5: (77.46, 81.50, 67), 10: (77.98, 81.86, 81)},
    "k_f": {2: (73.75, 78.54, 54), 4: (76.26, 80.60, 59), 8: (77.46, 81.50, 67), 16: (77.72, 81.71, 86)},
}
HYPERPARAMETER_TITLES = {"n_templates": "Templates", "k_r": "Reference views", "k_f": "Keyframes"}

# Robot-pose comparison on RealSense-Franka, AUC@2cm: method -> (training-free, ADD, ADD-S).
ROBOT_POSE = {"RoboPose": (False, 0.68, 6.94), "CTRNet": (False, 5.46, 22.57), "RoboKeyGen": (False, 9.35, 29.99),
              "FEEPE": (True, 60.5, 75.22)}
