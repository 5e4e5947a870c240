"""BOCA's fidelity rule (rbbo.boca) on a synthetic two-fidelity problem."""

import numpy as np
import pytest

from rbbo import grassmann as gr
from rbbo.acquisition import perturb
from rbbo.boca import BOCAFidelity
from rbbo.gp import GrassmannGP

M, C = 8, 2
T_MIN, T_MAX = 4.0, 10.0


def two_fidelity(bases, z, u, v):
    """Target ||B^T U||^2 / C at z = 1; at z = 0 biased by a smooth term in ||B^T V||^2."""
    hit = np.sum((bases.transpose(0, 2, 1) @ u) ** 2, axis=(1, 2)) / C
    bias = np.sum((bases.transpose(0, 2, 1) @ v) ** 2, axis=(1, 2)) / C
    return hit - 0.3 * (1.0 - z) * (1.0 + bias)


@pytest.fixture(scope="module")
def problem():
    rng = np.random.default_rng(3)
    u, v = gr.random_points(M, C, 2, rng)
    return u, v, rng


def _boca():
    # two fidelities only (T_min, T_max) and a fixed kappa: the rule itself, no adaptation
    return BOCAFidelity(T_MIN, T_MAX, n_candidates=2, kappa=0.5, window=10**6)


def _check_tau_and_gamma(boca, gp, basis, choice):
    """tau and gamma of a choice as rbbo.boca's docstring defines them: tau(z) the latent
    posterior sd at (B_c, z) in units of the observed R's sd, gamma(z) = kappa xi(z)
    (T / T_max)^q with xi = sqrt(1 - k_T(z, 1)^2), k_T = exp(-(z - 1)^2 / (2 h^2)), q = 1/2."""
    t = np.asarray(choice.candidates)
    np.testing.assert_array_equal(t, boca.candidates)
    z = (t - T_MIN) / (T_MAX - T_MIN)
    _, sd = gp.predict(np.repeat(basis[None], len(t), axis=0), z)
    np.testing.assert_allclose(choice.tau, sd / gp.y_std_, rtol=1e-12)
    h = gp.hyperparameters.fidelity_length_scale
    xi = np.sqrt(1.0 - np.exp(-((z - 1.0) ** 2) / h**2))
    np.testing.assert_allclose(choice.gamma, boca.kappa * xi * np.sqrt(t / T_MAX), rtol=1e-12)
    # T is the cheapest candidate whose tau exceeds its gamma, T_max if none does
    above = [c for c, a, b in zip(t, choice.tau, choice.gamma, strict=True) if a > b]
    assert choice.T == (above[0] if above else T_MAX)


def test_low_fidelity_first_when_the_gp_knows_little(problem):
    u, v, rng = problem
    boca = _boca()
    bases = gr.random_points(M, C, 4, rng)
    z = np.array([0.0, 0.0, 1.0, 1.0])
    gp = GrassmannGP(M, C, fidelity=True, random_state=0).fit(
        bases, two_fidelity(bases, z, u, v), z
    )
    basis = gr.random_points(M, C, rng=rng)
    choice = boca.choose(gp, basis)
    assert choice.T == T_MIN
    assert choice.tau[0] > choice.gamma[0]
    _check_tau_and_gamma(boca, gp, basis, choice)
    wider = BOCAFidelity(T_MIN, T_MAX, n_candidates=4, kappa=0.5)  # T in (4, 6, 8)
    _check_tau_and_gamma(wider, gp, basis, wider.choose(gp, basis))


def test_full_fidelity_once_low_fidelity_has_been_seen_near_the_candidate(problem):
    u, v, rng = problem
    boca = _boca()
    near = np.stack([perturb(u, s, rng) for s in rng.uniform(0.05, 0.4, 25)])
    far = gr.random_points(M, C, 10, rng)
    bases = np.concatenate([near, far])
    z = np.concatenate([np.zeros(25), np.ones(10)])
    gp = GrassmannGP(M, C, fidelity=True, random_state=0).fit(
        bases, two_fidelity(bases, z, u, v), z
    )
    choice = boca.choose(gp, u)
    assert choice.T == T_MAX
    assert choice.tau[0] <= choice.gamma[0]
    _check_tau_and_gamma(boca, gp, u, choice)
    # elsewhere the same GP is still unsure at low fidelity: a cheap look is worth it
    assert boca.choose(gp, gr.random_points(M, C, rng=rng)).T == T_MIN


def test_candidates_respect_the_cost_cap():
    boca = BOCAFidelity(2.0, 10.0, n_candidates=5, max_cost_ratio=0.9)
    np.testing.assert_allclose(boca.candidates, [2.0, 4.0, 6.0, 8.0])
    assert boca.z(10.0) == 1.0 and boca.z(2.0) == 0.0
    # T_max is the target, never a candidate, whatever the cap
    uncapped = BOCAFidelity(2.0, 10.0, n_candidates=5, max_cost_ratio=1.5)
    np.testing.assert_allclose(uncapped.candidates, [2.0, 4.0, 6.0, 8.0])


