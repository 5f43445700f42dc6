"""A stock eclipse-zenoh Python client reloads a script controller's script while its axis
moves, through the controller's reload key, as motorScriptMotor's ScriptMotorReload does.

Usage: python3 script_reload.py ENDPOINT AXIS CONTROLLER SCRIPT_FILE
The script file is rewritten by this client (it is a copy the test made).
Exits non-zero with a message on the first broken expectation.
"""
import json
import sys
import time

import cbor2
import zenoh

HOMED = 0x4000
endpoint, axis, controller, script = sys.argv[1:5]
conf = zenoh.Config()
conf.insert_json5("mode", '"client"')
conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
conf.insert_json5("scouting/multicast/enabled", "false")


def expect(condition, what):
    if not condition:
        sys.exit(f"script reload ({axis}): {what}")


with zenoh.open(conf) as session:

    def get_if_served(field):
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
        sys.exit(f"script reload ({axis}): {what}: {field} is {value} after {timeout} s")

    def reload():
        session.put(f"motor/@controller/{controller}/reload", "1")

    wait_for("SEVR", lambda v: v == 0, 20, "the axis never left its alarm")
    wait_for("DMOV", lambda v: v == 1, 20, "the axis never came up")
    expect(int(get_if_served("MSTA")) & HOMED == 0, "homed before the new script")

    # A long move, and the script rewritten and reloaded on the way: the move is stopped.
    far = get_if_served("HLM") - 1
    session.put(f"motor/{axis}/VAL", str(far))
    start = get_if_served("RBV")
    wait_for("RBV", lambda v: v > start + 0.5, 10, "the long move did not start")
    # A delete of the reload key is no command: nothing reloads, the move goes on.
    session.delete(f"motor/@controller/{controller}/reload")
    going = get_if_served("RBV")
    wait_for("RBV", lambda v: v > going + 0.5, 10, "the move stopped after a delete of the reload key")
    expect(get_if_served("DMOV") == 0, "the move ended after a delete of the reload key")
    with open(script, "a") as f:
        f.write(
            "\nlocal first_poll = poll\n"
            "function poll()\n"
            "  local moving = first_poll()\n"
            '  asyn.setIntegerParam(DRIVER, AXIS, "MOTOR_STATUS_HOMED", 1)\n'
            "  return moving\n"
            "end\n"
        )
    reload()
    wait_for("DMOV", lambda v: v == 1, 10, "the move was not stopped by the reload")
    stopped = get_if_served("RBV")
    expect(stopped < far - 1, f"the move went on to {stopped} through the reload")
    wait_for("MSTA", lambda v: int(v) & HOMED != 0, 10, "the new script does not run")

    # A script that does not load: refused, the running one kept, the axis still moves.
    with open(script, "a") as f:
        f.write("\nfunction broken(\n")
    reload()
    time.sleep(1.0)
    back = stopped - 1
    replies = list(session.get(f"motor/{axis}/VAL?wait", payload=str(back), timeout=30.0))
    expect(len(replies) == 1 and replies[0].ok is not None, f"a move after a refused reload: {replies}")
    expect(abs(get_if_served("RBV") - back) < 0.01, f"the move after a refused reload ended at {get_if_served('RBV')}")
    expect(int(get_if_served("MSTA")) & HOMED != 0, "the running script was dropped by a refused reload")
    print("script reload ok")
