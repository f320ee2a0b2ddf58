#!/usr/bin/env python3
"""Benchmark: what the agent's wiring costs, next to a direct ROS 2 topic, in one run.

The same producer and consumer (two small rclpy nodes in two processes, Pose2D messages carrying
the sequence number in `x` and the send time in `y`, milliseconds of the system's monotonic clock)
are wired three ways, one after the other:

- direct: the producer publishes on the topic the consumer reads (one DDS hop);
- relay:  producer topic -> the agent's `relay` (raw bytes, no conversion) -> consumer topic;
- bridge: producer topic -> the agent's `output` event (text) -> this script, which sends it back
  at once as an `input` request of another declared component -> consumer topic. This stands for
  Ecology's tuple hop, without Zenoh: message -> text -> JSON line -> host -> JSON line -> text ->
  message.

For each: one-way latency (median and p99) at 50 Hz for `--seconds` (10 by default), measured by
the consumer as receive time minus send time; and throughput, the messages received per second of
20,000 sent as fast as possible (reliable, keep last 100, so a path that cannot keep up loses
messages: the count received is shown too). Latency figures include rclpy's publish and callback
dispatch on both ends, the same for every path. The bridge writes numbers with 3 decimals, so its
times are read to the microsecond.

    /tmp/rosvenv/bin/python examples/ros2/bench_wiring.py [--seconds N] [--count N] [--json]

Each path starts once a probe message has gone through it (discovery done); a throughput run ends
when every message arrived or none came for 1 s.
"""

import argparse
import json
import os
import random
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
AGENT = HERE.parent.parent / "crates" / "ecology-ros2" / "agent" / "ecology_ros2_agent.py"
PYTHON = sys.executable

PATHS = {
    # path: (producer topic, consumer topic)
    "direct": ("/bench/direct", "/bench/direct"),
    "relay": ("/bench/p_relay", "/bench/c_relay"),
    "bridge": ("/bench/p_bridge", "/bench/c_bridge"),
}
QUIET = 1.0


def now_ms():
    return time.monotonic() * 1000.0


def qos():
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.VOLATILE)


# ---------------------------------------------------------------------------------------------
# The producer and consumer processes: commands as JSON lines on stdin, answers on stdout.


def spin_in_background(node):
    from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
    executor = SingleThreadedExecutor()
    executor.add_node(node)

    def spin():
        try:
            executor.spin()
        except ExternalShutdownException:
            pass
    threading.Thread(target=spin, daemon=True).start()
    return executor


def leave(executor):
    """Stops spinning and exits at once (daemon threads still hold rclpy entities)."""
    executor.shutdown(timeout_sec=1.0)
    import rclpy
    rclpy.try_shutdown()
    sys.stdout.flush()
    os._exit(0)


def answer(obj):
    sys.stdout.write(json.dumps(obj) + "\n")
    sys.stdout.flush()


def producer():
    """Publishes on the three producer topics when told. It is a lifecycle node (doing nothing
    on its transitions) only so that the agent can start it as a component for the bridge."""
    import rclpy
    from geometry_msgs.msg import Pose2D
    from rclpy.lifecycle import LifecycleNode
    rclpy.init()
    node = LifecycleNode("producer", namespace="bench")
    node.declare_parameter("ecology_params", "")
    publishers = {path: node.create_publisher(Pose2D, topic, qos())
                  for path, (topic, _) in PATHS.items()}
    executor = spin_in_background(node)
    stop_probe = threading.Event()
    answer({"ready": True})
    for line in sys.stdin:
        command = json.loads(line)
        publisher = publishers.get(command.get("path"))
        if command["cmd"] == "probe":
            stop_probe = threading.Event()

            def probe(publisher=publisher, stop=stop_probe):
                # A probe every 50 ms until the consumer has seen one (discovery is done).
                while not stop.wait(0.05):
                    publisher.publish(Pose2D(x=-1.0, y=now_ms(), theta=0.0))
            threading.Thread(target=probe, daemon=True).start()
        elif command["cmd"] == "unprobe":
            stop_probe.set()
        elif command["cmd"] == "rate":
            period = 1.0 / command["hz"]
            count = int(command["hz"] * command["seconds"])
            start = time.monotonic()
            for seq in range(count):
                # Absolute deadlines, so the rate does not drift with publish time.
                delay = start + seq * period - time.monotonic()
                if delay > 0:
                    time.sleep(delay)
                publisher.publish(Pose2D(x=float(seq), y=now_ms(), theta=0.0))
            answer({"sent": count})
        elif command["cmd"] == "burst":
            count = command["count"]
            began = time.monotonic()
            for seq in range(count):
                publisher.publish(Pose2D(x=float(seq), y=now_ms(), theta=0.0))
            answer({"sent": count, "seconds": time.monotonic() - began})
        elif command["cmd"] == "quit":
            break
    leave(executor)


