"""The PEIS part of a component written in Python, shared by examples/python/robot_counter.py and the
tutorial's examples/tutorial/door.py. It needs the standard library and the stock `eclipse-zenoh`
package (pip install eclipse-zenoh==1.10.2), nothing else, and follows docs/components.md:

- The wire format of a tuple: tuple (OWNER, a.b.c) lives at the Zenoh key expression
  peis/OWNER/a/b/c (`key_expr`); its value is the sample's payload and its metadata the sample's
  attachment, little-endian (`encode_meta`, `decode_meta`): version, flags, seq, ts_write, the
  optional fields the flags name (ts_user, expiry, epoch), the mimetype and, with flag bit 4, the
  creator (version 2; version 1 without it). A meta-tuple's value `(meta OWNER KEY)` points at another tuple
  (`parse_meta_tuple`). PEIS names match `NAME`, keys `KEY`; a value is at most `MAX_VALUE` bytes.
- The PEIS's own tuples: `Peis.set` publishes one with the next seq (from 1, per key) and the epoch
  of this run (none with --no-epoch), and keeps it to answer gets; `Peis.delete` removes one. The
  first is `contract` = `2`: the attachment version we read, so that writers speak it to us.
- Outputs only while read: `Peis.output(key, text)` publishes an output only while someone
  subscribes to it (`Peis.is_read`: Zenoh's matching status of a publisher declared for it), deletes
  it once nobody does, and keeps the last value back to publish the moment a reader comes.
- Queryables: peis/NAME/** answers gets with every tuple of ours the query's key expression
  intersects; peis/NAME/@set/** applies remote sets.
- Remote sets: only of the keys in `remote_settable` (the component's reqState, params and mi-INFO),
  with a value of at most `MAX_VALUE` bytes, `on` or `off` for a reqState, and without a time to live;
  anything else is refused with a reply error. Claims are arbitrated (`Peis.arbitrate`): a request
  the component's holders (`components.C.holders`) would not share is refused, naming them. An
  applied set is published as our tuple (with the request's mimetype and creator), replied with
  as applied, and handed to the component.
- Liveliness: the PEIS waits for the mesh to form, refuses to start when the token
  peis/NAME/@alive is already declared anywhere in the ecology, publishes its component's first
  tuples, declares both queryables, then the token. It leaves in order: the component reported off,
  a get to flush those tuples to the peers, the token withdrawn, the session closed.

`serve` runs a PEIS with one component from the command line. The component is an object made by
`make_component(peis, args)` once the name is known to be free, with:

- `on`: whether it is switched on;
- `on_set(key, text)`: called after a remote set of `key` was applied;
- `on_input(*item)`: called for every event ("input", item) it put on `peis.events` (from Zenoh
  callbacks: all events are handled by the main thread, one at a time);
- `tick(now)`: called after every event, and at least every 0.05 s, with time.monotonic();
- `unfollow()`: called on leaving, before the PEIS reports the component off.
"""

import json
import queue
import re
import signal
import struct
import sys
import threading
import time

import zenoh

MAX_VALUE = 1 << 20           # largest value accepted, in bytes
NAME = re.compile(r"[A-Za-z0-9_-]{1,255}\Z")
KEY = re.compile(r"[A-Za-z0-9_-]+(\.[A-Za-z0-9_-]+)*\Z")


def logger(program):
    """The function that logs a line `PROGRAM: TEXT` on stderr."""
    def log(text):
        print(f"{program}: {text}", file=sys.stderr, flush=True)
    return log


# --- Wire format: the metadata attachment, versions 1 and 2, little-endian -----------------------

F_TS_USER, F_EXPIRY, F_EXPIRED, F_EPOCH, F_CREATOR = 1, 2, 4, 8, 16
CONTRACT_KEY, CONTRACT = "contract", 2  # the tuple announcing the highest version we read


def encode_meta(seq, ts_write, epoch, mimetype, creator=None):
    """version, flags, seq, ts_write, [epoch if flag bit 3], mimetype length, mimetype,
    [creator length, creator if flag bit 4]. Version 2 when there is a creator, else version 1
    (the earlier format, which every reader reads)."""
    flags = (F_EPOCH if epoch else 0) | (F_CREATOR if creator else 0)
    out = struct.pack("<BBQQ", 2 if creator else 1, flags, seq, ts_write)
    if epoch:
        out += struct.pack("<Q", epoch)
    mime = mimetype.encode("ascii")
    out += bytes([len(mime)]) + mime
    if creator:
        name = creator.encode("ascii")
        out += bytes([len(name)]) + name
    return out


