//! The CRTP images' RTIC 2 application, bound by `firmware-crtp` (the
//! plain STM32F405) and `firmware-crazyflie` (the Crazyflie 2.1) with
//! [`crtp_app!`](macro@crate::crtp_app). Each gives it, at its crate's root, its
//! board's outputs (`BoardOutputs`, an [`Outputs`]), its watchdog
//! (`WATCHDOG`, a [`Watchdog`]), its IMU (`ImuBus`, an [`ImuBus`], started
//! by `imu_bus()`) and its vehicle (`vehicle()`, unstarted, in static
//! RAM). Four interrupt priorities, as a flight controller's tasks are
//! ordered (the sample first, then the controller, then the link):
//!
//! | priority | task | interrupt | work |
//! |---|---|---|---|
//! | 4 | `radio_bytes` | USART6 receive | the nRF51's bytes into their queue (1 Mbaud: a byte every 10 µs), the link pended |
//! | 3 | `data_ready` | USART1 receive (the simulator's `Imu` frame), or pended by the board's IMU | decodes the simulator's frames, takes the board's sample; a sample steps the estimator ([`CrtpShared::imu_begin`]) and goes to the controller |
//! | 3 | `gyro_ready`, `imu_bus_event`, `imu_bus_error` | EXTI15_10, I2C3_EV, I2C3_ER | the board's own IMU ([`ImuBus`]: the Crazyflie's BMI088; none in QEMU): data-ready starts the reads, the bus's interrupts advance them |
//! | 2 | `controller` | CAN2_RX0 (pended) | flies each step on the controller ([`fly_step`]), drives the outputs, answers the simulator; a take-off's reset ([`run_work`]) |
//! | 1 | `link` | CAN2_RX1 (pended) | syslink: the radio's packets handled under short locks of the vehicle (each packet's timed, the radio's interrupts in it apart: [`Holds`]), answers and log blocks queued for the radio; the re-designs a packet or the simulator asked for ([`run_work`]); the simulator's queued answers; the log |
//!
//! The vehicle's shared part ([`CrtpShared`]) is locked for an estimator
//! step, a packet, a step's result; never for a controller step, a design
//! or a USART write. A re-designing parameter write (tens of milliseconds,
//! allowed only while the motors are stopped, and no take-off while it runs) borrows the
//! controller for the link's task, which designs it in place: the
//! controller's task meanwhile answers every step on time with the motors
//! off ([`pass_step`]), so a design delays neither a sample nor a step.
//! The image measures it as `firmware` does ([`crate::timing`]): for
//! every step, data-ready → estimate and data-ready → outputs driven,
//! against one 1 kHz period.
//!
//! [`Holds`]: crate::timing::Holds
//! [`Outputs`]: crate::crtp_image::Outputs
//! [`Watchdog`]: crate::crtp_image::Watchdog
//! [`ImuBus`]: crate::crtp_image::ImuBus
//! [`CrtpShared`]: fc_crtp::vehicle::CrtpShared
//! [`CrtpShared::imu_begin`]: fc_crtp::vehicle::CrtpShared::imu_begin
//! [`fly_step`]: fc_crtp::vehicle::fly_step
//! [`pass_step`]: fc_crtp::vehicle::pass_step
//! [`run_work`]: fc_crtp::vehicle::run_work

/// Whether the vehicle is armed, as the link's task last saw it: the
/// settings store refuses writes then.
pub static ARMED: core::sync::atomic::AtomicBool = core::sync::atomic::AtomicBool::new(false);

/// SysTick ticks the radio's task has run (wrapping), timed by itself:
/// a hold's own work (and under QEMU a step's, [`RADIO_APART_FROM_STEPS`])
/// is its length less what this and [`RADIO_RUNS`] grew by meanwhile
/// ([`RadioMark`]).
pub static RADIO_TICKS: core::sync::atomic::AtomicU32 = core::sync::atomic::AtomicU32::new(0);

