"""`catkin_make install` and `catkin_make run_tests` work; a node runs from the install space alone.

The workspace's sources are built and installed into a temporary directory (its own build,
devel and install folders: the workspace's build/ and devel/ are never touched), with Noetic's
usual command line. Then, in an environment made only from the install space's setup.bash (no
devel space, no workspace source folder on any path), roslaunch starts robot_sim's map_publisher
through a launch file that loads the *installed* config/map_publisher.yaml, and the test
receives the map it publishes. That proves the pieces an installed robot needs: the
catkin_install_python relays of the nodes, the Python packages installed by setup.py
(catkin_python_setup), the generated messages, and the share files (launch/, config/).

To keep the suite's time reasonable only robot_common and robot_sim are built
(-DCATKIN_WHITELIST_PACKAGES; the whole workspace takes several minutes, mostly message
generation: see the README's Tests section); every package's install rules are checked by
catkin_lint in tests/test_manifests.py.

The same build (testing enabled, as a ROS developer's would be) then runs `catkin_make run_tests`:
each package's pytest suite and its launch-file check (robot_common's `robot_common_add_pytests`,
roslaunch's `roslaunch_add_file_check`) leave JUnit XML under build/test_results, which
`catkin_test_results` sums up. The suites run there without their ROS tests (PYTEST_ADDOPTS
`-m "not ros"`, which pytest reads whoever starts it): those start the workspace's nodes, as in
the suite's own run of the same tests, and add nothing to what run_tests proves but CPU.
"""
import os
import re
import subprocess
import xml.etree.ElementTree as ElementTree
from pathlib import Path
from typing import Dict

import pytest

from ros_harness import RosLaunch, wait_until

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("robot_common", "robot_sim")
# Message generators of other languages than Python are left out of the build (no package of the
# workspace uses their C++, Lisp, ... files; what is checked here is the Python install space).
OTHER_MESSAGE_LANGUAGES = "gencpp:geneus:genlisp:gennodejs"
# The packages' tests that `catkin_make run_tests` runs here (and that the count compares with).
SELECTION = {"PYTEST_ADDOPTS": "-m 'not ros'"}

pytestmark = [pytest.mark.ros, pytest.mark.slow]


def _python() -> str:
    """The interpreter catkin writes into the node relays: the venv's (README, Troubleshooting)."""
    venv = ROOT / ".venv" / "bin" / "python3"
    return str(venv if venv.exists() else "/usr/bin/python3")


@pytest.fixture(scope="module")
def install_space(tmp_path_factory) -> Path:
    """`catkin_make install` of PACKAGES into a fresh folder; the install space's path."""
    folder = tmp_path_factory.mktemp("catkin_install")
    command = ["catkin_make", "--directory", str(folder), "--source", str(ROOT / "src"),
               "--build", str(folder / "build"),
               f"-DCATKIN_DEVEL_PREFIX={folder / 'devel'}",
               f"-DCMAKE_INSTALL_PREFIX={folder / 'install'}",
               f"-DCATKIN_WHITELIST_PACKAGES={';'.join(PACKAGES)}",
               f"-DPYTHON_EXECUTABLE={_python()}", "-DCATKIN_ENABLE_TESTING=ON", "install"]
    env = dict(_clean_env(), ROS_LANG_DISABLE=OTHER_MESSAGE_LANGUAGES)
    result = subprocess.run(command, cwd=folder, env=env, capture_output=True, text=True,
                            timeout=1200)
    assert result.returncode == 0, \
        f"catkin_make install failed:\n{result.stdout[-4000:]}\n{result.stderr[-4000:]}"
    return folder / "install"


def _clean_env() -> Dict[str, str]:
    """A login-like environment: Debian's ROS under /usr, no devel space, no venv activation."""
    keep = {key: os.environ[key] for key in ("HOME", "USER", "LANG", "TMPDIR") if key in os.environ}
    return dict(keep, PATH="/usr/bin:/bin")


def installed_env(install: Path) -> Dict[str, str]:
    """The environment `source install/setup.bash` gives, started from a clean one."""
    script = f'source "{install}/setup.bash" && env -0'
    output = subprocess.run(["bash", "-c", script], env=_clean_env(), capture_output=True,
                            check=True, timeout=120).stdout.decode()
    env = dict(item.split("=", 1) for item in output.split("\0") if "=" in item)
    # the venv's interpreter runs the relays (shebang); its bin first, as `source env.sh` would
    env["PATH"] = f"{Path(_python()).parent}:{env['PATH']}"
    return env


