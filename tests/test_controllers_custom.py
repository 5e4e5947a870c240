"""A planner of one's own against the Planner base class and run_episode: the subclass
contract the docstrings promise, and the mistakes it names.

Small robots (a 28-node beam, 6 modes) and short horizons keep these fast."""

from dataclasses import dataclass, fields
from typing import Any

import gymnasium as gym
import numpy as np
import pytest

import softrom_gym  # noqa: F401  (registers the envs)
from controllers import Planner, PlannerSettings, default_settings, run_episode


def small_env(task="swim"):
    return gym.make("softrom_gym/SoftRobot-v0", robot="beam", task=task, sim_dim=6,
                    resolution=6)  # fmt: skip


class Stepper(Planner):
    """Plans by stepping the env itself (and forgets to put it back): every replan moves the
    robot without run_episode knowing."""

    name = "stepper"

    def optimise(self, state: Any) -> None:
        self.api_.unwrapped.step(np.ones(self.api_.control_dim))


def test_run_episode_refuses_a_planner_that_changes_the_env_state():
    env = small_env()
    planner = Stepper(PlannerSettings(horizon=4, knots=2))
    with pytest.raises(RuntimeError, match=r"Stepper\.plan changed the env's state"):
        run_episode(env, planner, 0.1, replan_every=2, seed=0, progress=False)


class Restorer(Planner):
    """Steps the env to evaluate, then restores the state with set_state: allowed."""

    name = "restorer"

    def optimise(self, state: Any) -> None:
        env = self.api_.unwrapped
        env.step(np.ones(self.api_.control_dim))
        env.set_state(state)


def test_run_episode_accepts_a_planner_that_restores_the_env_state():
    env = small_env()
    result = run_episode(env, Restorer(PlannerSettings(horizon=4, knots=2)), 0.1,
                         replan_every=2, seed=0, progress=False)  # fmt: skip
    assert result.stop_reason == "time" and result.planner == "restorer"


class ActionStepper(Restorer):
    """Plans as Restorer does, then steps the env in action(): the robot moves between the
    episode's steps as surely as when plan() steps it."""

    name = "action-stepper"

    def action(self, env: Any) -> np.ndarray:
        env.unwrapped.step(np.ones(self.api_.control_dim))
        return super().action(env)


class HalfRestorer(Planner):
    """Steps the env to evaluate, then restores the positions q only (velocities zeroed): the
    robot is where it was, but not moving as it was."""

    name = "half-restorer"

    def optimise(self, state: Any) -> None:
        import cpp_sim

        env = self.api_.unwrapped
        env.step(np.ones(self.api_.control_dim))
        env.set_state(cpp_sim.ReducedState(state.q, np.zeros_like(state.qdot), state.impulses))


@pytest.mark.parametrize(
    ("planner", "method"), [("ActionStepper", "action"), ("HalfRestorer", "plan")]
)
def test_run_episode_refuses_a_planner_that_moves_the_env_in_action_or_drops_its_velocity(
    planner, method
):
    # the check after action() (as after plan()) and on qdot and impulses (not q alone)
    env = small_env()
    with pytest.raises(RuntimeError, match=rf"{planner}\.{method} changed the env's state"):
        run_episode(env, globals()[planner](PlannerSettings(horizon=4, knots=2)), 0.1,
                    replan_every=2, seed=0, progress=False)  # fmt: skip


class Unbatched(Planner):
    """Scores its plan's knots (K, C) without the batch axis evaluate_knots takes."""

    def optimise(self, state: Any) -> None:
        self.evaluate_knots(state, self.spline.knots)


def test_evaluate_names_knots_without_their_batch_axis():
    env = small_env()
    planner = Unbatched(PlannerSettings(horizon=4, knots=2))
    planner.reset(env, seed=0)
    c = env.action_space.shape[0]
    with pytest.raises(ValueError, match=rf"knots has shape \(2, {c}\), expected \(B, 2, {c}\)"):
        planner.plan(env)


