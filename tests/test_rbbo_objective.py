"""Objectives (rbbo.objective): the env objective against a stand-in env and controllers."""

import json
import pickle
import sys
import types
from dataclasses import dataclass
from typing import Any, ClassVar

import gymnasium as gym
import numpy as np
import pytest
from gymnasium import spaces

from rbbo.objective import (
    EnvObjective,
    SyntheticObjective,
    make_objective,
    measured_steps,
    objective_differences,
    parse_objective_spec,
    settled_reward_rate,
    settled_step,
)

STEP = 0.025  # seconds per env step (dt = 1/200 s, frame_skip = 5), as the softrom envs


class StandInEnv(gym.Env):
    """Takes the softrom env's B_c arguments; each step rewards 1.0 for the first 2 s (the
    lean into a held pose) and then 0.1 * (first entry of B_c) per step."""

    metadata: ClassVar[dict] = {"render_modes": ["rgb_array"]}  # rollout --video's (none drawn)

    def __init__(self, sim_dim=20, control_dim=3, control_basis=None, render_mode=None):
        self.control_basis = np.asarray(control_basis)
        self.model = types.SimpleNamespace(dt=1 / 200)
        self.frame_skip = 5
        self.robot = types.SimpleNamespace(num_nodes=623)
        self.action_space = spaces.Box(-1, 1, (control_dim,))
        self.observation_space = spaces.Box(-1, 1, (1,))


gym.register("rbbo_test/StandIn-v0", entry_point=StandInEnv)


@dataclass
class EpisodeResult:
    rewards: np.ndarray


def _fake_controllers(calls):
    module = types.ModuleType("controllers")

    class MPPI:
        def __init__(self, settings=None):
            self.settings = settings

    module.MPPI = MPPI
    module.GaussNewtonShooting = MPPI

    def planner_for(env_id, planner, **changes):  # tuned where the stand-in has defaults
        default = getattr(module, "default_planner", None)
        if default is not None:
            return default(env_id, planner, **changes)
        return MPPI(changes or None), 1

    module.planner_for = planner_for
    module.has_defaults = lambda env_id: env_id != "rbbo_test/Untuned-v0"

    def run_episode(env, planner, seconds, replan_every=1, seed=0, progress=True, video=None):
        assert isinstance(planner, MPPI) and not progress
        calls.append((seconds, seed) if replan_every == 1 else (seconds, seed, replan_every))
        steps = round(seconds / STEP)
        t = np.arange(steps) * STEP
        lean = np.where(t < 2.0, 1.0, 0.0)
        walk = np.where(t >= 2.0, 0.1 * env.unwrapped.control_basis[0, 0], 0.0)
        return EpisodeResult(lean + walk)

    module.run_episode = run_episode
    return module


@pytest.fixture
def controllers(monkeypatch):
    calls = []
    monkeypatch.setitem(sys.modules, "controllers", _fake_controllers(calls))
    return calls


def test_env_objective_measures_reward_per_second_after_settling(controllers):
    objective = EnvObjective("rbbo_test/StandIn-v0", 20, 3, settle_time=2.0)
    basis = np.eye(20)[:, :3]
    # 0.1 per 0.025 s step = 4 per second from t = 2 s on; the 1.0-per-step lean is ignored
    assert objective(basis, 6.0, seed=3) == pytest.approx(4.0)
    assert controllers == [(6.0, 3)]
    assert objective(np.eye(20)[:, 1:4], 10.0, seed=3) == pytest.approx(0.0)


def test_env_objective_uses_the_controllers_tuned_defaults(controllers, monkeypatch):
    module = sys.modules["controllers"]
    asked = []

    def default_planner(env_id, planner, **changes):
        asked.append((env_id, planner, changes))
        return module.MPPI("tuned"), 10

    monkeypatch.setattr(module, "default_planner", default_planner, raising=False)
    objective = EnvObjective("rbbo_test/StandIn-v0", 20, 3, controller="gn",
                             planner_kwargs={"samples": 8})  # fmt: skip
    objective(np.eye(20)[:, :3], 4.0, seed=1)
    # dt None: the stand-in env has no frame_skip (its control period is not known); asked
    # once when made (its planner_kwargs checked) and once for the episode
    assert asked == 2 * [("rbbo_test/StandIn-v0", "gn", {"dt": None, "samples": 8})]
    assert controllers == [(4.0, 1, 10)]


