"""The workspace's structure, read from the source: which way the imports point.

- A product core (ros_mongo, igmm_layers, region_search, traffic_gp, lfd_controller, errand_nav;
  not their `sim` subpackage, not their tests) never reaches robot_sim, directly or through
  other modules.
- Every workspace package a package's code imports is declared in its package.xml (code outside
  `test/` and `sim/` needs <depend> or <exec_depend>; tests and sim parts may use <test_depend>).
- No two workspace modules import each other, directly or round a longer cycle (imports inside
  functions count: hiding a cycle there does not remove it).
- Every generated parameter file in a package's config/ matches its NodeConfig class.
"""
import ast
import functools
import xml.etree.ElementTree as ElementTree
from collections import defaultdict
from pathlib import Path
from typing import Dict, FrozenSet, List, Set, Tuple

import pytest

from robot_common.config_files import stale_files

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"
PRODUCTS = ("ros_mongo", "igmm_layers", "region_search", "traffic_gp", "lfd_controller",
            "errand_nav")
GENERATED = ("msg", "srv", "action")


def _packages(src: Path = SRC) -> Dict[str, Path]:
    return {p.parent.name: p.parent for p in sorted(src.glob("*/package.xml"))}


def _python_modules(src: Path = SRC) -> Dict[str, Tuple[str, Path]]:
    """dotted module name -> (catkin package, file) for every library module under src/*/src/."""
    modules = {}
    for package, root in _packages(src).items():
        for path in sorted((root / "src").rglob("*.py")):
            parts = list(path.relative_to(root / "src").with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            modules[".".join(parts)] = (package, path)
    return modules


def _code_files(src: Path = SRC) -> List[Tuple[str, Path, str]]:
    """(catkin package, file, role) of every Python file of the packages; role is 'core',
    'sim' or 'test'. Node and script executables without an extension count as core."""
    files = []
    for package, root in _packages(src).items():
        candidates = [p for p in root.rglob("*") if p.is_file() and (
            p.suffix == ".py" or (p.parent.name in ("nodes", "scripts") and not p.suffix))]
        for path in sorted(candidates):
            rel = path.relative_to(root).parts
            if rel[0] == "test":
                role = "test"
            elif rel[0] == "src" and len(rel) > 3 and rel[2] == "sim":
                role = "sim"
            else:
                role = "core"
            files.append((package, path, role))
    return files


def _imports(path: Path) -> Set[str]:
    """Every module name imported anywhere in the file (absolute imports; relative ones resolved).
    Each version of a file is parsed once: every check reads the same files."""
    stat = path.stat()
    return set(_parsed_imports(str(path), stat.st_mtime_ns, stat.st_size))


@functools.lru_cache(maxsize=None)
def _parsed_imports(path: str, mtime_ns: int, size: int) -> FrozenSet[str]:
    """`_imports` of the file at `path` as it is at (`mtime_ns`, `size`)."""
    tree = ast.parse(Path(path).read_text(), filename=path)
    names = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names.update(alias.name for alias in node.names)
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                raise AssertionError(f"{path}: relative import; the workspace uses absolute imports")
            names.add(node.module or "")
            names.update(f"{node.module}.{alias.name}" for alias in node.names)
    return frozenset(names)


def _workspace_targets(names: Set[str], modules: Dict[str, Tuple[str, Path]], src: Path = SRC):
    """(module names in the workspace, catkin packages incl. generated msg/srv) that `names` reach."""
    packages = _packages(src)
    top_level = {name.split(".")[0]: package for name, (package, _) in modules.items()}
    reached_modules, reached_packages = set(), set()
    for name in names:
        parts = name.split(".")
        if parts[0] in top_level:
            reached_packages.add(top_level[parts[0]])
        if len(parts) > 1 and parts[1] in GENERATED and parts[0] in packages:
            reached_packages.add(parts[0])
            continue
        if name in modules:
            reached_modules.add(name)
    return reached_modules, reached_packages


def _declared(package: str, src: Path = SRC) -> Dict[str, Set[str]]:
    tree = ElementTree.parse(_packages(src)[package] / "package.xml")
    kinds = defaultdict(set)
    for element in tree.getroot():
        if element.tag.endswith("depend") and element.text:
            kinds[element.tag].add(element.text.strip())
    return kinds


def _module_graph(src: Path = SRC) -> Dict[str, Set[str]]:
    modules = _python_modules(src)
    graph = {}
    for name, (_, path) in modules.items():
        reached, _ = _workspace_targets(_imports(path), modules, src)
        graph[name] = reached - {name}
    return graph


def _reachable(graph: Dict[str, Set[str]], start: str) -> Set[str]:
    seen, stack = set(), [start]
    while stack:
        for target in graph.get(stack.pop(), ()):
            if target not in seen:
                seen.add(target)
                stack.append(target)
    return seen


def core_reaching_simulator(product: str, src: Path = SRC) -> List[str]:
    """Files of `product`'s core that import robot_sim, directly or through other modules."""
    modules = _python_modules(src)
    graph = _module_graph(src)
    offenders = []
    for package, path, role in _code_files(src):
        if package != product or role != "core":
            continue
        reached, packages = _workspace_targets(_imports(path), modules, src)
        closure = set(reached)
        for module in reached:
            closure |= _reachable(graph, module)
        via = sorted(m for m in closure if m.split(".")[0] == "robot_sim")
        if "robot_sim" in packages or via:
            offenders.append(f"{path.relative_to(src)} -> {via or ['robot_sim']}")
    return offenders


def undeclared_imports(src: Path = SRC) -> List[str]:
    """Imports of workspace packages that the importing package's package.xml does not declare."""
    modules = _python_modules(src)
    missing = []
    for package, path, role in _code_files(src):
        _, packages = _workspace_targets(_imports(path), modules, src)
        declared = _declared(package, src)
        runtime = declared["depend"] | declared["exec_depend"]
        allowed = runtime | declared["test_depend"] if role in ("test", "sim") else runtime
        for target in sorted(packages - {package} - allowed):
            missing.append(f"{path.relative_to(src)} imports {target}, not declared "
                           f"({'test_depend or ' if role != 'core' else ''}depend/exec_depend) "
                           f"in {package}/package.xml")
    return missing


def import_cycles(src: Path = SRC) -> List[str]:
    """Pairs of workspace modules that reach each other through imports."""
    graph = _module_graph(src)
    cycles = set()
    for module in graph:
        for target in graph[module]:
            if module in _reachable(graph, target):
                cycles.add(" <-> ".join(sorted((module, target))))
    return sorted(cycles)


def test_the_scan_sees_the_whole_workspace():
    packages = _packages()
    assert {"robot_common", "robot_sim", "ros_harness", *PRODUCTS} <= set(packages)
    modules = _python_modules()
    assert "robot_common.maps" in modules and "traffic_gp.model" in modules
    graph = _module_graph()
    assert "robot_common.maps" in graph["robot_common.cells"]


@pytest.mark.parametrize("product", PRODUCTS)
def test_a_product_core_never_reaches_the_simulator(product):
    offenders = core_reaching_simulator(product)
    assert not offenders, "product core reaches robot_sim:\n" + "\n".join(offenders)


def test_every_imported_workspace_package_is_declared():
    missing = undeclared_imports()
    assert not missing, "\n".join(missing)


def test_no_two_workspace_modules_import_each_other():
    cycles = import_cycles()
    assert not cycles, "import cycles:\n" + "\n".join(cycles)


def _write_package(src: Path, name: str, depends: Dict[str, List[str]], files: Dict[str, str]):
    root = src / name
    deps = "".join(f"<{kind}>{dep}</{kind}>" for kind, names in depends.items() for dep in names)
    (root / "src" / name).mkdir(parents=True)
    (root / "package.xml").write_text(f'<package format="3"><name>{name}</name>{deps}</package>')
    (root / "src" / name / "__init__.py").write_text("")
    for rel, text in files.items():
        path = root / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)


