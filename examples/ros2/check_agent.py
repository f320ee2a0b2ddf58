#!/usr/bin/env python3
"""End-to-end check of the Ecology ROS 2 agent against the example lifecycle nodes.

Starts the three example nodes (ecology_nodes.py) and the agent
(crates/ecology-ros2/agent/ecology_ros2_agent.py) as processes on one random ROS_DOMAIN_ID, drives
the agent's JSON-lines protocol and checks what comes back:

- the text forms of the messages read and write as documented, and bad texts are refused (in
  process, importing the agent's file);
- bad request lines give `error` events and the agent carries on;
- a start of a node that is not running fails after 5 s naming it; a parameter the node refuses
  fails the start with the node's reason;
- the tracker, started with target astrid, turns image inputs into global-pos outputs, forwarded
  only while the host says someone reads them (`read`, `unread`);
- a relay of the tracker's global_pos into self_loc's input gives self_loc's position outputs,
  with no input sent to self_loc, and self_loc's own statuses are forwarded;
- navigation, given the map as a feed and positions along its route, steers (velocity outputs
  with the simulated tc's numbers) and reports `done` in the goal room;
- a node deactivated by hand is reported (`left active: now inactive`); the tracker killed with
  SIGKILL is reported (`does not answer`) within 3 s;
- stop leaves a node unconfigured (the agent says so and so does lifecycle_state.py);
- quit exits 0 within 3 s and leaves no node active.

Exits 0 printing `check_agent: ok`, or 1 naming what failed. Takes about 20 s.
Run with the ROS 2 venv's python: `/tmp/rosvenv/bin/python examples/ros2/check_agent.py`.
"""

import argparse
import json
import os
import random
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
REPO = HERE.parent.parent
AGENT = REPO / "crates" / "ecology-ros2" / "agent" / "ecology_ros2_agent.py"
NODES = HERE / "ecology_nodes.py"
LIFECYCLE_STATE = HERE / "lifecycle_state.py"
PYTHON = sys.executable

MAP = ("room living-room 0 0 3 3; room kitchen 3 0 5 3; room entrance 2.5 3 5 5; "
       "room bedroom 0 3 2.5 5; door living-room kitchen 3 1.5; "
       "door living-room entrance 2.75 3; door entrance bedroom 2.5 4")


class CheckFailed(Exception):
    pass


def fail(text):
    raise CheckFailed(text)


class Process:
    """A child process whose stdout lines are collected; killed on close."""

    def __init__(self, name, argv, env, stdin=False):
        self.name = name
        self.log = tempfile.NamedTemporaryFile("w+", prefix=f"check_agent_{name}_",
                                               suffix=".log", delete=False)
        self.proc = subprocess.Popen(argv, env=env, text=True, bufsize=1,
                                     stdin=subprocess.PIPE if stdin else subprocess.DEVNULL,
                                     stdout=subprocess.PIPE, stderr=self.log)
        self.lines = []
        self.changed = threading.Condition()
        self.reader = threading.Thread(target=self.read, daemon=True)
        self.reader.start()

    def read(self):
        for line in self.proc.stdout:
            with self.changed:
                self.lines.append(line.rstrip("\n"))
                self.changed.notify_all()
        with self.changed:
            self.changed.notify_all()

    def wait_line(self, predicate, timeout, what, since=0):
        """The index and line of the first line from `since` that satisfies `predicate`."""
        deadline = time.monotonic() + timeout
        with self.changed:
            while True:
                for i in range(since, len(self.lines)):
                    if predicate(self.lines[i]):
                        return i, self.lines[i]
                since = len(self.lines)
                left = deadline - time.monotonic()
                if left <= 0 or (self.proc.poll() is not None and not self.reader.is_alive()):
                    fail(f"{self.name}: no {what} within {timeout:g} s")
                self.changed.wait(left)

    def stderr_tail(self, lines=15):
        self.log.flush()
        with open(self.log.name, encoding="utf-8", errors="replace") as f:
            return "".join(f.readlines()[-lines:])

    def close(self):
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()