@dataclass(frozen=True)
class OwnSettings(PlannerSettings):
    samples: int = 8
    elites: int = 2


def test_from_shared_takes_the_shared_settings_of_a_benchmark_default():
    mppi, _ = default_settings("softrom_gym/CrossSwim-v0", "mppi")
    own = OwnSettings.from_shared(mppi, elites=3)
    assert isinstance(own, OwnSettings)
    for f in fields(PlannerSettings):
        assert getattr(own, f.name) == getattr(mppi, f.name), f.name
    # MPPI's own settings stay MPPI's, even where a name is shared (samples)
    assert (own.samples, own.elites) == (8, 3) and mppi.samples != 8
    with pytest.raises(TypeError, match="unknown OwnSettings setting 'elite'"):
        OwnSettings.from_shared(mppi, elite=3)
    with pytest.raises(TypeError, match="must be a PlannerSettings"):
        OwnSettings.from_shared({"horizon": 4})


def _example(name):
    """A module of examples/, imported from its file (examples/ is not a package)."""
    import importlib.util
    import sys
    from pathlib import Path

    path = Path(__file__).resolve().parents[1] / "examples" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # (a dataclass looks its module up there)
    spec.loader.exec_module(module)
    return module


def test_cem_example_runs_seeded_and_records_its_replans():
    cem = _example("cem_planner")
    env = small_env("walk")
    settings = cem.CEMSettings(horizon=6, knots=2, samples=4, elites=2, iterations=2)
    planner = cem.CEM(settings)
    first = run_episode(env, planner, 0.2, replan_every=4, seed=3, progress=False)
    again = run_episode(env, planner, 0.2, replan_every=4, seed=3, progress=False)
    np.testing.assert_array_equal(first.actions, again.actions)
    assert first.planner == "cem" and first.replans == 2
    record = first.replan_records[0]
    assert record["rollouts"] == 8
    assert record["objective_best"] >= record["objective_start"]
    with pytest.raises(ValueError, match="elites must be in"):
        cem.CEMSettings(samples=4, elites=5)


@pytest.mark.parametrize("seed", [-1, 1.5, "0", True])
def test_run_episode_names_a_bad_seed_before_the_env_is_reset(seed):
    # env.reset named it as gymnasium's "Seed must be ..." error; a fresh env's first reset
    # failing also left gymnasium's env checker broken, and the next episode on that env
    # failed in step() with "cannot unpack non-iterable NoneType object"
    env = small_env()
    planner = Restorer(PlannerSettings(horizon=4, knots=2))
    with pytest.raises(
        ValueError, match=rf"seed must be a non-negative integer or None, got {seed!r}"
    ):
        run_episode(env, planner, 0.05, seed=seed, progress=False)
    assert run_episode(env, planner, 0.05, seed=0, progress=False).stop_reason == "time"


def test_every_public_function_of_controllers_has_type_hints():
    # (a planner written against them is type-checked against them: from_shared and replace
    # returned Any, so CEMSettings.from_shared(...).elites was never checked)
    import inspect

    import controllers

    missing = []
    for name in controllers.__all__:
        obj = getattr(controllers, name)
        found = [(name, obj)] if inspect.isfunction(obj) else []
        if inspect.isclass(obj):
            for attr, member in vars(obj).items():
                if attr.startswith("_") and attr != "__init__":
                    continue
                func = getattr(member, "__func__", member)  # (a classmethod's function)
                func = getattr(func, "fget", func)  # (a property's getter)
                if inspect.isfunction(func):
                    found.append((f"{name}.{attr}", func))
        for label, func in found:
            signature = inspect.signature(func)
            if signature.return_annotation is inspect.Signature.empty:
                missing.append(f"{label} -> ?")
            missing += [f"{label}({p.name})" for p in signature.parameters.values()
                        if p.name not in ("self", "cls") and p.annotation is p.empty]  # fmt: skip
    assert missing == []


