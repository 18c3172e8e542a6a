//! The stack's high-water mark, measured by painting: the free stack below
//! the current frame is filled with a pattern, and the deepest word that
//! lost it is how far the stack has ever reached.
//!
//! The stack spans `_stack_end` (its lowest address) to `_stack_start`
//! (where it starts, growing down). The images link with flip-link, which
//! puts the statics at the top of RAM and the stack beneath them, down to
//! the start of RAM (`_stack_end` = 0x2000_0000): an overflow runs into
//! unmapped memory and faults instead of overwriting a static.

use core::sync::atomic::{AtomicBool, Ordering};

const PAINT: u32 = 0xA5A5_A5A5;

/// The boot's paint is done ([`boot_done`]): a [`Watch`] reads only after
/// it, or a pass that ran while the paint was under way would find the
/// boot's frames not yet painted over and take the boot's mark for the
/// tasks'.
static PAINTED: AtomicBool = AtomicBool::new(false);

extern "C" {
    static __sheap: u32;
    static __sdata: u32;
    static _stack_start: u32;
    static _stack_end: u32;
}

/// Fills the free stack between its lowest address and the current stack
/// pointer (less a small guard) with the pattern.
pub fn paint() {
    let bottom = core::ptr::addr_of!(_stack_end) as usize;
    let sp = cortex_m::register::msp::read() as usize;
    let mut a = bottom;
    while a + 64 < sp {
        // SAFETY: free stack below the live frames, above its lowest address.
        unsafe { core::ptr::write_volatile(a as *mut u32, PAINT) };
        a += 4;
    }
}

/// Bytes of stack ever used since [`paint`]: from where the stack starts
/// down to the lowest word that lost its paint (callers' frames included).
pub fn high_water() -> usize {
    let bottom = core::ptr::addr_of!(_stack_end) as usize;
    let top = core::ptr::addr_of!(_stack_start) as usize;
    let mut a = bottom;
    // SAFETY: reads of the stack's own memory.
    while a < top && unsafe { core::ptr::read_volatile(a as *const u32) } == PAINT {
        a += 4;
    }
    top - a
}

/// The end of the boot, from the idle task before it first sleeps: returns
/// the boot's high-water mark (the vehicle built, its first design, the
/// settings restored) and paints the free stack again, so that from here
/// [`high_water`] (and a [`Watch`]) measures the tasks, nested as they
/// pre-empt, over the frames of `main` and idle that stay. The paint
/// writes up to ~25 000 words, so it leaves interrupts on and the tasks
/// may pre-empt it: a task's frames are dead once it returns to idle, and the paint
/// only covers them; a task that runs during the paint is measured again
/// on its next run.
pub fn boot_done() -> usize {
    let boot = high_water();
    paint();
    PAINTED.store(true, Ordering::Release);
    boot
}

/// Words of the free stack a [`Watch`] reads per [`Watch::poll`] (a few
/// instructions each), so that the task that polls it on every run stays
/// short: a whole scan reads up to ~25 000 words.
pub const WATCH_WORDS: usize = 256;

/// The tasks' high-water mark (since [`boot_done`]), watched a bounded
/// slice at a time: each [`Watch::poll`] reads at most [`WATCH_WORDS`]
/// words, from the stack's lowest address up, and a pass ends at the first
/// word that lost its paint: the mark. The mark only grows (that word only
/// moves down), so no pass reads further than the one before.
/// [`Watch::log_if_grown`] logs it (`stack: high-water N bytes of M`, M:
/// [`capacity`]). The images poll it on every run of their lowest-priority
/// task and log it with their timing line (a log line masks interrupts
/// while it is written); the tools hold the mark to
/// [`crate::budgets::IMAGE_STACK_BYTES`].
#[derive(Debug, Clone, Copy, Default)]
pub struct Watch {
    /// The next word a pass reads, bytes above the stack's lowest address.
    next: usize,
    /// The mark the last whole pass found, bytes.
    mark: usize,
    /// The mark last logged, bytes.
    logged: usize,
}

impl Watch {
    /// At the start of a pass, nothing found or logged.
    pub const fn new() -> Self {
        Self {
            next: 0,
            mark: 0,
            logged: 0,
        }
    }

    /// Reads the pass's next slice; at its end, the mark is what it found.
    /// Nothing before the boot's paint is done.
    pub fn poll(&mut self) {
        if !PAINTED.load(Ordering::Acquire) {
            return;
        }
        let bottom = core::ptr::addr_of!(_stack_end) as usize;
        let top = core::ptr::addr_of!(_stack_start) as usize;
        let mut a = bottom + self.next;
        let end = (a + 4 * WATCH_WORDS).min(top);
        // SAFETY: reads of the stack's own memory.
        while a < end && unsafe { core::ptr::read_volatile(a as *const u32) } == PAINT {
            a += 4;
        }
        if a < end || a >= top {
            // The pass ends at the lowest word that lost its paint.
            self.next = 0;
            self.mark = self.mark.max(top - a);
        } else {
            self.next = a - bottom;
        }
    }

    /// Logs the mark if it grew since it was last logged.
    #[cfg(target_os = "none")]
    pub fn log_if_grown(&mut self) {
        if self.mark > self.logged {
            defmt::info!("stack: high-water {=usize} bytes of {=usize}", self.mark, capacity());
            self.logged = self.mark;
        }
    }
}

/// Bytes the stack may grow to: from where it starts to its lowest address.
pub fn capacity() -> usize {
    core::ptr::addr_of!(_stack_start) as usize - core::ptr::addr_of!(_stack_end) as usize
}

/// Where the stack starts (its highest address; it grows down from here).
pub fn start() -> usize {
    core::ptr::addr_of!(_stack_start) as usize
}

/// Bytes of static RAM (`.data`, `.bss`, `.uninit`).
pub fn static_ram() -> usize {
    core::ptr::addr_of!(__sheap) as usize - core::ptr::addr_of!(__sdata) as usize
}