def consumer():
    """Records every message on the three consumer topics: sequence, send and receive time."""
    import rclpy
    from geometry_msgs.msg import Pose2D
    rclpy.init()
    node = rclpy.create_node("consumer", namespace="bench")
    lock = threading.Condition()
    records = {path: [] for path in PATHS}
    probed = set()

    def on_message(path):
        def callback(msg):
            received = now_ms()
            with lock:
                if msg.x < 0:
                    if path not in probed:
                        probed.add(path)
                        answer({"probed": path})
                    return
                records[path].append((int(round(msg.x)), msg.y, received))
                lock.notify_all()
        return callback
    topics = {}
    for path, (_, topic) in PATHS.items():
        if topic not in topics:
            topics[topic] = node.create_subscription(Pose2D, topic, on_message(path), qos())
        else:
            # direct: producer and consumer topic are the same; one subscription only.
            pass
    executor = spin_in_background(node)
    answer({"ready": True})
    for line in sys.stdin:
        command = json.loads(line)
        if command["cmd"] == "reset":
            with lock:
                for r in records.values():
                    r.clear()
                probed.clear()
            answer({"reset": True})
        elif command["cmd"] == "collect":
            # Until `count` arrived, or none came for QUIET seconds (a path losing messages).
            path, count = command["path"], command["count"]
            with lock:
                last = time.monotonic()
                seen = len(records[path])
                while seen < count:
                    lock.wait(max(0.0, last + QUIET - time.monotonic()))
                    if len(records[path]) > seen:
                        seen, last = len(records[path]), time.monotonic()
                    elif time.monotonic() >= last + QUIET:
                        break
                got = list(records[path])
            answer({"records": got})
        elif command["cmd"] == "quit":
            break
    leave(executor)


# ---------------------------------------------------------------------------------------------
# The bench itself.


class Child:
    def __init__(self, name, argv, env):
        self.name = name
        self.proc = subprocess.Popen(argv, env=env, text=True, bufsize=1, stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, stderr=sys.stderr)
        self.lock = threading.Lock()

    def send(self, obj):
        with self.lock:
            self.proc.stdin.write(json.dumps(obj) + "\n")
            self.proc.stdin.flush()

    def receive(self, timeout, what):
        """The next JSON line; fails after `timeout` seconds."""
        result = []
        reader = threading.Thread(target=lambda: result.append(self.proc.stdout.readline()),
                                  daemon=True)
        reader.start()
        reader.join(timeout)
        if not result or not result[0]:
            sys.exit(f"bench_wiring: {self.name}: no {what} within {timeout:g} s")
        return json.loads(result[0])

    def close(self):
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()


