#!/usr/bin/python3
"""rostest: 1,000 malformed or hostile clouds on ~cloud_in, one after the other (each answered by
the node before the next is sent): NaN/Inf points, empty clouds, wrong and absurd frames, headers
promising billions of points, real arrays above ~max_points, fields outside the point, bad
datatypes and strides, random bytes, degenerate geometry. The node must answer every one (a
warning naming why it was ignored, or a new ~cloud when the cloud was usable), stay up, and plan a
good cloud afterwards."""
import json
import os
import random
import struct
import sys
import time
import unittest

import rosgraph
import rospy
import rostest
from rosgraph_msgs.msg import Log
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header
from std_srvs.srv import Trigger

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import shotcrete_test_utils as u  # noqa: E402

N_MESSAGES = 1000
MAX_POINTS = 50000  # ~max_points in hostile_messages.test
ANSWER_TIMEOUT_S = 60.0


def raw_msg(width, height, fields, point_step, row_step, data, frame="tunnel", big_endian=False):
    msg = PointCloud2()
    msg.header = Header(frame_id=frame, stamp=rospy.Time.now())
    msg.width, msg.height = width, height
    msg.fields = fields
    msg.point_step, msg.row_step = point_step, row_step
    msg.data = bytes(data)
    msg.is_bigendian = big_endian
    msg.is_dense = True
    return msg


def xyz_fields(datatype=PointField.FLOAT32, offsets=(0, 4, 8)):
    return [PointField(n, o, datatype, 1) for n, o in zip("xyz", offsets)]


class Hostile:
    """The hostile messages, drawn from kinds by a seeded generator."""

    def __init__(self, seed):
        self.rng = random.Random(seed)
        self.good = u.bay_points()

    def pts(self, n=None):
        pts = list(self.good)
        return pts if n is None else pts[:n]

    def kinds(self):
        r = self.rng
        return [
            ("nan", lambda: self.with_bad_values(float("nan"))),
            ("inf", lambda: self.with_bad_values(r.choice([float("inf"), float("-inf")]))),
            ("empty width", lambda: raw_msg(0, 1, xyz_fields(), 12, 0, b"")),
            ("empty height", lambda: raw_msg(r.randint(1, 10 ** 6), 0, xyz_fields(), 12, 12, b"\0" * 48)),
            ("wrong frame", lambda: u.cloud_msg(self.pts(), frame=r.choice(
                ["map", "", "TUNNEL", "tunnel ", "/tunnel", "x" * 10000, "t\u00fcnnel\u2603", "tunnel\0"]))),
            ("huge header", lambda: raw_msg(r.choice([2 ** 32 - 1, 2 ** 31, 10 ** 9]), r.choice([1, 2 ** 32 - 1, 7]),
                                            xyz_fields(), 12, r.choice([12, 2 ** 32 - 1, 0]), b"\0" * r.randint(0, 4096))),
            ("huge point_step", lambda: raw_msg(10, 1, xyz_fields(), 2 ** 32 - 1, 2 ** 32 - 1, b"\0" * 1200)),
            ("zero strides", lambda: raw_msg(100, 1, xyz_fields(), 0, 0, b"\0" * 1200)),
            ("row_step short", lambda: raw_msg(100, 2, xyz_fields(), 12, r.randint(0, 1199), b"\0" * 2400)),
            ("truncated", self.truncated),
            ("field outside point", lambda: raw_msg(100, 1, xyz_fields(offsets=(0, 4, r.choice([9, 12, 2 ** 32 - 4]))), 12, 1200,
                                                    b"\0" * 1200)),
            ("bad datatype", lambda: raw_msg(100, 1, xyz_fields(datatype=r.choice([0, 1, 2, 3, 4, 5, 6, 9, 255])), 12, 1200,
                                             b"\0" * 1200)),
            ("count zero / duplicates", self.odd_fields),
            ("missing field", lambda: raw_msg(100, 1, [f for f in xyz_fields() if f.name != r.choice("xyz")], 12, 1200,
                                              b"\0" * 1200)),
            ("big endian", lambda: raw_msg(100, 1, xyz_fields(), 12, 1200, b"\0" * 1200, big_endian=True)),
            ("random bytes", self.random_bytes),
            ("above max_points", lambda: raw_msg(MAX_POINTS + r.randint(1, 1000), 1, xyz_fields(), 12,
                                                 12 * (MAX_POINTS + 1000), b"\0" * (12 * (MAX_POINTS + 1000)))),
            ("big array", self.big_array),
            ("lying header", lambda: raw_msg(1000, 1, xyz_fields(), 12, 12000, os.urandom(r.choice([11999, 6000, 12])))),
            ("degenerate geometry", self.degenerate),
            ("millimetres or far away", self.scaled),
        ]

    def with_bad_values(self, value):
        pts = self.pts()
        for _ in range(self.rng.randint(1, 50)):
            i = self.rng.randrange(len(pts))
            p = list(pts[i])
            p[self.rng.randrange(3)] = value
            pts[i] = tuple(p)
        return u.cloud_msg(pts)

    def truncated(self):
        msg = u.cloud_msg(self.pts())
        msg.data = msg.data[: self.rng.randrange(len(msg.data))]
        return msg

    def odd_fields(self):
        fields = xyz_fields()
        if self.rng.random() < 0.5:
            fields[self.rng.randrange(3)].count = 0
        else:
            fields.append(PointField("x", 8, PointField.FLOAT32, 1))
        return raw_msg(100, 1, fields, 12, 1200, struct.pack("<300f", *([1.0] * 300)))

    def random_bytes(self):
        n = self.rng.randint(1, 3000)
        step = self.rng.choice([12, 16, 24])
        dtype = PointField.FLOAT64 if step == 24 else PointField.FLOAT32
        size = 8 if dtype == PointField.FLOAT64 else 4
        return raw_msg(n, 1, xyz_fields(dtype, (0, size, 2 * size)), step, n * step, os.urandom(n * step))

    def big_array(self):
        data = os.urandom(self.rng.randint(4, 16) * 2 ** 20)  # 4-16 MiB of random floats
        n = len(data) // 12
        return raw_msg(n, 1, xyz_fields(), 12, 12 * n, data)

    def degenerate(self):
        r = self.rng
        kind = r.randrange(4)
        if kind == 0:  # one point, repeated
            pts = [(1.0, 2.0, 5.0)] * r.randint(1, 5000)
        elif kind == 1:  # a line
            pts = [(0.001 * i, 0.0, 5.6) for i in range(r.randint(1, 3000))]
        elif kind == 2:  # a plane through the axis
            pts = [(0.01 * i, 0.0, 0.01 * j) for i in range(60) for j in range(60)]
        else:  # a few points
            pts = self.pts(r.randint(1, 20))
        return u.cloud_msg(pts)

    def scaled(self):
        s = self.rng.choice([1000.0, 1e-3, 1e6, 1e20, 1e37])  # float32 ends at 3.4e38
        off = self.rng.choice([0.0, 1e5, 1e12])
        return u.cloud_msg([(x * s + off, y * s, z * s) for x, y, z in self.pts()])

    def messages(self, n):
        kinds = self.kinds()
        for i in range(n):
            name, make = kinds[i % len(kinds)]
            yield name, make()


