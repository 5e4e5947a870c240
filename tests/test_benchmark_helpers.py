"""What the benchmark scripts measure with, beyond the package: their shared writers
(``benchmarks/_results.py``) and ``bench_mpc.py``'s physics floor."""

from pathlib import Path

import pytest

BENCHMARKS = Path(__file__).resolve().parent.parent / "benchmarks"


def test_a_benchmark_figure_is_replaced_whole_or_not_at_all(tmp_path, monkeypatch):
    # A run stopped while it draws (Ctrl-C, a kill, a full disk) must leave the last run's
    # figure, not a truncated PNG in its place, nor a temporary file beside it.
    pytest.importorskip("matplotlib")
    from matplotlib.figure import Figure

    monkeypatch.syspath_prepend(str(BENCHMARKS))
    import _results

    png = tmp_path / "study" / "cost_vs_c.png"  # (a folder not made yet)
    series = {"one GN iteration": ([1, 2, 3], [0.1, 0.2, 0.4], None)}
    _results.plot_lines(series, "C", "wall time (s)", png)
    before = png.read_bytes()
    assert before.startswith(b"\x89PNG")

    def torn(self, target, **kwargs):  # half an image, to a file object or a path
        if isinstance(target, (str, Path)):
            Path(target).write_bytes(b"\x89PNG half an ima")
        else:
            target.write(b"\x89PNG half an ima")
        raise KeyboardInterrupt

    monkeypatch.setattr(Figure, "savefig", torn)
    with pytest.raises(KeyboardInterrupt):
        _results.plot_lines(series, "C", "wall time (s)", png)
    assert png.read_bytes() == before
    assert [p.name for p in png.parent.iterdir()] == ["cost_vs_c.png"]


def test_a_benchmark_table_is_replaced_whole_or_not_at_all(tmp_path, monkeypatch):
    import csv

    monkeypatch.syspath_prepend(str(BENCHMARKS))
    import _results

    table = tmp_path / "runs" / "bench.csv"  # (a folder not made yet)
    _results.write_csv([{"C": 1, "s": 0.5}, {"C": 2, "s": 0.75}], table)
    before = table.read_bytes()
    assert list(csv.DictReader(before.decode().splitlines())) == [
        {"C": "1", "s": "0.5"}, {"C": "2", "s": "0.75"}]  # fmt: skip

    def torn(self, rows):  # a row written, then the run stopped
        self.writerow(rows[0])
        raise KeyboardInterrupt

    monkeypatch.setattr(csv.DictWriter, "writerows", torn)
    with pytest.raises(KeyboardInterrupt):
        _results.write_csv([{"C": 3, "s": 1.0}, {"C": 4, "s": 2.0}], table)
    assert table.read_bytes() == before
    assert [p.name for p in table.parent.iterdir()] == ["bench.csv"]


def test_bench_mpc_replays_each_replan_whole_and_leaves_the_episode_as_it_was(monkeypatch):
    # plan/phys is a replan over its own rollouts run again as one batch: the replay must hold
    # every rollout of that replan (and none of the gait seed's at reset), and must not move
    # the episode it measures.
    import gymnasium as gym
    import numpy as np

    import softrom_gym  # noqa: F401  (registers the envs)
    from controllers import default_planner, run_episode

    monkeypatch.syspath_prepend(str(BENCHMARKS))
    from bench_mpc import PhysicsFloor

    replayed = []

    class Counting(PhysicsFloor):
        def _replay(self):
            state = self.calls[-1][0]
            replayed.append(sum(u.shape[0] for s, u, _, _ in self.calls if s is state))
            super()._replay()

    env_id = "softrom_gym/CrossSwim-v0"
    results = []
    for env in (gym.make(env_id), Counting(gym.make(env_id))):
        planner, every = default_planner(env_id, "gn", threads=2, horizon=10, window=None,
                                         seed_horizon=10)  # fmt: skip
        results.append(run_episode(env, planner, 1.0, replan_every=every, seed=0,
                                   progress=False))  # fmt: skip
        env.close()
    plain, measured = results
    assert measured.replans == 2 == len(env.wall_s) == len(env.inside_s)
    assert replayed == [r["rollouts"] for r in measured.replan_records]
    assert np.array_equal(plain.actions, measured.actions)
    assert np.array_equal(plain.com, measured.com)
