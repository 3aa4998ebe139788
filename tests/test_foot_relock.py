"""The foot INS's UWB re-acquisition (models.foot.ins, ``uwb_relock_n``): a filter whose track is lost (every fix
outside its χ² gate) takes the fixes back after ``uwb_relock_n`` rejections in a row; with it off it stays lost."""

import numpy as np

from models.foot.ins import FootInsConfig, UwbFixes, run_foot_ins


def _still_foot(seconds=30.0, rate=100.0, seed=0):
    rng = np.random.default_rng(seed)
    n = int(seconds * rate)
    t = np.arange(n) / rate
    acc = np.tile([0.0, 0.0, 9.80665], (n, 1)) + rng.normal(0, 0.005, (n, 3))
    gyro = rng.normal(0, 1e-4, (n, 3))
    return t, acc, gyro


def _fixes(jump_m=5.0):
    # 10 Hz fixes of σ 0.1 m: at the origin for 10 s, then (a moved tag, or a lost INS) jump_m east for 20 s
    t = np.arange(0.05, 30.0, 0.1)
    en = np.zeros((len(t), 2))
    en[t >= 10.0, 0] = jump_m
    return UwbFixes(t, en, np.tile(np.eye(2) * 0.01, (len(t), 1, 1)))


def test_relock_takes_the_fixes_back():
    t, acc, gyro = _still_foot()
    run = run_foot_ins(t, acc, gyro, None, FootInsConfig(uwb_relock_n=10), uwb=_fixes())
    # the first ten fixes after the jump are rejected, then the filter re-acquires and follows them
    after = run.uwb_accepted[_fixes().t_s >= 10.0]
    assert not after[:9].any()
    assert after[-100:].all()
    assert abs(run.pos_m[-1, 0] - 5.0) < 0.1 and abs(run.pos_m[-1, 1]) < 0.1


def test_without_relock_the_gate_locks_the_filter_out():
    t, acc, gyro = _still_foot()
    run = run_foot_ins(t, acc, gyro, None, FootInsConfig(uwb_relock_n=0), uwb=_fixes())
    assert not run.uwb_accepted[_fixes().t_s >= 10.0].any()
    assert np.hypot(*run.pos_m[-1, :2]) < 0.1
