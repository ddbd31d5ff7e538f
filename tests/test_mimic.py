"""The mimic tables (data) against the couplings written in the source MJCF."""

import mujoco
import numpy as np
import pytest

from syneepose.robots.sources import ensure_source
from tests.mujoco_reference import reference_model

COUPLED = ["robotiq_2f140", "kinova_3f", "robotiq_3f"]  # the grippers whose MJCF has equality couplings


def _equalities(m):
    """Each equality as {joint: coefficient} such that sum coef * dq = 0 along the coupling."""
    out = []
    for e in range(m.neq):
        if m.eq_type[e] == mujoco.mjtEq.mjEQ_TENDON and m.eq_obj2id[e] < 0:
            t = m.eq_obj1id[e]
            adr, num = m.tendon_adr[t], m.tendon_num[t]
            coefs = {}
            for w in range(adr, adr + num):
                name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, m.wrap_objid[w])
                coefs[name] = coefs.get(name, 0.0) + m.wrap_prm[w]
            out.append(coefs)
        elif m.eq_type[e] == mujoco.mjtEq.mjEQ_JOINT:  # q1 = poly(q2); linear term only here
            j1 = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, m.eq_obj1id[e])
            j2 = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, m.eq_obj2id[e])
            out.append({j1: 1.0, j2: -m.eq_data[e][1]})
    return out


@pytest.mark.parametrize("name", COUPLED)
def test_mimic_slopes_satisfy_source_equalities(catalog, name):
    ee = catalog.end_effector(name)
    m = reference_model(ee, ensure_source(catalog.sources[ee.source]))
    mimic = dict(ee.mimic)
    equalities = _equalities(m)
    assert equalities
    for coefs in equalities:
        # d/d(master) of sum coef * q, with followers moving by their multiplier and masters by 1.
        masters = {mimic[j].joint if j in mimic else j for j in coefs}
        for master in masters:
            slope = sum(c * (mimic[j].multiplier if j in mimic and mimic[j].joint == master else float(j == master))
                        for j, c in coefs.items())
            assert abs(slope) < 1e-9, (name, coefs, master)


def test_every_follower_has_an_actuated_master(catalog):
    for ee in catalog.end_effectors.values():
        mimic = dict(ee.mimic)
        for follower, m in mimic.items():
            assert m.joint not in mimic, (ee.name, follower)
            assert np.isfinite([m.multiplier, m.offset]).all()
