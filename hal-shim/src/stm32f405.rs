//! STM32F405 implementations: USART1 and USART6 as byte links, SysTick as the cycle
//! clock (DWT CYCCNT on silicon is the same interface; QEMU does not model it,
//! and under `-icount shift=0` SysTick advances with executed instructions),
//! TIM2 as the loop timer, TIM3 as PWM outputs.
//!
//! Every register is reached through the `stm32f4` peripheral access crate
//! (device peripherals) or `cortex-m` (SysTick, SCB, NVIC, DWT, DCB): no
//! address is spelled here. The drivers own their peripheral by convention
//! (each is started once, by the image's `main`), which is why they steal
//! the PAC's handles instead of threading `Peripherals` through.

use crate::{ByteLink, CycleClock};
use core::cell::RefCell;
use cortex_m::peripheral::{DWT, NVIC, SCB, SYST};
use critical_section::Mutex;
use stm32f4::stm32f405 as pac;

/// The USARTs this driver serves: USART1 (the host link: PA9/PA10; QEMU's
/// first `-serial`) and USART6 (the Crazyflie's syslink to its nRF51:
/// PC6/PC7; QEMU's sixth `-serial`). Both sit on APB2.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Port {
    /// USART1.
    Usart1,
    /// USART6.
    Usart6,
}

/// USART1's received bytes, filled by [`usart_isr`], drained by [`Usart::read`].
static RX1: Mutex<RefCell<heapless::Deque<u8, 1024>>> = Mutex::new(RefCell::new(heapless::Deque::new()));
/// USART6's (syslink frames are at most 70 bytes; the nRF51 sends one per
/// radio packet).
static RX6: Mutex<RefCell<heapless::Deque<u8, 256>>> = Mutex::new(RefCell::new(heapless::Deque::new()));
/// Bytes each port lost: the receiver overran (ORE: a byte arrived while the
/// last was still unread, which on silicon happens while reception is paused).
static RX_OVERRUNS: Mutex<core::cell::Cell<[u32; 2]>> = Mutex::new(core::cell::Cell::new([0; 2]));

impl Port {
    /// The register block (the PAC's handle; USART6 shares USART1's layout).
    fn regs(self) -> &'static pac::usart1::RegisterBlock {
        // SAFETY: the PAC's pointers to the USARTs' registers; this driver
        // is their only user.
        unsafe {
            match self {
                Port::Usart1 => &*pac::USART1::ptr(),
                Port::Usart6 => &*pac::USART6::ptr(),
            }
        }
    }

    /// Its interrupt.
    fn irq(self) -> pac::Interrupt {
        match self {
            Port::Usart1 => pac::Interrupt::USART1,
            Port::Usart6 => pac::Interrupt::USART6,
        }
    }

    /// Runs `f` on its receive queue, in a critical section. Inlined, so
    /// that an image that names one port constant links only its queue.
    #[inline(always)]
    fn with_queue<R>(self, f: impl FnOnce(&mut heapless::deque::DequeView<u8>) -> R) -> R {
        critical_section::with(|cs| match self {
            Port::Usart1 => f(RX1.borrow_ref_mut(cs).as_mut_view()),
            Port::Usart6 => f(RX6.borrow_ref_mut(cs).as_mut_view()),
        })
    }

    /// The port whose interrupt number is `irqn`, if one is served.
    pub fn of_irq(irqn: i16) -> Option<Self> {
        [Port::Usart1, Port::Usart6]
            .into_iter()
            .find(|p| p.irq() as i16 == irqn)
    }
}

/// The RCC register block (the PAC's handle): enable bits only.
fn rcc() -> &'static pac::rcc::RegisterBlock {
    // SAFETY: the PAC's pointer; each driver sets only its own enable bit,
    // with a read-modify-write done before interrupts are enabled.
    unsafe { &*pac::RCC::ptr() }
}

