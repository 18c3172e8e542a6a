//! One description of a controller, [`ControllerSpec`], and the one table
//! ([`SPECS`]) that decides every name and wire id.
//!
//! A spec is four small enums: the [`Family`] (PD, LQR, MPC), the
//! [`AttitudeForm`] it is written in, the [`Preset`] of gains or MPC
//! settings, and the [`ReferenceMode`]. From it, without designing anything,
//! you get the controller's name, its execution period and its reference
//! preview; [`ControllerSpec::build`] designs it (Riccati, MPC condensing)
//! into an [`AnyController`]; [`ControllerSpec::to_wire`] and
//! [`ControllerSpec::from_wire`] give the byte the wire protocol's `Select`
//! message carries. The host's command line, the study's tables, the flight
//! loop on the MCU and the wire all go through here.

use super::{
    lqr_euler, lqr_quat, lqr_table::inputs_weighted_for, observer::AccelObserver, AnyController, ControlError, LqrQuat,
    MpcConfig, MpcFast, MpcThesis, PdEuler, PdEulerGains, PdQuatGains, ReferenceMode, Tuning,
};
use crate::model::{AttitudeForm, VehicleParams};
use core::fmt;
use nalgebra::RealField;

/// Controller family.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(rename_all = "lowercase")
)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Family {
    /// PD on position and attitude (thesis §3.6; Tables 4.1–4.4).
    Pd,
    /// LQR about hover, heading-scheduled (thesis §3.7; Tables 4.5–4.8).
    Lqr,
    /// Linear MPC with the core's QP solver (thesis §3.8).
    Mpc,
}

/// Gain set or MPC preset.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(
    feature = "serde",
    derive(serde::Serialize, serde::Deserialize),
    serde(rename_all = "lowercase")
)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Preset {
    /// The project's values: PD `tuned` gains ([`PdEulerGains::tuned`]),
    /// the MPC `fast` preset ([`MpcConfig::fast`]); the LQR's are the
    /// thesis weights designed at the control rate (it has no other set yet).
    Project,
    /// The thesis' printed values: PD Tables 4.1–4.4, the MPC of Appendix C,
    /// the LQR weights of Tables 4.5/4.7.
    Thesis,
}

/// Everything that chooses a controller.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
#[cfg_attr(feature = "serde", derive(serde::Serialize, serde::Deserialize))]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct ControllerSpec {
    /// PD, LQR or MPC.
    pub family: Family,
    /// Euler-angle or quaternion form.
    pub form: AttitudeForm,
    /// Gains or MPC preset.
    pub preset: Preset,
    /// Whether the reference's derivatives are fed forward.
    pub reference: ReferenceMode,
}

/// One row of [`SPECS`]: a family, form and preset with its names and wire id.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SpecRow {
    /// Family.
    pub family: Family,
    /// Attitude form.
    pub form: AttitudeForm,
    /// Preset.
    pub preset: Preset,
    /// Command-line and file name, e.g. `mpc-fast-quaternion`.
    pub name: &'static str,
    /// Title in tables and figures, e.g. `MPC fast` (the form is a column of its own).
    pub title: &'static str,
    /// The preset's own name for its family (`tuned`, `fast`, `thesis`).
    pub preset_name: &'static str,
    /// The byte `Select` carries (protocol v2); `None`: not selectable over the wire.
    pub wire_id: Option<u8>,
}

const fn row(
    family: Family,
    form: AttitudeForm,
    preset: Preset,
    name: &'static str,
    title: &'static str,
    preset_name: &'static str,
    wire_id: Option<u8>,
) -> SpecRow {
    SpecRow {
        family,
        form,
        preset,
        name,
        title,
        preset_name,
        wire_id,
    }
}

use AttitudeForm::{Euler, Quaternion};
use Family::{Lqr, Mpc, Pd};
use Preset::{Project, Thesis};