def test_env_objective_pickles_without_its_env(controllers):
    objective = EnvObjective("rbbo_test/StandIn-v0", 20, 3)
    objective(np.eye(20)[:, :3], 4.0, 0)
    clone = pickle.loads(pickle.dumps(objective))
    assert clone._env is None and clone.spec() == objective.spec()


def test_env_objective_rejects_bad_input():
    with pytest.raises(ValueError, match=r"unknown planner 'ilqr'; registered: gn, mppi .*"
                       "or an import path package.module:ClassName"):  # fmt: skip
        EnvObjective("x", 20, 3, controller="ilqr")
    with pytest.raises(TypeError, match="controller must be a planner name"):
        EnvObjective("x", 20, 3, controller=None)
    with pytest.raises(ValueError, match="settle_time must be >= 0, got -1"):
        EnvObjective("x", 20, 3, settle_time=-1)
    assert EnvObjective("x", 20, 3, settle_time=0).settle_time == 0  # R from the first step
    for settle in ("2", float("inf"), float("nan")):
        with pytest.raises(ValueError, match="settle_time must be"):
            EnvObjective("x", 20, 3, settle_time=settle)
    objective = EnvObjective("rbbo_test/StandIn-v0", 20, 3, settle_time=2.0)
    with pytest.raises(ValueError, match="T = 1.5 s must exceed the settle time 2.0 s"):
        objective(np.eye(20)[:, :3], 1.5, 0)
    # past the settle time but not by a whole step: named before the episode is simulated
    objective.episode = lambda *args: pytest.fail("the episode was simulated")
    with pytest.raises(ValueError, match=r"T = 2.01 s is 80 steps of 0.025 s, none of them "
                       r"from the settle time 2.0 s on"):  # fmt: skip
        objective(np.eye(20)[:, :3], 2.01, 0)


def test_settled_reward_counts_a_short_episode_as_zero_for_the_rest():
    result = EpisodeResult(np.full(120, 0.1))  # diverged at 3 s of a 6 s episode
    assert settled_reward_rate(result, STEP, 2.0, 6.0) == pytest.approx(0.1 * 40 / 4.0)


def test_settled_reward_is_per_second_simulated_when_t_is_off_the_step_grid():
    # BOCA's T = 2 + 2/3 s at 25 ms steps: the episode runs round(106.67) = 107 steps
    result = EpisodeResult(np.full(107, 0.1))
    rate = settled_reward_rate(result, 0.025, 1.0, 2.0 + 2.0 / 3.0)
    assert rate == pytest.approx(0.1 * 67 / (107 * 0.025 - 1.0), rel=1e-12)
    # on the grid, the time asked for (the arithmetic of recorded runs, to the bit)
    result = EpisodeResult(np.full(160, 0.1))
    assert settled_reward_rate(result, 0.025, 1.0, 4.0) == np.full(120, 0.1).sum() / (4.0 - 1.0)


def test_settled_step_is_the_step_starting_at_the_settle_time_despite_round_off():
    """k dt / dt rounds above k for some k (0.07 / 0.01 = 7.000000000000001): still step k,
    not k + 1; a settle time between steps starts at the next one."""
    for dt in (0.025, 0.01, 0.005):
        assert [settled_step(dt, k * dt) for k in range(200)] == list(range(200))
    assert settled_step(0.01, 0.07) == 7
    assert settled_step(STEP, 1.01) == 41
    # the steps R counts: whole steps of the episode from the settled one on
    assert measured_steps(STEP, 1.0, 1.01) == 0 and measured_steps(STEP, 1.0, 1.05) == 2
    assert measured_steps(STEP, 0.0, 0.001) == 1  # (an episode runs at least one step)


def test_settled_reward_divides_by_the_time_from_the_first_counted_step():
    """A settle time between steps: R counts steps 41.. (from 1.025 s) and divides by the
    4 - 1.025 s they cover, not by 4 - 1.01 s."""
    rate = settled_reward_rate(EpisodeResult(np.full(160, 0.1)), STEP, 1.01, 4.0)
    assert rate == pytest.approx(0.1 * 119 / (4.0 - 41 * STEP), rel=1e-12)


