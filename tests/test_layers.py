"""The package layers: dependencies point one way and no module imports itself back.

    core  <-  descriptors, limo  <-  sim (core, limo), maps (core, descriptors), controllers (core)
          <-  robot (the application)  <-  robot.bench

Every import counts, also those inside functions (a lazy import hides a cycle, it does not remove
it). Some packages must also stay free of heavy or hardware libraries: the decision logic runs
and is tested anywhere, and reading the settings on the robot's own computer never loads the
simulator.
"""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import networkx as nx
import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("core", "descriptors", "limo", "sim", "maps", "controllers", "robot")

#: layer -> the layers it may import (itself always)
ALLOWED = {
    "core": set(),
    "descriptors": {"core"},
    "limo": {"core"},
    "sim": {"core", "limo"},
    "maps": {"core", "descriptors"},
    "controllers": {"core"},
    "robot": {"core", "descriptors", "limo", "sim", "maps", "controllers"},
    "robot.bench": {"core", "descriptors", "limo", "sim", "maps", "controllers", "robot"},
}
#: third-party libraries a layer must not import (directly)
FORBIDDEN = {
    "core": {"torch", "pybullet", "pybullet_data", "serial", "cv2", "ray"},
    "controllers": {"torch", "pybullet", "pybullet_data", "serial", "cv2", "ray"},
    "maps": {"torch", "pybullet", "pybullet_data", "serial", "ray"},
    "descriptors": {"pybullet", "pybullet_data", "serial", "ray"},
    "limo": {"torch", "pybullet", "pybullet_data", "ray"},
    "sim": {"torch", "serial", "ray"},
    "robot": {"ray"},          # Ray is the evaluation harness's (robot.bench), never the robot's
}


def layer_of(module: str) -> str:
    return "robot.bench" if module == "robot.bench" or module.startswith("robot.bench.") else module.split(".")[0]


def module_files(root: Path = ROOT) -> dict[str, Path]:
    out = {}
    for package in PACKAGES:
        for path in (root / package).rglob("*.py"):
            parts = path.relative_to(root).with_suffix("").parts
            name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
            out[name] = path
    return out


def imports_of(module: str, path: Path, modules: set[str]) -> set[str]:
    """Every module ``module`` imports (project modules by full name, others by top-level name)."""
    tree = ast.parse(path.read_text(encoding="utf-8"), str(path))
    is_package = path.name == "__init__.py"
    found = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = module.split(".")
                keep = len(parts) - node.level + (1 if is_package else 0)
                base = ".".join(parts[:keep] + ([base] if base else []))
            for alias in node.names:
                candidate = f"{base}.{alias.name}"
                found.add(candidate if candidate in modules else base)
    out = set()
    for name in found:
        if name.split(".")[0] in PACKAGES:
            out.add(name)
        elif name and name != "__future__":
            out.add(name.split(".")[0])
    return out


def import_graph(files: dict[str, Path]) -> nx.DiGraph:
    graph = nx.DiGraph()
    names = set(files)
    for module, path in files.items():
        graph.add_node(module)
        for target in imports_of(module, path, names):
            graph.add_edge(module, target)
    return graph


def cycles(graph: nx.DiGraph) -> list[list[str]]:
    """One cycle per strongly connected group of project modules."""
    project = graph.subgraph(n for n in graph if n.split(".")[0] in PACKAGES)
    out = []
    for group in nx.strongly_connected_components(project):
        if len(group) > 1:
            out.append(nx.find_cycle(project.subgraph(group)))
    return out


def violations(graph: nx.DiGraph) -> list[str]:
    """Imports against the layer order or of a forbidden library, one line each."""
    out = []
    for src, dst in sorted(graph.edges):
        if src.split(".")[0] not in PACKAGES:
            continue
        here = layer_of(src)
        if dst.split(".")[0] in PACKAGES:
            there = layer_of(dst)
            if there != here and there not in ALLOWED[here]:
                out.append(f"{src} imports {dst}: layer {here!r} may import only {sorted(ALLOWED[here])}")
        elif dst in FORBIDDEN.get(here, ()):
            out.append(f"{src} imports {dst}: forbidden in layer {here!r}")
    return out


def test_every_module_belongs_to_a_known_layer():
    assert {layer_of(m) for m in module_files()} <= set(ALLOWED)


def test_no_import_cycle_between_modules():
    found = cycles(import_graph(module_files()))
    assert not found, "import cycles:\n" + "\n".join(" -> ".join(f"{a}" for a, _ in c) + f" -> {c[0][0]}"
                                                     for c in found)


def test_imports_follow_the_layers():
    found = violations(import_graph(module_files()))
    assert not found, "\n".join(found)


def test_the_checks_catch_a_forbidden_import_and_a_cycle(tmp_path):
    """The checker itself, on a copy of the tree with three bad imports added."""
    for package in PACKAGES:
        for path in (ROOT / package).rglob("*.py"):
            dest = tmp_path / path.relative_to(ROOT)
            dest.parent.mkdir(parents=True, exist_ok=True)
            dest.write_text(path.read_text(encoding="utf-8"), encoding="utf-8")
    voter = tmp_path / "controllers" / "voter.py"
    voter.write_text(voter.read_text() + "\n\ndef _late():\n    import torch  # noqa\n")
    twin = tmp_path / "sim" / "teleop.py"
    twin.write_text(twin.read_text() + "\nfrom robot.settings import StackConfig  # noqa\n")
    angles = tmp_path / "core" / "angles.py"
    angles.write_text(angles.read_text() + "\nfrom core.hal import Pose2D  # noqa\n")
    hal = tmp_path / "core" / "hal.py"
    hal.write_text(hal.read_text() + "\n\ndef _f():\n    from core.angles import wrap_angle  # noqa\n")
    graph = import_graph(module_files(tmp_path))
    found = violations(graph)
    assert any(v.startswith("controllers.voter imports torch: forbidden") for v in found)
    assert any(v.startswith("sim.teleop imports robot.settings: layer 'sim'") for v in found)
    assert any({a for a, _ in c} == {"core.hal", "core.angles"} for c in cycles(graph))


@pytest.mark.parametrize("module, heavy", [
    ("robot.settings", ("pybullet", "torch", "serial", "cv2")),     # the stack config, on any computer
    ("controllers.navigator", ("pybullet", "torch", "serial", "cv2")),
    ("limo.serial_base", ("pybullet", "torch")),                     # the real base's driver
    ("maps.store", ("pybullet", "torch")),
    # what `robot.run --mode navigate --hal serial` imports besides the descriptor (robot/run.py)
    ("robot.run, robot.episode.goal, robot.episode.loop, robot.episode.metrics, robot.episode.setup, "
     "robot.episode.start, limo.serial_base, sim.world_spec", ("pybullet",)),
])
def test_light_modules_load_no_heavy_library(module, heavy):
    code = (f"import sys, {module}\n"
            f"print(' '.join(m for m in {heavy!r} if m in sys.modules))")
    if module == "robot.settings":
        code = "from robot.settings import load_stack_config\nload_stack_config()\n" + code
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=60)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "", f"importing {module} loaded {out.stdout.strip()}"