/// Every controller the core can build, in the order tables list them, with
/// its names and its wire id. This table is the only place these are spelled.
pub const SPECS: [SpecRow; 12] = [
    row(Pd, Euler, Project, "pd-euler", "PD", "tuned", Some(0)),
    row(Pd, Quaternion, Project, "pd-quaternion", "PD", "tuned", Some(1)),
    row(Lqr, Euler, Project, "lqr-euler", "LQR", "tuned", Some(2)),
    row(Lqr, Quaternion, Project, "lqr-quaternion", "LQR", "tuned", Some(3)),
    row(Mpc, Euler, Project, "mpc-fast-euler", "MPC fast", "fast", Some(4)),
    row(
        Mpc,
        Quaternion,
        Project,
        "mpc-fast-quaternion",
        "MPC fast",
        "fast",
        Some(5),
    ),
    row(Mpc, Euler, Thesis, "mpc-thesis-euler", "MPC thesis", "thesis", Some(6)),
    row(
        Mpc,
        Quaternion,
        Thesis,
        "mpc-thesis-quaternion",
        "MPC thesis",
        "thesis",
        Some(7),
    ),
    row(Pd, Euler, Thesis, "pd-thesis-euler", "PD", "thesis", None),
    row(Pd, Quaternion, Thesis, "pd-thesis-quaternion", "PD", "thesis", None),
    row(Lqr, Euler, Thesis, "lqr-thesis-euler", "LQR", "thesis", None),
    row(Lqr, Quaternion, Thesis, "lqr-thesis-quaternion", "LQR", "thesis", None),
];

/// Time constant of the force part of the PD's and LQR's disturbance
/// observer (their integral action, [`AccelObserver`]), s. 50 ms cancels
/// most of the `wind` scenario's 0.5 Hz gust (the set-point under `wind`
/// ends within 3 cm; 0.1 s left 3.3 cm); shorter passes more sensor noise
/// into the attitude target (`sil-host fly --noise 1`: the LQR's u_norm
/// doubled at 30 ms). The robustness sweep flies every vehicle in the tube
/// at any value tried from 30 ms to 0.3 s.
pub const INTEGRAL_TAU_S: f64 = 0.05;

/// Time constant of the observer's moment part, s. Slow on purpose: with
/// slow rotors the torque not yet delivered looks like a moment
/// disturbance; at 2 ms–0.2 s the robustness sweep lost 1–13 % of its
/// vehicles to the attitude loop, at 1 s none (docs/book/src/model.md §8.6).
pub const INTEGRAL_MOMENT_TAU_S: f64 = 1.0;

/// Why a specification could not be read or sent.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum SpecError {
    /// No controller has this wire id.
    UnknownWireId(u8),
    /// This controller has no wire id (it is not selectable over the link).
    NotOnWire(ControllerSpec),
}

impl fmt::Display for SpecError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            SpecError::UnknownWireId(id) => write!(f, "no controller has wire id {id}"),
            SpecError::NotOnWire(s) => write!(
                f,
                "{} ({} gains) cannot be selected over the link: the flight controller offers only the ids of the wire table",
                s.row().name,
                s.row().preset_name
            ),
        }
    }
}

impl core::error::Error for SpecError {}

impl Family {
    /// Every family, in table order.
    pub const ALL: [Family; 3] = [Pd, Lqr, Mpc];

    /// Lower-case name (`pd`, `lqr`, `mpc`): command line, JSON, file names.
    pub const fn name(self) -> &'static str {
        match self {
            Pd => "pd",
            Lqr => "lqr",
            Mpc => "mpc",
        }
    }

    /// Title in tables (`PD`, `LQR`, `MPC`).
    pub const fn title(self) -> &'static str {
        match self {
            Pd => "PD",
            Lqr => "LQR",
            Mpc => "MPC",
        }
    }
}

impl ControllerSpec {
    /// A controller of `family` in `form`: the project's preset, reference fed forward.
    pub const fn new(family: Family, form: AttitudeForm) -> Self {
        Self {
            family,
            form,
            preset: Project,
            reference: ReferenceMode::Feedforward,
        }
    }

    /// The same with preset `preset`.
    pub const fn with_preset(mut self, preset: Preset) -> Self {
        self.preset = preset;
        self
    }

    /// The same with reference mode `reference`.
    pub const fn with_reference(mut self, reference: ReferenceMode) -> Self {
        self.reference = reference;
        self
    }

