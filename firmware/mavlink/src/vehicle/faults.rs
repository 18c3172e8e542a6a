//! Faults in the simulator's sensors: PX4's failure injection
//! (`MAV_CMD_INJECT_FAILURE`, obeyed only with `SYS_FAILURE_EN` 1, as
//! MAVSDK's `Failure` plugin and PX4's `failure` command send it) applied
//! where the vehicle takes the simulator's data, as PX4's simulator bridge
//! applies it; and each source's health ([`fc_loop::health`]) told to the
//! ground station as it changes.
//!
//! Modelled: the position fix (`HIL_STATE_QUATERNION`, PX4's "gps": off,
//! stuck, wrong by [`WRONG_BY_M`] north, intermittent), the barometer (off,
//! stuck), the magnetometer (off, stuck, wrong by a quarter turn), and the
//! IMU's gyro and accelerometer (off, stuck). A step without a good
//! gyro reading flies the gyro's recent mean; one without a good
//! accelerometer reading, in the air, the specific force its commanded
//! thrust gives (on the ground, the accelerometer's mean); past
//! [`IMU_TIMEOUT_US`](fc_loop::supervisor::IMU_TIMEOUT_US) in the air the
//! vehicle lands ([`fc_loop::modes::ModeCommander::watch_imu`]), and
//! without the gyro for [`GYRO_DEAD_US`] it stops its motors. On the ground
//! a part that has read with noise and then reads the same values in a row
//! refuses an arming.

#[cfg(feature = "sensor-faults")]
pub(in crate::vehicle) use on::*;
#[cfg(not(feature = "sensor-faults"))]
pub(in crate::vehicle) use stand_in::*;

#[cfg(feature = "sensor-faults")]
mod on {
    use super::super::{
        hil, MavResult, MavSeverity, MavShared, MavSink, Vector3, HIL_STATE_QUATERNION_DATA, MAG_IMPLAUSIBLE_RAD,
        MAG_SIGMA_RAD, POSITION_IMPLAUSIBLE_M,
    };
    use fc_core::estimate::ImuSample;
    use fc_loop::health::{fingerprint, Change, Watch};
    use fc_loop::supervisor::IMU_TIMEOUT_US;

    /// How far north a "wrong" position fix is, m.
    pub const WRONG_BY_M: f64 = 5.0;

    /// Each good IMU sample's weight in the running mean a step without one
    /// flies on (at 1 kHz, a time constant of 50 ms: the rates' noise and
    /// the last instant's motion averaged out, not the hover's).
    pub const IMU_MEAN_GAIN: f32 = 0.02;

    /// Without a good gyro reading for this long in the air, the vehicle
    /// stops its motors (PX4's flight termination): a quadrotor has no
    /// attitude to fly without its rates, and a landing on their mean flies
    /// away (metres, against rotorpy), µs.
    pub const GYRO_DEAD_US: u64 = 100_000;

    /// An intermittent source reads for this long, then is silent as long, µs.
    pub const INTERMITTENT_US: u64 = 300_000;

    /// Readings of an IMU part, disarmed, over which its noise is judged.
    pub const NOISE_WINDOW: u8 = 20;

    /// Sign changes of the differences between a part's readings in a row,
    /// on one axis, over [`NOISE_WINDOW`] readings disarmed, from which the
    /// part reads with noise. White noise changes sign about two times in
    /// three (≈ 13 of 19); a noiseless simulator's motion changes it only
    /// where the motion turns (a roll's end, a settling's swings).
    pub const NOISE_FLIPS: u8 = 8;

    /// One IMU part's readings while disarmed: whether it has read with
    /// noise, and how many readings in a row are the same. A part that has
    /// read with noise and then reads [`STUCK_READINGS`](fc_loop::health::STUCK_READINGS) equal in a row
    /// (by value), is stuck: no arming on it (PX4's preflight "stale" sensor). A
    /// noiseless simulator's IMU at rest reads the same for seconds, and has
    /// never read with noise: it arms.
    #[derive(Debug, Clone, Copy, Default)]
    struct Quiet {
        last: Option<Vector3<f32>>,
        sign: [i8; 3],
        flips: [u8; 3],
        window: u8,
        noisy: bool,
        same: u16,
    }

