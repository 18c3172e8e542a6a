#!/usr/bin/env python3
"""The peer table of docs/book/src/peers.md: every controller (ours: PD,
LQR, MPC through their own sensors and estimator; rotorpy's SE3 from the
true state) on each rotorpy vehicle and reference, every figure a
measurement of `tools/rotorpy_hil.py --measure` (`claims.py write` fills
them from a run's measurements).

    python3 tools/peer_table.py > /tmp/table.md   # the table, figures as placeholders
"""
CONTROLLERS = [("pd", "PD (ours)"), ("lqr", "LQR (ours)"), ("mpc", "MPC fast (ours)"), ("se3", "SE3 (rotorpy)")]
VEHICLES = [("crazyflie", "Crazyflie"), ("hummingbird", "Hummingbird")]
REFERENCES = [("step", "step to (1, 0, −1) m at 5 s; whole 5–30 s, steady 10–30 s"),
              ("circle", "circle, R 2 m, 20 s lap, from 3 s; whole 3–25 s, steady 8–25 s"),
              ("eight", "figure-8, A 1 m, 6 s lap, from 3 s; whole 3–23 s, steady 9–23 s")]


def mark(key, placeholder):
    return f"<!--m:{key}-->{placeholder}<!--/m-->"


def table(vehicle, ref):
    rows = ["| controller | RMSE whole | RMSE steady | worst whole | worst steady | final | "
            + ("settling s | " if ref == "step" else "") + "effort |",
            "|---|---|---|---|---|---|" + ("---|" if ref == "step" else "") + "---|"]
    for c, title in CONTROLLERS:
        k = f"rotorpy_{c}_{vehicle}_{ref}"
        cells = [mark(f"{k}_whole_rmse_m", "0.0000"), mark(f"{k}_steady_rmse_m", "0.0000"),
                 mark(f"{k}_whole_worst_m", "0.0000"), mark(f"{k}_steady_worst_m", "0.0000"),
                 mark(f"{k}_whole_final_m", "0.0000")]
        if ref == "step":
            cells.append(mark(f"{k}_settling_s", "0.00"))
        cells.append(mark(f"{k}_whole_effort", "0.0000"))
        rows.append(f"| {title} | " + " | ".join(cells) + " |")
    return "\n".join(rows)


def main():
    for v, vt in VEHICLES:
        for r, rt in REFERENCES:
            print(f"**{vt}, {rt}** (m)\n")
            print(table(v, r))
            print()


if __name__ == "__main__":
    main()
