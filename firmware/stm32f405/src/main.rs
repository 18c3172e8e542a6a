//! STM32F405 image of the flight-control core (`thumbv7em-none-eabihf`).
//!
//! An RTIC 2 application at three interrupt priorities, as a flight
//! controller's tasks are ordered (the sensor first, then the controller,
//! then the link):
//!
//! | priority | task | interrupt | work |
//! |---|---|---|---|
//! | 3 | `data_ready` | USART1 receive (the sample's arrival stands in for the gyro's data-ready line) | decodes the host's frames; on an `Imu` sample steps the estimator ([`fc_loop::Loop::on_frame`]) and hands the controller its job |
//! | 2 | `controller` | CAN2_RX0 (pended) | runs each job on the controller ([`fc_loop::run_job`]): the controller's step, designs, parameter writes; answers the step |
//! | 1 | `link` | CAN2_RX1 (pended) | sends the answers the sample task queued (handshake, heartbeats, parameter reads) and logs |
//!
//! The estimator's state ([`fc_loop::Loop`]) is shared; the controller
//! ([`fc_core::control::AnyController`]) belongs to the controller's task,
//! which locks the loop only to take the step's previews and to record its
//! result. So no controller step, design or link write delays an IMU step
//! by more than those short locks. The image measures it: for every step
//! the time from data-ready to the estimate, and to the controller's
//! answer (its `Actuator`, handed to the transmitter),
//! against the deadline of one 1 kHz period (168 000 cycles; under
//! QEMU, 74 667 instructions: CPI 1.5 with a 1.5 margin), logged once a
//! second of steps.
//!
//! The motors: each step's inputs `U` drive TIM3's four PWM outputs at
//! 400 Hz (`hal_shim::stm32f405::PwmActuators`; PA6, PA7, PB0, PB1 on most
//! F405 boards, the pins being the board's to mux), each rotor's duty its
//! commanded speed over Ωmax (the inverse mixer of the vehicle in force,
//! `fc_core::model::mixer::rotor_speeds`): a brushed-motor drive, as the
//! Crazyflie's. An ESC's 1–2 ms pulses are a board's choice not made here.
//! The compare values are logged once a second of steps (QEMU models TIM3;
//! `tests/tests/qemu.rs` checks them against the step's `U`); a fault
//! handler sets them to 0 first (`board`).
//!
//! Time is SysTick at 168 MHz, widened in software; under QEMU's
//! `-icount shift=0` one instruction is one nanosecond of virtual time, so
//! SysTick counts 0.168 per instruction. It logs through defmt: boot, the
//! handshake, controller selections, a design's length (a job that outlasts
//! a step's deadline), failsafe entries and exits, link
//! errors and the timing — over semihosting by default (QEMU; `sil-host fly
//! --target qemu --firmware-log` decodes it), over RTT with the `log-rtt`
//! feature. On the host this file compiles to an empty program so that
//! `cargo build --workspace` works everywhere.
#![cfg_attr(target_os = "none", no_std)]
#![cfg_attr(target_os = "none", no_main)]

#[cfg(target_os = "none")]
fc_stm32f405::board_runtime!();

#[cfg(target_os = "none")]
#[rtic::app(device = stm32f4::stm32f405, peripherals = false)]
mod app {
    use fc_core::control::AnyController;
    use fc_loop::{run_job, FcConfig, FlightLoop, Job, Loop, Mutex, Outbox};
    use fc_proto::{encode, Counters, FromFc, ToFc, MAX_FRAME, PROTOCOL_VERSION};
    use fc_stm32f405::board;
    use fc_stm32f405::log_changes;
    use fc_stm32f405::timing::{instructions, StepTiming, Timing, DEADLINE_TICKS};
    use hal_shim::stm32f405::{read_queued, ticks_now, usart_isr, Port, PwmActuators, SysTickClock, TxTimeout, Usart};
    use hal_shim::{ActuatorOutput, ByteLink};
    use heapless::spsc::{Consumer, Producer, Queue};
    use stm32f4::stm32f405::Interrupt;

    /// Jobs waiting for the controller's task (a step's job and the
    /// parameter writes or selections sent with it).
    const JOBS: usize = 8;
    /// Answers waiting for the link's task.
    const ANSWERS: usize = 16;

    #[shared]
    struct Shared {
        /// The loop: estimator, session, parameters, counters.
        lp: &'static mut Loop,
        /// USART1's transmitter (the controller's answers and the link's).
        tx: Usart,
        /// What the tasks measured.
        timing: Timing,
    }

    #[local]
    struct Local {
        last: Last,
        logged: StepTiming,
        /// The tasks' stack high-water mark, watched.
        stack: fc_stm32f405::stack::Watch,
        ctrl: &'static mut AnyController<f32>,
        jobs_in: Producer<'static, (Job, u64)>,
        jobs_out: Consumer<'static, (Job, u64)>,
        answers_in: Producer<'static, FromFc>,
        answers_out: Consumer<'static, FromFc>,
        /// The cycle clock, one handle per task.
        sample_clock: SysTickClock,
        control_clock: SysTickClock,
        /// The four motors on TIM3, and the steps they have been driven.
        motors: (PwmActuators, u32),
    }

