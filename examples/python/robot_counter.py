#!/usr/bin/env python3
"""A PEIS written by hand in Python: one `counter` component that counts robots.

It speaks the Ecology component contract (docs/components.md) over Eclipse Zenoh with the stock
`eclipse-zenoh` package (pip install eclipse-zenoh==1.10.2) and the standard library, nothing else.
The PEIS part lives in ecology_peis.py next to it, which the tutorial's door uses too:

- as the PEIS's init component it publishes components.c1.type/cost/currState and applies
  components.c1.reqState (on after a 0.2 s start-up, off at once);
- as component c1 it runs `(count-robots Q C P)`: it follows its input through the meta-tuple
  c1.mi-image, counts the robots in every image (`NAME X Y THETA; ...`), publishes the count as
  c1.out.robot-count while someone reads it (`Peis.output`: deleted once nobody does, the last
  count kept back and published the moment a reader comes) and reports c1.status
  (waiting / running / done, error with c1.cause) whether or not anyone reads it;
- as a PEIS (ecology_peis.py) it declares presence, answers gets for its tuples and applies remote
  sets.

Usage: robot_counter.py [--name counter] [--listen ENDPOINT]... [--connect ENDPOINT]... [--no-epoch]
"""

import argparse
import time

import zenoh

from ecology_peis import decode_meta, key_expr, logger, parse_meta_tuple, serve

C = "c1"                      # the component's name
KIND, COST = "counter", 5     # its type (the `pc` fact) and cost
STARTUP = 0.2                 # seconds from reqState `on` to currState `on`
STALE = 0.5                   # an input older than this is missing: report `waiting`
IMAGES_TO_COUNT = 10          # report `done` after counting this many images
OUTPUT = f"{C}.out.robot-count"
REMOTE_SETTABLE = {f"components.{C}.reqState", f"{C}.params", f"{C}.mi-image"}
log = logger("robot_counter")


def parse_image(text):
    """`NAME X Y THETA; ...` -> the robots' names; raises ValueError on a malformed entry."""
    robots = []
    for entry in text.split(";"):
        words = entry.split()
        if not words:
            continue
        try:
            ok = len(words) == 4 and all(abs(float(w)) != float("inf") for w in words[1:])
        except ValueError:
            ok = False
        if not ok:
            raise ValueError(f"entry {entry.strip()!r} is not NAME X Y THETA")
        robots.append(words[0])
    return robots


# --- The component: init-component duties for c1, and its body ----------------------------------

class Counter:
    def __init__(self, peis):
        self.peis = peis
        self.on, self.starting_until = False, None
        self.params, self.meta = None, None   # c1.params and c1.mi-image, as last set
        self.active = False                   # the body runs: on, with valid params
        self.done = self.broken = False       # finished; stopped by a bad c1.mi-image
        self.counted, self.last_image, self.problem, self.newest = 0, None, "image", None
        self.shown = None                     # (status, cause) last reported
        self.follow_id, self.subscriber, self.target = 0, None, None  # the input followed
        peis.set(f"components.{C}.type", KIND)
        peis.set(f"components.{C}.cost", str(COST))
        peis.set(f"components.{C}.currState", "off")
        self.report("idle")

    def report(self, status, cause=""):
        """c1.cause first, then c1.status, and only when they change."""
        if self.shown != (status, cause):
            self.peis.set(f"{C}.cause", cause)
            self.peis.set(f"{C}.status", status)
            self.shown = (status, cause)
            log(f"{C}: status {status}" + (f" ({cause})" if cause else ""))

    def on_set(self, key, text):
        if key == f"components.{C}.reqState":
            if text == "on" and not self.on and self.starting_until is None:
                self.starting_until = time.monotonic() + STARTUP
            elif text == "off":
                self.starting_until = None
                self.stop_body()
                if self.on:
                    self.on = False
                    self.peis.set(f"components.{C}.currState", "off")
                    log(f"{C}: currState off")
                    self.report("idle")
        elif key == f"{C}.params":
            self.params = text.strip() or None
            if self.on:
                self.start_body()
        elif key == f"{C}.mi-image":
            self.meta = text
            if self.active and not self.done:
                self.follow()  # re-follow: the input now comes from elsewhere

    def start_body(self):
        self.stop_body()
        if self.params is None:
            return self.report("idle")
        self.report("initializing")
        words = self.params.strip("()").split()
        if not words or words[0] != "count-robots" or len(words) != 4:
            return self.report("error", f"a counter cannot run {self.params}")
        self.active, self.done, self.counted = True, False, 0
        self.last_image, self.problem = None, "image"
        self.follow()

    def stop_body(self):
        self.active = False
        self.unfollow()
        self.peis.kept.pop(OUTPUT, None)  # a count held back is not published once stopped

    def follow(self):
        """Subscribes to the tuple c1.mi-image points at (and gets its current value)."""
        try:
            target = parse_meta_tuple(self.meta) if self.meta is not None else None
        except ValueError as e:
            self.unfollow()
            self.broken = True  # until a new c1.mi-image or new params
            return self.report("error", f"{C}.mi-image: {e}")
        if target is not None and target == self.target:
            return  # the same pointer written again: keep following without a gap
        self.unfollow()
        self.last_image, self.problem, self.newest, self.broken = None, "image", None, False
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
            return  # the image was removed: it goes stale
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
            robots = parse_image(sample.payload.to_bytes().decode("utf-8"))
        except ValueError as e:  # a bad image is a missing one: report waiting, saying why
            why = "not UTF-8 text" if isinstance(e, UnicodeDecodeError) else str(e)
            # The contract's cause for an input we cannot read: the executive blames its producer.
            self.last_image, self.problem = None, f"unreadable image: {why}"
            return self.report("waiting", self.problem)
        self.last_image, self.problem = time.monotonic(), "image"
        self.counted += 1
        self.report("running")
        self.peis.output(OUTPUT, str(len(robots)))
        if self.counted >= IMAGES_TO_COUNT:
            self.done = True
            self.unfollow()
            self.peis.kept.pop(OUTPUT, None)
            self.report("done")

    def tick(self, now):
        if self.starting_until is not None and now >= self.starting_until:
            self.starting_until, self.on = None, True
            self.peis.set(f"components.{C}.currState", "on")
            log(f"{C}: currState on")
            self.start_body()
        if self.active and not self.done and not self.broken:
            if self.last_image is None or now - self.last_image > STALE:
                self.report("waiting", self.problem)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--name", default="counter", help="the PEIS name (default: counter)")
    serve(parser, "robot_counter", C, REMOTE_SETTABLE, lambda peis, args: Counter(peis))


if __name__ == "__main__":
    main()
