//! Cycle budgets and stack high-water mark of the STM32F405 image, measured
//! in QEMU (`netduinoplus2`, `-icount shift=0`: one instruction is one
//! nanosecond of virtual time, SysTick counts 0.168 per instruction).
//!
//! For every controller at its rate (PD, LQR and MPC `fast` at 1 kHz, MPC
//! `thesis` at 4 Hz) it measures, over 60 steps of a
//! pseudo-random flight state against a climbing-circle reference (with the
//! MPC's preview):
//! - `control`: instructions in the controller's `update`;
//! - `loop`: instructions in everything the firmware does per step (frame
//!   decoding of setpoint, preview and sensor frames, the controller, the
//!   replies), through [`fc_loop::FlightLoop`] exactly as the image runs it;
//! - for the MPCs, `certified (exact QP)`: the same step held against a
//!   1 kHz budget whatever the preset's rate. The QP is solved exactly by
//!   enumerating every active set of its independent blocks
//!   ([`fc_core::qp::Blocks`]): the same work on every solve, no iteration
//!   count and no early exit, so the worst measured step is the certified
//!   one (up to branches: which candidate wins, clamps);
//! - for the fast MPC, `image step`: the whole step of the image at 1 kHz
//!   (IMU sample and a fix in, estimator, MPC, output), as the image itself
//!   counts it, enforced at
//!   [`fc_stm32f405::budgets::IMAGE_STEP_INSTRUCTIONS`]; and the same with
//!   the lockstep link's frames, for information;
//! - and `FGM to its a-priori bound, info`: the fast gradient method the
//!   exact solve replaced, forced to run its whole certified iteration
//!   bound, for comparison;
//! - and the CRTP link's longest hold of the vehicle over the packets that
//!   take it longest (`holds.rs`), enforced at
//!   [`fc_stm32f405::budgets::LINK_HOLD_INSTRUCTIONS`].
//!
//! A controller fits when `worst instructions × CPI × margin ≤ 168 MHz / rate`
//! with CPI 1.5 (Cortex-M4 from flash with the ART accelerator, FPU code;
//! a conservative figure) and margin 1.5. The `control` and `certified`
//! rows are enforced: the example exits with failure if one does not fit.
//! The `loop` rows are reported only: they include decoding the PIL link's
//! frames, and the MPC's 20 preview frames per step (≈ 1.3 kB, ≈ 4 k
//! instructions each) are an artefact of feeding the reference over the link;
//! on a vehicle the reference comes from an onboard trajectory generator.
//! Every row also gives the stack high-water mark of building the
//! controller and flying it (RAM painted before, scanned after; measured from
//! the top of RAM, so the callers' frames are included); the largest must be
//! within 32 KiB. The controller and the flight loop live in static RAM and
//! are designed in place, as in the image.
//!
//! Run (QEMU from Debian's `qemu-system-arm`; the runner is set in
//! `.cargo/config.toml`):
//! `cargo run --release -p fc-stm32f405 --bin budget --target thumbv7em-none-eabihf`
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

// The PAC's interrupt vectors (its `rt` feature, which RTIC needs for the
// `firmware` image, makes cortex-m-rt take them from the PAC).
#[cfg(target_os = "none")]
use stm32f4 as _;

#[cfg(target_os = "none")]
mod target {
    use cortex_m_rt::entry;
    use cortex_m_semihosting::hprintln;
    use fc_core::control::{
        AnyController, Controller, ControllerSpec, Family, MpcFast, PdEuler, PdEulerGains, Preset, ReferenceMode,
        Setpoint, StateEstimate, Tuning, SPECS,
    };
    use fc_core::estimate::{Eskf, EskfConfig, Fix, ImuSample};
    use fc_core::{euler_to_quat, VehicleParams};
    use fc_loop::nav::Navigator;
    use fc_loop::{run_job, setpoint_to_wire, Exclusive, FcConfig, FlightLoop, Framed, Outbox};
    use fc_proto::{encode, FrameDecoder, FromFc, ToFc, MAX_FRAME, PROTOCOL_VERSION};
    use fc_stm32f405::SYSCLK_HZ;
    use hal_shim::stm32f405::SysTickClock;
    use hal_shim::{ByteLink, CycleClock};
    use nalgebra::Vector3;

    mod holds;
    mod link;
    use link::*;

