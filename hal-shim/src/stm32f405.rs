//! STM32F405 implementations: USART1 as the byte link, SysTick as the cycle
//! clock (DWT CYCCNT on silicon is the same interface; QEMU does not model it,
//! and under `-icount shift=0` SysTick advances with executed instructions).

use crate::{ByteLink, CycleClock};
use core::cell::RefCell;
use core::ptr::{read_volatile, write_volatile};
use critical_section::Mutex;

/// System clock the drivers and the firmware assume, Hz: the F405's 168 MHz
/// maximum. QEMU's netduinoplus2 runs at it; on silicon the PLL must be set
/// to it before these drivers start (nothing in this crate does that yet).
pub const SYSCLK_HZ: u32 = 168_000_000;
/// APB2 peripheral clock (USART1) at [`SYSCLK_HZ`] / 2, Hz.
pub const PCLK2_HZ: u32 = 84_000_000;
/// Clock of the APB1 timers (TIM2, TIM3): twice PCLK1 = [`SYSCLK_HZ`] / 4, Hz.
pub const APB1_TIMER_CLK_HZ: u32 = 84_000_000;

/// Received bytes, filled by [`usart1_isr`], drained by [`Usart1::read`].
static RX: Mutex<RefCell<heapless::Deque<u8, 1024>>> = Mutex::new(RefCell::new(heapless::Deque::new()));
/// Bytes lost because the queue was full.
static RX_OVERRUNS: Mutex<core::cell::Cell<u32>> = Mutex::new(core::cell::Cell::new(0));
const CR1_RXNEIE: u32 = 1 << 5;
/// USART1's interrupt number on the STM32F405.
pub const USART1_IRQ: u16 = 37;
const NVIC_ISER: usize = 0xE000_E100;

/// USART1 receive interrupt: moves every received byte into the queue (the
/// interrupt itself wakes a main loop sleeping in WFI). Call from the
/// interrupt handler of [`USART1_IRQ`].
pub fn usart1_isr() {
    // SAFETY: reads of USART1's status and data registers; reading DR pops the byte.
    while unsafe { read_volatile((USART1 + SR) as *const u32) } & SR_RXNE != 0 {
        let b = unsafe { read_volatile((USART1 + DR) as *const u32) } as u8;
        critical_section::with(|cs| {
            if RX.borrow(cs).borrow_mut().push_back(b).is_err() {
                let c = RX_OVERRUNS.borrow(cs);
                c.set(c.get().wrapping_add(1));
            }
        });
    }
}

/// True if received bytes are waiting in the queue.
pub fn rx_pending() -> bool {
    critical_section::with(|cs| !RX.borrow(cs).borrow().is_empty())
}

const USART1: usize = 0x4001_1000;
const SR: usize = 0x00;
const DR: usize = 0x04;
const BRR: usize = 0x08;
const CR1: usize = 0x0C;
const SR_RXNE: u32 = 1 << 5;
const SR_TXE: u32 = 1 << 7;
const CR1_UE: u32 = 1 << 13;
const CR1_TE: u32 = 1 << 3;
const CR1_RE: u32 = 1 << 2;
const RCC_APB2ENR: usize = 0x4002_3844;
const RCC_APB2ENR_USART1EN: u32 = 1 << 4;

/// USART1 (PA9/PA10 on real boards; `-serial` 0 under QEMU's netduinoplus2).
/// Reception is interrupt-driven into a 1 KiB queue ([`usart1_isr`]); reads
/// never wait; writes wait for TXE at most a bounded number of polls per byte.
pub struct Usart1 {
    _private: (),
}

/// A write gave up waiting for the transmitter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TxTimeout;

