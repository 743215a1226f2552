#!/usr/bin/python3
"""The closed loop through the node (issue 19). The test writes, with the Python package, the job
`shotcrete demo` plans on the node's config (its ~<section>/<key> parameters) and the after-scan
`shotcrete synth --after` makes of it (0.84 deg / 0.10 m off, flow x 0.85) with its ground truth;
the node plans and executes the same bay (the job's figures are checked to match), then ~rescan
measures the after-scan. The published thickness per cell, the registration, the flow factor and
the corrective round are checked against the truth files and the job's cells.csv. Bad input
(nothing executed yet, a missing file, NaN, an after-scan of another place, empty or NaN clouds on
~after_scan) gives an error in the response and on ~rescan_status, and the node keeps serving. The
same after-scan published on ~after_scan, and the node's own synthetic after-scan (an empty path, as
demo.launch loop:=true runs it), against the same truth. Last, the corrective round the rescan made
the node's job is sprayed by ~execute (its deposit checked against the round's own summary), and a
synthetic after-scan of it is refused with the reason."""
import csv
import json
import math
import os
import subprocess
import sys
import tempfile
import time
import unittest

import rospy
import rostest
import yaml
from sensor_msgs import point_cloud2
from sensor_msgs.msg import PointCloud2
from std_msgs.msg import Header, String
from std_srvs.srv import Trigger
from visualization_msgs.msg import MarkerArray

from shotcrete_ros.srv import Rescan

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import shotcrete_test_utils as u  # noqa: E402

ROOT = os.path.realpath(os.path.join(os.path.dirname(os.path.realpath(__file__)), "..", ".."))
PYTHON = os.environ.get("SHOTCRETE_PYTHON", os.path.join(ROOT, ".venv", "bin", "python"))

# The node's config as the Python package sees it: default.yaml, then every ~<section>/<key>.
CONFIG_SCRIPT = """
import json, sys
import shotcrete
cfg = shotcrete.load_config()
for section, values in json.loads(sys.argv[1]).items():
    if isinstance(values, dict) and hasattr(cfg, section):
        for key, value in values.items():
            setattr(getattr(cfg, section), key, value)
cfg.validate()
open(sys.argv[2], "w").write(cfg.to_yaml())
"""
# The after-scan as raw little-endian float32 x, y, z (the ROS Python has no numpy to read a PLY).
RAW_SCRIPT = """
import sys
import numpy as np
import shotcrete
np.asarray(shotcrete.read_cloud(sys.argv[1]).xyz, dtype="<f4").tofile(sys.argv[2])
"""
# The mask of rescan.reference mask: the before-scan's points off the bay (the lined previous bay
# behind it, the face at its far end, the invert below the springlines).
MASK_SCRIPT = """
import sys
import numpy as np
import shotcrete
from shotcrete import _core
cfg = shotcrete.Config.from_yaml(open(sys.argv[1]).read())
xyz = np.asarray(_core.make_synthetic_bay(cfg.synth).sample_scan(cfg.grid.cell_size_m).xyz)
keep = (xyz[:, 0] < -0.1) | (xyz[:, 0] > cfg.synth.length_m - 0.02) | (xyz[:, 2] < -1.0)
shotcrete.write_cloud(sys.argv[2], _core.Cloud(xyz[keep]))
"""
MASK_PATH = "/tmp/shotcrete_rescan_loop_mask.ply"  # rescan_loop.test's ~rescan_mask_file
SHIFT_SCRIPT = """
import sys
import numpy as np
import shotcrete
from shotcrete import _core
xyz = np.asarray(shotcrete.read_cloud(sys.argv[1]).xyz).copy()
xyz[:, 0] += float(sys.argv[3])
shotcrete.write_cloud(sys.argv[2], _core.Cloud(xyz))
"""


def _run(*args):
    r = subprocess.run([PYTHON, *[str(a) for a in args]], capture_output=True, text=True, cwd=ROOT)
    return r.returncode, r.stdout + r.stderr


def _csv(path):
    """{cell: {column: value}} (the system Python of ROS has no numpy: plain lists and dicts here)."""
    with open(path, newline="") as f:
        return {int(r["cell"]): {k: float(v) if v != "" else float("nan") for k, v in r.items()} for r in csv.DictReader(f)}


def _angle_deg(T):
    """Rotation angle of the 3 x 3 upper left of T (atan2: accurate near 0)."""
    v = (T[2][1] - T[1][2], T[0][2] - T[2][0], T[1][0] - T[0][1])
    return math.degrees(math.atan2(math.hypot(*v) / 2, (T[0][0] + T[1][1] + T[2][2] - 1) / 2))