def test_every_public_member_of_controllers_has_a_docstring():
    import inspect

    import controllers

    missing = []
    for name in controllers.__all__:
        obj = getattr(controllers, name)
        if not inspect.isclass(obj):
            continue
        for attr, member in vars(obj).items():
            if attr.startswith("_"):
                continue
            if isinstance(member, property):
                documented = bool(member.__doc__)
            elif inspect.isfunction(getattr(member, "__func__", member)):
                documented = bool(inspect.getdoc(getattr(obj, attr)))  # (or its base's)
            else:
                continue
            if not documented:
                missing.append(f"{name}.{attr}")
    assert missing == []


def test_evaluate_scores_rollouts_from_one_start_state_each():
    # rollout takes a list of B start states (multiple shooting, a tree of plans); evaluate
    # took one start COM only, and B of them failed inside numpy ("all the input arrays must
    # have same number of dimensions")
    from controllers import CostWeights, evaluate

    env = small_env()
    env.reset(seed=0)
    get_state, rollout = env.get_wrapper_attr("get_state"), env.get_wrapper_attr("rollout")
    com_of, d = env.get_wrapper_attr("center_of_mass"), env.get_wrapper_attr("direction")
    bound = env.get_wrapper_attr("action_bound")
    first = get_state()
    env.step(np.full(env.action_space.shape, bound))
    second = get_state()
    u = np.random.default_rng(0).uniform(-1, 1, (2, 2, env.action_space.shape[0]))
    out = rollout([first, second], bound * u)
    starts = np.stack([com_of(first), com_of(second)])
    both = evaluate(out, u, starts, d, 0.025, CostWeights())
    for i, state in enumerate((first, second)):
        alone = evaluate(rollout(state, bound * u[i : i + 1]), u[i : i + 1], com_of(state), d,
                         0.025, CostWeights())  # fmt: skip
        np.testing.assert_allclose(both.objective[i], alone.objective[0], rtol=1e-12)
    with pytest.raises(
        ValueError, match=r"start_com has shape \(3, 3\), expected \(3,\) or \(2, 3\)"
    ):
        evaluate(out, u, np.zeros((3, 3)), d, 0.025, CostWeights())


def test_an_episode_result_keeps_its_replan_interval():
    # realtime_factor needed the replan interval given again, which the result did not keep
    env = small_env()
    result = run_episode(env, Restorer(PlannerSettings(horizon=4, knots=2)), 0.1,
                         replan_every=2, seed=0, progress=False)  # fmt: skip
    assert result.replan_every == 2
    assert result.realtime_factor() == result.realtime_factor(2) > 0


def test_a_planner_written_against_the_private_hooks_still_plans_with_a_warning():
    # Before the hook was public a planner overrode _optimise and used _evaluate and _plan:
    # it keeps working for a release, and each old name says which one replaces it.
    with pytest.warns(DeprecationWarning, match=r"Legacy overrides Planner\._optimise.*"
                      r"rename it optimise") as caught:  # fmt: skip

        class Legacy(Planner):
            name = "legacy"

            def _optimise(self, state: Any) -> None:
                knots = self._plan.knots
                j = self._evaluate(state, np.stack([knots, np.zeros_like(knots)])).objective
                self._plan.knots = np.zeros_like(knots) if j[1] > j[0] else knots
                self.last_.update(objective_start=float(j[0]), objective_best=float(j.max()))

    # (pointing at the class statement, not at the library)
    assert caught[0].filename == __file__
    env = small_env()
    planner = Legacy(PlannerSettings(horizon=4, knots=2))
    planner.reset(env, seed=0)
    with pytest.warns(DeprecationWarning) as caught:
        planner.plan(env)
    said = {str(w.message) for w in caught}
    assert "Planner._plan is deprecated: use Planner.spline" in said
    assert "Planner._evaluate is deprecated: use Planner.evaluate_knots" in said
    assert planner.last_["rollouts"] == 2
    assert planner.last_["objective_best"] >= planner.last_["objective_start"]


