"""A UR5 experiment for speed measurements (6 joints, one learned RMP).

The shoulder, elbow and wrists track small sines; wrist 1 holds the pitch of its link
(shoulder_lift + elbow + wrist_1, three parallel axes) at a constant angle and its RMP learns.
"""

import math

UR5 = {
    "name": "ur5_bench",
    "robot": "example-robot-data:ur5",
    "period_s": 1.0,
    "sim": {"rate_hz": 100, "cycles": 50},
    "primitives": {"basis": 10},
    "joints": {
        "shoulder_pan_joint": {"role": "track", "gains": {"kp": 400, "kd": 40},
                               "demo": {"kind": "sine", "mean": 0.0, "amplitude": 0.3}},
        "shoulder_lift_joint": {"role": "track", "gains": {"kp": 800, "kd": 80},
                                "demo": {"kind": "sine", "mean": -1.2, "amplitude": 0.2}},
        "elbow_joint": {"role": "track", "gains": {"kp": 400, "kd": 40},
                        "demo": {"kind": "sine", "mean": 1.0, "amplitude": 0.2, "phase": 1.0}},
        "wrist_1_joint": {"role": "stabilize", "gains": {"kp": 50, "kd": 5},
                          "target": {"link_angle": ["shoulder_lift_joint", "elbow_joint",
                                                    "wrist_1_joint"], "value": -math.pi / 2},
                          "learn": {"weight_scale": 0.05, "goal_spread": 0.05}},
        "wrist_2_joint": {"role": "track", "gains": {"kp": 50, "kd": 5},
                          "demo": {"kind": "sine", "mean": 0.0, "amplitude": 0.1}},
        "wrist_3_joint": {"role": "track", "gains": {"kp": 20, "kd": 2},
                          "demo": {"kind": "sine", "mean": 0.0, "amplitude": 0.1}},
    },
    "learning": {"error": "stabilizing", "rates": {"weights": 0.5, "goal": 1e-4}},
    "seeds": 1,
}
