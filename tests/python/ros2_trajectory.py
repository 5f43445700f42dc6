"""A ROS 2 action client and topic peer as rmw_zenoh (Jazzy) speaks them, written here from
rmw_zenoh_cpp 0.2.10's rules and the .msg/.action definitions with no zmotor code: it finds the
node's endpoints in the graph, moves two joints with one joint command, then calls the
control_msgs/action/FollowJointTrajectory action: a three-point trajectory to its result, goals
it must reject, a MoveIt-shaped one of many close waypoints on a line (each joint moved once, not
stopped at every point: counted on the axes' DMOV keys of zmotor's wire contract, the joints being
axes m1 and m2 of launch/ros2-joints.toml) and two such lines with a corner (each joint moved
twice), one replaced by the next, and a long one cancelled half way. CDR is written and read by
hand.

Usage: python3 ros2_trajectory.py ENDPOINT NAMESPACE
"""
import math
import os
import struct
import sys
import threading
import time
import traceback

import zenoh

JAZZY = {
    "JointState": "sensor_msgs::msg::dds_::JointState_/RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e",
    "SendGoal": "control_msgs::action::dds_::FollowJointTrajectory_SendGoal_/RIHS01_b13789dddc325a7a962825c45e28c77d37237ec129dd0c34dc5994562938c57f",
    "GetResult": "control_msgs::action::dds_::FollowJointTrajectory_GetResult_/RIHS01_e3ceb38e3e1867c8dc0f46014df26e90eb93422f27e9e97f936e07f94be4bc8b",
    "CancelGoal": "action_msgs::srv::dds_::CancelGoal_/RIHS01_573d8b0a534451d7bc2ac8c5ffde8ac14b8593b7001175d0cd6516dcbeb8689a",
    "Feedback": "control_msgs::action::dds_::FollowJointTrajectory_FeedbackMessage_/RIHS01_80398fcb9674a79081a9906e2ccf0c804dd7cb15e22e362e606ee87186beab71",
    "Status": "action_msgs::msg::dds_::GoalStatusArray_/RIHS01_6c1684b00f177d37438febe6e709fc4e2b0d4248dca4854946f9ed8b30cda83e",
    "JointTrajectory": "trajectory_msgs::msg::dds_::JointTrajectory_/RIHS01_179b33eba59d676f6d967ac71fe35e7ca2f64b2f3928f4a018cec115e213796e",
    "ControllerState": "control_msgs::msg::dds_::JointTrajectoryControllerState_/RIHS01_51d8dd89cc624cbe9daaeeb4d80d6de9b86168ffdc3be41fefc0953e3c26e480",
}
SUCCEEDED, CANCELED, ABORTED = 4, 5, 6
# Within a step and a half of each axis (MRES 0.001 mm and 0.001°), in SI.
RESOLUTION = {"lift": 1.5e-6, "turn": 2.7e-5}


def ok(check):
    print("ok", check, flush=True)


class Writer:
    """Little-endian CDR, alignment counted from after the 4-byte encapsulation header."""

    def __init__(self):
        self.body = bytearray()

    def align(self, n):
        self.body += b"\x00" * ((-len(self.body)) % n)

    def put(self, fmt, *values):
        self.align(struct.calcsize("<" + fmt[0]))
        self.body += struct.pack("<" + fmt, *values)

    def string(self, text):
        data = text.encode() + b"\x00"
        self.put("I", len(data))
        self.body += data

    def strings(self, texts):
        self.put("I", len(texts))
        for text in texts:
            self.string(text)

    def doubles(self, values):
        self.put("I", len(values))
        for value in values:
            self.put("d", value)

    def header(self):
        self.put("iI", 0, 0)
        self.string("")

    def bytes(self):
        return b"\x00\x01\x00\x00" + bytes(self.body)


class Reader:
    def __init__(self, payload):
        assert payload[:4] == b"\x00\x01\x00\x00", payload[:4]
        self.body, self.at = payload[4:], 0

    def get(self, fmt):
        size = struct.calcsize("<" + fmt[0])
        self.at += (-self.at) % size
        values = struct.unpack_from("<" + fmt, self.body, self.at)
        self.at += struct.calcsize("<" + fmt)
        return values if len(values) > 1 else values[0]

    def raw(self, n):
        data = self.body[self.at:self.at + n]
        self.at += n
        return data

    def string(self):
        n = self.get("I")
        return self.raw(n)[:-1].decode()

    def doubles(self):
        return [self.get("d") for _ in range(self.get("I"))]


