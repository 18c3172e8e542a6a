//! The STM32F4's I2C master (RM0090 §27.3.3, master mode), for I2C3 on the
//! Crazyflie 2.1 (PA8 SCL, PC9 SDA, 400 kHz fast mode), in two forms:
//!
//! - [`I2cMaster`]: blocking, for the sensors' start-up (chip ids,
//!   configuration, the BMP388's calibration). It implements embedded-hal
//!   1.0's `I2c`, so the [`crate::bmi088`] and [`crate::bmp388`] drivers run
//!   on it unchanged. **Every wait is bounded** ([`POLLS`] reads of SR1,
//!   ≈ 2 ms on the chip, where a byte takes 22.5 µs): a stuck bus is a
//!   [`I2cError::Timeout`] naming the stage, not a hang. (stm32f4xx-hal's
//!   master spins without a bound on SB, BTF and STOP; that, and its
//!   wanting to own the clock tree that `fc-stm32f405` sets up, is why this
//!   board carries its own.)
//! - [`Burst`]: interrupt-driven, for the 1 kHz sample: "register, repeated
//!   start, read 3–[`BURST_MAX`] bytes" advanced by the I2C3 event and
//!   error interrupts ([`Burst::on_event`], [`Burst::on_error`]), so the
//!   bus time of a BMI088 sample (two 6-byte reads, ≈ 0.45 ms at 400 kHz)
//!   costs a few interrupts instead of a busy priority level. Its owner
//!   bounds it: a burst still running at the next data-ready is abandoned
//!   ([`Burst::abort`]) and that sample counted missing.
//!
//! Both go through [`Regs`], the peripheral's five registers as bits, so
//! that the host tests run them against a model of the peripheral and of
//! the parts on the bus that checks the reference manual's sequences: the
//! last byte of a read is NACKed, no byte more is clocked than read, START
//! and STOP where the manual puts them.

use embedded_hal::i2c::{ErrorKind, NoAcknowledgeSource, Operation, SevenBitAddress};

/// CR1 bits (RM0090 §27.6.1).
pub mod cr1 {
    /// Peripheral enable.
    pub const PE: u32 = 1 << 0;
    /// START generation.
    pub const START: u32 = 1 << 8;
    /// STOP generation.
    pub const STOP: u32 = 1 << 9;
    /// ACK after each received byte.
    pub const ACK: u32 = 1 << 10;
    /// ACK/PEC position (the 2-byte reception).
    pub const POS: u32 = 1 << 11;
    /// Software reset.
    pub const SWRST: u32 = 1 << 15;
}

/// CR2 bits (§27.6.2).
pub mod cr2 {
    /// Error interrupt enable.
    pub const ITERREN: u32 = 1 << 8;
    /// Event interrupt enable.
    pub const ITEVTEN: u32 = 1 << 9;
    /// Buffer interrupt enable (TxE, RxNE).
    pub const ITBUFEN: u32 = 1 << 10;
}

/// SR1 bits (§27.6.6).
pub mod sr1 {
    /// START generated.
    pub const SB: u32 = 1 << 0;
    /// Address sent (and ACKed).
    pub const ADDR: u32 = 1 << 1;
    /// Byte transfer finished.
    pub const BTF: u32 = 1 << 2;
    /// Data register not empty (receiving).
    pub const RXNE: u32 = 1 << 6;
    /// Data register empty (transmitting).
    pub const TXE: u32 = 1 << 7;
    /// Bus error (misplaced START or STOP).
    pub const BERR: u32 = 1 << 8;
    /// Arbitration lost.
    pub const ARLO: u32 = 1 << 9;
    /// Acknowledge failure (NACK).
    pub const AF: u32 = 1 << 10;
    /// Overrun.
    pub const OVR: u32 = 1 << 11;
    /// The error flags, cleared by writing 0.
    pub const ERRORS: u32 = BERR | ARLO | AF | OVR;
}

