"""Drives an xArm controller (here: xarm-sim) with the UNMODIFIED official Python SDK.

The session is the basic one from docs/xarm-protocol.md: connect, clean errors, enable,
mode 1, state 0, stream set_servo_angle_j targets at 100 Hz, read them back with
get_servo_angle and get_position, check a client-side limit refusal, stop. Prints one JSON
line with the results; exits non-zero on the first failed check.

Usage: python xarm_sdk_check.py [HOST]   (the SDK always uses the real ports 502/30002)
"""

import json
import math
import sys
import time

from xarm.wrapper import XArmAPI


def check(cond, what):
    if not cond:
        print(json.dumps({"ok": False, "failed": what}), flush=True)
        sys.exit(1)


def main():
    host = sys.argv[1] if len(sys.argv) > 1 else "127.0.0.1"
    arm = XArmAPI(host, is_radian=True)
    check(arm.connected, "connected")
    check(arm.axis == 5, "axis is 5 (got %r)" % (arm.axis,))
    check(arm.clean_error() == 0, "clean_error")
    check(arm.motion_enable(enable=True) == 0, "motion_enable")
    check(arm.set_mode(1) == 0, "set_mode(1)")
    check(arm.set_state(0) == 0, "set_state(0)")
    time.sleep(0.1)
    code, state = arm.get_state()
    check(code == 0 and state in (1, 2), "state after set_state(0): %r %r" % (code, state))
    code, q0 = arm.get_servo_angle(is_radian=True)
    check(code == 0 and len(q0) == 7, "get_servo_angle at start: %r %r" % (code, q0))
    q0 = [float(v) for v in q0[:5]]

    last = list(q0)
    codes = []
    n = 150
    for k in range(n):
        last = list(q0)
        last[0] = q0[0] + 0.15 * k / n
        last[3] = q0[3] - 0.05 * k / n
        codes.append(arm.set_servo_angle_j(last, is_radian=True))
        time.sleep(0.01)
    check(all(c == 0 for c in codes), "set_servo_angle_j codes %r" % sorted(set(codes)))
    time.sleep(0.3)

    code, q = arm.get_servo_angle(is_radian=True)
    check(code == 0, "get_servo_angle code %r" % code)
    err = max(abs(q[i] - last[i]) for i in range(5))
    check(err < 1e-3, "joints reached the last target (max error %g rad)" % err)
    check(q[5] == 0 and q[6] == 0, "J6/J7 are 0 on the xArm5")
    code, pose = arm.get_position(is_radian=True)
    check(code == 0 and len(pose) == 6 and all(math.isfinite(v) for v in pose),
          "get_position %r %r" % (code, pose))

    # Client-side limit check: J2 = -2.5 rad is refused with -8 and nothing is sent.
    out_of_range = arm.set_servo_angle_j([0.0, -2.5, 0.0, 0.0, 0.0], is_radian=True)
    check(out_of_range == -8, "out-of-range target refused client-side (got %r)" % out_of_range)

    check(arm.set_state(4) == 0, "set_state(4)")
    time.sleep(0.05)
    code, state = arm.get_state()
    check(code == 0 and state == 4, "stopped: %r %r" % (code, state))
    code, (err_code, warn_code) = arm.get_err_warn_code()
    check(code == 0 and err_code == 0, "no controller error: %r %r" % (code, err_code))
    arm.disconnect()
    print(json.dumps({
        "ok": True,
        "servo_targets": n,
        "final_joints_rad": [round(v, 6) for v in q[:5]],
        "tcp_pose": [round(v, 4) for v in pose],
        "max_joint_error_rad": err,
        "version": arm.version,
    }), flush=True)


if __name__ == "__main__":
    main()
