"""The README stays true: its Python examples run, and its command lines name options that
exist, scripts that exist, and the install and test commands that CI runs."""

import re
import shlex
from pathlib import Path

import pytest

README = Path(__file__).resolve().parent.parent / "README.md"
CI_RUN = README.parent / ".ci" / "run"


def _blocks(language: str) -> list[str]:
    return re.findall(rf"^```{language}\n(.*?)^```", README.read_text(), flags=re.S | re.M)


def _command_lines() -> list[list[str]]:
    """Every command of the README's bash blocks, as argv lists (comments dropped, ``&&``
    chains split)."""
    commands = []
    for block in _blocks("bash"):
        for line in block.splitlines():
            words = shlex.split(line, comments=True)
            while words:
                end = words.index("&&") if "&&" in words else len(words)
                commands.append(words[:end])
                words = words[end + 1 :]
    return commands


PYTHON_BLOCKS = _blocks("python")
# The MPC episode example runs a 10-s quadruped episode (10-25 s of wall time on 2 cores).
SLOW_BLOCK = "run_episode("


def test_the_readme_has_its_examples():
    assert len(PYTHON_BLOCKS) >= 4
    assert len(_command_lines()) >= 30


@pytest.mark.parametrize(
    "source",
    [
        pytest.param(b, id=f"block{i}", marks=[pytest.mark.slow] if SLOW_BLOCK in b else [])
        for i, b in enumerate(PYTHON_BLOCKS, start=1)
    ],
)
def test_each_python_example_runs(source, tmp_path, monkeypatch):
    """As a reader pastes it, in a fresh namespace (warnings are errors, as everywhere in the
    suite: an example must not warn either)."""
    monkeypatch.chdir(tmp_path)  # anything an example writes lands here
    exec(compile(source, "README.md", "exec"), {"__name__": "__readme__"})


def test_the_first_two_commands_are_the_main_job_and_the_tests():
    """The README's first lines give exactly two set-up commands: an rbbo run, and the tests
    with the install CI uses."""
    first, second = _blocks("bash")[:2]
    assert "rbbo optimize" in first and first.startswith("python3 -m venv .venv && ")
    assert second.strip() == (
        "python3 -m venv .venv && .venv/bin/pip install torch==2.13.0 && "
        '.venv/bin/pip install -e ".[test]" && .venv/bin/pytest'
    )
    ci = [line.strip() for line in CI_RUN.read_text().splitlines()]
    for step in (
        ".venv/bin/pip install torch==2.13.0",
        '.venv/bin/pip install -e ".[test]"',
        "python3 -m venv .venv",
    ):
        assert step in ci, f".ci/run does not run the README's {step!r}"
    assert any(line.startswith(".venv/bin/pytest") for line in ci)


def test_every_rbbo_command_parses():
    """Each ``rbbo ...`` line parses with the command's own parser (nothing is run): an
    option renamed in the code but not in the README fails here."""
    from rbbo.cli.parser import _parser

    lines = [c for c in _command_lines() if c and c[0].endswith("bin/rbbo")]
    assert len(lines) >= 8
    for argv in lines:
        _parser().parse_args(argv[1:])  # raises UsageError naming the bad option


def test_every_controllers_command_parses():
    from controllers.__main__ import _parser

    lines = [c for c in _command_lines() if c[1:3] == ["-m", "controllers"]]
    assert lines
    for argv in lines:
        _parser().parse_args(argv[3:])


def test_every_benchmark_script_named_exists():
    scripts = [c[1] for c in _command_lines() if len(c) > 1 and c[1].startswith("benchmarks/")]
    assert len(scripts) >= 15
    missing = [s for s in scripts if not (README.parent / s).is_file()]
    assert not missing, f"the README names benchmark scripts that do not exist: {missing}"


