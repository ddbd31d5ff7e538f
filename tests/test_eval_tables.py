"""Tables and curves from two result folders written by the runner on the synthetic set: measured rows where
the runs have the options, reported rows always, in Markdown, LaTeX and CSV, and a PNG."""

import csv
import json
from dataclasses import dataclass

import numpy as np
import pytest
from matplotlib.image import imread

from eval import reported, run, tables
from eval.methods import option, register
from eval.methods.bop_csv import BopCsv, BopCsvFlags
from eval.metrics import auc
from eval.plots import convergence, frame_bins, mean_curve
from eval.records import FrameErrors, read_errors
from tests.test_eval_run import gt_csv, make_dataset


@dataclass(frozen=True)
class TunedFlags(BopCsvFlags):
    variant: str = option("D", "recorded as the run's variant")
    backbone: str = option("sift-normals", "recorded as the run's backbone")


@register("test-tuned")
class Tuned(BopCsv):
    """bop-csv with the options a FEEPE run records, so the ablation / layer / hyperparameter tables fill."""

    Options = TunedFlags

    def __init__(self, flags: TunedFlags):
        super().__init__(flags)
        self.variant, self.backbone = flags.variant, flags.backbone

    def options(self) -> dict:
        return {**super().options(), "variant": self.variant, "backbone": self.backbone, "layer": 19,
                "n_templates": 960, "k_r": 5, "k_f": 8}


@pytest.fixture(scope="module")
def result_dirs(tmp_path_factory, assets):
    root = tmp_path_factory.mktemp("tables")
    dataset = make_dataset(root / "data", assets)
    offset, exact = gt_csv(root / "offset.csv", dataset, offset_mm=(0.0, 0.0, 3.0)), gt_csv(root / "gt.csv", dataset)
    common = ["--dataset", str(dataset)]
    assert run.main(["--method", "bop-csv", "--out", str(root / "peer"), "--results", str(offset),
                     "--name", "Peer", *common]) == 0
    assert run.main(["--method", "test-tuned", "--out", str(root / "tuned"), "--results", str(exact),
                     "--name", "Tuned", "--variant", "D", *common]) == 0
    return root / "peer", root / "tuned"


def _rows(path) -> list[list[str]]:
    with open(path, newline="") as f:
        return list(csv.reader(f))


def test_all_tables_in_three_formats_with_measured_and_reported_rows(result_dirs, tmp_path):
    out = tmp_path / "tables"
    assert tables.main([str(d) for d in result_dirs] + ["--out", str(out)]) == 0
    stems = ["table1", "ablation", "layers", "hyperparameters", "robot_pose"]
    assert sorted(p.name for p in out.iterdir()) == sorted(
        [f"{s}{x}" for s in stems for x in (".md", ".tex", ".csv")] + ["accuracy_curves.png", "convergence.png",
                                                                    "tables.md"])

    table1 = {row[0]: row for row in _rows(out / "table1.csv")}
    assert table1["FEEPE (reported)"][1:] == ["85.24/86.29", "85.24/86.36", "84.53/85.23", "88.73/91.67",
                                              "84.33/86.11", "84.87/86.15", "29.27/48.71", "77.46/81.50", "67", "–"]
    assert table1["MegaPose† (reported)"][-2] == "2980"
    tuned, peer = table1["Tuned D (sift-normals, synthetic)"], table1["Peer (synthetic)"]
    kinova, gripper = reported.TABLE1_COLUMNS.index("kinova_3f") + 1, reported.TABLE1_COLUMNS.index("robotiq_2f85") + 1
    assert tuned[kinova] == tuned[gripper] == "100.00/100.00" and tuned[1] == "–"  # no Franka hand scene
    assert float(peer[kinova].split("/")[0]) == pytest.approx(70.0, abs=0.1)  # ADD = 3 mm
    assert tuned[-3:] == ["100.00/100.00", "50", "–"] and peer[7] == "–"  # one segment per end-effector: no spread

    ablation = _rows(out / "ablation.csv")
    assert ["A", "FEEPE (reported)", "7.50", "19.49"] in ablation
    assert ["D", "Tuned D (sift-normals, synthetic)", "100.00", "100.00"] in ablation
    assert not any("Peer" in row[1] for row in ablation)  # no variant option: not an ablation row
    assert ["19", "Tuned D (sift-normals, synthetic)", "100.00", "100.00"] in _rows(out / "layers.csv")
    hyper = _rows(out / "hyperparameters.csv")
    assert ["Reference views", "10", "FEEPE (reported)", "77.98", "81.86", "81"] in hyper
    assert ["Keyframes", "8", "Tuned D (sift-normals, synthetic)", "100.00", "100.00", "50"] in hyper
    robot = {row[0]: row for row in _rows(out / "robot_pose.csv")}
    assert robot["RoboKeyGen (reported)"][1:] == ["no", "9.35", "29.99", "RealSense-Franka"]
    assert float(robot["Peer (synthetic)"][2]) == pytest.approx(85.0, abs=0.1)  # 3 mm at 2 cm

    markdown, latex = (out / "table1.md").read_text(), (out / "table1.tex").read_text()
    assert "| Tuned D (sift-normals, synthetic) | – | 100.00/100.00 |" in markdown
    assert r"MegaPose\dag{} (reported) & " in latex and r"\begin{tabular}{lllllllllll}" in latex
    combined = (out / "tables.md").read_text()
    assert all(f"## {t}" in combined for t in ("Table I", "Ablation", "DINOv2 layer", "Hyperparameters",
                                               "Robot pose", "Accuracy curves", "Convergence along the segments"))
    assert "![accuracy curves](accuracy_curves.png)" in combined
    image = imread(out / "accuracy_curves.png")
    assert image.shape[0] > 100 and image.shape[1] > 100


