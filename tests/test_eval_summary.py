"""The spread of the Average over redrawn segments, on cases whose percentiles are known by counting."""

import math

import pytest

from eval.records import FrameErrors
from eval.summary import segment_spread, summarise


def _frame(ee: str, scene_id: int, error_m: float) -> FrameErrors:
    return FrameErrors(scene_id=scene_id, im_id=0, obj_id=1, config=f"arm+{ee}", end_effector=ee, add_m=error_m,
                       adds_m=error_m, rot_err_deg=0.0, trans_err_mm=0.0, calib_trans_mm=math.nan,
                       calib_rot_deg=math.nan, time_s=-1.0, score=1.0, wall_s=0.0)


def test_a_perfect_and_a_failed_segment_beside_a_perfect_end_effector():
    # "a": segments AUC 100 and 0, so a redraw averages 100, 50 or 0 with odds 1/4, 1/2, 1/4; "b" is always 100:
    # the Average is 100, 75 or 50, and its 5th and 95th percentiles are 50 and 100
    rows = [_frame("a", 0, 0.0), _frame("a", 1, math.inf), _frame("b", 2, 0.0), _frame("b", 3, 0.0)]
    spread = segment_spread(rows)
    assert spread["add@1cm"] == spread["adds@1cm"] == [50.0, 100.0]
    assert spread["segments"] == 4 and summarise(rows)["average"]["add@1cm"] == 75.0


def test_segments_alike_give_no_spread_and_frames_weigh_by_count():
    rows = [_frame("a", s, e) for s in (0, 1) for e in (0.0, 0.005)]  # each segment: a frame at 0 and one at 5 mm
    both = summarise(rows)["average"]["add@1cm"]
    assert both == pytest.approx(75.0, abs=0.1) and segment_spread(rows)["add@1cm"] == pytest.approx([both, both])
    unequal = [_frame("a", 0, 0.0), _frame("a", 1, 0.0), _frame("a", 1, 0.0), _frame("a", 1, math.inf)]
    lo, hi = segment_spread(unequal)["add@1cm"]  # segment 1 has three frames: a draw of it twice gives 66.7
    assert lo == pytest.approx(200 / 3) and hi == 100.0


def test_one_segment_per_end_effector_has_no_spread():
    assert segment_spread([_frame("a", 0, 0.0), _frame("b", 1, 0.0)]) is None
