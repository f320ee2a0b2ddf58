#!/usr/bin/env python3
"""The smart door of the tutorial (docs/tutorial.md): a PEIS with one `door` component, its motor.

It speaks the Ecology component contract (docs/components.md) over Eclipse Zenoh with the stock
`eclipse-zenoh` package (pip install eclipse-zenoh==1.10.2) and the standard library, nothing else.
Like examples/python/robot_counter.py, it leaves the wire format and the PEIS (presence, gets, remote
sets, leaving) to the module examples/python/ecology_peis.py; this file is its component.

- As the PEIS's init component it publishes components.m1.type (`door`), .cost and .currState (on:
  the motor is always powered) and applies components.m1.reqState.
- As component m1 it runs `(door-opener D M R)`: it follows the position of robot R through the
  meta-tuple m1.mi-position, and opens the door once R is within --near metres of it
  (m1.door = `open`), then reports `done`. Until then it reports `running` (the door closed), or
  `waiting` while no position came in the last 0.5 s. Empty params or `off` close the door.

Usage: door.py [--name door1] [--at X Y] [--near M] [--listen ENDPOINT]... [--connect ENDPOINT]... [--no-epoch]
"""

import argparse
import math
import os
import sys
import time

import zenoh

# The PEIS part (wire format, tuples, gets, remote sets, presence) is examples/python/ecology_peis.py,
# shared with robot_counter.py: its folder goes on the module path, found from this file's own place.
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "python"))
from ecology_peis import decode_meta, key_expr, logger, parse_meta_tuple, serve  # noqa: E402

C = "m1"                      # the component's name
KIND, COST = "door", 5        # its type (the `pc` fact) and cost (running: it is always on)
STALE = 0.5                   # an input older than this is missing: report `waiting`
REMOTE_SETTABLE = {f"components.{C}.reqState", f"{C}.params", f"{C}.mi-position"}
log = logger("door")


def parse_position(text):
    """`X Y THETA` (metres, radians) -> (x, y); raises ValueError saying what is wrong."""
    words = text.split()
    try:
        x, y, theta = (float(w) for w in words)
    except ValueError:
        raise ValueError(f"expected X Y THETA, found {text.strip()[:40]!r}") from None
    if not all(abs(v) != float("inf") and v == v for v in (x, y, theta)):
        raise ValueError(f"expected X Y THETA, found {text.strip()[:40]!r}")
    return x, y


# --- The component: init-component duties for m1, and its body -----------------------------------