class Agent(Process):
    """The agent process, its events parsed."""

    def __init__(self, env):
        super().__init__("agent", [PYTHON, str(AGENT)], env, stdin=True)
        self.events = []

    def send(self, request):
        line = request if isinstance(request, str) else json.dumps(request)
        self.proc.stdin.write(line + "\n")
        self.proc.stdin.flush()

    def mark(self):
        with self.changed:
            return len(self.lines)

    def expect(self, what, timeout=5.0, since=0, **fields):
        """The first event from line `since` on whose fields equal `fields` (a callable field
        value is a predicate on it)."""
        def matches(line):
            try:
                event = json.loads(line)
            except json.JSONDecodeError:
                fail(f"agent wrote a line that is not JSON on stdout: {line!r}")
            for key, want in fields.items():
                have = event.get(key)
                if callable(want):
                    if have is None or not want(have):
                        return False
                elif have != want:
                    return False
            return True
        index, line = self.wait_line(matches, timeout, what, since)
        return index, json.loads(line)

    def events_from(self, since):
        with self.changed:
            return [json.loads(line) for line in self.lines[since:]]


def check_conversions():
    """The agent's text forms, in process: each type both ways, and bad texts refused."""
    import importlib.util
    import math
    import types
    from rclpy.clock import Clock
    spec = importlib.util.spec_from_file_location("ecology_ros2_agent", AGENT)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    node = types.SimpleNamespace(get_clock=Clock)
    good = [
        ("geometry_msgs/msg/Pose2D", "1.5 1.5 0", "1.500 1.500 0.000"),
        ("geometry_msgs/msg/Pose2D", " -0.25\t3  1e-1 ", "-0.250 3.000 0.100"),
        ("geometry_msgs/msg/PoseStamped", "1 2 1.5708", "1.000 2.000 1.571"),
        ("geometry_msgs/msg/PoseStamped", "0 0 -3", "0.000 0.000 -3.000"),
        ("geometry_msgs/msg/Twist", "0.25 -0.5", "0.250 -0.500"),
        ("sensor_msgs/msg/LaserScan", "1 2 3.5", "1.000 2.000 3.500"),
        ("sensor_msgs/msg/LaserScan", "4", "4.000"),
        ("std_msgs/msg/String", "room a 0 0 1 1; door a b 1 0.5", "room a 0 0 1 1; door a b 1 0.5"),
        ("std_msgs/msg/String", "", ""),
        ("std_msgs/msg/Float64", "2.5", "2.500"),
    ]
    for name, text, want in good:
        kind = module.MessageType(name)
        msg = kind.from_text(text, node)
        if kind.to_text(msg) != want:
            fail(f"conversion {name}: {text!r} reads back as {kind.to_text(msg)!r}, not {want!r}")
    stamped = module.MessageType("geometry_msgs/msg/PoseStamped").from_text("1 2 3", node)
    scan_kind = module.MessageType("sensor_msgs/msg/LaserScan")
    scan = scan_kind.from_text("1 2 3", node)
    if (stamped.header.frame_id, scan.header.frame_id, scan.range_max) != ("map", "laser", 10.0) \
            or abs(scan.angle_increment - 2 * math.pi / 3) > 1e-6 or scan.angle_min != 0.0 or stamped.header.stamp.sec == 0:
        fail(f"conversion: PoseStamped {stamped.header} or LaserScan {scan.header} "
             f"{scan.angle_min} {scan.angle_increment} {scan.range_max} not as documented")
    scan.ranges = [1.0, float("inf"), float("nan")]
    if scan_kind.to_text(scan) != "1.000 10.000 10.000":
        fail(f"conversion: a scan's non-finite ranges read {scan_kind.to_text(scan)!r}")
    bad = [
        ("geometry_msgs/msg/Pose2D", t) for t in ("1 2", "1 2 3 4", "1 2 nan", "a b c", "", "1,2;3")
    ] + [
        ("geometry_msgs/msg/PoseStamped", "1 2 inf"), ("geometry_msgs/msg/Twist", "1 2 3"),
        ("geometry_msgs/msg/Twist", "1"), ("sensor_msgs/msg/LaserScan", ""),
        ("sensor_msgs/msg/LaserScan", "1 x 2"), ("std_msgs/msg/Float64", "inf"),
        ("std_msgs/msg/Float64", "1 2"),
    ]
    for name, text in bad:
        try:
            module.MessageType(name).from_text(text, node)
        except module.BadRequest:
            continue
        fail(f"conversion {name}: {text!r} was read, it should be refused")
    for name in ("nav_msgs/msg/Odometry", None, 3):
        try:
            module.MessageType(name)
        except module.BadRequest:
            continue
        fail(f"conversion: message type {name!r} was accepted")


