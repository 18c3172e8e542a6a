//! The independent watchdog (IWDG, clocked by the 32 kHz LSI) and the rule
//! that feeds it.
//!
//! The rule: the IWDG is fed only when, since the last feed, the IMU task
//! **and** the controller task both completed at least one step. The IMU
//! task runs on the gyroscope's data-ready (or, if that line goes silent,
//! on its backup timer, where it counts the missing sample and the
//! supervisor starts a failsafe descent): a dead sensor does not reset the
//! chip in flight, a hung task does. The feed itself runs in the
//! lowest-priority task, so a task that never returns starves it too.
//!
//! Timeout: LSI / 32 / 100 → 100 ms at the nominal 32 kHz; the LSI varies
//! from 17 to 47 kHz (datasheet DS8626 table 38), so 68–188 ms.
//! While the controller's task designs (tens of milliseconds on the chip,
//! no controller step), the timeout is widened to [`design_timeout_us`] and
//! set back after.
//!
//! QEMU's netduinoplus2 models no IWDG; [`FeedRule`] is the same code on
//! the board and in the host tests below, which run it against a model of
//! the IWDG's countdown.

use core::sync::atomic::{AtomicU32, Ordering};
use stm32f4::stm32f405::iwdg;

/// `IWDG_PR`: divide by 32 (PR = 3).
pub const PRESCALER_BITS: u8 = 3;
/// `IWDG_RLR`: 100 counts.
pub const RELOAD: u16 = 99;
/// Nominal LSI, Hz.
pub const LSI_HZ: u32 = 32_000;
/// Polls of the status register before giving up on the prescaler and
/// reload updates (each takes up to 5 LSI cycles, ≈ 160 µs ≈ 27 k cycles at 168 MHz).
pub const UPDATE_POLLS: u32 = 100_000;

/// The timeout at an LSI of `lsi_hz`, µs (RM0090 §19.3.3: 4·2^PR·(RL+1) / f_LSI).
pub const fn timeout_us(lsi_hz: u32) -> u32 {
    ((4u64 << PRESCALER_BITS) * (RELOAD as u64 + 1) * 1_000_000 / lsi_hz as u64) as u32
}

/// Why the watchdog did not start.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum WatchdogError {
    /// The prescaler or reload update was not confirmed (SR.PVU/RVU stayed set).
    UpdateTimeout,
}

impl core::fmt::Display for WatchdogError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            WatchdogError::UpdateTimeout => write!(f, "IWDG prescaler/reload update not confirmed"),
        }
    }
}

/// `IWDG_PR` while the controller's task designs: divide by 256 (PR = 6).
pub const DESIGN_PRESCALER_BITS: u8 = 6;
/// `IWDG_RLR` while the controller's task designs: 4096 counts, the most.
pub const DESIGN_RELOAD: u16 = 4095;

/// The timeout while a design runs, at an LSI of `lsi_hz`, µs: 32.8 s at
/// 32 kHz, 22.3 s at the LSI's fastest (47 kHz). A design of the fast MPC
/// takes ≈ 25 M instructions (≈ 0.2–0.35 s at CPI 1.2–2.25), longer than
/// [`timeout_us`]; a design that never ends still resets the chip.
pub const fn design_timeout_us(lsi_hz: u32) -> u32 {
    ((4u64 << DESIGN_PRESCALER_BITS) * (DESIGN_RELOAD as u64 + 1) * 1_000_000 / lsi_hz as u64) as u32
}

/// Starts the IWDG with the stated timeout (it cannot be stopped again
/// until reset) and feeds it once.
pub fn start(iwdg: &iwdg::RegisterBlock) -> Result<(), WatchdogError> {
    iwdg.kr().write(|w| w.key().start());
    set_timeout(iwdg, PRESCALER_BITS, RELOAD)
}

