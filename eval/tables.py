"""`python -m eval.tables RESULT_DIR... --out DIR`: the paper's tables from result folders, beside the
paper's reported rows, as Markdown, LaTeX and CSV, plus the accuracy curves and a combined tables.md.

A measured row is labelled with its method, backbone and data set, e.g. "FEEPE (sift-normals, mini)";
a reported row with "(reported)". A table holds the measured rows that exist: the ablation table the runs
whose options name a variant, the layer table those with a `layer` option, the hyperparameter table
those with `n_templates`, `k_r` or `k_f`.
"""

from __future__ import annotations

import argparse
import csv
import io
import sys
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path

from eval import reported
from eval.plots import accuracy_curves, convergence_plot, read_trials, targeting_plot
from eval.records import read_errors
from kernel.bop import DEPTH_DIR
from kernel.cli import output_dir, run_command
from kernel.errors import UserError
from kernel.files import read_json, write_atomic

NONE = "–"
_LATEX = {"\\": r"\textbackslash{}", "&": r"\&", "%": r"\%", "#": r"\#", "_": r"\_", "$": r"\$", "{": r"\{",
          "}": r"\}", "~": r"\textasciitilde{}", "^": r"\textasciicircum{}", "†": r"\dag{}", "–": "--"}


@dataclass
class Run:
    path: Path
    summary: dict
    label: str = ""

    @property
    def options(self) -> dict:
        return self.summary.get("options", {})


@dataclass
class Table:
    key: str  # file stem
    title: str
    header: list[str]
    rows: list[list[str]]
    notes: list[str] = field(default_factory=list)


def method_label(name: str, options: dict) -> str:
    """A method's name with its variant and our extensions, e.g. "FEEPE D + silhouette of the robot (ours)"."""
    if options.get("variant"):
        name += f" {options['variant']}" + (" + depth ICP (ours)" if options.get("icp") else "")
        if options.get("refine", "none") != "none":
            outline = " of the robot" if options.get("silhouette", "ee") != "ee" else ""
            name += f" + {options['refine']}{outline} (ours)"
    return name


SUMMARY_KEYS = ("method", "dataset", "average", "per_end_effector", "ms_per_frame")
AVERAGE_KEYS = ("add@1cm", "adds@1cm", "add@2cm", "adds@2cm")


def _summary(path: Path) -> dict:
    """A run's summary.json with what the tables read; a broken or foreign one is named in one line."""
    s = read_json(path, "run python -m eval.run into that folder again")
    missing = [k for k in SUMMARY_KEYS if k not in s]
    if not missing:
        missing = [f"average.{k}" for k in AVERAGE_KEYS if not isinstance(s["average"], dict) or k not in s["average"]]
    if missing:
        raise UserError(f"{path}: not an eval.run summary (no {', '.join(missing)}); run python -m eval.run "
                        "into that folder again")
    return s


def load_runs(folders: list[Path]) -> list[Run]:
    runs = []
    for folder in folders:
        path = Path(folder) / "summary.json"
        if not path.is_file():
            raise UserError(f"{path}: missing; give folders written by python -m eval.run --out")
        runs.append(Run(Path(folder), _summary(path)))
    for run in runs:
        s = run.summary
        method = method_label(run.options.get("name") or s["method"].upper(), run.options)
        for key, paper, title in (("k_r", 5, "K_r"), ("k_f", 8, "K_f")):
            if run.options.get(key) not in (None, paper):
                method += f" {title}={run.options[key]}"
        data = s["dataset"]
        details = [v for v in (s.get("backbone"), data.get("preset") or Path(data["path"]).name) if v]
        details += [f"{data['depth_dir']}/"] if data.get("depth_dir", DEPTH_DIR) != DEPTH_DIR else []
        details += ["perturbed masks"] if data.get("mask_noise") else []
        run.label = f"{method} ({', '.join(details)})"
    repeated = Counter(run.label for run in runs)
    for run in runs:
        if repeated[run.label] > 1:
            run.label += f" [{run.path.name}]"
    return runs