class Agent(Child):
    """The agent; a thread reads its events and bridges prod_c's outputs to cons_c's input."""

    def __init__(self, env):
        super().__init__("agent", [PYTHON, str(AGENT)], env)
        self.events = []
        self.changed = threading.Condition()
        self.reader = threading.Thread(target=self.read, daemon=True)
        self.reader.start()

    def read(self):
        stdin = self.proc.stdin
        for line in self.proc.stdout:
            event = json.loads(line)
            if event.get("ev") == "output" and event.get("id") == "prod_c":
                # The bridge: straight back as an input, as a host would after the tuple hop.
                request = {"op": "input", "id": "cons_c", "info": "pos", "text": event["text"]}
                with self.lock:
                    stdin.write(json.dumps(request) + "\n")
                    stdin.flush()
                continue
            with self.changed:
                self.events.append(event)
                self.changed.notify_all()

    def expect(self, timeout, what, **fields):
        deadline = time.monotonic() + timeout
        with self.changed:
            while True:
                for event in self.events:
                    if all(event.get(k) == v for k, v in fields.items()):
                        return event
                    if event.get("ev") == "error" or event.get("status") == "error":
                        sys.exit(f"bench_wiring: agent: {event}")
                left = deadline - time.monotonic()
                if left <= 0:
                    sys.exit(f"bench_wiring: agent: no {what} within {timeout:g} s")
                self.changed.wait(left)


def percentile(values, q):
    ordered = sorted(values)
    return ordered[min(len(ordered) - 1, int(q * len(ordered)))]


def wire(agent):
    pose = "geometry_msgs/msg/Pose2D"
    agent.send({"op": "declare", "id": "cons_b", "node": "/bench/consumer",
                "inputs": [{"info": "pos", "topic": PATHS["relay"][1], "type": pose}],
                "outputs": [], "feeds": [], "status_topic": None})
    agent.send({"op": "relay", "id": "cons_b", "info": "pos", "from": PATHS["relay"][0]})
    agent.send({"op": "declare", "id": "cons_c", "node": "/bench/consumer",
                "inputs": [{"info": "pos", "topic": PATHS["bridge"][1], "type": pose}],
                "outputs": [], "feeds": [], "status_topic": None})
    agent.send({"op": "declare", "id": "prod_c", "node": "/bench/producer", "inputs": [],
                "outputs": [{"info": "pos", "topic": PATHS["bridge"][0], "type": pose}],
                "feeds": [], "status_topic": None})
    agent.send({"op": "start", "id": "prod_c", "params": "(bench)", "parameters": {}})
    agent.expect(15.0, "prod_c running", ev="status", id="prod_c", status="running")


def measure(path, producer, consumer, seconds, count):
    consumer.send({"cmd": "reset"})
    consumer.receive(10.0, "reset")
    producer.send({"cmd": "probe", "path": path})
    consumer.receive(15.0, f"probe through {path}")
    producer.send({"cmd": "unprobe"})

    producer.send({"cmd": "rate", "path": path, "hz": 50, "seconds": seconds})
    sent = producer.receive(seconds + 30.0, "end of the 50 Hz run")["sent"]
    consumer.send({"cmd": "collect", "path": path, "count": sent})
    records = consumer.receive(seconds + 30.0, "50 Hz records")["records"]
    latencies = [received - sent_at for _, sent_at, received in records]
    if not latencies:
        sys.exit(f"bench_wiring: {path}: nothing arrived at 50 Hz")

    consumer.send({"cmd": "reset"})
    consumer.receive(10.0, "reset")
    producer.send({"cmd": "burst", "path": path, "count": count})
    burst = producer.receive(120.0, "end of the burst")
    consumer.send({"cmd": "collect", "path": path, "count": count})
    records = consumer.receive(180.0, "burst records")["records"]
    if records:
        first_sent = min(sent_at for _, sent_at, _ in records)
        last_received = max(received for _, _, received in records)
        rate = len(records) / max((last_received - first_sent) / 1000.0, 1e-9)
    else:
        rate = 0.0
    return {
        "path": path,
        "latency_samples": len(latencies),
        "latency_sent": sent,
        "latency_median_ms": statistics.median(latencies),
        "latency_p99_ms": percentile(latencies, 0.99),
        "burst_sent": count,
        "burst_send_rate": count / burst["seconds"],
        "burst_received": len(records),
        "throughput_per_s": rate,
    }


