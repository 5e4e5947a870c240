"""Planners: finite-difference Jacobian, monotone Gauss-Newton, MPPI, episodes, validation.

Small robots (a 28-node beam, 6 modes) and short horizons keep these fast."""

import dataclasses
import errno
import sys

import gymnasium as gym
import numpy as np
import pytest

import softrom_gym
from controllers import (
    MPPI,
    CostWeights,
    EpisodeResult,
    GaussNewtonSettings,
    GaussNewtonShooting,
    MPPISettings,
    PlannerSettings,
    SplinePlan,
    default_planner,
    default_settings,
    gait_grid,
    has_defaults,
    planner_for,
    run_episode,
)
from controllers.__main__ import _parser as cli_parser
from controllers.__main__ import main as cli_main
from controllers.cost import evaluate
from controllers.episode import _gif_timing


def small_env(task="walk", **kwargs):
    return gym.make("softrom_gym/SoftRobot-v0", robot="beam", task=task, sim_dim=6,
                    resolution=6, **kwargs)  # fmt: skip


@pytest.fixture(scope="module")
def swimmer():
    env = small_env("swim")
    env.reset(seed=0)
    return env


@pytest.fixture(scope="module")
def walker():
    env = small_env("walk")
    env.reset(seed=0)
    return env


def test_fd_jacobian_matches_central_differences(swimmer):
    settings = GaussNewtonSettings(horizon=6, knots=2, fd_step=1e-3,
                                   weights=CostWeights(orientation=1.0, lateral=1.0))  # fmt: skip
    gn = GaussNewtonShooting(settings)
    gn.reset(swimmer, seed=0)
    rng = np.random.default_rng(0)
    gn.plan_.knots = rng.uniform(-0.5, 0.5, gn.plan_.knots.shape)
    state = swimmer.get_wrapper_attr("get_state")()
    _, grad, jac = gn.jacobian(state)
    x = gn.plan_.knots.ravel()
    h = 1e-3
    plus = np.repeat(x[None], x.size, 0) + h * np.eye(x.size)
    minus = np.repeat(x[None], x.size, 0) - h * np.eye(x.size)
    ep = gn.evaluate_knots(state, plus.reshape(-1, 2, 3))
    em = gn.evaluate_knots(state, minus.reshape(-1, 2, 3))
    ref_grad = (ep.reward - em.reward) / (2 * h)
    ref_jac = ((ep.residuals - em.residuals) / (2 * h)).T
    assert np.abs(ref_grad).max() > 1e-7  # the knots do move the swimmer
    np.testing.assert_allclose(grad, ref_grad, rtol=0, atol=1e-2 * np.abs(ref_grad).max())
    np.testing.assert_allclose(jac, ref_jac, rtol=0, atol=1e-2 * np.abs(ref_jac).max())
    # A knot within fd_step of the bound is perturbed inwards (a step outwards would be
    # clipped by the env to part of itself, and the difference read as half the slope): its
    # column against a central difference of a step that stays inside, 4e-4 (measured:
    # 5e-4 of the slope apart, the backward difference's truncation; 1e-2 as above).
    knots = gn.plan_.knots.copy()
    knots[1, 0] = 0.9995
    _, grad, jac = gn.jacobian(state, knots)
    pair = np.repeat(knots[None], 2, 0)
    pair[0, 1, 0] += 4e-4
    pair[1, 1, 0] -= 4e-4
    ev = gn.evaluate_knots(state, pair)
    slope = (ev.reward[0] - ev.reward[1]) / 8e-4
    rows = (ev.residuals[0] - ev.residuals[1]) / 8e-4
    assert abs(slope) > 1e-7
    assert grad[3] == pytest.approx(slope, rel=1e-2)  # (knots[1, 0] is entry 3 of x)
    np.testing.assert_allclose(jac[:, 3], rows, rtol=0, atol=1e-2 * np.abs(rows).max())


def _plan_recording_rollouts(planner, env) -> list[tuple[np.ndarray, np.ndarray]]:
    """``planner.plan(env)``, returning the knots and objectives of each batched rollout."""
    calls = []
    real = planner.evaluate_knots

    def record(state, knots, horizon=None):
        ev = real(state, knots, horizon)
        calls.append((knots.copy(), ev.objective.copy()))
        return ev

    planner.evaluate_knots = record
    try:
        planner.plan(env)
    finally:
        del planner.evaluate_knots
    return calls


def test_gauss_newton_iterations_never_lower_the_objective(walker):
    settings = GaussNewtonSettings(horizon=8, knots=3, iterations=4, damping=1e-4)
    gn = GaussNewtonShooting(settings)
    gn.reset(walker, seed=0)
    calls = _plan_recording_rollouts(gn, walker)  # knots and objectives of each batch
    history = gn.last_["objectives"]
    assert len(history) == 4
    # Each iteration: a Jacobian rollout (K C + 1 = 10 plans), then the line search's (4),
    # whose trials are the damped Gauss-Newton steps of the module docstring,
    # dx = (2 J^T J + mu I)^-1 (grad R - 2 J^T r), for mu = mu_i * line_search; mu moves to
    # the accepted trial's, or to ten times the largest tried. Recomputed from the same
    # (deterministic) rollouts, the trials agree to the round-off of a 9 x 9 solve.
    assert [len(k) for k, _ in calls] == [10, 4] * 4
    state = walker.get_wrapper_attr("get_state")()
    mu = settings.damping
    for (base, _), (trials, objective) in zip(calls[::2], calls[1::2], strict=True):
        ev, grad, jac = gn.jacobian(state, base[0])
        x = base[0].ravel()
        mus = mu * np.asarray(settings.line_search)
        g = grad - 2.0 * jac.T @ ev.residuals[0]
        for trial, m in zip(trials, mus, strict=True):
            dx = np.linalg.solve(2.0 * jac.T @ jac + m * np.eye(9), g)
            np.testing.assert_allclose(trial.ravel(), np.clip(x + dx, -1, 1), rtol=0, atol=1e-9)
        best = int(np.argmax(objective))
        mu = mus[best] if objective[best] > ev.objective[0] else 10.0 * mus.max()
    assert gn.damping_ == pytest.approx(mu, rel=1e-15)
    starts = [h[0] for h in history]
    ends = [h[1] for h in history]
    assert all(e >= s for s, e in history)
    assert starts[1:] == ends[:-1]  # the next iteration starts where the last one ended
    assert ends[-1] > starts[0]  # and the plan did improve
    # the record: J of the warm start and of the plan adopted after the last iteration
    assert gn.last_["objective_start"] == starts[0] and gn.last_["objective_best"] == ends[-1]
    state = walker.get_wrapper_attr("get_state")()
    again = gn.evaluate_knots(state, gn.plan_.knots[None])
    assert again.objective[0] == ends[-1]


def test_gauss_newton_trust_region_bounds_every_knot_move(walker):
    settings = GaussNewtonSettings(horizon=8, knots=3, iterations=3, damping=1e-4,
                                   max_step=0.05)  # fmt: skip
    gn = GaussNewtonShooting(settings)
    gn.reset(walker, seed=0)
    before = gn.plan_.knots.copy()
    gn.plan(walker)
    moved = np.abs(gn.plan_.knots - before).max()
    assert 0 < moved <= 3 * 0.05 + 1e-12  # three iterations, each inside the region
    assert all(e >= s for s, e in gn.last_["objectives"])
    # exploration candidates too: they moved knots by up to the whole bound, as "explore".
    # (A damping of 1e6 shrinks the Gauss-Newton step to almost nothing, so an exploration
    # candidate wins on any physics; at 1e-4 whether one beat the step on this seed depended
    # on the contact solve's last bits, and stopped doing so in session 53.)
    explorer = GaussNewtonShooting(
        settings.replace(max_step=0.01, explore=8, explore_noise=0.3, damping=1e6)
    )
    explorer.reset(walker, seed=0)
    before = explorer.plan_.knots.copy()
    explorer.plan(walker)
    assert "explore" in explorer.last_["accepted"]
    assert np.abs(explorer.plan_.knots - before).max() <= 3 * 0.01 + 1e-12
    with pytest.raises(ValueError, match="max_step"):
        GaussNewtonSettings(max_step=0.0)


def test_gauss_newton_exploration_competes_under_the_same_acceptance_rule(walker):
    # Exploration candidates run in the line search's rollout; whichever candidate wins,
    # an iteration never lowers the objective, and a seed fixes the candidates.
    settings = GaussNewtonSettings(horizon=8, knots=3, iterations=4, damping=10.0,
                                   explore=6, explore_noise=0.3)  # fmt: skip
    runs = []
    for _ in range(2):
        gn = GaussNewtonShooting(settings)
        gn.reset(walker, seed=3)
        gn.plan(walker)
        runs.append((gn.plan_.knots.copy(), gn.last_["objectives"], gn.last_["rollouts"]))
    (knots_a, history, rollouts), (knots_b, _, _) = runs
    np.testing.assert_array_equal(knots_a, knots_b)
    assert all(e >= s for s, e in history)
    assert history[-1][1] > history[0][0]
    assert len(gn.last_["accepted"]) == 4
    assert set(gn.last_["accepted"]) <= {"step", "explore", "none"}
    for (start, end), kind in zip(history, gn.last_["accepted"], strict=True):
        assert (kind == "none") == (end == start)
    x_size = 3 * 3
    assert rollouts == 4 * ((x_size + 1) + len(settings.line_search) + 6)
    with pytest.raises(ValueError, match="explore must be an integer >= 0, got -1"):
        GaussNewtonSettings(explore=-1)
    with pytest.raises(ValueError, match="explore_noise must be a finite number > 0, got 0"):
        GaussNewtonSettings(explore_noise=0)


def test_gauss_newton_takes_no_step_that_only_ties_the_objective(walker):
    # At a damping where the step is below the knots' round-off every trial is the plan
    # itself and scores exactly its J: no improvement, so the iteration is rejected and mu
    # grows (accepting the tie, >= for >, would record a "step" that changed nothing and cut
    # mu tenfold where a rejection raises it a thousandfold).
    gn = GaussNewtonShooting(GaussNewtonSettings(horizon=6, knots=2))
    gn.reset(walker, seed=0)
    gn.plan_.knots[:] = 0.5
    gn.damping_ = 1e140
    gn.plan(walker)
    assert gn.last_["accepted"] == ["none"]
    assert gn.last_["objectives"][0][0] == gn.last_["objectives"][0][1]
    assert gn.damping_ == pytest.approx(1e140 * 100.0 * 10.0)
    np.testing.assert_array_equal(gn.plan_.knots, 0.5)


def test_gauss_newton_trust_region_scales_a_step_to_its_largest_knot_move(walker):
    # max_step bounds the move of each knot (the largest |dx_i|): a longer step is scaled until
    # that move is max_step itself (scaled by its Euclidean norm instead, every step would come
    # out shorter than the region, by up to sqrt(K C)).
    gn = GaussNewtonShooting(GaussNewtonSettings(horizon=8, knots=3, damping=1e-4,
                                                 max_step=0.05))  # fmt: skip
    gn.reset(walker, seed=0)
    (_, _), (trials, _) = _plan_recording_rollouts(gn, walker)
    moves = np.abs(trials.reshape(len(trials), -1)).max(axis=1)  # (the plan was all zeros)
    assert np.all(moves <= 0.05 + 1e-15)
    assert moves[0] == pytest.approx(0.05, rel=1e-12)  # the least damped step, scaled down


def test_gauss_newton_exploration_candidates_are_seeded_noise_clipped_to_the_bound(walker):
    # The candidates after the line search's steps are the plan plus explore_noise times
    # standard normal draws of the planner's seeded stream, clipped to the bound (unscaled
    # draws would ignore explore_noise; unclipped ones would leave knots outside [-1, 1]).
    gn = GaussNewtonShooting(GaussNewtonSettings(horizon=6, knots=2, explore=5,
                                                 explore_noise=0.6))  # fmt: skip
    gn.reset(walker, seed=3)
    (_, _), (trials, _) = _plan_recording_rollouts(gn, walker)
    noise = 0.6 * np.random.default_rng(3).standard_normal((5, 6))  # around knots at zero
    assert np.abs(noise).max() > 1.0  # some are clipped
    np.testing.assert_array_equal(trials[4:].reshape(5, 6), np.clip(noise, -1.0, 1.0))
    assert np.abs(gn.plan_.knots).max() <= 1.0


