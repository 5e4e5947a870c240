"""Planners chosen by name: what ``planner_for``, ``python -m controllers --planner`` and
``rbbo optimize --controller`` accept.

A name is either registered (the shipped "mppi" and "gn", or one given to
:func:`register_planner`) or an import path ``package.module:ClassName`` naming a
:class:`~controllers.Planner` subclass, imported when asked for. A process that finds planners
by name alone (``rbbo``'s worker processes, ``rbbo resume``, which read it from a run's
config.json) imports an import path by itself; a registered name exists there only if the
code that registers it runs there too. So ``rbbo`` records with a registered name its
:func:`planner_source` (the import paths of its classes and its defaults), and a process
without the registration chooses the same planner by :func:`planner_from_source`: a class
registered in a notebook or in a script's ``if __name__ == "__main__":`` block is found
there, as long as it is defined in a module of its own (one defined in ``__main__`` or inside
a function cannot be imported elsewhere, and ``rbbo`` refuses it up front).
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.util
import inspect
import os
import sys
import typing
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .planner import Planner
from .settings import PlannerSettings

__all__ = [
    "PlannerEntry",
    "PlannerNotImportable",
    "planner_from_source",
    "planner_source",
    "register_planner",
    "registered_planners",
    "resolve_planner",
]


class PlannerNotImportable(ValueError):
    """A registered planner's class that another process cannot import by its path (defined
    in ``__main__`` or inside a function): :func:`planner_source` cannot record it."""


@dataclass(frozen=True)
class PlannerEntry:
    """A planner as a name chooses it.

    Attributes
    ----------
    name : str
        The registered name, or the import path it was found by.
    planner_class : type of Planner
        Made as ``planner_class(settings, dt=dt)``.
    settings_class : type of PlannerSettings
        Made with a benchmark's plan and objective (:func:`controllers.planner_for`), then
        ``defaults``, then the caller's changes.
    defaults : mapping
        Tuned values of the planner's own settings (MPPI's samples, Gauss-Newton's fd_step);
        empty: the settings class's own defaults.
    """

    name: str
    planner_class: type[Planner]
    settings_class: type[PlannerSettings]
    defaults: Mapping[str, Any] = field(default_factory=dict)


_REGISTRY: dict[str, PlannerEntry] = {}


def register_planner(
    name: str,
    planner_class: type[Planner],
    settings_class: type[PlannerSettings] | None = None,
    *,
    defaults: Mapping[str, Any] | None = None,
) -> None:
    """Let ``name`` choose ``planner_class`` wherever "mppi" and "gn" are accepted.

    Parameters
    ----------
    name : str
        A new name (letters, digits, ``_``, ``-`` and ``.``; no ``:``, which marks an import
        path). A name already registered is refused: unregistering is not offered, so a
        planner chosen by name is the same one for the whole process.
    planner_class : type of Planner
        A concrete subclass (it implements :meth:`~controllers.Planner.optimise`).
    settings_class : type of PlannerSettings, optional
        Its settings (default: ``planner_class.settings_class``).
    defaults : mapping, optional
        Tuned values of settings of the planner's own, applied on every benchmark. A benchmark's
        plan and objective (horizon, period, window, knots, gait seed, weights; or the shared
        :data:`controllers.GENERIC` row on a robot without one) come from
        :data:`controllers.DEFAULTS` for every planner, registered or shipped; without
        ``defaults`` the rest are the settings class's own defaults.

    Registering in a notebook or a script is enough for ``rbbo``: its objective records the
    classes' import paths and ``defaults`` with the name (:func:`planner_source`), and its
    worker processes and ``rbbo resume`` choose the planner by them. That needs classes
    defined in a module (not in ``__main__`` nor inside a function) and ``defaults`` of plain
    values (numbers, strings, booleans, None, tuples of them). An import path
    ``package.module:ClassName`` needs no registering.
    """
    if not isinstance(name, str) or not name or not all(c.isalnum() or c in "_-." for c in name):
        raise ValueError(
            f"planner name must be a non-empty string of letters, digits, '_', '-' and '.', "
            f"got {name!r} (a ':' marks an import path, package.module:ClassName)"
        )
    if name in _REGISTRY:
        raise ValueError(
            f"planner name {name!r} is already registered, to "
            f"{_qualified(_REGISTRY[name].planner_class)}: choose another name"
        )
    _check_planner_class(planner_class, f"planner_class for {name!r}")
    if settings_class is None:
        settings_class = _settings_class_of(planner_class)
    if not (isinstance(settings_class, type) and issubclass(settings_class, PlannerSettings)):
        raise TypeError(f"settings_class for {name!r} must be a PlannerSettings subclass, got "
                        f"{settings_class!r}")  # fmt: skip
    # numpy's numbers and arrays as Python's numbers and tuples: a run records the settings
    # as JSON, where np.int64(4) was its repr, and a resume (which reads 4) another planner
    defaults = {k: _python(v) for k, v in (defaults or {}).items()}
    known = {f.name for f in dataclasses.fields(settings_class)}
    unknown = sorted(set(defaults) - known)
    if unknown:
        raise TypeError(f"defaults for {name!r}: unknown {settings_class.__name__} setting "
                        f"{', '.join(map(repr, unknown))}")  # fmt: skip
    shared = sorted(set(defaults) & _shared_settings())
    if shared:
        # (planner_for passes the benchmark's values of these beside the defaults: a
        # duplicate keyword there, and a planner that plans another gait than its rivals)
        raise TypeError(
            f"defaults for {name!r} set {', '.join(map(repr, shared))}, which belong to the "
            "benchmark's plan and objective that every planner shares (controllers.DEFAULTS); "
            "change "
            "them per call instead (planner_for(env_id, name, horizon=...), or rbbo's "
            "planner_kwargs)"
        )
    _REGISTRY[name] = PlannerEntry(name, planner_class, settings_class, defaults)


def _shared_settings() -> set[str]:
    """The settings a benchmark's row sets for every planner (plan, gait seed, weights)."""
    from .defaults import _COMMON, DEFAULTS, GENERIC

    keys = set(_COMMON) | set(GENERIC) | {"weights"}
    for row in DEFAULTS.values():
        keys |= set(row)
    return keys