def joint_state(payload):
    r = Reader(payload)
    r.get("iI")
    r.string()
    names = [r.string() for _ in range(r.get("I"))]
    return {"name": names, "position": r.doubles(), "velocity": r.doubles()}


def goal_statuses(payload):
    """action_msgs/GoalStatusArray: each goal's id and status."""
    r = Reader(payload)
    statuses = {}
    for _ in range(r.get("I")):
        goal_id = bytes(r.raw(16))
        r.get("iI")
        statuses[goal_id] = r.get("b")
    return statuses


def write_trajectory(w, names, points):
    """trajectory_msgs/JointTrajectory, field for field."""
    w.header()
    w.strings(names)
    w.put("I", len(points))
    for point in points:
        seconds, positions = point[0], point[1]
        w.doubles(positions)
        w.doubles(point[2] if len(point) > 2 else [])  # velocities
        w.doubles([])                   # accelerations
        w.doubles([])                   # effort
        w.put("iI", int(seconds), int(round((seconds % 1) * 1e9)))


def goal_request(goal_id, names, points):
    """FollowJointTrajectory_SendGoal request: the goal id, then the Goal, field for field."""
    w = Writer()
    w.body += goal_id
    write_trajectory(w, names, points)
    w.header()                          # multi_dof_trajectory.header
    w.strings([])
    w.put("I", 0)                       # its points
    for _ in range(4):                  # path, component path, goal, component goal tolerances
        w.put("I", 0)
    w.put("iI", 0, 0)                   # goal_time_tolerance
    return w.bytes()


class Client:
    """Service calls as rmw_zenoh's clients make them: a query carrying the request and the
    33-byte attachment (sequence number, time, the client's GID)."""

    def __init__(self, session, prefix):
        self.session, self.prefix, self.sequence = session, prefix, 0
        self.gid = os.urandom(16)

    def call(self, service, payload, timeout=10.0):
        self.sequence += 1
        attachment = struct.pack("<qq", self.sequence, time.time_ns()) + bytes([16]) + self.gid
        key = "%s/follow_joint_trajectory/_action/%s/%s" % (self.prefix, service.lower(), JAZZY[self.type_of(service)])
        replies = list(self.session.get(key, payload=payload, attachment=attachment,
                                        target=zenoh.QueryTarget.ALL_COMPLETE, timeout=timeout))
        answers = [r.ok for r in replies if r.ok is not None]
        assert len(answers) == 1, (service, replies)
        reply = bytes(answers[0].attachment.to_bytes())
        assert len(reply) == 33 and struct.unpack_from("<q", reply)[0] == self.sequence and reply[17:] == self.gid, reply.hex()
        return Reader(bytes(answers[0].payload.to_bytes()))

    @staticmethod
    def type_of(service):
        return {"send_goal": "SendGoal", "get_result": "GetResult", "cancel_goal": "CancelGoal"}[service]

    def send_goal(self, goal_id, names, points):
        r = self.call("send_goal", goal_request(goal_id, names, points))
        return bool(r.get("B"))

    def get_result(self, goal_id, timeout):
        r = self.call("get_result", Writer_with(goal_id), timeout)
        status = r.get("b")
        code = r.get("i")
        return status, code, r.string()

    def cancel(self, goal_id):
        w = Writer()
        w.body += goal_id
        w.put("iI", 0, 0)
        r = self.call("cancel_goal", w.bytes())
        code = r.get("b")
        canceling = []
        for _ in range(r.get("I")):
            canceling.append(bytes(r.raw(16)))
            r.get("iI")
        return code, canceling


def Writer_with(goal_id):
    w = Writer()
    w.body += goal_id
    return w.bytes()