def run(args):
    env = dict(os.environ)
    env["ROS_DOMAIN_ID"] = str(args.domain if args.domain is not None else random.randint(1, 100))
    children = []
    try:
        producer = Child("producer", [PYTHON, __file__, "--role", "producer"], env)
        consumer = Child("consumer", [PYTHON, __file__, "--role", "consumer"], env)
        agent = Agent(env)
        children += [producer, consumer, agent]
        producer.receive(20.0, "ready")
        consumer.receive(20.0, "ready")
        agent.expect(20.0, "ready", ev="ready")
        wire(agent)
        results = [measure(path, producer, consumer, args.seconds, args.count)
                   for path in args.paths]
        agent.send({"op": "quit"})
        agent.proc.wait(timeout=5.0)
        for child in (producer, consumer):
            child.send({"cmd": "quit"})
        for child in (producer, consumer):
            child.proc.wait(timeout=5.0)
    finally:
        for child in children:
            child.close()
    # The first path measured is the baseline (direct, unless --paths says otherwise).
    direct = results[0]
    for r in results:
        r["latency_median_ratio"] = r["latency_median_ms"] / direct["latency_median_ms"]
        r["latency_p99_ratio"] = r["latency_p99_ms"] / direct["latency_p99_ms"]
        r["throughput_ratio"] = r["throughput_per_s"] / max(direct["throughput_per_s"], 1e-9)
    return {"domain_id": int(env["ROS_DOMAIN_ID"]), "seconds": args.seconds, "hz": 50,
            "burst": args.count, "rmw": env.get("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp"),
            "paths": results}


def table(report):
    lines = [f"bench_wiring: {report['hz']} Hz for {report['seconds']:g} s, then a burst of "
             f"{report['burst']}; domain {report['domain_id']}, {report['rmw']}",
             f"{'path':<8} {'median ms':>10} {'p99 ms':>9} {'recv@50Hz':>10} "
             f"{'burst recv':>11} {'msg/s':>9} {'median x':>9} {'p99 x':>7} {'msg/s x':>8}"]
    for r in report["paths"]:
        lines.append(
            f"{r['path']:<8} {r['latency_median_ms']:>10.3f} {r['latency_p99_ms']:>9.3f} "
            f"{r['latency_samples']:>4}/{r['latency_sent']:<5} "
            f"{r['burst_received']:>5}/{r['burst_sent']:<5} {r['throughput_per_s']:>9.0f} "
            f"{r['latency_median_ratio']:>9.2f} {r['latency_p99_ratio']:>7.2f} "
            f"{r['throughput_ratio']:>8.2f}")
    return "\n".join(lines)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=10.0,
                        help="length of each 50 Hz latency run (default 10)")
    parser.add_argument("--count", type=int, default=20000,
                        help="messages in each throughput burst (default 20000)")
    parser.add_argument("--json", action="store_true", help="print the results as JSON")
    parser.add_argument("--domain", type=int, help="the ROS_DOMAIN_ID (default: random, 1-100)")
    parser.add_argument("--paths", type=lambda text: text.split(","), default=list(PATHS),
                        help="the paths to measure, in order, the first the baseline "
                             "(default direct,relay,bridge)")
    parser.add_argument("--role", choices=("producer", "consumer"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    unknown = [p for p in args.paths if p not in PATHS]
    if unknown:
        parser.error(f"unknown paths {', '.join(unknown)} (known: {', '.join(PATHS)})")
    if args.role == "producer":
        return producer()
    if args.role == "consumer":
        return consumer()
    report = run(args)
    print(json.dumps(report, indent=2) if args.json else table(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