    /// This spec's row of [`SPECS`] (every family × form × preset has one).
    pub fn row(&self) -> &'static SpecRow {
        let mut i = 0;
        while i < SPECS.len() {
            let r = &SPECS[i];
            if r.family == self.family && r.form == self.form && r.preset == self.preset {
                return r;
            }
            i += 1;
        }
        // SPECS lists all 2 × 3 × 2 combinations (checked by a unit test).
        &SPECS[0]
    }

    /// Command-line and file name, e.g. `mpc-fast-quaternion`.
    pub fn name(&self) -> &'static str {
        self.row().name
    }

    /// Title in tables, e.g. `MPC fast` (form and reference mode not included).
    pub fn title(&self) -> &'static str {
        self.row().title
    }

    /// The MPC configuration of this spec's preset (`None` for PD and LQR).
    pub fn mpc_config(&self) -> Option<MpcConfig> {
        match (self.family, self.preset) {
            (Mpc, Project) => Some(MpcConfig::fast(self.form)),
            (Mpc, Thesis) => Some(MpcConfig::thesis(self.form)),
            _ => None,
        }
    }

    /// The execution period the controller fixes itself, s: the MPC
    /// presets' (`None` for PD and LQR, which run at any rate).
    pub fn own_period_s(&self) -> Option<f64> {
        self.mpc_config().map(|c| c.exec_dt_s)
    }

    /// How often the controller runs, s: [`ControllerSpec::own_period_s`],
    /// else `control_period_s` (PD and LQR).
    pub fn period_s(&self, control_period_s: f64) -> f64 {
        self.own_period_s().unwrap_or(control_period_s)
    }

    /// The reference preview the controller wants before each step:
    /// `(points, spacing s)`; `None` for PD and LQR.
    pub fn preview(&self) -> Option<(usize, f64)> {
        let cfg = self.mpc_config()?;
        let n = match self.preset {
            Project => MpcFast::<f32>::HORIZON,
            Thesis => MpcThesis::<f32>::HORIZON,
        };
        Some((n, cfg.pred_dt_s))
    }

    /// Designs the controller for the vehicle `p`, PD and LQR at
    /// `control_period_s` (s), with the project's tuning ([`Tuning::project`]).
    pub fn build<T: RealField + Copy>(
        &self,
        p: VehicleParams<T>,
        control_period_s: f64,
    ) -> Result<AnyController<T>, ControlError> {
        self.build_with(p, control_period_s, None, &Tuning::project())
    }

    /// [`ControllerSpec::build`] with an MPC configuration replacing the
    /// preset's (tuning, sweeps; the sizes stay the preset's; ignored by PD
    /// and LQR) and the user's gains and weights `tuning`.
    pub fn build_with<T: RealField + Copy>(
        &self,
        p: VehicleParams<T>,
        control_period_s: f64,
        mpc: Option<MpcConfig>,
        tuning: &Tuning,
    ) -> Result<AnyController<T>, ControlError> {
        let mut c = AnyController::PdEuler(PdEuler::new(p, PdEulerGains::tuned(), self.reference));
        self.build_in(&mut c, p, control_period_s, mpc, tuning)?;
        Ok(c)
    }

    /// Builds the controller in place, in `slot` (the controller it held is
    /// replaced): what the firmware does, so that the large controllers
    /// (MPC, scheduled LQR, ≈ 7 KiB each) are designed where they live
    /// instead of being built on the stack and moved. `mpc` and `tuning` as
    /// in [`ControllerSpec::build_with`]: the project preset's PD takes its
    /// gains from `tuning` (the thesis preset's are the printed tables), and
    /// both presets' LQR and MPC weights are scaled by its multipliers. On
    /// error `slot` holds no usable controller: build one again (the flight
    /// loop rebuilds the previous).
    pub fn build_in<T: RealField + Copy>(
        &self,
        slot: &mut AnyController<T>,
        p: VehicleParams<T>,
        control_period_s: f64,
        mpc: Option<MpcConfig>,
        tuning: &Tuning,
    ) -> Result<(), ControlError> {
        let mode = self.reference;
        let ts = control_period_s;
        // Integral action (the disturbance observer) in the project's PD and
        // LQR; the thesis' printed controllers have none.
        let obs = match self.preset {
            // At a slow control rate (a period above τ) the estimate takes
            // each step's whole innovation: τ is at least one period.
            Project => AccelObserver::new(
                INTEGRAL_TAU_S.max(ts),
                INTEGRAL_MOMENT_TAU_S.max(ts),
                ts,
                p.cast::<f64>().gravity_mps2,
            )?,
            Thesis => AccelObserver::off(),
        };
        let mpc_config = |preset: fn(AttitudeForm) -> MpcConfig, form| {
            let mut cfg = mpc.unwrap_or(preset(form));
            tuning.apply_mpc(&mut cfg);
            cfg
        };
        match (self.family, self.form, self.preset) {
            (Pd, Euler, Project) => slot.become_pdeuler(p, PdEulerGains::from_tuning(tuning, &p), mode, obs),
            // The printed gains are the OS4's; the attitude loops keep their dynamics on `p`.
            (Pd, Euler, Thesis) => slot.become_pdeuler(p, PdEulerGains::thesis().for_vehicle(&p), mode, obs),
            (Pd, Quaternion, Project) => slot.become_pdquat(p, PdQuatGains::from_tuning(tuning, &p), mode, obs),
            (Pd, Quaternion, Thesis) => slot.become_pdquat(p, PdQuatGains::thesis().for_vehicle(&p), mode, obs),
            (Lqr, Euler, _) => {
                if !matches!(slot, AnyController::LqrEuler(_)) {
                    slot.become_lqreuler(p, mode);
                }
                if let AnyController::LqrEuler(c) = slot {
                    let (mut q, r) = match self.preset {
                        Project => lqr_euler::tuned_weights(),
                        Thesis => lqr_euler::euler_weights(),
                    };
                    // The weights are the OS4's; the inputs keep their relative cost.
                    let mut r = inputs_weighted_for(&r, &p);
                    tuning.lqr.apply_lqr(&mut q, &mut r);
                    c.redesign(p, &q, &r, ts, mode)?;
                    c.set_observer(obs.smoothed());
                }
            }
            (Lqr, Quaternion, preset) => {
                let (mut q, r) = match preset {
                    Project => lqr_quat::tuned_weights(),
                    Thesis => lqr_quat::quat_weights(),
                };
                let mut r = inputs_weighted_for(&r, &p);
                tuning.lqr.apply_lqr(&mut q, &mut r);
                slot.become_lqrquat(LqrQuat::new(p, &q, &r, ts, mode)?.with_observer(obs.smoothed()))
            }
            (Mpc, form, Project) => {
                let cfg = mpc_config(MpcConfig::fast, form);
                if !matches!(slot, AnyController::MpcFast(_)) {
                    slot.become_mpcfast(p, cfg);
                }
                if let AnyController::MpcFast(c) = slot {
                    c.redesign(p, cfg)?;
                }
            }
            (Mpc, form, Thesis) => {
                let cfg = mpc_config(MpcConfig::thesis, form);
                if !matches!(slot, AnyController::MpcThesis(_)) {
                    slot.become_mpcthesis(p, cfg);
                }
                if let AnyController::MpcThesis(c) = slot {
                    c.redesign(p, cfg)?;
                }
            }
        }
        Ok(())
    }

    /// The wire form: `(id, feedforward)` as the protocol's `Select` carries it.
    pub fn to_wire(&self) -> Result<(u8, bool), SpecError> {
        let id = self.row().wire_id.ok_or(SpecError::NotOnWire(*self))?;
        Ok((id, self.reference == ReferenceMode::Feedforward))
    }

    /// The spec a `Select{controller: id, feedforward}` names.
    pub fn from_wire(id: u8, feedforward: bool) -> Result<Self, SpecError> {
        let r = SPECS
            .iter()
            .find(|r| r.wire_id == Some(id))
            .ok_or(SpecError::UnknownWireId(id))?;
        let reference = if feedforward {
            ReferenceMode::Feedforward
        } else {
            ReferenceMode::Thesis
        };
        Ok(Self {
            family: r.family,
            form: r.form,
            preset: r.preset,
            reference,
        })
    }
}