    #[init(local = [
        jobs: Queue<(Job, u64), JOBS> = Queue::new(),
        answers: Queue<FromFc, ANSWERS> = Queue::new(),
    ])]
    fn init(cx: init::Context) -> (Shared, Local) {
        fc_stm32f405::stack::paint();
        let (clock, tx) = board::bring_up();
        let Some(fc) = flight_loop() else {
            board::fail("flight loop already taken");
        };
        if fc.start().is_err() {
            board::fail("boot controller design failed");
        }
        let (lp, ctrl) = fc.split();
        let (jobs_in, jobs_out) = cx.local.jobs.split();
        let (answers_in, answers_out) = cx.local.answers.split();
        // Duties are computed by the controller's task (the vehicle in force
        // can change): the driver takes them as they are.
        let motors = PwmActuators::start(fc_stm32f405::APB1_TIMER_CLK_HZ, MOTOR_PWM_HZ, |d| *d);
        defmt::info!(
            "up: protocol v{=u16}, waiting on USART1; tasks: data-ready (3), controller (2), link (1)",
            PROTOCOL_VERSION
        );
        (
            Shared {
                lp,
                tx,
                timing: Timing::new(DEADLINE_TICKS),
            },
            Local {
                last: Last((false, false, Counters::default(), 0)),
                logged: StepTiming::default(),
                stack: fc_stm32f405::stack::Watch::new(),
                ctrl,
                jobs_in,
                jobs_out,
                answers_in,
                answers_out,
                sample_clock: clock,
                control_clock: clock,
                motors: (motors, 0),
            },
        )
    }

    #[idle]
    fn idle(_: idle::Context) -> ! {
        board::idle()
    }

    /// The sample's arrival (data-ready): every received byte into the
    /// loop's decoder; a decoded `Imu` sample steps the estimator here, and
    /// the controller's task is given the rest.
    #[task(binds = USART1, priority = 3, shared = [lp, timing], local = [jobs_in, answers_in, sample_clock])]
    fn data_ready(cx: data_ready::Context) {
        usart_isr(Port::Usart1);
        let data_ready::LocalResources {
            jobs_in,
            answers_in,
            sample_clock: clock,
            ..
        } = cx.local;
        let (mut lp, mut timing) = (cx.shared.lp, cx.shared.timing);
        let mut out = Deferred(answers_in, 0);
        let mut buf = [0u8; 64];
        loop {
            let n = read_queued(Port::Usart1, &mut buf);
            if n == 0 {
                break;
            }
            for &b in &buf[..n] {
                let job = lp.lock(|lp| {
                    let frame = lp.decoder().push::<ToFc>(b)?;
                    // Data-ready: the sample is whole (on a board, the
                    // gyro's line; here, the `Imu` frame's last byte).
                    let entry = ticks_now();
                    let now_us = board::us_of(entry);
                    // The deferred outbox never fails.
                    let job = lp.on_frame(frame, &mut out, clock, now_us).unwrap_or(None)?;
                    Some((job, entry))
                });
                let Some((job, entry)) = job else { continue };
                if matches!(job, Job::Step(_)) {
                    let done = ticks_now();
                    timing.lock(|t| t.estimated(entry, done));
                }
                if jobs_in.enqueue((job, entry)).is_err() {
                    timing.lock(|t| t.job_dropped());
                }
                rtic::pend(Interrupt::CAN2_RX0);
            }
        }
        if out.1 > 0 {
            timing.lock(|t| t.answers_dropped(out.1));
        }
        rtic::pend(Interrupt::CAN2_RX1);
    }

    /// The controller: each job the sample task handed over, in order;
    /// a step's answers sent as soon as it is flown.
    #[task(binds = CAN2_RX0, priority = 2, shared = [lp, tx, timing], local = [ctrl, jobs_out, control_clock, motors])]
    fn controller(cx: controller::Context) {
        let controller::LocalResources {
            ctrl,
            jobs_out,
            control_clock: clock,
            motors,
            ..
        } = cx.local;
        let (lp, mut tx, mut timing) = (cx.shared.lp, cx.shared.tx, cx.shared.timing);
        let mut lp = ByRef(lp);
        while let Some((job, entry)) = jobs_out.dequeue() {
            // A job that is not a step, named for its log line, and when it
            // started: one that outlasts a step's deadline is a design, and
            // its length is logged (the steps it delays are counted as late
            // below). Its own instructions, from the job's start, not from
            // a sample's arrival, which the host times. A step reads no
            // clock here.
            let other = match job {
                Job::Step(_) => None,
                Job::Select(_) => Some("controller selection"),
                Job::Param { .. } => Some("parameter write"),
            }
            .map(|what| (what, ticks_now()));
            let mut out = Transmit(&mut tx, None, None);
            let sent = run_job(&mut lp, ctrl, job, &mut out, clock);
            if let Some((what, start)) = other {
                let took = ticks_now().saturating_sub(start);
                if took > DEADLINE_TICKS {
                    defmt::info!("job: a {=str} took {=u64} instructions", what, instructions(took));
                }
            }
            // The step is flown when its first answer (`Actuator`) goes to
            // the transmitter; its inputs then go to the motors.
            let done = out.1.unwrap_or_else(ticks_now);
            if let Some(u) = out.2 {
                drive(motors, &lp.lock(|lp| *lp.vehicle()), u);
            }
            timing.lock(|t| {
                if other.is_none() {
                    t.flown(entry, done);
                }
                if sent.is_err() {
                    t.tx_timeout();
                }
            });
        }
        rtic::pend(Interrupt::CAN2_RX1);
    }

    /// The link: the queued answers out, then what changed in the log.
    #[task(binds = CAN2_RX1, priority = 1, shared = [lp, tx, timing], local = [answers_out, last, logged, stack])]
    fn link(cx: link::Context) {
        let link::LocalResources {
            answers_out,
            last,
            logged,
            stack,
            ..
        } = cx.local;
        let (mut lp, mut tx, mut timing) = (cx.shared.lp, cx.shared.tx, cx.shared.timing);
        while let Some(m) = answers_out.dequeue() {
            if Transmit(&mut tx, None, None).send(&m).is_err() {
                timing.lock(|t| t.tx_timeout());
            }
        }
        lp.lock(|lp| log_changes(lp, &mut last.0));
        let now = timing.lock(|t| t.snapshot());
        stack.poll();
        if now.due(logged) {
            stack.log_if_grown();
        }
        now.log_if_due(logged);
    }

    /// What [`log_changes`] saw last.
    pub struct Last((bool, bool, Counters, u32));

    /// The loop as [`run_job`] locks it: through the controller task's
    /// lock on the shared reference.
    struct ByRef<M>(M);

    impl<M: Mutex<T = &'static mut Loop>> Mutex for ByRef<M> {
        type T = Loop;
        fn lock<R>(&mut self, f: impl FnOnce(&mut Loop) -> R) -> R {
            self.0.lock(|lp| f(lp))
        }
    }

    /// The motors' PWM frequency, Hz.
    const MOTOR_PWM_HZ: u32 = 400;

    /// A step's inputs `U` `[U1 N, U2 N, U3 N, U4 N·m]` on the motors: each
    /// rotor's duty its commanded speed over Ωmax for the vehicle `v` (a
    /// non-finite `U` stops the rotors it reaches); the compare values
    /// logged once every 1000 steps (a second at 1 kHz).
    fn drive(motors: &mut (PwmActuators, u32), v: &fc_core::VehicleParams<f32>, u: [f32; 4]) {
        let speeds = fc_core::model::mixer::rotor_speeds(v, &nalgebra::Vector4::from(u));
        motors.0.apply(speeds.map(|w| w / v.omega_max_radps).into());
        motors.1 = motors.1.wrapping_add(1);
        if motors.1 % 1000 == 500 {
            let (reload, compare) = motors.0.registers();
            defmt::info!("motors: TIM3 compare {} of reload {=u32} for U {}", compare, reload, u);
        }
    }

    /// Answers written to USART1 under its lock, one frame at a time; the
    /// time of the first (SysTick ticks) and the inputs of the step's
    /// `Actuator`, if one was sent.
    struct Transmit<'a, M>(&'a mut M, Option<u64>, Option<[f32; 4]>);

    impl<M: Mutex<T = Usart>> Outbox for Transmit<'_, M> {
        type Error = TxTimeout;
        fn send(&mut self, msg: &FromFc) -> Result<(), TxTimeout> {
            self.1.get_or_insert_with(ticks_now);
            if let FromFc::Actuator { u, .. } = msg {
                self.2 = Some(*u);
            }
            let mut frame = [0u8; MAX_FRAME];
            match encode(msg, &mut frame) {
                Ok(n) => self.0.lock(|u| u.write_all(&frame[..n])),
                // Our own messages always fit MAX_FRAME (tested).
                Err(_) => Ok(()),
            }
        }
    }

    /// The sample task's answers, queued for the link's task (a full queue
    /// drops and counts them: the sample task never waits on the link).
    struct Deferred<'a, 'q>(&'a mut Producer<'q, FromFc>, u32);

    impl Outbox for Deferred<'_, '_> {
        type Error = core::convert::Infallible;
        fn send(&mut self, msg: &FromFc) -> Result<(), Self::Error> {
            if self.0.enqueue(*msg).is_err() {
                self.1 = self.1.wrapping_add(1);
            }
            Ok(())
        }
    }

    /// The flight loop, in static RAM (its controller is ≈ 7 KiB), built
    /// once and unstarted: the boot controller is designed in place by
    /// `start`, after this frame is gone, so the design's stack is not
    /// beneath a copy of the loop.
    #[inline(never)]
    fn flight_loop() -> Option<&'static mut FlightLoop> {
        cortex_m::singleton!(: FlightLoop = FlightLoop::unstarted(FcConfig::default()))
    }
}

#[cfg(not(target_os = "none"))]
fn main() {
    println!("firmware: this binary is the STM32F405 image; build it with --target thumbv7em-none-eabihf");
}
