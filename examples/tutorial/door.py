#!/usr/bin/env python3
"""The smart door of the tutorial (docs/tutorial.md): a PEIS with one `door` component, its motor.

It speaks the Ecology component contract (docs/components.md) over Eclipse Zenoh with the stock
`eclipse-zenoh` package (pip install eclipse-zenoh==1.10.2) and the standard library, nothing else.
It is examples/python/robot_counter.py with another component: the wire format and the PEIS
(presence, gets, remote sets, leaving) are the same code.

- As the PEIS's init component it publishes components.m1.type (`door`), .cost and .currState (on:
  the motor is always powered) and applies components.m1.reqState.
- As component m1 it runs `(door-opener D M R)`: it follows the position of robot R through the
  meta-tuple m1.mi-position, and opens the door once R is within --near metres of it
  (m1.door = `open`), then reports `done`. Until then it reports `running` (the door closed), or
  `waiting` while no position came in the last 0.5 s. Empty params or `off` close the door.

Usage: door.py [--name door1] [--at X Y] [--near M] [--listen ENDPOINT]... [--connect ENDPOINT]... [--no-epoch]
"""

import argparse
import json
import math
import re
import signal
import struct
import sys
import threading
import time
import queue

import zenoh

C = "m1"                      # the component's name
KIND, COST = "door", 5        # its type (the `pc` fact) and cost (running: it is always on)
STALE = 0.5                   # an input older than this is missing: report `waiting`
REMOTE_SETTABLE = {f"components.{C}.reqState", f"{C}.params", f"{C}.mi-position"}
MAX_VALUE = 1 << 20           # largest value accepted, in bytes
NAME = re.compile(r"[A-Za-z0-9_-]{1,255}\Z")
KEY = re.compile(r"[A-Za-z0-9_-]+(\.[A-Za-z0-9_-]+)*\Z")


def log(text):
    print(f"door: {text}", file=sys.stderr, flush=True)


# --- Wire format: the metadata attachment, version 1, little-endian -----------------------------

F_TS_USER, F_EXPIRY, F_EXPIRED, F_EPOCH, F_CREATOR = 1, 2, 4, 8, 16


def encode_meta(seq, ts_write, epoch, mimetype, creator=None):
    """version, flags, seq, ts_write, [epoch if flag bit 3], mimetype length, mimetype,
    [creator length, creator if flag bit 4]."""
    flags = (F_EPOCH if epoch else 0) | (F_CREATOR if creator else 0)
    out = struct.pack("<BBQQ", 1, flags, seq, ts_write)
    if epoch:
        out += struct.pack("<Q", epoch)
    mime = mimetype.encode("ascii")
    out += bytes([len(mime)]) + mime
    if creator:
        name = creator.encode("ascii")
        out += bytes([len(name)]) + name
    return out


def decode_meta(data):
    """Reads an attachment; raises ValueError on any deviation from the layout."""
    if len(data) < 18 or data[0] != 1:
        raise ValueError("not a version 1 metadata attachment")
    flags = data[1]
    seq, ts_write = struct.unpack_from("<QQ", data, 2)
    at, fields = 18, {}
    for flag, name in ((F_TS_USER, "ts_user"), (F_EXPIRY, "expiry"), (F_EPOCH, "epoch")):
        if flags & flag:
            if len(data) < at + 8:
                raise ValueError("attachment too short")
            fields[name] = struct.unpack_from("<Q", data, at)[0]
            at += 8
    if len(data) < at + 1 or len(data) < at + 1 + data[at]:
        raise ValueError("bad mimetype length")
    end = at + 1 + data[at]
    mime = data[at + 1:end].decode("ascii")  # raises UnicodeDecodeError, a ValueError
    if not mime or not all(" " <= ch <= "~" for ch in mime):
        raise ValueError("invalid mimetype")
    creator = None
    if flags & F_CREATOR:
        if len(data) < end + 1 or len(data) < end + 1 + data[end]:
            raise ValueError("bad creator length")
        creator = data[end + 1:end + 1 + data[end]].decode("ascii")
        end += 1 + data[end]
    if len(data) != end:
        raise ValueError("trailing bytes")
    return dict(seq=seq, ts_write=ts_write, mimetype=mime, epoch=fields.get("epoch", 0),
                ts_user=fields.get("ts_user"), expiry=fields.get("expiry"), creator=creator)


