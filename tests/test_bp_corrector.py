"""BP corrector: learns a class-dependent bias, carries an uncertainty, guards, round-trips without pickle."""

import numpy as np
import pytest

from models.bp import N_INPUTS, BPConfig, BPCorrector, bp_inputs

CFG = BPConfig(hidden=8, n_members=3, epochs=150, patience=15, seed=4)


def _walk(rng, m=400):
    """Synthetic filter records: in class 'heavy' the filter sits 0.8 m west of truth (a NLOS-like bias);
    elsewhere it is unbiased. Inputs as :func:`bp_inputs` builds them."""
    t = np.cumsum(rng.uniform(0.1, 0.3, m))
    kind = rng.choice([0, 1, 2], size=m, p=[0.5, 0.3, 0.2])
    updated = kind > 0
    cls = (np.sin(t / 15.0) > 0.3).astype(int) * 2          # stretches of open (0) and heavy (2)
    proba = np.eye(3)[cls]
    K = np.zeros((m, 4, 2))
    K[updated, 0, 0] = K[updated, 1, 1] = 0.3
    nu = np.where(updated[:, None], rng.normal(0, 0.5, (m, 2)), np.nan)
    dx = np.where(updated[:, None], 0.3 * np.nan_to_num(nu), 0.0)
    nis = np.where(updated, rng.chisquare(2, m), np.nan)
    X = bp_inputs(t, kind, updated, updated, K, nu, dx, nis, proba)
    bias = np.where(cls[:, None] == 2, [0.8, 0.0], [0.0, 0.0])
    Y = bias + rng.normal(0, 0.1, (m, 2))
    return X, Y, cls


@pytest.fixture(scope="module")
def trained():
    rng = np.random.default_rng(0)
    walks = [_walk(rng) for _ in range(5)]
    bp = BPCorrector(CFG).fit([w[0] for w in walks], [w[1] for w in walks])
    return bp, rng


def test_inputs_hold_the_latest_update():
    t = np.array([0.0, 0.5, 1.0, 1.5])
    kind = np.array([0, 1, 0, 2])
    upd = kind > 0
    K = np.full((4, 4, 2), np.nan)
    K[1, :2] = [[0.1, 0.2], [0.3, 0.4]]
    K[3, :2] = [[0.5, 0.6], [0.7, 0.8]]
    nu = np.array([[np.nan] * 2, [1.0, 2.0], [np.nan] * 2, [3.0, 4.0]])
    X = bp_inputs(t, kind, upd, upd, K, nu, np.zeros((4, 2)), np.array([np.nan, 3.0, np.nan, 1.0]),
                  np.tile([1.0, 0, 0], (4, 1)))
    assert X.shape == (4, N_INPUTS)
    assert np.allclose(X[2, 3:7], [0.1, 0.2, 0.3, 0.4]) and np.allclose(X[2, 7:9], [1.0, 2.0])   # held
    assert X[2, 15] == pytest.approx(0.5)                                        # time since the update
    assert np.allclose(X[0, 3:9], 0) and X[3, 12] == 0 and X[3, 13] == 1         # source one-hot
    assert X[3, 16] == 1 and X[3, 17] == 1                                       # GNSS and acoustic recent


def test_learns_the_class_bias(trained):
    bp, rng = trained
    X, Y, cls = _walk(rng)
    mu, var = bp.predict(X)
    before = np.sqrt(np.mean(np.sum(Y ** 2, axis=1)))
    after = np.sqrt(np.mean(np.sum((Y - mu) ** 2, axis=1)))
    assert before > 0.5 and after < 0.25                 # 0.8 m bias in ~half the events, 0.14 m noise
    assert np.median(mu[cls == 2, 0]) == pytest.approx(0.8, abs=0.12)
    assert np.median(np.abs(mu[cls == 0, 0])) < 0.12
    assert np.median(np.sqrt(var[:, 0])) == pytest.approx(0.1, rel=0.6)   # the noise it was trained on


def test_ood_inputs_get_no_correction(trained):
    bp, rng = trained
    X, _, _ = _walk(rng)
    far = X.copy()
    far[:, 7:9] = 50.0                                    # innovations of 50 m: nothing like training
    assert bp.is_ood(X).mean() < 0.03 and bp.is_ood(far).all()
    prior = np.zeros((len(X), 2))
    c = bp.correct(far, prior, prior, np.tile(np.eye(2), (len(X), 1, 1)), np.zeros(len(X), bool))
    assert np.all(c.delta_m == 0) and c.disabled_share == 1.0