def _num(value, digits: int = 2) -> str:
    return NONE if value is None else f"{value:.{digits}f}"


def _slash(add: float, adds: float) -> str:
    return f"{add:.2f}/{adds:.2f}"


def _spread(spread: dict | None) -> str:
    if spread is None:
        return NONE
    (add_lo, add_hi), (adds_lo, adds_hi) = spread["add@1cm"], spread["adds@1cm"]
    return f"{add_lo:.1f}-{add_hi:.1f} / {adds_lo:.1f}-{adds_hi:.1f}"


def _pair(acc: dict | None) -> str:
    return NONE if acc is None else _slash(acc["add@1cm"], acc["adds@1cm"])


PAPER_CHOICES = {"n_templates": 960, "k_r": 5, "k_f": 8}


def _is_sweep(run: Run) -> bool:
    """A run that varies K_r or K_f away from the paper's choice (a template count is a data choice)."""
    return any(run.options.get(k) not in (None, PAPER_CHOICES[k]) for k in ("k_r", "k_f"))


def _main_runs(runs: list[Run]) -> list[Run]:
    """Table I and the robot-pose table: full-method runs at the paper's settings (not ablations, sweeps)."""
    return [run for run in runs if run.options.get("variant") in (None, "D") and not _is_sweep(run)]


def table1(runs: list[Run]) -> Table:
    header = ["Method", *(reported.COLUMN_TITLES[c] for c in reported.TABLE1_COLUMNS), "Speed (ms)",
              "Average over redrawn segments (5-95%)"]
    rows = [[f"{name} (reported)", *(_slash(*cells[c]) for c in reported.TABLE1_COLUMNS), str(speed), NONE]
            for name, (cells, speed) in reported.TABLE1.items()]
    for run in _main_runs(runs):
        per_ee = run.summary["per_end_effector"]
        cells = [_pair(per_ee.get(c)) for c in reported.TABLE1_COLUMNS[:-2]]
        rows.append([run.label, *cells, NONE, _pair(run.summary["average"]), _num(run.summary["ms_per_frame"], 0),
                     _spread(run.summary.get("average_spread"))])
    return Table("table1", "Table I: AUC@1cm of ADD/ADD-S per end-effector", header, rows, [
        "Reported Average: mean of the seven columns (RealSense-Franka included); measured Average: mean over "
        "the end-effectors the run measured (RealSense-Franka is a real data set this project does not have).",
        "MegaPose = MegaPose-RGBD; MegaPose† = MegaPose-RGB + multi-hypothesis + ICP. Speed: the method's own "
        "time per frame, without segmentation.",
        "Average over redrawn segments: the 5th-95th percentile of the measured Average (ADD / ADD-S) when each "
        "end-effector's segments are drawn again with replacement (1000 draws): the spread to expect from other "
        "segments of the same kind; a difference inside it is not a result."])


def _option_rows(runs: list[Run], option: str) -> list[tuple[object, Run]]:
    def order(pair):
        value = pair[0]
        return (0, value, "") if isinstance(value, (int, float)) else (1, 0, str(value)), pair[1].label

    return sorted(((run.options[option], run) for run in runs if run.options.get(option) is not None), key=order)


def ablation(runs: list[Run]) -> Table:
    rows = [[variant, "FEEPE (reported)", f"{add:.2f}", f"{adds:.2f}"]
            for variant, (add, adds) in reported.ABLATION.items()]
    rows += [[str(variant), run.label, _num(run.summary["average"]["add@1cm"]),
              _num(run.summary["average"]["adds@1cm"])]
             for variant, run in _option_rows([r for r in runs if not _is_sweep(r)], "variant")]
    return Table("ablation", "Ablation: average AUC@1cm", ["Variant", "Method", "ADD", "ADD-S"], rows, [
        "A: PnP on 2D-3D matches; B: + single-frame optimisation; C: + key-frame optimisation; "
        "D: + symmetry disambiguation (the full method)."])


