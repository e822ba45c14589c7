"""The workspace's conventions, read from the source (one way of doing each thing):

- errors: every error class a package defines derives from robot_common's `WorkspaceError`
  (private control-flow exceptions aside), and only robot_common defines a `ConfigError`;
- node parameters: every `NodeConfig` class lives in its package's `params.py`, named `...Params`;
- `ros_` modules: in the packages with a pure core, a library module imports rospy exactly when
  its name starts with `ros_`;
- node executables: each file in a package's nodes/ defines `main()` and runs it;
- bench/: grouped by package (plus experiments/), and no product installs a bench script;
- the tree holds no absolute path of a development machine.
"""
import ast
import re
import subprocess
from pathlib import Path
from typing import Dict, Iterator, List, Set, Tuple

ROOT = Path(__file__).resolve().parents[1]
SRC = ROOT / "src"
#: Packages whose library is a pure core plus thin `ros_*` modules (ros_harness and robot_demo are
#: ROS glue through and through).
PURE_CORE_PACKAGES = ("robot_common", "robot_sim", "ros_mongo", "igmm_layers", "region_search",
                      "traffic_gp", "lfd_controller", "errand_nav")
BUILTIN_ERRORS = {"Exception", "RuntimeError", "ValueError", "LookupError", "KeyError", "TypeError",
                  "OSError", "IOError", "IndexError", "ArithmeticError"}
MACHINE_PATH = re.compile(r"""(^|[\s('"`=])/(home|root|work|srv|mnt)/|(^|[\s('"`=])/tmp/(?!\.X)""")


def _library_modules(src: Path) -> Iterator[Tuple[str, Path]]:
    """(catkin package, file) of every library module (src/<pkg>/src/**.py)."""
    for package_xml in sorted(src.glob("*/package.xml")):
        package = package_xml.parent
        for path in sorted((package / "src").rglob("*.py")):
            yield package.name, path


def _classes(path: Path) -> Iterator[Tuple[str, List[str]]]:
    """(class name, base names) of every class defined in a file."""
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.ClassDef):
            bases = [b.attr if isinstance(b, ast.Attribute) else getattr(b, "id", "") for b in node.bases]
            yield node.name, bases


def _imported_names(path: Path) -> Dict[str, str]:
    """local name -> imported name, for `from x import a as b` imports."""
    names = {}
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.ImportFrom):
            for alias in node.names:
                names[alias.asname or alias.name] = alias.name
    return names


def error_convention_offences(src: Path = SRC) -> List[str]:
    """Error classes outside the workspace's error tree, and ConfigErrors outside robot_common."""
    classes: Dict[str, List[str]] = {}
    where: Dict[str, List[str]] = {}
    for package, path in _library_modules(src):
        aliases = _imported_names(path)
        for name, bases in _classes(path):
            classes.setdefault(name, [])
            classes[name] += [aliases.get(base, base) for base in bases]
            where.setdefault(name, []).append(f"{path.relative_to(src)} ({package})")
    rooted: Set[str] = {"WorkspaceError"}
    changed = True
    while changed:
        changed = False
        for name, bases in classes.items():
            if name not in rooted and any(base in rooted for base in bases):
                rooted.add(name)
                changed = True
    offences = []
    for name, bases in sorted(classes.items()):
        is_error = any(base in BUILTIN_ERRORS for base in bases) or name in rooted
        if is_error and name not in rooted and not name.startswith("_"):  # private: control flow
            offences.append(f"{name} in {', '.join(where[name])} does not derive from WorkspaceError")
        if name == "ConfigError":
            offences += [f"ConfigError defined in {place}" for place in where[name]
                         if not place.startswith("robot_common/")]
    return offences


def parameter_class_offences(src: Path = SRC) -> List[str]:
    """NodeConfig classes outside `<package>/params.py` or not named `...Params`."""
    classes = {}
    for _, path in _library_modules(src):
        for name, bases in _classes(path):
            classes[name] = (bases, path)
    params: Set[str] = {"NodeConfig"}
    changed = True
    while changed:
        changed = False
        for name, (bases, _) in classes.items():
            if name not in params and any(base in params for base in bases):
                params.add(name)
                changed = True
    offences = []
    for name in sorted(params - {"NodeConfig"}):
        path = classes[name][1]
        if path.name != "params.py" or not name.endswith("Params"):
            offences.append(f"{name} in {path.relative_to(src)}")
    return offences