def test_every_file_the_readme_cites_exists():
    # A prose reference (`tests/...py`, `docs/...md`) is not a command, so no other test
    # sees it go stale when a file is renamed or removed.
    cited = set(re.findall(r"`((?:benchmarks|tests|docs|rbbo|softrom_gym|controllers|cpp_sim)"
                           r"/[\w./-]+\.(?:py|pyi|md|cpp|h|npy|json|csv|png))`",
                           README.read_text()))  # fmt: skip
    assert len(cited) >= 15
    missing = sorted(p for p in cited if not (README.parent / p).exists())
    assert not missing, f"the README cites files that do not exist: {missing}"


def test_the_scripts_said_to_take_json_do_and_the_other_checks_do_not():
    text = README.read_text()
    paragraph = next(p for p in text.split("\n\n") if "take `--json` for one JSON" in p)
    said = set(re.findall(r"`(\w+\.py)`", paragraph))
    assert len(said) >= 10

    def takes_json(name: str) -> bool:
        return '"--json"' in (README.parent / "benchmarks" / name).read_text()

    assert sorted(s for s in said if not takes_json(s)) == []
    # "the other checks and studies print text only"
    named = set(re.findall(r"`(?:benchmarks/)?((?:check|study)_\w+\.py)`", text))
    assert sorted(s for s in named - said if takes_json(s)) == []


def test_every_name_the_benchmark_scripts_import_from_the_package_exists(monkeypatch):
    # The scripts are run by hand, for minutes each, and most import inside the function that
    # needs a name: a module split that moves a name breaks them silently until someone runs
    # the one measurement that imports it. Every import of theirs, lazy ones too, must
    # resolve.
    import ast
    import importlib

    folder = README.parent / "benchmarks"
    monkeypatch.syspath_prepend(str(folder))  # (their shared helpers: _actuation, _runs, ...)
    ours = {"rbbo", "softrom_gym", "controllers", "cpp_sim"} | {
        p.stem for p in folder.glob("_*.py")
    }
    missing, checked = [], 0
    for script in sorted(folder.glob("*.py")):
        for node in ast.walk(ast.parse(script.read_text())):
            if isinstance(node, ast.Import):
                imports = [(a.name, None) for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                imports = [(node.module, a.name) for a in node.names]
            else:
                continue
            for module, name in imports:
                if module.split(".")[0] not in ours:
                    continue
                checked += 1
                try:
                    imported = importlib.import_module(module)
                    if name is not None and not hasattr(imported, name):
                        importlib.import_module(f"{module}.{name}")  # (a submodule)
                except ImportError:
                    missing.append(f"{script.name}: {module}" + (f".{name}" if name else ""))
    assert checked > 100
    assert not missing, f"benchmark scripts import names that do not exist: {missing}"


def test_every_option_the_readme_gives_a_benchmark_script_exists():
    # The scripts are not run by the suite (minutes each), so an option renamed in a script
    # but not in the README's prose (`bench_rom.py --rounds 3`) or its bash block went stale
    # silently. Each --option written after a script's name, within the same `...` span or
    # command line, must be one that script defines ("--option" in its source).
    folder = README.parent / "benchmarks"
    text = README.read_text()
    prose = re.sub(r"^```.*?^```", "", text, flags=re.S | re.M)  # (fences break the pairing)
    spans = re.findall(r"`([^`]+)`", prose) + [" ".join(c) for c in _command_lines()]
    checked, stale = 0, []
    for span in spans:
        # split at each script name: an option belongs to the script named before it
        parts = re.split(r"(?:benchmarks/)?(\w+\.py)\b", span)
        for script, args in zip(parts[1::2], parts[2::2], strict=True):
            path = folder / script
            if not path.is_file():
                continue
            source = path.read_text()
            for option in re.findall(r"(?<![\w-])(--[a-z][a-z0-9-]*)", args.split("#")[0]):
                checked += 1
                if f'"{option}"' not in source:
                    stale.append(f"{script} {option}")
    assert checked >= 20
    assert not stale, f"the README gives benchmark scripts options they lack: {sorted(stale)}"