impl Usart1 {
    /// Enables the clock and the peripheral at `baud` for a `pclk_hz` bus clock.
    ///
    /// Must be called once, before any other use of USART1.
    pub fn init(pclk_hz: u32, baud: u32) -> Self {
        // SAFETY: fixed, documented STM32F405 register addresses; this driver
        // is the only user of USART1 and of the RCC bit it sets.
        unsafe {
            let en = read_volatile(RCC_APB2ENR as *const u32);
            write_volatile(RCC_APB2ENR as *mut u32, en | RCC_APB2ENR_USART1EN);
            write_volatile((USART1 + BRR) as *mut u32, pclk_hz / baud.max(1));
            write_volatile((USART1 + CR1) as *mut u32, CR1_UE | CR1_TE | CR1_RE | CR1_RXNEIE);
            let irq = usize::from(USART1_IRQ);
            write_volatile((NVIC_ISER + 4 * (irq / 32)) as *mut u32, 1 << (irq % 32));
        }
        Self { _private: () }
    }

    fn sr(&self) -> u32 {
        // SAFETY: read of the USART1 status register.
        unsafe { read_volatile((USART1 + SR) as *const u32) }
    }
}

/// Polls per byte before a write gives up.
const TX_SPIN: u32 = 1_000_000;

impl ByteLink for Usart1 {
    type Error = TxTimeout;
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        critical_section::with(|cs| {
            let mut q = RX.borrow(cs).borrow_mut();
            let mut n = 0;
            while n < buf.len() {
                match q.pop_front() {
                    Some(b) => {
                        buf[n] = b;
                        n += 1;
                    }
                    None => break,
                }
            }
            Ok(n)
        })
    }
    fn write_all(&mut self, bytes: &[u8]) -> Result<(), Self::Error> {
        for &b in bytes {
            let mut spins = 0;
            while self.sr() & SR_TXE == 0 {
                spins += 1;
                if spins > TX_SPIN {
                    return Err(TxTimeout);
                }
            }
            // SAFETY: writing DR sends the byte.
            unsafe { write_volatile((USART1 + DR) as *mut u32, u32::from(b)) };
        }
        Ok(())
    }
}

/// SysTick as the cycle clock: the 24-bit down-counter reloads every
/// millisecond and its interrupt ([`systick_isr`]) counts the reloads, so
/// [`SysTickClock::ticks`] is a 64-bit tick count and the main loop wakes at
/// least once a millisecond (the failsafe timer needs no other timer).
pub struct SysTickClock {
    hz: u32,
}

/// SysTick reloads counted by [`systick_isr`].
static WRAPS: Mutex<core::cell::Cell<u64>> = Mutex::new(core::cell::Cell::new(0));
/// SysTick's reload period in ticks, set by [`SysTickClock::start`].
static PERIOD: Mutex<core::cell::Cell<u32>> = Mutex::new(core::cell::Cell::new(1));

/// SysTick exception body: counts one reload. Call from the `SysTick`
/// exception handler.
pub fn systick_isr() {
    critical_section::with(|cs| {
        let w = WRAPS.borrow(cs);
        w.set(w.get().wrapping_add(1));
    });
}

const SYST_CSR: usize = 0xE000_E010;
const SYST_RVR: usize = 0xE000_E014;
const SYST_CVR: usize = 0xE000_E018;
const SCB_ICSR: usize = 0xE000_ED04;
const ICSR_PENDSTSET: u32 = 1 << 26;

impl SysTickClock {
    /// Starts SysTick on the processor clock (`hz`, ≥ 1 kHz), reloading every
    /// millisecond with its interrupt enabled.
    pub fn start(hz: u32) -> Self {
        let period = (hz / 1000).clamp(2, 0x0100_0000);
        critical_section::with(|cs| PERIOD.borrow(cs).set(period));
        // SAFETY: the architectural SysTick registers; this is their only user.
        unsafe {
            write_volatile(SYST_RVR as *mut u32, period - 1);
            write_volatile(SYST_CVR as *mut u32, 0);
            write_volatile(SYST_CSR as *mut u32, 0b111); // enable, processor clock, interrupt
        }
        Self { hz }
    }

    /// Processor-clock ticks since [`SysTickClock::start`], 64 bits wide.
    pub fn ticks(&self) -> u64 {
        ticks_now()
    }
}

