//! Vehicle parameters and scenarios from TOML files (`--vehicle FILE`,
//! `--scenario-file FILE`). Every field is optional: a file overrides what it
//! names and keeps the built-in default (the OS4 of docs/book/src/model.md §2, the docs/book/src/model.md §9
//! scenario) for the rest. Unknown fields, wrong types and non-physical
//! values are errors that name the field.
//!
//! Vehicle file (units in the names, as in `VehicleParams`):
//! ```toml
//! mass_kg = 0.65
//! inertia_kgm2 = [7.5e-3, 7.5e-3, 1.3e-2]
//! rotor_tau_s = 0.178
//! ```
//! Scenario file (angles in degrees):
//! ```toml
//! kind = "helix"          # setpoint | circle | helix | eight
//! radius_m = 3.0
//! period_s = 25.0
//! climb_rate_mps = 0.1
//! duration_s = 40.0
//!
//! [sensors]               # the sensors of --estimator ekf (all optional)
//! profile = "gps"         # mocap | gps
//! seed = 7
//! gyro_noise_dps_rthz = 0.014
//! accel_noise_ug_rthz = 175.0
//! fix_outage_s = [10.0, 2.0]   # start, length
//! fix_outlier_at_s = 5.0
//! imu_nan_at_s = 3.0
//! imu_stuck_s = [4.0, 0.05]
//! accel_clip_at_s = 6.0
//! ```
//! Command-line flags override the file's `[sensors]`.

use crate::scenario::{Scenario, ScenarioKind};
use crate::sensors::{FixProfile, SensorConfig};
use anyhow::{bail, Context, Result};
use fc_core::VehicleParams;
use serde::Deserialize;
use std::path::Path;

/// A vehicle file: any subset of the parameters.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct VehicleToml {
    mass_kg: Option<f64>,
    gravity_mps2: Option<f64>,
    inertia_kgm2: Option<[f64; 3]>,
    arm_m: Option<f64>,
    rotor_inertia_kgm2: Option<f64>,
    kf_ns2: Option<f64>,
    km_nms2: Option<f64>,
    kt_nspm: Option<[f64; 3]>,
    kr_nms: Option<[f64; 3]>,
    omega_max_radps: Option<f64>,
    rotor_tau_s: Option<f64>,
    rotor_gain: Option<f64>,
}

/// A scenario file: any subset of the scenario's numbers.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct ScenarioToml {
    kind: Option<ScenarioKind>,
    start_ned_m: Option<[f64; 3]>,
    start_yaw_deg: Option<f64>,
    target_ned_m: Option<[f64; 3]>,
    target_yaw_deg: Option<f64>,
    radius_m: Option<f64>,
    period_s: Option<f64>,
    climb_rate_mps: Option<f64>,
    duration_s: Option<f64>,
    sensors: Option<SensorsToml>,
}

/// A scenario file's `[sensors]` table.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
struct SensorsToml {
    profile: Option<FixProfile>,
    seed: Option<u64>,
    gyro_noise_dps_rthz: Option<f64>,
    accel_noise_ug_rthz: Option<f64>,
    fix_outage_s: Option<[f64; 2]>,
    fix_outlier_at_s: Option<f64>,
    imu_nan_at_s: Option<f64>,
    imu_stuck_s: Option<[f64; 2]>,
    accel_clip_at_s: Option<f64>,
}

fn read(path: &Path) -> Result<String> {
    std::fs::read_to_string(path).with_context(|| format!("reading {}", path.display()))
}

fn parse<T: serde::de::DeserializeOwned>(path: &Path, text: &str) -> Result<T> {
    // toml's message carries the offending key (unknown field `x`, or the
    // line of a mistyped value); say which file too.
    toml::from_str(text).map_err(|e| anyhow::anyhow!("{}: {}", path.display(), e.to_string().trim_end()))
}