    impl Quiet {
        fn read(&mut self, v: &Vector3<f32>) {
            let Some(last) = self.last.replace(*v) else {
                return;
            };
            let d = v - last;
            self.same = if d == Vector3::zeros() {
                self.same.saturating_add(1)
            } else {
                0
            };
            for (i, &di) in d.iter().enumerate() {
                let sign = if di > 0.0 {
                    1
                } else if di < 0.0 {
                    -1
                } else {
                    continue;
                };
                if self.sign[i] == -sign {
                    self.flips[i] = self.flips[i].saturating_add(1);
                }
                self.sign[i] = sign;
            }
            self.window += 1;
            if self.window >= NOISE_WINDOW {
                self.noisy |= self.flips.iter().any(|&f| f >= NOISE_FLIPS);
                self.window = 0;
                self.flips = [0; 3];
            }
        }

        /// Armed: the readings in the air are [`Watch`]'s; the next disarmed
        /// ones start again (whether the part is noisy is kept).
        fn armed(&mut self) {
            *self = Quiet {
                noisy: self.noisy,
                ..Quiet::default()
            };
        }

        fn stuck(&self) -> bool {
            self.noisy && self.same >= fc_loop::health::STUCK_READINGS
        }
    }

    /// A fault as MAVLink's `FAILURE_TYPE` names it (those modelled here).
    #[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
    pub enum Injected {
        /// `FAILURE_TYPE_OK`: as the simulator sends it.
        #[default]
        Ok,
        /// `FAILURE_TYPE_OFF`: nothing.
        Off,
        /// `FAILURE_TYPE_STUCK`: the reading at the injection, again and again.
        Stuck,
        /// `FAILURE_TYPE_WRONG`: plausible and wrong.
        Wrong,
        /// `FAILURE_TYPE_INTERMITTENT`: on and off in turns of [`INTERMITTENT_US`].
        Intermittent,
    }

    impl Injected {
        fn of(failure_type: f32) -> Option<Self> {
            // MAVLink's FAILURE_TYPE, a whole number (`as` saturates, NaN to
            // 0: a value that does not come back is not one).
            let k = failure_type as u8;
            if f32::from(k) != failure_type {
                return None;
            }
            Some(match k {
                0 => Injected::Ok,
                1 => Injected::Off,
                2 => Injected::Stuck,
                4 => Injected::Wrong,
                7 => Injected::Intermittent,
                _ => return None,
            })
        }