def test_gauss_newton_trust_region_leaves_exploration_noise_inside_it_as_drawn(walker):
    # max_step scales down a candidate whose largest knot move exceeds it; noise already
    # inside the region is used as drawn, not stretched out to the region's edge (a missing
    # min(1, .) blew it up fifty-fold: mutation testing, session 56)
    gn = GaussNewtonShooting(GaussNewtonSettings(horizon=6, knots=2, explore=5,
                                                 explore_noise=0.01, max_step=0.5))  # fmt: skip
    gn.reset(walker, seed=3)
    (_, _), (trials, _) = _plan_recording_rollouts(gn, walker)
    noise = 0.01 * np.random.default_rng(3).standard_normal((5, 6))  # around knots at zero
    assert np.abs(noise).max() < 0.5
    n_steps = len(gn.settings.line_search)
    np.testing.assert_array_equal(trials[n_steps:].reshape(5, 6), noise)


def test_mppi_with_zero_noise_returns_its_warm_start(walker):
    mppi = MPPI(MPPISettings(horizon=6, knots=3, samples=4, noise=0.0))
    mppi.reset(walker, seed=0)
    knots = np.random.default_rng(3).uniform(-1, 1, mppi.plan_.knots.shape)
    mppi.plan_.knots = knots.copy()
    mppi.plan(walker)
    np.testing.assert_array_equal(mppi.plan_.knots, knots)


def _mppi_replan(env, knots, **settings):
    mppi = MPPI(MPPISettings(horizon=6, knots=3, samples=6, **settings))
    mppi.reset(env, seed=0)
    mppi.plan_.knots = knots.copy()
    mppi.plan(env)
    return mppi.plan_.knots


def test_mppi_noise_per_control_dimension(walker):
    knots = np.random.default_rng(3).uniform(-0.5, 0.5, (3, 3))
    scalar = _mppi_replan(walker, knots, noise=0.2)
    # the same standard deviation given per dimension draws the same samples
    np.testing.assert_array_equal(_mppi_replan(walker, knots, noise=[0.2, 0.2, 0.2]), scalar)
    # a dimension at 0 keeps its knots; the others move
    moved = _mppi_replan(walker, knots, noise=(0.2, 0.0, 0.2))
    np.testing.assert_array_equal(moved[:, 1], knots[:, 1])
    assert np.abs(moved[:, [0, 2]] - knots[:, [0, 2]]).max() > 1e-3
    assert MPPISettings(noise=[0.2, 0, 1]).noise == (0.2, 0.0, 1.0)  # stored hashable
    planner = MPPI(MPPISettings(horizon=6, knots=3, samples=2, noise=(0.1, 0.2)))
    with pytest.raises(ValueError, match="noise has 2 standard deviations, .* C = 3: give 3"):
        planner.reset(walker, seed=0)
    assert planner.plan_ is None  # refused before it changed anything


def test_mppi_noise_decay_anneals_later_sampling_rounds(walker):
    knots = np.random.default_rng(4).uniform(-0.5, 0.5, (3, 3))
    one_round = _mppi_replan(walker, knots, noise=0.3)
    # A second round at a vanishing noise draws samples indistinguishable from the plan it
    # starts from, so it ends where the first round did; at the first round's noise it moves.
    annealed = _mppi_replan(walker, knots, noise=0.3, iterations=2, noise_decay=1e-12)
    np.testing.assert_allclose(annealed, one_round, rtol=0, atol=1e-9)
    constant = _mppi_replan(walker, knots, noise=0.3, iterations=2)
    assert np.abs(constant - one_round).max() > 1e-3


@pytest.mark.parametrize("restart", [False, True])
def test_gauss_newton_damping_carries_over_replans_unless_restarted(walker, restart):
    gn = GaussNewtonShooting(GaussNewtonSettings(horizon=6, knots=2, restart_damping=restart))
    gn.reset(walker, seed=0)
    gn.damping_ = 1e6  # as a run of rejected replans leaves it
    gn.plan(walker)
    # one iteration tries mu * line_search (0.1 .. 100) and ends at one of them or 10 x the
    # largest: at most 1e-2 * 1e3 from the setting, at least 1e6 * 0.1 carried over
    if restart:
        assert gn.last_["damping"] <= 10.0
    else:
        assert gn.last_["damping"] >= 1e5


def test_a_setting_added_since_records_is_left_out_of_them_at_its_neutral_value():
    from rbbo.objective import planner_record

    # what runs recorded before noise_decay existed is still the record of the default MPPI
    assert "noise_decay" not in MPPISettings().record()
    assert MPPISettings(noise_decay=0.5).record()["noise_decay"] == 0.5
    assert "threads" not in MPPISettings(threads=2).record()
    assert "restart_damping" not in GaussNewtonSettings().record()
    assert GaussNewtonSettings(restart_damping=True).record()["restart_damping"] is True
    record = planner_record(MPPI(MPPISettings(noise=(0.1, 0.2))), 4)
    assert record["settings"]["noise"] == [0.1, 0.2]
    assert record["settings"]["weights"] == {
        k: v for k, v in vars(CostWeights()).items() if not k.startswith("_")
    }


def test_the_default_planners_record_as_runs_recorded_them():
    """Every run records its planner, and resuming one compares the record with the planner
    of the day (rbbo's PlannerMismatch). tests/data/planner_records.json holds the records of
    the tuned and the shared (SoftRobot-v0) defaults as runs hold them (the same at f0a7552,
    before noise_decay and restart_damping were added): a changed default, or a new setting
    not listed in ``_neutral_since_records``, makes every such run unresumable. If that is
    meant, regenerate the file and say so in the change."""
    import json
    from pathlib import Path

    from controllers import TUNED_DT
    from rbbo.objective import planner_record

    expected = json.loads((Path(__file__).parent / "data" / "planner_records.json").read_text())
    for key, record in expected.items():
        env_id, name = key.split()
        planner, every = planner_for(env_id, name, dt=TUNED_DT)
        assert planner_record(planner, every) == record, key


def test_mppi_beats_zero_control_on_a_short_horizon(walker):
    mppi = MPPI(MPPISettings(horizon=10, knots=3, samples=12, noise=0.5, iterations=3))
    mppi.reset(walker, seed=0)
    rounds = _plan_recording_rollouts(mppi, walker)  # (samples, objectives) of each round
    assert mppi.last_["rollouts"] == 36  # 3 iterations of 12 samples
    # Each round moves the knots to the mean of its samples weighted exp((J - max J) /
    # (temperature spread)) (the module docstring), sample 0 being the plan it started from;
    # the next round starts there. The same sums in another order: round-off apart.
    assert len(rounds) == 3
    for i, (samples, j) in enumerate(rounds):
        weights = np.exp((j - j.max()) / (mppi.settings.temperature * np.ptp(j)))
        weights /= weights.sum()
        mean = np.einsum("b,bkc->kc", weights, samples)
        after = rounds[i + 1][0][0] if i < 2 else mppi.plan_.knots
        np.testing.assert_allclose(after, mean, rtol=0, atol=1e-12)
    assert mppi.last_["objective_start"] == rounds[0][1][0]
    assert mppi.last_["objective_best"] == max(j.max() for _, j in rounds)
    assert mppi.last_["effective_samples"] == pytest.approx(1 / np.sum(weights**2), rel=1e-12)
    state = walker.get_wrapper_attr("get_state")()
    ev = mppi.evaluate_knots(state, np.stack([mppi.plan_.knots, np.zeros_like(mppi.plan_.knots)]))
    assert ev.objective[0] > ev.objective[1] + 1e-3


def test_mppi_samples_are_the_plan_plus_seeded_noise_clipped_to_the_bound(walker):
    # Sample 0 is the plan; the others the plan plus noise times standard normal draws of the
    # stream reset(seed) starts, clipped to the bound (unclipped samples would leave the knots
    # outside [-1, 1]; a stream that ignored the seed would sample every seed alike).
    knots = np.random.default_rng(5).uniform(-0.5, 0.5, (3, 3))
    mppi = MPPI(MPPISettings(horizon=6, knots=3, samples=8, noise=0.8))
    mppi.reset(walker, seed=7)
    mppi.plan_.knots = knots.copy()
    ((samples, _),) = _plan_recording_rollouts(mppi, walker)
    eps = 0.8 * np.random.default_rng(7).standard_normal((8, 3, 3))
    eps[0] = 0.0
    assert np.abs(knots + eps).max() > 1.0  # some are clipped
    np.testing.assert_array_equal(samples, np.clip(knots + eps, -1.0, 1.0))
    assert np.abs(mppi.plan_.knots).max() <= 1.0


def test_mppi_at_a_cold_temperature_takes_its_best_sample(walker):
    # exp((J - max J) / (temperature spread)) -> 1 for the best sample, 0 for the others: the
    # exponents stay <= 0 (measured from min J instead, they would overflow: NaN knots)
    mppi = MPPI(MPPISettings(horizon=6, knots=3, samples=8, noise=0.3, temperature=1e-4))
    mppi.reset(walker, seed=0)
    ((samples, j),) = _plan_recording_rollouts(mppi, walker)
    np.testing.assert_allclose(mppi.plan_.knots, samples[np.argmax(j)], rtol=0, atol=1e-12)
    assert mppi.last_["effective_samples"] == pytest.approx(1.0, rel=1e-12)


def test_mppi_objective_best_is_the_best_sample_of_all_rounds(walker, monkeypatch):
    # With later rounds scoring worse, the best sample is in the first: objective_best is the
    # best of every round's (the last round's best would understate it)
    mppi = MPPI(MPPISettings(horizon=6, knots=3, samples=4, iterations=3))
    mppi.reset(walker, seed=0)
    evaluate = mppi.evaluate_knots
    bests = []

    def later_rounds_worse(state, knots, horizon=None):
        ev = evaluate(state, knots, horizon)
        ev = dataclasses.replace(ev, objective=ev.objective - 10.0 * len(bests))
        bests.append(float(ev.objective.max()))
        return ev

    monkeypatch.setattr(mppi, "evaluate_knots", later_rounds_worse)
    mppi.plan(walker)
    assert len(bests) == 3 and mppi.last_["objective_best"] == bests[0] > bests[-1]


@pytest.mark.parametrize("planner", ["mppi", "gn"])
def test_same_seed_same_episode_whatever_the_thread_count(planner):
    results = []
    for threads in (1, 2, 1):
        env = small_env("walk")
        settings = dict(horizon=6, knots=2, threads=threads)
        if planner == "mppi":
            p = MPPI(MPPISettings(samples=4, **settings))
        else:
            p = GaussNewtonShooting(GaussNewtonSettings(**settings))
        results.append(run_episode(env, p, 0.1, replan_every=2, seed=5, progress=False))
    a, b, c = results
    for key in ("rewards", "actions", "com", "orientation"):
        np.testing.assert_array_equal(getattr(a, key), getattr(b, key))
    np.testing.assert_array_equal(a.states[-1].q, b.states[-1].q)
    np.testing.assert_array_equal(a.actions, c.actions)
    assert np.any(a.actions != 0)


