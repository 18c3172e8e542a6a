//! # sil-host — software-in-the-loop for the flight-control core
//!
//! The nonlinear plant in `f64` built from the core's own equations, the
//! scenarios and disturbances of the study, the metrics, CSV/JSON output, and
//! the `sil-host` command line.
#![deny(missing_docs)]

pub mod config;
pub mod crtp;
pub mod disturbance;
pub mod endpoint;
pub mod estimation;
pub mod estimation_report;
pub mod figures;
pub mod flight;
pub mod flight_log;
pub mod full_report;
pub mod hil;
pub mod html;
pub mod link;
pub mod metrics;
pub mod noise;
pub mod openloop;
pub mod plant;
pub mod record;
pub mod report;
pub mod scenario;
pub mod sensors;
pub mod storage;
pub mod study;
pub mod study_plots;
pub mod sweep;
pub mod ulog;
pub mod ulog_plot;

pub use disturbance::DisturbanceSet;
pub use fc_core::AttitudeForm;
pub use plant::{Plant, PlantConfig};
pub use scenario::{FlatOutput, Scenario, ScenarioKind};
