//! STM32F405 implementations: USART1 as the byte link, SysTick as the cycle
//! clock (DWT CYCCNT on silicon is the same interface; QEMU does not model it,
//! and under `-icount shift=0` SysTick advances with executed instructions).

use crate::{ByteLink, CycleClock};
use core::cell::RefCell;
use core::ptr::{read_volatile, write_volatile};
use critical_section::Mutex;

/// Received bytes, filled by [`usart1_isr`], drained by [`Usart1::read`].
static RX: Mutex<RefCell<heapless::Deque<u8, 1024>>> = Mutex::new(RefCell::new(heapless::Deque::new()));
/// Bytes lost because the queue was full.
static RX_OVERRUNS: Mutex<core::cell::Cell<u32>> = Mutex::new(core::cell::Cell::new(0));
const CR1_RXNEIE: u32 = 1 << 5;
/// USART1's interrupt number on the STM32F405.
pub const USART1_IRQ: u16 = 37;
const NVIC_ISER: usize = 0xE000_E100;

/// USART1 receive interrupt: moves every received byte into the queue and
/// signals an event (SEV) so a main loop waiting in WFE wakes. Call from the
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
    // SAFETY: SEV only sets the event register.
    unsafe { core::arch::asm!("sev", options(nomem, nostack, preserves_flags)) };
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

/// SysTick as a free-running 24-bit counter, read as an up-counter.
pub struct SysTickClock {
    hz: u32,
}

const SYST_CSR: usize = 0xE000_E010;
const SYST_RVR: usize = 0xE000_E014;
const SYST_CVR: usize = 0xE000_E018;

impl SysTickClock {
    /// Starts SysTick on the processor clock (`hz`), full 24-bit range.
    pub fn start(hz: u32) -> Self {
        // SAFETY: the architectural SysTick registers; this is their only user.
        unsafe {
            write_volatile(SYST_RVR as *mut u32, 0x00FF_FFFF);
            write_volatile(SYST_CVR as *mut u32, 0);
            write_volatile(SYST_CSR as *mut u32, 0b101); // enable, processor clock, no interrupt
        }
        Self { hz }
    }

    /// Raw down-counter value.
    pub fn raw(&self) -> u32 {
        // SAFETY: read of the SysTick current value.
        unsafe { read_volatile(SYST_CVR as *const u32) & 0x00FF_FFFF }
    }
}

impl CycleClock for SysTickClock {
    fn now(&self) -> u32 {
        0x00FF_FFFF - self.raw()
    }
    fn hz(&self) -> u32 {
        self.hz
    }
    fn since(&self, start: u32) -> u32 {
        self.now().wrapping_sub(start) & 0x00FF_FFFF
    }
}