/// How many times the radio's task has run (wrapping): each run's entry
/// and exit, outside its own clock readings, is [`RADIO_OVERHEAD`] more.
pub static RADIO_RUNS: core::sync::atomic::AtomicU32 = core::sync::atomic::AtomicU32::new(0);

/// What one run of the radio's task costs outside its own clock readings
/// (its call, the halves of its two readings, its bookkeeping), in 1/256
/// SysTick ticks: measured once at the link's first run
/// ([`radio_overhead`]), 0 until then. QEMU delivers the radio's bytes
/// unpaced, one interrupt each, up to a hundred in one hold; without it a
/// hold's figure grew by some 70 instructions per byte that landed in it.
pub static RADIO_OVERHEAD: core::sync::atomic::AtomicU32 = core::sync::atomic::AtomicU32::new(0);

/// Whether a step's figures leave out the radio's runs that landed in it:
/// under QEMU (the `qemu` feature), which delivers the radio's bytes
/// unpaced, as fast as the image takes them, and, running at a fifth of
/// real time or less, several times as many per step as the nRF51's UART
/// could; there they moved the worst step by thousands of instructions from
/// run to run. On silicon the UART paces them, and their time is the
/// step's: counted in it.
pub const RADIO_APART_FROM_STEPS: bool = cfg!(feature = "qemu");

/// The radio's runs so far, to take what ran of them since off a figure.
#[derive(Debug, Clone, Copy)]
pub struct RadioMark {
    ticks: u32,
    runs: u32,
}

impl RadioMark {
    /// The radio's runs so far.
    pub fn now() -> Self {
        use core::sync::atomic::Ordering::Relaxed;
        Self {
            ticks: RADIO_TICKS.load(Relaxed),
            runs: RADIO_RUNS.load(Relaxed),
        }
    }

    /// SysTick ticks the radio's task has taken since `self`, each run's
    /// entry and exit included.
    pub fn since(self) -> u64 {
        use core::sync::atomic::Ordering::Relaxed;
        let now = Self::now();
        let runs = u64::from(now.runs.wrapping_sub(self.runs));
        u64::from(now.ticks.wrapping_sub(self.ticks)) + ((runs * u64::from(RADIO_OVERHEAD.load(Relaxed))) >> 8)
    }
}

/// Runs the radio's task `RUNS` times from software (pended, no byte
/// waiting: its clock readings and bookkeeping as for a byte), and the same
/// loop without it; returns the runs' cost outside their own readings,
/// 1/256 ticks per run. Call with the radio's priority unmasked (a lock of
/// the vehicle masks the tasks below it only). `clock` reads SysTick ticks.
pub fn radio_overhead(clock: fn() -> u64, pend: impl Fn()) -> u32 {
    use core::sync::atomic::Ordering::Relaxed;
    const RUNS: u32 = 32;
    let timed = |with: bool| {
        let (r0, n0) = (RADIO_TICKS.load(Relaxed), RADIO_RUNS.load(Relaxed));
        let t0 = clock();
        for _ in 0..RUNS {
            if with {
                pend();
            }
            // Taken here, before the next pend (ARMv7-M: after an ISB a
            // pended interrupt of higher priority is taken).
            cortex_m::asm::isb();
        }
        let t = clock().saturating_sub(t0) as u32;
        let (radio, runs) = (
            RADIO_TICKS.load(Relaxed).wrapping_sub(r0),
            RADIO_RUNS.load(Relaxed).wrapping_sub(n0),
        );
        (t.saturating_sub(radio), runs)
    };
    let (idle, _) = timed(false);
    let (pended, runs) = timed(true);
    (pended.saturating_sub(idle) << 8) / runs.max(1)
}