def test_reported_only_without_result_folders(tmp_path):
    assert tables.main(["--out", str(tmp_path)]) == 0
    rows = _rows(tmp_path / "table1.csv")
    assert [row[0] for row in rows[1:]] == [f"{name} (reported)" for name in reported.TABLE1]
    assert not (tmp_path / "accuracy_curves.png").exists()


def test_missing_summary_is_a_user_error(tmp_path, capsys):
    assert tables.main([str(tmp_path / "nowhere"), "--out", str(tmp_path / "t")]) == 2
    assert capsys.readouterr().err.startswith(f"error: {tmp_path / 'nowhere' / 'summary.json'}: missing")


def test_reported_averages_are_the_mean_of_the_seven_columns():
    """Catches transcription slips: the paper's Average column is the mean of the other seven."""
    for name, (cells, _) in reported.TABLE1.items():
        for k in (0, 1):
            columns = [cells[c][k] for c in reported.TABLE1_COLUMNS[:-1]]
            assert np.mean(columns) == pytest.approx(cells["average"][k], abs=0.01), name


def test_curve_area_is_the_average_auc(result_dirs):
    peer = result_dirs[0]
    rows, summary = read_errors(peer / "errors.csv"), json.loads((peer / "summary.json").read_text())
    x, frac = mean_curve(rows, "add_m", 0.01)
    assert np.trapz(frac, x) / 0.01 * 100 == pytest.approx(summary["average"]["add@1cm"], abs=1e-9)
    assert summary["average"]["add@1cm"] == pytest.approx(np.mean([auc([r.add_m for r in rows
                                                                        if r.end_effector == ee], 0.01)
                                                                   for ee in ("kinova_3f", "robotiq_2f85")]))


def test_convergence_by_frame_index():
    """Two end-effectors over frames 0-7 in bins of 2: the error halves every bin; AUC is their mean."""
    rows = [FrameErrors(scene_id=s, im_id=i, obj_id=s, config="c", end_effector=f"ee{s}",
                        add_m=0.008 / 2 ** (i // 2), adds_m=0.0, rot_err_deg=0.0, trans_err_mm=0.0,
                        calib_trans_mm=40.0 / 2 ** (i // 2) if i else float("nan"), calib_rot_deg=0.0,
                        time_s=0.0, score=1.0, wall_s=0.0) for s in (0, 1) for i in range(8)]
    bins = frame_bins(np.array([r.im_id for r in rows]), n_bins=4)
    assert bins == [(0, 1), (2, 3), (4, 5), (6, 7)]
    add_auc, calib = convergence(rows, bins)
    assert np.allclose(add_auc, [20.0, 60.0, 80.0, 90.0], atol=0.1)  # 1 - error / 1 cm in %, on a 0.01 mm grid
    assert np.allclose(calib, [40.0, 20.0, 10.0, 5.0])


@dataclass(frozen=True)
class RefinedFlags(TunedFlags):
    silhouette: str = option("ee", "recorded as the refinement's outline")


@register("test-refined")
class Refined(Tuned):
    """A FEEPE-like run that records a refinement and its outline."""

    Options = RefinedFlags

    def __init__(self, flags: RefinedFlags):
        super().__init__(flags)
        self.silhouette = flags.silhouette

    def options(self) -> dict:
        return {**super().options(), "refine": "silhouette+depth", "silhouette": self.silhouette}


def test_refined_runs_are_labelled_with_their_outline(assets, tmp_path):
    dataset = make_dataset(tmp_path / "data", assets)
    exact = gt_csv(tmp_path / "gt.csv", dataset)
    folders = []
    for outline in ("ee", "robot"):
        folders.append(tmp_path / outline)
        assert run.main(["--method", "test-refined", "--out", str(folders[-1]), "--results", str(exact), "--name",
                         "Refined", "--silhouette", outline, "--dataset", str(dataset)]) == 0
    assert tables.main([str(d) for d in folders] + ["--out", str(tmp_path / "tables")]) == 0
    names = [row[0] for row in _rows(tmp_path / "tables" / "table1.csv")]
    assert "Refined D + silhouette+depth (ours) (sift-normals, synthetic)" in names
    assert "Refined D + silhouette+depth of the robot (ours) (sift-normals, synthetic)" in names
