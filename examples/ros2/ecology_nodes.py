#!/usr/bin/env python3
"""Three ROS 2 lifecycle nodes that do what Ecology's simulated components do, for the agent.

Plain rclpy LifecycleNodes, as a ROS 2 user would write them, mirroring the simulated components of
`crates/ecology-sim/src/components.rs` (their text forms, speeds and rules):

- ``tracker`` (a ceiling tracking system, type ``tr-sys``): subscribes ``~/image``
  (std_msgs/String, ``NAME X Y THETA; ...``) and publishes ``~/global_pos`` (Pose2D) of its target
  (parameter ``target``, or else the third argument of ``ecology_params``) for each image that
  shows it.
- ``self_loc`` (type ``self-loc``): ``(pose-tracking R S)`` subscribes ``~/global_pos`` (Pose2D)
  and publishes ``~/position`` (Pose2D) for each; ``(scan-matching R S)`` subscribes ``~/odom``
  (Pose2D) and ``~/scan`` (LaserScan) and publishes ``~/position`` once per new pair of readings.
  With a map on ``~/map`` it matches the scan against the map around the odometry (the simulated
  component's grid search, rays at the scan's own angles); without one it passes the odometry on.
- ``navigation`` (the thinking cap, type ``tc``): subscribes ``~/position`` (Pose2D) and ``~/map``
  (std_msgs/String, transient local, ``room NAME X0 Y0 X1 Y1; door A B X Y; ...``), publishes
  ``~/cmd_vel`` (Twist) towards the room in parameter ``goal_room`` (or else the third argument of
  ``ecology_params``) through the doors on the way, and a zero Twist once there.

Each publishes ``~/ecology_status`` (std_msgs/String, transient local, reliable, depth 1):
``running``, ``done``, ``waiting CAUSE`` (the missing inputs by Ecology's information names:
``image``, ``global-pos``, ``range-scan``, ``odometry``, ``position``, ``map``) or ``error CAUSE``,
each time it changes.

Subscriptions and publishers are created in ``on_configure`` and destroyed in ``on_cleanup``;
publishers are lifecycle publishers, so nothing is published unless the node is active. Run one as

    python ecology_nodes.py tracker --name tr1 --namespace hsm

It prints ``ready`` on stdout once it is spinning and exits 0 on SIGTERM or SIGINT.
"""

import argparse
import math
import sys
import time

import rclpy
from geometry_msgs.msg import Pose2D, Twist
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.lifecycle import LifecycleNode, TransitionCallbackReturn
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import LaserScan
from std_msgs.msg import String

# As the simulated components (crates/ecology-sim/src/components.rs, world.rs).
PERIOD = 0.05
STALE = 0.5
IMAGES_LOST = 1.0
MAX_SPEED = 0.5
MAX_TURN = 1.5
MAX_RANGE = 8.0

LATCHED = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                     reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
POSE_FORM = "X Y THETA (three numbers)"


def wrap_angle(a):
    a = math.fmod(a, math.tau)
    if a > math.pi:
        a -= math.tau
    elif a <= -math.pi:
        a += math.tau
    return a


def quoted(text, limit=40):
    return '"' + (text if len(text) <= limit else text[:limit] + "…") + '"'


def numbers(text, count):
    """Exactly `count` finite numbers, or None."""
    try:
        values = [float(w) for w in text.split()]
    except ValueError:
        return None
    if len(values) != count or not all(math.isfinite(v) for v in values):
        return None
    return values


def parse_image(text):
    """[(name, (x, y, theta))] of an image `NAME X Y THETA; ...`, or None if any entry is bad."""
    seen = []
    for entry in (e.strip() for e in text.split(";")):
        if not entry:
            continue
        name, _, rest = entry.partition(" ")
        pose = numbers(rest, 3)
        if pose is None:
            return None
        seen.append((name, tuple(pose)))
    return seen