def test_settled_reward_on_the_step_grid_divides_by_the_time_asked_for_to_the_bit():
    """T = 2.9 s is 116 steps, and 116 * 0.025 rounds to 2.9000000000000004: on the grid R
    divides by T itself, the arithmetic of recorded runs."""
    result = EpisodeResult(np.full(116, 0.1))
    assert settled_reward_rate(result, STEP, 1.0, 2.9) == np.full(76, 0.1).sum() / (2.9 - 1.0)


def test_settled_reward_prefers_the_task_term_and_skips_non_finite_steps():
    """task_rewards (the controllers' R alone) over rewards; a non-finite step (one a diverging
    simulation ended on) adds nothing instead of making R NaN."""

    @dataclass
    class WithTask:
        rewards: np.ndarray
        task_rewards: np.ndarray

    both = WithTask(np.full(160, 5.0), np.full(160, 0.1))
    assert settled_reward_rate(both, STEP, 1.0, 4.0) == pytest.approx(0.1 * 120 / 3.0)
    rewards = np.full(160, 0.1)
    rewards[100] = np.nan
    rate = settled_reward_rate(EpisodeResult(rewards), STEP, 1.0, 4.0)
    assert rate == pytest.approx(0.1 * 119 / 3.0)


def test_settled_reward_needs_time_after_the_settle_time():
    with pytest.raises(ValueError, match="an episode of 2.0 s is not longer than the settle "
                                         "time 2.0 s"):  # fmt: skip
        settled_reward_rate(EpisodeResult(np.ones(80)), STEP, 2.0, 2.0)


def test_synthetic_objective_is_deterministic_and_rotation_invariant():
    objective = SyntheticObjective(6, 2, noise=0.1)
    u = objective.optimum
    assert objective.value(u) == pytest.approx(1.0)
    q = np.array([[0.0, 1.0], [1.0, 0.0]])
    assert objective(u, 10.0, 4) == pytest.approx(objective(u @ q, 10.0, 4))
    assert objective(u, 10.0, 4) != objective(u, 10.0, 5)
    # common random numbers: the seed's shared part cancels in differences between bases
    b = np.eye(6)[:, :2]
    diffs = [objective(u, 10.0, s) - objective(b, 10.0, s) for s in range(20)]
    assert np.std(diffs) < 0.1
    assert objective(u, 4.0, 0) < objective(u, 10.0, 0)  # low fidelity is biased low
    assert objective == SyntheticObjective(6, 2, noise=0.1)  # (its derived arrays aside)
    assert objective != SyntheticObjective(6, 2, noise=0.2)
    # also for an axis-aligned subspace (R_init's), whose B B^T rounds tiny entries to -0.0
    rng = np.random.default_rng(0)
    for _ in range(20):
        rotation = np.linalg.qr(rng.standard_normal((2, 2)))[0]
        assert objective(b @ rotation, 10.0, 3) == pytest.approx(objective(b, 10.0, 3), abs=1e-12)


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("synthetic", {"kind": "synthetic"}),
        ("synthetic:noise=0.1,seed=3", {"kind": "synthetic", "noise": 0.1, "optimum_seed": 3}),
        ("softrom_gym/CrossWalk-v0", {"kind": "env", "env_id": "softrom_gym/CrossWalk-v0"}),
    ],
)
def test_objective_specs(text, expected):
    assert parse_objective_spec(text) == expected


def test_bad_objective_specs():
    with pytest.raises(ValueError, match=r"bad synthetic option 'foo=1'; use key=value"):
        parse_objective_spec("synthetic:foo=1")
    with pytest.raises(ValueError, match="synthetic option noise needs a number, got 'x'"):
        parse_objective_spec("synthetic:noise=x")
    with pytest.raises(ValueError, match="synthetic option seed needs an integer, got '1.5'"):
        parse_objective_spec("synthetic:seed=1.5")
    with pytest.raises(ValueError, match="unknown objective kind 'csv'"):
        make_objective({"kind": "csv"}, 4, 2)
    for option in ("noise=inf", "bias=inf", "delay=nan"):
        key = option.split("=")[0]
        with pytest.raises(ValueError, match=f"{key} must be finite and >= 0"):
            make_objective(parse_objective_spec(f"synthetic:{option}"), 4, 2)
    with pytest.raises(ValueError, match="the synthetic seed must be an integer >= 0, got -1"):
        make_objective(parse_objective_spec("synthetic:seed=-1"), 4, 2)
    for env_id in ("", None):
        with pytest.raises(ValueError, match=f"ENV_ID must be a non-empty string, got {env_id!r}"):
            parse_objective_spec(env_id)
    for t_max in (0, float("inf")):
        with pytest.raises(ValueError, match=f"t_max must be finite and > 0, got {t_max}"):
            SyntheticObjective(4, 2, t_max=t_max)
    # named: a string raised math.isfinite's "must be real number, not str", True was 1
    for name in ("noise", "bias", "delay", "t_max"):
        for value in ("0.1", True, None):
            with pytest.raises(ValueError, match=f"{name} must be a number, got {value!r}"):
                SyntheticObjective(4, 2, **{name: value})
    # numpy's numbers are taken, and stored as Python's: the spec goes into config.json
    numpy = SyntheticObjective(np.int64(4), 2, optimum_seed=np.int64(3), noise=np.float32(0.5),
                               t_max=np.int64(4))  # fmt: skip
    assert json.loads(json.dumps(numpy.spec())) == SyntheticObjective(4, 2, 3, 0.5, t_max=4).spec()