/// Sets the running IWDG's prescaler (`pr_bits`, 0–6) and reload (12
/// bits), each update confirmed within [`UPDATE_POLLS`] polls of SR, then
/// feeds it: the stated timeout ([`PRESCALER_BITS`], [`RELOAD`]) or the
/// design's ([`DESIGN_PRESCALER_BITS`], [`DESIGN_RELOAD`]).
pub fn set_timeout(iwdg: &iwdg::RegisterBlock, pr_bits: u8, reload: u16) -> Result<(), WatchdogError> {
    let updated = || {
        let mut polls = 0;
        while iwdg.sr().read().bits() & 0b11 != 0 {
            polls += 1;
            if polls >= UPDATE_POLLS {
                return Err(WatchdogError::UpdateTimeout);
            }
        }
        Ok(())
    };
    // A previous update must be done before the registers take another.
    updated()?;
    iwdg.kr().write(|w| w.key().unlock());
    // SAFETY: PR is 3 bits and RL 12; both masked to fit.
    iwdg.pr().write(|w| unsafe { w.pr().bits(pr_bits & 0b111) });
    iwdg.rlr().write(|w| unsafe { w.rl().bits(reload & 0x0FFF) });
    updated()?;
    feed(iwdg);
    Ok(())
}

/// Reloads the counter (`KR` = 0xAAAA).
pub fn feed(iwdg: &iwdg::RegisterBlock) {
    iwdg.kr().write(|w| w.key().feed());
}

/// Progress of the two tasks the watchdog guards; shared across priorities
/// without a lock.
#[derive(Debug, Default)]
pub struct FeedRule {
    imu_steps: AtomicU32,
    controller_steps: AtomicU32,
}

/// What the feeder saw at its last feed.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Seen {
    imu: u32,
    controller: u32,
}

impl Seen {
    /// Nothing seen yet (for a static).
    pub const fn new() -> Self {
        Self { imu: 0, controller: 0 }
    }
}

impl FeedRule {
    /// No progress yet.
    pub const fn new() -> Self {
        Self {
            imu_steps: AtomicU32::new(0),
            controller_steps: AtomicU32::new(0),
        }
    }

    /// The IMU task finished a step (a sample, or a counted missing one).
    pub fn imu_step(&self) {
        self.imu_steps.fetch_add(1, Ordering::Relaxed);
    }

    /// The controller task finished a step.
    pub fn controller_step(&self) {
        self.controller_steps.fetch_add(1, Ordering::Relaxed);
    }