/// SR2 bits (§27.6.7).
pub mod sr2 {
    /// Bus busy.
    pub const BUSY: u32 = 1 << 1;
}

/// Polls of SR1 a wait makes before giving up: at 168 MHz a poll of an
/// APB1 register is ≥ 12 cycles, so 30 000 polls are ≥ 2.1 ms, about 95
/// byte times at 400 kHz.
pub const POLLS: u32 = 30_000;
/// Polls a [`Burst`] makes for the last transfer's STOP to be sent (CR1.STOP
/// and SR2.BUSY clear; RM0090 §27.6.1: CR1 must not be written while STOP
/// is set) before it starts: about one SCL period and t_BUF after the last
/// byte's interrupt, or a byte time (22.5 µs at 400 kHz) after an abort
/// mid-read. At ≥ 12 cycles a poll, 1 000 polls are ≥ 71 µs; a bus still
/// busy after them refuses the burst.
pub const BUS_FREE_POLLS: u32 = 1_000;
/// Longest [`Burst`] read, bytes.
pub const BURST_MAX: usize = 8;
/// PCLK1 of the clock tree (`fc-stm32f405`'s 168 MHz), Hz.
pub const PCLK1_HZ: u32 = 42_000_000;
/// The bus rate, Hz (fast mode).
pub const BUS_HZ: u32 = 400_000;

/// CR2.FREQ, CCR and TRISE for fast mode at `bus_hz` from `pclk1_hz`,
/// duty 2:1 (RM0090 §27.6.8–9: T_high + T_low = 3 × CCR × T_pclk1; TRISE
/// = 300 ns / T_pclk1 + 1). At 42 MHz and 400 kHz: FREQ 42, CCR 35 with
/// F/S set (0x8023), TRISE 13: SCL at exactly 400 kHz.
pub const fn timing(pclk1_hz: u32, bus_hz: u32) -> (u32, u32, u32) {
    let mhz = pclk1_hz / 1_000_000;
    let ccr = pclk1_hz.div_ceil(3 * bus_hz);
    (mhz, (1 << 15) | ccr, mhz * 300 / 1000 + 1)
}

/// The peripheral's registers, as bits.
pub trait Regs {
    /// Reads SR1.
    fn sr1(&self) -> u32;
    /// Reads SR2 (after an SR1 read: clears ADDR).
    fn sr2(&self) -> u32;
    /// Reads CR1.
    fn cr1(&self) -> u32;
    /// Writes CR1.
    fn set_cr1(&self, v: u32);
    /// Reads CR2.
    fn cr2(&self) -> u32;
    /// Writes CR2.
    fn set_cr2(&self, v: u32);
    /// Writes 0 to SR1's error flags in `mask` (the others are kept).
    fn clear_errors(&self, mask: u32);
    /// Reads DR.
    fn dr(&self) -> u8;
    /// Writes DR.
    fn set_dr(&self, b: u8);
    /// Writes CCR and TRISE.
    fn set_timing(&self, ccr: u32, trise: u32);
}

impl<T: Regs + ?Sized> Regs for &T {
    fn sr1(&self) -> u32 {
        (**self).sr1()
    }
    fn sr2(&self) -> u32 {
        (**self).sr2()
    }
    fn cr1(&self) -> u32 {
        (**self).cr1()
    }
    fn set_cr1(&self, v: u32) {
        (**self).set_cr1(v)
    }
    fn cr2(&self) -> u32 {
        (**self).cr2()
    }
    fn set_cr2(&self, v: u32) {
        (**self).set_cr2(v)
    }
    fn clear_errors(&self, mask: u32) {
        (**self).clear_errors(mask)
    }
    fn dr(&self) -> u8 {
        (**self).dr()
    }
    fn set_dr(&self, b: u8) {
        (**self).set_dr(b)
    }
    fn set_timing(&self, ccr: u32, trise: u32) {
        (**self).set_timing(ccr, trise)
    }
}