/// Checks that `field` is finite and positive (or ≥ 0 when `zero_ok`).
fn physical(path: &Path, field: &str, v: f64, zero_ok: bool) -> Result<f64> {
    if !v.is_finite() || v < 0.0 || (v == 0.0 && !zero_ok) {
        bail!(
            "{}: field `{field}` = {v} is not physical (must be finite and {})",
            path.display(),
            if zero_ok { "≥ 0" } else { "> 0" }
        );
    }
    Ok(v)
}

/// Parses a vehicle file's text over the OS4 defaults.
pub fn vehicle_from_str(path: &Path, text: &str) -> Result<VehicleParams<f64>> {
    let t: VehicleToml = parse(path, text)?;
    let mut p = VehicleParams::OS4;
    let one = |f: &str, v: Option<f64>, d: f64, zero_ok: bool| -> Result<f64> {
        v.map_or(Ok(d), |v| physical(path, f, v, zero_ok))
    };
    let three = |f: &str, v: Option<[f64; 3]>, d: [f64; 3], zero_ok: bool| -> Result<[f64; 3]> {
        match v {
            None => Ok(d),
            Some(a) => {
                for (i, x) in a.iter().enumerate() {
                    physical(path, &format!("{f}[{i}]"), *x, zero_ok)?;
                }
                Ok(a)
            }
        }
    };
    p.mass_kg = one("mass_kg", t.mass_kg, p.mass_kg, false)?;
    p.gravity_mps2 = one("gravity_mps2", t.gravity_mps2, p.gravity_mps2, false)?;
    p.inertia_kgm2 = three("inertia_kgm2", t.inertia_kgm2, p.inertia_kgm2, false)?;
    p.arm_m = one("arm_m", t.arm_m, p.arm_m, false)?;
    p.rotor_inertia_kgm2 = one("rotor_inertia_kgm2", t.rotor_inertia_kgm2, p.rotor_inertia_kgm2, true)?;
    p.kf_ns2 = one("kf_ns2", t.kf_ns2, p.kf_ns2, false)?;
    p.km_nms2 = one("km_nms2", t.km_nms2, p.km_nms2, false)?;
    p.kt_nspm = three("kt_nspm", t.kt_nspm, p.kt_nspm, true)?;
    p.kr_nms = three("kr_nms", t.kr_nms, p.kr_nms, true)?;
    p.omega_max_radps = one("omega_max_radps", t.omega_max_radps, p.omega_max_radps, false)?;
    p.rotor_tau_s = one("rotor_tau_s", t.rotor_tau_s, p.rotor_tau_s, false)?;
    p.rotor_gain = one("rotor_gain", t.rotor_gain, p.rotor_gain, false)?;
    // The vehicle must be able to hover with margin, or no controller can fly it.
    let max_thrust = 4.0 * p.kf_ns2 * p.omega_max_radps * p.omega_max_radps;
    if max_thrust < 1.2 * p.mass_kg * p.gravity_mps2 {
        bail!(
            "{}: fields `kf_ns2`, `omega_max_radps`, `mass_kg`: full thrust {max_thrust:.2} N is below 1.2 × weight {:.2} N",
            path.display(),
            p.mass_kg * p.gravity_mps2
        );
    }
    p.check().map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    Ok(p)
}

/// Reads a vehicle file (see the module docs).
pub fn load_vehicle(path: &Path) -> Result<VehicleParams<f64>> {
    vehicle_from_str(path, &read(path)?)
}