        fn name(self) -> &'static str {
            match self {
                Injected::Ok => "ok",
                Injected::Off => "off",
                Injected::Stuck => "stuck",
                Injected::Wrong => "wrong",
                Injected::Intermittent => "intermittent",
            }
        }
    }

    /// A source of the simulator's data.
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    pub(in crate::vehicle) enum Source {
        /// `HIL_STATE_QUATERNION`'s position and heading (PX4's "gps").
        Position,
        /// `HIL_SENSOR`'s pressure altitude.
        Baro,
        /// `HIL_SENSOR`'s magnetic field.
        Mag,
        /// `HIL_SENSOR`'s angular rates.
        Gyro,
        /// `HIL_SENSOR`'s specific force.
        Accel,
    }

    /// How many sources there are.
    const SOURCES: usize = 5;

    impl Source {
        const ALL: [Source; SOURCES] = [Source::Position, Source::Baro, Source::Mag, Source::Gyro, Source::Accel];

        fn name(self) -> &'static str {
            match self {
                Source::Position => "position fix",
                Source::Baro => "barometer",
                Source::Mag => "magnetometer",
                Source::Gyro => "gyro",
                Source::Accel => "accelerometer",
            }
        }

        /// MAVLink's `FAILURE_UNIT` of this source.
        fn of(unit: f32) -> Result<Self, &'static str> {
            match unit {
                4.0 => Ok(Source::Position),
                3.0 => Ok(Source::Baro),
                2.0 => Ok(Source::Mag),
                1.0 => Ok(Source::Accel),
                0.0 => Ok(Source::Gyro),
                _ => Err("no such sensor here"),
            }
        }

        /// The faults modelled for this source.
        fn takes(self, f: Injected) -> bool {
            match self {
                Source::Position => true,
                Source::Baro | Source::Gyro | Source::Accel => {
                    matches!(f, Injected::Ok | Injected::Off | Injected::Stuck)
                }
                Source::Mag => f != Injected::Intermittent,
            }
        }
    }

    /// The faults injected and each source's health.
    #[derive(Debug, Clone, Default)]
    pub struct Faults {
        injected: [Injected; SOURCES],
        held_state: Option<HIL_STATE_QUATERNION_DATA>,
        held_baro: Option<f32>,
        held_mag: Option<Vector3<f32>>,
        /// The gyro's and the accelerometer's readings when they stuck.
        held_imu: [Option<Vector3<f32>>; 2],
        watch: [Watch; SOURCES],
        /// The good readings' running mean ([`IMU_MEAN_GAIN`]): what a step
        /// flies on for a part without one.
        imu_mean: Option<ImuSample>,
        /// Since when the gyro and the accelerometer have had no good reading, µs.
        imu_lost_us: [Option<u64>; 2],
        /// The gyro's and the accelerometer's readings while disarmed.
        quiet: [Quiet; 2],
        /// Health changes since the last step's end, to be told.
        changes: heapless::Vec<(Source, Change), SOURCES>,
        /// In the air at the last step ([`fc_loop::modes::ModeCommander::in_air`]).
        airborne: bool,
        /// Armed at the last step.
        armed: bool,
    }

    impl Faults {
        /// Nothing injected, every source not heard yet.
        pub(in crate::vehicle) fn new() -> Self {
            Self::default()
        }

        fn injected(&self, s: Source) -> Injected {
            self.injected[s as usize]
        }

        fn note(&mut self, s: Source, c: Option<Change>) {
            if let Some(c) = c {
                let _ = self.changes.push((s, c));
            }
        }

        /// Whether a reading of `s` (whose values hash to `print`) at `t_us` is
        /// used ([`Watch::sample`]; `airborne`: the vehicle is in the air).
        fn sample(&mut self, s: Source, t_us: u64, print: u32) -> bool {
            let c = self.watch[s as usize].sample(t_us, print, self.airborne);
            self.note(s, c);
            self.watch[s as usize].feeds()
        }

        /// The position fix as the injected fault leaves it: `None` as it
        /// is, `Some(None)` nothing, else what it reads.
        pub(in crate::vehicle) fn position(
            &mut self,
            m: &HIL_STATE_QUATERNION_DATA,
        ) -> Option<Option<HIL_STATE_QUATERNION_DATA>> {
            Some(match self.injected(Source::Position) {
                Injected::Ok => return None,
                Injected::Off => None,
                Injected::Stuck => {
                    let held = self.held_state.get_or_insert_with(|| m.clone());
                    Some(HIL_STATE_QUATERNION_DATA {
                        time_usec: m.time_usec,
                        ..held.clone()
                    })
                }
                Injected::Wrong => {
                    let dlat_e7 = (WRONG_BY_M / hil::EARTH_RADIUS_M).to_degrees() * 1e7;
                    Some(HIL_STATE_QUATERNION_DATA {
                        lat: m.lat.saturating_add(dlat_e7 as i32),
                        ..m.clone()
                    })
                }
                Injected::Intermittent => (m.time_usec / INTERMITTENT_US).is_multiple_of(2).then(|| m.clone()),
            })
        }

        /// Whether the position fix `m` is used: its health
        /// ([`Watch::sample`] on every value but its time).
        pub(in crate::vehicle) fn position_usable(&mut self, m: &HIL_STATE_QUATERNION_DATA) -> bool {
            let q = m.attitude_quaternion.map(f32::to_bits);
            let print = fingerprint(&[
                m.lat as u32,
                m.lon as u32,
                m.alt as u32,
                q[0],
                q[1],
                q[2],
                q[3],
                m.rollspeed.to_bits(),
                m.pitchspeed.to_bits(),
                m.yawspeed.to_bits(),
                u32::from(m.vx as u16) | u32::from(m.vy as u16) << 16,
                u32::from(m.vz as u16) | u32::from(m.xacc as u16) << 16,
                u32::from(m.yacc as u16) | u32::from(m.zacc as u16) << 16,
            ]);
            self.sample(Source::Position, m.time_usec, print)
        }

        /// A barometric altitude as the injected fault leaves it, and whether
        /// it is used.
        pub(in crate::vehicle) fn baro(&mut self, t_us: u64, alt_m: f32) -> Option<f32> {
            let alt = match self.injected(Source::Baro) {
                Injected::Off => return None,
                Injected::Stuck => *self.held_baro.get_or_insert(alt_m),
                _ => alt_m,
            };
            self.sample(Source::Baro, t_us, alt.to_bits()).then_some(alt)
        }

        /// A magnetic field (FRD, gauss) as the injected fault leaves it (wrong:
        /// turned a quarter about the body's z axis), and whether it is used.
        pub(in crate::vehicle) fn mag(&mut self, t_us: u64, mag: &Vector3<f32>) -> Option<Vector3<f32>> {
            let m = match self.injected(Source::Mag) {
                Injected::Off => return None,
                Injected::Stuck => *self.held_mag.get_or_insert(*mag),
                Injected::Wrong => Vector3::new(-mag[1], mag[0], mag[2]),
                _ => *mag,
            };
            let print = fingerprint(&[m[0].to_bits(), m[1].to_bits(), m[2].to_bits()]);
            self.sample(Source::Mag, t_us, print).then_some(m)
        }

        /// The IMU's sample `s` at `t_us` as the injected faults leave it,
        /// and the sample to step on: each part (gyro, accelerometer) as it
        /// reads if it is used (not off, not condemned), else the running
        /// mean of its good readings ([`IMU_MEAN_GAIN`]); `None` before the
        /// first good sample. An accelerometer without a good reading is
        /// replaced by what `thrust_frd_mps2` gives instead, if anything: in
        /// the air, the specific force the commanded thrust gives (FRD,
        /// m/s²: `(0, 0, −U1/m)`). On a mean the estimator sees no climb or
        /// sink the height loop commands, and the loop oscillates on it.
        pub(in crate::vehicle) fn imu(
            &mut self,
            t_us: u64,
            s: &ImuSample,
            thrust_frd_mps2: impl FnOnce() -> Option<Vector3<f32>>,
        ) -> Option<ImuSample> {
            let gyro = self.imu_part(Source::Gyro, t_us, &s.gyro_frd_radps);
            let accel = self.imu_part(Source::Accel, t_us, &s.accel_frd_mps2);
            for (k, good) in [gyro.is_some(), accel.is_some()].into_iter().enumerate() {
                if good {
                    self.imu_lost_us[k] = None;
                } else {
                    self.imu_lost_us[k].get_or_insert(t_us);
                }
            }
            if let (None, Some(g), Some(a)) = (self.imu_mean, gyro, accel) {
                self.imu_mean = Some(ImuSample {
                    gyro_frd_radps: g,
                    accel_frd_mps2: a,
                });
            }
            let m = self.imu_mean.as_mut()?;
            if let Some(g) = gyro {
                m.gyro_frd_radps += (g - m.gyro_frd_radps) * IMU_MEAN_GAIN;
            }
            if let Some(a) = accel {
                m.accel_frd_mps2 += (a - m.accel_frd_mps2) * IMU_MEAN_GAIN;
            }
            Some(ImuSample {
                gyro_frd_radps: gyro.unwrap_or(m.gyro_frd_radps),
                accel_frd_mps2: accel.or_else(thrust_frd_mps2).unwrap_or(m.accel_frd_mps2),
            })
        }

        /// One part of the IMU's sample (`s`: [`Source::Gyro`] or
        /// [`Source::Accel`]) as its fault leaves it, if it is used.
        fn imu_part(&mut self, s: Source, t_us: u64, v: &Vector3<f32>) -> Option<Vector3<f32>> {
            let k = usize::from(s == Source::Accel);
            let v = match self.injected(s) {
                Injected::Off => return None,
                Injected::Stuck => *self.held_imu[k].get_or_insert(*v),
                _ => *v,
            };
            if self.armed {
                self.quiet[k].armed();
            } else {
                self.quiet[k].read(&v);
            }
            let print = fingerprint(&[v[0].to_bits(), v[1].to_bits(), v[2].to_bits()]);
            self.sample(s, t_us, print).then_some(v)
        }

        /// A part of the IMU without a good reading for longer than
        /// [`IMU_TIMEOUT_US`] at `t_us`: the steps fly its mean.
        pub(in crate::vehicle) fn imu_silent(&self, t_us: u64) -> bool {
            self.imu_lost_us
                .iter()
                .flatten()
                .any(|&since| t_us.saturating_sub(since) > IMU_TIMEOUT_US)
        }

        /// The gyro without a good reading for longer than [`GYRO_DEAD_US`]
        /// at `t_us`: no rate to damp the attitude with.
        pub(in crate::vehicle) fn gyro_dead(&self, t_us: u64) -> bool {
            self.imu_lost_us[0].is_some_and(|since| t_us.saturating_sub(since) > GYRO_DEAD_US)
        }

        /// Whether a reading of `s` agrees with the estimate
        /// ([`fc_loop::health::plausible`], [`Watch::judged`]).
        fn judged(&mut self, s: Source, agrees: bool) {
            let c = self.watch[s as usize].judged(agrees);
            self.note(s, c);
        }

        /// After the estimator's step at `t_us`: every source's silence
        /// ([`Watch::tick`]). Disarmed since the last step (`armed` false, it
        /// was armed): a new flight's health ([`Faults::restart`]); a source
        /// condemned on the ground stays so until it reads well, and refuses
        /// an arming.
        pub(in crate::vehicle) fn after_step(&mut self, t_us: u64, airborne: bool, armed: bool) {
            if self.armed && !armed {
                self.restart();
            }
            self.armed = armed;
            self.airborne = airborne;
            for w in &mut self.watch {
                w.fly(armed);
            }
            for s in Source::ALL {
                let c = self.watch[s as usize].tick(t_us);
                self.note(s, c);
            }
        }

        /// Whether position fixes are handed to the estimator ([`Watch::feeds`]).
        pub(in crate::vehicle) fn position_feeds(&self) -> bool {
            self.watch[Source::Position as usize].feeds()
        }

        /// The position is known: its fix is not condemned (stuck or wrong; a
        /// silent one is the estimator's to judge, which dead-reckons for a
        /// while).
        pub(in crate::vehicle) fn position_known(&self) -> bool {
            self.watch[Source::Position as usize].usable()
                || self.watch[Source::Position as usize].fault() == Some(fc_loop::health::Fault::Silent)
        }

        /// The first source whose fault refuses an arming, and the fault: a
        /// source's health, or an IMU part stuck while disarmed ([`Quiet`]).
        pub(in crate::vehicle) fn arming_refusal(&self) -> Option<(&'static str, fc_loop::health::Fault)> {
            Source::ALL
                .iter()
                .find_map(|&s| self.watch[s as usize].fault().map(|f| (s.name(), f)))
                .or_else(|| {
                    [Source::Gyro, Source::Accel]
                        .into_iter()
                        .zip(self.quiet)
                        .find_map(|(s, q)| q.stuck().then_some((s.name(), fc_loop::health::Fault::Stuck)))
                })
        }

        /// A new flight (disarmed, or a new time line): every source's health
        /// forgotten; the injected faults stay (and the IMU's last good
        /// sample: a disarmed vehicle still steps on it).
        pub(in crate::vehicle) fn restart(&mut self) {
            self.watch = [Watch::new(); SOURCES];
            self.airborne = false;
        }

        /// A new time line (a simulator that started again): a new flight,
        /// and the IMU's last good sample forgotten.
        pub(in crate::vehicle) fn new_time_line(&mut self) {
            self.restart();
            self.imu_mean = None;
            self.imu_lost_us = [None; 2];
            self.quiet = [Quiet::default(); 2];
        }
    }

    impl MavShared {
        /// The position fix just taken (`HIL_STATE_QUATERNION`, its NED
        /// in `reported_ned_m`) against the estimate: judged
        /// ([`fc_loop::health::plausible`]); whether it is handed to the
        /// estimator.
        pub(in crate::vehicle) fn judge_position(&mut self) -> bool {
            let Some(est) = self.lp.navigator().estimate() else {
                return true;
            };
            let off = (self.reported_ned_m.unwrap_or_default() - est.pos_ned_m.cast::<f64>()).norm() as f32;
            let sigma = self.lp.navigator().estimator().position_sigma_m();
            let agrees = fc_loop::health::plausible(off, sigma, POSITION_IMPLAUSIBLE_M);
            self.faults.judged(Source::Position, agrees);
            self.faults.position_feeds()
        }

        /// A magnetic heading `innovation` rad from the estimate: judged.
        pub(in crate::vehicle) fn judge_mag(&mut self, innovation: f32) {
            let agrees = fc_loop::health::plausible(innovation, MAG_SIGMA_RAD, MAG_IMPLAUSIBLE_RAD);
            self.faults.judged(Source::Mag, agrees);
        }

        /// `MAV_CMD_INJECT_FAILURE` (`unit`, `failure_type`, `instance`: 0 all,
        /// or the one there is): refused (`DENIED`) unless `SYS_FAILURE_EN` is
        /// 1; `UNSUPPORTED` for what is not modelled; each answer said.
        pub(in crate::vehicle) fn inject<S: MavSink>(
            &mut self,
            p: &[f32; 7],
            out: &mut S,
        ) -> Result<MavResult, S::Error> {
            if !self.lp.settings().nav.failure_injection {
                self.say(
                    out,
                    MavSeverity::MAV_SEVERITY_WARNING,
                    format_args!("failure injection off (SYS_FAILURE_EN 0)"),
                )?;
                return Ok(MavResult::MAV_RESULT_DENIED);
            }
            let what = Source::of(p[0]).and_then(|s| {
                let f = Injected::of(p[1])
                    .filter(|&f| s.takes(f))
                    .ok_or("fault not modelled here")?;
                if p[2] == 0.0 || p[2] == 1.0 {
                    Ok((s, f))
                } else {
                    Err("one instance of each sensor here")
                }
            });
            match what {
                Ok((s, f)) => {
                    self.faults.injected[s as usize] = f;
                    match s {
                        Source::Position => self.faults.held_state = None,
                        Source::Baro => self.faults.held_baro = None,
                        Source::Mag => self.faults.held_mag = None,
                        Source::Gyro => self.faults.held_imu[0] = None,
                        Source::Accel => self.faults.held_imu[1] = None,
                    }
                    self.say(
                        out,
                        MavSeverity::MAV_SEVERITY_WARNING,
                        format_args!("failure injected: {} {}", s.name(), f.name()),
                    )?;
                    Ok(MavResult::MAV_RESULT_ACCEPTED)
                }
                Err(why) => {
                    self.say(
                        out,
                        MavSeverity::MAV_SEVERITY_WARNING,
                        format_args!("failure refused: {why}"),
                    )?;
                    Ok(MavResult::MAV_RESULT_UNSUPPORTED)
                }
            }
        }

        /// Tells the ground station each source's health change since the
        /// last step ("position fix stuck: 20 readings the same, not used").
        pub(in crate::vehicle) fn tell_health<S: MavSink>(&mut self, out: &mut S) -> Result<(), S::Error> {
            let changes = core::mem::take(&mut self.faults.changes);
            for (s, c) in changes {
                match c {
                    Change::Lost(f) => self.say(
                        out,
                        MavSeverity::MAV_SEVERITY_CRITICAL,
                        format_args!("{} {f}: not used", s.name()),
                    )?,
                    Change::Back => self.say(out, MavSeverity::MAV_SEVERITY_INFO, format_args!("{} back", s.name()))?,
                }
            }
            Ok(())
        }
    }
}