def test_kappa_adapts_to_the_share_of_full_fidelity_choices():
    boca = BOCAFidelity(T_MIN, T_MAX, window=4, kappa=1.0)
    kappas = []
    for t in [T_MAX] * 4 + [T_MIN] * 4:
        boca.record(t)
        kappas.append(boca.kappa)
    # windows: 3 short, 4/4 and 3/4 at T_max (too many: lower), 2/4 and 1/4 (in range),
    # 0/4 (too few: raise)
    expected = [1, 1, 1, 1 / 1.1, 1 / 1.1**2, 1 / 1.1**2, 1 / 1.1**2, 1 / 1.1]
    np.testing.assert_allclose(kappas, expected)


def test_the_floor_keeps_a_quarter_of_the_choices_at_full_length(problem):
    # tau stays above gamma far from the data (the rule alone picks T_min), but once fewer
    # than target_fraction[0] of the recent choices were at T_max, T_max it is
    u, v, rng = problem
    bases = gr.random_points(M, C, 4, rng)
    z = np.array([0.0, 0.0, 1.0, 1.0])
    gp = GrassmannGP(M, C, fidelity=True, random_state=0).fit(
        bases, two_fidelity(bases, z, u, v), z
    )
    candidate = gr.random_points(M, C, rng=rng)
    boca = BOCAFidelity(T_MIN, T_MAX, n_candidates=2, kappa=0.5)
    for t in (T_MAX, T_MIN, T_MIN):  # fewer than floor_after = 4 recorded: no floor yet
        boca.record(t)
    assert boca.choose(gp, candidate).T == T_MIN
    boca.record(T_MIN)  # 1 of 4 at T_max: at the target's lower end, not below it
    assert boca.choose(gp, candidate).T == T_MIN
    boca.record(T_MIN)  # 1 of 5
    choice = boca.choose(gp, candidate)
    assert choice.T == T_MAX and choice.floor and choice.tau[0] > choice.gamma[0]
    # a T_max proposal still in flight counts: another worker is not sent to T_max as well
    assert boca.choose(gp, candidate, pending=[T_MAX]).T == T_MIN
    with pytest.raises(ValueError, match="floor_after must be an integer >= 1, got 0"):
        BOCAFidelity(T_MIN, T_MAX, floor_after=0)


def test_bad_fidelity_ranges():
    with pytest.raises(ValueError, match="T_max = 3.0 must exceed T_min = 4.0"):
        BOCAFidelity(4.0, 3.0)
    with pytest.raises(ValueError, match="T_min must be a positive finite number, got 0"):
        BOCAFidelity(0, 3.0)
    with pytest.raises(ValueError, match="n_candidates must be an integer >= 2, got 1"):
        BOCAFidelity(1.0, 3.0, n_candidates=1)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"t_max": np.inf}, "t_max must be finite, got inf"),  # (not "T_min must be ...")
        ({"t_min": "1"}, "t_min must be a number, got '1'"),
        ({"n_candidates": 2.5}, "n_candidates must be an integer >= 2, got 2.5"),
        ({"window": 0}, "window must be an integer >= 1, got 0"),
        ({"kappa": np.inf}, "kappa must be finite, got inf"),
        ({"kappa_step": 0.0}, "kappa_step must be >= 1, got 0.0"),
        ({"kappa_step": 0.5}, "kappa_step must be >= 1, got 0.5"),
        ({"cost_exponent": np.nan}, "cost_exponent must be finite, got nan"),
        ({"cost_exponent": -1}, "cost_exponent must be >= 0, got -1"),
        ({"max_cost_ratio": np.nan}, "max_cost_ratio must be finite, got nan"),
        ({"max_cost_ratio": 0}, "max_cost_ratio must be > 0, got 0"),
        ({"target_fraction": (0.5,)}, r"target_fraction must be a \(low, high\) pair"),
        ({"window": 3}, "floor_after = 4 exceeds window = 3: the floor could never apply"),
        ({"kappa": 0.0}, "kappa must be > 0, got 0.0"),
        ({"target_fraction": (0.8, 0.2)}, r"0 <= lo <= hi <= 1, got \(0.8, 0.2\)"),
        ({"target_fraction": (-0.1, 0.5)}, r"0 <= lo <= hi <= 1, got \(-0.1, 0.5\)"),
        ({"target_fraction": (0.5, 1.5)}, r"0 <= lo <= hi <= 1, got \(0.5, 1.5\)"),
    ],
)
def test_bad_settings_are_named_when_made(kwargs, match):
    # each was accepted and later failed elsewhere (n_candidates in linspace, window = 0 in
    # a mean of nothing), or silently chose T_max always (NaN thresholds), or ran the kappa
    # adaptation backwards (kappa_step < 1)
    with pytest.raises(ValueError, match=match):
        BOCAFidelity(**{"t_min": 1.0, "t_max": 3.0, **kwargs})


