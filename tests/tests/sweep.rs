//! The robustness sweep as shards: flown in slices (as a job array would)
//! and merged, it must be the one-machine sweep to the bit; a missing or
//! repeated shard must be refused.

use sil_host::sweep::{self, SweepOptions};
use sil_host::{Scenario, ScenarioKind};
use std::path::PathBuf;

fn options(out: PathBuf) -> SweepOptions {
    let mut base = Scenario::default_for(ScenarioKind::Helix);
    base.duration_s = 2.0;
    SweepOptions {
        samples: 5,
        seed: 7,
        progress: false,
        ..SweepOptions::defaults(base, out)
    }
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("sil-host-sweep-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    d
}

#[test]
fn shards_merged_equal_one_run() {
    let whole = sweep::run(&options(tmp("whole"))).unwrap();
    // Three shards into two directories (two machines' outputs).
    let (a, b) = (tmp("a"), tmp("b"));
    sweep::run_shard(&options(a.clone()), (0, 3)).unwrap();
    sweep::run_shard(&options(b.clone()), (1, 3)).unwrap();
    sweep::run_shard(&options(b.clone()), (2, 3)).unwrap();
    let (o, merged) = sweep::merge(&[a.clone(), b.clone()], tmp("merged")).unwrap();
    assert_eq!(o.samples, 5);
    assert_eq!(merged.len(), whole.len());
    for (m, w) in merged.iter().zip(&whole) {
        assert_eq!(m.controller, w.controller);
        assert_eq!(m.flights, w.flights, "{}", m.controller);
        assert_eq!(m.success_pct, w.success_pct);
        assert_eq!(
            format!("{:?}", m.rmse_percentiles_m),
            format!("{:?}", w.rmse_percentiles_m)
        );
    }
    // The files a merge writes are the one-machine sweep's.
    let p = sweep::write(&o, &merged).unwrap();
    let w = sweep::write(&options(tmp("whole")), &whole).unwrap();
    let json = |p: &PathBuf| std::fs::read_to_string(p.with_file_name("sweep.json")).unwrap();
    let strip_out = |s: String| {
        s.lines()
            .filter(|l| !l.contains("\"out\""))
            .collect::<Vec<_>>()
            .join("\n")
    };
    assert_eq!(strip_out(json(&p)), strip_out(json(&w)));
    // A missing shard, and a shard given twice, are refused by name.
    let e = sweep::merge(std::slice::from_ref(&b), tmp("m2"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("shard 0/3 is missing"), "{e}");
    let e = sweep::merge(&[a.clone(), a.clone(), b.clone()], tmp("m3"))
        .unwrap_err()
        .to_string();
    assert!(e.contains("given twice"), "{e}");
    for d in [a, b] {
        let _ = std::fs::remove_dir_all(d);
    }
}
