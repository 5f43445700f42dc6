"""A Newport XPS user's workflow through newportxps's low-level `XPS` class (Newport's own
Python driver, as the `newportxps` package ships it) against `zmotor sim-controller
newport_xps`: connect two sockets (each reads the error list, as the library does), read the
firmware, log in, initialise and home a group, move it absolute and relative (a motion call
blocks its socket until the motion ends), jog it and abort the jog, abort a move from a second
socket while the first waits (the move answers -27), read positions, velocities, travel limits,
the group's state and its text, and the error a move beyond the travel draws (-35, with the
text ErrorStringGet gives).

Usage: xps_newportxps.py HOST PORT. Prints "xps workflow ok" and exits 0, or exits non-zero
saying which expectation broke.
"""

import sys
import threading
import time

from newportxps.XPS_C8_drivers import XPS

GROUP, POSITIONER = "GROUP1", "GROUP1.POSITIONER"


def expect(condition, what):
    if not condition:
        sys.exit(f"xps workflow: {what}")


def ok(reply, what):
    """A call's reply, its error code checked."""
    expect(reply[0] == 0, f"{what} answered {reply}")
    return reply


def state(xps, sid):
    return ok(xps.GroupStatusGet(sid, GROUP), "GroupStatusGet")[1]


def position(xps, sid):
    return ok(xps.GroupPositionCurrentGet(sid, POSITIONER, 1), "GroupPositionCurrentGet")[1]


def main():
    host, port = sys.argv[1], int(sys.argv[2])
    xps = XPS()
    sid = xps.TCP_ConnectToServer(host, port, 20)
    expect(sid >= 0, f"no connection to {host}:{port}")
    expect(xps.errorcodes.get("-17"), f"the error list read at connection: {xps.errorcodes}")
    error, firmware = xps.FirmwareVersionGet(sid)
    expect(error == 0 and "XPS" in firmware, f"firmware: {error}, {firmware!r}")
    ok(xps.Login(sid, "Administrator", "Administrator"), "Login")

    ok(xps.GroupKill(sid, GROUP), "GroupKill")
    ok(xps.GroupInitialize(sid, GROUP), "GroupInitialize")
    expect(state(xps, sid) == 42, "initialised, not referenced (42)")
    ok(xps.GroupHomeSearch(sid, GROUP), "GroupHomeSearch")
    ready = state(xps, sid)
    expect(ready == 11, f"ready from homing (11) after the home returned, not {ready}")
    error, text = xps.GroupStatusStringGet(sid, ready)
    expect(error == 0 and "homing" in text.lower(), f"state 11's text: {error}, {text!r}")
    expect(abs(position(xps, sid)) < 1e-9, "homed at 0")

    ok(xps.GroupMoveAbsolute(sid, POSITIONER, [1.5]), "GroupMoveAbsolute")
    expect(abs(position(xps, sid) - 1.5) < 1e-9, "at 1.5 when the move returned")
    ok(xps.GroupMoveRelative(sid, POSITIONER, [-0.5]), "GroupMoveRelative")
    expect(abs(position(xps, sid) - 1.0) < 1e-9, "at 1.0 after -0.5")
    expect(state(xps, sid) == 12, "ready from motion (12)")
    error, low, high = ok(xps.PositionerUserTravelLimitsGet(sid, POSITIONER), "PositionerUserTravelLimitsGet")
    expect(low < 0 < high, f"travel {low} to {high}")

    error, _ = xps.GroupMoveAbsolute(sid, POSITIONER, [high + 1.0])
    expect(error == -35, f"a move beyond the travel answered {error}, not -35")
    error, text = xps.ErrorStringGet(sid, -35)
    expect(error == 0 and text, f"ErrorStringGet(-35): {error}, {text!r}")

    # A second socket aborts a move the first one waits on.
    abort_sid = xps.TCP_ConnectToServer(host, port, 20)
    expect(abort_sid >= 0 and abort_sid != sid, "a second socket")
    answered = {}
    mover = threading.Thread(target=lambda: answered.update(move=xps.GroupMoveAbsolute(sid, POSITIONER, [low + 1.0])))
    mover.start()
    for _ in range(100):
        if state(xps, abort_sid) == 44:
            break
        time.sleep(0.02)
    expect(state(xps, abort_sid) == 44, "moving (44) while the first socket waits")
    ok(xps.GroupMoveAbort(abort_sid, GROUP), "GroupMoveAbort")
    mover.join(timeout=20)
    expect(answered.get("move", [None])[0] == -27, f"the aborted move answered {answered}")
    stopped = position(xps, abort_sid)
    expect(low + 1.0 < stopped < 1.0, f"stopped on the way: {stopped}")

    ok(xps.GroupJogModeEnable(sid, GROUP), "GroupJogModeEnable")
    ok(xps.GroupJogParametersSet(sid, POSITIONER, [2.0], [20.0]), "GroupJogParametersSet")
    time.sleep(0.3)
    error, velocity = ok(xps.GroupVelocityCurrentGet(sid, POSITIONER, 1), "GroupVelocityCurrentGet")
    expect(velocity > 0.5, f"jogging at {velocity}")
    ok(xps.GroupMoveAbort(sid, GROUP), "GroupMoveAbort of the jog")
    time.sleep(0.5)
    error, velocity = ok(xps.GroupVelocityCurrentGet(sid, POSITIONER, 1), "GroupVelocityCurrentGet")
    expect(abs(velocity) < 1e-9, f"the jog stopped: {velocity}")

    xps.TCP_CloseSocket(abort_sid)
    xps.TCP_CloseSocket(sid)
    print("xps workflow ok")


main()