def key_expr(owner, key):
    """Tuple (OWNER, a.b.c) lives at peis/OWNER/a/b/c."""
    return f"peis/{owner}/{key.replace('.', '/')}"


def parse_meta_tuple(text):
    """`(meta OWNER KEY)` -> (OWNER, KEY); raises ValueError saying what is wrong."""
    inner = text.strip()
    if not (inner.startswith("(") and inner.endswith(")")):
        raise ValueError(f"{text!r} is not (meta OWNER KEY)")
    words = inner[1:-1].split()
    if len(words) != 3 or words[0] != "meta":
        raise ValueError(f"{text!r} is not (meta OWNER KEY)")
    if not NAME.match(words[1]) or not KEY.match(words[2]) or len(words[2]) > 255:
        raise ValueError(f"{text!r} names an invalid PEIS or key")
    return words[1], words[2]


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


# --- The PEIS: owns its tuples, answers gets, applies remote sets --------------------------------

class Peis:
    def __init__(self, args):
        self.name = args.name
        self.at, self.near = args.at, args.near  # where the door is; how near opens it
        self.epoch = 0 if args.no_epoch else time.time_ns()  # identifies this run of the PEIS
        self.tuples = {}   # key -> (KeyExpr, payload bytes, attachment bytes)
        self.seqs = {}     # key -> last seq
        self.events = queue.Queue()  # everything Zenoh delivers, handled by the main thread
        self.stop = threading.Event()
        conf = zenoh.Config()
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5("transport/link/tx/lease", "2000")  # we leave 2 s after vanishing
        # Like the Rust PEIS: gossip completes the mesh, only the greater Zenoh id dials.
        conf.insert_json5("scouting/gossip/autoconnect_strategy",
                          '{ peer: { to_router: "always", to_peer: "greater-zid" } }')
        if args.listen:
            conf.insert_json5("listen/endpoints", json.dumps(args.listen))
        if args.connect:
            conf.insert_json5("connect/endpoints", json.dumps(args.connect))
            conf.insert_json5("connect/timeout_ms", "5000")
            conf.insert_json5("connect/exit_on_failure", "true")
        self.session = zenoh.open(conf)
        self.settle_links()
        alive = f"peis/{self.name}/@alive"
        if any(r.ok is not None for r in self.session.liveliness().get(alive, timeout=2.0)):
            self.session.close()
            raise SystemExit(f"door: PEIS {self.name} is already present")
        self.door = Door(self)
        self.queryables = [
            self.session.declare_queryable(f"peis/{self.name}/**",
                                           lambda q: self.events.put(("get", q))),
            self.session.declare_queryable(f"peis/{self.name}/@set/**",
                                           lambda q: self.events.put(("set", q))),
        ]
        self.token = self.session.liveliness().declare_token(alive)

    def settle_links(self, quiet=0.25, most=3.0):
        """Waits for the mesh to form before asking anything: linked at first only to the PEIS we
        connected to, we learn the others from gossip and link to them a moment later, and peers do
        not relay. So the name check waits until the set of linked peers stays the same for
        `quiet` seconds (at most `most`), and not at all when no peer is linked."""
        linked = lambda: {str(z) for z in self.session.info.peers_zid()}
        start = time.monotonic()
        seen = linked()
        since = start
        while seen and time.monotonic() - since < quiet and time.monotonic() - start < most:
            time.sleep(0.025)
            now = linked()
            if now != seen:
                seen, since = now, time.monotonic()

    def set(self, key, data, mimetype="text/plain", creator=None):
        """Publishes our tuple `key` with the next seq; returns (payload, attachment)."""
        data = data.encode() if isinstance(data, str) else data
        seq = self.seqs[key] = self.seqs.get(key, 0) + 1
        meta = encode_meta(seq, time.time_ns(), self.epoch, mimetype, creator)
        ke = key_expr(self.name, key)
        self.tuples[key] = (zenoh.KeyExpr(ke), data, meta)
        self.session.put(ke, data, attachment=meta, congestion_control=zenoh.CongestionControl.BLOCK)
        return data, meta

    def answer_get(self, query):
        for ke, data, meta in list(self.tuples.values()):
            if query.key_expr.intersects(ke):
                query.reply(ke, data, attachment=meta)

    def apply_remote_set(self, query):
        prefix = f"peis/{self.name}/@set/"
        key = str(query.key_expr)[len(prefix):].replace("/", ".")
        if key not in REMOTE_SETTABLE:
            return query.reply_err(f"remote set of {key} is not allowed by {self.name}")
        data = query.payload.to_bytes() if query.payload is not None else b""
        mimetype, creator = "application/octet-stream", None  # a request without metadata
        if query.attachment is not None:
            try:
                request = decode_meta(query.attachment.to_bytes())
            except ValueError as e:
                return query.reply_err(f"malformed attachment: {e}")
            if request["expiry"] is not None:
                return query.reply_err(f"{self.name} does not support a time to live")
            mimetype, creator = request["mimetype"], request["creator"]
        if len(data) > MAX_VALUE:
            return query.reply_err(f"value of {len(data)} bytes is over {MAX_VALUE}")
        if key.endswith(".reqState") and data.decode("utf-8", "replace").strip() not in ("on", "off"):
            return query.reply_err(f"{key} must be on or off, not {data[:40]!r}")
        data, meta = self.set(key, data, mimetype, creator)
        query.reply(query.key_expr, data, attachment=meta)
        log(f"remote set {key} = {data.decode('utf-8', 'replace')}")
        self.door.on_set(key, data.decode("utf-8", "replace"))

    def run(self):
        """The main loop: one thread handles every event, so no state is shared between threads."""
        print("ready", flush=True)
        while not self.stop.is_set():
            try:
                kind, item = self.events.get(timeout=0.05)
            except queue.Empty:
                kind, item = None, None
            try:
                if kind in ("get", "set"):
                    with item:  # leaving the block finishes the query: the asker stops waiting
                        (self.answer_get if kind == "get" else self.apply_remote_set)(item)
                elif kind == "position":
                    self.door.on_position(*item)
                self.door.tick(time.monotonic())
            except Exception as e:  # a bug or a Zenoh error must not take the PEIS down
                log(f"error handling {kind}: {e!r}")
            item = None

    def close(self):
        """Reports the component switched off, then leaves: token first, then the session."""
        try:
            self.door.unfollow()
            self.set(f"components.{C}.currState", "off")
            if self.door.on:
                self.set(f"{C}.status", "idle")
            # Zenoh sends the token's withdrawal ahead of data still queued: a query, queued
            # behind our last tuples, comes back once the peers have taken them in.
            for _ in self.session.get("peis/*/leaving", timeout=0.5):
                pass
            self.token.undeclare()
        finally:
            self.session.close()