def test_a_shipped_planner_extended_through_the_private_hook_still_runs_its_base():
    from controllers import MPPI, MPPISettings

    with pytest.warns(DeprecationWarning, match="Polished overrides Planner._optimise"):

        class Polished(MPPI):
            def _optimise(self, state: Any) -> None:
                super()._optimise(state)  # MPPI's replan, then a step of its own
                self.last_["polished"] = True

    env = small_env()
    settings = MPPISettings(horizon=4, knots=2, samples=4)
    planner, reference = Polished(settings), MPPI(settings)
    planner.reset(env, seed=0)
    reference.reset(env, seed=0)
    with pytest.warns(DeprecationWarning, match="call Planner.optimise"):
        planner.plan(env)
    reference.plan(env)
    assert planner.last_["polished"] and planner.last_["rollouts"] == 4
    np.testing.assert_array_equal(planner.spline.knots, reference.spline.knots)


def test_the_plan_is_typed_and_named_before_reset():
    planner = Restorer(PlannerSettings(horizon=4, knots=2))
    with pytest.raises(RuntimeError, match=r"Restorer\.reset\(env, seed\) must be called"):
        planner.spline  # noqa: B018


def test_a_planner_that_keeps_its_old_hook_beside_optimise_plans_with_optimise():
    # A planner renamed to optimise that keeps _optimise for its old callers is no legacy
    # planner: no warning, and plan() calls its own optimise (a forwarder to _optimise,
    # which calls optimise, would recurse).
    class Migrated(Halver):
        def optimise(self, state: Any) -> None:
            super().optimise(state)
            self.last_["hook"] = "optimise"

        def _optimise(self, state: Any) -> None:  # (kept for callers of the old name)
            self.optimise(state)

    assert Migrated.optimise is vars(Migrated)["optimise"]
    env = small_env()
    planner = Migrated(HalverSettings(horizon=4, knots=2))
    planner.reset(env, seed=0)
    planner.plan(env)
    assert planner.last_["hook"] == "optimise" and planner.last_["rollouts"] == 2


