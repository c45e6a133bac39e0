#!/usr/bin/env python3
"""Draws a run recording (MCAP) headless, as a viewer would show it: the TCP path seen from
above and from the side over the boxes and goal the camera reported, the measured and
commanded joints over time, and the verdicts and the referee's clearance. Reads the file
with the `mcap` / `mcap-ros2-support` packages only (no Foresight code).

    render_mcap.py runs/latest/run.mcap docs/run-mcap.png
"""

import os
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402
from mcap.reader import make_reader  # noqa: E402
from mcap_ros2.decoder import DecoderFactory  # noqa: E402


def main(path, out):
    tcp, js, jc, verdicts, referee = [], [], [], [], []
    boxes = {}  # last marker array's boxes, by (ns, id)
    plan = []
    t0 = None
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _, channel, message, msg in reader.iter_decoded_messages():
            t0 = message.log_time if t0 is None else t0
            t = (message.log_time - t0) / 1e9
            topic = channel.topic
            if topic == "/tf":
                for tr in msg.transforms:
                    if tr.child_frame_id == "link_tcp":
                        v = tr.transform.translation
                        tcp.append((t, v.x, v.y, v.z))
            elif topic == "/joint_states":
                js.append((t, list(msg.position)))
            elif topic == "/joint_commands":
                jc.append((t, list(msg.position)))
            elif topic == "/foresight/verdicts":
                verdicts.append((t, msg.plan_approved, msg.safe, msg.min_distance_m))
            elif topic == "/foresight/referee":
                referee.append((t, msg.min_clearance_m))
            elif topic == "/foresight/scene_markers":
                for m in msg.markers:
                    if m.ns in ("goal", "obstacles") and m.type == 1:
                        boxes[(m.ns, m.id)] = (m.pose.position, m.scale)
                    elif m.ns == "plan_path" and len(m.points) >= 2:
                        plan = [(p.x, p.y, p.z) for p in m.points]

    fig = plt.figure(figsize=(13, 8.5), constrained_layout=True)
    grid = fig.add_gridspec(2, 3)
    run = os.path.basename(os.path.dirname(os.path.abspath(path)))
    fig.suptitle(f"Run recording {run}/run.mcap: {len(js)} joint states, {len(verdicts)} verdict(s), {len(referee)} referee reports")
    for k, (ax_i, ay_i, name) in enumerate([(1, 2, "top view (x–y)"), (1, 3, "side view (x–z)")]):
        ax = fig.add_subplot(grid[0, k])
        for (ns, _), (p, s) in boxes.items():
            c = "tab:green" if ns == "goal" else "tab:red"
            lo = ((p.x - s.x / 2), (p.y - s.y / 2) if ay_i == 2 else (p.z - s.z / 2))
            w, h = s.x, (s.y if ay_i == 2 else s.z)
            ax.add_patch(Rectangle(lo, w, h, color=c, alpha=0.35, label=ns))
        if tcp:
            ax.plot([r[ax_i] for r in tcp], [r[ay_i] for r in tcp], color="tab:blue", lw=2, label="TCP (measured, /tf)")
        if plan:
            ax.plot([p[0] for p in plan], [p[ay_i - 1] for p in plan], "--", color="black", lw=1, label="commanded plan path")
        ax.set_title(f"TCP path, {name}")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)" if ay_i == 2 else "z (m)")
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
        handles, labels = ax.get_legend_handles_labels()
        uniq = dict(zip(labels, handles))
        ax.legend(uniq.values(), uniq.keys(), fontsize=8, loc="best")

    ax = fig.add_subplot(grid[0, 2])
    if verdicts:
        for t, approved, safe, dist in verdicts:
            ax.scatter(t, dist * 1e3, color="tab:green" if approved else ("tab:orange" if safe else "tab:red"), s=25)
        ax.scatter([], [], color="tab:green", label="verdict: approved")
        ax.scatter([], [], color="tab:red", label="verdict: contact predicted")
    if referee:
        ax.plot([r[0] for r in referee], [r[1] * 1e3 for r in referee], color="tab:purple", label="referee: least clearance so far")
    ax.set_title("Lookahead and referee")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("distance (mm)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)

    ax = fig.add_subplot(grid[1, :])
    colours = ["tab:blue", "tab:orange", "tab:green", "tab:red", "tab:purple"]
    for j in range(5):
        if js:
            ax.plot([r[0] for r in js], [r[1][j] for r in js], color=colours[j], lw=1.5, label=f"joint{j + 1} measured")
        if jc:
            ax.plot([r[0] for r in jc], [r[1][j] for r in jc], color=colours[j], lw=0.8, ls="--")
    ax.set_title("Joints: measured (/joint_states, solid) and commanded (/joint_commands, dashed)")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("angle (rad)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, ncol=5, loc="upper right")
    fig.savefig(out, dpi=90)
    print(f"wrote {out}")


if __name__ == "__main__":
    if len(sys.argv) != 3:
        sys.exit(__doc__)
    main(sys.argv[1], sys.argv[2])