/// A USART's receive interrupt: moves every received byte into its queue
/// (the interrupt itself wakes a main loop sleeping in WFI). Call from the
/// interrupt handler of the port's interrupt ([`Port::of_irq`]).
///
/// A full queue pauses reception instead of dropping the byte: the byte
/// stays in DR and the interrupt is masked until [`Usart::read`] makes
/// room. Under QEMU, whose USART takes the next byte only once DR is read,
/// that is lossless flow control (a burst larger than the queue, such as a
/// lockstep step's twenty preview frames, arrives whole). On silicon the
/// sender does not wait: bytes arriving during the pause overrun (ORE) and
/// are counted ([`rx_overruns`]), so the loss is seen, not silent.
#[inline(always)]
pub fn usart_isr(port: Port) {
    let u = port.regs();
    loop {
        let sr = u.sr().read();
        if sr.ore().bit_is_set() {
            // Cleared by the SR read above and the DR read below.
            critical_section::with(|cs| {
                let c = RX_OVERRUNS.borrow(cs);
                let mut n = c.get();
                n[port as usize] = n[port as usize].wrapping_add(1);
                c.set(n);
            });
        }
        if sr.rxne().bit_is_clear() {
            break;
        }
        // One critical section per byte: DR is read (popping the byte and
        // clearing RXNE) only when the queue has room for it.
        let taken = port.with_queue(|q| !q.is_full() && q.push_back(u.dr().read().dr().bits() as u8).is_ok());
        if !taken {
            // Masked at the NVIC, not with RXNEIE: QEMU's USART keeps its
            // interrupt line raised while RXNE is set whatever RXNEIE says.
            NVIC::mask(port.irq());
            break;
        }
    }
}

/// Takes up to `buf.len()` bytes of `port`'s receive queue (what
/// [`usart_isr`] moved there) into `buf`, never waiting; returns how many.
/// What [`Usart::read`] does, for code that receives in the port's own
/// interrupt while another owner transmits.
#[inline(always)]
pub fn read_queued(port: Port, buf: &mut [u8]) -> usize {
    port.with_queue(|q| {
        let mut n = 0;
        for (slot, b) in buf.iter_mut().zip(core::iter::from_fn(|| q.pop_front())) {
            *slot = b;
            n += 1;
        }
        if n > 0 {
            // Room again: resume reception if the interrupt paused it
            // (a byte waiting in DR raises the interrupt at once).
            // SAFETY: unmasking the port's interrupt, as `Usart::init` does.
            unsafe { NVIC::unmask(port.irq()) };
        }
        n
    })
}

/// Received bytes `port` lost so far to receiver overruns (each one
/// corrupts the frame it belonged to; the protocol counts that frame as bad).
pub fn rx_overruns(port: Port) -> u32 {
    critical_section::with(|cs| RX_OVERRUNS.borrow(cs).get()[port as usize])
}

/// True if received bytes are waiting in `port`'s queue.
#[inline(always)]
pub fn rx_waiting(port: Port) -> bool {
    !port.with_queue(|q| q.is_empty())
}

/// A USART as a byte link ([`Port`]). Reception is interrupt-driven into a
/// queue (1 KiB for USART1, 256 B for USART6; [`usart_isr`]); reads never wait; writes wait for TXE at
/// most a bounded number of polls per byte.
pub struct Usart {
    port: Port,
}

/// A write gave up waiting for the transmitter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TxTimeout;

impl Usart {
    /// Enables the clock and the peripheral `port` at `baud` for a `pclk_hz`
    /// bus clock (APB2 for both ports).
    ///
    /// Must be called once per port, before any other use of it.
    pub fn init(port: Port, pclk_hz: u32, baud: u32) -> Self {
        rcc().apb2enr().modify(|_, w| match port {
            Port::Usart1 => w.usart1en().enabled(),
            Port::Usart6 => w.usart6en().enabled(),
        });
        // BRR = f_pclk / baud (16× oversampling): mantissa and fraction are
        // the quotient's integer part and 1/16ths, i.e. the quotient itself.
        let div = (pclk_hz / baud.max(1)).clamp(16, 0xFFFF);
        let u = port.regs();
        u.brr().write(|w| {
            w.div_mantissa()
                .set((div >> 4) as u16)
                .div_fraction()
                .set((div & 0xF) as u8)
        });
        u.cr1()
            .write(|w| w.ue().enabled().te().enabled().re().enabled().rxneie().enabled());
        // SAFETY: unmasking the port's interrupt; its handler only moves
        // bytes into the queue under a critical section.
        unsafe { NVIC::unmask(port.irq()) };
        Self { port }
    }