def test_knots_scored_over_another_horizon_start_at_the_plans_clock():
    """evaluate_knots(..., horizon) (and the deprecated _evaluate, which forwards it) rolls
    out the plan from its clock over that many steps: a periodic plan's first H controls are
    those of the plan's own horizon."""
    env = small_env()
    planner = Restorer(PlannerSettings(horizon=4, knots=2, period=6.0, gait_seed=False))
    planner.reset(env, seed=0)
    c = planner.api_.control_dim
    planner.spline.knots = np.stack([np.linspace(-0.5, 0.5, c), np.linspace(0.6, -0.2, c)])
    planner.spline.shift(2)  # (the clock two steps on, as after two actions)
    sent = []
    rollout = planner.api_.rollout

    def recording(state: Any, controls: np.ndarray, **kwargs: Any) -> Any:
        sent.append(np.array(controls))
        return rollout(state, controls, **kwargs)

    planner.api_.rollout = recording
    state = planner.api_.get_state()
    knots = np.stack([planner.spline.knots, 0.5 * planner.spline.knots])
    planner.evaluate_knots(state, knots)
    planner.evaluate_knots(state, knots, horizon=7)
    with pytest.warns(DeprecationWarning, match="_evaluate is deprecated"):
        planner._evaluate(state, knots, 7)
    own, longer, deprecated = sent
    assert own.shape == (2, 4, c) and longer.shape == (2, 7, c)
    np.testing.assert_allclose(longer[:, :4], own, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(deprecated, longer)


@dataclass(frozen=True)
class HalverSettings(PlannerSettings):
    shrink: float = 0.5
    levels: tuple[float, ...] = ()  # (a tuple setting, recorded as a JSON list)


class Halver(Planner):
    """Keeps its knots or shrinks them, whichever scores better. Its settings class is named
    by the annotation alone (no settings_class), as planners were written before it."""

    name = "halver"
    settings: HalverSettings

    def optimise(self, state: Any) -> None:
        knots = self.spline.knots
        both = np.stack([knots, self.settings.shrink * knots])
        j = self.evaluate_knots(state, both).objective
        self.spline.knots = both[int(np.argmax(j))]
        self.last_.update(objective_start=float(j[0]), objective_best=float(j.max()))


@pytest.fixture
def registry(monkeypatch):
    """The planner registry as shipped, restored after the test."""
    from controllers import registry

    monkeypatch.setattr(registry, "_REGISTRY", dict(registry._REGISTRY))
    return registry


def test_a_registered_planner_is_chosen_by_name_with_the_benchmarks_plan(registry):
    from controllers import default_planner, planner_for, register_planner, registered_planners
    from controllers.defaults import PLANNERS

    register_planner("halver", Halver, defaults={"shrink": 0.25})
    assert registered_planners() == ("gn", "halver", "mppi")
    assert PLANNERS["halver"] == (Halver, HalverSettings)  # (the old table follows it)
    mppi, mppi_every = default_settings("softrom_gym/BeamWalk-v0", "mppi")
    planner, every = default_planner("softrom_gym/BeamWalk-v0", "halver")
    # the benchmark's gait, objective and replan interval, its own tuned setting
    assert isinstance(planner, Halver) and every == mppi_every == 30
    assert planner.settings == HalverSettings.from_shared(mppi, shrink=0.25)
    # a robot of your own: the shared row; changes as for any planner
    planner, every = planner_for("softrom_gym/SoftRobot-v0", "halver", shrink=0.9, horizon=60)
    assert (planner.settings.shrink, planner.settings.horizon, every) == (0.9, 60, 20)
    env = small_env()
    planner, every = planner_for("softrom_gym/SoftRobot-v0", "halver", horizon=4, window=4,
                                 knots=2, gait_seed=False, seed_periods=(),
                                 dt=env.get_wrapper_attr("dt"))  # fmt: skip
    result = run_episode(env, planner, 0.1, replan_every=2, seed=0, progress=False)
    assert result.planner == "halver" and result.replan_records[0]["rollouts"] == 2


def test_a_planner_name_is_registered_once_and_checked(registry):
    from controllers import MPPI, register_planner

    register_planner("halver", Halver)
    with pytest.raises(ValueError, match=r"'halver' is already registered, to .*:Halver"):
        register_planner("halver", Halver)
    with pytest.raises(ValueError, match=r"'mppi' is already registered, to "
                       r"controllers\.mppi:MPPI: choose another name"):  # fmt: skip
        register_planner("mppi", Halver)
    with pytest.raises(ValueError, match="a ':' marks an import path"):
        register_planner("my:planner", Halver)
    with pytest.raises(TypeError, match="planner_class for 'x' must be a Planner subclass"):
        register_planner("x", HalverSettings)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match=r"controllers\.planner:Planner does not implement "
                       "optimise"):  # fmt: skip
        register_planner("x", Planner)
    with pytest.raises(TypeError, match="settings_class for 'x' must be a PlannerSettings"):
        register_planner("x", MPPI, dict)  # type: ignore[arg-type]
    with pytest.raises(TypeError, match="defaults for 'x': unknown HalverSettings setting "
                       "'shrnk'"):  # fmt: skip
        register_planner("x", Halver, defaults={"shrnk": 0.1})
    # (a shared setting in defaults reached planner_for twice: "got multiple values")
    with pytest.raises(TypeError, match="defaults for 'x' set 'horizon', 'weights', which "
                       "belong to the benchmark's plan"):  # fmt: skip
        register_planner("x", Halver, defaults={"weights": None, "horizon": 30})
    assert "x" not in registry._REGISTRY