// The registers are 16 bits wide (the PAC's `u16`); the bits above are 0.
impl Regs for stm32f4::stm32f405::i2c1::RegisterBlock {
    fn sr1(&self) -> u32 {
        u32::from(self.sr1().read().bits())
    }
    fn sr2(&self) -> u32 {
        u32::from(self.sr2().read().bits())
    }
    fn cr1(&self) -> u32 {
        u32::from(self.cr1().read().bits())
    }
    fn set_cr1(&self, v: u32) {
        // SAFETY: every bit of CR1 written is a documented control bit.
        self.cr1().write(|w| unsafe { w.bits(v as u16) });
    }
    fn cr2(&self) -> u32 {
        u32::from(self.cr2().read().bits())
    }
    fn set_cr2(&self, v: u32) {
        // SAFETY: FREQ and the interrupt enables, as documented.
        self.cr2().write(|w| unsafe { w.bits(v as u16) });
    }
    fn clear_errors(&self, mask: u32) {
        // SAFETY: rc_w0 flags: writing 1 keeps a flag, 0 clears it.
        self.sr1().write(|w| unsafe { w.bits(!((mask & sr1::ERRORS) as u16)) });
    }
    fn dr(&self) -> u8 {
        self.dr().read().bits() as u8
    }
    fn set_dr(&self, b: u8) {
        // SAFETY: an 8-bit data register.
        self.dr().write(|w| unsafe { w.bits(u16::from(b)) });
    }
    fn set_timing(&self, ccr: u32, trise: u32) {
        // SAFETY: values from `timing`, within the fields.
        self.ccr().write(|w| unsafe { w.bits(ccr as u16) });
        self.trise().write(|w| unsafe { w.bits(trise as u16) });
    }
}

/// Why a transfer failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum I2cError {
    /// No ACK: to the address or to a data byte.
    Nack(NoAcknowledgeSource),
    /// A misplaced START or STOP on the bus.
    Bus,
    /// Another master won the bus.
    Arbitration,
    /// A received byte was lost.
    Overrun,
    /// A bounded wait ran out; the stage it waited in.
    Timeout(&'static str),
    /// A transfer this master does not do (a read of 2 bytes; a read that
    /// is not the transaction's last operation; a burst outside 3–8 bytes).
    Unsupported,
}

impl embedded_hal::i2c::Error for I2cError {
    fn kind(&self) -> ErrorKind {
        match *self {
            I2cError::Nack(s) => ErrorKind::NoAcknowledge(s),
            I2cError::Bus => ErrorKind::Bus,
            I2cError::Arbitration => ErrorKind::ArbitrationLoss,
            I2cError::Overrun => ErrorKind::Overrun,
            I2cError::Timeout(_) | I2cError::Unsupported => ErrorKind::Other,
        }
    }
}

impl core::fmt::Display for I2cError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            I2cError::Nack(NoAcknowledgeSource::Address) => write!(f, "no ACK to the address"),
            I2cError::Nack(_) => write!(f, "no ACK to a data byte"),
            I2cError::Bus => write!(f, "bus error"),
            I2cError::Arbitration => write!(f, "arbitration lost"),
            I2cError::Overrun => write!(f, "overrun"),
            I2cError::Timeout(stage) => write!(f, "timed out waiting for {stage}"),
            I2cError::Unsupported => write!(f, "transfer not supported"),
        }
    }
}

/// The error SR1's flags `s` report, if any (cleared, a STOP sent).
fn fault<R: Regs>(r: &R, s: u32, address_phase: bool) -> Option<I2cError> {
    let e = if s & sr1::AF != 0 {
        I2cError::Nack(if address_phase {
            NoAcknowledgeSource::Address
        } else {
            NoAcknowledgeSource::Data
        })
    } else if s & sr1::BERR != 0 {
        I2cError::Bus
    } else if s & sr1::ARLO != 0 {
        I2cError::Arbitration
    } else if s & sr1::OVR != 0 {
        I2cError::Overrun
    } else {
        return None;
    };
    r.clear_errors(sr1::ERRORS);
    // Arbitration lost leaves the bus to the other master: no STOP.
    if e != I2cError::Arbitration {
        r.set_cr1(r.cr1() | cr1::STOP);
    }
    Some(e)
}