class Map:
    """Rooms and doors, from the world's map text (`ecology_tuples::world::Map`)."""

    FORM = "room NAME X0 Y0 X1 Y1 or door A B X Y"

    def __init__(self, text):
        """Raises ValueError with the contract's words for an item that is neither."""
        self.rooms = []  # (name, x0, y0, x1, y1)
        self.doors = []  # (a, b, x, y)
        for item in (i.strip() for i in text.split(";")):
            if not item:
                continue
            words = item.split()
            if len(words) == 6 and words[0] == "room" and numbers(" ".join(words[2:]), 4):
                self.rooms.append((words[1], *numbers(" ".join(words[2:]), 4)))
            elif len(words) == 5 and words[0] == "door" and numbers(" ".join(words[3:]), 2):
                self.doors.append((words[1], words[2], *numbers(" ".join(words[3:]), 2)))
            else:
                raise ValueError(f"expected {Map.FORM}, found {quoted(item)}")

    def room(self, name):
        return next((r for r in self.rooms if r[0] == name), None)

    def room_at(self, x, y):
        """The first room that contains (x, y), or else the nearest within 0.2 m (a door frame)."""
        if not (math.isfinite(x) and math.isfinite(y)):
            return None
        for r in self.rooms:
            if r[1] <= x <= r[3] and r[2] <= y <= r[4]:
                return r
        best = None
        for r in self.rooms:
            d = math.hypot(max(r[1] - x, x - r[3], 0.0), max(r[2] - y, y - r[4], 0.0))
            if d <= 0.2 and (best is None or d < best[0]):
                best = (d, r)
        return best and best[1]

    def route(self, start, goal):
        """Waypoints from room `start` to the centre of room `goal`: each door on the way (fewest
        doors first), then the centre; None when there is no way."""
        target = self.room(goal)
        if target is None:
            return None
        previous, seen, frontier = {}, {start}, [start]
        while frontier:
            room = frontier.pop(0)
            if room == goal:
                break
            for door in self.doors:
                if door[0] == room:
                    nxt = door[1]
                elif door[1] == room:
                    nxt = door[0]
                else:
                    continue
                if nxt not in seen:
                    seen.add(nxt)
                    previous[nxt] = (room, door)
                    frontier.append(nxt)
        if goal not in seen:
            return None
        doors, at = [], goal
        while at in previous:
            at, door = previous[at]
            doors.append((door[2], door[3]))
        doors.reverse()
        doors.append(((target[1] + target[3]) / 2.0, (target[2] + target[4]) / 2.0))
        return doors

    def ray(self, x, y, angle):
        """Distance from (x, y) along `angle` to the walls of its room, at most MAX_RANGE."""
        r = self.room_at(x, y)
        if r is None:
            return MAX_RANGE
        dx, dy = math.cos(angle), math.sin(angle)
        best = MAX_RANGE
        if dx > 1e-9:
            best = min(best, (r[3] - x) / dx)
        elif dx < -1e-9:
            best = min(best, (r[1] - x) / dx)
        if dy > 1e-9:
            best = min(best, (r[4] - y) / dy)
        elif dy < -1e-9:
            best = min(best, (r[2] - y) / dy)
        return max(best, 0.0)


