"""Node helpers against a real roscore: `shut_down_rospy` leaves no thread spinning behind."""
import subprocess
import sys
import textwrap

# A process that goes on after shutting its rospy node down. Once a second it reports whether a
# thread still runs rospy's XML-RPC server loop (a frame of rosgraph/xmlrpc.py on its stack) and
# ends by itself once none does, or after its last report.
PROBE = textwrap.dedent("""
    import sys, time
    import rospy
    from robot_common.ros_node import shut_down_rospy

    def frames(frame):
        while frame is not None:
            yield frame
            frame = frame.f_back

    def server_loop_running():
        return any(f.f_code.co_filename.endswith("rosgraph/xmlrpc.py")
                   for top in sys._current_frames().values() for f in frames(top))

    rospy.init_node("shutdown_probe", anonymous=True, disable_signals=True)
    print("up" if server_loop_running() else "no-server-loop", flush=True)
    if sys.argv[1] == "helper":
        shut_down_rospy("probe finished")
    else:
        rospy.signal_shutdown("probe finished")
    for _ in range(int(sys.argv[2])):
        running = server_loop_running()
        print("running" if running else "ended", flush=True)
        if not running:
            break
        time.sleep(1)
""")


def run_probe(roscore, how: str, reports: int) -> list:
    done = subprocess.run([sys.executable, "-c", PROBE, how, str(reports)], env=roscore.env(),
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                          timeout=120 + 2 * reports)
    assert done.returncode == 0, done.stdout
    return done.stdout.split()


def test_shut_down_rospy_ends_the_xmlrpc_server_loop(roscore):
    lines = run_probe(roscore, "helper", 60)
    assert lines[0] == "up" and lines[-1] == "ended", lines


def test_plain_signal_shutdown_leaves_the_server_loop_running(roscore):
    """Why the helper exists (and that the probe sees the loop): rospy's own shutdown leaves it
    polling the closed socket, a core busy until the process exits."""
    lines = run_probe(roscore, "plain", 3)
    assert lines == ["up", "running", "running", "running"], lines
