"""A stock eclipse-zenoh Python client drives a zmotor axis with no zmotor code at all.

Usage: python3 interop.py tcp/127.0.0.1:7447   (axis m1 must be running there)
Exits non-zero with a message on the first broken expectation.
"""
import json
import queue
import sys
import time

import cbor2
import zenoh

endpoint = sys.argv[1] if len(sys.argv) > 1 else "tcp/127.0.0.1:7447"
conf = zenoh.Config()
conf.insert_json5("mode", '"client"')
conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
conf.insert_json5("scouting/multicast/enabled", "false")


def value(sample):
    return cbor2.loads(sample.payload.to_bytes())


def expect(condition, what):
    if not condition:
        sys.exit(f"python interop: {what}")


with zenoh.open(conf) as session:
    # Read a field.
    replies = list(session.get("motor/m1/RBV", timeout=5.0))
    expect(len(replies) == 1 and replies[0].ok is not None, f"get RBV: {replies}")
    start = value(replies[0].ok)

    # Watch DMOV and the driver's commands, then at once move with a plain put of text: the
    # subscriptions reach the node before the write sent after them, as with any Zenoh
    # publisher. Subscribers come and go, as a screen's do: each try has its own, a while
    # (0.3 s) after the last left, when the node has heard them gone (one back at once may find
    # the node still counting the last: the node once missed DMOV 0 that way in a quarter of
    # the tries, and the move's trace in more).
    for attempt in range(12):
        dmov, traces = queue.Queue(), queue.Queue()
        sub = session.declare_subscriber("motor/m1/DMOV", lambda s: dmov.put(value(s)))
        tracer = session.declare_subscriber(
            "motor/m1/@driver/cmd", lambda s: traces.put((value(s), s.attachment, s.timestamp))
        )
        target = start + 2 if attempt % 2 == 0 else start
        session.put("motor/m1/VAL", str(target))
        seen = []
        try:
            while len(seen) < 2:
                seen.append(dmov.get(timeout=10))
        except queue.Empty:
            pass
        expect(seen == [0, 1], f"try {attempt}: DMOV pulse {seen}")
        rbv = value(list(session.get("motor/m1/RBV", timeout=5.0))[0].ok)
        expect(abs(rbv - target) < 1e-6, f"try {attempt}: RBV {rbv} after the move")
        traced = [traces.get() for _ in range(traces.qsize())]
        commands = [c for c, _, _ in traced]
        expect(any(c["cmd"] == "move" for c in commands), f"try {attempt}: driver commands {commands}")
        # Marked as state, as every publication of the node, and stamped.
        for c, attachment, stamp in traced:
            marker = cbor2.loads(attachment.to_bytes()) if attachment is not None else None
            expect(marker is not None and marker.get("kind") == "state", f"a trace's attachment: {c} {marker}")
            expect(stamp is not None, f"a trace without a timestamp: {c}")
        sub.undeclare()
        tracer.undeclare()
        time.sleep(0.3)

    # Put with completion: the reply comes when the motion is over and says how it ended.
    reply = list(session.get("motor/m1/VAL?wait", payload="1.5", timeout=30.0))[0]
    outcome = cbor2.loads(reply.ok.payload.to_bytes())
    expect(outcome["DMOV"] == 1 and outcome["reached"] == 1 and abs(outcome["RBV"] - 1.5) < 1e-6, f"{outcome}")

    # An answer carries the axis's state as a post does: the marker of the axis's last post (the
    # values are as of it) and the time of the values, so a client that reads has what one that
    # subscribes has.
    def marker(sample):
        expect(sample.attachment is not None, f"no state marker on {sample.key_expr}")
        return cbor2.loads(sample.attachment.to_bytes())

    ended = marker(reply.ok)
    expect(ended["kind"] == "state" and ended["seq"] > 0 and ended["sevr"] == 0, f"?wait answer's marker {ended}")
    expect(reply.ok.timestamp is not None, "the ?wait answer has no timestamp")
    read = list(session.get("motor/m1/RBV", timeout=5.0))[0].ok
    expect(marker(read)["seq"] >= ended["seq"], f"a read after the motion: {marker(read)}, the motion's end {ended}")
    expect(read.timestamp is not None, "a read's answer has no timestamp")
    expect(read.timestamp.get_time() >= reply.ok.timestamp.get_time(), "a read's values older than the motion's end")

    # A refused write answers with an error in plain words.
    reply = list(session.get("motor/m1/RBV", payload="3", timeout=5.0))[0]
    expect(reply.err is not None, "a write to RBV was accepted")
    expect(reply.err.payload.to_string() == "RBV is read-only", reply.err.payload.to_string())

    # DISP 1 disables puts (as on an IOC): a write is refused with its kind in the encoding's
    # schema and moves nothing; DISP 0 enables them again.
    reply = list(session.get("motor/m1/DISP", payload="1", timeout=5.0))[0]
    expect(reply.ok is not None and value(reply.ok) == 1, f"DISP 1: {reply}")
    reply = list(session.get("motor/m1/VAL", payload="3", timeout=5.0))[0]
    expect(reply.err is not None, "a write while DISP is 1 was accepted")
    expect(str(reply.err.encoding) == "text/plain;puts_disabled", f"its encoding: {reply.err.encoding}")
    expect(reply.err.payload.to_string().startswith("VAL: puts are disabled"), reply.err.payload.to_string())
    session.put("motor/m1/DISP", "0")
    reply = list(session.get("motor/m1/VAL?wait", payload="1", timeout=30.0))[0]
    expect(reply.ok is not None and cbor2.loads(reply.ok.payload.to_bytes())["reached"] == 1, f"after DISP 0: {reply}")

    # A state marker is known by its kind however its map is written (a bridge that decoded a
    # sample and encoded it again, with a key of its own): such a sample is never a write. Each
    # is followed by a confirmed write of SPMG's present value, answered once the node has
    # handled what came before it (and sent what that posted).
    vals = queue.Queue()
    # The node's posts only: this session's own puts come back to its subscriber too.
    val_watch = session.declare_subscriber(
        "motor/m1/VAL", lambda s: vals.put(value(s)) if str(s.encoding) == "application/cbor" else None
    )
    here = value(list(session.get("motor/m1/VAL", timeout=5.0))[0].ok)
    marker_map = {"kind": "state", "seq": 5, "stat": 0, "sevr": 0}
    for attachment in [
        cbor2.dumps({**marker_map, "src": "bridge"}),
        cbor2.dumps(marker_map, canonical=True),
        json.dumps(marker_map).encode(),
    ]:
        session.put("motor/m1/VAL", str(here + 7), attachment=attachment)
        list(session.get("motor/m1/SPMG", payload="Go", timeout=5.0))
        now = value(list(session.get("motor/m1/VAL", timeout=5.0))[0].ok)
        expect(now == here and vals.empty(), f"a marked sample ({attachment!r}) was taken as a write: VAL {here} -> {now}, posted {list(vals.queue)}")
    val_watch.undeclare()

    # A hold that names no token holds nothing: the write is refused (bad_hold), nothing moves.
    for attachment in [cbor2.dumps({"kind": "hold"}), json.dumps({"kind": "hold", "tokn": "x"}).encode()]:
        reply = list(session.get("motor/m1/JOGF", payload="1", attachment=attachment, timeout=5.0))[0]
        expect(reply.err is not None, f"a jog under a hold without a token was taken ({attachment!r})")
        expect(str(reply.err.encoding) == "text/plain;bad_hold", f"its encoding: {reply.err.encoding}")
        jogf = value(list(session.get("motor/m1/JOGF", timeout=5.0))[0].ok)
        expect(jogf == 0, f"JOGF {jogf} after a refused held jog")

    # A simulator setting takes a confirmed write as a field does.
    reply = list(session.get("sim/m1/fraction", payload="0.5", timeout=5.0))[0]
    expect(reply.ok is not None and value(reply.ok) == 0.5, f"sim/m1/fraction 0.5: {reply}")
    expect(value(list(session.get("sim/m1/fraction", timeout=5.0))[0].ok) == 0.5, "the setting was not kept")
    reply = list(session.get("sim/m1/fraction", payload="5", timeout=5.0))[0]
    expect(reply.err is not None, "a fraction of 5 was taken")
    list(session.get("sim/m1/fraction", payload="1", timeout=5.0))

    # A plain put to a key with wildcards is refused, on the ERR of each axis it covers.
    errs = queue.Queue()
    # (The put itself comes back to this session's subscriber: the node's report is text.)
    err_watch = session.declare_subscriber(
        "motor/m1/ERR", lambda s: errs.put(s) if str(s.encoding).startswith("text/plain") else None
    )
    session.put("motor/m1/*", "1")
    err = errs.get(timeout=10)
    expect(str(err.encoding) == "text/plain;wildcard", f"a wildcard put's ERR: {err.encoding}")
    expect(err.payload.to_string().startswith("motor/m1/*: a write names one field"), err.payload.to_string())
    err_watch.undeclare()
    # A read of ERR answers the last message posted there, as it was posted.
    last = list(session.get("motor/m1/ERR", timeout=5.0))[0].ok
    expect(last.payload.to_string() == err.payload.to_string(), f"a read of ERR: {last.payload.to_string()}")
    expect(str(last.encoding) == "text/plain;wildcard", f"a read of ERR: {last.encoding}")

    # A delete is not a write: refused on ERR, the field keeps its value.
    list(session.get("motor/m1/DESC", payload="slit", timeout=5.0))
    errs = queue.Queue()
    err_watch = session.declare_subscriber(
        "motor/m1/ERR", lambda s: errs.put(s) if str(s.encoding).startswith("text/plain") else None
    )
    session.delete("motor/m1/DESC")
    err = errs.get(timeout=10)
    expect(str(err.encoding) == "text/plain;bad_value", f"a delete's ERR: {err.encoding}")
    expect(err.payload.to_string().startswith("motor/m1/DESC: a delete is not a write"), err.payload.to_string())
    err_watch.undeclare()
    desc = value(list(session.get("motor/m1/DESC", timeout=5.0))[0].ok)
    expect(desc == "slit", f"DESC after a delete: {desc!r}")

    # A confirmed write to a key that names no field is refused, not answered with nothing.
    before = value(list(session.get("motor/m1/VAL", timeout=5.0))[0].ok)
    for key in ["motor/m1", "motor/m1/VAL/x"]:
        replies = list(session.get(key, payload="5", timeout=5.0))
        expect(len(replies) == 1 and replies[0].err is not None, f"a write to {key}: {replies}")
        words = replies[0].err.payload.to_string()
        expect(words == f"{key}: unknown field", f"a write to {key}: {words}")
    after = value(list(session.get("motor/m1/VAL", timeout=5.0))[0].ok)
    expect(after == before, f"a write that names no field changed VAL: {before} -> {after}")

    # Menu fields take choice names.
    reply = list(session.get("motor/m1/SPMG", payload="Pause", timeout=5.0))[0]
    expect(value(reply.ok) == 1, "SPMG Pause")

print("python interop: ok")