    /// SysTick counts per executed instruction under `-icount shift=0`.
    const TICKS_PER_INSTRUCTION: f32 = 0.168;
    /// Cycles per instruction assumed on silicon.
    const CPI: f32 = 1.5;
    /// Safety factor on the worst case.
    const MARGIN: f32 = 1.5;
    const STEPS: u32 = 60;
    /// Stack allowed for designing and flying any controller (a quarter of
    /// the SRAM), enforced like the cycle budgets.
    const STACK_BUDGET: usize = fc_stm32f405::budgets::STACK_BYTES as usize;
    /// Runs `f` and returns its result with the stack high-water mark it
    /// reached (bytes from the top of RAM, so including the callers' frames).
    #[inline(never)]
    fn with_stack<R>(f: impl FnOnce() -> R) -> (R, usize) {
        fc_stm32f405::stack::paint();
        let r = f();
        (r, fc_stm32f405::stack::high_water())
    }

    /// The controller under test, in static RAM and designed in place, as
    /// the image's lives inside its `FlightLoop`: the stack figures are then
    /// the design's and the flight's, not a harness copy of the controller.
    static mut SLOT: Option<AnyController<f32>> = None;
    /// The flight loop of the `loop` rows, likewise.
    static mut CORE: Option<FlightLoop> = None;

