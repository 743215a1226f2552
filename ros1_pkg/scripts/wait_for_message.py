#!/usr/bin/python3
"""Waits for one message on a std_msgs/String topic and prints it; exit 1 on timeout.
Usage: wait_for_message.py TOPIC TIMEOUT_S"""
import sys

import rospy
from std_msgs.msg import String

topic, timeout = sys.argv[1], float(sys.argv[2])
rospy.init_node("wait_for_message", anonymous=True, disable_signals=True)
try:
    print(rospy.wait_for_message(topic, String, timeout=timeout).data)
except rospy.ROSException as e:
    print("no message on %s within %.0f s: %s" % (topic, timeout, e), file=sys.stderr)
    sys.exit(1)
