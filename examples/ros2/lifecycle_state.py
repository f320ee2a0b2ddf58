#!/usr/bin/env python3
"""Prints the lifecycle state of ROS 2 nodes: `python lifecycle_state.py /hsm/tr1 [/astrid/s1 …]`,
one line per node, in order.

Prints `unconfigured`, `inactive`, `active`, `finalized` (or a transition state's label), or
`gone` when the node's `get_state` service does not answer within 2 s (`--timeout`; the time
includes discovery, which takes up to about 2 s on a loaded machine). Exits 0 either way; 2 on a
bad command line.
"""

import argparse
import sys
import threading
import time

import rclpy
from lifecycle_msgs.srv import GetState
from rclpy.executors import SingleThreadedExecutor

LIMIT = 2.0


def lifecycle_state(node, name, limit=LIMIT):
    """The label of node `name`'s lifecycle state, or `gone` if it does not answer in `limit`."""
    deadline = time.monotonic() + limit
    client = node.create_client(GetState, f"{name}/get_state")
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    try:
        # Discovery has no awaitable event in rclpy; spinning drives it until the service shows.
        while not client.service_is_ready():
            if time.monotonic() >= deadline:
                return "gone"
            executor.spin_once(timeout_sec=0.02)
        # A request sent just as the service shows may go unanswered (the server's reply writer
        # may not match this client yet), so an unanswered request is sent again.
        while True:
            future = client.call_async(GetState.Request())
            left = deadline - time.monotonic()
            executor.spin_until_future_complete(future, max(0.0, min(0.5, left)))
            if future.done() and future.result() is not None:
                return future.result().current_state.label
            client.remove_pending_request(future)
            if time.monotonic() >= deadline:
                return "gone"
    finally:
        executor.remove_node(node)
        node.destroy_client(client)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("nodes", nargs="+", metavar="NODE",
                        help="a node's fully qualified name, e.g. /hsm/tr1")
    parser.add_argument("--timeout", type=float, default=LIMIT,
                        help=f"seconds to wait for an answer (default {LIMIT:g})")
    args = parser.parse_args(argv)
    for name in args.nodes:
        if not name.startswith("/"):
            parser.error(f"a node's name must be fully qualified (start with /), found {name}")
    rclpy.init()
    try:
        node = rclpy.create_node(f"lifecycle_state_{threading.get_native_id()}")
        for name in args.nodes:
            print(lifecycle_state(node, name, args.timeout), flush=True)
        node.destroy_node()
    finally:
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
