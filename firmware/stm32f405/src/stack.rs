//! The stack's high-water mark, measured by painting: the free RAM between
//! the statics and the stack is filled with a pattern, and the deepest
//! word that lost it is how far the stack has ever reached.

const PAINT: u32 = 0xA5A5_A5A5;

extern "C" {
    static __sheap: u32;
    static __sdata: u32;
    static _stack_start: u32;
}

/// Fills the free RAM between the statics and the current stack pointer
/// (less a small guard) with the pattern.
pub fn paint() {
    let bottom = core::ptr::addr_of!(__sheap) as usize;
    let sp = cortex_m::register::msp::read() as usize;
    let mut a = bottom;
    while a + 64 < sp {
        // SAFETY: free RAM below the live stack, above every static.
        unsafe { core::ptr::write_volatile(a as *mut u32, PAINT) };
        a += 4;
    }
}

/// Bytes of stack ever used since [`paint`]: from the top of RAM down to
/// the lowest word that lost its paint (callers' frames included).
pub fn high_water() -> usize {
    let bottom = core::ptr::addr_of!(__sheap) as usize;
    let top = core::ptr::addr_of!(_stack_start) as usize;
    let mut a = bottom;
    // SAFETY: reads of RAM between the statics and the stack top.
    while a < top && unsafe { core::ptr::read_volatile(a as *const u32) } == PAINT {
        a += 4;
    }
    top - a
}

/// Bytes of static RAM (`.data`, `.bss`, `.uninit`).
pub fn static_ram() -> usize {
    core::ptr::addr_of!(__sheap) as usize - core::ptr::addr_of!(__sdata) as usize
}