def test_a_run_is_never_replayed_in_another_simulation_space():
    """A run records its B_r's fingerprint; an env that builds other reduced coordinates
    (a flipped mode: what another BLAS kernel gave before the canonical bases) is refused by
    name instead of giving its B_c another meaning."""
    from rbbo.objective import EnvObjective, SimulationSpaceMismatch, make_objective

    objective = EnvObjective("softrom_gym/BeamWalk-v0", 6, 2)
    spec = objective.spec()
    recorded = spec["simulation_space"]
    assert len(recorded) == 6 + 6
    again = make_objective(spec, 6, 2)  # the same space: accepted
    assert again.simulation_space() == pytest.approx(recorded)
    flipped = list(recorded)
    flipped[8] = -flipped[8]  # deformation coordinate 2 with the other sign
    with pytest.raises(SimulationSpaceMismatch, match=r"coordinates \[8\] differ"):
        make_objective({**spec, "simulation_space": flipped}, 6, 2)
    with pytest.raises(SimulationSpaceMismatch, match="no simulation space like"):
        objective.expect_simulation_space(recorded[:-1])
    objective.expect_simulation_space(None)  # a run from before the fingerprint: no check


def test_a_run_is_never_resumed_with_another_planner():
    """A run records its planner's resolved settings: when the controllers' defaults change
    (as a robot of your own's did, from the library settings to controllers.GENERIC), the
    run's objective would change with them, so it is refused by name."""
    from rbbo.objective import EnvObjective, PlannerMismatch, make_objective

    spec = EnvObjective("softrom_gym/SoftRobot-v0", 6, 2, env_kwargs={"robot": "beam"}).spec()
    assert spec["planner"]["name"] == "mppi" and spec["planner"]["replan_every"] == 20
    assert "threads" not in spec["planner"]["settings"]  # results do not depend on it
    make_objective(spec, 6, 2)  # the same planner: accepted
    old = {**spec["planner"], "replan_every": 1,
           "settings": {**spec["planner"]["settings"], "period": None}}  # fmt: skip
    with pytest.raises(PlannerMismatch, match=r"changed: period, replan_every"):
        make_objective({**spec, "planner": old}, 6, 2)
    older = {k: v for k, v in spec.items() if k != "planner"}  # a run from before the record
    with pytest.raises(PlannerMismatch, match="predates the planner record"):
        make_objective(older, 6, 2)  # a robot of your own: its defaults changed since
    beam = EnvObjective("softrom_gym/BeamWalk-v0", 6, 2).spec()
    make_objective({k: v for k, v in beam.items() if k != "planner"}, 6, 2)  # a benchmark: same
    # ... unless at another control period, whose times are now scaled to keep their seconds
    slow = EnvObjective("softrom_gym/BeamWalk-v0", 6, 2, env_kwargs={"frame_skip": 10}).spec()
    with pytest.raises(PlannerMismatch, match=r"control period \(0.05 s, not 0.025 s\)"):
        make_objective({k: v for k, v in slow.items() if k != "planner"}, 6, 2)


