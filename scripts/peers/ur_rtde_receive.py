"""Peer check: the public ur-rtde package (PyPI ur-rtde 1.6.5) reads the UR simulator.

Usage: python ur_rtde_receive.py HOST
Prints one JSON object with what RTDEReceiveInterface and DashboardClient returned.
Nothing here is robocal code: it only calls the public ur_rtde API.
"""
import json
import sys

import dashboard_client
import rtde_receive

host = sys.argv[1]
out = {}
r = rtde_receive.RTDEReceiveInterface(host)
out["connected"] = r.isConnected()
out["actual_q"] = list(r.getActualQ())
out["actual_tcp_pose"] = list(r.getActualTCPPose())
out["robot_mode"] = r.getRobotMode()
out["safety_mode"] = r.getSafetyMode()
out["runtime_state"] = r.getRuntimeState()
out["timestamp"] = r.getTimestamp()
r.disconnect()

d = dashboard_client.DashboardClient(host)
d.connect()
out["dashboard_connected"] = d.isConnected()
out["polyscope_version"] = d.polyscopeVersion()
out["robotmode"] = d.robotmode()
out["safetystatus"] = d.safetystatus()
out["serial"] = d.getSerialNumber()
out["remote"] = d.isInRemoteControl()
d.powerOn()
d.brakeRelease()
d.disconnect()
print(json.dumps(out))