def layers(runs: list[Run]) -> Table:
    rows = [[str(layer), "FEEPE (reported)", f"{add:.2f}", f"{adds:.2f}"]
            for layer, (add, adds) in reported.LAYERS.items()]
    rows += [[str(layer), run.label, _num(run.summary["average"]["add@1cm"]),
              _num(run.summary["average"]["adds@1cm"])] for layer, run in _option_rows(runs, "layer")]
    return Table("layers", "DINOv2 layer: average AUC@1cm", ["Layer", "Method", "ADD", "ADD-S"], rows)


def hyperparameters(runs: list[Run]) -> Table:
    rows = []
    for option, title in reported.HYPERPARAMETER_TITLES.items():
        rows += [[title, str(value), "FEEPE (reported)", f"{add:.2f}", f"{adds:.2f}", str(speed)]
                 for value, (add, adds, speed) in reported.HYPERPARAMETERS[option].items()]
        others = {k: v for k, v in PAPER_CHOICES.items() if k != option}
        full = [r for r in runs if r.options.get("variant") in (None, "D") and not r.options.get("icp")
                and r.options.get("refine") in (None, "none")
                and all(r.options.get(k) in (None, v) for k, v in others.items())]
        rows += [[title, str(value), run.label, _num(run.summary["average"]["add@1cm"]),
                  _num(run.summary["average"]["adds@1cm"]), _num(run.summary["ms_per_frame"], 0)]
                 for value, run in _option_rows(full, option)]
    return Table("hyperparameters", "Hyperparameters: average AUC@1cm and speed",
                 ["Hyperparameter", "Value", "Method", "ADD", "ADD-S", "Speed (ms)"], rows,
                 ["Reported choices: 960 templates, 5 reference views, 8 keyframes."])


def robot_pose(runs: list[Run]) -> Table:
    rows = [[f"{name} (reported)", "yes" if free else "no", f"{add:.2f}", f"{adds:.2f}", "RealSense-Franka"]
            for name, (free, add, adds) in reported.ROBOT_POSE.items()]
    rows += [[run.label, NONE, _num(run.summary["average"]["add@2cm"]), _num(run.summary["average"]["adds@2cm"]),
              run.summary["dataset"].get("preset") or NONE] for run in _main_runs(runs)]
    return Table("robot_pose", "Robot pose: AUC@2cm of ADD and ADD-S",
                 ["Method", "Training-free", "ADD@2cm", "ADD-S@2cm", "Data set"], rows,
                 ["Reported rows are on the real RealSense-Franka set; measured rows average the end-effectors "
                  "of their data set."])


def to_markdown(table: Table) -> str:
    lines = ["| " + " | ".join(table.header) + " |", "|" + "---|" * len(table.header)]
    lines += ["| " + " | ".join(row) + " |" for row in table.rows]
    return "\n".join(lines) + "\n"


def _latex(text: str) -> str:
    return "".join(_LATEX.get(char, char) for char in text)


def to_latex(table: Table) -> str:
    lines = [f"% {table.title}", r"\begin{tabular}{" + "l" * len(table.header) + "}", r"\toprule",
             " & ".join(_latex(h) for h in table.header) + r" \\", r"\midrule"]
    lines += [" & ".join(_latex(cell) for cell in row) + r" \\" for row in table.rows]
    lines += [r"\bottomrule", r"\end{tabular}"]
    return "\n".join(lines) + "\n"


def to_csv(table: Table) -> str:
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(table.header)
    writer.writerows(table.rows)
    return out.getvalue()


def _aim_cell(stats: dict) -> str:
    cell = f"{stats['points_mm_median']:.2f} / {stats['rot_deg_median']:.3f}"
    if stats["failures"]:
        cell += f" ({stats['failures']} of {stats['trials']} failed)"
    return cell


