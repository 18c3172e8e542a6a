//! The stack's high-water mark, measured by painting: the free stack below
//! the current frame is filled with a pattern, and the deepest word that
//! lost it is how far the stack has ever reached.
//!
//! The stack spans `_stack_end` (its lowest address) to `_stack_start`
//! (where it starts, growing down). The images link with flip-link, which
//! puts the statics at the top of RAM and the stack beneath them, down to
//! the start of RAM (`_stack_end` = 0x2000_0000): an overflow runs into
//! unmapped memory and faults instead of overwriting a static.

const PAINT: u32 = 0xA5A5_A5A5;

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

/// Logs the high-water mark ([`high_water`]) when it has grown past
/// `logged` (the mark last logged), as `stack: high-water N bytes of M`
/// (M: [`capacity`]); `logged` becomes it. It reads the free stack, so the
/// images call it only with their timing line, from their lowest-priority
/// task; the tools hold the mark to
/// [`crate::budgets::IMAGE_STACK_BYTES`].
#[cfg(target_os = "none")]
pub fn log_if_grown(logged: &mut usize) {
    let hw = high_water();
    if hw > *logged {
        defmt::info!("stack: high-water {=usize} bytes of {=usize}", hw, capacity());
        *logged = hw;
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
