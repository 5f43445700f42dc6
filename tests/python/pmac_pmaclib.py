"""A Delta Tau user's workflow through Diamond Light Source's dls-pmaclib against `zmotor
sim-controller pmac` (a Geo Brick, Turbo PMAC2, over Ethernet): connect (its `i6=1 i3=2 ver`
check), identify the model and count the axes as the library does (`cid`, I20..I23), read and
set motor I-variables, jog to a position and by an increment, jog on and stop, home, read
positions, kill and re-enable, the ERR003 answer to a command the controller does not know, and
disabling then enabling the limits (Ixx24 bit $20000). Every wait polls `#n?`, the motor status
words, for the in-position bit (word 2 bit 0) and home complete (word 2 bit 10).

Usage: pmac_pmaclib.py HOST PORT. Prints "pmac workflow ok" and exits 0, or exits non-zero
saying which expectation broke.
"""

import sys
import time

from dls_pmaclib.dls_pmacremote import PmacEthernetInterface

# Motor status bits (Turbo PMAC `#n?`: two 24-bit words, twelve hex digits).
AMPLIFIER_ENABLED = 1 << 19  # word 1
OPEN_LOOP = 1 << 18  # word 1
HOME_COMPLETE = 1 << 10  # word 2
IN_POSITION = 1 << 0  # word 2


def expect(condition, what):
    if not condition:
        sys.exit(f"pmac workflow: {what}")


def send(pmac, command):
    reply, ok = pmac.sendCommand(command)
    expect(ok, f"{command!r}: {reply}")
    return reply


def values(pmac, command):
    """The values a command line reports, one a line, its final ACK checked and dropped."""
    reply = send(pmac, command)
    expect(reply.endswith("\r\x06") or reply == "\x06", f"{command!r} answered {reply!r}")
    return reply.split("\r")[:-1]


def position(pmac, motor):
    return float(values(pmac, f"#{motor}P")[0])


def status(pmac, motor):
    (words,) = values(pmac, f"#{motor}?")
    expect(len(words) == 12, f"#{motor}? answered {words!r}")
    return int(words[:6], 16), int(words[6:], 16)


def wait_for(pmac, motor, what, bits, timeout=30.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if status(pmac, motor)[1] & bits == bits:
            return
        time.sleep(0.05)
    sys.exit(f"pmac workflow: motor {motor} never {what}: status {status(pmac, motor)}")


def moved(pmac, call, *args):
    command, reply, ok = call(*args)
    expect(ok and reply == "\x06", f"{command!r} answered {reply!r}")


def main(host, port):
    pmac = PmacEthernetInterface()
    pmac.setConnectionParams(host, port)
    failure = pmac.connect()
    expect(failure is None, f"connect: {failure}")
    try:
        expect(pmac.getPmacModel() == "Geo Brick (3U Turbo PMAC2)", f"model {pmac.getPmacModel()!r}")
        expect(pmac.isModelGeobrick(), "a Geo Brick")
        expect(pmac.getNumberOfAxes() == 8, f"{pmac.getNumberOfAxes()} axes, not 8")

        # Power-up: activated, amplifier enabled, loop closed, in position; Turbo SRM defaults.
        first, second = status(pmac, 1)
        expect(first & AMPLIFIER_ENABLED and not first & OPEN_LOOP, f"power-up status {first:06X}")
        expect(second & IN_POSITION, f"in position at power-up: {second:06X}")
        speeds = pmac.getAxisSetupIVars(1, [22, 23])
        expect(speeds == ["32", "32"], f"I122, I123: {speeds}")
        pmac.setAxisSetupIVar(1, 22, 50)
        pmac.setAxisSetupIVar(1, 19, 1)
        expect(pmac.getAxisSetupIVars(1, [19, 22]) == ["1", "50"], "I119, I122 as set")

        # Jog to a position, then by an increment; wait for in-position each time.
        moved(pmac, pmac.jogTo, 1, 5000)
        wait_for(pmac, 1, "in position", IN_POSITION)
        expect(position(pmac, 1) == 5000, f"#1P after J=5000: {position(pmac, 1)}")
        moved(pmac, pmac.jogInc, 1, "neg", 2000)
        wait_for(pmac, 1, "in position", IN_POSITION)
        expect(position(pmac, 1) == 3000, f"#1P after J^-2000: {position(pmac, 1)}")

        # Jog on, then stop.
        moved(pmac, pmac.jogContinous, 1, "pos")
        time.sleep(0.3)
        expect(not status(pmac, 1)[1] & IN_POSITION, "jogging, not in position")
        moved(pmac, pmac.jogStop, 1)
        wait_for(pmac, 1, "in position", IN_POSITION)
        stopped = position(pmac, 1)
        expect(stopped > 3000, f"#1P after J+ J/: {stopped}")

        # Home: complete, and zero at the home position.
        moved(pmac, pmac.homeCommand, 1)
        wait_for(pmac, 1, "homed", HOME_COMPLETE | IN_POSITION)
        expect(position(pmac, 1) == 0, f"#1P after HM: {position(pmac, 1)}")

        # Kill: amplifier off, loop open; J/ closes it again.
        values(pmac, "#1K")
        first, second = status(pmac, 1)
        expect(not first & AMPLIFIER_ENABLED and first & OPEN_LOOP, f"killed: {first:06X}")
        values(pmac, "#1J/")
        wait_for(pmac, 1, "in position again", IN_POSITION)

        # Two motors on one line.
        values(pmac, "#2J=-1000 #3J=1000")
        wait_for(pmac, 2, "in position", IN_POSITION)
        wait_for(pmac, 3, "in position", IN_POSITION)
        expect(values(pmac, "#2P #3P") == ["-1000", "1000"], "#2P #3P")

        # A command the controller does not know.
        reply = send(pmac, "nonsense")
        expect(reply == "\x07ERR003\r", f"'nonsense' answered {reply!r}")
        expect(pmac.PMAC_errors["ERR003"].startswith("Data error"), "ERR003 as the library names it")

        # Limits disabled (Ixx24 bit $20000) and enabled again.
        command, _, ok = pmac.disableLimits(1, True)
        expect(ok and command.lower() == "i124=$820001", f"disableLimits: {command!r}")
        expect(int(values(pmac, "i124")[0].lstrip("$"), 16) & 0x20000, "limits disabled")
        command, _, ok = pmac.disableLimits(1, False)
        expect(ok and command.lower() == "i124=$800001", f"enable limits: {command!r}")
    finally:
        pmac.disconnect()
    print("pmac workflow ok")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit("usage: pmac_pmaclib.py HOST PORT")
    main(sys.argv[1], int(sys.argv[2]))
