#!/usr/bin/env python3
"""The Ecology ROS 2 agent: drives ROS 2 lifecycle nodes on behalf of one `ecology peis` process.

The host (the Rust `ecology peis` process) runs this file as a subprocess and speaks JSON lines with
it: one JSON object per line, UTF-8, requests on the agent's stdin, events on its stdout. Nothing
but events is ever written on stdout (file descriptor 1 is moved to stderr at start, so ROS 2's own
logging cannot corrupt the stream); logs go to stderr. The file is self-contained (stdlib, rclpy and
the message packages) because the host embeds it.

Requests (host -> agent)
------------------------
- ``{"op":"declare","id":C,"node":"/NS/NAME","inputs":[{"info","topic","type"}],
  "outputs":[...],"feeds":[{"name","topic","type"}],"status_topic":T|null}``: component C is
  backed by the lifecycle node /NS/NAME. Creates the inputs' and feeds' publishers and the node's
  lifecycle service clients; does not touch the node. Declaring an id again replaces it (refused
  while it is started).
- ``{"op":"start","id":C,"params":TEXT,"parameters":{NAME:VALUE}}``: waits up to 5 s for the
  node's lifecycle services, brings it back to unconfigured (deactivate if active, cleanup if
  inactive), sets every entry of ``parameters`` and ``ecology_params`` = TEXT as string parameters,
  then configures and activates it. Events: ``initializing``, then ``running`` (or ``error`` with
  a cause naming the step that failed). While started its status topic, if any, is forwarded as
  ``status`` events, and each output someone reads (``read``) as ``output`` events.
- ``{"op":"read","id":C,"info":I}`` / ``{"op":"unread","id":C,"info":I}``: someone reads, or
  nobody reads any more, output I of C. The agent subscribes to an output's topic only while it
  is read and C is started, so an output nobody reads costs nothing: its node sees no
  subscriber (``get_subscription_count``), and no message is taken in or converted. Outputs
  start unread and stay as last said across runs (the host says it again at each start).
- ``{"op":"stop","id":C}``: deactivate (if active), cleanup (if inactive), drop its output, status
  and relay subscriptions; event ``{"ev":"stopped","id":C,"state":S}`` with the lifecycle state it
  ended in (``gone`` when the node does not answer within 1 s).
- ``{"op":"input","id":C,"info":I,"text":TEXT}``: TEXT converted to the input's type, published
  on the input's topic.
- ``{"op":"relay","id":C,"info":I,"from":TOPIC}`` / ``{"op":"unrelay","id":C,"info":I}``: every
  message on TOPIC is republished on the input's topic as it is (serialized bytes, no conversion).
  A relay replaces an earlier relay of the same input.
- ``{"op":"feed","id":C,"name":N,"text":TEXT}``: TEXT published on the feed's topic, transient
  local, reliable, depth 1 (a late subscriber gets the last one).
- ``{"op":"quit"}`` or EOF on stdin (the host died) or SIGTERM/SIGINT: stop every started
  component as ``stop`` does, in parallel, then exit 0.

Events (agent -> host)
----------------------
- ``{"ev":"ready","rmw":RMW,"domain_id":N}`` once rclpy is up.
- ``{"ev":"status","id":C,"status":"initializing|running|waiting|done|error","cause":TEXT}``
  (``cause`` omitted when empty).
- ``{"ev":"output","id":C,"info":I,"text":TEXT}``, ``{"ev":"stopped","id":C,"state":S}``.
- ``{"ev":"error","text":TEXT}``: a request that could not be served (bad JSON, unknown op, id,
  info or message type, a text that does not parse). The agent carries on.

Watching a started node, and how fast failures are seen
-------------------------------------------------------
While a component runs, its worker polls ``/NODE/get_state`` every 0.25 s, each call given at most
0.5 s. A node that has not answered for 1 s is reported as ``error`` with cause ``ROS 2 node N does
not answer (its process is gone?)``: a process killed with SIGKILL stays in the DDS graph for its
participant lease (20 s on Fast DDS), so the graph cannot be trusted for this. The last answer came
at most 0.25 s before the death and the error is reported 1 s after that answer, so a dead node is
reported 0.75 to 1 s after it died, plus scheduling delays: under 1.5 s (check_agent.py holds 2 s,
and measures about 0.8-0.9 s). A node that answers
with a state other than ``active`` is reported as ``error`` with cause ``ROS 2 node N left active:
now STATE``; ``/NODE/transition_event`` is watched too, so a transition out of active (a hand-made
deactivate, an ``on_error``) is reported as soon as the node announces it, without waiting for the
next poll.

Status topic
------------
A node with a status topic publishes ``std_msgs/msg/String`` there: ``running``, ``done``,
``waiting CAUSE`` or ``error CAUSE``. The agent subscribes with transient-local, reliable, depth 1
QoS (so the node's publisher must be transient local too: the last status is not lost between
activation and the agent's subscription), and forwards each change as a status event, starting from
``running`` once the node is active.

Threads and QoS
---------------
One thread spins rclpy (a SingleThreadedExecutor: no callback blocks, and rclpy's multi-threaded
executor stalled relays for hundreds of milliseconds); each component has a worker thread that
runs its lifecycle calls and watch in order; the main thread reads requests. Inputs, outputs and
relays use reliable, volatile, keep-last-100 QoS (a best-effort publisher does not match them).
Events are written as they come; a host that stops reading stdout stalls the agent.

Text forms of the messages
--------------------------
Numbers are written with 3 decimals. Reading a text never crashes: a text that does not parse is
reported as an ``error`` event and dropped.

=============================== =================== ===================================================
Message type                    Text                Notes
=============================== =================== ===================================================
geometry_msgs/msg/Pose2D        X Y THETA           metres, radians
geometry_msgs/msg/PoseStamped   X Y THETA           yaw <-> quaternion about z; written with frame_id
                                                    map and stamp = now
geometry_msgs/msg/Twist         V W                 linear.x m/s, angular.z rad/s
sensor_msgs/msg/LaserScan       R1 R2 ... (1 or     N rays evenly around the robot, the first along
                                more ranges)        its heading (as Ecology's simulated laser: 8 rays
                                                    every 45 degrees): angle_min 0, increment 2pi/N;
                                                    range_max 10, frame_id laser; non-finite ranges
                                                    are read as range_max
std_msgs/msg/String             the text as it is
std_msgs/msg/Float64            one number
=============================== =================== ===================================================

Only these types can be declared (relays included), so every declared port has a text form.
"""