class EcologyNode(LifecycleNode):
    """What the three nodes share: parameters, the status topic, a periodic check while active,
    and entities that live from configure to cleanup."""

    PARAMETERS = ()

    def __init__(self, name, namespace):
        super().__init__(name, namespace=namespace)
        for parameter in ("ecology_params", *self.PARAMETERS):
            self.declare_parameter(parameter, "")
        self.active = False
        self.shown = None
        self.status_pub = None
        self.timer = None
        self.entities = []

    # -- helpers -------------------------------------------------------------------------------

    def text_parameter(self, name):
        return self.get_parameter(name).get_parameter_value().string_value.strip()

    def args(self):
        """The arguments of `ecology_params`: `(pose-tracking astrid hsm)` -> [astrid, hsm]."""
        words = self.text_parameter("ecology_params").strip("() \t").split()
        return words[1:]

    def functionality(self):
        words = self.text_parameter("ecology_params").strip("() \t").split()
        return words[0] if words else ""

    def parameter_or_arg(self, name, index):
        """Parameter `name`, or else argument `index` (from 0) of ecology_params' arguments, as
        the simulated component reads `arg(index + 1)`."""
        value = self.text_parameter(name)
        if value:
            return value
        args = self.args()
        return args[index] if index < len(args) else ""

    def publisher(self, msg_type, topic, qos=10):
        pub = self.create_lifecycle_publisher(msg_type, topic, qos)
        self.entities.append(("publisher", pub))
        return pub

    def subscribe(self, msg_type, topic, callback, qos=10):
        self.entities.append(("subscription", self.create_subscription(msg_type, topic, callback,
                                                                       qos)))

    def report(self, status, cause=""):
        """Publishes the status when it changed."""
        now = (status, cause)
        if self.active and self.shown != now:
            self.shown = now
            self.status_pub.publish(String(data=f"{status} {cause}".strip()))

    # -- lifecycle -----------------------------------------------------------------------------

    def on_configure(self, state):
        problem = self.configure_ports()
        if problem:
            self.get_logger().error(f"cannot configure: {problem}")
            self.destroy_entities()
            return TransitionCallbackReturn.FAILURE
        self.status_pub = self.publisher(String, "~/ecology_status", LATCHED)
        return TransitionCallbackReturn.SUCCESS

    def on_activate(self, state):
        self.shown = None
        self.reset()
        result = super().on_activate(state)
        self.active = True
        self.timer = self.create_timer(PERIOD, self.tick)
        return result

    def on_deactivate(self, state):
        self.active = False
        if self.timer is not None:
            self.destroy_timer(self.timer)
            self.timer = None
        return super().on_deactivate(state)

    def on_cleanup(self, state):
        self.destroy_entities()
        return TransitionCallbackReturn.SUCCESS

    def on_shutdown(self, state):
        self.on_deactivate(state)
        self.destroy_entities()
        return TransitionCallbackReturn.SUCCESS

    def destroy_entities(self):
        for kind, entity in self.entities:
            if kind == "publisher":
                self.destroy_lifecycle_publisher(entity)
            else:
                self.destroy_subscription(entity)
        self.entities = []
        self.status_pub = None

    # -- what each node defines ----------------------------------------------------------------

    def configure_ports(self):
        """Creates the node's own subscriptions and publishers; a problem's text, or None."""
        raise NotImplementedError

    def reset(self):
        """Forgets what the last activation saw."""

    def tick(self):
        """Runs every PERIOD while active: judges staleness."""


class Tracker(EcologyNode):
    """A ceiling tracking system: the target's pose from the cameras' images."""

    PARAMETERS = ("target",)

    def configure_ports(self):
        self.target = self.parameter_or_arg("target", 2)
        if not self.target:
            return "no target (set parameter target, or ecology_params (tracking-system R S T))"
        self.global_pos = self.publisher(Pose2D, "~/global_pos")
        self.subscribe(String, "~/image", self.on_image)
        return None

    def reset(self):
        self.last_image = None
        self.ever = False

    def on_image(self, msg):
        if not self.active:
            return
        self.last_image = time.monotonic()
        self.ever = True
        image = parse_image(msg.data)
        if image is None:
            self.report("waiting", f"unreadable image: expected NAME X Y THETA entries separated "
                                   f"by ;, found {quoted(msg.data)}")
            return
        pose = next((p for name, p in image if name == self.target), None)
        if pose is None:
            self.report("waiting", f"{self.target} not in view")
            return
        self.report("running")
        self.global_pos.publish(Pose2D(x=pose[0], y=pose[1], theta=pose[2]))

    def tick(self):
        age = None if self.last_image is None else time.monotonic() - self.last_image
        if self.ever and age > IMAGES_LOST:
            self.report("error", f"no images from the cameras for {IMAGES_LOST:g} s: a camera "
                                 f"stopped producing images")
        elif age is None or age > STALE:
            self.report("waiting", "image")


