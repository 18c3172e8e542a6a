//! A flight written to a file is streamed, not held: the CSV and the metrics
//! of a streamed flight equal those of the same flight kept in memory.

use fc_core::control::Family;
use sil_host::flight::{fly, fly_target_with_progress, FlightConfig, Recording, Target};
use sil_host::metrics::flight_metrics;
use sil_host::record::{write_csv, CsvSink};
use sil_host::{AttitudeForm, Scenario, ScenarioKind};

#[test]
fn a_streamed_flight_writes_and_measures_what_a_kept_one_does() {
    let dir = std::env::temp_dir().join(format!("sil-host-recording-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    for (family, kind) in [(Family::Pd, ScenarioKind::Setpoint), (Family::Lqr, ScenarioKind::Helix)] {
        let cfg = FlightConfig::new(family, AttitudeForm::Quaternion, Scenario::default_for(kind));
        let kept = fly(&cfg).unwrap();
        // The metrics computed online equal the ones of the stored trace.
        assert_eq!(
            kept.metrics,
            flight_metrics(&kept.trace, &cfg.vehicle, cfg.scenario.tracking_from_s())
        );

        let (want, got) = (dir.join("kept.csv"), dir.join("streamed.csv"));
        write_csv(&want, &kept.rows, Some(&kept.reference)).unwrap();
        let mut sink = CsvSink::create(&got, true).unwrap();
        let streamed = fly_target_with_progress(&cfg, &Target::InProcess, None, Recording::Stream(&mut sink)).unwrap();
        assert_eq!(sink.finish().unwrap(), kept.rows.len());

        assert!(streamed.rows.is_empty() && streamed.reference.is_empty() && streamed.trace.t.is_empty());
        assert_eq!(streamed.metrics, kept.metrics, "{family:?} {kind:?}");
        assert_eq!(streamed.steps, kept.steps);
        let (a, b) = (
            std::fs::read_to_string(&want).unwrap(),
            std::fs::read_to_string(&got).unwrap(),
        );
        assert_eq!(a.lines().count(), kept.rows.len() + 1);
        assert!(
            a == b,
            "{family:?} {kind:?}: the streamed CSV differs from the kept one"
        );
    }
    let _ = std::fs::remove_dir_all(&dir);
}