import importlib
import json
import math
import os
import queue
import signal
import sys
import threading
import time

import rclpy
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions

# How long the start waits for the node's lifecycle services.
SERVICES_WAIT = 5.0
# The watcher: poll period, one call's limit, and the silence that means the node is gone.
POLL_PERIOD = 0.25
POLL_TIMEOUT = 0.5
# (1 s was too short on a loaded machine: a live node went that long unanswered in a full test
# run on two cores, and was reported gone.)
SILENCE = 2.0
# How long a lifecycle transition or a parameter change may take before it counts as failed.
TRANSITION_TIMEOUT = 5.0
# How long a stop waits for the node's state before calling it gone.
STOP_STATE_TIMEOUT = 1.0
# How long quit waits for every stop before exiting anyway.
QUIT_TIMEOUT = 2.5

STATUSES = ("initializing", "running", "waiting", "done", "error")

# Lifecycle state and transition ids (lifecycle_msgs/msg/State, lifecycle_msgs/msg/Transition).
UNCONFIGURED, INACTIVE, ACTIVE, FINALIZED = 1, 2, 3, 4
CONFIGURE, CLEANUP, ACTIVATE, DEACTIVATE = 1, 2, 3, 4
TRANSITION_NAMES = {CONFIGURE: "configure", CLEANUP: "cleanup", ACTIVATE: "activate",
                    DEACTIVATE: "deactivate"}

# Data ports: reliable, keep the last 100 (enough for bursts without unbounded memory).
DATA_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)
# Feeds and status topics: the last value survives for late subscribers.
LATCHED_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)


def log(text):
    print(f"ecology_ros2_agent: {text}", file=sys.stderr, flush=True)


class BadRequest(Exception):
    """A request that cannot be served; its text goes back to the host as an error event."""


# ---------------------------------------------------------------------------------------------
# Conversions between Ecology's text forms and messages.


def fmt(value):
    return f"{value:.3f}"


def numbers(text, count, form):
    """Exactly `count` finite numbers separated by white space, or BadRequest naming `form`."""
    words = text.split()
    try:
        values = [float(w) for w in words]
    except ValueError:
        values = None
    if values is None or len(values) != count or not all(math.isfinite(v) for v in values):
        raise BadRequest(f"expected {form}, found {quoted(text)}")
    return values