def declare(agent):
    agent.send({"op": "declare", "id": "tr1", "node": "/hsm/tr1",
                "inputs": [{"info": "image", "topic": "/hsm/tr1/image",
                            "type": "std_msgs/msg/String"}],
                "outputs": [{"info": "global-pos", "topic": "/hsm/tr1/global_pos",
                             "type": "geometry_msgs/msg/Pose2D"}],
                "feeds": [], "status_topic": None})
    agent.send({"op": "declare", "id": "sl1", "node": "/astrid/sl1",
                "inputs": [{"info": "global-pos", "topic": "/astrid/sl1/global_pos",
                            "type": "geometry_msgs/msg/Pose2D"}],
                "outputs": [{"info": "position", "topic": "/astrid/sl1/position",
                             "type": "geometry_msgs/msg/Pose2D"}],
                "feeds": [], "status_topic": "/astrid/sl1/ecology_status"})
    agent.send({"op": "declare", "id": "tc1", "node": "/astrid/tc1",
                "inputs": [{"info": "position", "topic": "/astrid/tc1/position",
                            "type": "geometry_msgs/msg/Pose2D"}],
                "outputs": [{"info": "velocity", "topic": "/astrid/tc1/cmd_vel",
                             "type": "geometry_msgs/msg/Twist"}],
                "feeds": [{"name": "map", "topic": "/astrid/tc1/map",
                           "type": "std_msgs/msg/String"}],
                "status_topic": "/astrid/tc1/ecology_status"})
    agent.send({"op": "declare", "id": "ghost", "node": "/nowhere/ghost", "inputs": [],
                "outputs": [], "feeds": [], "status_topic": None})


def check_bad_lines(agent):
    bad = [
        ("not JSON", "this is not json", "not JSON"),
        ("an unknown op", {"op": "fly", "id": "tr1"}, "unknown op"),
        ("an unknown id", {"op": "stop", "id": "nobody"}, "unknown component id"),
        ("an unknown message type",
         {"op": "declare", "id": "x", "node": "/x", "status_topic": None,
          "outputs": [{"info": "o", "topic": "/x/o", "type": "nav_msgs/msg/Odometry"}]},
         "unknown message type"),
        ("an unknown input", {"op": "input", "id": "tr1", "info": "sound", "text": "x"},
         "has no input"),
        ("an unreadable pose", {"op": "input", "id": "sl1", "info": "global-pos",
                                "text": "1,2;3"}, "expected X Y THETA"),
        ("a request without its field", {"op": "input", "id": "sl1", "info": "global-pos"},
         "lacks 'text'"),
    ]
    for what, line, words in bad:
        since = agent.mark()
        agent.send(line)
        agent.expect(f"error event for {what}", since=since, ev="error",
                     text=lambda t, w=words: w in t)


def expect_none(agent, what, since, **fields):
    """Fails if an event from line `since` on has `fields`."""
    try:
        _, event = agent.expect(what, timeout=0.01, since=since, **fields)
    except CheckFailed:
        return
    fail(f"agent: {what}: {event}")


def send_until(agent, request, what, timeout=5.0, **fields):
    """Sends `request` every 50 ms until the expected event comes: the first messages on a new
    topic may go before discovery has matched the two ends."""
    deadline = time.monotonic() + timeout
    since = agent.mark()
    while True:
        agent.send(request)
        try:
            return agent.expect(what, timeout=0.05, since=since, **fields)[1]
        except CheckFailed:
            if time.monotonic() > deadline:
                fail(f"agent: no {what} within {timeout:g} s of sending {request}")