/// Parses a scenario file's text over the docs/book/src/model.md §9 defaults of its kind
/// (`default_kind` when the file names none).
pub fn scenario_from_str(path: &Path, text: &str, default_kind: ScenarioKind) -> Result<Scenario> {
    let t: ScenarioToml = parse(path, text)?;
    let mut s = Scenario::default_for(t.kind.unwrap_or(default_kind));
    let finite = |f: &str, v: f64| -> Result<f64> {
        if v.is_finite() {
            Ok(v)
        } else {
            bail!("{}: field `{f}` = {v} is not finite", path.display())
        }
    };
    let finite3 = |f: &str, a: [f64; 3]| -> Result<[f64; 3]> {
        for (i, x) in a.iter().enumerate() {
            finite(&format!("{f}[{i}]"), *x)?;
        }
        Ok(a)
    };
    if let Some(a) = t.start_ned_m {
        s.start_ned_m = finite3("start_ned_m", a)?;
    }
    if let Some(a) = t.target_ned_m {
        s.target_ned_m = finite3("target_ned_m", a)?;
    }
    if let Some(v) = t.start_yaw_deg {
        s.start_yaw_rad = finite("start_yaw_deg", v)?.to_radians();
    }
    if let Some(v) = t.target_yaw_deg {
        s.target_yaw_rad = finite("target_yaw_deg", v)?.to_radians();
    }
    if let Some(v) = t.radius_m {
        s.radius_m = physical(path, "radius_m", v, false)?;
    }
    if let Some(v) = t.period_s {
        s.period_s = physical(path, "period_s", v, false)?;
    }
    if let Some(v) = t.climb_rate_mps {
        s.climb_rate_mps = finite("climb_rate_mps", v)?;
    }
    if let Some(v) = t.duration_s {
        s.duration_s = physical(path, "duration_s", v, false)?;
    }
    s.validate().map_err(|e| anyhow::anyhow!("{}: {e}", path.display()))?;
    Ok(s)
}

/// The `[sensors]` table of a scenario file's text over `SensorConfig::new`
/// (mocap, seed 1, a BMI088, no faults); `None` if the file has none.
pub fn sensors_from_str(path: &Path, text: &str) -> Result<Option<SensorConfig>> {
    let t: ScenarioToml = parse(path, text)?;
    let Some(st) = t.sensors else { return Ok(None) };
    let mut c = SensorConfig::new(st.profile.unwrap_or(FixProfile::Mocap), st.seed.unwrap_or(1));
    let time = |f: &str, v: f64| -> Result<f64> {
        if v.is_finite() && v >= 0.0 {
            Ok(v)
        } else {
            bail!("{}: field `sensors.{f}` = {v} must be a time ≥ 0 s", path.display())
        }
    };
    let window = |f: &str, w: [f64; 2]| -> Result<(f64, f64)> {
        if w.iter().all(|v| v.is_finite()) && w[0] >= 0.0 && w[1] > 0.0 {
            Ok((w[0], w[1]))
        } else {
            bail!(
                "{}: field `sensors.{f}` = {w:?} must be [start ≥ 0, length > 0] s",
                path.display()
            )
        }
    };
    if let Some(v) = st.gyro_noise_dps_rthz {
        c.imu.gyro_noise = physical(path, "sensors.gyro_noise_dps_rthz", v, true)?.to_radians();
    }
    if let Some(v) = st.accel_noise_ug_rthz {
        c.imu.accel_noise = physical(path, "sensors.accel_noise_ug_rthz", v, true)? * 1e-6 * 9.80665;
    }
    c.faults.outage = st.fix_outage_s.map(|w| window("fix_outage_s", w)).transpose()?;
    c.faults.imu_stuck = st.imu_stuck_s.map(|w| window("imu_stuck_s", w)).transpose()?;
    c.faults.outlier_at_s = st.fix_outlier_at_s.map(|v| time("fix_outlier_at_s", v)).transpose()?;
    c.faults.imu_nan_at_s = st.imu_nan_at_s.map(|v| time("imu_nan_at_s", v)).transpose()?;
    c.faults.accel_clip_at_s = st.accel_clip_at_s.map(|v| time("accel_clip_at_s", v)).transpose()?;
    Ok(Some(c))
}

/// Reads a scenario file's `[sensors]` table (see the module docs).
pub fn load_sensors(path: &Path) -> Result<Option<SensorConfig>> {
    sensors_from_str(path, &read(path)?)
}