def main():
    endpoint, namespace = sys.argv[1], sys.argv[2]
    prefix = "0" + namespace
    config = zenoh.Config()
    config.insert_json5("mode", '"client"')
    config.insert_json5("connect/endpoints", '["%s"]' % endpoint)
    config.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(config)

    ns = namespace.replace("/", "%")
    wanted = ["/NN/%/" + ns + "/zmotor"] + [
        "/SS/%%/%s/zmotor/%s%%follow_joint_trajectory%%_action%%%s/%s/::,10:,:,:,," % (ns, ns, s, JAZZY[t])
        for s, t in [("send_goal", "SendGoal"), ("get_result", "GetResult"), ("cancel_goal", "CancelGoal")]
    ] + [
        "/MP/%%/%s/zmotor/%s%%follow_joint_trajectory%%_action%%feedback/%s/::,10:,:,:,," % (ns, ns, JAZZY["Feedback"]),
        "/MP/%%/%s/zmotor/%s%%follow_joint_trajectory%%_action%%status/%s/:1:,1:,:,:,," % (ns, ns, JAZZY["Status"]),
        "/MP/%%/%s/zmotor/%s%%joint_states/%s/:1:,1:,:,:,," % (ns, ns, JAZZY["JointState"]),
        # joint_trajectory_controller's topics, SystemDefaultsQoS: rmw_zenoh's default depth (42), left out.
        "/MS/%%/%s/zmotor/%s%%joint_trajectory/%s/::,:,:,:,," % (ns, ns, JAZZY["JointTrajectory"]),
        "/MP/%%/%s/zmotor/%s%%controller_state/%s/::,:,:,:,," % (ns, ns, JAZZY["ControllerState"]),
    ]
    deadline, tokens = time.time() + 20, []
    while time.time() < deadline:
        tokens = [str(r.ok.key_expr) for r in session.liveliness().get("@ros2_lv/0/**") if r.ok]
        if all(any(t.endswith(w) for t in tokens) for w in wanted):
            break
        time.sleep(0.2)
    missing = [w for w in wanted if not any(t.endswith(w) for t in tokens)]
    assert not missing, (missing, tokens)
    ok("the graph shows the node, its joint_states (transient local), joint_trajectory, controller_state and the action's services and topics")

    states, feedback, statuses = [], [], []
    lock = threading.Lock()

    def on_state(sample):
        with lock:
            states.append(joint_state(bytes(sample.payload.to_bytes())))

    dmov_posts = {"m1": 0, "m2": 0}

    def on_dmov(sample):
        with lock:
            dmov_posts[str(sample.key_expr).split("/")[1]] += 1

    subscribers = [
        session.declare_subscriber("motor/%s/DMOV" % axis, on_dmov) for axis in dmov_posts
    ] + [
        session.declare_subscriber(prefix + "/joint_states/" + JAZZY["JointState"], on_state),
        session.declare_subscriber(prefix + "/follow_joint_trajectory/_action/feedback/" + JAZZY["Feedback"],
                                   lambda s: feedback.append(bytes(s.payload.to_bytes())[4:20])),
        session.declare_subscriber(prefix + "/follow_joint_trajectory/_action/status/" + JAZZY["Status"],
                                   lambda s: statuses.append(bytes(s.payload.to_bytes()))),
    ]

    def dmov_settled():
        """Once every DMOV 0 counted has had its DMOV 1 (the last may come after the readbacks
        settle), the counts start again."""
        deadline = time.time() + 5
        while time.time() < deadline:
            with lock:
                if all(n % 2 == 0 for n in dmov_posts.values()):
                    dmov_posts.update({"m1": 0, "m2": 0})
                    return
            time.sleep(0.05)
        raise AssertionError("a move without its end: %s" % dmov_posts)

    def dmov_posts_reaching(expected):
        """The DMOV posts counted, once they are `expected` (the last DMOV 1 may come after the
        result) or 2 s have passed."""
        deadline = time.time() + 2
        while time.time() < deadline:
            with lock:
                if dmov_posts == expected:
                    break
            time.sleep(0.05)
        with lock:
            return dict(dmov_posts)

    def last():
        deadline = time.time() + 10
        while time.time() < deadline:
            with lock:
                if states:
                    return dict(zip(states[-1]["name"], states[-1]["position"]))
            time.sleep(0.05)
        raise AssertionError("no joint state within 10 s")

    def settle(targets, within):
        deadline = time.time() + within
        while time.time() < deadline:
            now = last()
            if all(abs(now[j] - p) < RESOLUTION[j] for j, p in targets.items()):
                return now
            time.sleep(0.05)
        raise AssertionError("joints at %s, not %s" % (last(), targets))

    # Two axes moved by one joint command: 2 mm and 0.1 rad.
    w = Writer()
    w.header()
    w.strings(["lift", "turn"])
    w.doubles([0.002, 0.1])
    w.doubles([])
    w.doubles([])
    attachment = struct.pack("<qq", 1, time.time_ns()) + bytes([16]) + os.urandom(16)
    session.put(prefix + "/joint_commands/" + JAZZY["JointState"], w.bytes(), attachment=attachment)
    settle({"lift": 0.002, "turn": 0.1}, 15)
    ok("one joint command moved both joints")

    client = Client(session, prefix)
    # Goals that cannot run are rejected and move nothing.
    assert not client.send_goal(os.urandom(16), ["lift", "wrist"], [(1.0, [0.0, 0.0])])
    assert not client.send_goal(os.urandom(16), ["lift"], [(1.0, [0.5])]), "0.5 m is beyond the 100 mm soft limit"
    ok("goals naming an unknown joint or beyond the soft limits are rejected")

    def moving_away(joint, by):
        """Once `joint` has moved `by` (m) from where it is now: its move is under way."""
        start = last()[joint]
        deadline = time.time() + 10
        while time.time() < deadline:
            if abs(last()[joint] - start) >= by:
                return
            time.sleep(0.05)
        raise AssertionError("%s did not move from %s" % (joint, start))

    def run_to_success(names, points, targets):
        """A goal of `points`, sent and waited for to SUCCEEDED, the joints settled at `targets`:
        its id and how long it took."""
        goal = os.urandom(16)
        started = time.time()
        assert client.send_goal(goal, names, points)
        status, code, text = client.get_result(goal, timeout=60)
        took = time.time() - started
        assert (status, code) == (SUCCEEDED, 0), (status, code, text)
        settle(targets, 5)
        return goal, took

    # Three points in time order, to the result.
    points = [(1.0, [0.004, 0.3]), (2.0, [0.008, 0.6]), (3.0, [0.005, 0.9])]
    goal, took = run_to_success(["lift", "turn"], points, {"lift": 0.005, "turn": 0.9})
    assert 2.5 < took < 20, took
    assert goal in feedback, "feedback for the goal while it moved"
    with lock:
        lifts = [s["position"][s["name"].index("lift")] for s in states]
    assert max(lifts) > 0.0079, "the lift passed through its second point (8 mm) before its last (5 mm)"
    deadline = time.time() + 5
    while time.time() < deadline and not (statuses and goal_statuses(statuses[-1]).get(goal) == SUCCEEDED):
        time.sleep(0.05)
    assert statuses and goal_statuses(statuses[-1]).get(goal) == SUCCEEDED, statuses[-1:]
    ok("a three-point trajectory ran in %.1f s to SUCCEEDED, with feedback and status" % took)

    # A trajectory on the topic, as joint_trajectory_controller takes one: the joints follow it.
    w = Writer()
    write_trajectory(w, ["lift", "turn"], [(0.5, [0.007, 0.8]), (1.0, [0.008, 0.7])])
    attachment = struct.pack("<qq", 1, time.time_ns()) + bytes([16]) + os.urandom(16)
    session.put(prefix + "/joint_trajectory/" + JAZZY["JointTrajectory"], w.bytes(), attachment=attachment)
    settle({"lift": 0.008, "turn": 0.7}, 15)
    ok("a trajectory on joint_trajectory moved both joints")

    # As MoveIt plans it: 30 waypoints 0.1 s apart, each joint easing one way (a cosine ramp,
    # velocities given, 0 at both ends). The motor record stops at the end of each move: each
    # joint is to make one move, not thirty.
    # (The DMOV subscribers, declared at the start, have heard the moves before: they reach the node.)
    with lock:
        assert dmov_posts["m1"] > 0 and dmov_posts["m2"] > 0, dmov_posts
    dmov_settled()
    ease = [(1 - math.cos(math.pi * i / 30)) / 2 for i in range(31)]
    slope = [math.pi / 2 * math.sin(math.pi * i / 30) / 3.0 for i in range(31)]
    # The first point is where the joints are, as MoveIt starts its plans from the joint states.
    start = last()
    lift, turn = start["lift"], start["turn"]
    planned = [(0.1 * i, [lift + (0.015 - lift) * e, turn + (0.3 - turn) * e], [(0.015 - lift) * v, (0.3 - turn) * v])
               for i, (e, v) in enumerate(zip(ease, slope))]
    _, took = run_to_success(["lift", "turn"], planned, {"lift": 0.015, "turn": 0.3})
    posts = dmov_posts_reaching({"m1": 2, "m2": 2})
    assert posts == {"m1": 2, "m2": 2}, "one move a joint (DMOV 0, then 1), not one a waypoint: %s" % posts
    ok("a 31-waypoint trajectory ran as one move a joint in %.1f s (planned 3.0 s)" % took)

    # Two lines of ten waypoints with a corner between them where neither joint turns back: the
    # corner is kept (a joint moves twice), not cut by one move a joint.
    dmov_settled()
    corner = [(0.1 * i, [0.015 + 0.001 * i, 0.3 + 0.005 * i]) for i in range(1, 11)]
    corner += [(1.0 + 0.1 * i, [0.025 + 0.0005 * i, 0.35 + 0.025 * i]) for i in range(1, 11)]
    run_to_success(["lift", "turn"], corner, {"lift": 0.030, "turn": 0.6})
    posts = dmov_posts_reaching({"m1": 4, "m2": 4})
    assert posts == {"m1": 4, "m2": 4}, "two moves a joint, one a line: %s" % posts
    ok("a path with a corner ran as two moves a joint, the corner kept")

    # A goal sent while another runs replaces it, as joint_trajectory_controller does: the first
    # ends ABORTED (INVALID_GOAL), the second runs from where the lift stopped.
    first, second = os.urandom(16), os.urandom(16)
    with lock:
        states.clear()
    assert client.send_goal(first, ["lift"], [(20.0, [0.050])])
    moving_away("lift", 0.0005)
    replaced = time.time()
    assert client.send_goal(second, ["lift"], [(1.0, [0.020])])
    status, code, text = client.get_result(first, timeout=30)
    # It stopped at once: ended within seconds (left alone it would run on for 19 s).
    assert time.time() - replaced < 5, time.time() - replaced
    assert (status, code, text) == (ABORTED, -1, "Current goal preempted by new incoming action."), (status, code, text)
    status, code, text = client.get_result(second, timeout=30)
    assert (status, code) == (SUCCEEDED, 0), (status, code, text)
    settle({"lift": 0.020}, 5)
    with lock:
        highest = max(s["position"][s["name"].index("lift")] for s in states)
    assert highest < 0.035, "the first goal was stopped on its way to 50 mm: %s" % highest
    ok("a goal sent while another ran replaced it (ABORTED, INVALID_GOAL) and ran to SUCCEEDED")

    # A long goal, cancelled on the way: the joints stop short.
    goal = os.urandom(16)
    assert client.send_goal(goal, ["lift"], [(20.0, [0.050])])
    moving_away("lift", 0.0005)
    code, canceling = client.cancel(goal)
    assert code == 0 and canceling == [goal], (code, canceling)
    status, code, text = client.get_result(goal, timeout=30)
    assert status == CANCELED, (status, code, text)
    time.sleep(1.0)  # the last readbacks of the deceleration
    stopped = last()["lift"]
    time.sleep(1.0)
    assert 0.005 < stopped < 0.04 and abs(last()["lift"] - stopped) < 1e-6, stopped
    ok("a cancelled goal stopped the joint at %.4f m, short of 0.05" % stopped)

    for subscriber in subscribers:
        subscriber.undeclare()
    session.close()
    print("ros2 trajectory peer ok", flush=True)


# A failed check must end the process at once: an open Zenoh session keeps it alive.
try:
    main()
except BaseException:
    traceback.print_exc()
    sys.stderr.flush()
    os._exit(1)
os._exit(0)
