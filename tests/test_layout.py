"""The package layout is the architecture (DESIGN section 9): data flows one way through the stages,
the estimator never imports the simulator, ``factors/`` sees only the shared vocabulary, and no
module imports itself through a cycle. Checked on the source (``ast``), so a new module is covered
the moment it exists."""
from __future__ import annotations

import ast
import functools
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
SHARED = ("ampc_vo.config", "ampc_vo.epipolar", "ampc_vo.errors", "ampc_vo.geometry", "ampc_vo.observations", "ampc_vo.rig", "ampc_vo")
# rank of each stage in the flow io -> frontend -> solvers -> scale -> factors -> backend -> tools;
# a module may import its own stage and those of lower rank only. The simulator sits beside the
# flow: it may use the shared vocabulary and io (it writes through io), and only sim/ and tools/
# may import it.
STAGES = {"shared": 0, "io": 1, "frontend": 2, "solvers": 3, "scale": 4, "factors": 5, "backend": 6, "tools": 7, "sim": 1.5}


def _module_name(path: Path) -> str:
    parts = list(path.relative_to(ROOT).with_suffix("").parts)
    if parts[-1] == "__init__":
        parts.pop()
    return ".".join(parts)


def _modules() -> dict[str, Path]:
    files = list((ROOT / "ampc_vo").rglob("*.py")) + list((ROOT / "factors").rglob("*.py"))
    return {_module_name(path): path for path in files}


def _imports(path: Path) -> set[str]:
    """Every ampc_vo / factors module imported anywhere in the file (also inside functions)."""
    found = set()
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            found.add(node.module)
            found.update(f"{node.module}.{alias.name}" for alias in node.names)
    return {name for name in found if name.split(".")[0] in ("ampc_vo", "factors")}


def _resolve(name: str, modules: dict[str, Path]) -> str | None:
    """The module a dotted import name refers to (``from a.b import c``: ``a.b.c`` if a module, else ``a.b``)."""
    while name and name not in modules:
        name = name.rpartition(".")[0]
    return name or None


@functools.lru_cache(maxsize=1)
def _graph() -> dict[str, set[str]]:
    modules = _modules()
    return {name: {target for target in (_resolve(item, modules) for item in _imports(path)) if target and target != name}
            for name, path in modules.items()}


def _stage(module: str) -> str:
    if module in SHARED:
        return "shared"
    parts = module.split(".")
    return parts[0] if parts[0] == "factors" else parts[1]


def test_every_module_belongs_to_a_stage():
    for module in _modules():
        assert _stage(module) in STAGES, f"{module}: not in a stage folder (DESIGN section 9)"


def test_top_level_package_holds_only_the_shared_vocabulary():
    top_level = sorted(path.stem for path in (ROOT / "ampc_vo").glob("*.py") if path.stem != "__init__")
    assert len(top_level) <= 8, top_level
    assert {f"ampc_vo.{name}" for name in top_level} <= set(SHARED)


@pytest.mark.parametrize("module", sorted(_modules()))
def test_imports_follow_the_data_flow(module):
    graph = _graph()
    stage = _stage(module)
    for target in sorted(graph[module]):
        target_stage = _stage(target)
        if target_stage == "sim":
            assert stage in ("sim", "tools"), f"{module} imports the simulator ({target}): only sim/ and tools/ may"
        elif stage == "factors":
            assert target_stage in ("shared", "factors"), f"{module} (factors) imports {target}: only the shared vocabulary"
        else:
            assert STAGES[target_stage] <= STAGES[stage], f"{module} ({stage}) imports {target} ({target_stage}): against the data flow"


def test_no_import_cycles():
    graph = _graph()
    state: dict[str, int] = {}

    def visit(module: str, path: list[str]) -> None:
        state[module] = 1
        for target in sorted(graph.get(module, ())):
            if state.get(target) == 1:
                raise AssertionError("import cycle: " + " -> ".join(path + [module, target]))
            if state.get(target) is None:
                visit(target, path + [module])
        state[module] = 2

    for module in sorted(graph):
        if module not in state:
            visit(module, [])


def test_the_estimator_imports_without_the_simulator():
    """Importing the whole estimator (pipeline, sources, runner) loads no ``ampc_vo.sim`` module."""
    import subprocess
    import sys

    code = ("import sys; import ampc_vo.frontend.sources, ampc_vo.backend.pipeline, ampc_vo.tools.runner, ampc_vo.tools.evaluation; "
            "loaded = sorted(m for m in sys.modules if m.startswith('ampc_vo.sim')); print(loaded); sys.exit(1 if loaded else 0)")
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT)
    assert result.returncode == 0, result.stdout + result.stderr