class HostileMessages(unittest.TestCase):
    def test_thousand_hostile_clouds(self):
        logs = u.Collector("/rosout", Log)
        clouds = u.Collector(u.NS + "/cloud", PointCloud2)
        rospy.wait_for_service(u.NS + "/plan", timeout=60)
        pub = rospy.Publisher(u.NS + "/cloud_in", PointCloud2, queue_size=10)
        time.sleep(1.0)  # let the node connect before the first message
        master = rosgraph.Master("/test")
        answers = {"ignored": 0, "accepted": 0}
        per_kind = {}
        t_start = time.time()
        for i, (name, msg) in enumerate(Hostile(seed=17).messages(N_MESSAGES)):
            with logs._lock:  # only answers to this message count
                logs.items = []
            with clouds._lock:
                clouds.items = []
            t = time.time()
            pub.publish(msg)
            end = t + ANSWER_TIMEOUT_S
            answer = None
            while answer is None and time.time() < end and not rospy.is_shutdown():
                if any(m.name == u.NS and "cloud on" in m.msg and "ignored" in m.msg for _, m in logs.snapshot()):
                    answer = "ignored"
                elif clouds.snapshot():
                    answer = "accepted"
                else:
                    time.sleep(0.002)
            self.assertIsNotNone(answer, "message %d (%s): no answer from the node in %.0f s" % (i, name, ANSWER_TIMEOUT_S))
            answers[answer] += 1
            if answer == "ignored":  # a reason, on one line, never a number printed past its type
                text = next(m.msg for _, m in logs.snapshot() if m.name == u.NS and "ignored" in m.msg)
                self.assertNotIn("\n", text, name)
                self.assertNotIn("-9,223,372", text, name)
                self.assertLess(len(text), 400, name)
            per_kind.setdefault(name, {}).setdefault(answer, 0)
            per_kind[name][answer] += 1
            if i % 100 == 99:
                self.assertIsNotNone(master.lookupService(u.NS + "/plan"), "node gone after message %d" % i)
        print("hostile clouds: %d in %.0f s, %s, per kind %s" % (N_MESSAGES, time.time() - t_start, answers, per_kind))
        self.assertEqual(sum(answers.values()), N_MESSAGES)
        # The kinds that can never be a usable cloud were all refused.
        for kind in ("nan", "inf", "empty width", "empty height", "wrong frame", "huge header", "huge point_step",
                     "zero strides", "row_step short", "truncated", "field outside point", "bad datatype",
                     "missing field", "big endian", "above max_points", "big array", "lying header"):
            self.assertEqual(per_kind[kind].get("accepted", 0), 0, "%s cloud accepted: %s" % (kind, per_kind[kind]))

        # Still plans: a good cloud is taken, planned and executed.
        t = time.time()
        pub.publish(u.cloud_msg(u.bay_points()))
        self.assertIsNotNone(clouds.wait(timeout=60, after=t), "good cloud not accepted after the hostile ones")
        res = rospy.ServiceProxy(u.NS + "/plan", Trigger)()
        self.assertTrue(res.success, res.message)
        self.assertGreater(json.loads(res.message)["passes"], 0)
        ex = rospy.ServiceProxy(u.NS + "/execute", Trigger)()
        self.assertTrue(ex.success, ex.message)


if __name__ == "__main__":
    rospy.init_node("test_hostile_messages")
    rostest.rosrun("shotcrete_ros", "hostile_messages", HostileMessages, sys.argv)