    /// Which port this is.
    pub fn port(&self) -> Port {
        self.port
    }
}

/// Polls per byte before a write gives up.
const TX_SPIN: u32 = 1_000_000;

impl ByteLink for Usart {
    type Error = TxTimeout;
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        Ok(read_queued(self.port, buf))
    }
    fn write_all(&mut self, bytes: &[u8]) -> Result<(), Self::Error> {
        let u = self.port.regs();
        for &b in bytes {
            let mut spins = 0;
            while u.sr().read().txe().bit_is_clear() {
                spins += 1;
                if spins > TX_SPIN {
                    return Err(TxTimeout);
                }
            }
            // Writing DR sends the byte.
            u.dr().write(|w| w.dr().set(u16::from(b)));
        }
        Ok(())
    }
}

/// SysTick as the cycle clock: the 24-bit down-counter reloads every
/// millisecond and its interrupt ([`systick_isr`]) counts the reloads, so
/// [`SysTickClock::ticks`] is a 64-bit tick count and the main loop wakes at
/// least once a millisecond (the failsafe timer needs no other timer).
#[derive(Debug, Clone, Copy)]
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

/// SCB ICSR: SysTick exception pending (ARMv7-M architecture manual, B3.2.4).
const ICSR_PENDSTSET: u32 = 1 << 26;