/// The blocking master on `R` (see the module's documentation).
pub struct I2cMaster<R> {
    r: R,
}

impl<R: Regs> I2cMaster<R> {
    /// Resets the peripheral and sets it up for [`BUS_HZ`] from
    /// [`PCLK1_HZ`] (its clock and pins already enabled).
    pub fn new(r: R) -> Self {
        r.set_cr1(cr1::SWRST);
        r.set_cr1(0);
        let (freq, ccr, trise) = timing(PCLK1_HZ, BUS_HZ);
        r.set_cr2(freq);
        r.set_timing(ccr, trise);
        r.set_cr1(cr1::PE);
        Self { r }
    }

    /// The registers (for a [`Burst`] once start-up is done).
    pub fn regs(&self) -> &R {
        &self.r
    }

    fn set(&self, bits: u32) {
        self.r.set_cr1(self.r.cr1() | bits);
    }

    fn clear(&self, bits: u32) {
        self.r.set_cr1(self.r.cr1() & !bits);
    }

    /// Waits for `flag` in SR1 (an error flag ends the wait).
    fn wait(&self, flag: u32, stage: &'static str, address_phase: bool) -> Result<(), I2cError> {
        for _ in 0..POLLS {
            let s = self.r.sr1();
            if let Some(e) = fault(&self.r, s, address_phase) {
                return Err(e);
            }
            if s & flag != 0 {
                return Ok(());
            }
        }
        self.set(cr1::STOP);
        Err(I2cError::Timeout(stage))
    }

    /// Waits for the STOP just asked for to have been sent.
    fn wait_stopped(&self) -> Result<(), I2cError> {
        for _ in 0..POLLS {
            if self.r.cr1() & cr1::STOP == 0 {
                return Ok(());
            }
        }
        Err(I2cError::Timeout("the STOP"))
    }

    /// START (or a repeated START) and the address: `read` sets its low bit.
    fn start(&self, addr: u8, read: bool) -> Result<(), I2cError> {
        self.set(cr1::START);
        self.wait(sr1::SB, "the START", false)?;
        self.r.set_dr((addr << 1) | u8::from(read));
        self.wait(sr1::ADDR, "the address's ACK", true)
    }

    /// Clears ADDR (SR1 then SR2 read).
    fn clear_addr(&self) {
        let _ = self.r.sr1();
        let _ = self.r.sr2();
    }

    fn write_bytes(&self, bytes: &[u8]) -> Result<(), I2cError> {
        for &b in bytes {
            self.wait(sr1::TXE, "the data register to empty", false)?;
            self.r.set_dr(b);
        }
        self.wait(sr1::BTF, "the last byte to go out", false)
    }

    /// Reads `buf` (any length but 2) from the addressed part: RM0090's
    /// closing sequences for 1 byte and for more than 2, then STOP.
    fn read_bytes(&self, addr: u8, buf: &mut [u8]) -> Result<(), I2cError> {
        let n = buf.len();
        if n == 0 {
            return Ok(());
        }
        self.set(cr1::ACK);
        self.start(addr, true)?;
        if n == 1 {
            // NACK the only byte, STOP after it.
            self.clear(cr1::ACK);
            self.clear_addr();
            self.set(cr1::STOP);
            self.wait(sr1::RXNE, "the byte", false)?;
            buf[0] = self.r.dr();
            return self.wait_stopped();
        }
        self.clear_addr();
        for b in buf.iter_mut().take(n - 3) {
            self.wait(sr1::RXNE, "a byte", false)?;
            *b = self.r.dr();
        }
        // Byte N−2 in DR, N−1 in the shift register, SCL held low.
        self.wait(sr1::BTF, "the last three bytes", false)?;
        self.clear(cr1::ACK);
        buf[n - 3] = self.r.dr();
        self.set(cr1::STOP);
        buf[n - 2] = self.r.dr();
        self.wait(sr1::RXNE, "the last byte", false)?;
        buf[n - 1] = self.r.dr();
        self.wait_stopped()
    }