def test_the_checks_find_what_they_look_for(tmp_path):
    """A small made-up workspace with one of each fault: every check reports exactly it."""
    _write_package(tmp_path, "robot_sim", {}, {"src/robot_sim/people.py": "X = 1\n"})
    _write_package(tmp_path, "traffic_gp", {"test_depend": ["robot_sim"]}, {
        "src/traffic_gp/model.py": "from traffic_gp.helper import f\n",
        "src/traffic_gp/helper.py": "def f():\n    from traffic_gp.model import g\n",
        "src/traffic_gp/costmap.py": "from traffic_gp.sim.truth import T\n",
        "src/traffic_gp/sim/__init__.py": "",
        "src/traffic_gp/sim/truth.py": "from robot_sim.people import X as T\n",
        "test/test_model.py": "import robot_sim.people\n",
        "nodes/server": "import rospy\nfrom ros_mongo.store import S\n",
    })
    _write_package(tmp_path, "ros_mongo", {}, {"src/ros_mongo/store.py": "S = 1\n"})
    assert core_reaching_simulator("traffic_gp", tmp_path) == [
        "traffic_gp/src/traffic_gp/costmap.py -> ['robot_sim.people']"]
    assert undeclared_imports(tmp_path) == [
        "traffic_gp/nodes/server imports ros_mongo, not declared (depend/exec_depend) in "
        "traffic_gp/package.xml"]
    assert import_cycles(tmp_path) == ["traffic_gp.helper <-> traffic_gp.model"]


def test_generated_parameter_files_match_their_classes():
    assert not stale_files(SRC), "run: python -m robot_common.config_files --write"