impl SysTickClock {
    /// Starts SysTick on the processor clock (`hz`, ≥ 1 kHz), reloading every
    /// millisecond with its interrupt enabled.
    pub fn start(hz: u32) -> Self {
        let period = (hz / 1000).clamp(2, 0x0100_0000);
        critical_section::with(|cs| PERIOD.borrow(cs).set(period));
        // SAFETY: cortex-m's SysTick handle; this clock is its only user.
        let mut syst = unsafe { cortex_m::Peripherals::steal() }.SYST;
        syst.set_clock_source(cortex_m::peripheral::syst::SystClkSource::Core);
        syst.set_reload(period - 1);
        syst.clear_current();
        syst.enable_interrupt();
        syst.enable_counter();
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
        let cvr = SYST::get_current() & 0x00FF_FFFF;
        let into = (period - 1).saturating_sub(cvr);
        // A reload while interrupts are masked is pending, not yet counted:
        // ICSR.PENDSTSET says so. If it came after the counter was read, the
        // reading is near the period's end and needs no correction.
        // SAFETY: a read of the System Control Block's ICSR through cortex-m's handle.
        let pending = unsafe { (*SCB::PTR).icsr.read() } & ICSR_PENDSTSET != 0;
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

impl DwtClock {
    /// Enables the trace block and starts CYCCNT; `hz` is the core clock.
    pub fn start(hz: u32) -> Self {
        // SAFETY: cortex-m's DCB and DWT handles; this clock is their only user.
        let mut p = unsafe { cortex_m::Peripherals::steal() };
        p.DCB.enable_trace();
        p.DWT.set_cycle_count(0);
        p.DWT.enable_cycle_counter();
        Self { hz }
    }
}

impl CycleClock for DwtClock {
    fn now(&self) -> u32 {
        DWT::cycle_count()
    }
    fn hz(&self) -> u32 {
        self.hz
    }
}

fn tim2() -> &'static pac::tim2::RegisterBlock {
    // SAFETY: the PAC's pointer to TIM2; [`LoopTimer`] is its only user.
    unsafe { &*pac::TIM2::ptr() }
}

fn tim3() -> &'static pac::tim3::RegisterBlock {
    // SAFETY: the PAC's pointer to TIM3; [`PwmActuators`] is its only user.
    unsafe { &*pac::TIM3::ptr() }
}

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
        rcc().apb1enr().modify(|_, w| w.tim2en().enabled());
        let t = tim2();
        t.psc().write(|w| w.psc().set(psc as u16));
        t.arr().write(|w| w.arr().set(arr));
        t.egr().write(|w| w.ug().update()); // load PSC/ARR
        t.sr().write(|w| w.uif().clear_bit());
        // Update interrupt enabled in the timer (not in the NVIC: nothing
        // is taken); QEMU's timer model sets UIF only with UIE on.
        t.dier().write(|w| w.uie().enabled());
        t.cr1().write(|w| w.cen().enabled());
        Self { _private: () }
    }

    /// What TIM2 holds: its prescaler and auto-reload values, read back
    /// (for checks; the period is `(PSC + 1)(ARR + 1)` timer clocks, RM0090).
    pub fn registers(&self) -> (u32, u32) {
        let t = tim2();
        (u32::from(t.psc().read().psc().bits()), t.arr().read().arr().bits())
    }

    /// True once per period: the update flag, cleared when seen. Never blocks.
    pub fn expired(&mut self) -> bool {
        let t = tim2();
        if t.sr().read().uif().bit_is_set() {
            t.sr().write(|w| w.uif().clear_bit());
            true
        } else {
            false
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
        rcc().apb1enr().modify(|_, w| w.tim3en().enabled());
        let t = tim3();
        t.psc().write(|w| w.psc().set(psc as u16));
        t.arr().write(|w| w.arr().set(arr as u16));
        // PWM mode 1 with preload on channels 1-4, outputs enabled.
        t.ccmr1_output().write(|w| {
            w.oc1m()
                .pwm_mode1()
                .oc1pe()
                .enabled()
                .oc2m()
                .pwm_mode1()
                .oc2pe()
                .enabled()
        });
        t.ccmr2_output().write(|w| {
            w.oc3m()
                .pwm_mode1()
                .oc3pe()
                .enabled()
                .oc4m()
                .pwm_mode1()
                .oc4pe()
                .enabled()
        });
        t.ccer()
            .write(|w| w.cc1e().set_bit().cc2e().set_bit().cc3e().set_bit().cc4e().set_bit());
        for ch in 0..4 {
            t.ccr(ch).write(|w| w.ccr().set(0));
        }
        t.egr().write(|w| w.ug().update());
        t.cr1().write(|w| w.cen().enabled().arpe().enabled());
        Self { arr, to_duty }
    }

    /// What the timer holds: the auto-reload value and the four compare
    /// values, read back from TIM3 (for checks; duty = compare / (reload + 1)).
    pub fn registers(&self) -> (u32, [u32; 4]) {
        (u32::from(tim3().arr().read().arr().bits()), tim3_compares())
    }

    fn set(&mut self, duty: [f32; 4]) {
        for (ch, d) in duty.iter().enumerate() {
            // NaN or out of range → the nearest safe value (NaN → 0: motor off).
            let d = if d.is_nan() { 0.0 } else { d.clamp(0.0, 1.0) };
            let ccr = (d * self.arr as f32) as u32;
            tim3().ccr(ch).write(|w| w.ccr().set(ccr as u16));
        }
    }
}

/// Every motor output off at once, from whatever state the program is in
/// (a fault handler's first act): TIM3's four compare values set to 0 and
/// loaded now by an update event, not at the end of the PWM period. Returns
/// the compare values read back. Harmless if [`PwmActuators`] never started
/// (the outputs were never driven).
pub fn motors_off_now() -> [u32; 4] {
    let t = tim3();
    for ch in 0..4 {
        t.ccr(ch).write(|w| w.ccr().set(0));
    }
    t.egr().write(|w| w.ug().update());
    tim3_compares()
}

/// TIM3's four compare values, read back.
fn tim3_compares() -> [u32; 4] {
    let t = tim3();
    core::array::from_fn(|ch| u32::from(t.ccr(ch).read().ccr().bits()))
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
