"""A stock eclipse-zenoh Python client drives an axis on a motor controller (or its emulator,
`zmotor sim-controller`) through motor/<axis>/... keys, with no zmotor code at all.

Usage: python3 controller_client.py PHASE ENDPOINT AXIS [--no-home] [--settles-at-once]
  motion     home (unless --no-home: a controller without a home switch, whose home is refused
             or does nothing), move absolute and relative, jog, stop a move (with
             --settles-at-once, a piezo that arrives before anyone could stop it: a jog goes
             to the end of the stroke, and a stop of an axis at rest moves nothing)
  lost       the controller is gone: the axis is in COMM alarm and a move goes nowhere
  recovered  the controller is back: the alarm clears and nothing moves by itself
Exits non-zero with a message on the first broken expectation.
"""
import json
import sys
import time

import cbor2
import zenoh

COMM_ERR = 0x1000
HOME, HOMED = 0x0008, 0x4000

phase, endpoint, axis = sys.argv[1], sys.argv[2], sys.argv[3]
homes = "--no-home" not in sys.argv[4:]
settles_at_once = "--settles-at-once" in sys.argv[4:]
conf = zenoh.Config()
conf.insert_json5("mode", '"client"')
conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
conf.insert_json5("scouting/multicast/enabled", "false")


def expect(condition, what):
    if not condition:
        sys.exit(f"controller client ({phase}, {axis}): {what}")