    /// The controller slot (a placeholder PD until a row designs its own).
    #[inline(never)]
    fn slot() -> &'static mut AnyController<f32> {
        // SAFETY: the harness is single-threaded and no interrupt touches
        // SLOT; each row takes this reference once and drops it before the next.
        let s = unsafe { &mut *core::ptr::addr_of_mut!(SLOT) };
        s.get_or_insert_with(|| {
            AnyController::PdEuler(PdEuler::new(
                VehicleParams::os4(),
                PdEulerGains::tuned(),
                ReferenceMode::Feedforward,
            ))
        })
    }

    /// A fresh, unstarted flight loop in its static home (the caller starts
    /// it, outside this frame, as the image does).
    #[inline(never)]
    fn fresh_flight_loop(cfg: FcConfig) -> &'static mut FlightLoop {
        // SAFETY: as for `slot`.
        let s = unsafe { &mut *core::ptr::addr_of_mut!(CORE) };
        s.insert(FlightLoop::unstarted(cfg))
    }

    /// The estimator of the `estimator` row, in static RAM as the image's would be.
    static mut NAV: Option<Eskf<{ fc_loop::nav::HISTORY }>> = None;

    /// Largest instructions of one estimator step allowed (the bound).
    const ESTIMATOR_BUDGET: u32 = fc_stm32f405::budgets::ESTIMATOR_STEP_INSTRUCTIONS;
    /// The longest the CRTP link may hold the vehicle, instructions.
    const LINK_HOLD_BUDGET: u32 = fc_stm32f405::budgets::LINK_HOLD_INSTRUCTIONS;

    /// An IMU at rest, level.
    const REST: ImuSample = ImuSample {
        gyro_frd_radps: Vector3::new(0.0, 0.0, 0.0),
        accel_frd_mps2: Vector3::new(0.0, 0.0, -9.81),
    };

    /// Worst instructions of one estimator step at 1 kHz: predict with an
    /// IMU sample (pseudo-random rates up to 1 rad/s, specific force −g ± 2
    /// m/s² per axis) and fuse a whole mocap fix (position and heading, 10
    /// ms old: 4 scalar updates) at every step — more than the worst case:
    /// the navigator fuses at most [`fc_loop::nav::MAX_UPDATES_PER_STEP`]
    /// per step, and a real mocap fix arrives every tenth.
    #[inline(never)]
    fn estimator_worst(clock: &SysTickClock) -> Option<u32> {
        // SAFETY: as for `slot`.
        let nav = unsafe { &mut *core::ptr::addr_of_mut!(NAV) };
        let f = nav.insert(Eskf::new(EskfConfig::BMI088).ok()?);
        let rest = REST;
        let fix = mocap_fix;
        for _ in 0..30 {
            f.predict(&rest, 0.001).ok()?;
        }
        f.fuse(&fix(Vector3::new(0.0, 0.0, -1.0), 0.2)).ok()?;
        // History for the fixes' 10 ms of latency.
        for _ in 0..20 {
            f.predict(&rest, 0.001).ok()?;
        }
        let noise = 0.004;
        let mut rng = Lcg(11);
        let mut worst = 0u32;
        for _ in 0..STEPS {
            let imu = rng.imu();
            let e = f.estimate().ok()?;
            let z = e.pos_ned_m + rng.vector(noise);
            let yaw = e.euler()[2] + 0.01 * rng.next();
            let t0 = clock.now();
            f.predict(&imu, 0.001).ok()?;
            f.fuse(&fix(z, yaw)).ok()?;
            worst = worst.max(clock.since(t0));
        }
        Some(instructions(worst))
    }

    /// The MAVLink signing check of the largest signed frame (255 bytes of
    /// payload: five SHA-256 blocks with the key), a fresh timestamp each
    /// time: worst over [`STEPS`] frames.
    fn signing_worst(clock: &SysTickClock) -> Option<u32> {
        use fc_mavlink::signing::Signing;
        let key = [0x5a; 32];
        let (mut sender, mut vehicle) = (Signing::with_key(key, 1), Signing::with_key(key, 1));
        let mut frame = [0u8; fc_mavlink::MAX_FRAME];
        // Start byte, length 255, no flags, sequence, system 255, component
        // 190, message 0; the payload and CRC bytes are what the check hashes.
        frame[..10].copy_from_slice(&[0xFD, 255, 0, 0, 0, 255, 190, 0, 0, 0]);
        let mut rng = Lcg(5);
        let mut worst = 0u32;
        for _ in 0..STEPS {
            for b in &mut frame[10..267] {
                *b = (rng.next() * 100.0) as u8;
            }
            frame[2] = 0;
            let n = sender.sign(&mut frame, 267, 0)?;
            let t0 = clock.now();
            let ok = vehicle.check(&frame[..n], 0);
            worst = worst.max(clock.since(t0));
            if ok != Ok(true) {
                return None;
            }
        }
        Some(instructions(worst))
    }

    /// The navigator of the `gps` estimator row, in static RAM.
    static mut NAVIGATOR: Option<Navigator> = None;

    /// Worst instructions of one navigator step at 1 kHz on gps: predict
    /// (as [`estimator_worst`]) with a whole gps fix arriving at *every*
    /// step — position and velocity 100 ms old, barometer altitude and
    /// magnetometer heading: 8 scalar updates, which the navigator splits
    /// into three parts of at most 3 and fuses one part per step (the queue
    /// overflows and counts its drops here; a real gps fix arrives every
    /// hundredth step).
    #[inline(never)]
    fn navigator_gps_worst(clock: &SysTickClock) -> Option<u32> {
        // SAFETY: as for `slot`.
        let slot = unsafe { &mut *core::ptr::addr_of_mut!(NAVIGATOR) };
        let nav = slot.insert(Navigator::bmi088());
        let rest = REST;
        let fix = |p: Vector3<f32>, yaw: f32| Fix {
            age_s: 0.1,
            pos_ned_m: Some(p),
            pos_sigma_m: Vector3::new(0.3, 0.3, 0.5),
            vel_ned_mps: Some(Vector3::zeros()),
            vel_sigma_mps: 0.05,
            yaw_rad: Some(yaw),
            yaw_sigma_rad: 0.0175,
            alt_m: Some(-p[2]),
            alt_sigma_m: 0.1,
        };
        let mut now_us = 0u64;
        // Aligned at rest, then 150 ms of history for the fixes' latency.
        for k in 0..180 {
            now_us += 1_000;
            let fixes = [fix(Vector3::new(0.0, 0.0, -1.0), 0.2)];
            nav.step(now_us, &rest, if k % 10 == 0 { &fixes } else { &[] }).ok()?;
        }
        let mut rng = Lcg(13);
        let mut worst = 0u32;
        for _ in 0..STEPS {
            let imu = rng.imu();
            let e = nav.estimate()?;
            let fixes = [fix(e.pos_ned_m + rng.vector(0.3), e.euler()[2] + 0.01 * rng.next())];
            now_us += 1_000;
            let t0 = clock.now();
            nav.step(now_us, &imu, &fixes).ok()?;
            worst = worst.max(clock.since(t0));
        }
        Some(instructions(worst))
    }

    /// A reproducible number in [−1, 1].
    struct Lcg(u32);
    impl Lcg {
        fn next(&mut self) -> f32 {
            self.0 = self.0.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
            (self.0 >> 8) as f32 / (1u32 << 23) as f32 - 1.0
        }

        /// A vector with each component in [−s, s].
        fn vector(&mut self, s: f32) -> Vector3<f32> {
            Vector3::new(s * self.next(), s * self.next(), s * self.next())
        }

        /// An IMU sample: rates up to 1 rad/s, specific force −g ± 2 m/s² per axis.
        fn imu(&mut self) -> ImuSample {
            let gyro_frd_radps = self.vector(1.0);
            ImuSample {
                gyro_frd_radps,
                accel_frd_mps2: REST.accel_frd_mps2 + self.vector(2.0),
            }
        }
    }

    /// The climbing circle (radius 2 m, 20 s, 0.05 m/s up) at time `t`, with
    /// its velocity, acceleration and jerk.
    fn reference(t: f32) -> Setpoint<f32> {
        let w = core::f32::consts::TAU / 20.0;
        let (s, c) = fc_core::math::sin_cos(w * t);
        let r = 2.0;
        Setpoint {
            pos_ned_m: Vector3::new(r * c, r * s, -5.0 - 0.05 * t),
            vel_ned_mps: Vector3::new(-r * w * s, r * w * c, -0.05),
            acc_ned_mps2: Vector3::new(-r * w * w * c, -r * w * w * s, 0.0),
            jerk_ned_mps3: Vector3::new(r * w * w * w * s, -r * w * w * w * c, 0.0),
            yaw_rad: 0.26,
            yaw_rate_radps: 0.0,
        }
    }

    /// A state near the reference: up to 3 m and 2 m/s off, tilted up to
    /// 0.3 rad at any heading, turning up to 1 rad/s.
    fn state(rng: &mut Lcg, sp: &Setpoint<f32>) -> StateEstimate<f32> {
        let v = |rng: &mut Lcg, s: f32| Vector3::new(s * rng.next(), s * rng.next(), s * rng.next());
        StateEstimate {
            pos_ned_m: sp.pos_ned_m + v(rng, 3.0),
            vel_ned_mps: v(rng, 2.0),
            att: euler_to_quat(0.3 * rng.next(), 0.3 * rng.next(), 3.1 * rng.next()),
            rates_frd_radps: v(rng, 1.0),
        }
    }

    /// The test flight: `STEPS` pseudo-random states against the climbing
    /// circle, the controller's preview set before each; `step` flies one
    /// and returns the SysTick counts of what it measured (`None`: the
    /// measurement failed). The worst, in instructions.
    fn test_flight<C: Controller<f32> + ?Sized>(
        ctrl: &mut C,
        dt: f32,
        mut step: impl FnMut(&mut C, &StateEstimate<f32>, &Setpoint<f32>) -> Option<u32>,
    ) -> Option<u32> {
        let mut rng = Lcg(7);
        let mut worst = 0u32;
        for k in 0..STEPS {
            let t = k as f32 * dt;
            let sp = reference(t);
            if let Some((n, pdt)) = ctrl.preview_request() {
                for i in 1..=n {
                    let _ = ctrl.set_preview(i, &reference(t + i as f32 * pdt as f32));
                }
            }
            let est = state(&mut rng, &sp);
            worst = worst.max(step(ctrl, &est, &sp)?);
        }
        Some(instructions(worst))
    }

    /// Worst instructions of `update` over the test flight.
    fn control_worst(ctrl: &mut dyn Controller<f32>, clock: &SysTickClock, dt: f32) -> Option<u32> {
        test_flight(ctrl, dt, |c, est, sp| {
            let t0 = clock.now();
            let _ = c.update(est, sp);
            Some(clock.since(t0))
        })
    }

    /// Worst instructions of the fast MPC's QP solve alone over the test
    /// flight: each step's QP (`last_qp`) solved again, exactly as in the
    /// step, on its own clock (`None` if the answer differs from the step's).
    fn qp_worst(mpc: &mut MpcFast<f32>, clock: &SysTickClock, dt: f32) -> Option<u32> {
        test_flight(mpc, dt, |c, est, sp| {
            let _ = Controller::update(c, est, sp);
            let t0 = clock.now();
            let sol = c.resolve_last_qp()?;
            let ticks = clock.since(t0);
            (sol.z == c.last_qp()?.solution.z).then_some(ticks)
        })
    }

    fn instructions(ticks: u32) -> u32 {
        (ticks as f32 / TICKS_PER_INSTRUCTION) as u32
    }

    /// Worst instructions per step of the whole firmware loop (frames in,
    /// controller, frames out) for controller `id` at period `dt`.
    fn loop_worst(id: u8, dt: f32, preview: Option<(usize, f64)>, clock: &SysTickClock) -> Option<u32> {
        let cfg = FcConfig {
            control_period_s: dt as f64,
            ..FcConfig::default()
        };
        let (fc, link) = open_session(cfg, id, clock)?;
        let mut rng = Lcg(7);
        let mut offset = Vector3::<f32>::zeros();
        let mut worst = 0u32;
        for k in 0..STEPS {
            let t = k as f32 * dt;
            let sp = reference(t);
            push(link, &ToFc::Setpoint(setpoint_to_wire(&sp)));
            if let Some(p) = preview {
                push_preview(link, t, p);
            }
            let mut e = state(&mut rng, &sp);
            // The position may not jump between frames (the loop refuses a
            // state the vehicle cannot have reached): it wanders up to 3 m
            // off the reference, at most 1 m a step; the rest stays random.
            let step = Vector3::new(rng.next(), rng.next(), rng.next());
            offset = (offset + step).map(|v| v.clamp(-3.0, 3.0));
            e.pos_ned_m = sp.pos_ned_m + offset;
            let mut x = [0f32; 13];
            x[0..3].copy_from_slice(e.pos_ned_m.as_slice());
            x[3..6].copy_from_slice(e.vel_ned_mps.as_slice());
            x[6..10].copy_from_slice(e.att.as_slice());
            x[10..13].copy_from_slice(e.rates_frd_radps.as_slice());
            push(
                link,
                &ToFc::Sensor {
                    seq: k + 1,
                    t_us: (t * 1e6) as u64,
                    state: x,
                },
            );
            let now_us = (t * 1e6) as u64;
            let t0 = clock.now();
            while !link.rx.is_empty() {
                fc.service(link, clock, now_us).ok()?;
            }
            worst = worst.max(clock.since(t0));
        }
        // Every sensor frame flown (none refused as invalid or implausible).
        let c = fc.counters();
        (c.ok > STEPS && c.invalid_values == 0 && link.tx_bytes > 0).then_some(instructions(worst))
    }

    /// Largest instructions of one whole image step of the fast MPC at
    /// 1 kHz (the bound: 168 000 cycles ÷ CPI 1.5 ÷ margin 1.5).
    const IMAGE_STEP_BUDGET: u32 = fc_stm32f405::budgets::IMAGE_STEP_INSTRUCTIONS;

    /// Worst instructions of one whole image step at 1 kHz, as a vehicle
    /// flies the controller `id`: an `Imu` sample in (pseudo-random rates
    /// up to 1 rad/s, specific force −g ± 2 m/s²) with a mocap fix at
    /// *every* step (a real one arrives every tenth), the estimator, the
    /// controller (due at every sample at 1 kHz) and its output
    /// ([`ImageStep`]): `step` is what the image itself reports for the
    /// step (`Telemetry.cycles`: from the IMU sample to the actuator output,
    /// the figure a QEMU flight's `instructions_per_step` is made of);
    /// `framed` adds the lockstep link's work (decoding the `Fix` and
    /// `Imu` frames, encoding `Actuator`, `Telemetry`, `Nav` and `NavBias`),
    /// which on a vehicle is the link task's, below the IMU and the
    /// controller; `imu_task` and `control_task` are the two halves as
    /// `firmware`'s tasks run them. Every other step has the reference preview (its frames
    /// serviced before the step: on a vehicle an onboard trajectory
    /// generator gives it), the others extrapolate the set-point.
    fn image_step_worst(id: u8, preview: Option<(usize, f64)>, clock: &SysTickClock) -> Option<ImageStep> {
        let (fc, link) = open_session(FcConfig::default(), id, clock)?;
        let start = Vector3::new(2.0, 0.0, -5.0);
        let fix = mocap_fix;
        let imu_frame = |seq: u32, imu: &ImuSample| ToFc::Imu {
            seq,
            t_us: u64::from(seq) * 1_000,
            gyro: imu.gyro_frd_radps.into(),
            accel: imu.accel_frd_mps2.into(),
        };
        // Aligned at rest at the circle's start, with 50 ms of history.
        let mut seq = 0u32;
        for k in 0..100u32 {
            seq += 1;
            if k % 10 == 0 {
                push(link, &ToFc::Fix(fc_loop::fix_to_wire(&fix(start, 0.26))));
            }
            push(link, &imu_frame(seq, &REST));
            while !link.rx.is_empty() {
                fc.service(link, clock, 0).ok()?;
            }
        }
        let mut rng = Lcg(17);
        let (mut worst, mut worst_framed) = (0u32, 0u32);
        let (mut worst_imu, mut worst_control) = (0u32, 0u32);
        for k in 0..STEPS {
            seq += 1;
            let t = seq as f32 * 1e-3;
            push(link, &ToFc::Setpoint(setpoint_to_wire(&reference(t))));
            if let Some(p) = preview.filter(|_| k % 2 == 0) {
                push_preview(link, t, p);
            }
            while !link.rx.is_empty() {
                fc.service(link, clock, 0).ok()?;
            }
            link.tx.clear();
            let e = fc.navigator().estimate()?;
            let z = e.pos_ned_m + rng.vector(0.004);
            push(
                link,
                &ToFc::Fix(fc_loop::fix_to_wire(&fix(z, e.euler()[2] + 0.01 * rng.next()))),
            );
            push(link, &imu_frame(seq, &rng.imu()));
            let t0 = clock.now();
            // As the image's tasks run it: each frame decoded, the loop's
            // half (the IMU task: the estimator and the controller's
            // inputs), then the controller's (`run_job`) until its first
            // answer (the output) is handed over.
            while let Some(b) = link.rx.pop_front() {
                let Some(frame) = fc.decoder().push::<ToFc>(b) else {
                    continue;
                };
                if let Some((imu, control)) = as_tasks(fc, frame, link, clock)? {
                    worst_imu = worst_imu.max(imu);
                    worst_control = worst_control.max(control);
                }
            }
            worst_framed = worst_framed.max(clock.since(t0));
            worst = worst.max(link.step_cycles()?);
        }
        // Every step navigated and flown (nothing refused as invalid).
        let c = fc.counters();
        (fc.navigator().estimate().is_some() && c.invalid_values == 0 && link.tx_bytes > 0).then_some(ImageStep {
            step: instructions(worst),
            framed: instructions(worst_framed),
            imu_task: instructions(worst_imu),
            control_task: instructions(worst_control),
        })
    }

    /// One decoded frame as `firmware`'s tasks run it: the loop's half,
    /// then the controller's until its first answer. Returns the two
    /// halves' ticks when the frame was a step; `None` if anything failed.
    #[inline(never)]
    fn as_tasks(
        fc: &mut FlightLoop,
        frame: Result<ToFc, fc_proto::FrameError>,
        link: &mut MemLink,
        clock: &SysTickClock,
    ) -> Option<Option<(u32, u32)>> {
        let ts = clock.now();
        let Some(job) = fc.on_frame(frame, &mut Framed(&mut *link), clock, 0).ok()? else {
            return Some(None);
        };
        let te = clock.now();
        let (lp, ctrl) = fc.split();
        let mut out = FirstAnswer {
            link: Framed(link),
            clock,
            at: None,
        };
        run_job(&mut Exclusive(lp), ctrl, job, &mut out, clock).ok()?;
        Some(Some((te.wrapping_sub(ts), out.at?.wrapping_sub(te))))
    }

    /// One of [`ImageStep`]'s figures.
    type Figure = fn(&ImageStep) -> u32;

    /// The image step's worst figures, instructions.
    #[derive(Clone, Copy)]
    struct ImageStep {
        /// Sample to output, as the image reports it (`Telemetry.cycles`).
        step: u32,
        /// With the lockstep link's frames decoded and encoded.
        framed: u32,
        /// The IMU task: the decoded sample to the estimate and the controller's inputs.
        imu_task: u32,
        /// The controller task: its inputs to its output handed over.
        control_task: u32,
    }

    /// An outbox that notes when its first message is sent (the step's
    /// output, `Actuator`).
    struct FirstAnswer<'a, 'c> {
        link: Framed<'a, MemLink>,
        clock: &'c SysTickClock,
        at: Option<u32>,
    }

    impl Outbox for FirstAnswer<'_, '_> {
        type Error = ();
        fn send(&mut self, m: &FromFc) -> Result<(), ()> {
            self.at.get_or_insert_with(|| self.clock.now());
            self.link.send(m)
        }
    }

    /// One table row; returns whether it fits.
    fn row(name: &str, form: &str, hz: u32, what: &str, measured: (Option<u32>, usize)) -> bool {
        let (worst, stack) = measured;
        let Some(worst) = worst else {
            hprintln!("| {} | {} | {} | {} | failed | | | | {} |", name, form, hz, what, stack);
            return false;
        };
        let budget = SYSCLK_HZ / hz;
        let need = worst as f32 * CPI * MARGIN;
        let fits = need <= budget as f32;
        hprintln!(
            "| {} | {} | {} | {} | {} | {} | {:.1} % | {} | {} |",
            name,
            form,
            hz,
            what,
            worst,
            budget,
            100.0 * need / budget as f32,
            if fits { "fits" } else { "OVER" },
            stack
        );
        fits
    }

    #[entry]
    fn main() -> ! {
        let clock = SysTickClock::start(SYSCLK_HZ);
        let p = VehicleParams::<f32>::os4();
        hprintln!(
            "budget: instructions per step under QEMU -icount shift=0; fits = worst x CPI {} x margin {} <= 168 MHz / rate",
            CPI,
            MARGIN
        );
        hprintln!("| controller | form | rate Hz | measured | worst instructions | budget cycles | load | verdict | stack bytes |");
        hprintln!("|---|---|---|---|---|---|---|---|---|");
        let mut ok = true;
        let mut stack_max = 0usize;
        let mut check = |name: &str, form: &str, hz: u32, what: &str, m: (Option<u32>, usize)| {
            stack_max = stack_max.max(m.1);
            row(name, form, hz, what, m)
        };
        // Every controller the wire offers, at its rate (PD and LQR at 1 kHz,
        // the MPC presets at their own): the controller alone; for the MPCs
        // also with the QP forced to run its full allowance (the guaranteed
        // worst case); and the whole loop (reported, not enforced: see above).
        for r in SPECS.iter() {
            let Some(id) = r.wire_id else { continue };
            let spec = ControllerSpec::new(r.family, r.form).with_preset(r.preset);
            let dt = spec.period_s(0.001) as f32;
            let hz = (1.0 / dt + 0.5) as u32;
            let name = match r.family {
                Family::Mpc => r.name.trim_end_matches(r.form.name()).trim_end_matches('-'),
                f => f.name(),
            };
            let form = r.form.name();
            let whats: &[&str] = if r.family == Family::Mpc {
                &["control", "FGM to its a-priori bound, info"]
            } else {
                &["control"]
            };
            for &what in whats {
                let m = with_stack(|| {
                    let mut mpc = spec.mpc_config();
                    // The iterative solver this replaced, run to its whole
                    // a-priori bound (the worst case of a certified FGM solve),
                    // for comparison (reported only).
                    if let (Some(c), "FGM to its a-priori bound, info") = (mpc.as_mut(), what) {
                        c.qp_enumerate = false;
                        c.qp_early_exit = false;
                        c.qp_max_iterations = u32::MAX;
                    }
                    let slot = slot();
                    spec.build_in(slot, p, dt as f64, mpc, &Tuning::project()).ok()?;
                    // The MPCs are measured as their own types, as the image calls them.
                    match slot {
                        AnyController::MpcFast(c) => control_worst(c, &clock, dt),
                        AnyController::MpcThesis(c) => control_worst(c, &clock, dt),
                        c => control_worst(c, &clock, dt),
                    }
                });
                if what.ends_with("info") {
                    check(name, form, hz, what, m);
                } else {
                    ok &= check(name, form, hz, what, m);
                    // The exact QP does the same work on every solve (every
                    // active set of every block, no early exit): the control
                    // step's worst case is the certified one, held against
                    // a 1 kHz step whatever the preset's own rate.
                    if spec.mpc_config().is_some_and(|c| c.qp_enumerate) {
                        ok &= check(name, form, 1000, "certified (exact QP)", m);
                    }
                }
            }
            if r.family == Family::Mpc && r.preset == Preset::Project {
                let m = with_stack(|| {
                    let slot = slot();
                    spec.build_in(slot, p, dt as f64, spec.mpc_config(), &Tuning::project())
                        .ok()?;
                    match slot {
                        AnyController::MpcFast(c) => qp_worst(c, &clock, dt),
                        _ => None,
                    }
                });
                check(name, form, 1000, "QP alone (exact, 108 active sets), info", m);
            }
            let m = with_stack(|| loop_worst(id, dt, spec.preview(), &clock));
            check(name, form, hz, "loop", m);
            // The fast MPC re-solves at every 1 kHz IMU sample: the whole
            // image step (frames, estimator with a fix, MPC) is its budget.
            if r.family == Family::Mpc && r.preset == Preset::Project {
                let (m, stack) = with_stack(|| image_step_worst(id, spec.preview(), &clock));
                // The whole step (enforced), with the PIL link's frames
                // (reported), and the image's two tasks apart (`firmware`'s
                // data-ready and controller tasks: enforced).
                let rows: [(&str, Figure, bool); 4] = [
                    ("image step (IMU + fix in, ESKF, MPC, output)", |w| w.step, true),
                    ("image step with the PIL link's frames, info", |w| w.framed, false),
                    ("IMU task (sample to estimate)", |w| w.imu_task, true),
                    ("controller task (estimate to output)", |w| w.control_task, true),
                ];
                for (what, figure, enforced) in rows {
                    let fits = check(name, form, hz, what, (m.as_ref().map(figure), stack));
                    if enforced {
                        ok &= fits;
                    }
                }
                match m.map(|w| w.step) {
                    Some(w) if w <= IMAGE_STEP_BUDGET => {
                        hprintln!(
                            "budget: {} image step: {} instructions, within {}",
                            r.name,
                            w,
                            IMAGE_STEP_BUDGET
                        )
                    }
                    w => {
                        hprintln!(
                            "budget: {} image step: {:?} instructions, OVER {}",
                            r.name,
                            w,
                            IMAGE_STEP_BUDGET
                        );
                        ok = false;
                    }
                }
            }
        }
        // The estimator of sensor flights: one predict and one fix update per
        // 1 kHz step, against the whole budget and against its own bound.
        for (what, run) in [
            (
                "predict + mocap fix",
                estimator_worst as fn(&SysTickClock) -> Option<u32>,
            ),
            ("navigator + gps fix", navigator_gps_worst),
        ] {
            let m = with_stack(|| run(&clock));
            ok &= check("estimator (ESKF)", "15 states", 1000, what, m);
            match m.0 {
                Some(w) if w <= ESTIMATOR_BUDGET => {
                    hprintln!(
                        "budget: estimator, {}: {} instructions per step, within its {}",
                        what,
                        w,
                        ESTIMATOR_BUDGET
                    )
                }
                w => {
                    hprintln!(
                        "budget: estimator, {}: {:?} instructions per step, OVER its {}",
                        what,
                        w,
                        ESTIMATOR_BUDGET
                    );
                    ok = false;
                }
            }
        }
        // The MAVLink signing check, per frame heard (reported, not
        // enforced: `firmware-mavlink` checks frames outside the 1 kHz step).
        check(
            "MAVLink signing",
            "SHA-256",
            1000,
            "check a signed 280-byte frame, info",
            with_stack(|| signing_worst(&clock)),
        );
        // The CRTP link's longest hold of the vehicle over the packets that
        // take it longest (a sample ready meanwhile waits), enforced.
        let vehicle = holds::vehicle();
        let m = with_stack(|| holds::link_hold_worst(vehicle?, &clock));
        check("CRTP link", "packet", 1000, "longest hold of the vehicle", m);
        match m.0 {
            Some(w) if w <= LINK_HOLD_BUDGET => {
                hprintln!("budget: link hold: {} instructions, within its {}", w, LINK_HOLD_BUDGET)
            }
            w => {
                hprintln!("budget: link hold: {:?} instructions, OVER its {}", w, LINK_HOLD_BUDGET);
                ok = false;
            }
        }
        let static_ram = fc_stm32f405::stack::static_ram();
        hprintln!(
            "budget: stack high-water {} bytes, static RAM {} bytes, of 131072",
            stack_max,
            static_ram
        );
        if stack_max > STACK_BUDGET {
            hprintln!("budget: stack high-water over its budget of {} bytes", STACK_BUDGET);
            ok = false;
        }
        hprintln!("budget: {}", if ok { "all fit" } else { "SOME DO NOT FIT" });
        fc_stm32f405::harness_exit(ok)
    }

    fc_stm32f405::harness_runtime!("budget");
}

#[cfg(not(target_os = "none"))]
fn main() {
    println!("budget runs on the MCU: cargo run --release -p fc-stm32f405 --bin budget --target thumbv7em-none-eabihf");
}