def test_a_bad_planner_setting_or_env_keyword_is_refused_when_the_objective_is_made():
    """From Python, as ``rbbo optimize --mpc`` / ``--env-kwarg`` do: an unknown key, a bad
    value or a noise of another length than C used to pass, and then every evaluation failed
    in its worker (a 2-evaluation RBBO.run returned failed=2 and no R, saying nothing)."""
    env = "softrom_gym/BeamWalk-v0"
    with pytest.raises(TypeError, match="unknown MPPISettings setting 'nosie'"):
        EnvObjective(env, 6, 2, planner_kwargs={"nosie": 0.3})
    with pytest.raises(ValueError, match="noise must be a finite number >= 0, got -0.3"):
        EnvObjective(env, 6, 2, planner_kwargs={"noise": -0.3})
    with pytest.raises(ValueError, match="noise has 3 standard deviations.*C = 2"):
        EnvObjective(env, 6, 2, planner_kwargs={"noise": (0.3, 0.2, 0.1)})
    with pytest.raises(TypeError, match="unknown GaussNewtonSettings setting 'samples'"):
        EnvObjective(env, 6, 2, controller="gn", planner_kwargs={"samples": 8})
    with pytest.raises(TypeError, match="planner_kwargs must be a dict"):
        EnvObjective(env, 6, 2, planner_kwargs=[("noise", 0.3)])
    # and the env's keywords, by name (the env is not built)
    with pytest.raises(ValueError, match="BeamWalk-v0 takes no keyword 'colour'"):
        EnvObjective(env, 6, 2, env_kwargs={"colour": 3})
    with pytest.raises(ValueError, match="env keyword 'sim_dim' is set by rbbo itself"):
        EnvObjective(env, 6, 2, env_kwargs={"sim_dim": 10})
    with pytest.raises(TypeError, match="env_kwargs must be a dict"):
        EnvObjective(env, 6, 2, env_kwargs=None)
    good = EnvObjective(env, 6, 2, planner_kwargs={"noise": (0.3, 0.2)})
    assert good.planner()[0].settings.noise == (0.3, 0.2)
    # numpy's numbers are taken and stored as Python's (an np.int64 M failed RBBO.create's
    # config.json with "Object of type int64 is not JSON serializable")
    numpy = EnvObjective(env, np.int64(6), np.int32(2), settle_time=np.float32(1.5))
    assert (type(numpy.sim_dim), type(numpy.control_dim), type(numpy.settle_time)) == (
        int, int, float)  # fmt: skip
    # ... and planner settings: the planner's record read np.int64(8) as the string
    # "np.int64(8)", and the spec failed json.dumps
    numpy = EnvObjective(env, 6, 2, planner_kwargs={
        "samples": np.int64(8), "temperature": np.float32(0.25),
        "noise": np.array([0.3, 0.2]), "seed_amplitudes": (np.float32(1.0), 1.5)})  # fmt: skip
    record = numpy.planner_record()["settings"]
    assert (record["samples"], record["temperature"], record["noise"]) == (8, 0.25, [0.3, 0.2])
    assert json.loads(json.dumps(numpy.planner_kwargs)) == {
        "samples": 8,
        "temperature": 0.25,
        "noise": [0.3, 0.2],
        "seed_amplitudes": [1.0, 1.5],
    }


def test_the_planner_keeps_its_seconds_at_the_envs_control_period():
    from rbbo.objective import EnvObjective

    slow = EnvObjective("softrom_gym/BeamWalk-v0", 6, 2, env_kwargs={"frame_skip": 10})
    planner, every = slow.planner()
    assert planner.settings.period == 5.0 and every == 15  # 0.25 s cycles, 0.75 s replans
    assert slow.spec()["planner"]["settings"]["horizon"] == 20  # 1 s, recorded
    planner, every = EnvObjective("softrom_gym/BeamWalk-v0", 6, 2).planner()
    assert planner.settings.period == 10 and every == 30


def test_an_evaluation_runs_its_whole_t_whatever_the_registered_time_limit(monkeypatch):
    from rbbo.objective import NO_TIME_LIMIT

    # 400 registered env steps are 2 s at frame_skip=1: T = 2.5 s used to end there, and R
    # read the lost half second as zero
    fast = EnvObjective("softrom_gym/BeamWalk-v0", 6, 2, settle_time=1.0,
                        env_kwargs={"frame_skip": 1})  # fmt: skip
    env = fast.make_env(np.eye(6)[:, :2])
    assert env.spec.max_episode_steps == NO_TIME_LIMIT
    # an env that still cuts an episode short (a user's own wrapping) fails the evaluation,
    # named, rather than scoring the missing seconds as zero
    cut = types.SimpleNamespace(stop_reason="truncated by the time limit", seconds=2.0,
                                dt=0.005, rewards=np.ones(400))  # fmt: skip
    monkeypatch.setattr(EnvObjective, "episode", lambda self, *args, **kwargs: cut)
    with pytest.raises(RuntimeError, match="time limit ended the T = 2.5 s episode at 2 s"):
        fast(np.eye(6)[:, :2], 2.5, 0)


