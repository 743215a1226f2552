"""Helpers shared by the rostests: an independent synthetic bay cloud, topic collectors, URDF limits."""
import math
import threading
import time
import xml.etree.ElementTree as ET

import rospy
from sensor_msgs import point_cloud2
from sensor_msgs.msg import PointCloud2, PointField
from std_msgs.msg import Header

NS = "/shotcrete_node"
R_DESIGN_M = 5.6  # config/default.yaml profile.design_radius_m


def bay_points(length_m=0.6, theta_min=1.0, theta_max=2.0, step_m=0.025, overbreak_m=0.10,
               pits=((0.3, 1.45 * R_DESIGN_M, 0.08, 0.4), (0.15, 1.8 * R_DESIGN_M, 0.05, 0.3))):
    """Half-cylinder strip outside the design line (written here, not by the core's generator):
    wall radius = R_DESIGN + overbreak + dig pits dT = Tmax (1 - d^2/D^2)^1.5 on the unrolled wall.
    pits: (d_m, s_m, depth_m, radius_m)."""
    pts = []
    n_d = int(round(length_m / step_m))
    dth = step_m / R_DESIGN_M
    n_th = int(round((theta_max - theta_min) / dth))
    for i in range(n_d):
        d = (i + 0.5) * step_m
        for j in range(n_th):
            th = theta_min + (j + 0.5) * dth
            td = overbreak_m
            for (pd, ps, depth, rad) in pits:
                dist2 = (d - pd) ** 2 + (th * R_DESIGN_M - ps) ** 2
                if dist2 < rad * rad:
                    td += depth * (1.0 - dist2 / (rad * rad)) ** 1.5
            r = R_DESIGN_M + td
            pts.append((d, r * math.cos(th), r * math.sin(th)))
    return pts


def cloud_msg(points, frame="tunnel", fields=None):
    header = Header(frame_id=frame, stamp=rospy.Time.now())
    if fields is None:
        return point_cloud2.create_cloud_xyz32(header, points)
    return point_cloud2.create_cloud(header, fields, points)


def float_fields(*names):
    return [PointField(n, 4 * i, PointField.FLOAT32, 1) for i, n in enumerate(names)]


def cloud_arrays(msg):
    """(xyz list, intensity list) of a PointCloud2 with x, y, z, intensity."""
    xyz, td = [], []
    for x, y, z, i in point_cloud2.read_points(msg, field_names=("x", "y", "z", "intensity")):
        xyz.append((x, y, z))
        td.append(i)
    return xyz, td


class Collector:
    """Keeps every message of a topic with its arrival time (wall clock)."""

    def __init__(self, topic, msg_type):
        self.items = []
        self._lock = threading.Lock()
        self.sub = rospy.Subscriber(topic, msg_type, self._cb, queue_size=1000)

    def _cb(self, msg):
        with self._lock:
            self.items.append((time.time(), msg))

    def snapshot(self):
        with self._lock:
            return list(self.items)

    def wait(self, predicate=lambda m: True, timeout=30.0, after=0.0):
        """First message received after `after` that satisfies predicate, or None."""
        end = time.time() + timeout
        while time.time() < end and not rospy.is_shutdown():
            for t, m in self.snapshot():
                if t >= after and predicate(m):
                    return m
            time.sleep(0.05)
        return None


def urdf_limits(path):
    """{joint name: (lower, upper)} of the movable joints of a URDF file."""
    limits = {}
    for joint in ET.parse(path).getroot().findall("joint"):
        if joint.get("type") in ("revolute", "prismatic"):
            lim = joint.find("limit")
            limits[joint.get("name")] = (float(lim.get("lower")), float(lim.get("upper")))
    return limits