def test_install_space_has_the_nodes_libraries_and_share_files(install_space):
    assert (install_space / "lib" / "robot_sim" / "map_publisher").is_file()
    assert os.access(install_space / "lib" / "robot_sim" / "map_publisher", os.X_OK)
    site = install_space / "lib" / "python3" / "dist-packages"
    assert (site / "robot_sim" / "ros_map_publisher.py").is_file()
    assert (site / "robot_common" / "msg" / "_PeopleCount.py").is_file()   # generated messages
    assert (install_space / "share" / "robot_sim" / "config" / "map_publisher.yaml").is_file()
    assert (install_space / "share" / "robot_sim" / "launch" / "sim.launch").is_file()
    env = installed_env(install_space)
    assert str(install_space) in env["CMAKE_PREFIX_PATH"]
    for variable in ("ROS_PACKAGE_PATH", "PYTHONPATH", "CMAKE_PREFIX_PATH"):
        assert str(ROOT) not in env.get(variable, ""), (variable, env.get(variable))
    found = subprocess.run(["rospack", "find", "robot_sim"], env=env, capture_output=True,
                           text=True, timeout=60)
    assert found.stdout.strip() == str(install_space / "share" / "robot_sim"), found


def test_a_node_runs_from_the_install_space(install_space, roscore, rospy_node, tmp_path):
    from nav_msgs.msg import OccupancyGrid

    env = roscore.env(installed_env(install_space))
    launch_file = tmp_path / "installed_map.launch"
    launch_file.write_text(
        "<launch>\n"
        '  <node pkg="robot_sim" type="map_publisher" name="installed_map_publisher">\n'
        '    <rosparam command="load" file="$(find robot_sim)/config/map_publisher.yaml"/>\n'
        '    <remap from="map" to="/installed/map"/>\n'
        "  </node>\n"
        "</launch>\n")
    launch = RosLaunch([str(launch_file)], master_uri=roscore.uri, log_dir=tmp_path, env=env)
    received = []
    subscriber = rospy_node.Subscriber("/installed/map", OccupancyGrid, received.append)
    try:
        launch.start()
        launch.wait_for_topics(["/installed/map"])
        wait_until(lambda: received, 90, what="the latched map from the installed node",
                   check=launch.process.check_alive)
        pid = launch.node_pid("/installed_map_publisher")
        command_line = Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0")
        assert str(install_space / "lib" / "robot_sim" / "map_publisher").encode() in command_line
        node_env = dict(item.split(b"=", 1) for item in
                        Path(f"/proc/{pid}/environ").read_bytes().split(b"\0") if b"=" in item)
        assert str(ROOT).encode() not in node_env.get(b"PYTHONPATH", b"")
    finally:
        subscriber.unregister()
        launch.stop()
    grid = received[0]
    assert grid.header.frame_id == "map"
    assert grid.info.width > 10 and grid.info.height > 10
    assert len(grid.data) == grid.info.width * grid.info.height
    assert {0, 100} <= set(grid.data)          # free and occupied cells of the generated floor


def _collected_tests(test_dirs) -> Dict[Path, int]:
    """How many tests pytest itself collects in each folder (an independent count; one run)."""
    listed = subprocess.run([_python(), "-m", "pytest", "--collect-only", "-q", "-p", "no:cacheprovider",
                             *map(str, test_dirs)], cwd=ROOT, capture_output=True, text=True,
                            timeout=600, env=dict(os.environ, **SELECTION))
    ids = [line for line in listed.stdout.splitlines() if "::" in line]
    return {folder: sum(1 for i in ids if folder in (ROOT / i.split("::")[0]).parents)
            for folder in test_dirs}


def test_catkin_make_run_tests_runs_each_packages_tests_and_launch_checks(install_space):
    folder = install_space.parent
    results = folder / "build" / "test_results"
    env = dict(os.environ, PATH=f"/usr/bin:/bin:{os.environ['PATH']}",
               ROS_LANG_DISABLE=OTHER_MESSAGE_LANGUAGES, **SELECTION)
    run = subprocess.run(["catkin_make", "--directory", str(folder), "--source", str(ROOT / "src"),
                          "--build", str(folder / "build"), "run_tests"],
                         cwd=folder, env=env, capture_output=True, text=True, timeout=1800)
    assert run.returncode == 0, f"catkin_make run_tests failed:\n{run.stdout[-4000:]}\n{run.stderr[-4000:]}"
    collected = _collected_tests([ROOT / "src" / package / "test" for package in PACKAGES])
    for package in PACKAGES:
        report = results / package / f"pytest-{package}.xml"
        assert report.is_file(), sorted(p.name for p in (results / package).glob("*"))
        suite = ElementTree.parse(report).getroot()
        suite = suite if suite.tag == "testsuite" else suite.find("testsuite")
        assert int(suite.get("tests")) == collected[ROOT / "src" / package / "test"] > 0
        assert (int(suite.get("failures")), int(suite.get("errors"))) == (0, 0), report.read_text()[-3000:]
    assert (results / "robot_sim" / "roslaunch-check_launch.xml").is_file()
    summary = subprocess.run(["catkin_test_results", str(results)], env=env, capture_output=True,
                             text=True, timeout=120)
    assert summary.returncode == 0, summary.stdout + summary.stderr
    found = re.search(r"Summary: (\d+) tests, 0 errors, 0 failures", summary.stdout)
    assert found and int(found.group(1)) > 50, summary.stdout