def registered_planners() -> tuple[str, ...]:
    """The registered planner names, sorted (an import path is accepted besides them)."""
    return tuple(sorted(_REGISTRY))


def resolve_planner(name: str | PlannerEntry) -> PlannerEntry:
    """The planner ``name`` chooses: a registered name, or an import path
    ``package.module:ClassName`` of a :class:`~controllers.Planner` subclass (a
    :class:`PlannerEntry`, such as :func:`planner_from_source` gives, is returned as it is).

    An import path's module is imported from ``sys.path``; one that is not found there is
    looked for in the current directory too (which is then appended to ``sys.path``), as
    ``python -m`` finds it, so that ``rbbo optimize ... --controller my_planners:CEM`` run
    next to ``my_planners.py`` finds it, and so do its spawned workers. A class that is also
    registered gets its registered defaults.

    Raises
    ------
    ValueError
        For an unknown name (listing the registered ones and the import-path form) or an
        import path that names no module or attribute.
    TypeError
        For a name that is not a string, or an import path that names no concrete Planner
        subclass.
    """
    if isinstance(name, PlannerEntry):
        return name
    if not isinstance(name, str):
        raise TypeError(f"planner must be a name (str), got {name!r}")
    entry = _REGISTRY.get(name)
    if entry is not None:
        return entry
    if ":" not in name:
        raise ValueError(unknown_planner_message(name))
    cls = _imported(name)
    for entry in _REGISTRY.values():
        if entry.planner_class is cls:
            return dataclasses.replace(entry, name=name)
    return PlannerEntry(name, cls, _settings_class_of(cls))


