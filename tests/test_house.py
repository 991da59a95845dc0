"""The house reads as the pipeline: stage folders know no robot, data flows one way.

Checked by reading the source (no imports run). The throwing task's words (scoop, ball, throw) still appear in
the stage modules listed in ``NOT_YET_TASK_NEUTRAL``: the list may only shrink (a module that newly names them
fails), and it is printed by ``python3 -m pytest tests/test_house.py -rA``.
"""

from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "besdrake"
STAGES = ("mocap", "segmentation", "imitation", "embodiment", "sim", "search", "transfer", "diagnosis", "pipeline")
#: Stage modules that import a task module: only backwards-compatible re-exports of a task's names, defining nothing
#: (test_task_imports_are_pure_reexports). Empty: the old import paths (sim/outcome.py, sim/throws.py, the
#: ThrowReward of search/refinement) are gone; code imports from besdrake.tasks.throwing.* instead.
KNOWN_TASK_IMPORTS: set[str] = set()
#: Stage files that still name the throwing task's objects (issue 23: to become task-neutral). Empty since the
#: throwing task's code moved into besdrake/tasks/throwing/; a stage file that names them again fails.
NOT_YET_TASK_NEUTRAL: set[str] = set()


def _stage_files(suffixes=(".py",)):
    for stage in STAGES:
        for path in sorted((PACKAGE / stage).rglob("*")):
            if path.suffix in suffixes and "__pycache__" not in path.parts:
                yield stage, path


def _imports(path: Path) -> list[str]:
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.append(node.module)
        elif isinstance(node, ast.Import):
            out.extend(a.name for a in node.names)
    return out


def test_no_stage_folder_names_a_robot():
    hits = [f"{p.relative_to(PACKAGE)}:{i}" for _, p in _stage_files((".py", ".yaml", ".md"))
            for i, line in enumerate(p.read_text().splitlines(), 1) if re.search(r"\bcompi\b", line, re.IGNORECASE)]
    assert hits == [], "robot knowledge belongs in robot files: " + ", ".join(hits)


def test_data_flows_one_way_and_stages_import_no_task():
    rank = {s: i for i, s in enumerate(STAGES)}
    backwards, task_imports = [], set()
    for stage, path in _stage_files():
        for module in _imports(path):
            parts = module.split(".")
            if parts[0] != "besdrake" or len(parts) < 2:
                continue
            if parts[1] in rank and rank[parts[1]] > rank[stage]:
                backwards.append(f"{path.relative_to(PACKAGE)} imports {module}")
            if parts[1] == "tasks":
                task_imports.add(str(path.relative_to(PACKAGE)))
    assert backwards == []
    allowed = KNOWN_TASK_IMPORTS
    assert task_imports <= allowed, f"new task imports in stage modules: {sorted(task_imports - allowed)}"


def test_task_words_in_stage_folders_only_shrink():
    naming = {str(p.relative_to(PACKAGE)) for _, p in _stage_files((".py", ".yaml", ".md"))
              if re.search(r"scoop|ball|throw", p.read_text(), re.IGNORECASE)}
    new = naming - NOT_YET_TASK_NEUTRAL
    assert not new, f"stage files newly naming the throwing task's objects: {sorted(new)}"
    total = sum(1 for _ in _stage_files((".py", ".yaml", ".md")))
    print(f"stage files still naming scoop/ball/throw: {len(naming)} of {total}")


def test_task_imports_are_pure_reexports():
    """A stage module that imports a task only re-exports its names: a docstring, imports and ``__all__``."""
    for rel in KNOWN_TASK_IMPORTS:
        path = PACKAGE / rel
        if not path.is_file():
            continue
        body = ast.parse(path.read_text()).body
        extra = [type(n).__name__ for n in body[1:] if not isinstance(n, (ast.Import, ast.ImportFrom))
                 and not (isinstance(n, ast.Assign) and [t.id for t in n.targets if isinstance(t, ast.Name)] == ["__all__"])]
        assert isinstance(body[0], ast.Expr) and extra == [], f"{rel} holds more than a re-export: {extra}"


@pytest.mark.parametrize("folder", ["robot.py", "plan.py", "task.py"])
def test_platform_modules_import_no_stage_or_task_at_module_level(folder):
    tree = ast.parse((PACKAGE / folder).read_text())
    top = [n for n in tree.body if isinstance(n, (ast.Import, ast.ImportFrom))]
    modules = [n.module if isinstance(n, ast.ImportFrom) else n.names[0].name for n in top]
    assert not [m for m in modules if m and m.startswith(("besdrake.tasks", *(f"besdrake.{s}" for s in STAGES)))]
