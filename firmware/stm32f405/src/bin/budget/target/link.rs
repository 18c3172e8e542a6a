//! The `loop` rows' in-memory byte link: our protocol's frames pushed in,
//! the loop's answers decoded as they go; the session and preview frames.

use super::{
    encode, fresh_flight_loop, reference, setpoint_to_wire, ByteLink, FcConfig, Fix, FlightLoop, FrameDecoder, FromFc,
    SysTickClock, ToFc, Vector3, MAX_FRAME, PROTOCOL_VERSION,
};

/// The `loop` rows' byte link (its 4 KiB queue is static RAM, as the
/// image's USART queues are).
pub(super) static mut LINK: MemLink = MemLink {
    rx: heapless::Deque::new(),
    tx_bytes: 0,
    tx: heapless::Vec::new(),
};

/// The link, emptied.
#[inline(never)]
pub(super) fn fresh_link() -> &'static mut MemLink {
    // SAFETY: as for `slot`.
    let l = unsafe { &mut *core::ptr::addr_of_mut!(LINK) };
    l.rx.clear();
    l.tx_bytes = 0;
    l.tx.clear();
    l
}

/// An in-memory byte link; what the loop sends is decoded as it goes,
/// for the step's own instruction count (its `Telemetry`).
pub(super) struct MemLink {
    pub(super) rx: heapless::Deque<u8, 4096>,
    pub(super) tx_bytes: u32,
    /// What was sent since the last [`MemLink::step_cycles`].
    pub(super) tx: heapless::Vec<u8, 1024>,
}

impl MemLink {
    /// The `cycles` of the last `Telemetry` sent since the last call
    /// (SysTick counts), decoded outside the timed step.
    pub(super) fn step_cycles(&mut self) -> Option<u32> {
        let mut dec = FrameDecoder::<MAX_FRAME>::new();
        let mut cycles = None;
        for &b in self.tx.iter() {
            if let Some(Ok(FromFc::Telemetry { cycles: c, .. })) = dec.push::<FromFc>(b) {
                cycles = Some(c);
            }
        }
        self.tx.clear();
        cycles
    }
}
impl ByteLink for MemLink {
    type Error = ();
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, ()> {
        let mut n = 0;
        while n < buf.len() {
            match self.rx.pop_front() {
                Some(b) => buf[n] = b,
                None => break,
            }
            n += 1;
        }
        Ok(n)
    }
    fn write_all(&mut self, bytes: &[u8]) -> Result<(), ()> {
        self.tx_bytes += bytes.len() as u32;
        // Kept while there is room (the image steps send ≈ 250 bytes).
        let _ = self.tx.extend_from_slice(bytes);
        Ok(())
    }
}

pub(super) fn push(link: &mut MemLink, m: &ToFc) {
    let mut b = [0u8; MAX_FRAME];
    if let Ok(n) = encode(m, &mut b) {
        for &x in &b[..n] {
            let _ = link.rx.push_back(x);
        }
    }
}

/// A fresh flight loop with `cfg`, started, its session opened over a
/// fresh link and controller `id` selected.
pub(super) fn open_session(
    cfg: FcConfig,
    id: u8,
    clock: &SysTickClock,
) -> Option<(&'static mut FlightLoop, &'static mut MemLink)> {
    let fc = fresh_flight_loop(cfg);
    fc.start().ok()?;
    let link = fresh_link();
    push(
        link,
        &ToFc::Hello {
            version: PROTOCOL_VERSION,
        },
    );
    push(
        link,
        &ToFc::Select {
            controller: id,
            feedforward: true,
        },
    );
    while !link.rx.is_empty() {
        fc.service(link, clock, 0).ok()?;
    }
    Some((fc, link))
}

/// The climbing circle's `n` preview points `pdt` s apart after `t`, as
/// `Preview` frames.
pub(super) fn push_preview(link: &mut MemLink, t: f32, (n, pdt): (usize, f64)) {
    for i in 1..=n {
        let p = reference(t + i as f32 * pdt as f32);
        push(
            link,
            &ToFc::Preview {
                k: i as u8,
                sp: setpoint_to_wire(&p),
            },
        );
    }
}

/// A mocap fix (position σ 2 mm, heading σ 0.5°, 10 ms old).
pub(super) fn mocap_fix(p: Vector3<f32>, yaw: f32) -> Fix {
    Fix {
        age_s: 0.01,
        pos_ned_m: Some(p),
        pos_sigma_m: Vector3::repeat(0.002),
        yaw_rad: Some(yaw),
        yaw_sigma_rad: 0.0087,
        ..Fix::EMPTY
    }
}