def test_innovation_guard_switches_off_a_harmful_correction(trained):
    bp, rng = trained
    X, Y, cls = _walk(rng)
    m = len(X)
    prior = np.zeros((m, 2))
    S = np.tile(np.eye(2) * 0.05, (m, 1, 1))
    updated = np.ones(m, bool)
    mu, _ = bp.predict(X)
    helpful = bp.correct(X, prior, mu + rng.normal(0, 0.05, (m, 2)), S, updated)     # fixes agree with it
    harmful = bp.correct(X, prior, -mu + rng.normal(0, 0.05, (m, 2)), S, updated)    # fixes contradict it
    heavy = cls == 2
    assert helpful.innovation_off[heavy].mean() < 0.1
    assert harmful.innovation_off[heavy].mean() > 0.8


def test_seeded_and_round_trip(trained):
    bp, rng = trained
    params, arrays = bp.get_state()
    again = BPCorrector.from_state(params, arrays)
    X, _, _ = _walk(rng, m=50)
    assert np.array_equal(bp.predict(X)[0], again.predict(X)[0])
    walks = [_walk(np.random.default_rng(9)) for _ in range(2)]
    small = BPConfig(hidden=4, n_members=1, epochs=5, seed=2)
    a = BPCorrector(small).fit([w[0] for w in walks], [w[1] for w in walks]).predict(X)[0]
    b = BPCorrector(small).fit([w[0] for w in walks], [w[1] for w in walks]).predict(X)[0]
    assert np.array_equal(a, b)
    with pytest.raises(ValueError, match="hidden"):
        BPConfig(hidden=0)
    with pytest.raises(ValueError, match="too few"):
        BPCorrector(small).fit([X[:5]], [np.zeros((5, 2))])


def _guard_loop(raw, withheld, prior, z, S, updated, window):
    """The innovation guard written as the plain loop of its definition: the oracle of the vectorised one."""
    off = np.zeros(len(raw), bool)
    n0s, n1s, prev, enabled = [], [], np.zeros(2), True
    for i in range(len(raw)):
        if updated[i] and np.all(np.isfinite(S[i])) and np.all(np.isfinite(z[i])):
            si = np.linalg.inv(S[i])
            v0 = z[i] - prior[i]
            v1 = v0 - prev
            n0s.append(float(v0 @ si @ v0))
            n1s.append(float(v1 @ si @ v1))
            n0s, n1s = n0s[-window:], n1s[-window:]
            enabled = np.mean(n1s) <= np.mean(n0s) if len(n0s) >= 3 else True
        off[i] = not enabled
        prev = np.zeros(2) if withheld[i] else raw[i]
    return off


def test_vectorised_innovation_guard_equals_its_loop():
    from models.bp import _innovation_off

    rng = np.random.default_rng(8)
    for _ in range(20):
        m = int(rng.integers(5, 300))
        raw = rng.normal(0, 0.5, (m, 2))
        withheld = rng.random(m) < 0.3
        prior = rng.normal(0, 1, (m, 2))
        z = prior + rng.normal(0, 0.5, (m, 2)) + (raw if rng.random() < 0.5 else -raw)
        z[rng.random(m) < 0.1] = np.nan
        S = np.tile(np.eye(2) * 0.3, (m, 1, 1)) * rng.uniform(0.5, 2, (m, 1, 1))
        updated = rng.random(m) < 0.6
        window = int(rng.integers(1, 15))
        assert np.array_equal(_innovation_off(raw, withheld, prior, z, S, updated, window),
                              _guard_loop(raw, withheld, prior, z, S, updated, window))


def test_innovation_guard_is_on_in_a_window_without_corrections():
    """Where no correction reached the last ``window`` fixes, corrected and uncorrected NIS are the same numbers:
    the guard must read that as a tie (on), after any history — the running-sum form once left rounding residue
    of ~1e-14 there and switched the correction off on a held-out walk."""
    from models.bp import _innovation_off

    rng = np.random.default_rng(3)
    m, window = 400, 10
    raw = rng.normal(0, 0.5, (m, 2))
    withheld = np.zeros(m, bool)
    withheld[300:] = True                                  # no correction applied from event 300 on
    prior = rng.normal(0, 1, (m, 2)) * 37.3
    z = prior + rng.normal(0, 0.5, (m, 2))
    S = np.tile(np.eye(2) * 0.3, (m, 1, 1)) * rng.uniform(0.5, 2, (m, 1, 1))
    updated = np.ones(m, bool)
    off = _innovation_off(raw, withheld, prior, z, S, updated, window)
    assert off[:300].any()                                 # the guard does act while corrections are applied
    assert not off[302 + window:].any()
    assert np.array_equal(off, _guard_loop(raw, withheld, prior, z, S, updated, window))