def _imports_rospy(path: Path) -> bool:
    for node in ast.walk(ast.parse(path.read_text(), filename=str(path))):
        if isinstance(node, ast.Import) and any(a.name.split(".")[0] == "rospy" for a in node.names):
            return True
        if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] == "rospy":
            return True
    return False


def ros_prefix_offences(src: Path = SRC) -> List[str]:
    offences = []
    for package, path in _library_modules(src):
        if package not in PURE_CORE_PACKAGES:
            continue
        prefixed, imports = path.name.startswith("ros_"), _imports_rospy(path)
        if prefixed and not imports:
            offences.append(f"{path.relative_to(src)}: ros_ prefix but no rospy import")
        elif imports and not prefixed:
            offences.append(f"{path.relative_to(src)}: imports rospy without the ros_ prefix")
    return offences


def node_main_offences(src: Path = SRC) -> List[str]:
    """Node executables without a `main()` that `if __name__ == "__main__"` runs."""
    offences = []
    for path in sorted(src.glob("*/nodes/*")):
        tree = ast.parse(path.read_text(), filename=str(path))
        defines = any(isinstance(n, ast.FunctionDef) and n.name == "main" for n in tree.body)
        imports = any(isinstance(n, ast.ImportFrom) and any(a.name == "main" for a in n.names)
                      for n in tree.body)
        runs = any(isinstance(n, ast.If) and "__main__" in ast.dump(n.test) and "main" in ast.dump(n)
                   for n in tree.body)
        if not (defines or imports) or not runs:
            offences.append(f"{path.relative_to(src)}: no main() run under __main__")
    return offences


def bench_layout_offences(root: Path = ROOT) -> List[str]:
    """Files directly in bench/ that are not its shared set-up, folders that are not a package's."""
    bench, packages = root / "bench", {p.parent.name for p in (root / "src").glob("*/package.xml")}
    allowed_files = {"README.md", "run_all.sh", "requirements-bench.txt"}
    offences = []
    for entry in sorted(bench.iterdir()) if bench.is_dir() else []:
        if entry.name.startswith((".", "__")):
            continue
        if entry.is_file() and entry.name not in allowed_files:
            offences.append(f"bench/{entry.name}: belongs in bench/<package>/ or bench/experiments/")
        if entry.is_dir() and entry.name not in packages | {"experiments", "data"}:
            offences.append(f"bench/{entry.name}/: not a package of the workspace")
    for cmake in sorted((root / "src").glob("*/CMakeLists.txt")):
        for line in cmake.read_text().splitlines():
            if "bench" in line and not line.lstrip().startswith("#"):
                offences.append(f"{cmake.relative_to(root)}: installs a bench script: {line.strip()}")
    return offences


def machine_path_offences(root: Path = ROOT) -> List[str]:
    listed = subprocess.run(["git", "ls-files", "-co", "--exclude-standard"], cwd=root,
                            capture_output=True, text=True, check=True).stdout.split()
    offences = []
    for rel in listed:
        path = root / rel
        if not path.is_file() or path.suffix in (".png", ".pgm", ".npz", ".bag", ".gz", ".zip", ".mcap"):
            continue
        try:
            text = path.read_text()
        except (UnicodeDecodeError, OSError):
            continue
        for number, line in enumerate(text.splitlines(), 1):
            if MACHINE_PATH.search(line):
                offences.append(f"{rel}:{number}: {line.strip()[:100]}")
    return offences


def test_every_error_derives_from_the_workspace_root_and_config_errors_are_one():
    offences = error_convention_offences()
    assert not offences, "\n".join(offences)


def test_node_parameter_classes_live_in_params_modules():
    offences = parameter_class_offences()
    assert not offences, "NodeConfig classes belong in <package>/params.py as <Node>Params:\n" + \
        "\n".join(offences)


def test_the_ros_prefix_means_the_module_imports_rospy():
    offences = ros_prefix_offences()
    assert not offences, "\n".join(offences)