/// Reads a scenario file (see the module docs).
pub fn load_scenario(path: &Path, default_kind: ScenarioKind) -> Result<Scenario> {
    scenario_from_str(path, &read(path)?, default_kind)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn p() -> &'static Path {
        Path::new("test.toml")
    }

    #[test]
    fn empty_files_are_the_defaults() {
        assert_eq!(vehicle_from_str(p(), "").unwrap(), VehicleParams::OS4);
        assert_eq!(
            scenario_from_str(p(), "", ScenarioKind::Circle).unwrap(),
            Scenario::default_for(ScenarioKind::Circle)
        );
    }

    #[test]
    fn fields_override_the_defaults() {
        let v = vehicle_from_str(p(), "mass_kg = 0.8\ninertia_kgm2 = [0.01, 0.01, 0.02]\n").unwrap();
        assert_eq!(v.mass_kg, 0.8);
        assert_eq!(v.inertia_kgm2, [0.01, 0.01, 0.02]);
        assert_eq!(v.arm_m, VehicleParams::OS4.arm_m);
        let s = scenario_from_str(
            p(),
            "kind = \"helix\"\nradius_m = 3\ntarget_yaw_deg = 90\n",
            ScenarioKind::Setpoint,
        )
        .unwrap();
        assert_eq!(s.kind, ScenarioKind::Helix);
        let text = "kind = \"helix\"\n[sensors]\nprofile = \"gps\"\nseed = 7\nfix_outage_s = [10.0, 2.0]\n\
                    gyro_noise_dps_rthz = 0.028\n";
        let c = sensors_from_str(p(), text).unwrap().unwrap();
        assert_eq!(
            (c.profile, c.seed, c.faults.outage),
            (FixProfile::Gps, 7, Some((10.0, 2.0)))
        );
        assert!((c.imu.gyro_noise - 2.0 * crate::sensors::ImuModel::BMI088.gyro_noise).abs() < 1e-12);
        // The scenario part of the same file still parses, the table aside.
        assert_eq!(
            scenario_from_str(p(), text, ScenarioKind::Setpoint).unwrap().kind,
            ScenarioKind::Helix
        );
        assert_eq!(sensors_from_str(p(), "kind = \"helix\"").unwrap(), None);
        assert_eq!(s.radius_m, 3.0);
        assert!((s.target_yaw_rad - std::f64::consts::FRAC_PI_2).abs() < 1e-15);
    }

    #[test]
    fn bad_files_name_the_field() {
        for (text, field) in [
            ("masss_kg = 0.7", "masss_kg"),
            ("mass_kg = \"heavy\"", "mass_kg"),
            ("mass_kg = -1.0", "mass_kg"),
            ("inertia_kgm2 = [0.1, 0.1]", "inertia_kgm2"),
            ("kt_nspm = [0.1, -0.1, 0.1]", "kt_nspm[1]"),
            ("mass_kg = 5.0", "mass_kg"), // cannot hover: thrust < 1.2 weight
        ] {
            let e = vehicle_from_str(p(), text).unwrap_err().to_string();
            assert!(e.contains(field), "{text:?}: {e}");
            assert!(e.contains("test.toml"), "{e}");
        }
        for (text, field) in [
            ("radius = 2.0", "radius"),
            ("kind = \"spiral\"", "kind"),
            ("period_s = 0.0", "period_s"),
            ("duration_s = nan", "duration_s"),
            ("[sensors]\nprofile = \"radar\"", "profile"),
            ("[sensors]\nfix_outage_s = [1.0, -2.0]", "sensors.fix_outage_s"),
            ("[sensors]\nimu_nan_at_s = -1.0", "sensors.imu_nan_at_s"),
            ("[sensors]\ngyro_noise = 1.0", "gyro_noise"),
        ] {
            if text.starts_with("[sensors]") {
                let e = sensors_from_str(p(), text).unwrap_err().to_string();
                assert!(e.contains(field), "{text:?}: {e}");
                continue;
            }
            let e = scenario_from_str(p(), text, ScenarioKind::Circle)
                .unwrap_err()
                .to_string();
            assert!(e.contains(field), "{text:?}: {e}");
        }
    }
}