with zenoh.open(conf) as session:

    def get(field):
        replies = list(session.get(f"motor/{axis}/{field}", timeout=5.0))
        expect(len(replies) == 1 and replies[0].ok is not None, f"get {field}: {replies}")
        return cbor2.loads(replies[0].ok.payload.to_bytes())

    def put(field, value):
        session.put(f"motor/{axis}/{field}", str(value))

    def put_wait(field, value, timeout=60.0):
        replies = list(session.get(f"motor/{axis}/{field}?wait", payload=str(value), timeout=timeout))
        expect(len(replies) == 1 and replies[0].ok is not None, f"{field}={value}?wait: {replies}")
        return cbor2.loads(replies[0].ok.payload.to_bytes())

    def get_if_served(field):
        """The field's value, None while no node answers for the axis (it may still be starting)."""
        replies = [r for r in session.get(f"motor/{axis}/{field}", timeout=5.0) if r.ok is not None]
        return cbor2.loads(replies[0].ok.payload.to_bytes()) if replies else None

    def wait_for(field, accept, timeout, what):
        deadline = time.monotonic() + timeout
        value = None
        while time.monotonic() < deadline:
            value = get_if_served(field)
            if value is not None and accept(value):
                return value
            time.sleep(0.05)
        sys.exit(f"controller client ({phase}, {axis}): {what}: {field} is {value} after {timeout} s")

    def near(a, b, within):
        return abs(a - b) <= within

    if phase == "motion":
        # The node may have started before its controller answered: it reaches it soon after.
        wait_for("SEVR", lambda v: v == 0, 20, "the axis never left its alarm")
        wait_for("DMOV", lambda v: v == 1, 20, "the axis never came up")
        resolution = abs(get("MRES"))
        within = max(get("RDBD"), resolution)

        # Home first: some controllers (an SMC100, a PI axis) move only once referenced. The
        # search ends on the home switch, or with the axis referenced.
        if homes:
            outcome = put_wait("HOMR", 1, timeout=120.0)
            expect(outcome["DMOV"] == 1, f"home: {outcome}")
            msta = int(get("MSTA"))
            expect(msta & (HOME | HOMED) != 0, f"home ended neither at home nor homed: MSTA {msta:#x}")
        start = get("RBV")

        # Absolute, with completion.
        outcome = put_wait("VAL", start + 2)
        expect(outcome["reached"] == 1 and near(outcome["RBV"], start + 2, within), f"absolute move: {outcome}")

        # Relative: a DMOV pulse, then the readback one further.
        put("RLV", 1)
        wait_for("DMOV", lambda v: v == 0, 5, "the relative move never started")
        wait_for("DMOV", lambda v: v == 1, 30, "the relative move never ended")
        expect(near(get("RBV"), start + 3, within), f"relative move ended at {get('RBV')}")

        # Beyond the soft limit: refused, nothing moves.
        here = get("RBV")
        beyond = get("HLM") + 1
        replies = list(session.get(f"motor/{axis}/VAL?wait", payload=str(beyond), timeout=30.0))
        expect(len(replies) == 1 and replies[0].err is not None, f"a target beyond HLM was accepted: {replies}")
        expect(get("LVIO") == 1 and get("RBV") == here, "a refused target moved the axis")

        if settles_at_once:
            # A jog goes to the end of the stroke; a stop at rest moves nothing.
            before = get("RBV")
            put("JOGF", 1)
            wait_for("RBV", lambda v: v > before + 0.2, 10, "the jog did not move the axis")
            put("JOGF", 0)
            wait_for("DMOV", lambda v: v == 1, 20, "the jog never ended")
            at_rest = get("RBV")
            put("STOP", 1)
            time.sleep(0.5)
            later, dmov = get("RBV"), get("DMOV")
            expect(later == at_rest and dmov == 1, f"a stop at rest moved the axis: RBV {at_rest}, then {later}, DMOV {dmov}")
            print("controller client: motion ok")
            sys.exit(0)

        # Jog forward, then let go: the axis stops, wherever it is.
        before = get("RBV")
        put("JOGF", 1)
        wait_for("RBV", lambda v: v > before + 0.2, 10, "the jog did not move the axis")
        put("JOGF", 0)
        wait_for("DMOV", lambda v: v == 1, 20, "the jog never ended")
        stopped = get("RBV")
        time.sleep(0.5)
        later, movn = get("RBV"), get("MOVN")
        expect(later == stopped and movn == 0, f"still moving after the jog ended: RBV {stopped}, then {later}, MOVN {movn}")

        # A long move (to near the high soft limit), stopped on the way.
        origin = get("RBV")
        far = get("HLM") - 0.5
        put("VAL", far)
        wait_for("RBV", lambda v: v > origin + 0.2, 10, "the long move did not start")
        put("STOP", 1)
        wait_for("DMOV", lambda v: v == 1, 20, "the stopped move never ended")
        stopped = get("RBV")
        expect(stopped < far - 1, f"STOP did not stop the move to {far}: at {stopped}")
        time.sleep(0.5)
        expect(get("RBV") == stopped, "moving after the stop")

        print("controller client: motion ok")

    elif phase == "lost":
        wait_for("SEVR", lambda v: v == 3, 15, "no INVALID alarm after the controller went away")
        expect(get("STAT") == 9, f"STAT {get('STAT')} is not COMM")
        expect(int(get("MSTA")) & COMM_ERR != 0, f"MSTA {int(get('MSTA')):#x} has no comm error")
        before = get("RBV")
        put("VAL", before + 1)
        wait_for("DMOV", lambda v: v == 1, 10, "a move without a controller never ended")
        expect(get("RBV") == before, "the readback changed without a controller")
        print("controller client: lost ok")

    elif phase == "recovered":
        # The COMM alarm clears; a controller that restarted may report a problem of its own
        # (a PI servo off until switched on again), which is not a comm error.
        wait_for("STAT", lambda v: v != 9, 30, "the COMM alarm never cleared after the controller came back")
        expect(int(get("MSTA")) & COMM_ERR == 0, "MSTA still has the comm error")
        rbv = get("RBV")
        time.sleep(1.0)
        expect(get("RBV") == rbv and get("MOVN") == 0 and get("DMOV") == 1, "something moved by itself")
        print("controller client: recovered ok")

    else:
        sys.exit(f"unknown phase {phase}")