def decode_meta(data):
    """Reads an attachment of any version (docs/tuples.md, "Compatibility"): unknown flag bits are
    ignored, and from version 2 on so is anything after the fields we know (a later version only
    appends). Raises ValueError on a truncated field, a bad mimetype or creator, version 0, or
    bytes after the fields of version 1."""
    if len(data) < 18:
        raise ValueError("attachment too short")
    version, flags = data[0], data[1]
    if version == 0:
        raise ValueError("unknown version")
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
    # Version 1 knew no creator; executives wrote one under it for a while, after the mimetype.
    if flags & F_CREATOR and (version >= 2 or len(data) > end):
        if len(data) < end + 1 or len(data) < end + 1 + data[end]:
            raise ValueError("bad creator length")
        creator = data[end + 1:end + 1 + data[end]].decode("ascii")
        if not NAME.match(creator):
            raise ValueError("invalid creator")
        end += 1 + data[end]
    if version == 1 and len(data) != end:
        raise ValueError("trailing bytes")
    return dict(seq=seq, ts_write=ts_write, mimetype=mime, epoch=fields.get("epoch", 0),
                ts_user=fields.get("ts_user"), expiry=fields.get("expiry"),
                expired=bool(flags & F_EXPIRED), creator=creator)


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


# --- The PEIS: owns its tuples, answers gets, applies remote sets --------------------------------

class Refused(Exception):
    """A remote set refused because others hold the component; the message names them."""