# --- The component: init-component duties for m1, and its body -----------------------------------

class Door:
    def __init__(self, peis):
        self.peis = peis
        self.at, self.near = peis.at, peis.near
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
            ke, lambda sample: events.put(("position", (fid, sample))))

        def on_reply(reply):
            if reply.ok is not None:
                events.put(("position", (fid, reply.ok)))
        self.peis.session.get(ke, on_reply, timeout=2.0)
        log(f"{C}: following {owner}:{key}")

    def unfollow(self):
        self.follow_id += 1  # samples already queued for the old target are ignored
        self.target = None
        if self.subscriber is not None:
            self.subscriber.undeclare()
            self.subscriber = None

    def on_position(self, fid, sample):
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
    parser.add_argument("--listen", action="append", default=[], metavar="ENDPOINT")
    parser.add_argument("--connect", action="append", default=[], metavar="ENDPOINT")
    parser.add_argument("--no-epoch", action="store_true",
                        help="publish without the epoch field (for readers that predate it)")
    args = parser.parse_args()
    if not NAME.match(args.name):
        parser.error("--name: 1-255 characters from A-Z a-z 0-9 _ -")
    try:
        peis = Peis(args)
    except zenoh.ZError as e:
        sys.exit(f"door: cannot join: {e}")
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: peis.stop.set())
    try:
        peis.run()
    finally:
        peis.close()
        log("left")


if __name__ == "__main__":
    main()