def planner_source(name: str) -> dict[str, Any]:
    """What lets a process where ``name`` is not registered choose the planner it chooses here:
    the import paths of its planner and settings classes and its registered defaults, as JSON.

    ``rbbo`` records it with a registered name (the objective's spec, config.json), so that
    its spawned workers and a later ``rbbo resume``, where the code that registered the name
    did not run (a script's ``if __name__ == "__main__":`` block, a notebook), find the same
    planner with :func:`planner_from_source`.

    Returns
    -------
    dict
        ``{"planner_class": "package.module:ClassName", "settings_class": ...,
        "defaults": {...}}``, the defaults with numpy's numbers and arrays and tuples as
        Python's numbers and lists.

    Raises
    ------
    PlannerNotImportable
        A ValueError, for a class that another process cannot import by its path (defined in
        ``__main__``, a script run directly or a notebook, or inside a function), saying so
        and what to do.
    ValueError
        For a name that is not registered, or defaults that JSON cannot hold.
    """
    entry = _REGISTRY.get(name)
    if entry is None:
        raise ValueError(unknown_planner_message(name))
    paths = {}
    for key, cls in (("planner_class", entry.planner_class),
                     ("settings_class", entry.settings_class)):  # fmt: skip
        why = _not_importable(cls)
        if why is not None:
            raise PlannerNotImportable(
                f"planner {name!r} is registered to {_qualified(cls)}, {why}: another process "
                "(rbbo's worker processes, a later rbbo resume) cannot import it, so it could "
                "not find this planner by its name. Define the class in a module of its own "
                "(my_planners.py, imported where you register it), or choose it by its import "
                "path (my_planners:ClassName)"
            )
        paths[key] = _qualified(cls)
    defaults = {}
    for key, value in entry.defaults.items():
        plain = _json_plain(value)
        if plain is _NOT_JSON:
            raise ValueError(f"planner {name!r}: its default {key} = {value!r} is not a plain "
                             "value (numbers, strings, booleans, None, lists of them) that a "
                             "run's config.json can record")  # fmt: skip
        defaults[key] = plain
    return {**paths, "defaults": defaults}


def planner_from_source(name: str, source: Mapping[str, Any]) -> PlannerEntry:
    """The planner that a registered ``name`` chose where :func:`planner_source` gave
    ``source``: its classes imported by their paths, with its defaults (lists as tuples, as
    settings hold them). Pass it to :func:`controllers.planner_for` in place of the name.

    Raises
    ------
    ValueError
        For a ``source`` that is not what :func:`planner_source` gives, or a path that names
        no module or attribute.
    TypeError
        For paths that name no concrete Planner or PlannerSettings subclass.
    """
    if not (isinstance(source, Mapping)
            and set(source) == {"planner_class", "settings_class", "defaults"}
            and isinstance(source["defaults"], Mapping)):  # fmt: skip
        raise ValueError(f"the source of planner {name!r} must be a dict with planner_class, "
                         f"settings_class and defaults (controllers.planner_source), got "
                         f"{source!r}")  # fmt: skip
    planner_class = _imported(str(source["planner_class"]))
    settings_path = str(source["settings_class"])
    settings_class: Any = _attribute(settings_path)
    if not (isinstance(settings_class, type) and issubclass(settings_class, PlannerSettings)):
        raise TypeError(f"settings_class of planner {name!r}: {settings_path!r} is not a "
                        "PlannerSettings subclass")  # fmt: skip
    defaults = {k: _tuples(v) for k, v in source["defaults"].items()}
    return PlannerEntry(name, planner_class, settings_class, defaults)


def unknown_planner_message(name: str) -> str:
    """What an unknown planner name is told: the registered names and the import-path form."""
    return (
        f"unknown planner {name!r}; registered: {', '.join(registered_planners())} "
        "(controllers.register_planner adds one), or an import path "
        "package.module:ClassName naming a Planner subclass"
    )


class _PlannerTable(Mapping[str, tuple[type[Planner], type[PlannerSettings]]]):
    """The registered planners as ``{name: (planner class, settings class)}``, a read-only
    view that follows :func:`register_planner` (``controllers.defaults.PLANNERS``)."""

    def __getitem__(self, name: str) -> tuple[type[Planner], type[PlannerSettings]]:
        entry = _REGISTRY[name]
        return entry.planner_class, entry.settings_class

    def __iter__(self) -> Iterator[str]:
        return iter(_REGISTRY)

    def __len__(self) -> int:
        return len(_REGISTRY)


def _qualified(cls: type) -> str:
    return f"{cls.__module__}:{cls.__qualname__}"


