"""A ROS 2 peer as rmw_zenoh (Jazzy) speaks it, written here from rmw_zenoh_cpp 0.2.10's rules
with no zmotor code: it finds `zmotor ros2`'s node, publisher and subscription in the graph's
liveliness tokens, reads sensor_msgs/JointState samples (CDR decoded by hand, the 33-byte
attachment checked), and moves the joint by publishing a JointState on joint_commands.

Usage: python3 ros2_peer.py ENDPOINT JOINT
"""
import os
import struct
import sys
import time
import traceback

import zenoh
import zenoh.ext

JOINT_STATE = "sensor_msgs::msg::dds_::JointState_/RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e"
JOINT_TRAJECTORY = "trajectory_msgs::msg::dds_::JointTrajectory_/RIHS01_179b33eba59d676f6d967ac71fe35e7ca2f64b2f3928f4a018cec115e213796e"
# As `ros2 topic info -v` shows joint_trajectory_controller's ~/controller_state in Jazzy.
CONTROLLER_STATE = "control_msgs::msg::dds_::JointTrajectoryControllerState_/RIHS01_51d8dd89cc624cbe9daaeeb4d80d6de9b86168ffdc3be41fefc0953e3c26e480"


def ok(check):
    print("ok", check, flush=True)


def read_joint_state(payload):
    """sensor_msgs/JointState from little-endian CDR, alignment counted after the header."""
    assert payload[:4] == b"\x00\x01\x00\x00", payload[:4]
    body, at = payload[4:], 0

    def align(n):
        nonlocal at
        at += (-at) % n

    def u32():
        nonlocal at
        align(4)
        (value,) = struct.unpack_from("<I", body, at)
        at += 4
        return value

    def string():
        nonlocal at
        length = u32()
        text = body[at:at + length - 1].decode()
        at += length
        return text

    def doubles():
        nonlocal at
        count = u32()
        align(8) if count else None
        values = list(struct.unpack_from("<%dd" % count, body, at))
        at += 8 * count
        return values

    sec, nanosec = u32(), u32()
    frame = string()
    names = [string() for _ in range(u32())]
    return {"stamp": (sec, nanosec), "frame": frame, "name": names,
            "position": doubles(), "velocity": doubles(), "effort": doubles()}


def joint_command(name, position):
    """A JointState naming one joint and its target, as CDR."""
    out = bytearray(b"\x00\x01\x00\x00")
    body = bytearray()
    body += struct.pack("<iI", 0, 0)
    body += struct.pack("<I", 1) + b"\x00"          # frame_id ""
    body += b"\x00" * ((-len(body)) % 4)
    body += struct.pack("<I", 1)                     # one name
    encoded = name.encode() + b"\x00"
    body += struct.pack("<I", len(encoded)) + encoded
    body += b"\x00" * ((-len(body)) % 4)
    body += struct.pack("<I", 1)                     # one position
    body += b"\x00" * ((-len(body)) % 8)
    body += struct.pack("<d", position)
    body += struct.pack("<II", 0, 0)                 # no velocity, no effort
    return bytes(out + body)


def main():
    endpoint, joint = sys.argv[1], sys.argv[2]
    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", '["%s"]' % endpoint)
    config.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(config)

    deadline = time.time() + 20
    tokens = []
    while time.time() < deadline:
        tokens = [str(r.ok.key_expr) for r in session.liveliness().get("@ros2_lv/0/**") if r.ok]
        if any("/NN/%/%/zmotor" in t for t in tokens) and any("/MP/" in t and "/%joint_states/" in t for t in tokens) and any("/MS/" in t for t in tokens) and any("/%controller_state/" in t for t in tokens):
            break
        time.sleep(0.2)
    node = [t for t in tokens if "/NN/%/%/zmotor" in t]
    assert node and node[0].endswith("/NN/%/%/zmotor"), tokens
    publisher = [t for t in tokens if "/MP/" in t and "/%joint_states/" in t]
    assert len(publisher) == 1 and publisher[0].endswith("/%joint_states/" + JOINT_STATE + "/:1:,1:,:,:,,"), tokens
    assert any(t.endswith("/%joint_commands/" + JOINT_STATE + "/::,10:,:,:,,") for t in tokens if "/MS/" in t), tokens
    # joint_trajectory_controller's topics, with its SystemDefaultsQoS (rmw_zenoh's default depth, 42, left out).
    assert any(t.endswith("/%joint_trajectory/" + JOINT_TRAJECTORY + "/::,:,:,:,,") for t in tokens if "/MS/" in t), tokens
    assert any(t.endswith("/%controller_state/" + CONTROLLER_STATE + "/::,:,:,:,,") for t in tokens if "/MP/" in t), tokens
    ok("the graph shows the node zmotor, its joint_states and controller_state publishers, its joint_commands and joint_trajectory subscriptions")

    # A transient-local subscription, as rmw_zenoh declares one: the node publishes its state
    # only every 30 s at rest here, so a state within 5 s comes from the publisher's cache.
    states = []
    subscriber = zenoh.ext.declare_advanced_subscriber(
        session, "0/joint_states/" + JOINT_STATE,
        handler=lambda s: states.append((bytes(s.attachment.to_bytes()) if s.attachment else b"",
                                         read_joint_state(bytes(s.payload.to_bytes())))),
        history=zenoh.ext.HistoryConfig(detect_late_publishers=True, max_samples=1),
        recovery=zenoh.ext.RecoveryConfig(heartbeat=True),
        subscriber_detection=True)
    deadline = time.time() + 5
    while not states and time.time() < deadline:
        time.sleep(0.05)
    assert states, "no joint state within 5 s: the late subscriber got nothing from the cache"
    attachment, first = states[-1]
    assert len(attachment) == 33 and attachment[16] == 16, attachment.hex()
    assert first["name"] == [joint] and len(first["position"]) == 1, first
    ok("a late transient-local subscriber gets the last joint state; CDR and attachment as rmw_zenoh lays them out")

    start = first["position"][0]
    target = start + 0.003  # metres: 3 mm more
    seq = 1
    gid = bytes(16)
    attachment = struct.pack("<qq", seq, time.time_ns()) + bytes([16]) + gid
    session.put("0/joint_commands/" + JOINT_STATE, joint_command(joint, target), attachment=attachment)
    deadline = time.time() + 15
    seen_moving = False
    while time.time() < deadline:
        _, last = states[-1]
        seen_moving |= any(abs(s["velocity"][0]) > 0 for _, s in states[-5:] if s["velocity"])
        if abs(last["position"][0] - target) < 1e-6:
            break
        time.sleep(0.05)
    assert abs(states[-1][1]["position"][0] - target) < 1e-6, (target, states[-1][1])
    assert seen_moving, "a velocity while it moved"
    ok("a joint command moved the axis to its target, seen on joint_states")
    subscriber.undeclare()
    session.close()
    print("ros2 peer ok", flush=True)


# A failed check must end the process at once: an open Zenoh session keeps it alive.
try:
    main()
except BaseException:
    traceback.print_exc()
    sys.stderr.flush()
    os._exit(1)
os._exit(0)