def test_an_env_without_a_simulation_space_is_built_once_to_learn_it(monkeypatch):
    """The stand-in env has no ``subspace``: its None fingerprint is remembered like any
    other, so ``spec()`` and the resume checks do not build the env again on every call."""
    objective = EnvObjective("rbbo_test/StandIn-v0", 20, 3)
    built = []
    real_make_env = EnvObjective.make_env

    def counting(self, basis):
        built.append(basis)
        return real_make_env(self, basis)

    monkeypatch.setattr(EnvObjective, "make_env", counting)
    assert objective.simulation_space() is None
    assert objective.simulation_space() is None
    objective.spec()
    assert len(built) == 1


def test_a_planner_of_ones_own_by_import_path_is_recorded_and_found_again():
    """The run records the import path (config.json), a worker process unpickles the
    objective and imports it by itself, and a resume finds the same planner."""
    from rbbo.objective import PlannerMismatch

    env_kwargs = {"robot": "beam", "task": "swim", "resolution": 6}
    tiny = {"horizon": 4, "window": 4, "knots": 2, "gait_seed": False, "seed_periods": (),
            "samples": 4, "elites": 2, "iterations": 1}  # fmt: skip
    cem = "examples.cem_planner:CEM"
    objective = EnvObjective("softrom_gym/SoftRobot-v0", 6, 2, controller=cem, settle_time=0.0,
                             env_kwargs=env_kwargs, planner_kwargs=tiny)  # fmt: skip
    spec = json.loads(json.dumps(objective.spec()))
    assert spec["controller"] == cem and "registered_planner" not in spec  # (as before)
    assert spec["planner"]["name"] == "cem" and spec["planner"]["settings"]["elites"] == 2
    resumed = make_objective(spec, 6, 2)
    assert resumed.controller == cem
    worker = pickle.loads(pickle.dumps(resumed))
    basis = np.eye(6)[:, :2]
    assert worker(basis, 0.1, seed=0) == objective(basis, 0.1, seed=0)
    with pytest.raises(PlannerMismatch, match="changed: elites"):
        make_objective({**spec, "planner_kwargs": {**tiny, "elites": 3}}, 6, 2)
    with pytest.raises(ValueError, match="module 'examples.cem_planner' has no 'CME'"):
        make_objective({**spec, "controller": "examples.cem_planner:CME"}, 6, 2)


@pytest.fixture
def planner_registry(monkeypatch):
    """The planner registry as shipped, restored after the test (registrations are for the
    whole process)."""
    from controllers import registry

    monkeypatch.setattr(registry, "_REGISTRY", dict(registry._REGISTRY))
    return registry


_SMALL_SWIM = {"robot": "beam", "task": "swim", "resolution": 6}
_TINY_CEM = {"horizon": 4, "window": 4, "knots": 2, "gait_seed": False, "seed_periods": (),
             "elites": 2, "iterations": 1}  # fmt: skip


