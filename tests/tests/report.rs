//! The main job: `sil-host report --quick` writes its index (Markdown and
//! self-contained HTML) and every figure it links, and its numbers are the
//! metrics of the same flights flown alone.

use fc_core::control::{Family, Preset};
use sil_host::disturbance::DisturbanceSet;
use sil_host::flight::fly;
use sil_host::full_report::{missing_links, write_report, ReportOptions};
use sil_host::study::{find, Sel};
use sil_host::{AttitudeForm, ScenarioKind};

#[test]
fn quick_report_is_complete_and_its_numbers_are_single_flights() {
    let dir = std::env::temp_dir().join(format!("sil-report-test-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let w = write_report(&ReportOptions {
        out: dir.clone(),
        quick: true,
        progress: false,
        qemu: false,
    })
    .unwrap();

    // Index, HTML and every linked file exist; figures are real SVG/PNG.
    let md = std::fs::read_to_string(&w.index_md).unwrap();
    let html = std::fs::read_to_string(&w.index_html).unwrap();
    assert!(md.contains("## Headline") && md.contains("Table") && md.contains("## Figures"));
    assert_eq!(missing_links(&w.index_md).unwrap(), Vec::<String>::new());
    assert!(w.figures.len() >= 28, "{} figure files", w.figures.len());
    for f in &w.figures {
        let bytes = std::fs::read(f).unwrap_or_else(|e| panic!("{}: {e}", f.display()));
        match f.extension().and_then(|e| e.to_str()) {
            Some("png") => assert_eq!(&bytes[1..4], b"PNG", "{}", f.display()),
            _ => assert!(String::from_utf8_lossy(&bytes).contains("<svg"), "{}", f.display()),
        }
        // Linked from the index.
        let name = f.file_name().unwrap().to_string_lossy().into_owned();
        assert!(md.contains(&name), "{name} is not linked from index.md");
    }
    // The HTML stands alone: figures inlined, no external images.
    assert!(html.matches("<svg").count() >= 14);
    assert!(!html.contains("<img"));
    // QEMU was not requested: the table says so instead of silently vanishing.
    assert!(md.contains("not requested"));
    // Flying from sensors: truth beside estimate for PD, LQR and the fast
    // MPC, calm and wind,mismatch, and the five ±3σ figures.
    let sensors = &md[md.find("## Flying from sensors").expect("the sensor section")..];
    let rows = sensors
        .lines()
        .filter(|l| l.starts_with("| PD |") || l.starts_with("| LQR |") || l.starts_with("| MPC fast |"));
    assert_eq!(rows.count(), 6, "{sensors}");
    for g in ["position", "velocity", "attitude", "gyro_bias", "accel_bias"] {
        assert!(sensors.contains(&format!("figures/estimate_{g}.svg")), "{g}");
    }

    // Numbers in the tables are the metrics of the same flight flown alone.
    let cases = [
        (
            Family::Pd,
            Preset::Project,
            AttitudeForm::Euler,
            ScenarioKind::Setpoint,
            DisturbanceSet::NONE,
        ),
        (
            Family::Mpc,
            Preset::Project,
            AttitudeForm::Quaternion,
            ScenarioKind::Helix,
            DisturbanceSet {
                wind: true,
                mismatch: true,
            },
        ),
        (
            Family::Lqr,
            Preset::Project,
            AttitudeForm::Quaternion,
            ScenarioKind::Circle,
            DisturbanceSet::NONE,
        ),
    ];
    for (fam, preset, model, kind, d) in cases {
        let o = find(&w.outcomes, fam, model, kind, d, Sel::defaults(preset)).expect("case in the study");
        let alone = fly(&o.cfg).unwrap();
        assert_eq!(o.res.metrics, alone.metrics, "{fam:?} {model:?} {kind:?} {d}");
    }
    // And the printed cells carry them: the PD Euler set-point block.
    let pd = find(
        &w.outcomes,
        Family::Pd,
        AttitudeForm::Euler,
        ScenarioKind::Setpoint,
        DisturbanceSet::NONE,
        Sel::defaults(Preset::Project),
    )
    .unwrap();
    let alone = fly(&pd.cfg).unwrap();
    let x = format!("| x | 3 m | **{:.2}** (4.09) |", alone.metrics.x.settling_s.unwrap());
    let z = format!("| z | −5 m | **{:.2}** (1.77) |", alone.metrics.z.settling_s.unwrap());
    assert!(md.contains(&x), "{x}");
    assert!(md.contains(&z), "{z}");
    // The headline's helix numbers for the fast MPC, recomputed from single flights.
    let helix = |d| {
        let o = find(
            &w.outcomes,
            Family::Mpc,
            AttitudeForm::Quaternion,
            ScenarioKind::Helix,
            d,
            Sel::defaults(Preset::Project),
        )
        .unwrap();
        let m = fly(&o.cfg).unwrap().metrics;
        format!("{:.3}", m.x.rmse_m.max(m.y.rmse_m).max(m.z.rmse_m))
    };
    let row = md
        .lines()
        .find(|l| l.starts_with("| MPC fast |"))
        .expect("headline row");
    let cells: Vec<&str> = row.split('|').map(str::trim).collect();
    assert_eq!(cells[4], helix(DisturbanceSet::NONE), "{row}");
    assert_eq!(
        cells[5],
        helix(DisturbanceSet {
            wind: true,
            mismatch: true
        }),
        "{row}"
    );

    // The sensor-noise table: the fast MPC's cell at noise × 1 is the windy
    // helix (20 s in --quick) flown alone with that noise.
    let section = md.split("## Sensor noise").nth(1).expect("sensor-noise section");
    let row = section
        .lines()
        .find(|l| l.starts_with("| MPC fast |"))
        .expect("noise row");
    let cells: Vec<&str> = row.split('|').map(str::trim).collect();
    let mut sc = sil_host::Scenario::default_for(ScenarioKind::Helix);
    sc.duration_s = 20.0;
    let mut cfg = sil_host::flight::FlightConfig::new(Family::Mpc, AttitudeForm::Quaternion, sc);
    cfg.disturbance = "wind".parse().unwrap();
    cfg.noise = Some(sil_host::noise::SensorNoise::typical(1.0, 1).unwrap());
    let rmse = fly(&cfg).unwrap().metrics.position_rmse_m();
    assert_eq!(cells[3], format!("{rmse:.4}"), "{row}");
    std::fs::remove_dir_all(&dir).unwrap();
}