class SelfLocalization(EcologyNode):
    """Self-localization: pose tracking from a global position, or scan matching."""

    def configure_ports(self):
        self.mode = self.functionality()
        self.position = self.publisher(Pose2D, "~/position")
        if self.mode == "pose-tracking":
            self.subscribe(Pose2D, "~/global_pos", self.on_global_pos)
        elif self.mode == "scan-matching":
            self.subscribe(Pose2D, "~/odom", self.on_odom)
            self.subscribe(LaserScan, "~/scan", self.on_scan)
            self.subscribe(String, "~/map", self.on_map, LATCHED)
            self.map = None
        else:
            return (f"ecology_params {quoted(self.text_parameter('ecology_params'))} name neither "
                    f"(pose-tracking R S) nor (scan-matching R S)")
        return None

    def reset(self):
        self.heard = {}  # information name -> monotonic time of the last message
        self.odom = None
        self.scan = None
        self.fresh = (False, False)
        self.correction = (0.0, 0.0, 0.0)

    def inputs(self):
        return ["global-pos"] if self.mode == "pose-tracking" else ["range-scan", "odometry"]

    def missing(self):
        now = time.monotonic()
        return [i for i in self.inputs() if now - self.heard.get(i, -math.inf) > STALE]

    def on_global_pos(self, msg):
        if not self.active:
            return
        self.heard["global-pos"] = time.monotonic()
        self.report("running")
        self.position.publish(Pose2D(x=msg.x, y=msg.y, theta=msg.theta))

    def on_map(self, msg):
        try:
            self.map = Map(msg.data)
        except ValueError as e:
            self.get_logger().warning(f"unreadable map: {e}")

    def on_odom(self, msg):
        if self.active:
            self.heard["odometry"] = time.monotonic()
            self.odom = msg
            self.fresh = (self.fresh[0], True)
            self.match()

    def on_scan(self, msg):
        if self.active:
            self.heard["range-scan"] = time.monotonic()
            self.scan = msg
            self.fresh = (True, self.fresh[1])
            self.match()

    def match(self):
        # As the simulated component: once per new pair of readings, whichever came first, so
        # the result does not depend on their order.
        if not all(self.fresh) or self.missing():
            return
        self.fresh = (False, False)
        odom = self.odom
        if self.map is None:
            best = (odom.x, odom.y, odom.theta)
        else:
            c = self.correction
            guess = (odom.x + c[0], odom.y + c[1], wrap_angle(odom.theta + c[2]))
            best = match_scan(self.map, guess, self.scan)
            self.correction = (best[0] - odom.x, best[1] - odom.y,
                               wrap_angle(best[2] - odom.theta))
        self.report("running")
        self.position.publish(Pose2D(x=best[0], y=best[1], theta=best[2]))

    def tick(self):
        missing = self.missing()
        if missing:
            self.report("waiting", " ".join(missing))


def match_scan(map_, guess, scan):
    """The pose near `guess` whose expected ranges best match the scan: the simulated scan
    matcher's grid search over ±0.3 m and ±0.06 rad, residuals capped at 1 m."""
    angles = [scan.angle_min + i * scan.angle_increment for i in range(len(scan.ranges))]
    ranges = [r for r in scan.ranges]
    best = (math.inf, guess)
    for i in range(-6, 7):
        for j in range(-6, 7):
            for k in range(-2, 3):
                x, y = guess[0] + i * 0.05, guess[1] + j * 0.05
                theta = wrap_angle(guess[2] + k * 0.03)
                error = sum(min(abs(map_.ray(x, y, theta + a) - r), 1.0) ** 2
                            for a, r in zip(angles, ranges) if math.isfinite(r))
                error += 0.001 * (i * i + j * j + k * k)
                if error < best[0]:
                    best = (error, (x, y, theta))
    return best[1]


