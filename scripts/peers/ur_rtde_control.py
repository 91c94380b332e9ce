"""Peer check: the public ur-rtde package moves the UR simulator with RTDEControlInterface.moveJ.

Usage: python ur_rtde_control.py HOST q0 q1 q2 q3 q4 q5
Uploads ur_rtde's own control script (FLAG_UPLOAD_SCRIPT, default), calls moveJ (blocking),
then reads the joints back with RTDEReceiveInterface. Prints one JSON object.
"""
import json
import sys

import rtde_control
import rtde_receive

host = sys.argv[1]
target = [float(x) for x in sys.argv[2:8]]
out = {}
c = rtde_control.RTDEControlInterface(host)
out["control_connected"] = c.isConnected()
out["program_running"] = c.isProgramRunning()
out["movej"] = c.moveJ(target, 1.05, 1.4)
r = rtde_receive.RTDEReceiveInterface(host)
out["actual_q"] = list(r.getActualQ())
out["safety_mode"] = r.getSafetyMode()
c.stopScript()
c.disconnect()
r.disconnect()
print(json.dumps(out))
