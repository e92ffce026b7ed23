"""The package reads top-down: every import of a snake_env module, at module level or inside a
function, goes to the same layer or one below it. Order: dynamics -> physics -> controllers ->
tasks -> envs -> wrappers -> agents -> train; ``benchmarks`` sits beside ``train``; the leaf
helpers (atomic writes, config lookup) below everything; registration and the package's
``__init__`` on top of the core."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
# snake_env.<part> -> (folder or file in the repository, rank); equal ranks may import each other
PARTS = {
    "atomic": ("snake_env/atomic.py", 0),
    "configfiles": ("snake_env/configfiles.py", 0),
    "dynamics": ("snake_env/dynamics", 1),
    "physics": ("snake_env/physics", 2),
    "controllers": ("snake_env/controllers", 3),
    "tasks": ("snake_env/tasks", 4),
    "envs": ("snake_env/envs", 5),
    "wrappers": ("snake_env/wrappers", 6),
    "registration": ("snake_env/registration.py", 7),
    "__init__": ("snake_env/__init__.py", 7),
    "agents": ("agents", 8),
    "train": ("train", 9),
    "benchmarks": ("benchmarks", 9),
}
CORE_TOP = 7


def _modules(location: str) -> list[Path]:
    path = REPO / location
    if path.suffix == ".py":
        return [path] if path.is_file() else []
    if path.with_suffix(".py").is_file():  # a part that is still a single module
        return [path.with_suffix(".py")]
    return sorted(path.rglob("*.py"))


def _package_of(part: str, path: Path) -> list[str]:
    """The dotted package a module lives in (for relative imports)."""
    location = REPO / PARTS[part][0]
    if location.is_dir():
        return ["snake_env", part, *path.parent.relative_to(location).parts]
    return ["snake_env"]


def _imported_parts(part: str, path: Path) -> list[tuple[int, str]]:
    """(line, snake_env part) of every import in the module, relative ones resolved."""
    out = []
    package = _package_of(part, path)
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        names = []
        if isinstance(node, ast.Import):
            names = [alias.name for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package[:len(package) - node.level + 1]
                names = [".".join(base + ([node.module] if node.module else []))]
                if not node.module and len(base) == 1:  # from . import x (in the package root)
                    names = [f"snake_env.{alias.name}" for alias in node.names]
            else:
                names = [node.module or ""]
                if node.module == "snake_env":
                    names = [f"snake_env.{alias.name}" for alias in node.names]
        for name in names:
            pieces = name.split(".")
            if pieces[0] == "snake_env" and len(pieces) > 1:
                out.append((node.lineno, pieces[1]))
    return out


@pytest.mark.parametrize("part", PARTS)
def test_no_module_imports_a_layer_above_its_own(part):
    location, rank = PARTS[part]
    modules = _modules(location)
    assert modules, f"{location} holds no module"
    upward = []
    for path in modules:
        for line, target in _imported_parts(part, path):
            if target not in PARTS:
                upward.append(f"{path.relative_to(REPO)}:{line} imports unknown part snake_env.{target}")
            elif PARTS[target][1] > rank:
                upward.append(f"{path.relative_to(REPO)}:{line} imports snake_env.{target} (a layer above)")
    assert not upward, "\n".join(upward)


def test_the_core_never_imports_agents_train_or_benchmarks():
    for part, (location, rank) in PARTS.items():
        if rank > CORE_TOP:
            continue
        for path in _modules(location):
            bad = [t for _, t in _imported_parts(part, path) if t in ("agents", "train", "benchmarks")]
            assert not bad, f"{path.relative_to(REPO)} imports {bad}"


def test_the_checker_sees_relative_and_function_level_imports(tmp_path, monkeypatch):
    """The tests above could pass by not seeing imports: the checker must resolve these."""
    package = tmp_path / "probe"
    (package / "sub").mkdir(parents=True)
    module = package / "sub" / "m.py"
    module.write_text("from ...tasks import Task\nfrom .. import helpers\n\n\ndef f():\n"
                      "    from snake_env.agents import search\n    import snake_env.train.config\n"
                      "    from snake_env import envs\n")
    monkeypatch.setitem(PARTS, "probe", (str(package), 3))
    assert [t for _, t in _imported_parts("probe", module)] == ["tasks", "probe", "agents", "train", "envs"]