def quoted(text, limit=40):
    return json.dumps(text if len(text) <= limit else text[:limit] + "…", ensure_ascii=False)


def yaw_of(q):
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def pose2d_text(m):
    return f"{fmt(m.x)} {fmt(m.y)} {fmt(m.theta)}"


def pose2d_msg(cls, text, node):
    x, y, theta = numbers(text, 3, "X Y THETA (three numbers)")
    return cls(x=x, y=y, theta=theta)


def pose_stamped_text(m):
    p = m.pose.position
    return f"{fmt(p.x)} {fmt(p.y)} {fmt(yaw_of(m.pose.orientation))}"


def pose_stamped_msg(cls, text, node):
    x, y, theta = numbers(text, 3, "X Y THETA (three numbers)")
    m = cls()
    m.header.frame_id = "map"
    m.header.stamp = node.get_clock().now().to_msg()
    m.pose.position.x, m.pose.position.y = x, y
    m.pose.orientation.z, m.pose.orientation.w = math.sin(theta / 2.0), math.cos(theta / 2.0)
    return m


def twist_text(m):
    return f"{fmt(m.linear.x)} {fmt(m.angular.z)}"


def twist_msg(cls, text, node):
    v, w = numbers(text, 2, "V W (two numbers)")
    m = cls()
    m.linear.x, m.angular.z = v, w
    return m


def scan_text(m):
    return " ".join(fmt(r if math.isfinite(r) else m.range_max) for r in m.ranges)


def scan_msg(cls, text, node):
    words = text.split()
    ranges = numbers(text, max(len(words), 1), "ranges in metres separated by spaces")
    m = cls()
    m.header.frame_id = "laser"
    m.header.stamp = node.get_clock().now().to_msg()
    # N rays evenly around the robot, the first along its heading: as Ecology's simulated laser
    # measures them (8 rays every 45 degrees).
    m.angle_increment = 2.0 * math.pi / len(ranges)
    m.angle_min = 0.0
    m.angle_max = m.angle_increment * (len(ranges) - 1)
    m.range_min, m.range_max = 0.0, 10.0
    m.ranges = ranges
    return m


def string_text(m):
    return m.data


def string_msg(cls, text, node):
    return cls(data=text)


def float_text(m):
    return fmt(m.data)


def float_msg(cls, text, node):
    (value,) = numbers(text, 1, "one number")
    return cls(data=value)


# type name -> (module, class, message -> text, (class, text, node) -> message)
CONVERSIONS = {
    "geometry_msgs/msg/Pose2D": ("geometry_msgs.msg", "Pose2D", pose2d_text, pose2d_msg),
    "geometry_msgs/msg/PoseStamped": ("geometry_msgs.msg", "PoseStamped", pose_stamped_text,
                                      pose_stamped_msg),
    "geometry_msgs/msg/Twist": ("geometry_msgs.msg", "Twist", twist_text, twist_msg),
    "sensor_msgs/msg/LaserScan": ("sensor_msgs.msg", "LaserScan", scan_text, scan_msg),
    "std_msgs/msg/String": ("std_msgs.msg", "String", string_text, string_msg),
    "std_msgs/msg/Float64": ("std_msgs.msg", "Float64", float_text, float_msg),
}


class MessageType:
    """A declared message type with its text form."""

    def __init__(self, name):
        if name not in CONVERSIONS:
            raise BadRequest(f"unknown message type {quoted(str(name))} (known: "
                             f"{', '.join(sorted(CONVERSIONS))})")
        module, cls, self.to_text, self._from_text = CONVERSIONS[name]
        try:
            self.cls = getattr(importlib.import_module(module), cls)
        except (ImportError, AttributeError) as e:
            raise BadRequest(f"message type {name} is not installed: {e}") from e
        self.name = name

    def from_text(self, text, node):
        return self._from_text(self.cls, text, node)


# ---------------------------------------------------------------------------------------------
# Output: one writer for the protocol stream.


