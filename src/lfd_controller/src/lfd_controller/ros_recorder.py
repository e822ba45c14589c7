"""DemoRecorderNode: records demonstrations from the robot's topics into bags and the database."""
import threading
from collections import deque
from pathlib import Path
from typing import Optional

import rospy
from geometry_msgs.msg import Twist, TwistStamped
from nav_msgs.msg import Odometry
from nav_msgs.msg import Path as PathMsg
from sensor_msgs.msg import LaserScan, TimeReference
from std_msgs.msg import Bool, String
from std_srvs.srv import Trigger, TriggerResponse

from lfd_controller import ros_demos
from lfd_controller.errors import DemonstrationError
from lfd_controller.msg import Demonstration as DemonstrationMsg
from lfd_controller.params import ROS_HOME_PREFIX, DemoRecorderParams
from lfd_controller.recording import DemoBuilder, SampleMatcher
from robot_common.errors import ModelError, TaskError
from robot_common.msg import People
from robot_common.ros_node import odom_state, read_config, ros_home
from robot_common.tasks import scenario_from_yaml
from ros_mongo import StoreError, open_store
from ros_mongo.urls import warn_password_in_url


def resolve_bag_dir(value: str) -> Optional[Path]:
    """The bag folder of ~bag_dir: None for "" (no bags); a leading $ROS_HOME is ros_home()."""
    if not value:
        return None
    if value == ROS_HOME_PREFIX or value.startswith(ROS_HOME_PREFIX + "/"):
        value = str(ros_home()) + value[len(ROS_HOME_PREFIX):]
    return Path(value).expanduser()


def _stamp(msg) -> rospy.Time:
    """The message's stamp, or now for an unstamped one (a latched path often is)."""
    return rospy.Time.now() if msg.header.stamp.is_zero() else msg.header.stamp


