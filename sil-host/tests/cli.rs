//! The `sil-host` binary: options, CSV layout, errors.

use std::process::Command;

fn sil_host() -> Command {
    Command::new(env!("CARGO_BIN_EXE_sil-host"))
}

#[test]
fn open_loop_writes_the_documented_csv() {
    let dir = std::env::temp_dir().join(format!("sil-host-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let csv = dir.join("ol.csv");
    let out = sil_host()
        .args([
            "open-loop",
            "--model",
            "euler",
            "--u",
            "6.4765,0.001,0,0.01",
            "--duration",
            "3",
            "--csv",
        ])
        .arg(&csv)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = std::fs::read_to_string(&csv).unwrap();
    let mut lines = text.lines();
    assert_eq!(
        lines.next().unwrap(),
        "t,x,y,z,vx,vy,vz,q0,q1,q2,q3,phi,theta,psi,p,q,r,u1,u2,u3,u4"
    );
    let rows: Vec<Vec<f64>> = lines
        .map(|l| l.split(',').map(|v| v.parse().unwrap()).collect())
        .collect();
    assert_eq!(rows.len(), 301, "one row per 10 ms including t = 0 and t = 3 s");
    for (k, r) in rows.iter().enumerate() {
        assert_eq!(r.len(), 21);
        assert!((r[0] - k as f64 * 0.01).abs() < 1e-9);
        // Quaternion columns are a unit quaternion consistent with the Euler columns.
        let n = (r[7] * r[7] + r[8] * r[8] + r[9] * r[9] + r[10] * r[10]).sqrt();
        assert!((n - 1.0).abs() < 1e-9);
    }
    // Yaw torque 0.01 N·m: yaw rate heads to U4/krz = 0.0667 rad/s.
    assert!((rows[300][16] - 0.01 / 0.15).abs() < 1e-4);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn bad_options_are_rejected_with_a_message() {
    for args in [
        vec!["open-loop", "--u", "1,2,3"],
        vec!["open-loop", "--u", "1,2,3,nan"],
        vec!["open-loop", "--u", "6,0,0,0", "--duration", "-1"],
        vec!["open-loop", "--u", "6,0,0,0", "--disturbance", "storm"],
        vec!["open-loop", "--u", "6,0,0,0", "--model", "rodrigues"],
    ] {
        let out = sil_host().args(&args).output().unwrap();
        assert!(!out.status.success(), "{args:?} should fail");
        assert!(!out.stderr.is_empty());
    }
}

#[test]
fn help_explains_every_option() {
    let out = sil_host().args(["open-loop", "--help"]).output().unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    for opt in [
        "--model",
        "--u",
        "--duration",
        "--csv",
        "--rotor-lag",
        "--disturbance",
        "--integration-hz",
        "--start",
    ] {
        assert!(text.contains(opt), "help lacks {opt}");
    }
}
