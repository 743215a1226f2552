#!/usr/bin/python3
"""rostest: plan_only.launch plans the synthetic bay at startup and publishes the summary, the
passes, the levels, the TD cloud and the clearance markers without anybody calling a service."""
import json
import os
import sys
import unittest

import rospy
import rostest
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import String
from visualization_msgs.msg import MarkerArray

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import shotcrete_test_utils as u  # noqa: E402


class PlanOnly(unittest.TestCase):
    def test_plans_at_startup(self):
        summary = u.Collector(u.NS + "/summary", String)
        passes = u.Collector(u.NS + "/passes", MarkerArray)
        levels = u.Collector(u.NS + "/grid_levels", MarkerArray)
        clouds = u.Collector(u.NS + "/cloud", PointCloud2)
        clearance = u.Collector(u.NS + "/clearance", MarkerArray)
        s = summary.wait(timeout=90)
        self.assertIsNotNone(s, "no plan summary")
        report = json.loads(s.data)  # the job summary, as in report.json
        # Finished: flush (graded) or levelled (optimal mode), every cell at level 0 or below.
        self.assertRegex(report["stop_reason"], r"^(flush|levelled)")
        after = report["levels_after"]
        self.assertTrue(after and all(int(level) <= 0 for level in after), after)
        self.assertIsNotNone(passes.wait(lambda m: any(k.ns == "passes" and k.points for k in m.markers), 10))
        self.assertIsNotNone(levels.wait(lambda m: any(k.points for k in m.markers), 10))
        # One closest-point marker per link of report.json's clearance, red exactly where a link is
        # closer than its margin; every link's shapes drawn at the posture of its least distance.
        links = report["clearance"]["links"]
        m = clearance.wait(lambda m: any(k.ns == "clearance_closest" for k in m.markers), 10)
        self.assertIsNotNone(m, "no clearance markers")
        dots = sorted((k for k in m.markers if k.ns == "clearance_closest"), key=lambda k: k.id)
        self.assertEqual(len(dots), len(links))
        for dot, link in zip(dots, links):
            self.assertEqual(dot.color.r > 0.5, link["min_m"] < link["margin_m"], link)
            self.assertAlmostEqual(dot.pose.position.x, link["closest_m"][0], places=6)
        self.assertGreaterEqual(sum(k.ns == "clearance_links" for k in m.markers), len(links))
        c = clouds.wait(timeout=10)
        self.assertIsNotNone(c)
        self.assertGreater(c.width * c.height, 1000)


if __name__ == "__main__":
    rospy.init_node("test_plan_only")
    rostest.rosrun("shotcrete_ros", "plan_only", PlanOnly, sys.argv)