def test_episode_result_records_the_episode(walker, tmp_path):
    env = small_env("walk", render_mode="rgb_array")
    p = MPPI(MPPISettings(horizon=4, knots=2, samples=3))
    video = tmp_path / "walk.mp4"
    res = run_episode(env, p, 0.1, replan_every=2, seed=0, progress=True, video=video)
    assert res.rewards.shape == (4,) and res.actions.shape == (4, 3) and res.com.shape == (5, 3)
    assert len(res.states) == 5 and res.replans == 2 and list(res.replan_steps) == [0, 2]
    assert res.stop_reason == "time"
    # each replan's record, as the planner's last_ was after it
    assert len(res.replan_records) == 2
    for record in res.replan_records:
        assert record["rollouts"] == 3 and record["effective_samples"] >= 1.0
        assert record["objective_best"] >= record["objective_start"]
    assert res.R == pytest.approx(res.distance[-1], abs=1e-12)
    assert res.distance_between(0.05) == pytest.approx(res.distance[4] - res.distance[2])
    bound = env.get_wrapper_attr("action_bound")
    assert np.all(np.abs(res.actions) <= bound)
    assert "replans" in res.summary() and video.stat().st_size > 500
    import imageio.v2 as imageio

    with imageio.get_reader(video) as reader:  # the frames keep their size (no 16-px blocks)
        assert reader.get_data(0).shape == env.render().shape
    with pytest.raises(ValueError, match=r"times \(0.5, None\) must lie in \[0, 0.1\] s"):
        res.distance_between(0.5)
    # within half a step outside the episode, a time rounded into it and was taken
    for times in [(0.11,), (-0.01,), (0.0, 0.11), (0.06, 0.04)]:
        with pytest.raises(ValueError, match=r"must lie in \[0, 0.1\] s, in order"):
            res.distance_between(*times)
    assert res.distance_between(0.0, 0.1) == pytest.approx(res.distance[-1])


def _made_up_episode(body_length=0.5, planner="mppi"):
    """8 steps of 0.025 s, the COM at 0.01 t^2 along x (t in steps), replans at steps 0 and 4."""
    n = 8
    com = np.zeros((n + 1, 3))
    com[:, 0] = 0.01 * np.arange(n + 1) ** 2
    return EpisodeResult(planner=planner, dt=0.025, body_length=body_length,
                         rewards=np.diff(com[:, 0]), orientation=np.zeros(n),
                         lateral=np.zeros(n), effort=np.zeros(n), actions=np.zeros((n, 3)),
                         com=com, distance=com[:, 0], states=[None] * (n + 1),
                         replan_steps=np.array([0, 4]),
                         replan_wall_s=np.array([0.1, 0.3]))  # fmt: skip


def test_a_noise_sequence_of_another_length_than_c_says_what_to_give():
    """The message "give 3 numbers or one" refused noise=(0.3,), which is one number: it says a
    single number goes outside a sequence."""
    with pytest.raises(ValueError, match=r"noise has 1 standard deviations, one per control "
                       r"dimension, but the env has C = 3: give 3 numbers, or one number "
                       r"\(not in a sequence\) for every dimension"):  # fmt: skip
        MPPISettings(noise=(0.3,)).check_control_dim(3)
    MPPISettings(noise=0.3).check_control_dim(3)
    MPPISettings(noise=(0.3, 0.2, 0.1)).check_control_dim(3)


def test_episode_result_documents_every_field_and_its_summary():
    """planner, dt, body_length and seed_gait were in no docstring, and summary(start), the
    README's first MPC example's output, had none."""
    import dataclasses
    import re

    for f in dataclasses.fields(EpisodeResult):
        assert re.search(rf"``{f.name}``", EpisodeResult.__doc__), f.name
    assert "``start``" in (EpisodeResult.summary.__doc__ or "")
    assert "``replan_every``" in (EpisodeResult.realtime_factor.__doc__ or "")


def test_episode_result_arithmetic_on_a_made_up_episode():
    # 0.15 s / 0.025 s is 5.999...: distance_between reads step 6, the nearest (int() would
    # read step 5); the real-time factor is the simulated seconds between replans per wall second
    # of one (not one step's); a start at the episode's end summarises the whole episode, as
    # one past it does, not the empty window at its end.
    res = _made_up_episode()
    com = res.com
    assert res.distance_between(0.15) == pytest.approx(com[8, 0] - com[6, 0], rel=1e-12)
    assert res.distance_between(0.05, 0.15) == pytest.approx(com[6, 0] - com[2, 0], rel=1e-12)
    assert res.realtime_factor(4) == pytest.approx(4 * 0.025 / 0.2, rel=1e-12)
    assert "distance t=0..0.2 s +0.640 m (+1.28 body lengths)" in res.summary(start=0.2)
    assert "distance t=0.1..0.2 s +0.480 m" in res.summary(start=0.1)


def test_an_episode_lasts_the_nearest_whole_number_of_steps():
    # 0.15 s of 0.025 s steps is 5.999... steps: six are run (int() would run five)
    env = small_env("walk")
    res = run_episode(env, MPPI(MPPISettings(horizon=4, knots=2, samples=2)), 0.15,
                      replan_every=10, seed=0, progress=False)  # fmt: skip
    assert res.rewards.size == 6 and res.seconds == pytest.approx(0.15)


class _StartFrom(gym.Wrapper):
    """Resets the env to a given state (as ``options={"state": ...}`` does)."""

    def __init__(self, env, state):
        super().__init__(env)
        self.state = state

    def reset(self, *, seed=None, options=None):
        return self.env.reset(seed=seed, options={"state": self.state})


def test_an_episode_from_a_state_away_from_the_origin_counts_its_distance_from_there():
    # distance is along d since the episode's first state, wherever it is (measured from the
    # origin, R of an episode reset to a state mid-walk would include the walk before it; the
    # benchmarks reset to the origin, where the two agree)
    env = small_env("walk")
    env.reset(seed=0)
    for _ in range(10):
        env.step(np.full(3, 0.5 * env.get_wrapper_attr("action_bound"), dtype=np.float32))
    start = _StartFrom(env, env.get_wrapper_attr("get_state")())
    res = run_episode(start, MPPI(MPPISettings(horizon=4, knots=2, samples=2)), 0.1,
                      seed=0, progress=False)  # fmt: skip
    assert abs(res.com[0] @ env.get_wrapper_attr("direction")) > 1e-5  # away from the origin
    assert res.distance[0] == 0.0
    assert res.R == pytest.approx(res.rewards.sum(), abs=1e-12)


def test_a_video_without_imageio_fails_before_the_episode(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "imageio", None)  # import imageio raises ImportError
    monkeypatch.setitem(sys.modules, "imageio.v2", None)
    env = small_env("walk", render_mode="rgb_array")
    planner = MPPI(MPPISettings(horizon=4, knots=2, samples=2))
    with pytest.raises(ImportError, match=r"pip install 'softrom\[video\]'"):
        run_episode(env, planner, 0.1, seed=0, progress=False, video=tmp_path / "a.mp4")
    assert planner.plan_ is None  # refused before the episode started


def test_a_video_path_under_home_is_expanded(tmp_path, monkeypatch):
    # "~/walk.gif" was refused as "the folder '~' does not exist" (--video "~/..." too), where
    # a robot's mesh path and export_trajectory read "~" as the home folder
    home = tmp_path / "home"
    home.mkdir()
    monkeypatch.setenv("HOME", str(home))
    monkeypatch.chdir(tmp_path)
    env = small_env("walk", render_mode="rgb_array")
    run_episode(env, MPPI(MPPISettings(horizon=4, knots=2, samples=2)), 0.05, seed=0,
                progress=False, video="~/walk.gif")  # fmt: skip
    assert (home / "walk.gif").stat().st_size > 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["home"]


def test_a_bad_video_path_fails_before_the_episode(tmp_path):
    env = small_env("walk", render_mode="rgb_array")
    planner = MPPI(MPPISettings(horizon=4, knots=2, samples=2))
    with pytest.raises(ValueError, match="the folder .*nodir' does not exist"):
        run_episode(env, planner, 0.1, seed=0, progress=False, video=tmp_path / "nodir/a.mp4")
    with pytest.raises(ValueError, match="the file name must end in one of .avi"):
        run_episode(env, planner, 0.1, seed=0, progress=False, video=tmp_path / "a.xyz")
    assert planner.plan_ is None
    with pytest.raises(SystemExit) as exc:
        cli_main(["BeamWalk-v0", "--video", str(tmp_path / "nodir/a.mp4")])
    assert exc.value.code == 2


def test_a_video_of_control_periods_over_two_seconds_plays_one_frame_a_second(tmp_path):
    # 1 / 2.5 s rounds to 0 frames per second: the GIF writer divided by it after the episode
    env = small_env("walk", render_mode="rgb_array", dt=0.5, frame_skip=5)
    planner = MPPI(MPPISettings(horizon=1, knots=1, samples=2, threads=1))
    video = tmp_path / "slow.gif"
    res = run_episode(env, planner, 5.0, seed=0, progress=False, video=video)
    assert res.rewards.size == 2
    from PIL import Image

    with Image.open(video) as gif:
        assert gif.n_frames == 3 and gif.info["duration"] == 1000


def test_a_gif_plays_in_real_time(tmp_path):
    # GIF counts delays in 1/100 s: 1000 / 40 fps = 25 ms was stored as 20 ms, and a 40-fps
    # episode played at 50 fps (0.8 of real time)
    env = small_env("walk", render_mode="rgb_array")
    video = tmp_path / "walk.gif"
    res = run_episode(env, MPPI(MPPISettings(horizon=4, knots=2, samples=2)), 0.5, seed=0,
                      progress=False, video=video)  # fmt: skip
    from PIL import Image

    with Image.open(video) as gif:
        delays = []
        for i in range(gif.n_frames):
            gif.seek(i)
            delays.append(gif.info["duration"])
    assert min(delays) >= 20  # (browsers play a shorter delay as 100 ms)
    # 21 frames of 25 ms each: the episode's 0.5 s and its first frame's 25 ms, to 1/100 s
    assert sum(delays) == pytest.approx(1000 * (res.seconds + res.dt), abs=10)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["walk.gif"]  # (no temporary file)


def test_a_video_path_that_is_a_folder_fails_before_the_episode(tmp_path, capsys, monkeypatch):
    # it passed the check, and the write failed after the whole episode, with a traceback
    # and without the episode's result
    env = small_env("walk", render_mode="rgb_array")
    planner = MPPI(MPPISettings(horizon=4, knots=2, samples=2))
    (tmp_path / "walk.mp4").mkdir()
    with pytest.raises(ValueError, match=r"walk.mp4' is a folder; give a file name"):
        run_episode(env, planner, 0.1, seed=0, progress=False, video=tmp_path / "walk.mp4")
    assert planner.plan_ is None
    with pytest.raises(SystemExit) as exc:
        cli_main(["BeamWalk-v0", "--video", str(tmp_path / "walk.mp4")])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "walk.mp4' is a folder" in err
    # a folder one cannot write in: found by trying, before the episode
    import controllers.episode as episode

    def refused(path):
        raise PermissionError(errno.EACCES, "Permission denied", str(path))

    monkeypatch.setattr(episode, "_temporary_name", refused)
    with pytest.raises(ValueError, match=r"cannot write in the folder .* \(Permission denied"):
        run_episode(env, planner, 0.1, seed=0, progress=False, video=tmp_path / "a.mp4")
    assert planner.plan_ is None


def test_a_video_that_cannot_be_written_hands_back_the_episode(tmp_path, capsys, monkeypatch):
    # a write that failed after the episode (a full disk) raised without the episode's result
    import imageio.v2 as imageio

    def full_disk(uri, *args, **kwargs):
        with open(uri, "wb") as f:
            f.write(b"part of a video")
        raise OSError(errno.ENOSPC, "No space left on device\n\nFFMPEG COMMAND: ...")

    video = tmp_path / "walk.mp4"
    video.write_bytes(b"an earlier video")
    monkeypatch.setattr(imageio, "mimwrite", full_disk)
    env = small_env("walk", render_mode="rgb_array")
    with pytest.raises(OSError, match="No space left") as exc:
        run_episode(env, MPPI(MPPISettings(horizon=4, knots=2, samples=2)), 0.1, seed=0,
                    progress=False, video=video)  # fmt: skip
    result = exc.value.result
    assert result.stop_reason == "time" and result.rewards.size == 4 and len(result.states) == 5
    # the earlier video is as it was, and no part of the new one is left beside it
    assert video.read_bytes() == b"an earlier video"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["walk.mp4"]
    # the command line prints the episode's line, then the error on one line: exit 1
    code = cli_main(["BeamWalk-v0", "--planner", "gn", "--seconds", "0.05", "--horizon", "4",
                     "--window", "all", "--iterations", "1", "--no-progress", "--video",
                     str(video)])  # fmt: skip
    out, err = capsys.readouterr()
    assert code == 1 and out.startswith("BeamWalk-v0 gn: 0.05 s") and "real-time factor" in out
    # (the lines before it, if any, are the env's first build of the robot's model)
    assert err.endswith("\n") and err.splitlines()[-1] == (
        f"python -m controllers: error: the video {video} was not written: [Errno 28] No space "
        "left on device"
    )


