"""BOP results CSV: exact round trip, BOP's duplicate rule, and errors that name the file and line."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from eval.bop_results import HEADER, BopResult, read_results, write_results
from kernel.errors import UserError
from kernel.transforms import make_T

ROW = "2,5,3,0.9,1 0 0 0 1 0 0 0 1,10 20 300,0.05"


def _result(seed: int, score: float = 0.5, key=(0, 1, 2)) -> BopResult:
    rng = np.random.default_rng(seed)
    T = make_T(Rotation.random(random_state=rng).as_matrix(), rng.uniform(-1, 1, 3))
    return BopResult(*key, score=score, T_cam_ee=T, time_s=0.067)


def _csv(tmp_path, *lines: str):
    path = tmp_path / "results.csv"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_round_trip(tmp_path):
    written = [_result(i, score=0.1 * i, key=(i, 10 + i, 1 + i % 6)) for i in range(4)]
    written[3].time_s = -1.0
    path = tmp_path / "r.csv"
    write_results(path, written)
    assert path.read_text().splitlines()[0] == HEADER
    got = read_results(path, obj_ids=range(1, 7), scene_ids=range(4))
    assert sorted(got) == [(0, 10, 1), (1, 11, 2), (2, 12, 3), (3, 13, 4)]
    for want in written:
        r = got[(want.scene_id, want.im_id, want.obj_id)]
        assert (r.score, r.time_s) == (want.score, want.time_s)
        assert np.abs(r.T_cam_ee - want.T_cam_ee).max() < 1e-15


def test_reads_the_bop_units(tmp_path):
    r = read_results(_csv(tmp_path, HEADER, ROW))[(2, 5, 3)]
    assert np.array_equal(r.T_cam_ee, make_T(np.eye(3), [0.01, 0.02, 0.3]))  # t in mm
    assert (r.score, r.time_s) == (0.9, 0.05)


def test_duplicates_keep_the_highest_score(tmp_path):
    low, high, other = _result(1, 0.2), _result(2, 0.8), _result(3, 0.5)
    for order in ([low, high, other], [other, high, low]):
        path = tmp_path / "dup.csv"
        write_results(path, order)
        got = read_results(path)
        assert len(got) == 1 and got[(0, 1, 2)].score == 0.8
        assert np.abs(got[(0, 1, 2)].T_cam_ee - high.T_cam_ee).max() < 1e-15


@pytest.mark.parametrize("lines, line, message", [
    (["scene_id,im_id,obj,score,R,t,time", ROW], 1, "expected the BOP header"),
    ([HEADER, ROW, "2,6,3,0.9,1 0 0 0 1 0 0 0 1,10 20 300"], 3, "6 columns, expected 7"),
    ([HEADER, ROW, "", "2,x,3,0.9,1 0 0 0 1 0 0 0 1,10 20 300,0.05"], 4, "not a number"),
    ([HEADER, "2,5,3,0.9,1 0 0 0 1 0 0 0,10 20 300,0.05"], 2, "R needs 9"),
    ([HEADER, "2,5,3,0.9,1 0 0 0 1 0 0 0 1,10 20 nan,0.05"], 2, "finite"),
    ([HEADER, "2,5,3,0.9,1 0 0 0 1 0 0 0 -1,10 20 300,0.05"], 2, "not a rotation"),  # a reflection
    ([HEADER, "2,5,3,0.9,1.01 0 0 0 1 0 0 0 1,10 20 300,0.05"], 2, "not a rotation"),
    ([HEADER, ROW.replace("2,5,3", "2,5,9")], 2, "obj_id 9 is not in the data set"),
    ([HEADER, ROW, ROW.replace("2,5,3", "4,5,3")], 3, "scene 4 is not in the data set"),
])
def test_bad_lines_name_file_and_line(tmp_path, lines, line, message):
    path = _csv(tmp_path, *lines)
    with pytest.raises(UserError, match=message) as info:
        read_results(path, obj_ids=range(1, 7), scene_ids=[0, 1, 2])
    assert str(info.value).startswith(f"{path}:{line}: ")


def test_six_printed_digits_pass_the_rotation_check(tmp_path):
    R = Rotation.random(random_state=5).as_matrix()
    row = f"0,0,1,1,{' '.join(f'{v:.6f}' for v in R.ravel())},0 0 500,-1"
    assert np.abs(read_results(_csv(tmp_path, HEADER, row))[(0, 0, 1)].T_cam_ee[:3, :3] - R).max() < 1e-6