def test_a_registered_planner_is_chosen_again_by_its_source_where_it_is_not_registered(
    registry,
):
    """planner_source (what rbbo records with a registered name) names the classes by import
    path and the defaults as JSON; planner_from_source, in a process without the registration
    (a worker, a resume), makes the same entry: the same planner for planner_for."""
    import json

    from controllers import planner_for, planner_from_source, planner_source, register_planner

    # numpy's values are stored as Python's (a run records them as JSON: np.float64(0.25)
    # was a repr there, and a resume reading 0.25 another planner)
    register_planner("halver", Halver, defaults={"shrink": np.float64(0.25)})
    entry = registry.resolve_planner("halver")
    assert entry.defaults == {"shrink": 0.25} and type(entry.defaults["shrink"]) is float
    source = json.loads(json.dumps(planner_source("halver")))
    assert source == {"planner_class": f"{__name__}:Halver",
                      "settings_class": f"{__name__}:HalverSettings",
                      "defaults": {"shrink": 0.25}}  # fmt: skip
    again = planner_from_source("halver", source)
    assert again == entry
    by_name, every = planner_for("softrom_gym/BeamWalk-v0", "halver")
    by_source, every_again = planner_for("softrom_gym/BeamWalk-v0", again)
    assert by_source.settings == by_name.settings and every_again == every
    # an array as the tuple that settings hold, a list in JSON, a tuple again
    register_planner("amplitudes", Halver, defaults={"levels": np.array([0.5, 1.0])})
    entry = registry.resolve_planner("amplitudes")
    assert entry.defaults == {"levels": (0.5, 1.0)}
    source = json.loads(json.dumps(planner_source("amplitudes")))
    assert source["defaults"] == {"levels": [0.5, 1.0]}
    assert planner_from_source("amplitudes", source) == entry
    with pytest.raises(ValueError, match="unknown planner 'nobody'"):
        planner_source("nobody")
    with pytest.raises(ValueError, match="the source of planner 'halver' must be a dict with "
                       "planner_class, settings_class and defaults"):  # fmt: skip
        planner_from_source("halver", {"planner_class": f"{__name__}:Halver"})
    with pytest.raises(ValueError, match="the source of planner 'halver' must be a dict"):
        planner_from_source("halver", {**source, "seed": 1})  # (a key it would not use)
    with pytest.raises(TypeError, match=f"'{__name__}:Halver' is not a PlannerSettings"):
        planner_from_source("halver", {**source, "settings_class": f"{__name__}:Halver"})


def test_an_unknown_planner_name_lists_the_registered_ones_and_the_import_path_form():
    from controllers import planner_for

    with pytest.raises(ValueError) as exc:
        planner_for("softrom_gym/BeamWalk-v0", "ilqr")
    assert str(exc.value) == (
        "unknown planner 'ilqr'; registered: gn, mppi (controllers.register_planner adds "
        "one), or an import path package.module:ClassName naming a Planner subclass"
    )


def test_an_import_path_chooses_a_planner_without_registering_it():
    from controllers import default_planner, planner_for

    mppi, _ = default_settings("softrom_gym/BeamWalk-v0", "mppi")
    planner, every = planner_for("softrom_gym/BeamWalk-v0", f"{__name__}:Halver")
    # its settings class found by the annotation, with that class's own defaults
    assert type(planner) is Halver and every == 30
    assert planner.settings == HalverSettings.from_shared(mppi)
    planner, _ = default_planner("softrom_gym/BeamWalk-v0", "examples.cem_planner:CEM")
    assert type(planner).__name__ == "CEM" and planner.settings.samples == 8
    # a shipped planner by its path is the registered one, tuned defaults included
    planner, _ = planner_for("softrom_gym/BeamWalk-v0", "controllers.mppi:MPPI")
    assert planner.settings == mppi
    for path, error, message in (
        ("no_such_module_here:X", ValueError, "no module named 'no_such_module_here' on "
         "sys.path or in the current directory"),
        (f"{__name__}:Nope", ValueError, f"module '{__name__}' has no 'Nope'"),
        (f"{__name__}:HalverSettings", TypeError, "must be a Planner subclass"),
        ("controllers.planner:Planner", TypeError, "does not implement optimise"),
        ("my planners:CEM", ValueError, "neither registered .* nor an import path"),
    ):  # fmt: skip
        with pytest.raises(error, match=message):
            planner_for("softrom_gym/BeamWalk-v0", path)