def _not_importable(cls: type) -> str | None:
    """Why another process cannot import ``cls`` by :func:`_qualified`; None where it can."""
    if cls.__module__ in ("__main__", "__mp_main__"):
        return "a class defined in __main__ (a script run directly, or a notebook)"
    if "<locals>" in cls.__qualname__:
        return "a class defined inside a function"
    module = sys.modules.get(cls.__module__)
    found: Any = module
    for part in cls.__qualname__.split("."):
        found = getattr(found, part, None)
    if found is not cls:
        return f"which its module {cls.__module__!r} does not hold by that name"
    return None


_NOT_JSON = object()


def _json_plain(value: Any) -> Any:
    """``value`` as JSON holds it (numpy's numbers and arrays and tuples as Python's numbers
    and lists), or ``_NOT_JSON``."""
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if isinstance(value, (list, tuple)):
        items = [_json_plain(v) for v in value]
        return _NOT_JSON if any(v is _NOT_JSON for v in items) else items
    if isinstance(value, np.generic):
        value = value.item()
    if value is None or isinstance(value, (bool, int, float, str)):
        return value
    return _NOT_JSON


def _python(value: Any) -> Any:
    """numpy's numbers and arrays as Python's numbers and tuples (anything else as it is)."""
    if isinstance(value, np.ndarray):
        return _tuples(value.tolist())
    if isinstance(value, np.generic):
        return value.item()
    return value


def _tuples(value: Any) -> Any:
    """JSON's lists as the tuples that settings hold."""
    return tuple(_tuples(v) for v in value) if isinstance(value, list) else value


def _check_planner_class(cls: Any, what: str) -> None:
    if not (isinstance(cls, type) and issubclass(cls, Planner)):
        raise TypeError(f"{what} must be a Planner subclass, got {cls!r}")
    if inspect.isabstract(cls):
        missing = ", ".join(sorted(getattr(cls, "__abstractmethods__", ())))
        raise TypeError(f"{what}: {_qualified(cls)} does not implement {missing}")


def _settings_class_of(cls: type[Planner]) -> type[PlannerSettings]:
    """``cls.settings_class``; for a planner that does not set it, the class of its
    ``settings`` annotation (``settings: CEMSettings``, as the shipped planners write it)."""
    named = cls.settings_class
    if named is not PlannerSettings:
        return named
    try:
        hint = typing.get_type_hints(cls).get("settings")
    except Exception:  # an annotation that names what its module imports only for mypy
        return named
    if isinstance(hint, type) and issubclass(hint, PlannerSettings):
        return hint
    return named


def _imported(path: str) -> type[Planner]:
    """The class an import path ``package.module:ClassName`` names."""
    obj = _attribute(path)
    _check_planner_class(obj, f"planner {path!r}")
    return typing.cast(type[Planner], obj)


def _attribute(path: str) -> Any:
    """What an import path ``package.module:Name`` names."""
    module_name, _, attribute = path.partition(":")
    parts_ok = all(p.isidentifier() for p in module_name.split(".")) and all(
        p.isidentifier() for p in attribute.split(".")
    )
    if not parts_ok:
        raise ValueError(
            f"planner {path!r} is neither registered ({', '.join(registered_planners())}) nor "
            "an import path package.module:ClassName"
        )
    top = module_name.split(".")[0]
    here = os.getcwd()
    on_path = {os.path.abspath(p or os.curdir) for p in sys.path}
    appended = False
    if top not in sys.modules and here not in on_path and importlib.util.find_spec(top) is None:
        sys.path.append(here)  # (after the installed packages: it shadows none of them)
        importlib.invalidate_caches()
        appended = True
    try:
        obj: Any = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name is None or not f"{module_name}.".startswith(f"{exc.name}."):
            raise  # a module that the planner's module imports is missing: its own error
        if appended and top not in sys.modules:
            # (not here either, as a mistyped name: the process's path stays as it was)
            sys.path.remove(here)
        raise ValueError(
            f"planner {path!r}: no module named {exc.name!r} on sys.path or in the current "
            f"directory ({here}); run from the directory that holds it, or add that to "
            "PYTHONPATH"
        ) from None
    for part in attribute.split("."):
        try:
            obj = getattr(obj, part)
        except AttributeError:
            raise ValueError(f"planner {path!r}: module {module_name!r} has no "
                             f"{attribute!r}") from None  # fmt: skip
    return obj