/// Binds the CRTP images' RTIC application (see the module's
/// documentation) in an image, once, at its crate's root on the target,
/// beside [`board_runtime!`](crate::board_runtime) and the board's parts
/// the application names.
#[macro_export]
#[allow(
    clippy::crate_in_macro_def,
    reason = "`crate::` is the image's: the board's parts it names"
)]
macro_rules! crtp_app {
    () => {
        #[rtic::app(device = stm32f4::stm32f405, peripherals = false)]
        mod app {
            use $crate::crtp_image::{ImuBus, Outputs, Watchdog};
            use $crate::board;
            use fc_core::control::AnyController;
            use fc_core::estimate::{Fix, ImuSample};
            use fc_crtp::syslink::Syslink;
            use fc_crtp::vehicle::{fly_step, pass_step, run_work, ControllerWork, CrtpShared, ImuStep};
            use fc_loop::params::Refusal;
            use fc_loop::{fix_from_wire, Mutex};
            use fc_proto::{FrameDecoder, FromFc, ToFc};
            use $crate::crtp_image::{log_changes, send, Last, SimCounters, DOWNLINK, FIXES, SYSLINK_BAUD};
            use $crate::timing::{Holds, StepTiming, Timing};
            use $crate::PCLK2_HZ;
            use hal_shim::stm32f405::{read_queued, ticks_now, usart_isr, Port, SysTickClock, Usart};
            use heapless::spsc::{Consumer, Producer, Queue};
            use nalgebra::Vector3;
            use stm32f4::stm32f405::Interrupt;

            /// Steps waiting for the controller's task from the sample's.
            const TASKS: usize = 8;
            /// Work from the link's task (a take-off's reset: 2 is room enough).
            const WORKS: usize = 2;
            /// The sample task's answers to the simulator, waiting for the link.
            const ANSWERS: usize = 8;

            /// A sample's step for the controller's task, in the order the
            /// samples came.
            pub struct Task {
                /// The sample's step: its controller half.
                step: ImuStep,
                /// The simulator's sequence number (`None`: the board's own
                /// sample, not answered).
                seq: Option<u32>,
                /// Its data-ready time (SysTick ticks).
                entry: u64,
                /// The radio's runs at data-ready: what ran of them since is
                /// not the step's own work.
                radio: $crate::crtp_app::RadioMark,
            }

            #[shared]
            struct Shared {
                /// The vehicle without its controller.
                v: &'static mut CrtpShared,
                /// USART1's transmitter: the simulator's answers.
                sim_tx: Usart,
                /// What the tasks measured.
                timing: Timing,
                /// What the simulator's link did.
                sim: SimCounters,
                /// The board's own IMU (none in QEMU).
                imu: crate::ImuBus,
                /// The controller: the controller's task's, lent to the link's
                /// task for a re-design (`None` meanwhile).
                ctrl: Option<&'static mut AnyController<f32>>,
            }

            #[local]
            struct Local {
                outputs: crate::BoardOutputs,
                decoder: FrameDecoder,
                fixes: heapless::Vec<Fix, FIXES>,
                tasks_in: Producer<'static, Task>,
                tasks_out: Consumer<'static, Task>,
                works_in: Producer<'static, ControllerWork>,
                works_out: Consumer<'static, ControllerWork>,
                answers_in: Producer<'static, FromFc>,
                answers_out: Consumer<'static, FromFc>,
                radio: Usart,
                syslink: Syslink<DOWNLINK>,
                last: Last,
                logged: StepTiming,
                /// The link's longest hold of the vehicle.
                holds: Holds,
                /// The tasks' stack high-water mark, watched.
                stack: $crate::stack::Watch,
                tx_errors: u32,
                sample_clock: SysTickClock,
                control_clock: SysTickClock,
            }

            #[init(local = [
                tasks: Queue<Task, TASKS> = Queue::new(),
                works: Queue<ControllerWork, WORKS> = Queue::new(),
                answers: Queue<FromFc, ANSWERS> = Queue::new(),
                store: Option<$crate::flash::Kept> = None,
            ])]
            fn init(cx: init::Context) -> (Shared, Local) {
                $crate::stack::paint();
                let (clock, sim_tx) = board::bring_up();
                let outputs = crate::BoardOutputs::start();
                let Some(vehicle) = crate::vehicle() else {
                    board::fail("vehicle already taken");
                };
                if vehicle.start().is_err() {
                    board::fail("boot controller design failed");
                }
                // cflib's persistent parameters: the stored values, each through
                // the check a client's write goes through.
                let mut store = $crate::flash::open_settings(&$crate::crtp_app::ARMED, |on| crate::WATCHDOG.designing(on))
                    .map(|s| cx.local.store.insert(s));
                if let Some(st) = store.as_deref_mut() {
                    let (mut taken, mut refused) = (0u16, 0u16);
                    for i in 0..fc_loop::params::CRTP_PARAMS {
                        if let Ok(Some(value)) = fc_storage::Persist::param(st, i as u16) {
                            match vehicle.write_param(i, value) {
                                Ok(_) => taken += 1,
                                Err(_) => refused += 1,
                            }
                        }
                    }
                    defmt::info!(
                        "storage: {=u16} stored parameters taken, {=u16} refused",
                        taken,
                        refused
                    );
                }
                let (v, ctrl) = vehicle.split();
                // The board's sensors, started (QEMU's: the simulator's).
                let (imu, sensors) = crate::imu_bus();
                v.set_sensors(sensors);
                let mut radio = Usart::init(Port::Usart6, PCLK2_HZ, SYSLINK_BAUD);
                let mut syslink: Syslink<DOWNLINK> = Syslink::new();
                if syslink.boot(&mut radio).is_err() {
                    defmt::warn!("USART6 transmit timed out (RADIO_READY)");
                }
                if let Some(st) = store {
                    syslink.keep_in(st);
                }
                defmt::info!(
                    "up: CRTP over syslink on USART6, the simulator on USART1; tasks: radio bytes (4), data-ready (3), controller (2), link (1)"
                );
                let (tasks_in, tasks_out) = cx.local.tasks.split();
                let (works_in, works_out) = cx.local.works.split();
                let (answers_in, answers_out) = cx.local.answers.split();
                (
                    Shared {
                        v,
                        sim_tx,
                        timing: Timing::new($crate::timing::DEADLINE_TICKS),
                        sim: SimCounters::default(),
                        imu,
                        ctrl: Some(ctrl),
                    },
                    Local {
                        outputs,
                        decoder: FrameDecoder::new(),
                        fixes: heapless::Vec::new(),
                        tasks_in,
                        tasks_out,
                        works_in,
                        works_out,
                        answers_in,
                        answers_out,
                        radio,
                        syslink,
                        last: Last::default(),
                        logged: StepTiming::default(),
                        holds: Holds::default(),
                        stack: $crate::stack::Watch::new(),
                        tx_errors: 0,
                        sample_clock: clock,
                        control_clock: clock,
                    },
                )
            }

            #[idle]
            fn idle(_: idle::Context) -> ! {
                board::idle()
            }

            /// The radio's bytes into their queue; the link's task takes them.
            /// Timed by itself, for the holds' and the steps' own work
            /// ([`RadioMark`]).
            #[task(binds = USART6, priority = 4)]
            fn radio_bytes(_: radio_bytes::Context) {
                use core::sync::atomic::Ordering::Relaxed;
                let t0 = hold_clock();
                usart_isr(Port::Usart6);
                rtic::pend(Interrupt::CAN2_RX1);
                let ran = hold_clock().saturating_sub(t0) as u32;
                $crate::crtp_app::RADIO_TICKS.fetch_add(ran, Relaxed);
                $crate::crtp_app::RADIO_RUNS.fetch_add(1, Relaxed);
            }

            /// The simulator's frames: a parameter write (answered, or its design
            /// left to the link's task), a fix (kept for the next sample), a
            /// sample (data-ready: the estimator's step, then the controller's).
            #[task(binds = USART1, priority = 3, shared = [v, timing, sim, imu], local = [decoder, fixes, tasks_in, answers_in, sample_clock])]
            fn data_ready(cx: data_ready::Context) {
                usart_isr(Port::Usart1);
                let data_ready::LocalResources {
                    decoder,
                    fixes,
                    tasks_in,
                    answers_in,
                    sample_clock: clock,
                    ..
                } = cx.local;
                let (mut v, mut timing, mut sim, mut imu) = (cx.shared.v, cx.shared.timing, cx.shared.sim, cx.shared.imu);
                let mut st = Stepping {
                    v: &mut v,
                    timing: &mut timing,
                    tasks_in,
                    fixes,
                    clock,
                };
                let mut buf = [0u8; 64];
                loop {
                    let n = read_queued(Port::Usart1, &mut buf);
                    if n == 0 {
                        break;
                    }
                    for &b in &buf[..n] {
                        let m = match decoder.push::<ToFc>(b) {
                            None => continue,
                            Some(Err(_)) => {
                                sim.lock(|c| c.bad = c.bad.wrapping_add(1));
                                continue;
                            }
                            Some(Ok(m)) => m,
                        };
                        match m {
                            ToFc::ParamSet { index, value } => {
                                // A write that re-designs stays queued in the
                                // vehicle: the link's task (pended as this one
                                // ends) takes it, designs and answers.
                                if let Some(a) = st.v.lock(|v| v.sim_param(index, value)) {
                                    if answers_in.enqueue(a).is_err() {
                                        st.timing.lock(|t| t.answers_dropped(1));
                                    }
                                }
                            }
                            ToFc::Fix(w) => {
                                if st.fixes.push(fix_from_wire(&w)).is_err() {
                                    sim.lock(|c| c.fixes_dropped = c.fixes_dropped.wrapping_add(1));
                                }
                            }
                            ToFc::Imu { seq, t_us, gyro, accel } => {
                                // Data-ready: the sample is whole (here, the `Imu`
                                // frame's last byte).
                                let entry = ticks_now();
                                let radio = $crate::crtp_app::RadioMark::now();
                                let s = ImuSample {
                                    gyro_frd_radps: Vector3::from(gyro),
                                    accel_frd_mps2: Vector3::from(accel),
                                };
                                st.sample(t_us, Some(&s), Some(seq), entry, radio);
                            }
                            _ => sim.lock(|c| c.ignored = c.ignored.wrapping_add(1)),
                        }
                    }
                }
                // The board's own barometer (50 Hz): a height fix before the next
                // sample's step.
                if let Some((at, alt_m)) = imu.lock(|b| b.take_baro()) {
                    st.v.lock(|v| v.baro(board::us_of(at), alt_m));
                }
                // The board's own sample, read on its bus's interrupts (a board's
                // data-ready line, its time taken there).
                while let Some((entry, s)) = imu.lock(|b| b.take()) {
                    // (the radio's runs from here: those between the line's
                    // interrupt and here count as the step's)
                    let radio = $crate::crtp_app::RadioMark::now();
                    st.sample(board::us_of(entry), s.as_ref(), None, entry, radio);
                }
                rtic::pend(Interrupt::CAN2_RX1);
            }

            /// The sample task's step, whichever source the sample came from.
            struct Stepping<'a, V, T> {
                v: &'a mut V,
                timing: &'a mut T,
                tasks_in: &'a mut Producer<'static, Task>,
                fixes: &'a mut heapless::Vec<Fix, FIXES>,
                clock: &'a SysTickClock,
            }

            impl<V, T> Stepping<'_, V, T>
            where
                V: rtic::Mutex<T = &'static mut CrtpShared>,
                T: rtic::Mutex<T = Timing>,
            {
                /// The estimator's step of a sample taken at `t_us` (`None`:
                /// missing) whose data-ready came at `entry` (the radio's runs
                /// then: `radio`), then the controller's queued (`seq`: the
                /// simulator's, answered).
                fn sample(
                    &mut self,
                    t_us: u64,
                    s: Option<&ImuSample>,
                    seq: Option<u32>,
                    entry: u64,
                    radio: $crate::crtp_app::RadioMark,
                ) {
                    let (fixes, clock) = (&mut *self.fixes, self.clock);
                    let step = self.v.lock(|v| v.imu_begin(t_us, s, fixes, clock));
                    self.fixes.clear();
                    let done = ticks_now().saturating_sub(if $crate::crtp_app::RADIO_APART_FROM_STEPS { radio.since() } else { 0 });
                    crate::WATCHDOG.imu_step();
                    self.timing.lock(|t| t.estimated(entry, done));
                    if self.tasks_in.enqueue(Task { step, seq, entry, radio }).is_err() {
                        self.timing.lock(|t| t.job_dropped());
                    }
                    rtic::pend(Interrupt::CAN2_RX0);
                }
            }

            /// The board's data-ready line (the Crazyflie's gyroscope INT3 on PC14,
            /// EXTI14): the sample's reads start. Never fires in QEMU.
            #[task(binds = EXTI15_10, priority = 3, shared = [imu])]
            fn gyro_ready(mut cx: gyro_ready::Context) {
                let entry = ticks_now();
                if cx.shared.imu.lock(|b| b.data_ready(entry)) {
                    rtic::pend(Interrupt::USART1);
                }
            }

            /// The board's IMU bus (I2C3): each event advances the sample's reads;
            /// the last pends `data_ready`.
            #[task(binds = I2C3_EV, priority = 3, shared = [imu])]
            fn imu_bus_event(mut cx: imu_bus_event::Context) {
                if cx.shared.imu.lock(|b| b.bus_interrupt(false)) {
                    rtic::pend(Interrupt::USART1);
                }
            }

            /// The board's IMU bus's errors (NACK, bus error, arbitration lost).
            #[task(binds = I2C3_ER, priority = 3, shared = [imu])]
            fn imu_bus_error(mut cx: imu_bus_error::Context) {
                if cx.shared.imu.lock(|b| b.bus_interrupt(true)) {
                    rtic::pend(Interrupt::USART1);
                }
            }

            /// The controller: the link's work first (a take-off's reset), then
            /// the sample task's steps in order; each step flown on the controller
            /// (passed, motors off, while the link's task designs it), its outputs
            /// driven and the simulator answered.
            #[task(binds = CAN2_RX0, priority = 2, shared = [v, sim_tx, timing, ctrl], local = [outputs, tasks_out, works_out, control_clock])]
            fn controller(cx: controller::Context) {
                let controller::LocalResources {
                    outputs,
                    tasks_out,
                    works_out,
                    control_clock: clock,
                    ..
                } = cx.local;
                let (mut v, mut sim_tx, mut timing, mut ctrl) =
                    (cx.shared.v, cx.shared.sim_tx, cx.shared.timing, cx.shared.ctrl);
                // The link's task (below this one) cannot run before this task
                // ends: the controller is this task's until then, or the link's
                // for its whole design.
                ctrl.lock(|ctrl| loop {
                    // The link's work (a take-off's reset) before the next step.
                    if let Some(work) = works_out.dequeue() {
                        let answer = match ctrl.as_deref_mut() {
                            Some(c) => run_work(&mut v, c, work).1,
                            // Not reached (a take-off is refused while a
                            // design runs); refused if it were.
                            None => v.lock(|v| v.work_done(&work, Err(Refusal::Busy))),
                        };
                        if let Some(a) = answer {
                            if sim_tx.lock(|u| send(u, &a)).is_err() {
                                timing.lock(|t| t.tx_timeout());
                            }
                        }
                        continue;
                    }
                    let Some(Task { step, seq, entry, radio }) = tasks_out.dequeue() else {
                        break;
                    };
                    let flown = ctrl.is_some();
                    let power = match ctrl.as_deref_mut() {
                        Some(c) => fly_step(&mut v, c, step, clock),
                        None => pass_step(&mut v, step, clock),
                    };
                    v.lock(|v| outputs.drive(v, &power));
                    // The step is flown when its outputs are driven (under
                    // QEMU, the radio's runs that landed in it apart).
                    let (done, radio) = (ticks_now(), radio.since());
                    let done = done.saturating_sub(if $crate::crtp_app::RADIO_APART_FROM_STEPS { radio } else { 0 });
                    crate::WATCHDOG.controller_step();
                    // The simulator's sample is answered; the board's own is not.
                    let sent = match seq {
                        Some(seq) => {
                            let answer = FromFc::Actuator {
                                seq,
                                u: power.u.into(),
                                failsafe: false,
                            };
                            sim_tx.lock(|tx| send(tx, &answer))
                        }
                        None => Ok(()),
                    };
                    // The log blocks due, sampled at this step; what the
                    // outputs show besides the motors.
                    let (armed, nav, battery_v) = v.lock(|v| {
                        v.sample_logs();
                        (v.armed(), v.flight_loop().navigator().mode(), v.battery_v())
                    });
                    outputs.report(armed, nav, battery_v);
                    timing.lock(|t| {
                        t.radio_in_step(radio);
                        if flown {
                            t.flown(entry, done);
                        } else {
                            t.passed(entry, done);
                        }
                        if sent.is_err() {
                            t.tx_timeout();
                        }
                    });
                });
                rtic::pend(Interrupt::CAN2_RX1);
            }

            /// The link: the simulator's re-designs, the radio's packets (a
            /// re-design one asks for run at once), the log blocks and answers
            /// that fell due, the simulator's queued answers, then what changed in
            /// the log.
            #[task(binds = CAN2_RX1, priority = 1, shared = [v, sim_tx, timing, sim, ctrl], local = [radio, syslink, works_in, answers_out, last, logged, holds, stack, tx_errors])]
            fn link(cx: link::Context) {
                let link::LocalResources {
                    radio,
                    syslink,
                    works_in,
                    answers_out,
                    last,
                    logged,
                    holds,
                    stack,
                    tx_errors,
                    ..
                } = cx.local;
                let (v, mut sim_tx, mut timing, mut sim) = (cx.shared.v, cx.shared.sim_tx, cx.shared.timing, cx.shared.sim);
                let mut vehicle = Handing {
                    v,
                    holds,
                    works: works_in,
                    ctrl: cx.shared.ctrl,
                    answer: None,
                };
                let mut ok = true;
                // Once: what a run of the radio's task costs outside its
                // own clock readings, under the vehicle's lock as a hold is.
                if $crate::crtp_app::RADIO_OVERHEAD.load(core::sync::atomic::Ordering::Relaxed) == 0 {
                    let k = vehicle.v.lock(|_| {
                        $crate::crtp_app::radio_overhead(hold_clock, || rtic::pend(Interrupt::USART6))
                    });
                    $crate::crtp_app::RADIO_OVERHEAD.store(k.max(1), core::sync::atomic::Ordering::Relaxed);
                    defmt::info!(
                        "link: a run of the radio's task costs {=u64} instructions outside its own clock readings (measured; taken off each hold it lands in, and under QEMU each step)",
                        $crate::timing::instructions(u64::from(k)) >> 8
                    );
                }
                // The store refuses writes while armed.
                $crate::crtp_app::ARMED.store(vehicle.v.lock(|v| v.armed()), core::sync::atomic::Ordering::Relaxed);
                // The simulator's re-designing write, if one waits.
                vehicle.lock(|_| ());
                let mut buf = [0u8; 64];
                loop {
                    let n = read_queued(Port::Usart6, &mut buf);
                    if n == 0 {
                        break;
                    }
                    ok &= syslink.receive(&buf[..n], &mut vehicle, radio).is_ok();
                }
                syslink.poll(&mut vehicle);
                while let Some(m) = answers_out.dequeue().or_else(|| vehicle.answer.take()) {
                    ok &= sim_tx.lock(|u| send(u, &m)).is_ok();
                }
                if !ok {
                    *tx_errors = tx_errors.wrapping_add(1);
                    defmt::warn!("a USART transmit timed out ({=u32} so far)", *tx_errors);
                }
                crate::WATCHDOG.service();
                let (armed, imu) = vehicle.v.lock(|v| (v.armed(), v.imu_counters()));
                let sc = sim.lock(|c| *c);
                log_changes(armed, imu, &syslink.counters(), &sc, last);
                let now = timing.lock(|t| t.snapshot());
                stack.poll();
                if now.due(logged) {
                    stack.log_if_grown();
                    vehicle.holds.log_if_grown();
                    if let Some(n) = timing.lock(|t| t.radio_grown()) {
                        defmt::info!("radio: its interrupts took up to {=u64} instructions of one step", n);
                    }
                }
                now.log_if_due(logged);
            }

            /// [`ticks_now`] out of line: read at the start and end of each of
            /// the link's packet locks ([`Holds`], [`Handing::lock`]'s many
            /// instances), where inlined it costs kilobytes of flash, and by
            /// the radio's task during them.
            #[inline(never)]
            fn hold_clock() -> u64 {
                ticks_now()
            }

            /// The vehicle as the link's task locks it: the controller work a
            /// packet asked for runs as the lock ends, a re-design here
            /// ([`Handing::design`]), anything else in the controller's task.
            struct Handing<'a, M, C> {
                v: M,
                /// The longest hold of `v` so far.
                holds: &'a mut Holds,
                works: &'a mut Producer<'static, ControllerWork>,
                ctrl: C,
                /// The simulator's answer to its re-designing write, once designed.
                answer: Option<FromFc>,
            }

            impl<M, C> Handing<'_, M, C>
            where
                M: Mutex<T = &'static mut CrtpShared>,
                C: rtic::Mutex<T = Option<&'static mut AnyController<f32>>>,
            {
                /// Runs the re-design `work` on the controller, borrowed from the
                /// controller's task for it (which passes its steps meanwhile, the
                /// vehicle disarmed); returns the simulator's answer, if it asked.
                fn design(&mut self, work: ControllerWork) -> Option<FromFc> {
                    let Some(c) = self.ctrl.lock(|c| c.take()) else {
                        // Not reached (the controller's task gives it back before
                        // it ends); refused if it were.
                        return self.v.lock(|v| v.work_done(&work, Err(Refusal::Busy)));
                    };
                    crate::WATCHDOG.designing(true);
                    let (_, answer) = run_work(&mut self.v, c, work);
                    crate::WATCHDOG.designing(false);
                    self.ctrl.lock(|slot| *slot = Some(c));
                    answer
                }
            }

            impl<M, C> Mutex for Handing<'_, M, C>
            where
                M: Mutex<T = &'static mut CrtpShared>,
                C: rtic::Mutex<T = Option<&'static mut AnyController<f32>>>,
            {
                type T = CrtpShared;
                fn lock<R>(&mut self, f: impl FnOnce(&mut CrtpShared) -> R) -> R {
                    // Timed inside the lock (once it ends, a task it held
                    // back runs first), less the radio's interrupts that
                    // fell inside it: the hold's own work. The flag is set
                    // after the start and cleared before the end, so an
                    // interrupt at either edge counts as the hold's.
                    use core::sync::atomic::Ordering::Relaxed;
                    let (r, work, held) = self.v.lock(|v| {
                        let t0 = hold_clock();
                        let radio = $crate::crtp_app::RadioMark::now();
                        let r = f(v);
                        let work = v.take_work();
                        let radio = radio.since();
                        (r, work, hold_clock().saturating_sub(t0).saturating_sub(radio))
                    });
                    self.holds.held(held);
                    match work {
                        // A packet's design is answered over CRTP (`work_done`),
                        // the simulator's by a message for it.
                        Some(work) if work.designs() => {
                            if let Some(a) = self.design(work) {
                                self.answer = Some(a);
                            }
                        }
                        Some(work) => {
                            if self.works.enqueue(work).is_err() {
                                // Not reached (one piece of work at a time);
                                // refused if it were.
                                self.v.lock(|v| v.work_done(&work, Err(Refusal::Busy)));
                            }
                            rtic::pend(Interrupt::CAN2_RX0);
                        }
                        None => {}
                    }
                    r
                }
            }
        }
    };
}
