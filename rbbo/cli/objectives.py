"""What an ``rbbo`` command evaluates: the env an ENV_ID names, and a stored run's objective.

Each check here is a usage error when it fails: an unknown ENV_ID (listing the registered
ones), a ``controllers`` module that is not softrom's, a run whose config does not say what
its objective is.
"""

from __future__ import annotations

from .errors import UsageError, _bad_input


def _resolve_env(env_id: str, synthetic: bool = True) -> str:
    """A registered env id (short names get the softrom_gym/ namespace). ``synthetic``: the
    command also accepts the synthetic objective (the error message lists it)."""
    import gymnasium as gym

    import softrom_gym  # noqa: F401  (registers the envs)

    if env_id not in gym.registry and f"softrom_gym/{env_id}" in gym.registry:
        env_id = f"softrom_gym/{env_id}"
    if env_id not in gym.registry:
        known = sorted(k for k in gym.registry if k.startswith("softrom_gym/"))
        also = ", synthetic" if synthetic else ""
        raise UsageError(f"unknown ENV_ID {env_id!r}; registered: {', '.join(known)}{also}")
    return env_id


def _check_controllers() -> None:
    try:
        import controllers
    except ImportError as exc:  # pragma: no cover - part of this package
        raise UsageError(f"the env objective needs the controllers package: {exc}") from None
    missing = [n for n in ("run_episode", "MPPI", "GaussNewtonShooting")
               if not hasattr(controllers, n)]  # fmt: skip
    if missing:
        # "controllers" is a common name: a user's own module of that name can shadow ours.
        where = getattr(controllers, "__file__", None) or "a module without a file"
        raise UsageError(
            f"controllers has no {', '.join(missing)}: the module imported as controllers "
            f"({where}) is not softrom's (another package or file of that name first on "
            "sys.path?); use ENV_ID 'synthetic' to try rbbo without the simulator"
        )


def _objective_of(opt):
    from ..objective import make_objective

    spec = opt.objective_spec
    if not isinstance(spec, dict) or "kind" not in spec:
        raise UsageError(f"{opt.store.path}/config.json does not say what the objective is")
    if spec["kind"] == "env":
        _check_controllers()
    with _bad_input():
        return make_objective(spec, opt.config.sim_dim, opt.config.control_dim)
