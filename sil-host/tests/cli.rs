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

#[test]
fn an_unusable_output_is_refused_before_any_flight() {
    // `report --out FILE` and `sweep --out FILE` where FILE exists: refused
    // at once (no flight flown, so well under a second), naming the path.
    let file = std::env::temp_dir().join(format!("sil-host-not-a-dir-{}", std::process::id()));
    std::fs::write(&file, b"x").unwrap();
    for cmd in ["report", "sweep"] {
        let t0 = std::time::Instant::now();
        let out = sil_host()
            .args([cmd, "--no-progress", "--out"])
            .arg(&file)
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{cmd}: {err}");
        assert!(
            err.contains("is not a directory") && err.contains(&*file.to_string_lossy()),
            "{cmd}: {err}"
        );
        assert!(t0.elapsed().as_secs_f64() < 5.0, "{cmd} flew before refusing");
    }
    let _ = std::fs::remove_file(&file);
}

#[test]
fn inputs_that_cannot_be_flown_are_refused_by_name_before_flying() {
    // Each: the arguments, and what the message must name. All are refused
    // at once with a non-zero exit: none may hang, allocate without bound or
    // "fly" saturated nonsense.
    let dir = std::env::temp_dir().join(format!("sil-host-refusals-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let vehicle = |name: &str, text: &str| {
        let p = dir.join(name);
        std::fs::write(&p, text).unwrap();
        p.to_string_lossy().into_owned()
    };
    let huge_inertia = vehicle("huge.toml", "inertia_kgm2 = [1e300, 0.0075, 0.013]\n");
    let tiny_inertia = vehicle("tiny.toml", "inertia_kgm2 = [1e-300, 0.0075, 0.013]\n");
    let bad_radius = vehicle("radius.toml", "kind = \"circle\"\nradius_m = -1\n");
    let cf_vehicle = concat!(env!("CARGO_MANIFEST_DIR"), "/../vehicles/crazyflie-rotorpy.toml");
    let cases: Vec<(Vec<&str>, &str)> = vec![
        (
            vec!["fly", "--controller", "lqr", "--duration", "1e300"],
            "(--duration)",
        ),
        (
            vec!["fly", "--controller", "lqr", "--integration-hz", "1e12"],
            "--integration-hz",
        ),
        (
            vec!["fly", "--controller", "lqr", "--duration", "0.1", "--param-flood", "2"],
            "--param-flood needs a flight controller behind a link",
        ),
        (
            vec![
                "fly",
                "--controller",
                "lqr",
                "--target",
                "framed",
                "--param-flood",
                "17",
            ],
            "--param-flood 17 is out of range",
        ),
        (vec!["open-loop", "--u", "6,0,0,0", "--duration", "1e300"], "--duration"),
        (
            vec!["open-loop", "--u", "6,0,0,0", "--integration-hz", "1e12"],
            "--integration-hz",
        ),
        (
            vec!["fly", "--controller", "pd", "--target", "1e300,0,-1,0"],
            "target_ned_m[0]",
        ),
        (
            vec!["fly", "--controller", "pd", "--target", "0,0,-1,1e300"],
            "target_yaw",
        ),
        (
            vec!["fly", "--controller", "pd", "--scenario", "circle", "--radius", "1e9"],
            "radius_m (--radius)",
        ),
        (
            vec!["fly", "--controller", "pd", "--scenario", "circle", "--radius", "-1"],
            "radius_m (--radius)",
        ),
        (
            vec!["fly", "--controller", "pd", "--scenario", "circle", "--radius", "0"],
            "radius_m (--radius)",
        ),
        (
            vec!["fly", "--controller", "pd", "--scenario", "circle", "--period", "1e-9"],
            "horizontal acceleration",
        ),
        (
            vec![
                "fly",
                "--controller",
                "pd",
                "--scenario",
                "helix",
                "--climb-rate",
                "1e300",
            ],
            "climb_rate_mps",
        ),
        (vec!["fly", "--controller", "lqr", "--control-hz", "0"], "--control-hz"),
        (vec!["fly", "--controller", "lqr", "--control-hz", "-5"], "--control-hz"),
        (
            vec!["fly", "--controller", "lqr", "--control-hz", "nan"],
            "--control-hz",
        ),
        (
            vec!["fly", "--controller", "lqr", "--vehicle", &huge_inertia],
            "inertia_kgm2[0]",
        ),
        (
            vec!["fly", "--controller", "lqr", "--vehicle", &tiny_inertia],
            "inertia_kgm2[0]",
        ),
        (
            vec!["fly", "--controller", "lqr", "--scenario-file", &bad_radius],
            "radius_m",
        ),
        (
            vec![
                "px4-hil",
                "--vehicle",
                cf_vehicle,
                "--waypoint",
                "0,0,0,-1",
                "--state",
                "estimated",
            ],
            "unknown --state 'estimated'",
        ),
        (
            vec![
                "px4-hil",
                "--vehicle",
                cf_vehicle,
                "--waypoint",
                "0,0,0,-1",
                "--state",
                "truth",
                "--target",
                "qemu",
            ],
            "--state truth flies the flight controller in this process only",
        ),
    ];
    for (args, names) in cases {
        let t0 = std::time::Instant::now();
        let out = sil_host().args(&args).env("RUST_BACKTRACE", "0").output().unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{args:?} was accepted");
        assert!(
            err.contains(names),
            "{args:?}: the message does not name {names:?}: {err}"
        );
        assert!(t0.elapsed().as_secs_f64() < 10.0, "{args:?} took {:?}", t0.elapsed());
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// The book's command-line chapter is the binary's own reference, generated
/// from the clap definitions, so the two cannot drift apart.
#[test]
fn the_books_cli_chapter_is_the_generated_reference() {
    let out = sil_host().arg("markdown-help").output().unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let chapter = concat!(env!("CARGO_MANIFEST_DIR"), "/../docs/book/src/cli.md");
    let book = std::fs::read_to_string(chapter).unwrap();
    assert!(
        book == String::from_utf8_lossy(&out.stdout),
        "docs/book/src/cli.md is not the CLI's reference: regenerate it with \
         `cargo run -p sil-host -- markdown-help > docs/book/src/cli.md`"
    );
    for command in ["fly", "report", "sweep", "px4-hil", "serve", "--ulog"] {
        assert!(book.contains(command), "the reference names {command}");
    }
}

/// A flight's ULog is read back by another parser (yule_log) and drawn as
/// the report draws its figures: every 10 ms row of the CSV is a sample.
#[test]
fn a_flights_ulog_draws_the_reports_position_figures() {
    let dir = std::env::temp_dir().join(format!("sil-host-plot-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (ulg, csv, figs) = (dir.join("hover.ulg"), dir.join("hover.csv"), dir.join("figs"));
    let out = sil_host()
        .args([
            "fly",
            "--controller",
            "lqr",
            "--scenario",
            "circle",
            "--duration",
            "3",
            "--ulog",
        ])
        .arg(&ulg)
        .arg("--csv")
        .arg(&csv)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let rows = std::fs::read_to_string(&csv).unwrap().lines().count() - 1;
    assert_eq!(rows, 301, "3 s of 10 ms rows");
    let out = sil_host()
        .args(["plot", "--ulog"])
        .arg(&ulg)
        .arg("--out")
        .arg(&figs)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let text = String::from_utf8_lossy(&out.stdout);
    assert!(
        text.contains(&format!(
            "{rows} samples of vehicle_local_position_groundtruth, {rows} set-points"
        )),
        "{text}"
    );
    for stem in ["hover_position", "hover_path_top"] {
        for ext in ["svg", "png"] {
            let f = figs.join(format!("{stem}.{ext}"));
            assert!(
                std::fs::metadata(&f).map(|m| m.len() > 1000).unwrap_or(false),
                "{} drawn",
                f.display()
            );
        }
    }
    // Not a ULog: a clear error, non-zero exit.
    let out = sil_host().args(["plot", "--ulog"]).arg(&csv).output().unwrap();
    assert!(!out.status.success());
    assert!(
        String::from_utf8_lossy(&out.stderr).contains("not a ULog"),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// The JSON's `control_hz` is the rate the controller flew at: the MPC
/// preset's own, not a `--control-hz` it cannot honour (which it refuses).
#[test]
fn the_json_reports_the_rate_flown_and_the_mpc_refuses_a_rate() {
    let rate = |args: &[&str]| -> (f64, u64) {
        let out = sil_host()
            .args(["fly", "--scenario", "setpoint", "--duration", "1", "--json", "-"])
            .args(args)
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        let v: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
        (v["control_hz"].as_f64().unwrap(), v["steps"].as_u64().unwrap())
    };
    assert_eq!(rate(&["--controller", "mpc"]), (1000.0, 1001));
    assert_eq!(rate(&["--controller", "mpc", "--preset", "thesis"]), (4.0, 5));
    assert_eq!(rate(&["--controller", "lqr", "--control-hz", "250"]), (250.0, 251));
    assert_eq!(rate(&["--controller", "pd"]), (500.0, 501));
    let out = sil_host()
        .args(["fly", "--controller", "mpc", "--control-hz", "1000", "--duration", "1"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--control-hz 1000: the MPC's preset fixes its own rate (1000 Hz"),
        "{err}"
    );
}

/// A simulator that hangs up mid-flight ends `px4-hil` with exit 0, a
/// line saying so and the summary (it failed with a backtrace before).
#[test]
fn px4_hil_ends_with_its_summary_when_the_simulator_hangs_up() {
    use fc_mavlink::common::{HilSensorUpdatedFlags, HIL_SENSOR_DATA};
    use fc_mavlink::{encode, MavHeader, MavMessage, MAX_FRAME};
    use std::io::Write;
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    let vehicle = concat!(env!("CARGO_MANIFEST_DIR"), "/../vehicles/crazyflie-rotorpy.toml");
    let mut child = sil_host()
        .args([
            "px4-hil",
            "--vehicle",
            vehicle,
            "--connect",
            &format!("127.0.0.1:{port}"),
        ])
        .args(["--waypoint", "0,0,0,-1", "--duration", "30"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    // Bounded: a px4-hil that exits before connecting fails the test.
    listener.set_nonblocking(true).unwrap();
    let start = std::time::Instant::now();
    let mut sim = loop {
        match listener.accept() {
            Ok((s, _)) => break s,
            Err(_) if start.elapsed().as_secs() < 30 && child.try_wait().unwrap().is_none() => {
                std::thread::sleep(std::time::Duration::from_millis(20))
            }
            Err(e) => {
                let _ = child.kill();
                panic!("px4-hil never connected: {e}; {:?}", child.wait_with_output().unwrap());
            }
        }
    };
    sim.set_nonblocking(false).unwrap();
    let mut buf = [0u8; MAX_FRAME];
    for k in 0..50u64 {
        let header = MavHeader {
            system_id: 1,
            component_id: 51,
            sequence: k as u8,
        };
        let sample = MavMessage::HIL_SENSOR(HIL_SENSOR_DATA {
            time_usec: 1_000_000 + k * 1000,
            zacc: -9.81,
            abs_pressure: 1013.25,
            fields_updated: HilSensorUpdatedFlags::all(),
            ..Default::default()
        });
        let n = encode(header, &sample, &mut buf).unwrap();
        sim.write_all(&buf[..n]).unwrap();
    }
    std::thread::sleep(std::time::Duration::from_millis(300));
    drop(sim);
    let out = child.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "{stderr}");
    let res: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let end = res["end"].as_str().unwrap();
    // Closed with the vehicle's answers unread: the kernel resets the
    // connection (either way it ends the flight).
    assert!(
        end.starts_with("the simulator ") && end.contains(" after 50 steps"),
        "{end}"
    );
    assert_eq!(res["steps"], 50);
    assert!(stderr.contains("the flight ended: the simulator "), "{stderr}");
}
