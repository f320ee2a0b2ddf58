#!/usr/bin/env python3
"""A PEIS written by hand in Python: one `counter` component that counts robots.

It speaks the Ecology component contract (docs/components.md) over Eclipse Zenoh with the stock
`eclipse-zenoh` package (pip install eclipse-zenoh==1.10.2) and the standard library, nothing else:

- as the PEIS's init component it publishes components.c1.type/cost/currState and applies
  components.c1.reqState (on after a 0.2 s start-up, off at once);
- as component c1 it runs `(count-robots Q C P)`: it follows its input through the meta-tuple
  c1.mi-image, counts the robots in every image (`NAME X Y THETA; ...`), publishes the count as
  c1.out.robot-count and reports c1.status (waiting / running / done, error with c1.cause);
- as a PEIS it declares presence, answers gets for its tuples and applies remote sets.

Usage: robot_counter.py [--name counter] [--listen ENDPOINT]... [--connect ENDPOINT]... [--no-epoch]
"""

import argparse
import json
import re
import signal
import struct
import sys
import threading
import time
import queue

import zenoh

C = "c1"                      # the component's name
KIND, COST = "counter", 5     # its type (the `pc` fact) and cost
STARTUP = 0.2                 # seconds from reqState `on` to currState `on`
STALE = 0.5                   # an input older than this is missing: report `waiting`
IMAGES_TO_COUNT = 10          # report `done` after counting this many images
REMOTE_SETTABLE = {f"components.{C}.reqState", f"{C}.params", f"{C}.mi-image"}
MAX_VALUE = 1 << 20           # largest value accepted, in bytes
NAME = re.compile(r"[A-Za-z0-9_-]{1,255}\Z")
KEY = re.compile(r"[A-Za-z0-9_-]+(\.[A-Za-z0-9_-]+)*\Z")


def log(text):
    print(f"robot_counter: {text}", file=sys.stderr, flush=True)


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


# --- The PEIS: owns its tuples, answers gets, applies remote sets --------------------------------

class Peis:
    def __init__(self, args):
        self.name = args.name
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
            raise SystemExit(f"robot_counter: PEIS {self.name} is already present")
        self.counter = Counter(self)
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
        self.counter.on_set(key, data.decode("utf-8", "replace"))

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
                elif kind == "image":
                    self.counter.on_image(*item)
                self.counter.tick(time.monotonic())
            except Exception as e:  # a bug or a Zenoh error must not take the PEIS down
                log(f"error handling {kind}: {e!r}")
            item = None

    def close(self):
        """Reports the component switched off, then leaves: token first, then the session."""
        try:
            self.counter.unfollow()
            self.set(f"components.{C}.currState", "off")
            if self.counter.on:
                self.set(f"{C}.status", "idle")
            # Zenoh sends the token's withdrawal ahead of data still queued: a query, queued
            # behind our last tuples, comes back once the peers have taken them in.
            for _ in self.session.get("peis/*/leaving", timeout=0.5):
                pass
            self.token.undeclare()
        finally:
            self.session.close()


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
            ke, lambda sample: events.put(("image", (fid, sample))))

        def on_reply(reply):
            if reply.ok is not None:
                events.put(("image", (fid, reply.ok)))
        self.peis.session.get(ke, on_reply, timeout=2.0)
        log(f"{C}: following {owner}:{key}")

    def unfollow(self):
        self.follow_id += 1  # samples already queued for the old target are ignored
        self.target = None
        if self.subscriber is not None:
            self.subscriber.undeclare()
            self.subscriber = None

    def on_image(self, fid, sample):
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
        self.peis.set(f"{C}.out.robot-count", str(len(robots)))
        if self.counted >= IMAGES_TO_COUNT:
            self.done = True
            self.unfollow()
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
        sys.exit(f"robot_counter: cannot join: {e}")
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: peis.stop.set())
    try:
        peis.run()
    finally:
        peis.close()
        log("left")


if __name__ == "__main__":
    main()