def test_an_import_path_is_found_in_the_current_directory(tmp_path, monkeypatch):
    # (rbbo's console script does not put the current directory on sys.path, as python -m does)
    import os
    import sys

    from controllers import resolve_planner

    (tmp_path / "own_planners_here.py").write_text(
        f"from {__name__} import Halver\n\n\nclass Mine(Halver):\n    name = 'mine'\n"
    )
    here = {os.getcwd(), str(tmp_path), ""}
    monkeypatch.setattr(sys, "path", [p for p in sys.path if p not in here])
    monkeypatch.chdir(tmp_path)
    try:
        entry = resolve_planner("own_planners_here:Mine")
        assert entry.planner_class.name == "mine" and entry.settings_class is HalverSettings
        assert sys.path[-1] == str(tmp_path)  # (after the installed packages)
    finally:
        sys.modules.pop("own_planners_here", None)


class Holder:
    class Nested(Halver):
        """A planner class inside a class: its import path is by its qualified name."""

        name = "nested"


def test_a_registered_class_inside_a_class_is_recorded_by_its_qualified_name(registry):
    import json

    from controllers import planner_from_source, planner_source, register_planner

    register_planner("nested", Holder.Nested)
    source = json.loads(json.dumps(planner_source("nested")))
    assert source["planner_class"] == f"{__name__}:Holder.Nested"
    assert planner_from_source("nested", source) == registry.resolve_planner("nested")


def test_the_current_directory_is_appended_only_for_a_module_not_found_elsewhere(
    tmp_path, monkeypatch
):
    # (an import path found on sys.path, or already imported, leaves sys.path as it was; a
    # class of __main__, whose __spec__ is None in a script, is not looked for: find_spec
    # raised ValueError for it)
    import os
    import sys

    from controllers import resolve_planner

    lib, work = tmp_path / "lib", tmp_path / "work"
    lib.mkdir()
    work.mkdir()
    (lib / "own_planners_on_path.py").write_text(
        f"from {__name__} import Halver\n\n\nclass Mine(Halver):\n    name = 'mine'\n"
    )
    here = {os.getcwd(), str(work), ""}
    monkeypatch.setattr(sys, "path", [p for p in sys.path if p not in here] + [str(lib)])
    monkeypatch.chdir(work)
    before = list(sys.path)
    try:
        assert resolve_planner(f"{__name__}:Halver").planner_class is Halver
        assert sys.path == before
        monkeypatch.setattr(sys.modules["__main__"], "Scripted", Halver, raising=False)
        assert resolve_planner("__main__:Scripted").planner_class is Halver
        assert sys.path == before
        assert resolve_planner("own_planners_on_path:Mine").planner_class.name == "mine"
        assert sys.path == before
        # (a module found nowhere, a typo: the current directory was tried, and is taken off
        # again, so sys.path is the process's as before)
        with pytest.raises(ValueError, match="no module named 'own_planners_nowhere'"):
            resolve_planner("own_planners_nowhere:Mine")
        assert sys.path == before
    finally:
        sys.modules.pop("own_planners_on_path", None)


def test_a_class_its_module_does_not_hold_by_its_name_is_not_recorded(registry):
    # (made by type() in a function, or shadowed by another object of that name: another
    # process importing the path would find nothing, or something else)
    from controllers import PlannerNotImportable, planner_source, register_planner

    register_planner("ghost", type("Ghost", (Halver,), {"__module__": __name__}))
    with pytest.raises(PlannerNotImportable, match=f"which its module '{__name__}' does "
                       "not hold by that name"):  # fmt: skip
        planner_source("ghost")


def test_a_module_missing_what_it_imports_raises_its_own_error(tmp_path, monkeypatch):
    # (not "no module named 'no_such_dependency_here' on sys.path or in the current
    # directory", which would send the user looking for the dependency in the wrong place)
    import sys

    from controllers import resolve_planner

    (tmp_path / "own_planners_broken.py").write_text("import no_such_dependency_here\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    try:
        with pytest.raises(ModuleNotFoundError, match="'no_such_dependency_here'"):
            resolve_planner("own_planners_broken:Mine")
    finally:
        sys.modules.pop("own_planners_broken", None)