def test_an_interrupted_episodes_failed_video_leaves_it_the_steps(tmp_path, monkeypatch):
    import imageio.v2 as imageio

    def full_disk(uri, *args, **kwargs):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(imageio, "mimwrite", full_disk)
    env = _InterruptAt(small_env("walk", render_mode="rgb_array"), 3)
    said = r"so_far.gif of the steps so far was not written: \[Errno 28\]"
    with pytest.warns(RuntimeWarning, match=said), pytest.raises(KeyboardInterrupt) as interrupt:
        run_episode(env, MPPI(MPPISettings(horizon=4, knots=2, samples=2)), 0.2, seed=0,
                    progress=False, video=tmp_path / "so_far.gif")  # fmt: skip
    assert interrupt.value.result.rewards.size == 2
    assert list(tmp_path.iterdir()) == []


def test_an_mp4_without_imageio_ffmpeg_fails_before_the_episode(tmp_path, capsys, monkeypatch):
    # imageio was checked, imageio-ffmpeg (which .mp4 needs) only met after the episode, as
    # imageio's "Could not find a backend", which does not name the extra
    monkeypatch.setitem(sys.modules, "imageio_ffmpeg", None)  # import raises ImportError
    env = small_env("walk", render_mode="rgb_array")
    planner = MPPI(MPPISettings(horizon=4, knots=2, samples=2))
    with pytest.raises(ImportError, match=r"a \.mp4 video needs imageio-ffmpeg: pip install "
                       r"'softrom\[video\]'"):  # fmt: skip
        run_episode(env, planner, 0.1, seed=0, progress=False, video=tmp_path / "a.mp4")
    assert planner.plan_ is None
    with pytest.raises(SystemExit) as exc:
        cli_main(["BeamWalk-v0", "--video", str(tmp_path / "a.mp4")])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "pip install 'softrom[video]'" in err
    # a GIF needs no ffmpeg
    run_episode(env, planner, 0.05, seed=0, progress=False, video=tmp_path / "a.gif")
    # without imageio, the command line's error is one usage line too, before the env is made
    monkeypatch.setitem(sys.modules, "imageio", None)
    monkeypatch.setitem(sys.modules, "imageio.v2", None)
    with pytest.raises(SystemExit) as exc:
        cli_main(["BeamWalk-v0", "--video", str(tmp_path / "b.gif")])
    assert exc.value.code == 2
    assert capsys.readouterr().err == ("python -m controllers: error: writing a video needs "
                                       "imageio: pip install 'softrom[video]' (imageio and "
                                       "imageio-ffmpeg)\n")  # fmt: skip


def test_an_action_wrapper_that_rescales_is_refused():
    # The planners act in the robot's units; RescaleAction would scale their actions again
    # (every action ended up clipped to the bound, with no error).
    env = small_env("walk")
    one = np.ones(env.action_space.shape, dtype=np.float32)
    wrapped = gym.wrappers.RescaleAction(env, -one, one)
    planner = MPPI(MPPISettings(horizon=4, knots=2, samples=2))
    with pytest.raises(ValueError, match="wrapped in RescaleAction, an action wrapper"):
        run_episode(wrapped, planner, 0.1, seed=0, progress=False)
    clipped = gym.wrappers.ClipAction(env)  # the same box: allowed
    assert run_episode(clipped, planner, 0.05, seed=0, progress=False).stop_reason == "time"


def test_stop_reason_tells_a_finished_episode_from_a_time_limit():
    env = small_env("walk", max_episode_steps=4)
    p = MPPI(MPPISettings(horizon=4, knots=2, samples=2))
    # The limit's last step is the episode's own last step: it ran the time it was asked for.
    assert run_episode(env, p, 0.1, seed=0, progress=False).stop_reason == "time"
    cut = run_episode(env, p, 0.2, seed=0, progress=False)
    assert cut.stop_reason == "truncated by the time limit" and cut.rewards.shape == (4,)


def test_damping_after_a_rejected_step_is_ten_times_the_largest_tried(walker, monkeypatch):
    # Multipliers in descending order: the largest is the first, not the last.
    settings = GaussNewtonSettings(horizon=4, knots=2, line_search=(100.0, 1.0), damping=0.5)
    gn = GaussNewtonShooting(settings)
    gn.reset(walker, seed=0)
    evaluate = gn.evaluate_knots

    def every_trial_worse(state, knots, horizon=None):
        ev = evaluate(state, knots, horizon)
        if len(knots) == len(settings.line_search):  # the line search's rollout
            ev = dataclasses.replace(ev, objective=ev.objective - 1.0)
        return ev

    monkeypatch.setattr(gn, "evaluate_knots", every_trial_worse)
    gn.plan(walker)
    assert gn.last_["accepted"] == ["none"]
    assert gn.damping_ == pytest.approx(0.5 * 100.0 * 10.0)
    # A long run of rejections (a minute of quadruped walking) must not overflow mu to inf
    # and the knots to NaN: mu stops at a cap, far past where the step is nil.
    gn.damping_ = 1e149
    gn.plan(walker)
    assert gn.damping_ == 1e150 and np.all(np.isfinite(gn.plan_.knots))


def test_gait_seed_picks_a_sinusoid_and_plans_carry_it(walker):
    settings = MPPISettings(horizon=8, knots=4, period=8, window=4, gait_seed=True, samples=2,
                            noise=0.0)  # fmt: skip
    p = MPPI(settings)
    p.reset(walker, seed=0)
    assert p.seed_["gait"].startswith("5Hz")
    u = p.plan_.controls()
    assert np.abs(u).max() > 0.4
    first = p.action(walker)
    np.testing.assert_allclose(first / walker.get_wrapper_attr("action_bound"), u[0])
    np.testing.assert_allclose(p.plan_.controls()[:7], u[1:], atol=1e-14)


def test_the_gait_seed_knots_sample_the_chosen_sinusoid_scored_over_seed_horizon(walker):
    # The seed's knots are the chosen gait, A sin(2 pi f t_k + phi) clipped to the bound, at the
    # knot times t_k = k P / K of the chosen cycle P (in seconds: times dt) and f = 1 / (P dt);
    # each candidate is scored over seed_horizon steps. (Without dt the knots would sample
    # another frequency; with the settings' period for every cycle's f, a seed_periods cycle
    # would be sampled at the wrong one; with the plan's horizon, seed_horizon ignored.) K = 4:
    # at 40 Hz control a knot time in steps, not seconds, gives the same phases for K = 3.
    settings = MPPISettings(horizon=12, knots=4, period=6, gait_seed=True, seed_horizon=10,
                            seed_periods=(4,), seed_amplitudes=(0.5, 1.5), samples=2,
                            threads=1)  # fmt: skip
    planner = MPPI(settings)
    scored = []
    real = planner._evaluate_controls

    def favour_last(state, u, horizon):
        ev = real(state, u, horizon)
        scored.append(u.copy())
        objective = np.zeros(u.shape[0])
        objective[-1] = 1.0  # the 4-step cycle's last gait (A = 1.5: clipped knots)
        return dataclasses.replace(ev, objective=objective)

    planner._evaluate_controls = favour_last
    planner.reset(walker, seed=0)
    dt = walker.get_wrapper_attr("dt")
    gait = gait_grid(3, (1.0 / (4 * dt),), settings.seed_amplitudes)[-1]
    knots = np.clip(gait.controls(4, dt, 1.0), -1.0, 1.0)  # t_k = k (4 / 4) dt
    assert np.abs(gait.controls(4, dt, 1.0)).max() > 1.0  # (some clipped)
    assert planner.plan_.period == 4 and planner.seed_["gait"] == gait.label()
    np.testing.assert_allclose(planner.plan_.knots, knots, rtol=0, atol=1e-12)
    (u,) = scored  # one batched rollout
    assert u.shape == (2 * len(gait_grid(3, (1.0,), (0.5, 1.5))), 10, 3)
    trial = SplinePlan(10, 4, 3, period=4)
    np.testing.assert_allclose(u[-1], np.clip(trial.controls(knots), -1, 1), rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    ("cls", "kwargs", "message"),
    [
        (PlannerSettings, {"horizon": 0}, "horizon must be an integer >= 1, got 0"),
        (PlannerSettings, {"horizon": 4, "knots": 5}, r"knots = 5 exceeds the horizon \(4"),
        (PlannerSettings, {"knots": 0}, "knots must be an integer >= 1, got 0"),
        (PlannerSettings, {"period": 4, "knots": 6}, r"knots = 6 exceeds the period \(4"),
        (PlannerSettings, {"window": 50}, r"window = 50 exceeds the horizon \(40\)"),
        (PlannerSettings, {"gait_seed": True}, "gait_seed needs a periodic plan"),
        (MPPISettings, {"samples": 1}, "samples must be an integer >= 2, got 1"),
        (MPPISettings, {"samples": 2.5}, "samples must be an integer >= 2, got 2.5"),
        (MPPISettings, {"temperature": 0.0}, "temperature must be a finite number > 0, got 0.0"),
        (MPPISettings, {"temperature": float("nan")}, "temperature must be .* got nan"),
        (MPPISettings, {"noise": -0.1}, "noise must be a finite number >= 0, got -0.1"),
        (MPPISettings, {"noise": ()}, r"noise must be .*one per control dimension\), got \(\)"),
        (MPPISettings, {"noise": (0.1, -0.2)}, r"one per control .* got \(0.1, -0.2\)"),
        (MPPISettings, {"noise": (0.1, "x")}, "noise must be a sequence of numbers"),
        (MPPISettings, {"noise_decay": 0.0}, "noise_decay must be a finite number > 0, got 0.0"),
        (MPPISettings, {"noise_decay": 1.5}, r"noise_decay must be in \(0, 1\], got 1.5"),
        (GaussNewtonSettings, {"fd_step": 0.0}, "fd_step must be a finite number > 0, got 0.0"),
        (GaussNewtonSettings, {"line_search": ()}, r"line_search must be positive numbers"),
        (GaussNewtonSettings, {"line_search": [1, "x"]}, r"line_search must be a sequence of"),
        (PlannerSettings, {"seed_amplitudes": "ab"}, "seed_amplitudes must be a sequence of"),
        (PlannerSettings, {"seed_amplitudes": (0.5, -1)}, r"seed_amplitudes must be positive "
                                                          r"numbers, got \(0.5, -1.0\)"),
        (PlannerSettings, {"seed_amplitudes": ()}, r"positive numbers, got \(\)"),
        (PlannerSettings, {"seed_amplitudes": (1.0, 0.0)}, r"positive numbers, got \(1.0, 0.0\)"),
        (PlannerSettings, {"kind": "quintic"}, r"kind must be one of \['cubic', 'linear'\], got "
                                               "'quintic'"),
        (GaussNewtonSettings, {"fd_step": 0.6}, r"fd_step must be <= 0.5 \(units of the bound\), "
                                                "got 0.6"),
        (CostWeights, {"lateral": "1"}, "weight lateral must be a number, got '1'"),
        (CostWeights, {"effort": True}, "weight effort must be a number, got True"),
    ],
)  # fmt: skip
def test_invalid_settings_raise_value_errors_naming_the_value(cls, kwargs, message):
    with pytest.raises(ValueError, match=message):
        cls(**kwargs)


def test_settings_take_their_boundary_values():
    """The refusals above stop at their bounds: fd_step <= 0.5 includes 0.5."""
    assert GaussNewtonSettings(fd_step=0.5).fd_step == 0.5