class Events:
    """Writes events on the protocol stream, one line each, from any thread."""

    def __init__(self, stream):
        self._stream = stream
        self._lock = threading.Lock()

    def send(self, event):
        line = json.dumps(event, ensure_ascii=False, separators=(",", ":"))
        with self._lock:
            try:
                self._stream.write(line + "\n")
                self._stream.flush()
            except (BrokenPipeError, ValueError):
                # The host is gone; quit follows from EOF on stdin.
                pass

    def status(self, cid, status, cause=""):
        event = {"ev": "status", "id": cid, "status": status}
        if cause:
            event["cause"] = cause
        self.send(event)

    def error(self, text):
        log(f"error: {text}")
        self.send({"ev": "error", "text": text})


# ---------------------------------------------------------------------------------------------
# Components.


def field(request, name, kind=str, optional=False):
    value = request.get(name)
    if value is None and optional:
        return None
    if not isinstance(value, kind):
        raise BadRequest(f"{request.get('op')} request lacks {name!r} "
                         f"({kind.__name__ if isinstance(kind, type) else 'value'})")
    return value


def absolute(topic, what):
    if not isinstance(topic, str) or not topic.startswith("/") or len(topic) < 2:
        raise BadRequest(f"{what} must be an absolute ROS 2 name, found {quoted(str(topic))}")
    return topic


class Port:
    """A declared input, output or feed: its topic and message type."""

    def __init__(self, spec, key, owner):
        if not isinstance(spec, dict):
            raise BadRequest(f"component {owner}: a port must be an object, found {spec!r}")
        self.name = field(spec, key)
        self.topic = absolute(spec.get("topic"), f"component {owner} {key} {self.name} topic")
        self.type = MessageType(spec.get("type"))
        self.publisher = None
        self.relay = None
        # An output: whether someone reads it, and the subscription forwarding it while so.
        self.read = False
        self.subscription = None