def test_a_name_registered_only_here_is_found_by_the_workers_and_a_resume(planner_registry,
                                                                          monkeypatch):  # fmt: skip
    """A planner registered in the user's session only (a notebook, a script's __main__
    block): the spawned worker processes, which never ran that registration, evaluate with it,
    and a resume without the registration finds the same planner with the same defaults.
    Before the objective recorded the class's import path, every worker evaluation failed
    with "unknown planner 'parent-cem'"."""
    import controllers
    from examples.cem_planner import CEM, CEMSettings
    from rbbo import RBBO, RBBOConfig

    controllers.register_planner("parent-cem", CEM, defaults={"samples": np.int64(4),
                                                              "noise": 0.2})  # fmt: skip
    objective = EnvObjective("softrom_gym/SoftRobot-v0", 6, 2, controller="parent-cem",
                             settle_time=0.0, env_kwargs=_SMALL_SWIM,
                             planner_kwargs=_TINY_CEM)  # fmt: skip
    spec = json.loads(json.dumps(objective.spec()))
    assert spec["controller"] == "parent-cem"
    assert spec["registered_planner"] == {
        "planner_class": "examples.cem_planner:CEM",
        "settings_class": "examples.cem_planner:CEMSettings",
        "defaults": {"samples": 4, "noise": 0.2},
    }
    assert spec["planner"]["settings"]["samples"] == 4
    config = RBBOConfig(6, 2, n_init=1, max_evaluations=1, n_confirm=0, t_min=0.1, t_max=0.2,
                        acq_random=16, acq_starts=1, gp_restarts=0)  # fmt: skip
    opt = RBBO(config, objective_spec=spec)
    opt.run(objective, workers=1, timeout_s=120, confirm=False)  # (a spawned worker)
    [evaluation] = opt.history
    assert evaluation.status == "ok", evaluation.error
    # a resume in a process without the registration (rbbo resume): the recorded source
    monkeypatch.setattr(planner_registry, "_REGISTRY", {
        k: v for k, v in planner_registry._REGISTRY.items() if k != "parent-cem"})  # fmt: skip
    resumed = make_objective(spec, 6, 2)  # (its planner record checked: the same settings)
    planner, _ = resumed.planner()
    assert type(planner) is CEM and type(planner.settings) is CEMSettings
    assert (planner.settings.samples, planner.settings.noise) == (4, 0.2)
    assert json.loads(json.dumps(resumed.spec())) == spec
    basis = np.eye(6)[:, :2]
    assert resumed(basis, 0.1, seed=0) == objective(basis, 0.1, seed=0)
    # a spec recorded before the source was: without the registration unknown, as before
    old = {k: v for k, v in spec.items() if k != "registered_planner"}
    with pytest.raises(ValueError, match="unknown planner 'parent-cem'; registered: gn, mppi"):
        make_objective(old, 6, 2)
    # with it, the same objective (the key it lacks is no difference: no ObjectiveMismatch)
    controllers.register_planner("parent-cem", CEM, defaults={"samples": 4, "noise": 0.2})
    assert objective_differences(old, make_objective(old, 6, 2)) == []
    assert objective_differences(spec, make_objective(old, 6, 2)) == []


def test_a_registered_class_no_other_process_can_import_is_named_up_front(planner_registry):
    """A class defined in __main__ or inside a function cannot be found by a worker or a
    resume: EnvObjective warns so, and what to do, instead of every evaluation failing
    silently; the planner still runs in this process (a notebook's, the serial executor)."""
    import controllers
    from examples.cem_planner import CEM

    class Local(CEM):
        pass

    in_main = type("Scripted", (CEM,), {"__module__": "__main__"})
    controllers.register_planner("local-cem", Local)
    controllers.register_planner("main-cem", in_main)
    for name, where, why in (
        ("local-cem", rf"{__name__}:.*<locals>\.Local", "a class defined inside a function"),
        ("main-cem", "__main__:Scripted", r"a class defined in __main__ \(a script run "
         r"directly, or a notebook\)"),
    ):  # fmt: skip
        with pytest.warns(UserWarning, match=(
            rf"planner '{name}' is registered to {where}, {why}: another process \(rbbo's "
            r"worker processes, a later rbbo resume\) cannot import it, .* Define the class "
            r"in a module of its own .* or choose it by its import path.*plans in this "
            r"process only")) as caught:  # fmt: skip
            objective = EnvObjective("softrom_gym/SoftRobot-v0", 6, 2, controller=name)
        assert caught[0].filename == __file__  # (pointing at the caller's line)
        assert objective.registered_planner is None and "registered_planner" not in objective.spec()
        assert type(objective.planner()[0]).__name__ in ("Local", "Scripted")  # (it runs here)
    with pytest.warns(UserWarning, match=r"controller '__main__:Scripted' names a class of "
                      r"__main__ .* plans in this process only") as caught:  # fmt: skip
        sys.modules["__main__"].Scripted = in_main  # type: ignore[attr-defined]
        try:
            EnvObjective("softrom_gym/SoftRobot-v0", 6, 2, controller="__main__:Scripted")
        finally:
            del sys.modules["__main__"].Scripted  # type: ignore[attr-defined]
    assert caught[0].filename == __file__
    controllers.register_planner("odd-cem", CEM, defaults={"noise": object()})
    with pytest.raises(ValueError, match="planner 'odd-cem': its default noise = <object"):
        EnvObjective("softrom_gym/SoftRobot-v0", 6, 2, controller="odd-cem")