def test_invalid_weights_and_inputs_raise_clear_errors(walker):
    with pytest.raises(ValueError, match="weight lateral must be finite and >= 0, got -1.0"):
        CostWeights(lateral=-1.0)
    with pytest.raises(ValueError, match="weight effort must be finite and >= 0, got inf"):
        CostWeights(effort=float("inf"))
    with pytest.raises(TypeError, match=r"must be a controllers\.CostWeights\(.*got \{'lat"):
        PlannerSettings(weights={"lateral": 1.0})
    with pytest.raises(TypeError, match="settings must be MPPISettings, got GaussNewtonSettings"):
        MPPI(GaussNewtonSettings())
    with pytest.raises(RuntimeError, match=r"MPPI.reset\(env, seed\) must be called first"):
        MPPI().plan(walker)
    bound_to_walker = MPPI(MPPISettings(horizon=4, knots=2, samples=2))
    bound_to_walker.reset(walker, seed=0)
    other = small_env("walk")
    other.reset(seed=0)
    with pytest.raises(ValueError, match="MPPI was reset on another env"):
        bound_to_walker.plan(other)
    with pytest.raises(ValueError, match="MPPI was reset on another env"):
        bound_to_walker.action(other)
    with pytest.raises(ValueError, match="replan_every must be a positive integer, got 0"):
        run_episode(walker, MPPI(), 1.0, replan_every=0)
    with pytest.raises(ValueError, match="no defaults for 'softrom_gym/SoftRobot-v0'") as e:
        default_settings("softrom_gym/SoftRobot-v0", "mppi")
    assert "controllers.planner_for(env_id, planner)" in str(e.value)  # where to go instead
    with pytest.raises(ValueError, match=r"unknown planner 'ilqr'; registered: gn, mppi"):
        default_planner("CrossWalk-v0", "ilqr")
    with pytest.raises(TypeError, match="planners need a softrom_gym env"):
        MPPI().reset(gym.make("CartPole-v1"))
    with pytest.raises(TypeError, match="gait_seed must be True or False, got 'no'"):
        PlannerSettings(gait_seed="no", period=10)
    with pytest.raises(TypeError, match="restart_damping must be True or False, got 1"):
        GaussNewtonSettings(restart_damping=1)
    # lists are stored as tuples: the frozen settings stay hashable
    settings = GaussNewtonSettings(line_search=[1, 10], seed_amplitudes=np.array([0.5]))
    assert settings.line_search == (1.0, 10.0) and settings.seed_amplitudes == (0.5,)
    assert hash(settings) == hash(GaussNewtonSettings(line_search=(1, 10), seed_amplitudes=[0.5]))
    # a shorter horizon than the benchmark's scoring window says so (window was not given)
    with pytest.raises(ValueError, match=r"horizon = 10 is shorter than the default window"):
        default_planner("CrossSwim-v0", "mppi", horizon=10)
    assert (
        default_planner("CrossSwim-v0", "mppi", horizon=10, window=None)[0].settings.window is None
    )
    # a horizon as long as the window is not shorter than it: accepted
    assert default_planner("CrossSwim-v0", "mppi", horizon=20)[0].settings.window == 20


def test_evaluate_checks_what_it_is_given(walker):
    planner = MPPI(MPPISettings(horizon=4, knots=2, samples=2))
    planner.reset(walker, seed=0)
    state = walker.get_wrapper_attr("get_state")()
    bound = walker.get_wrapper_attr("action_bound")
    out = walker.get_wrapper_attr("rollout")(state, np.zeros((2, 4, 3)))
    args = (state.q[:3], np.array([1.0, 0.0, 0.0]), 0.025, CostWeights())
    assert evaluate(out, np.zeros((2, 4, 3)), *args).objective.shape == (2,)
    with pytest.raises(ValueError, match=r"controls has shape \(2, 3, 3\), expected \(2, 4, C\)"):
        evaluate(out, np.zeros((2, 3, 3)), *args)
    with pytest.raises(ValueError, match="units of the action bound, within"):
        evaluate(out, np.full((2, 4, 3), bound), *args)
    for window in (-3, 0):  # (0 would score every plan 0: R over no steps)
        with pytest.raises(ValueError, match=f"window must be an integer >= 1 or None, got "
                           f"{window}"):  # fmt: skip
            evaluate(out, np.zeros((2, 4, 3)), *args, window=window)
    # (dt <= 0 gave NaN or -inf objectives; a direction of length 10 scaled R tenfold)
    for dt in (0.0, -0.025, float("nan"), True):
        with pytest.raises(ValueError, match=f"dt must be a finite number > 0 .*got {dt!r}"):
            evaluate(out, np.zeros((2, 4, 3)), state.q[:3], args[1], dt, CostWeights())
    for direction in ([10.0, 0.0, 0.0], [1.0, 0.0], [np.nan, 0.0, 0.0]):
        with pytest.raises(ValueError, match="direction must be a unit vector of shape"):
            evaluate(out, np.zeros((2, 4, 3)), state.q[:3], direction, 0.025, CostWeights())


def test_evaluate_is_r_minus_lambda_of_the_module_docstring():
    # Per-step terms made up by hand (two rollouts of H = 5 steps, the second losing its last
    # two steps to a divergence), every weight non-zero and distinct, scored term by term as
    # controllers.cost's docstring defines R and Λ (com[t] is the centre of mass after step
    # t + 1, so c_{H-W} is com[H - W - 1]). The same arithmetic in another order, so the two
    # agree to round-off (1e-12 of terms of order 1).
    rng = np.random.default_rng(11)
    b, h, dt = 2, 5, 0.025
    out = {"com": rng.normal(size=(b, h, 3)), "theta": 0.1 * rng.normal(size=(b, h, 3)),
           "lost": np.array([[0, 0, 0, 0, 0], [0, 0, 0, 1, 1]])}  # fmt: skip
    u = rng.uniform(-1.0, 1.0, (b, h, 3))
    c0, d = rng.normal(size=3), np.array([0.6, 0.8, 0.0])
    side = np.array([-0.8, 0.6, 0.0])  # d turned a quarter left in the ground plane
    w = CostWeights(orientation=2.0, lateral=3.0, effort=0.5, divergence=4.0, velocity=0.7)
    for window in (None, 2, 5):
        ev = evaluate(out, u, c0, d, dt, w, window)
        for i in range(b):
            c = out["com"][i]
            gained = d @ (c[-1] - (c0 if window in (None, h) else c[h - 1 - window]))
            reward = gained + w.velocity * d @ (c[-1] - c[-2]) / dt
            smooth = sum(dt * (w.orientation * out["theta"][i, t] @ out["theta"][i, t]
                               + w.lateral * (side @ (c[t] - c0)) ** 2
                               + w.effort * u[i, t] @ u[i, t]) for t in range(h))  # fmt: skip
            lost = out["lost"][i].sum()
            assert ev.reward[i] == pytest.approx(reward, rel=1e-12, abs=1e-12), window
            assert ev.smooth[i] == pytest.approx(smooth, rel=1e-12), window
            assert ev.lost[i] == lost
            assert ev.objective[i] == pytest.approx(reward - smooth - 4.0 * lost, rel=1e-12)
            # Gauss-Newton linearises the residuals: |r|^2 is the smooth part exactly
            assert ev.residuals[i] @ ev.residuals[i] == pytest.approx(smooth, rel=1e-12)


def test_defaults_are_valid_for_every_benchmark():
    for name in softrom_gym.BENCHMARKS:
        for planner in ("mppi", "gn"):
            settings, every = default_settings(f"softrom_gym/{name}", planner)
            assert settings.horizon * 0.025 >= 1.0  # a gait cycle or more
            assert 1 <= every <= settings.horizon


def test_cli_runs_an_episode_and_rejects_bad_arguments(capsys):
    assert cli_main(["BeamWalk-v0", "--planner", "gn", "--seconds", "0.05", "--horizon", "4",
                     "--window", "all", "--iterations", "1", "--no-progress"]) == 0  # fmt: skip
    line = capsys.readouterr().out.strip()
    assert line.startswith("BeamWalk-v0 gn: 0.05 s") and "planning real-time factor" in line
    # a horizon shorter than the default window is named, as in Python, not silently widened
    with pytest.raises(SystemExit):
        cli_main(["BeamWalk-v0", "--horizon", "4", "--no-progress"])
    assert "horizon = 4 is shorter than the default window" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        cli_main(["Pendulum-v1"])
    assert "Pendulum-v1: not a registered softrom env" in capsys.readouterr().err
    assert "distance t=0..0.05 s" in line  # shorter than the settling time: the whole episode
    with pytest.raises(SystemExit) as exc:
        cli_main(["BeamWalk-v0", "--samples", "0"])
    assert exc.value.code == 2
    assert "samples must be an integer >= 2, got 0" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exc:
        cli_main(["BeamWalk-v0", "--mpc", "noise=0.1:0.2"])
    assert exc.value.code == 2
    assert "noise has 2 standard deviations, one per control dimension, but the env has C = 3" in (
        capsys.readouterr().err
    )
    for bad in (["--seconds", "0"], ["--seconds", "nan"]):
        with pytest.raises(SystemExit) as exc:
            cli_main(["BeamWalk-v0", *bad])
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert f"--seconds must be a positive number, got {float(bad[1])}" in err
    # options only as spelled, as rbbo takes them; a usage error is one line, as rbbo's are
    with pytest.raises(SystemExit) as exc:
        cli_main(["BeamWalk-v0", "--second", "1"])
    assert exc.value.code == 2
    err = "python -m controllers: error: unrecognized arguments: --second 1 (did you mean "
    err += "--seconds for --second? python -m controllers --help lists the options)\n"
    assert capsys.readouterr().err == err
    # one KEY=VALUE per --env-kwarg: its help showed two joined by a comma, which sets robot
    # to "my_robot.stl,task=swim"
    help_ = " ".join(cli_parser().format_help().split())
    assert "--env-kwarg robot=my_robot.stl --env-kwarg task=swim" in help_
    # and the description said only "Watch a planner walk", not what it prints
    assert "prints a one-line summary: distance between t = 2 s (t = 0 in episodes" in help_
    assert ":mod:" not in help_ and "``" not in help_
    with pytest.raises(SystemExit) as exc:
        cli_main([])
    assert exc.value.code == 2
    err = "python -m controllers: error: the following arguments are required: env_id\n"
    assert capsys.readouterr().err == err


def test_cli_runs_a_robot_of_your_own(capsys):
    args = ["SoftRobot-v0", "--env-kwarg", "robot=beam", "--env-kwarg", "sim_dim=6",
            "--seconds", "0.05", "--horizon", "4", "--window", "4", "--no-progress"]  # fmt: skip
    assert cli_main(args) == 0
    assert capsys.readouterr().out.startswith("SoftRobot-v0 mppi: 0.05 s")
    with pytest.raises(SystemExit) as exc:
        cli_main(["SoftRobot-v0", "--env-kwarg", "robot=missing.stl"])
    assert exc.value.code == 2
    assert "mesh file 'missing.stl' does not exist" in capsys.readouterr().err


def test_planner_for_uses_tuned_defaults_only_where_they_exist():
    tuned, every = planner_for("softrom_gym/CrossWalk-v0", "mppi", threads=1)
    settings, tuned_every = default_settings("softrom_gym/CrossWalk-v0", "mppi")
    assert every == tuned_every and tuned.settings == settings.replace(threads=1)
    # a robot of one's own: the shared defaults around a 2 Hz gait, replanning every cycle
    own, every = planner_for("softrom_gym/SoftRobot-v0", "gn", threads=1)
    assert isinstance(own, GaussNewtonShooting) and every == 20
    assert own.settings.period == 20 and own.settings.gait_seed and own.settings.threads == 1
    assert own.settings.explore == default_settings("CrossWalk-v0", "gn")[0].explore
    assert has_defaults("CrossSwim-v0") and not has_defaults("SoftRobot-v0")
    with pytest.raises(ValueError, match="unknown planner 'ilqr'"):
        planner_for("softrom_gym/SoftRobot-v0", "ilqr")
    for env_id in ("softrom_gym/SoftRobot-v0", "softrom_gym/CrossWalk-v0"):
        with pytest.raises(TypeError, match=r"unknown MPPISettings setting 'bogus'; valid: \["):
            planner_for(env_id, "mppi", bogus=3)