class Component:
    """One declared component: its node, ports, and a worker thread that owns its lifecycle."""

    def __init__(self, agent, cid, node_name, inputs, outputs, feeds, status_topic):
        self.agent = agent
        self.id = cid
        self.node_name = node_name
        self.inputs = inputs
        self.outputs = outputs
        self.feeds = feeds
        self.status_topic = status_topic
        node = agent.node
        group = agent.group
        from lifecycle_msgs.srv import ChangeState, GetState
        from rcl_interfaces.srv import SetParameters
        self.get_state = node.create_client(GetState, f"{node_name}/get_state", callback_group=group)
        self.change_state = node.create_client(ChangeState, f"{node_name}/change_state",
                                               callback_group=group)
        self.set_parameters = node.create_client(SetParameters, f"{node_name}/set_parameters",
                                                 callback_group=group)
        for port in inputs.values():
            port.publisher = node.create_publisher(port.type.cls, port.topic, DATA_QOS,
                                                   callback_group=group)
        for port in feeds.values():
            port.publisher = node.create_publisher(port.type.cls, port.topic, LATCHED_QOS,
                                                   callback_group=group)
        # The lifecycle of the node is handled by the worker only; other threads talk to it
        # through the queue. `lock` guards the phase and the status forwarding.
        self.lock = threading.Lock()
        self.phase = "idle"  # idle, starting, running, failed
        self.pending_status = None
        self.last_status = None
        self.subscriptions = []
        # Whether the node's subscriptions are up (between subscribe and drop_subscriptions);
        # outputs read are subscribed to only then. Guarded by `lock`.
        self.listening = False
        self.queue = queue.Queue()
        self.stopped = threading.Event()
        self.worker = threading.Thread(target=self.work, name=f"component-{cid}", daemon=True)
        self.worker.start()

    @property
    def started(self):
        return self.phase != "idle"

    def destroy(self):
        """Ends the worker and drops every ROS entity (for a redeclaration)."""
        self.queue.put(("exit",))
        self.worker.join(timeout=2.0)
        node = self.agent.node
        self.drop_subscriptions()
        for port in self.inputs.values():
            self.unrelay(port)
            node.destroy_publisher(port.publisher)
        for port in self.feeds.values():
            node.destroy_publisher(port.publisher)
        for client in (self.get_state, self.change_state, self.set_parameters):
            node.destroy_client(client)

    # -- requests from the host (any thread) ---------------------------------------------------

    def input(self, info, text):
        self.publish(self.inputs, info, "input", text)

    def feed(self, name, text):
        self.publish(self.feeds, name, "feed", text)

    def publish(self, ports, name, kind, text):
        """TEXT converted to the message type of the `kind` port `name`, published on its topic."""
        port = self.port(ports, name, kind)
        try:
            msg = port.type.from_text(text, self.agent.node)
        except BadRequest as e:
            raise BadRequest(f"{kind} {self.id} {name}: {e}") from None
        port.publisher.publish(msg)

    def set_read(self, info, read):
        """Someone reads output `info`, or nobody does any more."""
        port = self.port(self.outputs, info, "output")
        with self.lock:
            port.read = read
            if read and self.listening:
                self.forward(port)
            elif not read:
                self.unforward(port)

    def forward(self, port):
        """Subscribes to output `port`'s topic, if not yet; the caller holds `lock`."""
        if port.subscription is None:
            port.subscription = self.agent.node.create_subscription(
                port.type.cls, port.topic, self.output_callback(port), DATA_QOS,
                callback_group=self.agent.group)

    def unforward(self, port):
        """Drops output `port`'s subscription, if any; the caller holds `lock`."""
        if port.subscription is not None:
            self.agent.node.destroy_subscription(port.subscription)
            port.subscription = None

    def relay(self, info, source):
        port = self.port(self.inputs, info, "input")
        absolute(source, f"relay {self.id} {info} from")
        self.unrelay(port)
        publisher = port.publisher
        # Raw: the bytes are republished as they came, never deserialized.
        port.relay = self.agent.node.create_subscription(
            port.type.cls, source, publisher.publish, DATA_QOS, raw=True,
            callback_group=self.agent.group)

    def unrelay(self, port):
        if port.relay is not None:
            self.agent.node.destroy_subscription(port.relay)
            port.relay = None

    def port(self, ports, name, what):
        if name not in ports:
            raise BadRequest(f"component {self.id} has no {what} {quoted(str(name))} (it has: "
                             f"{', '.join(sorted(ports)) or 'none'})")
        return ports[name]

    # -- the worker ----------------------------------------------------------------------------

    def work(self):
        next_poll = None
        while True:
            timeout = None if next_poll is None else max(0.0, next_poll - time.monotonic())
            try:
                item = self.queue.get(timeout=timeout)
            except queue.Empty:
                item = ("poll",)
            try:
                if item[0] == "exit":
                    return
                if item[0] == "start":
                    next_poll = None
                    if self.start(item[1], item[2]):
                        self.last_answer = time.monotonic()
                        next_poll = time.monotonic() + POLL_PERIOD
                elif item[0] == "stop":
                    next_poll = None
                    self.stop()
                elif item[0] == "left" and next_poll is not None:
                    self.fail(f"ROS 2 node {self.node_name} left active: now {item[1]}")
                    next_poll = None
                elif item[0] == "poll" and next_poll is not None:
                    next_poll = self.poll()
            except Exception as e:  # noqa: BLE001 - a bug must not kill the worker silently
                log(f"component {self.id}: {item[0]} failed: {e!r}")
                self.agent.events.error(f"component {self.id}: {item[0]} failed: {e}")
                next_poll = None

    def poll(self):
        """One watch of the node; the time of the next one, or None once it failed."""
        began = time.monotonic()
        deadline = self.last_answer + SILENCE
        state = self.state(min(POLL_TIMEOUT, max(0.0, deadline - began)))
        now = time.monotonic()
        if state is not None:
            self.last_answer = now
            if state[0] != ACTIVE:
                self.fail(f"ROS 2 node {self.node_name} left active: now {state[1]}")
                return None
        elif now >= deadline:
            self.fail(f"ROS 2 node {self.node_name} does not answer (its process is gone?)")
            return None
        return max(began + POLL_PERIOD, now) if state is not None else now

    def fail(self, cause):
        with self.lock:
            if self.phase == "failed":
                return
            self.phase = "failed"
            self.agent.events.status(self.id, "error", cause)

    def start(self, params, parameters):
        """Brings the node from whatever state to active with the new parameters; True when
        it runs."""
        if self.started:
            self.teardown()
        events = self.agent.events
        with self.lock:
            self.phase = "starting"
            self.pending_status = None
            self.last_status = None
        events.status(self.id, "initializing")
        name = self.node_name
        if not self.wait_for_services():
            self.fail(f"ROS 2 node {name} is not running "
                      f"(no lifecycle services after {SERVICES_WAIT:g} s)" if self.agent.running
                      else "the ROS 2 agent is quitting")
            return False
        state = self.state(TRANSITION_TIMEOUT)
        if state is None:
            self.fail(f"ROS 2 node {name} does not answer (its process is gone?)")
            return False
        if state[0] == ACTIVE:
            state = self.transition(DEACTIVATE, state)
            if state is None:
                return False
        if state[0] == INACTIVE:
            state = self.transition(CLEANUP, state)
            if state is None:
                return False
        if state[0] != UNCONFIGURED:
            self.fail(f"ROS 2 node {name} cannot be configured: it is {state[1]}")
            return False
        if not self.set_node_parameters(params, parameters):
            return False
        self.subscribe()
        state = self.transition(CONFIGURE, state)
        if state is None:
            return False
        state = self.transition(ACTIVATE, state)
        if state is None:
            return False
        with self.lock:
            self.phase = "running"
            self.last_status = ("running", "")
            events.status(self.id, "running")
            if self.pending_status not in (None, self.last_status):
                self.last_status = self.pending_status
                events.status(self.id, *self.pending_status)
            self.pending_status = None
        return True

    def stop(self):
        """Deactivates and cleans up the node, drops its subscriptions; reports `stopped`."""
        state = self.teardown()
        for port in self.inputs.values():
            self.unrelay(port)
        self.agent.events.send({"ev": "stopped", "id": self.id,
                                "state": "gone" if state is None else state[1]})
        self.stopped.set()

    def teardown(self):
        """Unconfigures the node as far as it goes; its last state, or None when gone."""
        with self.lock:
            self.phase = "idle"
        self.drop_subscriptions()
        state = self.state(STOP_STATE_TIMEOUT)
        for transition, source in ((DEACTIVATE, ACTIVE), (CLEANUP, INACTIVE)):
            if state is not None and state[0] == source:
                self.call(self.change_state, self.change_request(transition), TRANSITION_TIMEOUT)
                state = self.state(STOP_STATE_TIMEOUT)
        return state

    def wait_for_services(self):
        # rclpy offers no way to await a graph change from Python, so the graph is polled.
        deadline = time.monotonic() + SERVICES_WAIT
        clients = (self.get_state, self.change_state, self.set_parameters)
        while not all(c.service_is_ready() for c in clients):
            if time.monotonic() >= deadline or not self.agent.running:
                return False
            time.sleep(0.02)
        return True

    def call(self, client, request, timeout):
        """The response of one service call, or None when none came within `timeout`."""
        done = threading.Event()
        future = client.call_async(request)
        future.add_done_callback(lambda _: done.set())
        if not done.wait(timeout) or future.result() is None:
            future.cancel()
            client.remove_pending_request(future)
            return None
        return future.result()

    def state(self, timeout):
        """The node's lifecycle state as (id, label), or None when it did not answer."""
        from lifecycle_msgs.srv import GetState
        response = self.call(self.get_state, GetState.Request(), timeout)
        if response is None:
            return None
        return response.current_state.id, response.current_state.label

    def change_request(self, transition):
        from lifecycle_msgs.srv import ChangeState
        request = ChangeState.Request()
        request.transition.id = transition
        return request

    def transition(self, transition, before):
        """Runs one transition; the new state, or None after reporting the failure."""
        what = TRANSITION_NAMES[transition]
        name = self.node_name
        response = self.call(self.change_state, self.change_request(transition), TRANSITION_TIMEOUT)
        if response is None:
            self.fail(f"ROS 2 node {name} did not answer {what} within {TRANSITION_TIMEOUT:g} s")
            return None
        state = self.state(TRANSITION_TIMEOUT)
        now = "unknown" if state is None else state[1]
        if not response.success:
            self.fail(f"{what} of ROS 2 node {name} failed (it was {before[1]}, now {now})")
            return None
        if state is None:
            self.fail(f"ROS 2 node {name} does not answer (its process is gone?)")
            return None
        return state

    def set_node_parameters(self, params, parameters):
        from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
        from rcl_interfaces.srv import SetParameters
        values = dict(parameters)
        values["ecology_params"] = params
        request = SetParameters.Request()
        request.parameters = [
            Parameter(name=key, value=ParameterValue(type=ParameterType.PARAMETER_STRING,
                                                     string_value=str(value)))
            for key, value in values.items()]
        response = self.call(self.set_parameters, request, TRANSITION_TIMEOUT)
        name = self.node_name
        if response is None:
            self.fail(f"ROS 2 node {name} did not answer set_parameters within "
                      f"{TRANSITION_TIMEOUT:g} s")
            return False
        for parameter, result in zip(request.parameters, response.results):
            if not result.successful:
                self.fail(f"ROS 2 node {name} refused parameter {parameter.name}: "
                          f"{result.reason or 'no reason given'}")
                return False
        return True

    # -- subscriptions (callbacks run on the executor's threads) -------------------------------

    def subscribe(self):
        node = self.agent.node
        group = self.agent.group
        with self.lock:
            self.listening = True
            for port in self.outputs.values():
                if port.read:
                    self.forward(port)
        if self.status_topic is not None:
            from std_msgs.msg import String
            self.subscriptions.append(node.create_subscription(
                String, self.status_topic, self.on_status, LATCHED_QOS, callback_group=group))
        from lifecycle_msgs.msg import TransitionEvent
        self.subscriptions.append(node.create_subscription(
            TransitionEvent, f"{self.node_name}/transition_event", self.on_transition, 10,
            callback_group=group))

    def drop_subscriptions(self):
        with self.lock:
            self.listening = False
            for port in self.outputs.values():
                self.unforward(port)
        for subscription in self.subscriptions:
            self.agent.node.destroy_subscription(subscription)
        self.subscriptions = []

    def output_callback(self, port):
        events = self.agent.events
        prefix = {"ev": "output", "id": self.id, "info": port.name}

        def on_output(msg):
            try:
                text = port.type.to_text(msg)
            except (AttributeError, TypeError, ValueError) as e:
                events.error(f"output {self.id} {port.name}: cannot write a {port.type.name}: {e}")
                return
            events.send({**prefix, "text": text})
        return on_output

    def on_status(self, msg):
        status, _, cause = msg.data.strip().partition(" ")
        if status not in STATUSES:
            self.agent.events.error(f"component {self.id}: ROS 2 node {self.node_name} "
                                    f"published an unknown status {quoted(msg.data)} on "
                                    f"{self.status_topic}")
            return
        now = (status, cause.strip())
        with self.lock:
            if self.phase == "starting":
                self.pending_status = now
            elif self.phase == "running" and now != self.last_status:
                self.last_status = now
                self.agent.events.status(self.id, *now)

    def on_transition(self, msg):
        # A transition announces its transitional state first (deactivating), then the primary
        # one it ends in; the primary one is what the host should hear.
        if self.phase == "running" and msg.goal_state.id in (UNCONFIGURED, INACTIVE, FINALIZED):
            self.queue.put(("left", msg.goal_state.label or str(msg.goal_state.id)))


