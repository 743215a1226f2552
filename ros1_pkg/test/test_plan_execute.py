#!/usr/bin/python3
"""rostest: a real master and shotcrete_node. Publish a small bay, call ~plan, check the markers and
the summary; call ~execute, check /joint_states (rate, names, limits, motion) and that the
republished cloud's TD goes down."""
import json
import math
import os
import sys
import time
import unittest

import rospy
import rostest
from sensor_msgs.msg import JointState, PointCloud2
from std_msgs.msg import String
from std_srvs.srv import Trigger
from visualization_msgs.msg import Marker, MarkerArray

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import shotcrete_test_utils as u  # noqa: E402


class PlanExecute(unittest.TestCase):
    def test_plan_then_execute(self):
        clouds = u.Collector(u.NS + "/cloud", PointCloud2)
        levels = u.Collector(u.NS + "/grid_levels", MarkerArray)
        passes = u.Collector(u.NS + "/passes", MarkerArray)
        summary = u.Collector(u.NS + "/summary", String)
        joints = u.Collector("/joint_states", JointState)
        rospy.wait_for_service(u.NS + "/plan", timeout=60)
        pub = rospy.Publisher(u.NS + "/cloud_in", PointCloud2, queue_size=1, latch=True)
        points = u.bay_points()
        pub.publish(u.cloud_msg(points))

        first = clouds.wait(timeout=60)
        self.assertIsNotNone(first, "no cloud on ~cloud after publishing one on ~cloud_in")
        xyz, td = u.cloud_arrays(first)
        self.assertGreater(len(xyz), 0.9 * len(points))  # the outlier filter may drop a few
        # TD = r - r_design, checked against the coordinates themselves (float32 precision).
        for (x, y, z), t in zip(xyz, td):
            self.assertAlmostEqual(t, math.hypot(y, z) - u.R_DESIGN_M, delta=2e-4)
        self.assertGreater(min(td), 0.09)  # every point has over-break to fill

        lv = levels.wait(lambda m: any(k.type == Marker.CUBE_LIST and k.points for k in m.markers), timeout=10)
        self.assertIsNotNone(lv, "no grid level markers")

        plan = rospy.ServiceProxy(u.NS + "/plan", Trigger)()
        self.assertTrue(plan.success, plan.message)
        report = json.loads(plan.message)  # the job summary, as in report.json
        for key in ("rounds", "passes", "spray_time_s", "levels_before", "levels_after", "residual_mm", "ik"):
            self.assertIn(key, report)
        self.assertGreater(report["passes"], 0)
        self.assertGreater(report["spray_time_s"], 0.0)
        self.assertTrue(report["ik"]["solved"], report["ik"])
        self.assertGreaterEqual(report["total_time_s"], report["spray_time_s"])
        self.assertEqual(report["points_in"], len(points))
        self.assertGreater(report["trajectory"]["samples"], 0)

        def has_passes(m):
            return any(k.ns == "passes" and k.points for k in m.markers)
        pm = passes.wait(has_passes, timeout=10)
        self.assertIsNotNone(pm, "no pass markers after ~plan")
        for k in pm.markers:
            if k.ns == "passes":
                self.assertEqual(len(k.colors), len(k.points))  # one speed colour per vertex
        self.assertTrue(any(k.ns == "regions" and k.points for k in pm.markers), "no region outlines")
        sm = summary.wait(lambda m: m.data == plan.message, timeout=5)
        self.assertIsNotNone(sm, "~summary does not carry the plan summary")
        self.assertEqual(json.loads(sm.data), report)

        n_clouds = len(clouds.snapshot())
        n_levels = len(levels.snapshot())
        limits = u.urdf_limits(rospy.get_param("~urdf"))
        t_call = time.time()
        ex = rospy.ServiceProxy(u.NS + "/execute", Trigger)()
        t_ret = time.time()
        self.assertTrue(ex.success, ex.message)
        time.sleep(0.5)

        during = [(t, m) for t, m in joints.snapshot() if t_call <= t <= t_ret]
        self.assertGreater(len(during), 20, "too few joint states during execution")
        rate = (len(during) - 1) / (during[-1][0] - during[0][0])
        self.assertGreaterEqual(rate, 30.0, "joint states at %.1f Hz" % rate)
        self.assertEqual(set(during[0][1].name), set(limits))
        spans = {n: [math.inf, -math.inf] for n in limits}
        for _, m in during:
            for n, q in zip(m.name, m.position):
                lo, hi = limits[n]
                self.assertTrue(lo - 1e-6 <= q <= hi + 1e-6, "%s = %.4f outside [%.3f, %.3f]" % (n, q, lo, hi))
                spans[n][0] = min(spans[n][0], q)
                spans[n][1] = max(spans[n][1], q)
        self.assertGreater(max(hi - lo for lo, hi in spans.values()), 0.05, "the arm did not move")

        after = [m for _, m in clouds.snapshot()[n_clouds:]]
        self.assertGreaterEqual(len(after), 2, "cloud not republished during execution")
        td_first = u.cloud_arrays(first)[1]
        means = [sum(u.cloud_arrays(m)[1]) / len(td_first) for m in after]
        self.assertLess(means[-1], sum(td_first) / len(td_first) - 0.005, "mean TD did not go down")
        for a, b in zip(means, means[1:]):
            self.assertLessEqual(b, a + 1e-6)  # concrete is only added
        # The final wall is the core's executed deposit (the trajectory with the pump's flow), the
        # one the plan summary reports: its levels exactly, its mean TD (per point here, per cell
        # there) to a tenth of the starting mean. The planner's own estimate may differ from it.
        mean0 = sum(td_first) / len(td_first)
        self.assertEqual(report["deposit_source"], "executed")
        self.assertAlmostEqual(means[-1] * 1000.0, report["residual_mm"]["mean"], delta=0.1 * mean0 * 1000.0)
        text = ex.message.split("levels_after={")[1].split("}")[0]
        executed_levels = {int(k): int(v) for k, v in (kv.split(": ") for kv in text.split(", "))}
        self.assertEqual(executed_levels, {int(k): v for k, v in report["levels_after"].items()})
        self.assertIn("plan predicted ", ex.message)
        # The levels are republished for the sprayed wall: its highest level is below the scan's.
        def top_level(m):
            return max(k.id for k in m.markers if k.ns == "levels" and k.points) - 100  # id = level - kNoDataLevel
        lv_after = [m for _, m in levels.snapshot()[n_levels:]]
        self.assertTrue(lv_after, "grid levels not republished after execution")
        self.assertLess(top_level(lv_after[-1]), top_level(lv))
        self.assertIn("levels_after=", ex.message)
        td_last = u.cloud_arrays(after[-1])[1]
        self.assertEqual(len(td_last), len(td_first))
        self.assertTrue(all(b <= a + 1e-6 for a, b in zip(td_first, td_last)))


if __name__ == "__main__":
    rospy.init_node("test_plan_execute")
    rostest.rosrun("shotcrete_ros", "plan_execute", PlanExecute, sys.argv)