    fn busy_check(&self) -> Result<(), I2cError> {
        for _ in 0..POLLS {
            if self.r.sr2() & sr2::BUSY == 0 {
                return Ok(());
            }
        }
        Err(I2cError::Timeout("the bus to be free"))
    }
}

impl<R: Regs> embedded_hal::i2c::ErrorType for I2cMaster<R> {
    type Error = I2cError;
}

impl<R: Regs> embedded_hal::i2c::I2c<SevenBitAddress> for I2cMaster<R> {
    /// Writes (any number, sent as one), then at most one read, last.
    fn transaction(&mut self, addr: SevenBitAddress, ops: &mut [Operation<'_>]) -> Result<(), I2cError> {
        let writes = ops.iter().take_while(|o| matches!(o, Operation::Write(_))).count();
        let two = matches!(ops.last(), Some(Operation::Read(b)) if b.len() == 2);
        if ops.len() > writes + 1 || two {
            // Refused before the bus is touched.
            return Err(I2cError::Unsupported);
        }
        self.busy_check()?;
        let (w, rest) = ops.split_at_mut(writes);
        if writes > 0 {
            self.start(addr, false)?;
            self.clear_addr();
            for op in w.iter() {
                if let Operation::Write(bytes) = op {
                    self.write_bytes(bytes)?;
                }
            }
            if rest.is_empty() {
                self.set(cr1::STOP);
                return self.wait_stopped();
            }
        }
        match rest.first_mut() {
            Some(Operation::Read(buf)) => self.read_bytes(addr, buf),
            _ => Ok(()),
        }
    }
}

/// Where a [`Burst`] is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Phase {
    Idle,
    Start,
    AddrWrite,
    Register,
    Restart,
    StartRead,
    AddrRead,
    Receive,
}

/// What a [`Burst`] event came to.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Progress {
    /// Under way.
    Pending,
    /// All bytes read ([`Burst::data`]).
    Done,
    /// Ended by an error (a STOP was sent).
    Failed(I2cError),
}

/// An interrupt-driven "register, repeated START, read" (see the module's
/// documentation).
#[derive(Debug, Clone, Copy)]
pub struct Burst {
    phase: Phase,
    addr: u8,
    reg: u8,
    buf: [u8; BURST_MAX],
    len: usize,
    got: usize,
}

impl Default for Burst {
    fn default() -> Self {
        Self::new()
    }
}

const IRQS: u32 = cr2::ITEVTEN | cr2::ITBUFEN | cr2::ITERREN;

impl Burst {
    /// Idle.
    pub const fn new() -> Self {
        Self {
            phase: Phase::Idle,
            addr: 0,
            reg: 0,
            buf: [0; BURST_MAX],
            len: 0,
            got: 0,
        }
    }

    /// A burst under way.
    pub fn busy(&self) -> bool {
        self.phase != Phase::Idle
    }

    /// Starts reading `len` (3–[`BURST_MAX`]) bytes from register `reg` of
    /// `addr`; the interrupts do the rest.
    pub fn start<R: Regs>(&mut self, r: &R, addr: u8, reg: u8, len: usize) -> Result<(), I2cError> {
        if !(3..=BURST_MAX).contains(&len) {
            return Err(I2cError::Unsupported);
        }
        if self.busy() {
            return Err(I2cError::Bus);
        }
        // The transfer before (this burst's last one, or another's) may end
        // with its STOP still going out.
        let mut polls = 0;
        while r.cr1() & cr1::STOP != 0 || r.sr2() & sr2::BUSY != 0 {
            polls += 1;
            if polls >= BUS_FREE_POLLS {
                return Err(I2cError::Bus);
            }
        }
        *self = Self {
            phase: Phase::Start,
            addr,
            reg,
            len,
            ..Self::new()
        };
        r.set_cr2(r.cr2() | IRQS);
        r.set_cr1(r.cr1() | cr1::ACK | cr1::START);
        Ok(())
    }

