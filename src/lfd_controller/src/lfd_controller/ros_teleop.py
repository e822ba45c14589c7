"""JoyTeleopNode: sensor_msgs/Joy -> cmd_vel, and recording buttons -> the recorder's services."""
import threading

import rospy
from geometry_msgs.msg import Twist
from sensor_msgs.msg import Joy
from std_srvs.srv import Trigger

from lfd_controller.params import JoyTeleopParams
from lfd_controller.teleop import JoyTeleop
from robot_common.ros_node import read_config


class JoyTeleopNode:
    """Drives from a joystick while the dead-man button is held.

    Parameters (lfd_controller.params.JoyTeleopParams; config/joy_teleop.yaml; Xbox 360 pad under
    the joy driver):
      ~axis_linear (int, 1), ~axis_angular (int, 0), ~scale_linear (double, 0.5 m/s),
      ~scale_angular (double, 1.5 rad/s), ~deadzone (double, 0.05), ~enable_button (int, 4: LB),
      ~record_start_button (int, 0: A), ~record_stop_button (int, 1: B), ~recorder (str,
      "demo_recorder": its ~start/~stop services are called on the recording buttons).
    Topics: joy (sensor_msgs/Joy) in; cmd_vel (geometry_msgs/Twist) out: one per Joy message while
      enabled, one zero command on release.
    """

    def __init__(self, config: JoyTeleopParams):
        self.teleop = JoyTeleop(config.mapping())
        recorder = config.recorder.rstrip("/")
        self.services = {"start": f"{recorder}/start", "stop": f"{recorder}/stop"}
        self.cmd = None

    def setup(self) -> "JoyTeleopNode":
        """Publishers and subscribers."""
        self.cmd = rospy.Publisher("cmd_vel", Twist, queue_size=5)
        rospy.Subscriber("joy", Joy, self.on_joy, queue_size=5)
        return self

    def on_joy(self, msg: Joy) -> None:
        command, events = self.teleop.update(msg.axes, msg.buttons)
        if command is not None:
            twist = Twist()
            twist.linear.x, twist.angular.z = command
            self.cmd.publish(twist)
        for event in events:
            threading.Thread(target=self.call, args=(self.services[event],), daemon=True).start()

    def call(self, service: str) -> None:
        try:
            rospy.wait_for_service(service, timeout=2.0)
            response = rospy.ServiceProxy(service, Trigger)()
            log = rospy.loginfo if response.success else rospy.logwarn
            log(f"joy_teleop: {service}: {response.message}")
        except (rospy.ROSException, rospy.ServiceException) as err:
            rospy.logwarn(f"joy_teleop: {service} failed: {err}")


def start() -> JoyTeleopNode:
    """The node's start-up: ~parameters -> core -> ROS wiring (ConfigError, LfdError on bad ones)."""
    return JoyTeleopNode(read_config(JoyTeleopParams)).setup()