class DemoRecorderNode:
    """Records one demonstration between ~start and ~stop.

    Parameters (lfd_controller.params.DemoRecorderParams; config/demo_recorder.yaml):
      ~bag_dir (str, "$ROS_HOME/lfd_demos"): one bag per demonstration ("" = no bags; a leading
      $ROS_HOME is the ROS_HOME environment variable or ~/.ros).
      ~db_url (str, ""): ros_mongo store URL (CouchDB or mongodb://...; "" = no database).
      ~source (str, "joystick"): who demonstrates (stored with the demo, used as a tag).
      ~session_id (str, ""): stored with each demo in the database, so learning can take one
      session's demos only ("" = none).
      ~min_steps (int, 5), ~use_applied_cmd (bool, true): pair odom with the simulator's
      cmd_vel_applied and sim_time by stamp (exact); false: odom with the latest cmd_vel (robot).
    Topics in: odom, cmd_vel_applied (geometry_msgs/TwistStamped), sim_time
      (sensor_msgs/TimeReference), cmd_vel (Twist; robot mode), scenario (std_msgs/String YAML);
      in a building also path (nav_msgs/Path: the path driven along, latched), scan
      (sensor_msgs/LaserScan) and people (robot_common/People: tracked people), kept in the
      demonstration's bag as /path, /scan, /people (what learn_reward --kind hallway learns from).
    Topics out: ~demonstrations (lfd_controller/Demonstration, latched: the last one), ~recording
      (std_msgs/Bool, latched).
    Services: ~start, ~stop (std_srvs/Trigger; stop answers with where the demo was stored).
    """

    def __init__(self, config: DemoRecorderParams):
        self.lock = threading.Lock()
        self.builder = DemoBuilder(config.min_steps)
        self.matcher = SampleMatcher()
        self.bag_dir = resolve_bag_dir(config.bag_dir)
        self.db_url = config.db_url
        self.source = config.source
        self.session_id = config.session_id or None
        self.exact = config.use_applied_cmd
        self.scenario, self.raw, self.count = None, [], 0
        self.latest_cmd, self.first_stamp, self.path = (0.0, 0.0), None, None
        # topic -> the newest scan / people / sim_time messages (a few: topics arrive in any order)
        self.sensors = {topic: deque(maxlen=5) for topic in ("/scan", "/people", "/sim_time")}
        self.demos = self.recording = None

    def setup(self) -> "DemoRecorderNode":
        """Publishers, subscribers and services."""
        self.demos = rospy.Publisher("~demonstrations", DemonstrationMsg, queue_size=5, latch=True)
        self.recording = rospy.Publisher("~recording", Bool, queue_size=1, latch=True)
        self.recording.publish(Bool(False))
        rospy.Subscriber("scenario", String, self.on_scenario, queue_size=1)
        rospy.Subscriber("odom", Odometry, self.on_odom, queue_size=50)
        if self.exact:
            rospy.Subscriber("cmd_vel_applied", TwistStamped, self.on_applied, queue_size=50)
            rospy.Subscriber("sim_time", TimeReference, self.on_time, queue_size=50)
        else:
            rospy.Subscriber("cmd_vel", Twist, self.on_cmd, queue_size=50)
        rospy.Subscriber("path", PathMsg, self.on_path, queue_size=1)
        rospy.Subscriber("scan", LaserScan, self.on_sensor, callback_args="/scan", queue_size=20)
        rospy.Subscriber("people", People, self.on_sensor, callback_args="/people", queue_size=20)
        rospy.Service("~start", Trigger, self.on_start)
        rospy.Service("~stop", Trigger, self.on_stop)
        return self

    def on_scenario(self, msg):
        try:
            scenario = scenario_from_yaml(msg.data)
        except (TaskError, ModelError) as err:
            rospy.logwarn(f"demo_recorder: ignored scenario: {err}")
            return
        with self.lock:
            self.scenario = scenario

    def _sample(self, key, part, value, raw):
        with self.lock:
            step = self.matcher.add(key, part, value)
            if self.builder.recording:
                self.raw.append(raw)
            if step is not None:
                self.builder.observe(step["state"], step["command"], step["time"])

    def on_odom(self, msg):
        raw = ("/odom", msg, msg.header.stamp)
        if self.exact:
            self._sample(msg.header.stamp, "state", odom_state(msg), raw)
            return
        with self.lock:
            self.first_stamp = self.first_stamp or msg.header.stamp
            t = (msg.header.stamp - self.first_stamp).to_sec()
            if self.builder.recording:
                self.raw.append(raw)
            self.builder.observe(odom_state(msg), self.latest_cmd, t)

    def on_applied(self, msg):
        self._sample(msg.header.stamp, "command", (msg.twist.linear.x, msg.twist.angular.z),
                     ("/cmd_vel_applied", msg, msg.header.stamp))

    def on_time(self, msg):
        with self.lock:
            self.sensors["/sim_time"].append(msg)
        self._sample(msg.header.stamp, "time", msg.time_ref.to_sec(), ("/sim_time", msg, msg.header.stamp))

    def on_path(self, msg):
        with self.lock:
            self.path = msg
            if self.builder.recording:
                self.raw.append(("/path", msg, _stamp(msg)))

    def on_sensor(self, msg, topic):
        with self.lock:
            self.sensors[topic].append(msg)
            if self.builder.recording:
                self.raw.append((topic, msg, msg.header.stamp))

    def on_cmd(self, msg):
        with self.lock:
            self.latest_cmd = (msg.linear.x, msg.angular.z)

    def on_start(self, _request):
        with self.lock:
            if self.scenario is None:
                return TriggerResponse(False, "no scenario received yet on 'scenario'; not recording")
            try:
                self.builder.start()
            except DemonstrationError as err:
                return TriggerResponse(False, str(err))
            # the path, and what the robot saw at the step the recording starts from with that
            # step's clock (a simulator publishes a step's scan after its odometry: it may
            # have come before ~start)
            self.raw = [] if self.path is None else [("/path", self.path, _stamp(self.path))]
            self.raw += [(topic, msg, msg.header.stamp) for topic, kept in self.sensors.items()
                         for msg in kept]
        self.recording.publish(Bool(True))
        return TriggerResponse(True, f"recording demonstration {self.count + 1} in {self.scenario.name}")

    def on_stop(self, _request):
        with self.lock:
            try:
                demo = self.builder.stop(self.scenario, self.source)
            except DemonstrationError as err:
                self.recording.publish(Bool(False))
                return TriggerResponse(False, str(err))
            raw, self.raw = self.raw, []
        self.recording.publish(Bool(False))
        self.count += 1
        msg = ros_demos.to_msg(demo, rospy.Time.now())
        ok, message = self.persist(msg, raw, demo.meta.get("model_error", 0.0))
        self.demos.publish(msg)     # after persisting: a listener may load it right away
        return TriggerResponse(ok, message)

    def persist(self, msg, raw, model_error):
        """Bag first, then the database; a failure of one keeps the other and says so."""
        parts, ok = [f"demonstration {self.count}: {len(msg.commands) // 2} steps, "
                     f"model error {model_error:.3g} m"], True
        if self.bag_dir is not None:
            name = f"demo_{msg.scenario_name}_{msg.header.stamp.to_nsec()}.bag"
            try:
                parts.append(f"bag {ros_demos.write_bag(self.bag_dir / name, msg, raw)}")
            except (OSError, DemonstrationError) as err:
                ok = False
                parts.append(f"bag NOT written: {err}")
        if self.db_url:
            try:
                with open_store(self.db_url) as store:
                    stored_id = ros_demos.store_demo(store, msg, session_id=self.session_id)
                    parts.append(f"database id {stored_id}")
            except StoreError as err:
                ok = False
                parts.append(f"database NOT written: {err}")
        return ok, "; ".join(parts)


def start() -> DemoRecorderNode:
    """The node's start-up: ~parameters -> recorder -> ROS wiring (ConfigError on a bad one)."""
    config = read_config(DemoRecorderParams)
    warn_password_in_url(config.db_url)  # roslaunch prints parameters: say so at once
    return DemoRecorderNode(config).setup()
