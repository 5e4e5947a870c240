"""RL baselines: Stable-Baselines3 PPO and SAC in the same control spaces B_c as the MPC.

Each (algorithm, basis) trains in ``OUT/<algo>-<basis>/``: ``checkpoints/step_<n>.zip`` every
``checkpoint_every`` env steps and at the end, with ``step_<n>.json`` (its training wall time)
beside it (the latest also keeps ``step_<n>_state.pkl``: the generators and the training env
part-way through its episode; SAC also keeps the latest replay buffer; so a resume goes on
bitwise as the job trained straight through),
``final.zip``, ``run.json`` (what was trained: a re-run with
the same OUT continues from the latest checkpoint and refuses another env, basis or seed; a
larger ``steps`` trains the same run further, SAC keeping the replay-buffer size it was
created with, the oldest transitions replaced) and
``progress.jsonl`` (append-only: per checkpoint the env steps, the training wall time and the
evaluation), and SB3's own training log, ``sb3/from_step_<n>/progress.csv`` per training
segment (losses, entropy, fps; a resume starts a new one). Every checkpoint is evaluated, so
the table shows distance against simulator steps spent. The MPC planner
(``controllers.default_planner(env_id, "mppi")``) runs beside it on the same bases, seeds and
seconds; its results are cached in ``OUT/mppi-<basis>/``.

Evaluation: the deterministic policy, one episode of ``seconds`` from ``env.reset(seed=s)``
per seed; the score is the distance along the task direction from ``settle_time`` to the end
(m, and body lengths), mean ± 95 % t-interval over the seeds. Cost: for RL the env steps
trained and the physics steps (env steps x frame_skip) and training wall time (evaluation
excluded); for MPC, per episode, the physics steps of every planning rollout plus the
executed ones, and the episode's wall time.
"""

# The RL baselines, module by job: algorithms.py (which algorithms, their env steps, and
# Stable-Baselines3), bases.py (the control bases by name), envs.py (the env a job acts in),
# evaluation.py (a policy's distance per seed and their t-interval), progress.py (a job's
# folder: its claim and progress log), training.py (an RL job: train, checkpoint, evaluate),
# mpc.py (an MPC job beside it), jobs.py (run_baselines: the jobs and their worker processes)
# and table.py (the result rows and their table). The names below are re-exported so that
# imports from rbbo.rl keep working.
from .algorithms import ALGOS, DEFAULT_STEPS, parse_steps, require_sb3, steps_per_algo
from .bases import _expect_run_space as _expect_run_space
from .bases import resolve_bases
from .envs import SET_BY_BASELINES
from .envs import _make_env as _make_env
from .evaluation import EVAL_SEED0, evaluate_policy, t_interval
from .jobs import _job as _job
from .jobs import _run_jobs as _run_jobs
from .jobs import _torch_threads as _torch_threads
from .jobs import run_baselines
from .mpc import _mpc as _mpc
from .progress import _claim as _claim
from .progress import _read_progress as _read_progress
from .progress import _wall_at_checkpoint as _wall_at_checkpoint
from .table import _COLUMNS as _COLUMNS
from .table import _reached as _reached
from .table import _row as _row
from .table import format_table
from .training import _train as _train

__all__ = [
    "ALGOS",
    "DEFAULT_STEPS",
    "EVAL_SEED0",
    "SET_BY_BASELINES",
    "evaluate_policy",
    "format_table",
    "parse_steps",
    "require_sb3",
    "resolve_bases",
    "run_baselines",
    "steps_per_algo",
    "t_interval",
]