def _inv_times(A, B):
    """inv(A) @ B for rigid 4 x 4 A: [R^T, -R^T t] @ B."""
    Ai = [[A[j][i] for j in range(3)] + [-sum(A[j][i] * A[j][3] for j in range(3))] for i in range(3)] + [[0, 0, 0, 1]]
    return [[sum(Ai[i][k] * B[k][j] for k in range(4)) for j in range(4)] for i in range(4)]


def _mean(v):
    return sum(v) / len(v)


def _rms(v):
    return math.sqrt(sum(x * x for x in v) / len(v))


class RescanLoop(unittest.TestCase):
    @classmethod
    def setUpClass(cls):
        assert os.path.exists(PYTHON), f"no Python with the shotcrete package at {PYTHON} (set SHOTCRETE_PYTHON)"
        cls.tmp = tempfile.mkdtemp(prefix="rescan_loop_")
        cls.status = u.Collector(u.NS + "/rescan_status", String)
        cls.thickness = u.Collector(u.NS + "/thickness", PointCloud2)
        cls.corrective = u.Collector(u.NS + "/corrective_passes", MarkerArray)
        cls.passes = u.Collector(u.NS + "/passes", MarkerArray)
        rospy.wait_for_service(u.NS + "/rescan", timeout=60)
        cls.rescan = rospy.ServiceProxy(u.NS + "/rescan", Rescan)
        d = cls.tmp
        cls.cfg_path = os.path.join(d, "cfg.yaml")
        code, out = _run("-c", CONFIG_SCRIPT, json.dumps(rospy.get_param(u.NS)), cls.cfg_path)
        assert code == 0, out
        code, out = _run("-m", "shotcrete.cli", "demo", "--config", cls.cfg_path, "--out", os.path.join(d, "job"))
        assert code in (0, 3), out
        cls.after = os.path.join(d, "after.ply")
        code, out = _run("-m", "shotcrete.cli", "synth", "--config", cls.cfg_path, "--after", os.path.join(d, "job"),
                         "--out", cls.after)
        assert code == 0, out

    def call(self, path):
        t = time.time()
        res = self.rescan(path)
        st = self.status.wait(timeout=10, after=t)
        self.assertIsNotNone(st, "nothing on ~rescan_status after ~rescan")
        return res, json.loads(st.data)

    def test_1_refused_before_anything_was_sprayed(self):
        res, st = self.call(self.after)
        self.assertFalse(res.success)
        self.assertIn("nothing sprayed yet", res.message)
        self.assertEqual(st, {"ok": False, "error": res.message})

    def test_2_loop_against_the_truth(self):
        d = self.tmp
        job = json.load(open(os.path.join(d, "job", "report.json")))
        plan = rospy.ServiceProxy(u.NS + "/plan", Trigger)()
        self.assertTrue(plan.success, plan.message)
        node_job = json.loads(plan.message)
        # The node planned the job the Python package planned (same core, config and bay).
        for key in ("rounds", "passes", "spray_time_s", "levels_after"):
            self.assertEqual(node_job[key], job[key], key)
        ex = rospy.ServiceProxy(u.NS + "/execute", Trigger)()
        self.assertTrue(ex.success, ex.message)

        t0 = time.time()
        res, st = self.call(self.after)
        self.assertTrue(res.success, res.message)
        self.assertEqual(json.loads(res.message), st)
        truth = json.load(open(os.path.join(d, "after_truth.json")))
        tcsv, cells = _csv(os.path.join(d, "after_truth.csv")), _csv(os.path.join(d, "job", "cells.csv"))
        self.assertEqual(set(tcsv), set(cells))

        # Registration: the true after -> before pose recovered.
        T = st["registration"]["matrix"]
        E = _inv_times(T, truth["pose_after_to_before"])
        self.assertLess(_angle_deg(E), 0.05)
        self.assertLess(math.hypot(E[0][3], E[1][3], E[2][3]), 0.005)  # a 1 rad crown slice: ~3 mm across (test_rescan.py)
        self.assertGreater(st["registration"]["overlap"], 0.9)
        self.assertAlmostEqual(st["registration"]["rotation_deg"], _angle_deg(T), delta=1e-3)

        # ~thickness: one point per measured cell, intensity = layer, at the wall as sprayed.
        msg = self.thickness.wait(lambda m: m.width > 0, timeout=10, after=t0)
        self.assertIsNotNone(msg, "no ~thickness cloud after the rescan")
        pts = list(point_cloud2.read_points(msg, field_names=("x", "y", "z", "intensity", "lod95", "cell")))
        ids = [int(p[5]) for p in pts]
        self.assertEqual(len(set(ids)), len(ids))
        self.assertTrue(set(ids) <= set(tcsv), "a thickness cell the job does not have")
        self.assertGreater(len(ids), 0.99 * len(tcsv))
        self.assertEqual(len(ids), st["cells_measured"])
        m_mm = [p[3] * 1000.0 for p in pts]
        true_mm = [tcsv[c]["true_thickness_mm"] for c in ids]
        err = [m - t for m, t in zip(m_mm, true_mm)]
        self.assertLess(abs(_mean(err)), 1.0)
        self.assertLess(_rms(err), 4.0)
        # The 95 % level of detection covers the error about as often as it should.
        self.assertGreater(_mean([abs(e) <= p[4] * 1000.0 for e, p in zip(err, pts)]), 0.85)
        self.assertAlmostEqual(st["thickness_mm"]["mean"], _mean(m_mm), delta=0.01)
        # The point sits on the sprayed wall: radius - R_design = TD before - layer (within the
        # before-scan's own TD reading of the cell, rescan's 20 mm match).
        off = [(math.hypot(p[1], p[2]) - u.R_DESIGN_M) * 1000 - (cells[c]["td_before_mm"] - m)
               for p, c, m in zip(pts, ids, m_mm)]
        self.assertLess(max(abs(o) for o in off), 20.0)
        # Measured vs the executed deposit of the job (cells.csv): the node's own deposit is the job's.
        diff = [m - cells[c]["deposit_executed_mm"] for c, m in zip(ids, m_mm)]
        self.assertAlmostEqual(st["measured_vs_predicted_mm"]["bias"], _mean(diff), delta=0.05)
        self.assertAlmostEqual(st["measured_vs_predicted_mm"]["rms"], _rms(diff), delta=0.05)

        # Flow factor: the one the truth realises, and the after-scan's 0.85.
        cal = st["calibration"]
        pt = [(tcsv[c]["predicted_mm"], tcsv[c]["true_thickness_mm"]) for c in ids if tcsv[c]["predicted_mm"] >= 20.0]
        realised = sum(p * t for p, t in pt) / sum(p * p for p, _ in pt)
        # Within 1 % of what the truth realises (the target is 2 % of the true factor):
        # the estimate rests on the measured layer, noisy per cell, and moved from within 0.5 % to
        # 0.504 % when the levelling guard changed this bay's plan.
        self.assertAlmostEqual(cal["flow_factor"] / realised, 1.0, delta=0.01)
        self.assertAlmostEqual(cal["flow_factor"] / truth["layer_scale"], 1.0, delta=0.03)
        base = yaml.safe_load(open(self.cfg_path))["deposition"]["peak_rate_mps"]
        self.assertAlmostEqual(cal["deposition_peak_rate_mps"], base * cal["flow_factor"], delta=1e-6)
        self.__class__.figures = {"registration_rotation_err_deg": _angle_deg(E),
                                  "registration_translation_err_mm": 1000 * math.hypot(E[0][3], E[1][3], E[2][3]),
                                  "thickness_bias_mm": _mean(err), "thickness_rms_mm": _rms(err),
                                  "flow_factor": cal["flow_factor"], "realised": realised,
                                  "layer_scale": truth["layer_scale"]}

        # The corrective round: planned on the measured residual (TD before - true layer, on average).
        corr = st["correction"]
        self.assertIsNotNone(corr, "no corrective round")
        true_residual = [cells[c]["td_before_mm"] - t for c, t in zip(ids, true_mm)]
        self.assertAlmostEqual(corr["td_before_mm"]["mean"], _mean(true_residual), delta=3.0)
        self.assertGreaterEqual(corr["rounds"], 1)
        self.assertEqual(set(corr["levels_after"]), {"0"})  # every cell within tolerance after it
        cm = self.corrective.wait(lambda m: any(k.ns == "passes" and k.points for k in m.markers), timeout=10, after=t0)
        self.assertIsNotNone(cm, "no ~corrective_passes markers")
        rounds = {k.id for k in cm.markers if k.ns == "passes" and k.points}
        self.assertTrue(1 <= len(rounds) <= corr["rounds"])
        # Every pass point is in front of the bay's wall: inside the design circle, over the bay's
        # chainage and arc (with the spot's reach beyond the edges).
        w = [(q.x, q.y, q.z) for k in cm.markers if k.ns == "passes" for q in k.points]
        self.assertTrue(all(math.hypot(y, z) < u.R_DESIGN_M for _, y, z in w))
        self.assertTrue(all(-0.5 < x < 1.1 for x, _, _ in w))
        self.assertTrue(all(0.8 < math.atan2(z, y) < 2.2 for _, y, z in w))
        # The executed plan's passes are cleared: the corrective round is what is left.
        pm = self.passes.wait(lambda m: not any(k.points for k in m.markers), timeout=10, after=t0)
        self.assertIsNotNone(pm, "~passes still shows the executed plan after the rescan")
        print("figures:", json.dumps(self.figures), file=sys.stderr)

    def test_3_bad_inputs_answer_with_the_reason(self):
        d = self.tmp
        with open(os.path.join(d, "nan.xyz"), "w") as f:
            f.write("1 2 3\nnan 0 0\n4 5 6\n")
        far = os.path.join(d, "far.ply")
        code, out = _run("-c", SHIFT_SCRIPT, self.after, far, "50.0")
        self.assertEqual(code, 0, out)
        for path, needle in ((os.path.join(d, "missing.ply"), "missing.ply"), (os.path.join(d, "nan.xyz"), "nan.xyz"),
                             (far, "another bay")):
            res, st = self.call(path)
            self.assertFalse(res.success, path)
            self.assertIn(needle, res.message)
            self.assertEqual(len(res.message.splitlines()), 1, res.message)
            self.assertEqual(st, {"ok": False, "error": res.message})
        pub = rospy.Publisher(u.NS + "/after_scan", PointCloud2, queue_size=1, latch=True)
        time.sleep(1.0)
        for points, needle in (([], "empty"), ([(1.0, 2.0, 3.0), (float("nan"), 0.0, 0.0)], "NaN")):
            t = time.time()
            pub.publish(u.cloud_msg(points))
            st = self.status.wait(timeout=10, after=t)
            self.assertIsNotNone(st, "nothing on ~rescan_status after a bad ~after_scan")
            err = json.loads(st.data)
            self.assertFalse(err["ok"])
            self.assertIn("after_scan", err["error"])
            self.assertIn(needle, err["error"])
        # Still serving.
        res, _ = self.call(os.path.join(d, "missing.ply"))
        self.assertFalse(res.success)

    def test_4_after_scan_on_the_topic(self):
        # The after-scan of test 2 as a PointCloud2 on ~after_scan: the same pose and layer.
        d = self.tmp
        raw = os.path.join(d, "after.f32")
        code, out = _run("-c", RAW_SCRIPT, self.after, raw)
        self.assertEqual(code, 0, out)
        data = open(raw, "rb").read()
        msg = PointCloud2(header=Header(frame_id="tunnel", stamp=rospy.Time.now()), height=1, width=len(data) // 12,
                          fields=u.float_fields("x", "y", "z"), is_bigendian=False, point_step=12,
                          row_step=len(data), data=data, is_dense=True)
        pub = rospy.Publisher(u.NS + "/after_scan", PointCloud2, queue_size=1, latch=True)
        time.sleep(1.0)
        t0 = time.time()
        pub.publish(msg)
        st = self.status.wait(lambda m: json.loads(m.data).get("source") == "topic " + u.NS + "/after_scan",
                              timeout=300, after=t0)
        self.assertIsNotNone(st, "no ok status for the after-scan on ~after_scan")
        st = json.loads(st.data)
        truth = json.load(open(os.path.join(d, "after_truth.json")))
        E = _inv_times(st["registration"]["matrix"], truth["pose_after_to_before"])
        self.assertLess(_angle_deg(E), 0.05)
        self.assertLess(math.hypot(E[0][3], E[1][3], E[2][3]), 0.005)
        tcsv = _csv(os.path.join(d, "after_truth.csv"))
        th = self.thickness.wait(lambda m: m.width > 0, timeout=10, after=t0)
        self.assertIsNotNone(th)
        pts = list(point_cloud2.read_points(th, field_names=("intensity", "cell")))
        self.assertGreater(len(pts), 0.99 * len(tcsv))
        err = [p[0] * 1000.0 - tcsv[int(p[1])]["true_thickness_mm"] for p in pts]
        self.assertLess(abs(_mean(err)), 1.0)
        self.assertLess(_rms(err), 4.0)
        self.assertAlmostEqual(st["calibration"]["flow_factor"], 0.85, delta=0.03 * 0.85)

    def test_5_synthetic_after_scan_of_the_node(self):
        # An empty path: the node's own synthetic after-scan (the core's make_after_scan of its executed
        # deposit, the same generator and seed as `synth --after`): the same truth applies.
        t0 = time.time()
        res, st = self.call("")
        self.assertTrue(res.success, res.message)
        msg = self.thickness.wait(lambda m: m.width > 0, timeout=10, after=t0)
        self.assertIsNotNone(msg)
        tcsv = _csv(os.path.join(self.tmp, "after_truth.csv"))
        pts = list(point_cloud2.read_points(msg, field_names=("intensity", "cell")))
        self.assertGreater(len(pts), 0.99 * len(tcsv))
        err = [p[0] * 1000.0 - tcsv[int(p[1])]["true_thickness_mm"] for p in pts]
        self.assertLess(abs(_mean(err)), 1.0)
        self.assertLess(_rms(err), 4.0)
        self.assertAlmostEqual(st["calibration"]["flow_factor"], 0.85, delta=0.03 * 0.85)
        self.assertIsNotNone(st["correction"])
        self.assertEqual(st["source"], "the synthetic after-scan")

        self.__class__.correction = st["correction"]

    def test_6_the_corrective_round_is_sprayed(self):
        # Test 5's rescan made its corrective round the node's job: ~execute sprays it on the
        # after-scan's wall with the calibrated flow.
        corr = self.correction
        self.assertEqual(corr["status"], "ok", corr.get("problems"))
        cloud = u.Collector(u.NS + "/cloud", PointCloud2)
        t0 = time.time()
        ex = rospy.ServiceProxy(u.NS + "/execute", Trigger)()
        self.assertTrue(ex.success, ex.message)
        # Its levels are the round's own executed deposit (the summary the rescan gave).
        levels = {k: v for k, v in corr["levels_after"].items()}
        text = "levels_after={" + ", ".join(f"{k}: {v}" for k, v in sorted(levels.items(), key=lambda kv: int(kv[0]))) + "}"
        self.assertIn(text, ex.message)
        self.assertEqual(set(levels), {"0"})
        # The wall published at the end is the after-scan's wall with the round's deposit: its TD
        # per point averages the round's residual per cell (points, not cells: a few mm apart), far
        # below the TD the round started from.
        self.assertIsNotNone(cloud.wait(lambda m: m.width > 0, timeout=30, after=t0))
        time.sleep(2.0)  # ~execute publishes the final wall before it answers
        msg = cloud.snapshot()[-1][1]
        _, td = u.cloud_arrays(msg)
        td_mm = _mean(td) * 1000.0
        self.assertAlmostEqual(td_mm, corr["residual_mm"]["mean"], delta=3.0)
        self.assertLess(td_mm, corr["td_before_mm"]["mean"] - 10.0)

    def test_7_a_corrective_round_has_no_synthetic_after_scan(self):
        res, st = self.call("")
        self.assertFalse(res.success)
        self.assertIn("corrective round", res.message)
        self.assertEqual(st, {"ok": False, "error": res.message})


    def test_8_mask_reference(self):
        # A second node with rescan.reference mask registers on the mask cloud: refused with the
        # reason while the file is missing, then the same pose as the dry reference.
        ns = u.NS + "_mask"
        if os.path.exists(MASK_PATH):
            os.remove(MASK_PATH)
        plan = rospy.ServiceProxy(ns + "/plan", Trigger)()
        self.assertTrue(plan.success, plan.message)
        ex = rospy.ServiceProxy(ns + "/execute", Trigger)()
        self.assertTrue(ex.success, ex.message)
        rescan = rospy.ServiceProxy(ns + "/rescan", Rescan)
        res = rescan(self.after)
        self.assertFalse(res.success)
        self.assertIn("mask cloud", res.message)
        self.assertIn(MASK_PATH, res.message)
        code, out = _run("-c", MASK_SCRIPT, self.cfg_path, MASK_PATH)
        self.assertEqual(code, 0, out)
        try:
            res = rescan(self.after)
        finally:
            os.remove(MASK_PATH)
        self.assertTrue(res.success, res.message)
        st = json.loads(res.message)
        self.assertEqual(st["registration"]["reference"], "mask")
        truth = json.load(open(os.path.join(self.tmp, "after_truth.json")))
        E = _inv_times(st["registration"]["matrix"], truth["pose_after_to_before"])
        # This mask (1 m of lining, the face, the invert; none of the bay's own dry cells) grips the
        # pose less than the dry reference does: 12 mm along it in CI, the rotation within 0.05 deg.
        self.assertLess(_angle_deg(E), 0.05)
        self.assertLess(math.hypot(E[0][3], E[1][3], E[2][3]), 0.025)
        self.assertAlmostEqual(st["calibration"]["flow_factor"], 0.85, delta=0.05 * 0.85)


if __name__ == "__main__":
    rospy.init_node("test_rescan_loop")
    rostest.rosrun("shotcrete_ros", "rescan_loop", RescanLoop)
