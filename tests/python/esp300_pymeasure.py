"""A stock, third-party ESP300 client against whatever answers on a serial device.

The client is pymeasure's `pymeasure.instruments.newport.ESP300` (PyPI: pymeasure), over its
`SerialAdapter` (pyserial) at the ESP300's 19,200 baud, commands ended by CR, replies by CR LF,
driven as its users drive it: identify the controller, read the axes' positions, enable an axis,
home it, move it to an absolute target and wait for the motion to end (`WS`, then `MD?` until
done), move it relatively, define a position, read the error buffer empty, and make the
controller report errors its own way: a motion of a motor that is off (x13), an axis that is
not there (9), a command that does not exist (6), each read through `error` / `errors` (`TE?`
until 0). `ESP300.axes`, `enable()` and `disable()` are not used: `axes` reads every property of
the instrument, SCPI ones (`*IDN?`, `*OPC?`, ...) included, which an ESP300 does not have.

Usage: esp300_pymeasure.py <serial device> (a pseudo-terminal served by `zmotor sim-controller
newport_esp300 --pty`); prints "esp300 workflow ok" when all went well.
"""

import sys
import time
import warnings

from pymeasure.adapters import SerialAdapter

with warnings.catch_warnings():
    warnings.simplefilter("ignore")  # pymeasure warns that it does not know whether it is SCPI
    from pymeasure.instruments.newport import ESP300
    from pymeasure.instruments.newport.esp300 import AxisError, GeneralError


def check(what, condition, detail=""):
    if not condition:
        raise SystemExit(f"{what} broke{': ' if detail else ''}{detail}")


def close_to(value, target):
    return abs(value - target) < 1e-3


def wait_for_stop(axis, timeout=30):
    """pymeasure's own wait (WS, then MD? until done), with a deadline."""
    deadline = time.monotonic() + timeout
    axis.write("WS0")
    while not axis.motion_done:
        check("waiting for the motion to end", time.monotonic() < deadline, f"axis {axis.axis}")
        time.sleep(0.05)


def main(device):
    adapter = SerialAdapter(device, baudrate=19200, timeout=2, write_termination="\r", read_termination="\r\n")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        esp = ESP300(adapter)
    version = esp.ask("VE?").strip()
    check("identification (VE?)", version.startswith("ESP30"), repr(version))
    esp.clear_errors()

    positions = [axis.position for axis in (esp.x, esp.y, esp.phi)]
    check("reading the positions (TP)", all(isinstance(p, float) for p in positions), repr(positions))
    x = esp.x
    check("the units (SN?)", x.units == "millimeter", repr(x.units))
    check("the software limits (SL?, SR?)", x.left_limit < 0 < x.right_limit, f"{x.left_limit}, {x.right_limit}")

    x.enable()
    check("enabling axis 1 (MO, MO?)", x.enabled)
    x.position = 3.0
    wait_for_stop(x)
    check("the move away from home", close_to(x.position, 3.0), repr(x.position))
    x.home(type=1)
    wait_for_stop(x)
    check("the home search (OR1)", close_to(x.position, 0.0), repr(x.position))

    x.position = 5.0
    wait_for_stop(x)
    check("the absolute move (PA)", close_to(x.position, 5.0), repr(x.position))
    x.write("PR-1.25")
    wait_for_stop(x)
    check("the relative move (PR)", close_to(x.position, 3.75), repr(x.position))
    x.define_position(10.0)
    check("defining the position (DH)", close_to(x.position, 10.0), repr(x.position))
    x.zero()
    check("zeroing (DH)", close_to(x.position, 0.0), repr(x.position))
    errors = esp.errors
    check("an error buffer empty after a clean run (TE?)", errors == [], repr(errors))

    esp.y.position = 1.0  # axis 2 was never enabled
    code = esp.error
    check("the error of a motor that is off (TE?)", code == 213, repr(code))
    check("an error read once", esp.error == 0)
    esp.write("4PA1")
    esp.write("1XY")
    errors = esp.errors
    kinds = [(type(e), e.message) for e in errors]
    expected = [(GeneralError, "AXIS NUMBER OUT OF RANGE"), (GeneralError, "COMMAND DOES NOT EXIST")]
    check("the errors of a wrong axis and an unknown command", kinds == expected, repr(kinds))
    esp.phi.position = 1.0
    errors = esp.errors
    check(
        "an axis error as pymeasure reads it",
        len(errors) == 1 and isinstance(errors[0], AxisError) and errors[0].message == "MOTOR NOT ENABLED",
        repr([str(e) for e in errors]),
    )

    x.disable()
    check("disabling axis 1 (MF)", not x.enabled)
    adapter.close()
    print("esp300 workflow ok")


if __name__ == "__main__":
    if len(sys.argv) != 2:
        raise SystemExit(__doc__)
    main(sys.argv[1])