/// Processor-clock ticks since SysTick was started ([`SysTickClock::start`];
/// 0 before): the reload count joined with the counter. Usable anywhere,
/// e.g. for log timestamps.
pub fn ticks_now() -> u64 {
    critical_section::with(|cs| {
        let wraps = WRAPS.borrow(cs).get();
        let period = PERIOD.borrow(cs).get();
        // SAFETY: read of the SysTick current value.
        let cvr = unsafe { read_volatile(SYST_CVR as *const u32) } & 0x00FF_FFFF;
        let into = (period - 1).saturating_sub(cvr);
        // A reload while interrupts are masked is pending, not yet counted:
        // ICSR.PENDSTSET says so. If it came after the counter was read, the
        // reading is near the period's end and needs no correction.
        // SAFETY: read of the System Control Block's ICSR.
        let pending = unsafe { read_volatile(SCB_ICSR as *const u32) } & ICSR_PENDSTSET != 0;
        let wraps = if pending && into < period / 2 { wraps + 1 } else { wraps };
        wraps * u64::from(period) + u64::from(into)
    })
}

impl CycleClock for SysTickClock {
    /// The low 32 bits of [`SysTickClock::ticks`] (wraps after 25 s at 168 MHz).
    fn now(&self) -> u32 {
        self.ticks() as u32
    }
    fn hz(&self) -> u32 {
        self.hz
    }
}

/// The Cortex-M4 cycle counter (DWT CYCCNT) as the cycle clock: what the
/// firmware uses on silicon. QEMU does not model it (it reads 0 there; use
/// [`SysTickClock`] under QEMU).
pub struct DwtClock {
    hz: u32,
}

const DEMCR: usize = 0xE000_EDFC;
const DEMCR_TRCENA: u32 = 1 << 24;
const DWT_CTRL: usize = 0xE000_1000;
const DWT_CYCCNT: usize = 0xE000_1004;

impl DwtClock {
    /// Enables the trace block and starts CYCCNT; `hz` is the core clock.
    pub fn start(hz: u32) -> Self {
        // SAFETY: architectural debug registers; this is their only user.
        unsafe {
            write_volatile(DEMCR as *mut u32, read_volatile(DEMCR as *const u32) | DEMCR_TRCENA);
            write_volatile(DWT_CYCCNT as *mut u32, 0);
            write_volatile(DWT_CTRL as *mut u32, read_volatile(DWT_CTRL as *const u32) | 1);
        }
        Self { hz }
    }
}

impl CycleClock for DwtClock {
    fn now(&self) -> u32 {
        // SAFETY: read of the cycle counter.
        unsafe { read_volatile(DWT_CYCCNT as *const u32) }
    }
    fn hz(&self) -> u32 {
        self.hz
    }
}

const RCC_APB1ENR: usize = 0x4002_3840;
const TIM2: usize = 0x4000_0000;
const TIM3: usize = 0x4000_0400;
const TIM_CR1: usize = 0x00;
const TIM_DIER: usize = 0x0C;
const TIM_SR: usize = 0x10;
const TIM_EGR: usize = 0x14;
const TIM_CCMR1: usize = 0x18;
const TIM_CCMR2: usize = 0x1C;
const TIM_CCER: usize = 0x20;
const TIM_PSC: usize = 0x28;
const TIM_ARR: usize = 0x2C;
const TIM_CCR1: usize = 0x34;

/// TIM2 as the control-loop period: an update flag every `1/rate` s.
pub struct LoopTimer {
    _private: (),
}

impl LoopTimer {
    /// Starts TIM2 (clocked at `tim_clk_hz`, 84 MHz on an F405 at 168 MHz) to
    /// overflow at `rate_hz` (1 µs resolution).
    pub fn start(tim_clk_hz: u32, rate_hz: u32) -> Self {
        let psc = (tim_clk_hz / 1_000_000).max(1) - 1; // 1 MHz tick
        let arr = (1_000_000 / rate_hz.max(1)).max(2) - 1;
        // SAFETY: RCC enable bit and TIM2 registers; this driver owns TIM2.
        unsafe {
            let en = read_volatile(RCC_APB1ENR as *const u32);
            write_volatile(RCC_APB1ENR as *mut u32, en | 1); // TIM2EN
            write_volatile((TIM2 + TIM_PSC) as *mut u32, psc);
            write_volatile((TIM2 + TIM_ARR) as *mut u32, arr);
            write_volatile((TIM2 + TIM_EGR) as *mut u32, 1); // load PSC/ARR
            write_volatile((TIM2 + TIM_SR) as *mut u32, 0);
            // Update interrupt enabled in the timer (not in the NVIC: nothing
            // is taken); QEMU's timer model sets UIF only with UIE on.
            write_volatile((TIM2 + TIM_DIER) as *mut u32, 1);
            write_volatile((TIM2 + TIM_CR1) as *mut u32, 1); // CEN
        }
        Self { _private: () }
    }