class Peis:
    def __init__(self, name, component, remote_settable, make_component, program,
                 listen=(), connect=(), no_epoch=False):
        """Joins as PEIS `name` hosting component `component` (its name, as `c1`), whose keys in
        `remote_settable` others may set; `program` starts every line logged."""
        self.name, self.c, self.remote_settable = name, component, set(remote_settable)
        self.log = logger(program)
        self.epoch = 0 if no_epoch else time.time_ns()  # identifies this run of the PEIS
        self.tuples = {}   # key -> (KeyExpr, payload bytes, attachment bytes)
        self.seqs = {}     # key -> last seq
        self.readers = {}  # key -> a publisher declared for its matching status
        self.kept = {}     # key -> the last value of an output held back while nobody read it
        self.events = queue.Queue()  # everything Zenoh delivers, handled by the main thread
        self.stop = threading.Event()
        conf = zenoh.Config()
        conf.insert_json5("mode", '"peer"')
        conf.insert_json5("scouting/multicast/enabled", "false")
        conf.insert_json5("transport/link/tx/lease", "2000")  # we leave 2 s after vanishing
        # Like the Rust PEIS: gossip completes the mesh, only the greater Zenoh id dials.
        conf.insert_json5("scouting/gossip/autoconnect_strategy",
                          '{ peer: { to_router: "always", to_peer: "greater-zid" } }')
        if listen:
            conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
        if connect:
            conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
            conf.insert_json5("connect/timeout_ms", "5000")
            conf.insert_json5("connect/exit_on_failure", "true")
        self.session = zenoh.open(conf)
        self.settle_links()
        alive = f"peis/{self.name}/@alive"
        taken = lambda: any(r.ok is not None
                            for r in self.session.liveliness().get(alive, timeout=2.0))
        # A run of this PEIS that just stopped without leaving stays present until its lease (2 s)
        # runs out: ask again for up to 3 s before taking the name for a live twin's.
        deadline = time.monotonic() + 3.0
        said = False
        while taken():
            if not said:
                self.log(f"a PEIS named {self.name} is present: waiting up to 3s for it to leave")
                said = True
            if time.monotonic() >= deadline:
                self.session.close()
                raise SystemExit(f"{program}: PEIS {self.name} is already present")
            time.sleep(0.25)
        self.set(CONTRACT_KEY, str(CONTRACT))
        self.component = make_component(self)
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

    def delete(self, key):
        """Removes our tuple `key`, if we have it, with the next seq."""
        if self.tuples.pop(key, None) is None:
            return
        seq = self.seqs[key] = self.seqs.get(key, 0) + 1
        meta = encode_meta(seq, time.time_ns(), self.epoch, "text/plain")
        self.session.delete(key_expr(self.name, key), attachment=meta,
                            congestion_control=zenoh.CongestionControl.BLOCK)

    def is_read(self, key):
        """Whether anyone subscribes to our tuple `key` now: the matching status of a publisher
        declared for it (never used to put), whose matching listener says when a reader comes. A
        Zenoh peer, as this PEIS is, is told of its peers' subscribers as they are declared, so it
        knows at once."""
        if key not in self.readers:
            publisher = self.session.declare_publisher(key_expr(self.name, key))
            publisher.declare_matching_listener(
                lambda status: status.matching and self.events.put(("readers", key)))
            self.readers[key] = publisher
        return self.readers[key].matching_status.matching

    def output(self, key, text):
        """Publishes output `key` while someone reads it; otherwise deletes it and keeps `text`
        back, published the moment a reader comes."""
        if self.is_read(key):
            self.kept.pop(key, None)
            self.set(key, text)
        else:
            self.delete(key)
            self.kept[key] = text

    def answer_get(self, query):
        for ke, data, meta in list(self.tuples.values()):
            if query.key_expr.intersects(ke):
                query.reply(ke, data, attachment=meta)

    def apply_remote_set(self, query):
        prefix = f"peis/{self.name}/@set/"
        chunks = str(query.key_expr)[len(prefix):]
        # One spelling per key, one segment per chunk: `components/c1.reqState` would slip past
        # an access rule that matches chunks.
        if "." in chunks:
            return query.reply_err(f"{chunks} is not one exact key (a remote set needs one exact key)")
        key = chunks.replace("/", ".")
        if key not in self.remote_settable:
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
        try:
            writes = self.arbitrate(creator, key, data)
        except Refused as e:
            return query.reply_err(str(e))
        answer = None
        for k, value in writes:
            written = self.set(k, value, mimetype if k == key else "text/plain",
                               creator if k == key else None)
            if k == key:
                answer = written
            if k != f"components.{self.c}.holders":
                self.log(f"remote set {k} = {value.decode('utf-8', 'replace')}")
                self.component.on_set(k, value.decode("utf-8", "replace"))
        if answer is None:  # shared, or a release of what others still hold: nothing of ours moved
            answer = self.tuples.get(key, (None, data, encode_meta(0, time.time_ns(), self.epoch,
                                                                    mimetype)))[1:]
        query.reply(query.key_expr, answer[0], attachment=answer[1])

    def text(self, key):
        """Our tuple `key` as text, stripped; empty when we have none."""
        entry = self.tuples.get(key)
        return entry[1].decode("utf-8", "replace").strip() if entry else ""

    def arbitrate(self, requester, key, data):
        """Claims (docs/components.md, "Several executives"): the writes a remote set of `key` comes
        to, as (key, bytes) pairs, or `Refused` naming who holds the component. Free: applied, and
        the requester holds it. The same as what runs: shared, only the holders change. Anything else
        while others hold it: refused. A release (reqState off, empty params) removes only its
        requester while others hold; the last holder's release switches off what a request
        switched on and clears the params."""
        holders_key = f"components.{self.c}.holders"
        holders = self.text(holders_key).split()
        others = [h for h in holders if h != requester]
        asked = data.decode("utf-8", "replace").strip()
        power, params = f"components.{self.c}.reqState", f"{self.c}.params"
        release = (key == power and asked == "off") or (key == params and asked == "")
        named = lambda hs: " ".join(hs).encode()
        if release:
            if others:
                return [(holders_key, named(others))] if len(others) != len(holders) else []
            writes = [(key, data)]
            if holders:
                # The last holder leaves: off again, if a request switched it on.
                switched_on = (self.text(power) == "on"
                               and decode_meta(self.tuples[power][2])["creator"] is not None)
                if key == params and switched_on:
                    writes.append((power, b"off"))
                if key == power and self.text(params):
                    writes.append((params, b""))
                writes.append((holders_key, b""))
            return writes
        if others:
            if key == power:
                same = self.component.on
            elif key == params:
                same = self.text(params) == asked
            else:  # a wire shares only for a holder: params come first
                same = requester in holders and self.tuples.get(key, (None, None))[1] == data
            if not same:
                now = self.text(key) or "nothing"
                raise Refused(f"held by {' '.join(others)}: {key} is {now}")
            writes = []
        else:
            writes = [(key, data)]
        if requester and requester not in holders:
            writes.append((holders_key, named(holders + [requester])))
        return writes

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
                elif kind == "input":
                    self.component.on_input(*item)
                elif kind == "readers" and item in self.kept and self.is_read(item):
                    self.set(item, self.kept.pop(item))
                self.component.tick(time.monotonic())
            except Exception as e:  # a bug or a Zenoh error must not take the PEIS down
                self.log(f"error handling {kind}: {e!r}")
            item = None

    def close(self):
        """Reports the component switched off, then leaves: token first, then the session."""
        try:
            self.component.unfollow()
            self.set(f"components.{self.c}.currState", "off")
            if self.component.on:
                self.set(f"{self.c}.status", "idle")
            # Zenoh sends the token's withdrawal ahead of data still queued: a query, queued
            # behind our last tuples, comes back once the peers have taken them in.
            for _ in self.session.get("peis/*/leaving", timeout=0.5):
                pass
            self.token.undeclare()
            for publisher in self.readers.values():
                publisher.undeclare()
        finally:
            self.session.close()


def serve(parser, program, component, remote_settable, make_component):
    """The command line of a PEIS with one component: `parser` has --name and the component's own
    options; this adds --listen, --connect and --no-epoch, joins, runs until SIGINT or SIGTERM and
    leaves. `make_component(peis, args)` makes the component."""
    parser.add_argument("--listen", action="append", default=[], metavar="ENDPOINT")
    parser.add_argument("--connect", action="append", default=[], metavar="ENDPOINT")
    parser.add_argument("--no-epoch", action="store_true",
                        help="publish without the epoch field (for readers that predate it)")
    args = parser.parse_args()
    if not NAME.match(args.name):
        parser.error("--name: 1-255 characters from A-Z a-z 0-9 _ -")
    try:
        peis = Peis(args.name, component, remote_settable, lambda p: make_component(p, args),
                    program, args.listen, args.connect, args.no_epoch)
    except zenoh.ZError as e:
        sys.exit(f"{program}: cannot join: {e}")
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: peis.stop.set())
    try:
        peis.run()
    finally:
        peis.close()
        peis.log("left")