class Door:
    def __init__(self, peis, at, near):
        self.peis = peis
        self.at, self.near = at, near         # where the door is; how near opens it
        self.on = True                        # the motor is powered from the start
        self.params, self.meta = None, None   # m1.params and m1.mi-position, as last set
        self.robot = None                     # R of the params
        self.active = False                   # the body runs: on, with valid params
        self.done = self.broken = False       # opened; stopped by a bad m1.mi-position
        self.last_position, self.problem, self.newest = None, "position", None
        self.shown = None                     # (status, cause) last reported
        self.follow_id, self.subscriber, self.target = 0, None, None  # the input followed
        peis.set(f"components.{C}.type", KIND)
        peis.set(f"components.{C}.cost", str(COST))
        peis.set(f"components.{C}.currState", "on")
        self.set_door("closed")
        self.report("idle")

    def set_door(self, state):
        self.peis.set(f"{C}.door", state)
        log(f"{C}: the door is {state}")

    def report(self, status, cause=""):
        """m1.cause first, then m1.status, and only when they change."""
        if self.shown != (status, cause):
            self.peis.set(f"{C}.cause", cause)
            self.peis.set(f"{C}.status", status)
            self.shown = (status, cause)
            log(f"{C}: status {status}" + (f" ({cause})" if cause else ""))

    def on_set(self, key, text):
        if key == f"components.{C}.reqState":
            if text == "on" and not self.on:
                self.on = True
                self.peis.set(f"components.{C}.currState", "on")
                self.start_body()
            elif text == "on" and self.on and not self.active:
                self.start_body()  # on again after an error: run the params again
            elif text == "off" and self.on:
                self.stop_body()
                self.on = False
                self.peis.set(f"components.{C}.currState", "off")
                self.report("idle")
        elif key == f"{C}.params":
            self.params = text.strip() or None
            if self.on:
                self.start_body()
        elif key == f"{C}.mi-position":
            self.meta = text
            if self.active and not self.done:
                self.follow()  # re-follow: the input now comes from elsewhere

    def start_body(self):
        self.stop_body()
        if self.params is None:
            return self.report("idle")
        self.report("initializing")
        words = self.params.strip("()").split()
        if len(words) != 4 or words[0] != "door-opener" or words[2] != C:
            return self.report("error", f"a door motor cannot run {self.params}")
        self.robot = words[3]
        self.active, self.done = True, False
        self.last_position, self.problem = None, "position"
        self.follow()

    def stop_body(self):
        if self.active or self.done:
            self.set_door("closed")
        self.active = self.done = False
        self.unfollow()

    def follow(self):
        """Subscribes to the tuple m1.mi-position points at (and gets its current value)."""
        try:
            target = parse_meta_tuple(self.meta) if self.meta is not None else None
        except ValueError as e:
            self.unfollow()
            self.broken = True  # until a new m1.mi-position or new params
            return self.report("error", f"{C}.mi-position: {e}")
        if target is not None and target == self.target:
            return  # the same pointer written again: keep following without a gap
        self.unfollow()
        self.last_position, self.problem, self.newest, self.broken = None, "position", None, False
        if target is None:
            return  # no input yet: tick() reports waiting
        owner, key = self.target = target
        self.follow_id += 1
        fid, ke, events = self.follow_id, key_expr(owner, key), self.peis.events
        # Subscribe first, then get the current value: nothing published in between is missed.
        self.subscriber = self.peis.session.declare_subscriber(
            ke, lambda sample: events.put(("input", (fid, sample))))

        def on_reply(reply):
            if reply.ok is not None:
                events.put(("input", (fid, reply.ok)))
        self.peis.session.get(ke, on_reply, timeout=2.0)
        log(f"{C}: following {owner}:{key}")

    def unfollow(self):
        self.follow_id += 1  # samples already queued for the old target are ignored
        self.target = None
        if self.subscriber is not None:
            self.subscriber.undeclare()
            self.subscriber = None

    def on_input(self, fid, sample):
        if fid != self.follow_id or not self.active or self.done or self.broken:
            return
        if sample.kind != zenoh.SampleKind.PUT:
            return  # the position was removed: it goes stale
        try:  # a sample without metadata is read as seq 0, epoch 0
            m = decode_meta(sample.attachment.to_bytes()) if sample.attachment else None
        except ValueError as e:
            return log(f"dropped a sample on {sample.key_expr}: {e}")
        version = (m["epoch"], m["seq"], m["ts_write"]) if m else None
        if version is not None and self.newest is not None:
            if version == self.newest:
                return  # the same sample again (from the get and the subscriber)
            if version[0] and self.newest[0] and version[:2] < self.newest[:2]:
                return  # older than the one we have (an older epoch, or out of order)
        self.newest = version
        try:
            x, y = parse_position(sample.payload.to_bytes().decode("utf-8"))
        except ValueError as e:  # a bad position is a missing one: report waiting, saying why
            why = "not UTF-8 text" if isinstance(e, UnicodeDecodeError) else str(e)
            # The contract's cause for an input we cannot read: the executive blames its producer.
            self.last_position, self.problem = None, f"unreadable position: {why}"
            return self.report("waiting", self.problem)
        self.last_position, self.problem = time.monotonic(), "position"
        distance = math.hypot(x - self.at[0], y - self.at[1])
        if distance > self.near:
            return self.report("running")
        self.set_door("open")
        log(f"{C}: {self.robot} is {distance:.2f} m away: opened for it")
        self.done = True
        self.unfollow()
        self.report("done")

    def tick(self, now):
        if self.active and not self.done and not self.broken:
            if self.last_position is None or now - self.last_position > STALE:
                self.report("waiting", self.problem)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--name", default="door1", help="the PEIS name (default: door1)")
    parser.add_argument("--at", nargs=2, type=float, default=[4.0, 1.5], metavar=("X", "Y"),
                        help="where the door is, in metres (default: 4.0 1.5)")
    parser.add_argument("--near", type=float, default=1.0, metavar="M",
                        help="open when the robot is this close, in metres (default: 1.0)")
    serve(parser, "door", C, REMOTE_SETTABLE, lambda peis, args: Door(peis, args.at, args.near))


if __name__ == "__main__":
    main()