    /// True once per period: the update flag, cleared when seen. Never blocks.
    pub fn expired(&mut self) -> bool {
        // SAFETY: TIM2 status register; writing 0 to UIF clears it.
        unsafe {
            if read_volatile((TIM2 + TIM_SR) as *const u32) & 1 != 0 {
                write_volatile((TIM2 + TIM_SR) as *mut u32, 0);
                true
            } else {
                false
            }
        }
    }
}

/// Four ESC outputs on TIM3 channels 1–4 (PA6, PA7, PB0, PB1 on most F4
/// boards; pin muxing is the board's job): PWM at `pwm_hz`, duty from the
/// rotor commands that `to_duty` derives from `U` (the firmware passes its
/// mixer inverse: `U` → rotor speeds → duty in [0, 1]).
pub struct PwmActuators {
    arr: u32,
    to_duty: fn(&[f32; 4]) -> [f32; 4],
}

impl PwmActuators {
    /// Starts TIM3 PWM mode 1 on all four channels, outputs at 0.
    pub fn start(tim_clk_hz: u32, pwm_hz: u32, to_duty: fn(&[f32; 4]) -> [f32; 4]) -> Self {
        // TIM3 is 16-bit: prescale so the period fits.
        let counts = tim_clk_hz / pwm_hz.max(1);
        let psc = counts.div_ceil(0x1_0000).max(1) - 1;
        let arr = (counts / (psc + 1)).clamp(2, 0x1_0000) - 1;
        // SAFETY: RCC enable bit and TIM3 registers; this driver owns TIM3.
        unsafe {
            let en = read_volatile(RCC_APB1ENR as *const u32);
            write_volatile(RCC_APB1ENR as *mut u32, en | 2); // TIM3EN
            write_volatile((TIM3 + TIM_PSC) as *mut u32, psc);
            write_volatile((TIM3 + TIM_ARR) as *mut u32, arr);
            // PWM mode 1 with preload on channels 1-4.
            write_volatile((TIM3 + TIM_CCMR1) as *mut u32, 0x6868);
            write_volatile((TIM3 + TIM_CCMR2) as *mut u32, 0x6868);
            write_volatile((TIM3 + TIM_CCER) as *mut u32, 0x1111);
            for ch in 0..4 {
                write_volatile((TIM3 + TIM_CCR1 + 4 * ch) as *mut u32, 0);
            }
            write_volatile((TIM3 + TIM_EGR) as *mut u32, 1);
            write_volatile((TIM3 + TIM_CR1) as *mut u32, 1 | (1 << 7)); // CEN, ARPE
        }
        Self { arr, to_duty }
    }

    fn set(&mut self, duty: [f32; 4]) {
        for (ch, d) in duty.iter().enumerate() {
            // NaN or out of range → the nearest safe value (NaN → 0: motor off).
            let d = if d.is_nan() { 0.0 } else { d.clamp(0.0, 1.0) };
            let ccr = (d * self.arr as f32) as u32;
            // SAFETY: TIM3 compare registers.
            unsafe { write_volatile((TIM3 + TIM_CCR1 + 4 * ch) as *mut u32, ccr) };
        }
    }
}

impl crate::ActuatorOutput for PwmActuators {
    fn apply(&mut self, u: [f32; 4]) {
        let duty = (self.to_duty)(&u);
        self.set(duty);
    }
    fn disarm(&mut self) {
        self.set([0.0; 4]);
    }
}