def test_the_shipped_planners_specs_are_as_before(controllers):
    """The specs of "mppi" and "gn" runs get no new key: a resumed run's recorded spec is
    compared with its objective's (an ObjectiveMismatch names any key it lacks)."""
    for name in EnvObjective.CONTROLLERS:
        spec = EnvObjective("rbbo_test/StandIn-v0", 20, 3, controller=name).spec()
        assert set(spec) == {"kind", "env_id", "sim_dim", "control_dim", "controller",
                             "settle_time", "env_kwargs", "planner_kwargs", "planner"}  # fmt: skip
    with pytest.raises(ValueError, match="registered_planner is recorded for a registered "
                       "planner name, not for 'gn'"):  # fmt: skip
        EnvObjective("rbbo_test/StandIn-v0", 20, 3, controller="gn", registered_planner={})
    # (an import path is recorded by itself: a source beside it is refused as for a shipped one)
    cem = "examples.cem_planner:CEM"
    with pytest.raises(ValueError, match="registered_planner is recorded for a registered "
                       f"planner name, not for '{cem}'"):  # fmt: skip
        EnvObjective("rbbo_test/StandIn-v0", 20, 3, controller=cem, registered_planner={})


def test_a_recorded_source_is_checked_up_front_and_a_registration_here_wins(planner_registry):
    """A name not registered here plans with its recorded source, which a wrong path makes
    an error at once, not in every evaluation; a name registered here plans with its
    registration, even where that class cannot be recorded and the recorded source names
    another."""
    import controllers
    from examples.cem_planner import CEM

    listed: Any = ["examples.cem_planner:CEM"]
    with pytest.raises(TypeError, match="registered_planner must be a dict .* got list"):
        EnvObjective("softrom_gym/SoftRobot-v0", 6, 2, controller="gone-cem",
                     registered_planner=listed)  # fmt: skip
    source = {"planner_class": "examples.cem_planner:CME",
              "settings_class": "examples.cem_planner:CEMSettings", "defaults": {}}  # fmt: skip
    with pytest.raises(ValueError, match="module 'examples.cem_planner' has no 'CME'"):
        EnvObjective("softrom_gym/SoftRobot-v0", 6, 2, controller="gone-cem",
                     registered_planner=source)  # fmt: skip

    class Local(CEM):
        pass

    controllers.register_planner("gone-cem", Local)
    with pytest.warns(UserWarning, match="plans in this process only"):
        objective = EnvObjective("softrom_gym/SoftRobot-v0", 6, 2, controller="gone-cem",
                                 registered_planner={**source, "planner_class":
                                                     "examples.cem_planner:CEM"})  # fmt: skip
    assert type(objective.planner()[0]) is Local
    # (the recorded source named another class: a resume with this one is another objective)
    assert objective.registered_planner is None
    recorded = {**objective.spec(), "registered_planner": {**source, "planner_class":
                                                           "examples.cem_planner:CEM"}}  # fmt: skip
    (difference,) = objective_differences(recorded, objective)
    assert difference.startswith("registered_planner absent (recorded {'planner_class': "
                                 "'examples.cem_planner:CEM'")  # fmt: skip


def test_a_simulation_space_coordinate_off_either_way_is_refused():
    """The B_r fingerprint check compares |current - recorded|: a coordinate off by the same
    amount upwards or downwards is refused. The existing test flips a coordinate that happens
    to be positive, so a check of current - recorded > tol (without abs) passed it."""
    from rbbo.objective import EnvObjective, SimulationSpaceMismatch

    objective = EnvObjective("softrom_gym/BeamWalk-v0", 6, 2)
    recorded = objective.spec()["simulation_space"]
    step = 1e-3 * max(abs(v) for v in recorded)
    for k in (3, 8):
        for sign in (1.0, -1.0):
            off = list(recorded)
            off[k] += sign * step
            with pytest.raises(SimulationSpaceMismatch, match=rf"coordinates \[{k}\] differ"):
                objective.expect_simulation_space(off)
    objective.expect_simulation_space(recorded)  # itself: accepted