def test_more_knots_on_a_robot_of_ones_own_drop_the_shared_cycles_too_short_for_them():
    # The shared defaults' gait seed also tries cycles of 13.3 and 10 steps; knots=12 was
    # refused with "seed_periods must be ... >= knots", a setting the caller never gave.
    # Cycles too short for the knots asked for are dropped, as at another control period.
    for knots, kept in ((6, (40 / 3, 10.0)), (12, (40 / 3,)), (14, ())):
        settings = planner_for("softrom_gym/SoftRobot-v0", "mppi", knots=knots)[0].settings
        assert settings.knots == knots and settings.seed_periods == pytest.approx(kept)
        assert settings.gait_seed and settings.period == 20
    # cycles the caller gives are the caller's: still refused when too short
    with pytest.raises(ValueError, match=r"seed_periods must be .* >= knots = 12, got \(10.0,\)"):
        planner_for("softrom_gym/SoftRobot-v0", "mppi", knots=12, seed_periods=(10,))


def test_defaults_keep_their_seconds_at_another_control_period():
    # Tuned in env steps of 0.025 s; at frame_skip = 10 (0.05 s) the same seconds are half
    # the steps, and the benchmark's own period passes through unchanged.
    base, base_every = planner_for("softrom_gym/TripodWalk-v0", "gn")
    assert planner_for("softrom_gym/TripodWalk-v0", "gn", dt=0.025)[0].settings == base.settings
    slow, every = planner_for("softrom_gym/TripodWalk-v0", "gn", dt=0.05)
    s, b = slow.settings, base.settings
    assert s.period * 0.05 == pytest.approx(b.period * 0.025)
    assert (s.horizon, s.window, s.seed_horizon, every) == (20, 14, 60, 14)
    assert (b.horizon, b.window, b.seed_horizon, base_every) == (40, 27, 120, 27)
    assert s.knots == b.knots == 6 and s.fd_step == b.fd_step  # not times
    # a cycle of fewer steps than knots: one knot a step; changes are in the env's steps
    quad = planner_for("softrom_gym/QuadrupedWalk-v0", "mppi", dt=0.05)[0].settings
    assert (quad.period, quad.knots) == (5.0, 5)
    # a cycle of 3.33 steps (the tripod's 3 Hz at 0.1 s) takes 3 knots, the whole steps in it
    # (rounded up to 4, more knots than steps in the cycle, the settings would refuse it)
    tripod = planner_for("softrom_gym/TripodWalk-v0", "gn", dt=0.1)[0].settings
    assert tripod.period == pytest.approx(10 / 3) and tripod.knots == 3
    own = planner_for("softrom_gym/SoftRobot-v0", "mppi", dt=0.0125, horizon=100)[0].settings
    assert (own.period, own.horizon, own.window) == (40.0, 100, 40)
    with pytest.raises(ValueError, match=r"default gait cycle \(0.25 s\) is 1.25 env steps"):
        planner_for("softrom_gym/QuadrupedWalk-v0", "mppi", dt=0.2)
    with pytest.raises(ValueError, match="must be a positive number, got -1"):
        default_planner("softrom_gym/QuadrupedWalk-v0", "mppi", dt=-1)


def test_control_period_is_read_without_building_the_env():
    from softrom_gym.registration import control_period

    assert control_period("softrom_gym/CrossSwim-v0") == pytest.approx(0.025)
    assert control_period("softrom_gym/CrossSwim-v0", frame_skip=10) == pytest.approx(0.05)
    # numpy's integers as the env takes them (an np.int64 frame_skip read as None)
    assert control_period("softrom_gym/CrossSwim-v0", frame_skip=np.int64(10)) == pytest.approx(
        0.05
    )
    assert control_period("softrom_gym/CrossSwim-v0", frame_skip=True) is None
    assert control_period("softrom_gym/SoftRobot-v0", dt=0.002) == pytest.approx(0.01)
    assert control_period("softrom_gym/CrossSwim-v0", dt="x") is None  # the env names it
    assert control_period("CartPole-v1") is None


def test_the_gait_seed_picks_the_cycle_among_seed_periods(walker):
    # every (cycle, gait) candidate is scored in one rollout; the best one's cycle becomes
    # the plan's period for the episode
    settings = MPPISettings(horizon=12, knots=3, period=6, gait_seed=True, seed_horizon=12,
                            seed_periods=(4, 3), samples=2, threads=1)  # fmt: skip
    planner = MPPI(settings)
    scored = []
    real = planner._evaluate_controls

    def favour_last(state, u, horizon):
        ev = real(state, u, horizon)
        scored.append(u.shape[0])
        objective = np.zeros(u.shape[0])
        objective[-1] = 1.0  # the last candidate: the 3-step cycle's last gait
        return dataclasses.replace(ev, objective=objective)

    planner._evaluate_controls = favour_last
    planner.reset(walker, seed=0)
    per_cycle = len(gait_grid(3, (1.0,), settings.seed_amplitudes))
    assert scored == [3 * per_cycle]  # three cycles' candidates, one batched rollout
    assert planner.plan_.period == 3 and planner.plan_.horizon == 12
    assert planner.seed_["period"] == 3 and planner.settings.period == 6  # as given
    with pytest.raises(ValueError, match=r"seed_periods must be numbers of env steps >= knots"):
        MPPISettings(knots=6, period=20, gait_seed=True, seed_periods=(4,))
    with pytest.raises(ValueError, match="set gait_seed=True"):
        MPPISettings(knots=3, period=20, seed_periods=(10,))
    own = planner_for("softrom_gym/SoftRobot-v0", "mppi")[0].settings
    assert own.seed_periods == (40 / 3, 10.0)  # a robot of your own: 2, 3 and 4 Hz tried
    assert default_settings("softrom_gym/TripodWalk-v0", "mppi")[0].seed_periods == ()


def test_an_unversioned_benchmark_id_gets_its_tuned_planner():
    for env_id in ("softrom_gym/CrossWalk", "CrossWalk"):
        assert has_defaults(env_id)
        planner, every = planner_for(env_id, "mppi")
        tuned, tuned_every = planner_for("softrom_gym/CrossWalk-v0", "mppi")
        assert (planner.settings, every) == (tuned.settings, tuned_every)


def test_reset_refuses_an_env_the_planner_was_not_made_for():
    env = gym.make("softrom_gym/CrossSwim-v0", frame_skip=10)
    planner, _ = planner_for("softrom_gym/CrossSwim-v0", "mppi")  # for 0.025 s steps
    with pytest.raises(ValueError, match=r"a 0.025 s control period, but the env steps 0.05 s"):
        planner.reset(env, seed=0)
    planner, _ = planner_for("softrom_gym/CrossSwim-v0", "mppi", dt=env.get_wrapper_attr("dt"))
    planner.reset(env, seed=0)  # made for it: accepted
    # a planner made by hand has no period to check
    MPPI(MPPISettings(horizon=4, knots=2)).reset(env, seed=0)
    # the actions are f_c: an action wrapper that rescales them is refused here too, not only
    # by run_episode (a hand-written receding-horizon loop would send wrong actions)
    one = np.ones(3, dtype=np.float32)
    rescaled = gym.wrappers.RescaleAction(gym.make("softrom_gym/CrossSwim-v0"), -one, one)
    planner, _ = planner_for("softrom_gym/CrossSwim-v0", "mppi")
    with pytest.raises(ValueError, match="wrapped in RescaleAction, an action wrapper"):
        planner.reset(rescaled, seed=0)
    with pytest.raises(ValueError, match="seed must be a non-negative integer or None, got -1"):
        planner.reset(gym.make("softrom_gym/CrossSwim-v0"), seed=-1)


def test_default_planner_names_a_bad_horizon_and_takes_numpy_periods():
    with pytest.raises(ValueError, match="horizon must be an integer >= 1, got -3"):
        default_planner("softrom_gym/CrossSwim-v0", "mppi", horizon=-3)
    planner, every = default_planner("softrom_gym/CrossSwim-v0", "mppi", dt=np.float32(0.05))
    assert planner.dt == pytest.approx(0.05) and every == 10
    planner.reset(gym.make("softrom_gym/CrossSwim-v0", frame_skip=10), seed=0)  # its period


def test_r_is_the_distance_whatever_a_reward_wrapper_does():
    planner, every = planner_for("softrom_gym/BeamWalk-v0", "mppi", samples=2, horizon=10,
                                 window=None, seed_horizon=10)  # fmt: skip
    plain = run_episode(gym.make("softrom_gym/BeamWalk-v0"), planner, 0.5, every, progress=False)
    assert plain.R == pytest.approx(plain.rewards.sum(), abs=1e-12)
    scaled = gym.wrappers.TransformReward(gym.make("softrom_gym/BeamWalk-v0"), lambda r: 100 * r)
    wrapped = run_episode(scaled, planner, 0.5, every, progress=False)
    np.testing.assert_allclose(wrapped.rewards, 100 * plain.rewards)
    assert wrapped.R == plain.R != 0.0


class _InterruptAt(gym.Wrapper):
    """Raises KeyboardInterrupt (as Ctrl-C would) at the n-th step."""

    def __init__(self, env, n):
        super().__init__(env)
        self.n, self.calls = n, 0

    def step(self, action):
        self.calls += 1
        if self.calls == self.n:
            raise KeyboardInterrupt
        return self.env.step(action)