def lifecycle_state(env, node):
    # More than the default 2 s: a new process's discovery alone can take 2 s on a loaded
    # machine, and whether the node is gone is not what this asks.
    out = subprocess.run([PYTHON, str(LIFECYCLE_STATE), node, "--timeout", "6"], env=env,
                         stdout=subprocess.PIPE,
                         text=True, timeout=10)
    return out.stdout.strip()


def change_state_by_hand(env, node, transition):
    """Runs one lifecycle transition on `node` from outside the agent, as an operator would."""
    code = (
        "import sys, rclpy\n"
        "from lifecycle_msgs.srv import ChangeState\n"
        "rclpy.init(); n = rclpy.create_node('operator')\n"
        f"c = n.create_client(ChangeState, '{node}/change_state')\n"
        "c.wait_for_service(5.0)\n"
        f"r = ChangeState.Request(); r.transition.id = {transition}\n"
        "f = c.call_async(r); rclpy.spin_until_future_complete(n, f, timeout_sec=5.0)\n"
        "sys.exit(0 if f.done() and f.result().success else 1)\n")
    if subprocess.run([PYTHON, "-c", code], env=env, timeout=15).returncode != 0:
        fail(f"could not run transition {transition} on {node} by hand")


def run(env, children):
    check_conversions()
    nodes = {}
    for kind, name, namespace in (("tracker", "tr1", "hsm"), ("self_loc", "sl1", "astrid"),
                                  ("navigation", "tc1", "astrid")):
        nodes[name] = Process(name, [PYTHON, str(NODES), kind, "--name", name,
                                     "--namespace", namespace], env)
        children.append(nodes[name])
    agent = Agent(env)
    children.append(agent)
    _, ready = agent.expect("ready event", timeout=15.0, ev="ready")
    if ready.get("domain_id") != int(env["ROS_DOMAIN_ID"]) or not ready.get("rmw"):
        fail(f"agent: ready event {ready} does not name rmw and domain {env['ROS_DOMAIN_ID']}")
    for name, node in nodes.items():
        node.wait_line(lambda line: line == "ready", 15.0, "ready line")

    declare(agent)
    check_bad_lines(agent)
    ghost_since = agent.mark()
    agent.send({"op": "start", "id": "ghost", "params": "(nothing)", "parameters": {}})

    # A parameter the node does not declare: the start fails with the node's reason.
    since = agent.mark()
    agent.send({"op": "start", "id": "tr1", "params": "(tracking-system hsm tr1 astrid)",
                "parameters": {"target": "astrid", "colour": "red"}})
    agent.expect("initializing of tr1", since=since, ev="status", id="tr1",
                 status="initializing")
    _, refused = agent.expect("error for the refused parameter", timeout=10.0, since=since,
                              ev="status", id="tr1", status="error")
    if "refused parameter colour" not in refused.get("cause", ""):
        fail(f"tr1: expected a refused parameter colour, got {refused}")

    # The tracker: images in, global-pos of the target out.
    since = agent.mark()
    agent.send({"op": "start", "id": "tr1", "params": "(tracking-system hsm tr1 astrid)",
                "parameters": {"target": "astrid"}})
    agent.expect("tr1 running", timeout=10.0, since=since, ev="status", id="tr1",
                 status="running")
    agent.send({"op": "read", "id": "tr1", "info": "global-pos"})
    send_until(agent, {"op": "input", "id": "tr1", "info": "image",
                       "text": "pippi 4.0 1.0 0.5; astrid 1.5 1.5 0.0"},
               "tr1 global-pos output", ev="output", id="tr1", info="global-pos",
               text="1.500 1.500 0.000")
    # Nobody reads it: the node still publishes (its input is matched now), the agent forwards
    # nothing; read again, it forwards again.
    agent.send({"op": "unread", "id": "tr1", "info": "global-pos"})
    time.sleep(0.2)
    since = agent.mark()
    for _ in range(10):
        agent.send({"op": "input", "id": "tr1", "info": "image", "text": "astrid 1.0 1.0 0.0"})
        time.sleep(0.05)
    time.sleep(0.3)
    expect_none(agent, "an output nobody reads was forwarded", since, ev="output", id="tr1")
    agent.send({"op": "read", "id": "tr1", "info": "global-pos"})
    send_until(agent, {"op": "input", "id": "tr1", "info": "image",
                       "text": "astrid 1.5 1.5 0.0"},
               "tr1 global-pos output read again", ev="output", id="tr1", info="global-pos",
               text="1.500 1.500 0.000")
    since = agent.mark()
    agent.send({"op": "input", "id": "tr1", "info": "image", "text": "pippi 4 1 0"})
    agent.send({"op": "input", "id": "tr1", "info": "image",
                "text": "astrid 2.25 0.75 -1.2; pippi 4 1 0"})
    _, out = agent.expect("tr1 second global-pos", since=since, ev="output", id="tr1")
    if out["text"] != "2.250 0.750 -1.200":
        fail(f"tr1: an image without astrid gave an output, or wrong numbers: {out}")

    # self_loc fed by a relay from the tracker's topic, DDS to DDS.
    since = agent.mark()
    agent.send({"op": "read", "id": "sl1", "info": "position"})
    agent.send({"op": "start", "id": "sl1", "params": "(pose-tracking astrid hsm)",
                "parameters": {}})
    agent.expect("sl1 running", timeout=10.0, since=since, ev="status", id="sl1",
                 status="running")
    agent.expect("sl1's own waiting status", since=since, ev="status", id="sl1",
                 status="waiting", cause="global-pos")
    agent.send({"op": "relay", "id": "sl1", "info": "global-pos", "from": "/hsm/tr1/global_pos"})
    send_until(agent, {"op": "input", "id": "tr1", "info": "image",
                       "text": "astrid 1.25 2.5 0.3"},
               "sl1 position output through the relay", ev="output", id="sl1",
               info="position", text="1.250 2.500 0.300")
    agent.expect("sl1 running again once fed", since=since, ev="status", id="sl1",
                 status="running", cause=None)

    # navigation: the map as a feed, positions along the route, done in the bedroom.
    agent.send({"op": "feed", "id": "tc1", "name": "map", "text": MAP})
    since = agent.mark()
    agent.send({"op": "read", "id": "tc1", "info": "velocity"})
    agent.send({"op": "start", "id": "tc1", "params": "(navigation astrid tc1 bedroom)",
                "parameters": {"goal_room": "bedroom"}})
    agent.expect("tc1 running", timeout=10.0, since=since, ev="status", id="tc1",
                 status="running")
    # At (1, 1) facing east, the first door (2.75, 3) is 0.85 rad to the left: turn on the spot
    # at the top turn rate, as the simulated tc does.
    send_until(agent, {"op": "input", "id": "tc1", "info": "position", "text": "1.0 1.0 0.0"},
               "tc1 velocity output", ev="output", id="tc1", info="velocity",
               text="0.000 1.500")
    since = agent.mark()
    for pose in ("2.0 2.0 0.785", "2.75 3.0 1.571", "2.5 4.0 3.142", "1.3 4.0 3.142",
                 "1.25 4.0 3.142"):
        agent.send({"op": "input", "id": "tc1", "info": "position", "text": pose})
    _, steer = agent.expect("tc1 steering at (2, 2)", since=since, ev="output", id="tc1")
    if steer["text"] != "0.396 0.356":
        fail(f"tc1: at (2, 2) heading 0.785 towards the door at (2.75, 3) expected velocity "
             f"0.396 0.356, got {steer}")
    agent.expect("tc1 done in the bedroom", since=since, ev="status", id="tc1", status="done")
    agent.expect("tc1 stopping the base", since=since, ev="output", id="tc1", text="0.000 0.000")

    # A node deactivated by hand is no longer running.
    since = agent.mark()
    change_state_by_hand(env, "/astrid/sl1", 4)
    agent.expect("sl1 left active", timeout=2.0, since=since, ev="status", id="sl1",
                 status="error", cause="ROS 2 node /astrid/sl1 left active: now inactive")

    # The tracker's process killed: reported within 3 s (the agent's silence is 2 s).
    since = agent.mark()
    killed = time.monotonic()
    nodes["tr1"].proc.send_signal(signal.SIGKILL)
    agent.expect("tr1 error after SIGKILL", timeout=3.0, since=since, ev="status", id="tr1",
                 status="error",
                 cause="ROS 2 node /hsm/tr1 does not answer (its process is gone?)")
    detected = time.monotonic() - killed

    # The node that never ran.
    agent.expect("ghost error", timeout=8.0, since=ghost_since, ev="status", id="ghost",
                 status="error",
                 cause="ROS 2 node /nowhere/ghost is not running (no lifecycle services after 5 s)")

    # stop: unconfigured, as the node itself says; the dead tracker is gone.
    since = agent.mark()
    agent.send({"op": "stop", "id": "sl1"})
    agent.send({"op": "stop", "id": "tr1"})
    agent.expect("sl1 stopped unconfigured", since=since, ev="stopped", id="sl1",
                 state="unconfigured")
    agent.expect("tr1 stopped gone", since=since, ev="stopped", id="tr1", state="gone")
    state = lifecycle_state(env, "/astrid/sl1")
    if state != "unconfigured":
        fail(f"lifecycle_state.py /astrid/sl1 says {state!r} after stop, not 'unconfigured'")

    # The agent still serves requests after all that, then quits cleanly.
    since = agent.mark()
    agent.send({"op": "start", "id": "sl1", "params": "(pose-tracking astrid hsm)",
                "parameters": {}})
    agent.expect("sl1 running again", timeout=10.0, since=since, ev="status", id="sl1",
                 status="running")
    since = agent.mark()
    agent.send({"op": "quit"})
    began = time.monotonic()
    try:
        code = agent.proc.wait(timeout=3.0)
    except subprocess.TimeoutExpired:
        fail("agent: still running 3 s after quit")
    took = time.monotonic() - began
    if code != 0:
        fail(f"agent: exit code {code} after quit")
    stopped = {e["id"]: e["state"] for e in agent.events_from(since) if e.get("ev") == "stopped"}
    if stopped != {"sl1": "unconfigured", "tc1": "unconfigured", "ghost": "gone"}:
        fail(f"agent: quit should stop sl1, tc1 (unconfigured) and ghost (gone), "
             f"it reported {stopped}")
    for node in ("/astrid/sl1", "/astrid/tc1"):
        state = lifecycle_state(env, node)
        if state != "unconfigured":
            fail(f"lifecycle_state.py {node} says {state!r} after quit, not 'unconfigured'")
    return detected, took


def main():
    began = time.monotonic()
    env = dict(os.environ)
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--domain", type=int, help="the ROS_DOMAIN_ID (default: random, 1-100)")
    args = parser.parse_args()
    env["ROS_DOMAIN_ID"] = str(args.domain if args.domain is not None else random.randint(1, 100))
    env["PYTHONUNBUFFERED"] = "1"
    children = []
    try:
        detected, took = run(env, children)
    except CheckFailed as e:
        print(f"check_agent: FAILED: {e}", file=sys.stderr)
        for child in children:
            if isinstance(child, Agent):
                with child.changed:
                    tail = "\n".join(child.lines[-12:])
                print(f"--- agent events, last lines:\n{tail}", file=sys.stderr)
            print(f"--- {child.name} stderr ({child.log.name}), last lines:\n"
                  f"{child.stderr_tail()}", file=sys.stderr)
        return 1
    finally:
        for child in children:
            child.close()
    print(f"check_agent: SIGKILL detected in {detected:.2f} s; quit took {took:.2f} s; "
          f"domain {env['ROS_DOMAIN_ID']}; {time.monotonic() - began:.1f} s in all")
    print("check_agent: ok")
    return 0


if __name__ == "__main__":
    sys.exit(main())