impl fmt::Display for ControllerSpec {
    /// `name` plus `, thesis reference` when the reference is not fed forward.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())?;
        if self.reference == ReferenceMode::Thesis {
            f.write_str(", thesis reference")?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_combination_has_exactly_one_row() {
        for family in Family::ALL {
            for form in AttitudeForm::ALL {
                for preset in [Project, Thesis] {
                    let n = SPECS
                        .iter()
                        .filter(|r| r.family == family && r.form == form && r.preset == preset)
                        .count();
                    assert_eq!(n, 1, "{family:?} {form:?} {preset:?}");
                    let s = ControllerSpec::new(family, form).with_preset(preset);
                    assert_eq!((s.row().family, s.row().form, s.row().preset), (family, form, preset));
                }
            }
        }
    }

    #[test]
    fn names_and_wire_ids_are_unique_and_round_trip() {
        for (i, a) in SPECS.iter().enumerate() {
            for b in &SPECS[i + 1..] {
                assert_ne!(a.name, b.name);
                assert!(a.wire_id.is_none() || a.wire_id != b.wire_id, "{} {}", a.name, b.name);
            }
            let s = ControllerSpec::new(a.family, a.form).with_preset(a.preset);
            for reference in [ReferenceMode::Feedforward, ReferenceMode::Thesis] {
                let s = s.with_reference(reference);
                match s.to_wire() {
                    Ok((id, ff)) => assert_eq!(ControllerSpec::from_wire(id, ff), Ok(s)),
                    Err(e) => assert_eq!(e, SpecError::NotOnWire(s)),
                }
            }
        }
        assert_eq!(ControllerSpec::from_wire(200, true), Err(SpecError::UnknownWireId(200)));
    }

    #[test]
    fn designing_in_place_over_any_controller_equals_a_fresh_design() {
        // Every spec built into a slot that held every other spec (the state
        // a flight controller's slot is in after a selection) must be the
        // controller a fresh build gives, to the bit: nothing of the
        // previous occupant (gains, Hessian, observer state) survives.
        extern crate std;
        use std::format;
        let p = VehicleParams::<f32>::os4();
        let specs: std::vec::Vec<ControllerSpec> = SPECS
            .iter()
            .map(|r| ControllerSpec::new(r.family, r.form).with_preset(r.preset))
            .collect();
        for s in &specs {
            let fresh = format!("{:?}", s.build(p, 0.001).expect("design"));
            for before in &specs {
                let mut slot = before.build(p, 0.001).expect("design");
                // Fly it a little, off the setpoint, so its run-time state is not the initial one.
                let sp = crate::control::Setpoint::hold(nalgebra::Vector3::new(0.0, 0.0, -1.0), 0.0);
                let est = crate::control::StateEstimate {
                    pos_ned_m: nalgebra::Vector3::new(0.3, -0.2, -0.8),
                    vel_ned_mps: nalgebra::Vector3::new(0.1, 0.0, 0.05),
                    att: crate::model::euler_to_quat(0.05, -0.03, 0.2),
                    rates_frd_radps: nalgebra::Vector3::new(0.01, 0.02, -0.01),
                };
                for _ in 0..3 {
                    crate::control::Controller::update(&mut slot, &est, &sp).expect("step");
                }
                s.build_in(&mut slot, p, 0.001, None, &Tuning::project())
                    .expect("design in place");
                assert_eq!(format!("{slot:?}"), fresh, "{} over {}", s.name(), before.name());
            }
        }
    }

    #[test]
    fn every_spec_builds_at_slow_and_fast_control_rates() {
        // The integral action's time constants are shorter than a slow
        // control period (4 Hz, as the thesis MPC runs): building must still
        // work there (it once refused with InvalidParameter).
        let p = VehicleParams::<f32>::os4();
        for r in &SPECS {
            let s = ControllerSpec::new(r.family, r.form).with_preset(r.preset);
            for ts in [0.0005, 0.002, 0.01, 0.1, 0.25] {
                assert!(s.build(p, ts).is_ok(), "{} at {ts} s", r.name);
            }
        }
    }

    #[test]
    fn period_and_preview_match_the_built_controller() {
        use crate::control::Controller;
        let p = VehicleParams::<f32>::os4();
        for r in &SPECS {
            let s = ControllerSpec::new(r.family, r.form).with_preset(r.preset);
            let c = s.build(p, 0.002).expect("design");
            assert_eq!(s.preview(), c.preview_request(), "{}", r.name);
            assert_eq!(Some(s.period_s(0.002)), c.period_s().or(Some(0.002)), "{}", r.name);
        }
    }
}