def test_an_interrupted_episode_hands_back_what_it_recorded(tmp_path, capsys, monkeypatch):
    planner, every = planner_for("softrom_gym/BeamWalk-v0", "mppi", samples=2, horizon=10,
                                 window=None, seed_horizon=10)  # fmt: skip
    env = _InterruptAt(gym.make("softrom_gym/BeamWalk-v0", render_mode="rgb_array"), 6)
    video = tmp_path / "so_far.mp4"
    with pytest.raises(KeyboardInterrupt) as interrupt:
        run_episode(env, planner, 1.0, every, progress=False, video=video)
    assert video.stat().st_size > 500  # the frames so far, written
    result = interrupt.value.result
    assert result.stop_reason == "interrupted" and result.rewards.size == 5
    assert result.com.shape == (6, 3) and len(result.states) == 6
    assert result.actions.shape == (5, 3) and result.R == pytest.approx(result.rewards.sum())

    # interrupted in the planner's set-up: nothing recorded, and the interrupt says so
    # (before, it carried no result at all)
    def interrupted_reset(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(planner, "reset", interrupted_reset)
    with pytest.raises(KeyboardInterrupt) as interrupt:
        run_episode(env, planner, 1.0, every, progress=False)
    assert interrupt.value.result is None
    monkeypatch.undo()
    # the command line prints it and exits 130, as rbbo does
    import controllers.episode as episode  # (main imports run_episode from it when it runs)

    original = episode.run_episode

    def interrupted(env, *args, **kwargs):
        return original(_InterruptAt(env, 3), *args, **kwargs)

    monkeypatch.setattr(episode, "run_episode", interrupted)
    code = cli_main(["BeamWalk-v0", "--seconds", "1", "--samples", "2", "--no-progress"])
    out, err = capsys.readouterr()
    assert code == 130 and "interrupted" in err
    assert out.startswith("BeamWalk-v0 mppi: 0.05 s") and "(stopped: interrupted)" in out


def test_the_command_line_raises_the_time_limit_to_the_seconds_asked(capsys, monkeypatch):
    import controllers.episode as episode

    seen = {}

    def record(env, planner, seconds, **kwargs):
        seen["limit"] = env.spec.max_episode_steps
        raise KeyboardInterrupt  # (nothing to run: the limit is what is checked)

    monkeypatch.setattr(episode, "run_episode", record)
    assert cli_main(["BeamWalk-v0", "--env-kwarg", "frame_skip=1", "--seconds", "3"]) == 130
    assert seen["limit"] == 600  # 3 s of 5 ms steps; the registration's 400 would stop at 2 s


def test_planner_settings_from_the_command_line(capsys, monkeypatch):
    import argparse

    import controllers.episode as episode
    from controllers.defaults import parse_changes

    parsed = parse_changes("horizon=8,window=none,noise=0.3,kind=linear,gait_seed=false")
    assert parsed == {"horizon": 8, "window": None, "noise": 0.3, "kind": "linear",
                      "gait_seed": False}  # fmt: skip
    assert parse_changes("noise=0.3:0.1:1,kind=a:b") == {"noise": (0.3, 0.1, 1.0), "kind": "a:b"}
    with pytest.raises(argparse.ArgumentTypeError, match="expected key=value pairs, got 'x'"):
        parse_changes("horizon=8,x")
    # one number for a tuple setting is a tuple of one (a command line has no other way to
    # give one): seed_periods=10 was refused as "must be a sequence of numbers"
    gn, _ = planner_for(
        "softrom_gym/BeamWalk-v0",
        "gn",
        **parse_changes("seed_periods=20,seed_amplitudes=1,line_search=1"),
    )
    assert (gn.settings.seed_periods, gn.settings.seed_amplitudes,
            gn.settings.line_search) == ((20.0,), (1.0,), (1.0,))  # fmt: skip
    assert hash(gn.settings) == hash(gn.settings.replace(line_search=(1.0,)))
    with pytest.raises(ValueError, match="line_search must be a sequence of numbers"):
        GaussNewtonSettings(line_search=True)
    seen = {}

    def record(env, planner, seconds, **kwargs):
        seen["settings"] = planner.settings
        raise KeyboardInterrupt  # (nothing to run: the settings are what is checked)

    monkeypatch.setattr(episode, "run_episode", record)
    args = ["BeamWalk-v0", "--mpc", "noise=0.3,temperature=0.05", "--mpc", "samples=8",
            "--samples", "4"]  # fmt: skip
    assert cli_main(args) == 130
    settings = seen["settings"]
    # --mpc sets any setting; the dedicated flags win over it
    assert (settings.noise, settings.temperature, settings.samples) == (0.3, 0.05, 4)
    with pytest.raises(SystemExit):
        cli_main(["BeamWalk-v0", "--mpc", "nois=0.3"])
    assert "unknown MPPISettings setting 'nois'" in capsys.readouterr().err


def test_predict_is_what_the_plan_then_does_and_changes_nothing():
    env = gym.make("softrom_gym/BeamWalk-v0")
    env.reset(seed=0)
    planner, _ = planner_for("softrom_gym/BeamWalk-v0", "mppi", samples=2)
    planner.reset(env, seed=0)
    planner.plan(env)
    last, knots = dict(planner.last_), planner.plan_.knots.copy()
    predicted = planner.predict(env)
    h = planner.settings.horizon
    assert predicted["controls"].shape == (h, 3) and predicted["com"].shape == (h, 3)
    assert planner.last_ == last and np.array_equal(planner.plan_.knots, knots)
    # its objective is R - Λ over the settings' window, as a replan scores the plan (with R
    # over the whole horizon it would be another number than the one the planner maximises)
    state = env.get_wrapper_attr("get_state")()
    assert planner.settings.window < h
    scored = planner.evaluate_knots(state, planner.plan_.knots[None]).objective[0]
    assert predicted["objective"] == pytest.approx(scored, rel=1e-9, abs=1e-12)
    # the plan played out step by step is the prediction, to the bit (one simulator)
    for t in range(3):
        action = planner.action(env)
        np.testing.assert_array_equal(action, predicted["controls"][t])
        _, reward, *_, info = env.step(action)
        np.testing.assert_array_equal(info["com"], predicted["com"][t])
        assert reward == predicted["rewards"][t]
    assert np.isfinite(predicted["objective"])


def test_an_open_plan_sends_between_replans_the_controls_its_replan_scored(walker):
    # action() re-sampled an open plan's knots at every step: by the tenth step after a replan
    # it sent f_c half the bound away from the plan the replan had optimised
    planner = MPPI(MPPISettings(horizon=40, knots=6, samples=4, noise=0.8, threads=1))
    planner.reset(walker, seed=0)
    bound = walker.get_wrapper_attr("action_bound")
    for _ in range(2):  # the second replan warm-starts from the clock the first left
        planner.plan(walker)
        scored = bound * np.clip(planner.plan_.controls(), -1.0, 1.0)
        state = walker.get_wrapper_attr("get_state")()
        sent = [planner.action(walker) for _ in range(10)]
        walker.get_wrapper_attr("set_state")(state)  # (the env itself stays where it was)
        np.testing.assert_allclose(np.array(sent), scored[:10], rtol=0, atol=1e-12 * bound)
    assert planner.plan_.offset == 10.0  # the steps since the last replan
    planner.plan(walker)
    assert planner.plan_.offset == 0.0


def test_the_command_line_takes_a_control_basis_file(tmp_path, capsys, monkeypatch):
    import controllers.episode as episode

    seen = {}

    def record(env, planner, seconds, **kwargs):
        seen["basis"] = env.get_wrapper_attr("control_basis")
        raise KeyboardInterrupt  # (nothing to run: the basis is what is checked)

    monkeypatch.setattr(episode, "run_episode", record)
    np.save(tmp_path / "b.npy", 2.0 * np.eye(20)[:, :2])  # full rank: orthonormalised
    assert cli_main(["BeamWalk-v0", "--control-basis", str(tmp_path / "b.npy")]) == 130
    np.testing.assert_allclose(seen["basis"], np.eye(20)[:, :2])
    with pytest.raises(SystemExit):
        cli_main(["BeamWalk-v0", "--control-basis", str(tmp_path / "none.npy")])
    assert "control_basis file" in capsys.readouterr().err
    np.save(tmp_path / "t.npy", np.eye(20)[:2])
    with pytest.raises(SystemExit):
        cli_main(["BeamWalk-v0", "--control-basis", str(tmp_path / "t.npy")])
    assert "B_c is M x C with M >= C" in capsys.readouterr().err


def test_a_bad_replan_interval_is_named_before_the_env_is_built(capsys, monkeypatch):
    """--replan-every 0 was refused only after gym.make: for a robot of your own, after minutes
    of building its B_r and cubature, or not at all when the env failed first."""
    monkeypatch.setattr(gym, "make", lambda *a, **k: pytest.fail("the env was built"))
    for bad in ("0", "-2"):
        with pytest.raises(SystemExit) as exc:
            cli_main(["SoftRobot-v0", "--env-kwarg", "robot=missing.stl", "--replan-every", bad])
        assert exc.value.code == 2
        assert capsys.readouterr().err.splitlines()[-1] == (
            f"python -m controllers: error: --replan-every must be >= 1, got {bad}"
        )


def test_the_studies_name_bad_arguments_before_building_an_env(monkeypatch):
    """A generator of C's was reported as "got []" (the check had consumed it), C = 1.5 was
    studied as C = 1, repeats=True ran once, and seconds="10" failed in numpy's isfinite."""
    from controllers.studies import gn_cost_against_c, reward_against_c

    monkeypatch.setattr(gym, "make", lambda *a, **k: pytest.fail("an env was built"))
    for cs, shown in (((c for c in (2, 0)), r"\[2, 0\]"), ([1.5], r"\[1.5\]"), ([], r"\[\]"),
                      ([True], r"\[True\]")):  # fmt: skip
        with pytest.raises(ValueError, match=f"control dimensions must be integers >= 1, got "
                           f"{shown}"):  # fmt: skip
            gn_cost_against_c(cs=cs)
        with pytest.raises(ValueError, match="control dimensions must be integers"):
            reward_against_c(cs=cs if isinstance(cs, list) else [2, 0])
    for repeats in (0, True, 2.0):
        with pytest.raises(ValueError, match=f"repeats must be an integer >= 1, got {repeats!r}"):
            gn_cost_against_c(cs=[1], repeats=repeats)
    for seconds in (0, float("inf"), "10", None):
        with pytest.raises(ValueError, match=f"seconds must be a positive number, got "
                           f"{seconds!r}"):  # fmt: skip
            reward_against_c(seconds=seconds)
    for start in (-1, 10.0, "2"):
        with pytest.raises(ValueError, match=rf"start must lie in \[0, seconds = 10.0\) s, got "
                           f"{start!r}"):  # fmt: skip
            reward_against_c(seconds=10.0, start=start)
    with pytest.raises(ValueError, match="give at least one seed"):
        reward_against_c(seeds=[])


def test_reward_against_c_rows_are_each_episodes_distances(monkeypatch):
    # One row per (C, seed), an episode on the robot with C modes: R_m the distance from
    # ``start`` to the end, R_bl the same in body lengths (not R_m again), R_total_m the
    # whole episode's. The episode is made up: the rows' arithmetic is what is checked.
    import controllers.studies as studies

    seen = []

    def made_up(env, planner, seconds, **kwargs):
        seen.append((env.action_space.shape[0], kwargs["seed"], seconds))
        return _made_up_episode(body_length=0.8, planner=planner.name)

    monkeypatch.setattr(studies, "run_episode", made_up)
    rows = studies.reward_against_c("softrom_gym/BeamWalk-v0", cs=[2], seeds=[4], seconds=0.2,
                                    start=0.05)  # fmt: skip
    assert seen == [(2, 4, 0.2)]
    # (the made-up episode has no stop reason)
    assert rows == [{"C": 2, "seed": 4, "R_m": pytest.approx(0.60), "R_bl": pytest.approx(0.75),
                     "R_total_m": pytest.approx(0.64), "planner": "mppi",
                     "seconds": pytest.approx(0.2), "start": 0.05, "stop": "",
                     "threads": 2}]  # fmt: skip


def test_reward_against_c_runs_past_the_time_limit_and_scores_an_early_stop(monkeypatch):
    """The registered 10-s limit truncated a 10.5-s study episode at 10 s, and a start past the
    end (the limit, or a divergence) failed after the episode had run. A threads setting in
    planner_changes met the threads argument as a duplicate keyword."""
    import controllers.studies as studies

    limits, threads = [], []

    def diverged_at_0_2_s(env, planner, seconds, **kwargs):
        limits.append(env.spec.max_episode_steps)
        threads.append(planner.settings.threads)
        result = _made_up_episode(planner=planner.name)
        result.stop_reason = "diverged"
        return result

    monkeypatch.setattr(studies, "run_episode", diverged_at_0_2_s)
    rows = studies.reward_against_c("softrom_gym/BeamWalk-v0", cs=[2], seeds=[0], seconds=10.5,
                                    start=10.2, planner_changes={"threads": 1})  # fmt: skip
    assert limits == [420]  # 10.5 s of 0.025-s control periods, where 400 were registered
    assert threads == [1]
    assert rows[0]["R_m"] == 0.0 and rows[0]["stop"] == "diverged" and rows[0]["threads"] == 1
    assert rows[0]["R_total_m"] == pytest.approx(0.64)


def test_evaluate_knots_over_a_longer_horizon_holds_an_open_plan_and_repeats_a_cycle(walker):
    """A longer horizon made a new SplinePlan of that horizon, which spaced an open plan's knots
    over it: the same knots were scored as a plan stretched in time."""
    for period in (None, 5.0):
        planner = MPPI(MPPISettings(horizon=10, knots=4, samples=2, period=period,
                                    gait_seed=False, threads=1))  # fmt: skip
        planner.reset(walker, seed=0)
        state = walker.get_wrapper_attr("get_state")()
        knots = np.random.default_rng(1).uniform(-1, 1, (1, 4, 3))
        plan = planner.plan_
        scored = []
        planner._evaluate_controls = lambda state, u, horizon, scored=scored: scored.append(u)
        planner.evaluate_knots(state, knots, horizon=20)
        u = scored[0][0]
        assert u.shape == (20, 3)
        np.testing.assert_allclose(u[:10], np.clip(plan.controls(knots)[0], -1, 1), atol=1e-14)
        if period is None:
            np.testing.assert_allclose(u[10:], np.tile(u[9], (10, 1)), atol=1e-14)
        else:
            np.testing.assert_allclose(u[5:], u[:15], atol=1e-14)
        for horizon in (0, 2.5, True):
            with pytest.raises(ValueError, match=f"horizon must be a positive integer, got "
                               f"{horizon!r}"):  # fmt: skip
                planner.evaluate_knots(state, knots, horizon=horizon)


def test_an_episode_takes_a_numpy_integer_seed(walker):
    # validated as a seed, then handed to gymnasium's reset, which refuses numpy integers
    planner = MPPI(MPPISettings(horizon=4, knots=2, samples=2, threads=1))
    for seed in np.arange(1, 2):
        result = run_episode(walker, planner, 0.05, seed=seed, progress=False)
        assert result.seconds == pytest.approx(0.05)


def test_cli_names_more_bad_arguments_and_takes_an_unversioned_id_and_replan_interval(
    capsys, monkeypatch
):
    for argv, message in (
        (["--seed", "-1"], "--seed must be >= 0, got -1"),
        (["--window", "x"], "argument --window: expected a number of env steps or 'all', got 'x'"),
        (["--planner", "gn", "--samples", "4"],
         "--samples applies to a planner with samples (mppi), not gn"),
        (["--planner", "ilqr"], "--planner: unknown planner 'ilqr'; registered: gn, mppi "
         "(controllers.register_planner adds one), or an import path package.module:ClassName "
         "naming a Planner subclass"),
    ):  # fmt: skip
        with pytest.raises(SystemExit) as exc:
            cli_main(["BeamWalk-v0", *argv])
        assert exc.value.code == 2
        err = capsys.readouterr().err
        assert err.splitlines()[-1] == f"python -m controllers: error: {message}"
    # "BeamWalk" is its latest version, as gym.make reads it; --replan-every is the episode's
    assert cli_main(["BeamWalk", "--seconds", "0.1", "--horizon", "4", "--window", "4",
                     "--replan-every", "2", "--no-progress"]) == 0  # fmt: skip
    out = capsys.readouterr().out
    assert out.startswith("BeamWalk-v0 mppi: 0.1 s") and "2 replans" in out
    # with several versions, the latest is the highest number (v10 after v2, not by spelling)
    from controllers.__main__ import _registered

    for version in ("v2", "v10"):
        monkeypatch.setitem(gym.registry, f"softrom_gym/BeamWalk-{version}",
                            gym.spec("softrom_gym/BeamWalk-v0"))  # fmt: skip
    assert _registered("softrom_gym/BeamWalk", "BeamWalk") == "softrom_gym/BeamWalk-v10"


def test_run_episode_names_bad_arguments(walker, tmp_path):
    from controllers.planner import EnvAPI

    with pytest.raises(TypeError, match="planner must be a controllers.Planner, got str"):
        run_episode(walker, "mppi", 1.0)
    for seconds in (0, float("nan"), "1"):
        with pytest.raises(ValueError, match=f"seconds must be a positive number, got "
                           f"{seconds!r}"):  # fmt: skip
            run_episode(walker, MPPI(), seconds)
    with pytest.raises(ValueError, match="video needs an env made with render_mode='rgb_array'"):
        run_episode(walker, MPPI(), 1.0, video=tmp_path / "a.mp4")
    assert not any(tmp_path.iterdir())
    with pytest.raises(TypeError, match="env must be a gymnasium Env, got object"):
        EnvAPI(object())
    with pytest.raises(TypeError, match="settings must be GaussNewtonSettings, got MPPISettings"):
        GaussNewtonShooting(MPPISettings())
    with pytest.raises(TypeError, match="env_id must be a str .*, got 3"):
        default_settings(3, "mppi")
    with pytest.raises(ValueError, match=r"unknown planner 'ilqr'; registered: gn, mppi"):
        default_settings("CrossWalk-v0", "ilqr")


@pytest.mark.filterwarnings("ignore:.*a tetrahedron is inverted")
def test_an_episode_that_diverges_stops_there_and_says_so():
    class FullThrottle(MPPI):
        def action(self, env):
            return np.full(3, env.get_wrapper_attr("action_bound"), dtype=np.float32)

    env = gym.make("softrom_gym/SoftRobot-v0", robot="beam", action_scale=1e9)
    result = run_episode(env, FullThrottle(MPPISettings(horizon=4, knots=2, samples=2)), 1.0,
                         seed=0, progress=False)  # fmt: skip
    assert result.stop_reason == "diverged"
    assert result.rewards.shape == (1,) and result.seconds == pytest.approx(0.025)
    assert np.isfinite(result.R) and "(stopped: diverged)" in result.summary()


def test_gaits_beyond_four_modes_and_their_controls():
    from controllers import SinusoidGait, phase_orders

    # beyond C = 4 the (C - 1)! orders are too many: the two directions and all in phase
    five = 2 * np.pi * np.arange(5) / 5
    orders = phase_orders(5)
    assert len(orders) == 3
    np.testing.assert_allclose(orders[0], five)
    np.testing.assert_allclose(orders[1], -five % (2 * np.pi))
    assert orders[2] == (0.0,) * 5
    assert len(gait_grid(5, (2.0,), (0.5, 1.0))) == 6
    # up to C = 4 every order: (C - 1)! travelling and 2^(C - 1) standing waves, less those
    # that are both (C = 1, 2); at C = 4 not only the two directions and all in phase
    assert [len(phase_orders(c)) for c in (1, 2, 3, 4)] == [1, 2, 6, 14]
    for bad, error, message in ((True, TypeError, "control_dim must be an int, got True"),
                                (2.0, TypeError, "control_dim must be an int, got 2.0"),
                                (0, ValueError, "control_dim must be >= 1, got 0")):  # fmt: skip
        with pytest.raises(error, match=message):
            phase_orders(bad)
    for frequencies, amplitudes, name in (((), (1.0,), "frequencies"),
                                          ((2.0,), (-1.0,), "amplitudes"),
                                          ((2.0,), (1.0, 0.0), "amplitudes")):  # fmt: skip
        with pytest.raises(ValueError, match=f"{name} must be a non-empty list of positive"):
            gait_grid(2, frequencies, amplitudes)
    gait = SinusoidGait(2.0, 0.5, (0.0, np.pi / 2))
    u = gait.controls(3, 0.125, 4.0, t0=0.25)
    t = 0.25 + 0.125 * np.arange(3)
    expected = 0.5 * 4.0 * np.sin(2 * np.pi * 2.0 * t[:, None] + np.array([0.0, np.pi / 2]))
    np.testing.assert_allclose(u, expected, atol=1e-15)
    assert gait.label() == "2Hz A=0.5 phases=0/90"


def test_the_command_says_a_warning_in_one_line(monkeypatch, say_warning):
    # Python's display named a line inside the package and echoed its source; the command says
    # a warning as its parser says an error. (An argument list leaves the display alone.)
    import warnings

    before = warnings.showwarning
    with pytest.raises(SystemExit):
        cli_main(["BeamWalk-v0", "--seconds", "-1"])
    assert warnings.showwarning is before
    monkeypatch.setattr(sys, "argv", ["controllers", "BeamWalk-v0", "--seconds", "-1"])
    with pytest.raises(SystemExit):
        cli_main()
    assert say_warning("the gait diverged") == [
        "python -m controllers: warning: the gait diverged (RuntimeWarning)"
    ]


SCALES = [{"line_search": (1e160,)},  # mu * 1e160 > 1.8e308 once mu is at its cap
          {"damping": 1e150, "line_search": (1.0, 1e200)},
          {"damping": 1e-150, "line_search": (1e-200, 1.0)}]  # fmt: skip


@pytest.mark.parametrize("settings", SCALES)
def test_gauss_newton_damping_stays_finite_and_positive_at_any_scale(walker, settings):
    # mu * line_search overflowed to inf (a RuntimeWarning, then NaN steps) once mu had
    # reached its cap (1e150) with a multiplier above ~1e158, and underflowed to 0 below
    # ~1e-308, where a rejection's "ten times the largest tried" left mu at 0 for good
    gn = GaussNewtonShooting(GaussNewtonSettings(horizon=6, knots=2, iterations=3, **settings))
    gn.reset(walker, seed=0)
    for _ in range(2):
        gn.plan(walker)
        assert 1e-150 <= gn.damping_ <= 1e150
        assert np.isfinite(gn.plan_.knots).all()
        assert all(e >= s for s, e in gn.last_["objectives"])


def test_gauss_newton_refuses_a_damping_beyond_its_range_naming_it():
    import re

    for damping in (1e151, 1e-151):
        message = f"damping must be between 1e-150 and 1e+150 (m per unit knot^2), got {damping!r}"
        with pytest.raises(ValueError, match=re.escape(message)):
            GaussNewtonSettings(damping=damping)


def test_weights_given_on_a_command_line_are_named_as_not_settable_there(capsys):
    # --mpc weights=... read as a number or a string: the error said only "must be a
    # CostWeights, got int", which a command line cannot give
    with pytest.raises(SystemExit) as exc:
        cli_main(["BeamWalk-v0", "--mpc", "weights=1"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "weights must be a controllers.CostWeights" in err and "got 1" in err
    assert "--mpc cannot set them" in err
    with pytest.raises(TypeError, match=r"CostWeights\(orientation=, lateral=, effort="):
        MPPISettings(weights={"effort": 0.01})


@pytest.mark.parametrize("fps", [60, 100, 200])
def test_a_gif_above_50_fps_drops_frames_to_keep_real_time(fps):
    """GIF stores delays in 1/100 s and plays one under 2/100 s as 1/10 s: above 50 fps some
    frames are dropped, each kept frame lasts at least 20 ms, and the delays still add up to
    the video's running time. The existing GIF test runs at 40 fps, where no frame is
    dropped, so keeping frames 1/100 s apart (then 20-ms delays on 10-ms frames: the GIF
    played at half speed at 100 fps) passed it."""
    count = 50
    keep, delays = _gif_timing(count, fps)
    assert keep[0] == 0 and np.all(np.diff(keep) > 0) and keep[-1] < count
    assert len(keep) == len(delays) and min(delays) >= 20
    assert sum(delays) == pytest.approx(1000 * count / fps, abs=10)
    assert len(keep) < count  # (frames were dropped: 10-ms frames cannot each last 20 ms)


class _InfoInterruptedAtCom(dict):
    def __getitem__(self, key):
        if key == "com":
            raise KeyboardInterrupt  # Ctrl-C after the step's other terms were appended
        return super().__getitem__(key)


class _InterruptBeforeCom(gym.Wrapper):
    def __init__(self, env, n):
        super().__init__(env)
        self.n, self.calls = n, 0

    def step(self, action):
        obs, reward, terminated, truncated, info = self.env.step(action)
        self.calls += 1
        if self.calls == self.n:
            info = _InfoInterruptedAtCom(info)
        return obs, reward, terminated, truncated, info


def test_an_interrupt_between_a_step_s_appends_keeps_only_whole_steps():
    """EpisodeResult keeps the steps recorded whole: an interrupt after a step's rewards and
    actions were appended but before its centre of mass was leaves that step out, so that
    com and states have one row more than rewards. Sizing by len(com) rather than
    len(com) - 1 (rewards of 3 steps with 3 com rows) passed every test."""
    env = _InterruptBeforeCom(gym.make("softrom_gym/SoftRobot-v0", robot="beam", task="walk",
                                       sim_dim=6, resolution=6), 3)  # fmt: skip
    planner = MPPI(MPPISettings(horizon=4, knots=2, samples=2))
    with pytest.raises(KeyboardInterrupt) as interrupt:
        run_episode(env, planner, 0.25, seed=0, progress=False)
    result = interrupt.value.result
    assert result.stop_reason == "interrupted"
    assert result.rewards.size == 2 and result.actions.shape[0] == 2
    assert result.com.shape == (3, 3) and len(result.states) == 3
    assert result.distance.shape == (3,)