    /// The bytes read by the last burst that finished.
    pub fn data(&self) -> &[u8] {
        &self.buf[..self.len]
    }

    fn end<R: Regs>(&mut self, r: &R, p: Progress) -> Progress {
        r.set_cr2(r.cr2() & !IRQS);
        self.phase = Phase::Idle;
        p
    }

    /// Abandons a burst (its owner's bound: the next data-ready came first).
    pub fn abort<R: Regs>(&mut self, r: &R) {
        if self.busy() {
            r.set_cr1((r.cr1() & !cr1::ACK) | cr1::STOP);
            self.end(r, Progress::Pending);
        }
    }

    /// The I2C event interrupt.
    pub fn on_event<R: Regs>(&mut self, r: &R) -> Progress {
        let s = r.sr1();
        let left = self.len.saturating_sub(self.got);
        match self.phase {
            Phase::Idle => {
                // Not ours: nothing under way; quiet the source.
                r.set_cr2(r.cr2() & !IRQS);
            }
            Phase::Start if s & sr1::SB != 0 => {
                r.set_dr(self.addr << 1);
                self.phase = Phase::AddrWrite;
            }
            Phase::AddrWrite if s & sr1::ADDR != 0 => {
                let _ = r.sr2();
                self.phase = Phase::Register;
            }
            Phase::Register if s & sr1::TXE != 0 => {
                r.set_dr(self.reg);
                // TxE stays set while the byte shifts out: wait for BTF.
                r.set_cr2(r.cr2() & !cr2::ITBUFEN);
                self.phase = Phase::Restart;
            }
            Phase::Restart if s & sr1::BTF != 0 => {
                r.set_cr1(r.cr1() | cr1::START);
                r.set_cr2(r.cr2() | cr2::ITBUFEN);
                self.phase = Phase::StartRead;
            }
            Phase::StartRead if s & sr1::SB != 0 => {
                r.set_dr((self.addr << 1) | 1);
                self.phase = Phase::AddrRead;
            }
            Phase::AddrRead if s & sr1::ADDR != 0 => {
                r.set_cr1(r.cr1() | cr1::ACK);
                let _ = r.sr2();
                self.phase = Phase::Receive;
                if left == 3 {
                    // Wait for BTF: bytes N−2 and N−1 both in.
                    r.set_cr2(r.cr2() & !cr2::ITBUFEN);
                }
            }
            Phase::Receive if left == 3 && s & sr1::BTF != 0 => {
                r.set_cr1(r.cr1() & !cr1::ACK);
                self.buf[self.got] = r.dr();
                r.set_cr1(r.cr1() | cr1::STOP);
                self.buf[self.got + 1] = r.dr();
                self.got += 2;
                r.set_cr2(r.cr2() | cr2::ITBUFEN);
            }
            Phase::Receive if left > 3 && s & sr1::RXNE != 0 => {
                self.buf[self.got] = r.dr();
                self.got += 1;
                if left - 1 == 3 {
                    r.set_cr2(r.cr2() & !cr2::ITBUFEN);
                }
            }
            Phase::Receive if left == 1 && s & sr1::RXNE != 0 => {
                self.buf[self.got] = r.dr();
                self.got += 1;
                return self.end(r, Progress::Done);
            }
            _ => {}
        }
        Progress::Pending
    }

    /// The I2C error interrupt.
    pub fn on_error<R: Regs>(&mut self, r: &R) -> Progress {
        let address_phase = matches!(self.phase, Phase::AddrWrite | Phase::AddrRead);
        match fault(r, r.sr1(), address_phase) {
            Some(e) => self.end(r, Progress::Failed(e)),
            None => Progress::Pending,
        }
    }
}

#[cfg(test)]
mod tests;