# ---------------------------------------------------------------------------------------------
# The agent.


class Agent:
    def __init__(self, events):
        self.events = events
        self.running = True
        self.node = rclpy.create_node(f"ecology_ros2_agent_{os.getpid()}")
        self.group = ReentrantCallbackGroup()
        # One thread runs every callback. None of them blocks (the lifecycle calls wait in the
        # components' workers), and rclpy's MultiThreadedExecutor stalled relays for hundreds of
        # milliseconds under load (bench_wiring.py: relay p99 over 250 ms against 2 ms here).
        self.executor = SingleThreadedExecutor()
        self.executor.add_node(self.node)
        self.spinner = threading.Thread(target=self.spin, name="spin", daemon=True)
        self.spinner.start()
        self.components = {}

    def spin(self):
        try:
            self.executor.spin()
        except ExternalShutdownException:
            pass

    def handle(self, line):
        """Serves one request line; False when the agent should quit."""
        try:
            request = json.loads(line)
        except json.JSONDecodeError as e:
            raise BadRequest(f"bad request line (not JSON: {e}): {quoted(line, 80)}") from None
        if not isinstance(request, dict):
            raise BadRequest(f"bad request line (not a JSON object): {quoted(line, 80)}")
        op = request.get("op")
        if op == "quit":
            return False
        if op == "declare":
            self.declare(request)
            return True
        handlers = {"start": self.start, "stop": self.stop, "input": self.input,
                    "relay": self.relay, "unrelay": self.unrelay, "feed": self.feed,
                    "read": self.read, "unread": self.unread}
        if op not in handlers:
            raise BadRequest(f"unknown op {quoted(str(op))} (known: declare, "
                             f"{', '.join(handlers)}, quit)")
        cid = field(request, "id")
        if cid not in self.components:
            raise BadRequest(f"{op}: unknown component id {quoted(cid)} (declare it first)")
        handlers[op](self.components[cid], request)
        return True

    def declare(self, request):
        cid = field(request, "id")
        node_name = absolute(request.get("node"), f"component {cid} node")
        ports = {}
        for key, name in (("inputs", "info"), ("outputs", "info"), ("feeds", "name")):
            specs = request.get(key) or []
            if not isinstance(specs, list):
                raise BadRequest(f"component {cid}: {key} must be a list")
            ports[key] = {}
            for spec in specs:
                port = Port(spec, name, cid)
                ports[key][port.name] = port
        status_topic = request.get("status_topic")
        if status_topic is not None:
            absolute(status_topic, f"component {cid} status_topic")
        old = self.components.get(cid)
        if old is not None:
            if old.started:
                raise BadRequest(f"declare: component {cid} is started; stop it first")
            old.destroy()
        self.components[cid] = Component(self, cid, node_name, ports["inputs"],
                                         ports["outputs"], ports["feeds"], status_topic)

    def start(self, component, request):
        params = field(request, "params")
        parameters = request.get("parameters") or {}
        if not isinstance(parameters, dict) or not all(
                isinstance(v, (str, int, float)) for v in parameters.values()):
            raise BadRequest(f"start {component.id}: parameters must be an object of strings")
        component.stopped.clear()
        component.queue.put(("start", params, parameters))

    def stop(self, component, request):
        component.stopped.clear()
        component.queue.put(("stop",))

    def input(self, component, request):
        component.input(field(request, "info"), field(request, "text"))

    def feed(self, component, request):
        component.feed(field(request, "name"), field(request, "text"))

    def relay(self, component, request):
        component.relay(field(request, "info"), field(request, "from"))

    def unrelay(self, component, request):
        component.unrelay(component.port(component.inputs, field(request, "info"), "input"))

    def read(self, component, request):
        component.set_read(field(request, "info"), True)

    def unread(self, component, request):
        component.set_read(field(request, "info"), False)

    def quit(self):
        """Stops every started component, all at once, within QUIT_TIMEOUT."""
        # Starts still waiting for their node give up now.
        self.running = False
        started = [c for c in self.components.values() if c.started]
        for component in started:
            component.stopped.clear()
            component.queue.put(("stop",))
        deadline = time.monotonic() + QUIT_TIMEOUT
        for component in started:
            if not component.stopped.wait(max(0.0, deadline - time.monotonic())):
                log(f"component {component.id}: not stopped within {QUIT_TIMEOUT:g} s")


    def close(self):
        """Leaves the DDS domain cleanly: a participant that just vanishes (os._exit, SIGKILL)
        makes the next process to join the domain take about 3 s longer to discover the others
        (Fast DDS)."""
        for component in self.components.values():
            component.queue.put(("exit",))
        for component in self.components.values():
            component.worker.join(timeout=1.0)
        self.executor.shutdown(timeout_sec=1.0)
        self.spinner.join(timeout=1.0)
        try:
            self.node.destroy_node()
            rclpy.shutdown()
        except Exception as e:  # noqa: BLE001 - shutting down anyway
            log(f"rclpy shutdown: {e!r}")


class Interrupted(Exception):
    """SIGTERM or SIGINT: quit as the host asked."""


def main():
    # The protocol owns the real stdout; everything else written to fd 1 (ROS 2's C logging,
    # stray prints) lands on stderr.
    protocol = os.fdopen(os.dup(1), "w", encoding="utf-8", buffering=1)
    os.dup2(2, 1)
    sys.stdout = sys.stderr
    events = Events(protocol)

    def interrupted(signum, frame):
        raise Interrupted()

    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    signal.signal(signal.SIGTERM, interrupted)
    signal.signal(signal.SIGINT, interrupted)
    agent = Agent(events)
    events.send({"ev": "ready", "rmw": rclpy.get_rmw_implementation_identifier(),
                 "domain_id": agent.node.context.get_domain_id()})
    stdin = open(sys.stdin.fileno(), "r", encoding="utf-8", errors="replace", closefd=False)
    try:
        while True:
            line = stdin.readline()
            if not line:
                log("stdin closed: quitting")
                break
            if not line.strip():
                continue
            try:
                if not agent.handle(line.strip()):
                    break
            except BadRequest as e:
                events.error(str(e))
    except Interrupted:
        log("interrupted: quitting")
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    agent.quit()
    agent.close()
    protocol.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