/// The stand-in without `sensor-faults`: nothing injected, every source
/// taken as it is; `MAV_CMD_INJECT_FAILURE` is `UNSUPPORTED`.
#[cfg(not(feature = "sensor-faults"))]
mod stand_in {
    use super::super::{MavResult, MavShared, MavSink, Vector3, HIL_STATE_QUATERNION_DATA};
    use fc_core::estimate::ImuSample;

    /// Nothing (see the module).
    #[derive(Debug, Clone)]
    pub struct Faults;

    impl Faults {
        /// Nothing.
        #[inline(always)]
        pub(in crate::vehicle) const fn new() -> Self {
            Faults
        }
        #[inline(always)]
        pub(in crate::vehicle) fn position(
            &mut self,
            _: &HIL_STATE_QUATERNION_DATA,
        ) -> Option<Option<HIL_STATE_QUATERNION_DATA>> {
            None
        }
        #[inline(always)]
        pub(in crate::vehicle) fn position_usable(&mut self, _: &HIL_STATE_QUATERNION_DATA) -> bool {
            true
        }
        #[inline(always)]
        pub(in crate::vehicle) fn baro(&mut self, _: u64, alt_m: f32) -> Option<f32> {
            Some(alt_m)
        }
        #[inline(always)]
        pub(in crate::vehicle) fn mag(&mut self, _: u64, mag: &Vector3<f32>) -> Option<Vector3<f32>> {
            Some(*mag)
        }
        #[inline(always)]
        pub(in crate::vehicle) fn imu(
            &mut self,
            _: u64,
            s: &ImuSample,
            _: impl FnOnce() -> Option<Vector3<f32>>,
        ) -> Option<ImuSample> {
            Some(*s)
        }
        #[inline(always)]
        pub(in crate::vehicle) fn after_step(&mut self, _: u64, _: bool, _: bool) {}
        #[inline(always)]
        pub(in crate::vehicle) fn arming_refusal(&self) -> Option<(&'static str, fc_loop::health::Fault)> {
            None
        }
        #[inline(always)]
        pub(in crate::vehicle) fn new_time_line(&mut self) {}
    }

    impl MavShared {
        #[inline(always)]
        pub(in crate::vehicle) fn judge_position(&mut self) -> bool {
            true
        }
        #[inline(always)]
        pub(in crate::vehicle) fn judge_mag(&mut self, _: f32) {}
        #[inline(always)]
        pub(in crate::vehicle) fn inject<S: MavSink>(
            &mut self,
            _: &[f32; 7],
            _: &mut S,
        ) -> Result<MavResult, S::Error> {
            Ok(MavResult::MAV_RESULT_UNSUPPORTED)
        }
        #[inline(always)]
        pub(in crate::vehicle) fn tell_health<S: MavSink>(&mut self, _: &mut S) -> Result<(), S::Error> {
            Ok(())
        }
    }
}