def test_target_fraction_takes_its_bounds():
    """0 <= lo <= hi <= 1 is inclusive: one fraction (lo = hi) and the whole range are valid."""
    for pair in ((0.3, 0.3), (0.0, 1.0)):
        assert BOCAFidelity(t_min=1.0, t_max=3.0, target_fraction=pair).target_fraction == pair


def test_boca_needs_a_fidelity_gp(problem):
    rng = problem[2]
    bases = gr.random_points(M, C, 3, rng)
    gp = GrassmannGP(M, C).fit(bases, np.arange(3.0))
    with pytest.raises(ValueError, match="BOCA needs a GP with a fidelity kernel"):
        _boca().choose(gp, bases[0])


def test_the_choice_history_is_state_not_a_setting():
    # ``recent`` was an undocumented constructor argument: a list passed there became the
    # starting history of the adaptation.
    with pytest.raises(TypeError, match="recent"):
        BOCAFidelity(T_MIN, T_MAX, recent=[True] * 5)
    boca = BOCAFidelity(T_MIN, T_MAX, window=5)
    assert list(boca.recent) == [] and boca.recent.maxlen == 5


def _small_gp(problem):
    u, v, rng = problem
    bases = gr.random_points(M, C, 4, rng)
    z = np.array([0.0, 0.0, 1.0, 1.0])
    return GrassmannGP(M, C, fidelity=True, random_state=0).fit(
        bases, two_fidelity(bases, z, u, v), z
    )


def test_a_candidate_costing_exactly_the_cap_is_considered():
    """'at most max_cost_ratio': T = 8 of T_max = 10 is a candidate under a cap of 0.8."""
    boca = BOCAFidelity(2.0, 10.0, n_candidates=5, max_cost_ratio=0.8)
    np.testing.assert_array_equal(boca.candidates, [2.0, 4.0, 6.0, 8.0])


def test_no_candidate_under_the_cap_means_full_length(problem):
    """A cap below T_min / T_max leaves nothing to choose from: T_max, with empty records."""
    boca = BOCAFidelity(T_MIN, T_MAX, max_cost_ratio=0.3)
    assert len(boca.candidates) == 0
    choice = boca.choose(_small_gp(problem), gr.random_points(M, C, rng=problem[2]))
    assert (choice.T, choice.candidates, choice.tau, choice.gamma) == (T_MAX, (), (), ())
    assert not choice.floor


def test_the_floor_flag_marks_only_a_choice_the_floor_changed(problem):
    """Below the floor, a T_max the threshold chose by itself (kappa so high that no tau
    exceeds gamma) is not the floor's doing."""
    boca = BOCAFidelity(T_MIN, T_MAX, n_candidates=2, kappa=1e6, window=10**6)
    for _ in range(5):
        boca.record(T_MIN)
    assert boca.below_floor()
    choice = boca.choose(_small_gp(problem), gr.random_points(M, C, rng=problem[2]))
    assert choice.T == T_MAX and not choice.floor


def test_the_floor_counts_from_floor_after_choices_and_over_the_window_only():
    boca = BOCAFidelity(T_MIN, T_MAX, window=4, floor_after=4)
    for _ in range(3):
        boca.record(T_MIN)
    assert not boca.below_floor()  # three choices: too few to judge
    boca.record(T_MIN)
    assert boca.below_floor()  # floor_after = 4 of them, none at T_max
    boca = BOCAFidelity(T_MIN, T_MAX, window=4, floor_after=4)
    for t in (T_MAX, T_MAX, T_MIN, T_MIN):
        boca.record(t)
    assert not boca.below_floor()  # 2 of 4
    # two T_min proposals in flight: the window's last four are all T_min (2 of all 6 are
    # T_max, which would be above the floor)
    assert boca.below_floor(pending=[T_MIN, T_MIN])
    assert not boca.below_floor(pending=[T_MIN, T_MAX])


def test_kappa_step_one_and_cost_exponent_zero_are_valid_settings():
    """kappa_step = 1 switches the adaptation off, cost_exponent = 0 drops the cost factor."""
    boca = BOCAFidelity(T_MIN, T_MAX, window=4, kappa=0.7, kappa_step=1.0, cost_exponent=0.0)
    for _ in range(8):
        boca.record(T_MAX)
    assert boca.kappa == 0.7