def targeting(summaries: list[dict]) -> Table:
    """Camera-to-base error against the number of views: mean distance at the 5 workspace points (mm) and
    rotation (deg), medians over scenes x draws, from `python -m eval.targeting` folders."""
    views = sorted({int(v) for s in summaries for per in s["by_method"].values() for v in per})
    rows, seen = [], set()
    for s in summaries:
        for method, per in s["by_method"].items():
            if method in seen:  # every targeting run repeats the marker baseline on the same draws
                continue
            seen.add(method)
            cells = [_aim_cell(per[str(v)]) if str(v) in per else NONE for v in views]
            rows.append([method, *cells])
    return Table("targeting", "Targeting: camera-to-base error vs views (mm at 5 workspace points / deg)",
                 ["Method", *(f"{v} views" for v in views)], rows,
                 ["Medians over scenes x random draws of the views, a failed trial (marker: fewer than 3 views "
                  "with the board found) counting as infinite; the plot shows the trials that gave a calibration. "
                  "The paper's real-robot figure reports FEEPE "
                  "within 3 mm from 3 views and 1 mm from 15, ahead of marker hand-eye at every count."])


def write_tables(folders: list[Path], out: Path) -> list[Path]:
    """Every table in three formats, the curves (when there are runs) and tables.md; returns the files.
    Folders holding `targeting.json` (python -m eval.targeting) add the targeting table and plot."""
    aimed = [Path(f) for f in folders if (Path(f) / "targeting.json").is_file()]
    runs = load_runs([f for f in folders if Path(f) not in aimed])
    out = output_dir(out)
    tables = [table1(runs), ablation(runs), layers(runs), hyperparameters(runs), robot_pose(runs)]
    aims = [read_json(f / "targeting.json", "run python -m eval.targeting into that folder again") for f in aimed]
    if aims:
        tables.append(targeting(aims))
    written, sections = [], ["# Tables\n", "Measured rows: `python -m eval.run`; rows marked (reported) are the "
                             "paper's figures.\n"]
    for table in tables:
        for suffix, render in ((".md", to_markdown), (".tex", to_latex), (".csv", to_csv)):
            written.append(out / f"{table.key}{suffix}")
            write_atomic(written[-1], render(table).encode())
        sections += [f"## {table.title}\n", to_markdown(table), *(f"{note}\n" for note in table.notes)]
    if runs:
        written.append(out / "accuracy_curves.png")
        accuracy_curves([(run.label, read_errors(run.path / "errors.csv")) for run in runs], written[-1])
        sections += ["## Accuracy curves\n", "Fraction of frames with error <= x, averaged over end-effectors "
                     "(its area is the Average AUC).\n", f"![accuracy curves]({written[-1].name})\n"]
        written.append(out / "convergence.png")
        convergence_plot([(run.label, read_errors(run.path / "errors.csv")) for run in runs], written[-1])
        sections += ["## Convergence along the segments\n", "AUC@1cm of ADD (mean over end-effectors) and the "
                     "median camera-to-base error of the frames in each frame-index range: how many frames an "
                     "online method needs.\n", f"![convergence]({written[-1].name})\n"]
    if aims:
        written.append(out / "targeting.png")
        targeting_plot([read_trials(f / "targeting.csv") for f in aimed], written[-1])
        sections += ["## Targeting plot\n", f"![targeting]({written[-1].name})\n"]
    written.append(out / "tables.md")
    write_atomic(written[-1], "\n".join(sections).encode())
    return written


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m eval.tables", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("results", nargs="*", type=Path, help="result folders of python -m eval.run")
    parser.add_argument("--out", required=True, type=Path, help="folder for the tables and curves")
    args = parser.parse_args(argv)

    def action() -> str:
        written = write_tables(args.results, args.out)
        return f"tables: {len(written)} files in {args.out} (see {args.out / 'tables.md'})"

    return run_command(action)

if __name__ == "__main__":
    sys.exit(main())