def test_every_node_executable_runs_its_main():
    offences = node_main_offences()
    assert not offences, "\n".join(offences)


def test_bench_is_grouped_by_package_and_no_product_installs_it():
    offences = bench_layout_offences()
    assert not offences, "\n".join(offences)


def test_the_tree_holds_no_machine_paths():
    offences = machine_path_offences()
    assert not offences, "\n".join(offences)


def test_the_checks_find_what_they_look_for(tmp_path):
    """A made-up workspace with one of each fault: every check reports exactly it."""
    files = {
        "robot_common/package.xml": "<package/>",
        "robot_common/src/robot_common/errors.py": "class WorkspaceError(Exception):\n    pass\n"
                                                   "class ConfigError(WorkspaceError):\n    pass\n",
        "robot_common/src/robot_common/params.py": "class NodeConfig:\n    pass\n",
        "traffic_gp/package.xml": "<package/>",
        "traffic_gp/src/traffic_gp/errors.py":
            "from robot_common.errors import WorkspaceError as Root\n"
            "class TrafficError(Root):\n    pass\n"
            "class ModelFormatError(TrafficError):\n    pass\n"
            "class ConfigError(TrafficError, ValueError):\n    pass\n",
        "traffic_gp/src/traffic_gp/legacy.py": "class LegacyError(ValueError):\n    pass\n",
        "traffic_gp/src/traffic_gp/params.py": "from robot_common.params import NodeConfig\n"
                                               "class ServerParams(NodeConfig):\n    pass\n",
        "traffic_gp/src/traffic_gp/server_config.py": "from traffic_gp.params import ServerParams\n"
                                                      "class ServerConfig(ServerParams):\n    pass\n",
        "traffic_gp/src/traffic_gp/ros_store.py": "import numpy\n",
        "traffic_gp/src/traffic_gp/node_helper.py": "from rospy import Publisher\n",
        "traffic_gp/src/traffic_gp/ros_node.py": "import rospy\n",
        "traffic_gp/nodes/traffic_server": "def main():\n    return 0\n",
        "traffic_gp/nodes/good": "import sys\nfrom traffic_gp.ros_node import main\n"
                                 "if __name__ == '__main__':\n    sys.exit(main())\n",
        "traffic_gp/CMakeLists.txt": "catkin_install_python(PROGRAMS\n  scripts/bench_publisher\n)\n",
    }
    for rel, text in files.items():
        path = tmp_path / "src" / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    (tmp_path / "bench" / "traffic_gp").mkdir(parents=True)
    (tmp_path / "bench" / "loose_bench.py").write_text("")
    (tmp_path / "bench" / "README.md").write_text("")
    src = tmp_path / "src"
    assert error_convention_offences(src) == [
        "ConfigError defined in traffic_gp/src/traffic_gp/errors.py (traffic_gp)",
        "LegacyError in traffic_gp/src/traffic_gp/legacy.py (traffic_gp) does not derive from "
        "WorkspaceError"]
    assert parameter_class_offences(src) == ["ServerConfig in traffic_gp/src/traffic_gp/server_config.py"]
    assert ros_prefix_offences(src) == [
        "traffic_gp/src/traffic_gp/node_helper.py: imports rospy without the ros_ prefix",
        "traffic_gp/src/traffic_gp/ros_store.py: ros_ prefix but no rospy import"]
    assert node_main_offences(src) == ["traffic_gp/nodes/traffic_server: no main() run under __main__"]
    assert bench_layout_offences(tmp_path) == [
        "bench/loose_bench.py: belongs in bench/<package>/ or bench/experiments/",
        "src/traffic_gp/CMakeLists.txt: installs a bench script: scripts/bench_publisher"]
    subprocess.run(["git", "init", "-q"], cwd=tmp_path, check=True)
    planted = "/" + "home/dev/shared/data"
    (tmp_path / "notes.md").write_text(f"data in {planted}\nX display /tmp/.X11-unix/X99\n"
                                       "see /usr/share/doc\n")
    assert machine_path_offences(tmp_path) == [f"notes.md:1: data in {planted}"]
