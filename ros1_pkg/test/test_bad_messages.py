#!/usr/bin/python3
"""rostest: malformed clouds on ~cloud_in are logged with their reason and ignored; the node keeps
running, refuses to plan without a cloud, and plans a good cloud afterwards."""
import json
import math
import os
import struct
import sys
import time
import unittest

import rosgraph
import rospy
import rostest
from rosgraph_msgs.msg import Log
from sensor_msgs.msg import PointCloud2
from std_srvs.srv import Trigger

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import shotcrete_test_utils as u  # noqa: E402


class BadMessages(unittest.TestCase):
    def node_alive(self):
        return rosgraph.Master("/test").lookupService(u.NS + "/plan") is not None

    def wait_log(self, logs, text, after, timeout=20.0):
        m = logs.wait(lambda m: m.name == u.NS and text in m.msg, timeout=timeout, after=after)
        self.assertIsNotNone(m, "no log from %s containing %r" % (u.NS, text))
        return m

    def test_bad_clouds_are_ignored(self):
        logs = u.Collector("/rosout", Log)
        clouds = u.Collector(u.NS + "/cloud", PointCloud2)
        rospy.wait_for_service(u.NS + "/plan", timeout=60)
        plan = rospy.ServiceProxy(u.NS + "/plan", Trigger)
        res = plan()
        self.assertFalse(res.success)
        self.assertIn("no cloud yet", res.message)

        pub = rospy.Publisher(u.NS + "/cloud_in", PointCloud2, queue_size=10)
        time.sleep(1.0)  # let the node connect before the first message
        good = u.bay_points()
        nan = list(good)
        nan[7] = (float("nan"), nan[7][1], nan[7][2])
        inf = list(good)
        inf[3] = (inf[3][0], float("inf"), inf[3][2])
        truncated = u.cloud_msg(good)
        truncated.data = truncated.data[: len(truncated.data) // 2]
        float64 = u.cloud_msg([p + (0.0,) for p in good], fields=u.float_fields("x", "y", "intensity", "q"))
        mm = [(x * 1000.0, y * 1000.0, z * 1000.0) for x, y, z in good]
        cases = [
            ("empty", u.cloud_msg([]), "empty cloud"),
            ("nan", u.cloud_msg(nan), "NaN/Inf"),
            ("inf", u.cloud_msg(inf), "NaN/Inf"),
            ("missing z", u.cloud_msg([p[:2] + (0.0,) for p in good], fields=u.float_fields("x", "y", "intensity")),
             "missing field 'z'"),
            ("no xyz at all", float64, "missing field 'z'"),
            ("wrong frame", u.cloud_msg(good, frame="map"), "frame 'map'"),
            ("truncated data", truncated, "data holds"),
            ("millimetres", u.cloud_msg(mm), "ignored"),
        ]
        for name, msg, reason in cases:
            t = time.time()
            pub.publish(msg)
            log = self.wait_log(logs, reason, after=t)
            self.assertIn("ignored", log.msg, name)
            self.assertEqual(log.level, Log.WARN, name)
            self.assertTrue(self.node_alive(), "node gone after the %s cloud" % name)
        self.assertEqual(clouds.snapshot(), [], "a bad cloud reached ~cloud")
        res = plan()
        self.assertFalse(res.success, "planned without any good cloud")

        t = time.time()
        pub.publish(u.cloud_msg(good))
        self.assertIsNotNone(clouds.wait(timeout=60, after=t), "good cloud not accepted after bad ones")
        res = plan()
        self.assertTrue(res.success, res.message)
        self.assertGreater(json.loads(res.message)["passes"], 0)
        # ... and a bad cloud after a plan leaves the plan in place.
        t = time.time()
        pub.publish(u.cloud_msg(nan))
        self.wait_log(logs, "NaN/Inf", after=t)
        ex = rospy.ServiceProxy(u.NS + "/execute", Trigger)()
        self.assertTrue(ex.success, ex.message)


if __name__ == "__main__":
    rospy.init_node("test_bad_messages")
    rostest.rosrun("shotcrete_ros", "bad_messages", BadMessages, sys.argv)
