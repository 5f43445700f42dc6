"""A PI user's workflow through PI's own Python library (pipython) against `zmotor sim-controller
pi_gcs2`: identify, servo on, reference and wait, move absolute and relative and wait, read
positions and on-target states, halt, and the documented refusals (GCSError 5 for a move of an
unreferenced axis, 7 for a target beyond the travel range).

Usage: pi_workflow.py HOST PORT. Prints "pi workflow ok" and exits 0, or exits non-zero saying
which expectation broke.

pipython's GCSDevice() alone connects through PI's GCS shared library (libpi_pi_gcs2.so), which
is not free software and not installed here; GCSDevice(gateway=PISocket(host, port)) is
pipython's own TCP path to the same controller, and the same GCSDevice API from there on.
"""

import sys

from pipython import GCSDevice, GCSError, pitools
from pipython.pidevice.interfaces.pisocket import PISocket


def expect(condition, what):
    if not condition:
        sys.exit(f"pi workflow: {what}")


def expect_error(code, what, call, *args):
    try:
        call(*args)
    except GCSError as error:
        expect(error.val == code, f"{what}: GCSError {error.val} ({error}), not {code}")
        return
    sys.exit(f"pi workflow: {what}: no GCSError {code}")


def main(host, port):
    # Closing the device closes its gateway too.
    with GCSDevice(gateway=PISocket(host=host, port=port)) as pidevice:
        idn = pidevice.qIDN()
        expect("Physik Instrumente" in idn and "C-884" in idn, f"qIDN: {idn!r}")
        expect(pidevice.qCSV() == 2.0, "qCSV is 2.0 (GCS 2)")
        axes = pidevice.qSAI()
        expect(len(axes) >= 2 and axes[0] == "1", f"qSAI: {axes}")
        expect(pidevice.HasqFRF() and pidevice.HasIsControllerReady(), "HLP? lists FRF? and #7")
        axis, other = axes[0], axes[1]

        # Power-up: servo off, unreferenced; a move is refused with 5.
        expect(pidevice.qSVO(axis)[axis] is False, "servo off at power-up")
        expect(pidevice.qFRF(axis)[axis] is False, "unreferenced at power-up")
        pidevice.SVO([axis, other], [True, True])
        expect(pidevice.qSVO(axis)[axis] is True, "servo on after SVO")
        expect_error(5, "MOV of an unreferenced axis", pidevice.MOV, axis, 1.0)

        # Reference both axes at their reference switch.
        pidevice.FRF([axis, other])
        pitools.waitonreferencing(pidevice, [axis, other], timeout=60)
        expect(all(pidevice.qFRF([axis, other]).values()), "referenced after FRF")
        expect(abs(pidevice.qPOS(axis)[axis]) < 1e-6, "0 at the reference switch")

        # The travel range and a target beyond it.
        low, high = pidevice.qTMN(axis)[axis], pidevice.qTMX(axis)[axis]
        expect(low < 0 < high, f"travel range {low}..{high}")
        expect_error(7, "MOV beyond TMX", pidevice.MOV, axis, high + 1.0)
        counts = pidevice.qSPA(axis, 0xE)[axis]
        expect(list(counts.values()) == [10000], f"counts per unit (SPA? 0xE): {counts}")

        # Absolute and relative moves, waited for.
        pidevice.VEL(axis, 10.0)
        pidevice.MOV(axis, 2.5)
        pitools.waitontarget(pidevice, axis, timeout=60)
        expect(abs(pidevice.qPOS(axis)[axis] - 2.5) < 1e-4, f"at 2.5: {pidevice.qPOS(axis)}")
        expect(pidevice.qONT(axis)[axis] is True, "on target after MOV")
        pidevice.MVR(axis, -1.0)
        pitools.waitontarget(pidevice, axis, timeout=60)
        expect(abs(pidevice.qPOS(axis)[axis] - 1.5) < 1e-4, f"at 1.5: {pidevice.qPOS(axis)}")

        # A long move halted: error 10, stopped short of its target.
        pidevice.VEL(axis, 1.0)
        pidevice.MOV(axis, 15.0)
        expect(pidevice.IsMoving(axis)[axis], "#5 shows the axis moving")
        expect_error(10, "HLT", pidevice.HLT, axis)
        pitools.waitonready(pidevice)
        position = pidevice.qPOS(axis)[axis]
        expect(1.5 < position < 15.0, f"halted between: {position}")
        expect(pidevice.qERR() == 0, "the error was read and reset")
    print("pi workflow ok")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit("usage: pi_workflow.py HOST PORT")
    main(sys.argv[1], int(sys.argv[2]))