    /// True when both tasks progressed since `seen`, which is then updated:
    /// the caller feeds the IWDG exactly then.
    pub fn may_feed(&self, seen: &mut Seen) -> bool {
        let now = Seen {
            imu: self.imu_steps.load(Ordering::Relaxed),
            controller: self.controller_steps.load(Ordering::Relaxed),
        };
        if now.imu != seen.imu && now.controller != seen.controller {
            *seen = now;
            true
        } else {
            false
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_timeout_is_the_stated_one_and_the_registers_get_rm0090s_keys() {
        assert_eq!(timeout_us(LSI_HZ), 100_000);
        assert_eq!((timeout_us(47_000), timeout_us(17_000)), (68_085, 188_235));
        // IWDG in host memory: KR, PR, RLR, SR; SR reads 0 (updates done).
        let mut regs = [0u32; 4];
        // SAFETY: 4 words ≥ the register block; volatile cells over host memory.
        let iwdg: &iwdg::RegisterBlock = unsafe { &*regs.as_mut_ptr().cast() };
        assert_eq!(start(iwdg), Ok(()));
        // The last key written is the feed; PR = 3 (/32), RLR = 99.
        assert_eq!(regs[..3], [0xAAAA, 3, 99]);
        // SR stuck with PVU set: refused after the bounded poll.
        let mut regs = [0, 0, 0, 1u32];
        let iwdg: &iwdg::RegisterBlock = unsafe { &*regs.as_mut_ptr().cast() };
        assert_eq!(start(iwdg), Err(WatchdogError::UpdateTimeout));
    }

    #[test]
    fn a_design_widens_the_timeout_and_the_stated_one_comes_back() {
        // RM0090 §19.3.3: 4 · 2^PR · (RL + 1) / f_LSI; /256 is PR = 6.
        assert_eq!(design_timeout_us(LSI_HZ), 32_768_000);
        assert_eq!(design_timeout_us(47_000), 22_310_127);
        let mut regs = [0u32; 4];
        // SAFETY: 4 words ≥ the register block; volatile cells over host memory.
        let iwdg: &iwdg::RegisterBlock = unsafe { &*regs.as_mut_ptr().cast() };
        assert_eq!(set_timeout(iwdg, DESIGN_PRESCALER_BITS, DESIGN_RELOAD), Ok(()));
        assert_eq!(regs[..3], [0xAAAA, 6, 4095]);
        let iwdg: &iwdg::RegisterBlock = unsafe { &*regs.as_mut_ptr().cast() };
        assert_eq!(set_timeout(iwdg, PRESCALER_BITS, RELOAD), Ok(()));
        assert_eq!(regs[..3], [0xAAAA, 3, 99]);
        // An update still under way (RVU set) is waited for, boundedly.
        let mut regs = [0, 0, 0, 2u32];
        let iwdg: &iwdg::RegisterBlock = unsafe { &*regs.as_mut_ptr().cast() };
        assert_eq!(
            set_timeout(iwdg, DESIGN_PRESCALER_BITS, DESIGN_RELOAD),
            Err(WatchdogError::UpdateTimeout)
        );
        assert_eq!(regs[..3], [0, 0, 0], "nothing written before the last update is done");
    }

    /// The IWDG's countdown at its nominal timeout: feeds reload it; at
    /// zero it resets the chip.
    struct Iwdg {
        left_us: u32,
        reset_at_us: Option<u32>,
    }

    /// A 1 kHz IMU task, a 500 Hz controller and a feeder every 10 ms, each
    /// of which can hang from a given time on; returns when the IWDG reset
    /// the chip, if it did within `run_us`.
    fn fly(imu_hangs_us: u32, ctrl_hangs_us: u32, feeder_hangs_us: u32, run_us: u32) -> Option<u32> {
        let rule = FeedRule::new();
        let mut seen = Seen::default();
        let mut w = Iwdg {
            left_us: timeout_us(LSI_HZ),
            reset_at_us: None,
        };
        for t in (0..run_us).step_by(100) {
            if t % 1000 == 0 && t < imu_hangs_us {
                rule.imu_step();
            }
            if t % 2000 == 500 && t < ctrl_hangs_us {
                rule.controller_step();
            }
            if t % 10_000 == 0 && t < feeder_hangs_us && rule.may_feed(&mut seen) {
                w.left_us = timeout_us(LSI_HZ);
            }
            w.left_us = w.left_us.saturating_sub(100);
            if w.left_us == 0 {
                w.reset_at_us = Some(t);
                break;
            }
        }
        w.reset_at_us
    }

    #[test]
    fn the_rule_keeps_a_healthy_loop_alive_and_resets_a_hung_task() {
        let never = u32::MAX;
        // 10 s of healthy flight: never reset.
        assert_eq!(fly(never, never, never, 10_000_000), None);
        // Each hang at 2 s resets within the timeout plus one feeder period.
        for (imu, ctrl, feeder) in [
            (2_000_000, never, never),
            (never, 2_000_000, never),
            (never, never, 2_000_000),
        ] {
            let reset = fly(imu, ctrl, feeder, 10_000_000).expect("the IWDG resets");
            assert!(
                (2_000_000..=2_000_000 + 100_000 + 10_000).contains(&reset),
                "reset at {reset} µs"
            );
        }
    }

    #[test]
    fn progress_of_one_task_alone_does_not_feed() {
        let rule = FeedRule::new();
        let mut seen = Seen::default();
        assert!(!rule.may_feed(&mut seen));
        for _ in 0..100 {
            rule.imu_step();
        }
        assert!(!rule.may_feed(&mut seen));
        rule.controller_step();
        assert!(rule.may_feed(&mut seen));
        // Both must progress again before the next feed.
        rule.controller_step();
        assert!(!rule.may_feed(&mut seen));
    }
}
