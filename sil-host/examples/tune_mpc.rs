//! Tuning aid: flies the fast MPC on the hardest cases with the preset
//! changed by `KEY=VALUE` arguments (tau, q0..q11, r0..r3, s0..s3, pred, exec,
//! yawlim, poslim, trend, trendmax, ratelp; lag = 1/0 the rotors' lag in the
//! prediction, moves = the prediction steps each move but the last spans;
//! noise = scale of the typical sensor noise; thesis = 1 starts from the
//! thesis preset instead of the fast one).
//! `cargo run --release -p sil-host --example tune_mpc -- tau=0.1 q2=80`

use fc_core::control::Family;
use fc_core::control::{AttitudeForm, MpcConfig};
use sil_host::flight::{fly, FlightConfig};
use sil_host::noise::SensorNoise;
use sil_host::{DisturbanceSet, Scenario, ScenarioKind};

fn main() {
    let thesis = std::env::args().any(|a| a == "thesis=1");
    for model in AttitudeForm::ALL {
        let form = model;
        let mut c = if thesis {
            MpcConfig::thesis(form)
        } else {
            MpcConfig::fast(form)
        };
        let mut noise = None;
        for arg in std::env::args().skip(1) {
            let (k, v) = arg.split_once('=').expect("KEY=VALUE");
            let v: f64 = v.parse().expect("number");
            match k {
                "thesis" => {}
                "noise" => noise = Some(SensorNoise::typical(v, 1).expect("noise scale")),
                "yawlim" => c.max_heading_error_rad = v,
                "poslim" => c.max_position_error_m = v,
                "lag" => c.rotor_lag_prediction = v != 0.0,
                "moves" => c.move_steps = v as usize,
                "mtau" => c.observer_moment_tau_s = v,
                "trend" => c.disturbance_trend_s = if v > 0.0 { Some(v) } else { None },
                "trendmax" => c.disturbance_trend_max_mps2 = v,
                "ratelp" => c.disturbance_rate_filter_s = v,
                "tau" => c.observer_tau_s = if v > 0.0 { Some(v) } else { None },
                "pred" => c.pred_dt_s = v,
                "exec" => c.exec_dt_s = v,
                _ if k.starts_with('q') => c.q[k[1..].parse::<usize>().unwrap()] = v,
                _ if k.starts_with('r') => c.r[k[1..].parse::<usize>().unwrap()] = v,
                _ if k.starts_with('s') => c.s[k[1..].parse::<usize>().unwrap()] = v,
                _ => panic!("unknown key {k}"),
            }
        }
        for (kind, d) in [
            (ScenarioKind::Helix, "none"),
            (ScenarioKind::Helix, "wind"),
            (ScenarioKind::Setpoint, "wind"),
            (ScenarioKind::Setpoint, "mismatch"),
            (ScenarioKind::Helix, "wind,mismatch"),
            // The hardest unlisted case of tests/tests/mpc.rs: a far target at −120°.
            (ScenarioKind::Setpoint, "turn: wind,mismatch"),
        ] {
            let mut sc = Scenario::default_for(kind);
            let d = match d.strip_prefix("turn: ") {
                Some(rest) => {
                    sc.target_ned_m = [-2.0, 4.0, -2.0];
                    sc.target_yaw_rad = (-120f64).to_radians();
                    rest
                }
                None => d,
            };
            let mut f = FlightConfig::new(Family::Mpc, model, sc);
            f.disturbance = d.parse::<DisturbanceSet>().unwrap();
            if thesis {
                f.spec.preset = fc_core::control::Preset::Thesis;
            }
            f.mpc_override = Some(c);
            f.noise = noise;
            let r = fly(&f).unwrap();
            let m = r.metrics;
            // x RMS error over [0,5), [5,10) and [10,end) s: start-up, wind onset, steady gust.
            let tr = &r.trace;
            let win = |lo: f64, hi: f64| {
                let e: Vec<f64> = (0..tr.t.len())
                    .filter(|&i| tr.t[i] >= lo && tr.t[i] < hi)
                    .map(|i| tr.actual[i][0] - tr.reference[i][0])
                    .collect();
                (e.iter().map(|v| v * v).sum::<f64>() / e.len().max(1) as f64).sqrt()
            };
            println!(
                "{:10} {:8} {:14} rmse {:.4} {:.4} {:.4} [x {:.4} {:.4} {:.4}] final {:.4} it {:.0}/{}{}",
                model.name(),
                kind.name(),
                d,
                m.x.rmse_m,
                m.y.rmse_m,
                m.z.rmse_m,
                win(0.0, 5.0),
                win(5.0, 10.0),
                win(10.0, 1e9),
                m.final_error_m,
                r.qp_iterations.0,
                r.qp_iterations.1,
                if r.diverged || m.final_error_m > 1.0 {
                    "  UNSTABLE"
                } else {
                    ""
                }
            );
        }
    }
}