class Navigation(EcologyNode):
    """The thinking cap's navigation: steers to the goal room through the doors on the way."""

    PARAMETERS = ("goal_room",)

    def configure_ports(self):
        self.goal = self.parameter_or_arg("goal_room", 2)
        if not self.goal:
            return "no goal room (set parameter goal_room, or ecology_params (navigation R S ROOM))"
        self.cmd_vel = self.publisher(Twist, "~/cmd_vel")
        self.subscribe(Pose2D, "~/position", self.on_position)
        self.subscribe(String, "~/map", self.on_map, LATCHED)
        self.map = None
        self.map_problem = None
        return None

    def reset(self):
        self.last_position = None
        self.route = None
        self.arrived = False
        self.failed = False

    def on_map(self, msg):
        try:
            self.map, self.map_problem = Map(msg.data), None
        except ValueError as e:
            self.map, self.map_problem = None, f"unreadable map: {e}"

    def drive(self, v, w):
        twist = Twist()
        twist.linear.x, twist.angular.z = float(v), float(w)
        self.cmd_vel.publish(twist)

    def on_position(self, msg):
        if not self.active or self.arrived or self.failed:
            return
        self.last_position = time.monotonic()
        if self.map is None:
            self.report("waiting", self.map_problem or "map")
            return
        if self.route is None:
            here = self.map.room_at(msg.x, msg.y)
            if here is None:
                return self.fail(f"position {msg.x:.3f} {msg.y:.3f} {msg.theta:.4f} is outside "
                                 f"the map")
            self.route = self.map.route(here[0], self.goal)
            if self.route is None:
                return self.fail(f"no way from {here[0]} to {self.goal}")
        route = self.route
        while len(route) > 1 and math.hypot(msg.x - route[0][0], msg.y - route[0][1]) < 0.2:
            route.pop(0)
        wx, wy = route[0]
        distance = math.hypot(msg.x - wx, msg.y - wy)
        if len(route) == 1 and distance < 0.15:
            self.arrived = True
            self.drive(0.0, 0.0)
            self.report("done")
            return
        error = wrap_angle(math.atan2(wy - msg.y, wx - msg.x) - msg.theta)
        w = max(-MAX_TURN, min(MAX_TURN, 2.5 * error))
        v = 0.0 if abs(error) > 0.7 else min(0.8 * distance, 0.8 * MAX_SPEED) * math.cos(error)
        self.report("running")
        self.drive(v, w)

    def fail(self, cause):
        self.failed = True
        self.drive(0.0, 0.0)
        self.report("error", cause)

    def tick(self):
        if self.arrived or self.failed:
            return
        if self.last_position is None or time.monotonic() - self.last_position > STALE:
            # As the simulated one: stop the base while the position is missing or stale.
            self.drive(0.0, 0.0)
            self.report("waiting", "position")


KINDS = {"tracker": Tracker, "self_loc": SelfLocalization, "navigation": Navigation}


def main(argv=None):
    parser = argparse.ArgumentParser(description="Run one of Ecology's example lifecycle nodes.")
    parser.add_argument("kind", choices=sorted(KINDS))
    parser.add_argument("--name", help="the node's name (default: the kind)")
    parser.add_argument("--namespace", default="", help="the node's namespace, e.g. hsm")
    args = parser.parse_args(argv)
    rclpy.init()
    node = KINDS[args.kind](args.name or args.kind, args.namespace)
    executor = SingleThreadedExecutor()
    executor.add_node(node)

    def announce():
        # Runs inside spin, so "ready" means the node is spinning.
        ready.cancel()
        print("ready", flush=True)
    ready = node.create_timer(0.0, announce)
    try:
        executor.spin()
    except (ExternalShutdownException, KeyboardInterrupt):
        pass
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
