//! The host end of the wire protocol: a client that flies the controller
//! behind frames — in-process over a loopback byte link (`framed`) or over TCP
//! (`tcp:HOST:PORT`, e.g. `sil-host serve`) — and the TCP server itself.

use anyhow::{bail, Context, Result};
use firmware::control::Setpoint;
use firmware::fc::{setpoint_to_wire, FcConfig, FlightCore};
use firmware::proto::{encode, ControllerId, FrameDecoder, FromFc, ToFc, WireSetpoint, MAX_FRAME, PROTOCOL_VERSION};
use hal_shim::host::{LoopbackLink, MonotonicClock};
use hal_shim::ByteLink;
use std::io::{ErrorKind, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::time::{Duration, Instant};

/// What one remote control step returned.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct RemoteStep {
    /// Inputs `[U1 N, U2 N, U3 N, U4 N·m]`.
    pub u: [f32; 4],
    /// Cycles (or instructions, or ns on the host) spent in the controller.
    pub cycles: u32,
    /// QP iterations.
    pub qp_iterations: u16,
    /// Failsafe active.
    pub failsafe: bool,
    /// The flight controller's frame and error counters after this step.
    pub counters: firmware::proto::Counters,
}

fn frame(m: &ToFc) -> Result<Vec<u8>> {
    let mut b = [0u8; MAX_FRAME];
    let n = encode(m, &mut b).map_err(|e| anyhow::anyhow!("encoding {m:?}: {e:?}"))?;
    Ok(b[..n].to_vec())
}

/// Where the frames go.
enum Transport {
    /// The core in this process behind a loopback byte link.
    Local {
        fc: Box<FlightCore>,
        link: LoopbackLink,
        clock: MonotonicClock,
        t0: Instant,
    },
    /// A TCP peer.
    Tcp(TcpStream),
}

/// A client of the flight controller's protocol.
pub struct FcClient {
    transport: Transport,
    decoder: FrameDecoder<MAX_FRAME>,
    pending: Vec<FromFc>,
    /// The setpoint the flight controller holds (it keeps the last one sent).
    last_setpoint: Option<WireSetpoint>,
}

impl FcClient {
    /// The core in-process, reached through frames only.
    pub fn local() -> Result<Self> {
        let fc = FlightCore::new(FcConfig::default()).map_err(|e| anyhow::anyhow!("{e:?}"))?;
        Ok(Self::with(Transport::Local {
            fc: Box::new(fc),
            link: LoopbackLink::default(),
            clock: MonotonicClock::default(),
            t0: Instant::now(),
        }))
    }

    /// A TCP peer at `addr` (e.g. `127.0.0.1:7000`).
    pub fn tcp(addr: &str) -> Result<Self> {
        let s = TcpStream::connect(addr).with_context(|| format!("connecting to {addr}"))?;
        s.set_nodelay(true)?;
        s.set_read_timeout(Some(Duration::from_secs(5)))?;
        Ok(Self::with(Transport::Tcp(s)))
    }

    fn with(transport: Transport) -> Self {
        Self {
            transport,
            decoder: FrameDecoder::new(),
            pending: Vec::new(),
            last_setpoint: None,
        }
    }

    fn send(&mut self, m: &ToFc) -> Result<()> {
        let bytes = frame(m)?;
        match &mut self.transport {
            Transport::Local { fc, link, clock, t0 } => {
                link.rx.extend(bytes);
                let now = t0.elapsed().as_micros() as u64;
                while !link.rx.is_empty() {
                    fc.service(link, clock, now).map_err(|e| anyhow::anyhow!("{e:?}"))?;
                }
                Ok(())
            }
            Transport::Tcp(s) => Ok(s.write_all(&bytes)?),
        }
    }

    /// Waits for the next message the flight controller sends.
    fn receive(&mut self) -> Result<FromFc> {
        loop {
            if !self.pending.is_empty() {
                return Ok(self.pending.remove(0));
            }
            let bytes: Vec<u8> = match &mut self.transport {
                Transport::Local { link, .. } => {
                    if link.tx.is_empty() {
                        bail!("the flight controller sent nothing");
                    }
                    std::mem::take(&mut link.tx)
                }
                Transport::Tcp(s) => {
                    let mut buf = [0u8; 512];
                    let n = s.read(&mut buf).context("reading from the flight controller")?;
                    if n == 0 {
                        bail!("the flight controller closed the connection");
                    }
                    buf[..n].to_vec()
                }
            };
            for b in bytes {
                if let Some(Ok(m)) = self.decoder.push::<FromFc>(b) {
                    self.pending.push(m);
                }
            }
        }
    }

    /// Handshake and controller selection.
    pub fn open(&mut self, controller: ControllerId, feedforward: bool) -> Result<()> {
        // Hello is repeated until answered: a flight controller that is still
        // booting drops what arrives before its UART is up.
        let patient = match &self.transport {
            Transport::Tcp(s) => {
                let t = s.read_timeout()?;
                s.set_read_timeout(Some(Duration::from_millis(200)))?;
                t
            }
            Transport::Local { .. } => None,
        };
        let mut answer = None;
        for _ in 0..50 {
            self.send(&ToFc::Hello {
                version: PROTOCOL_VERSION,
            })?;
            match self.receive() {
                Ok(m) => {
                    answer = Some(m);
                    break;
                }
                // Only a read timeout means "ask again".
                Err(e)
                    if e.chain().any(|c| {
                        c.downcast_ref::<std::io::Error>()
                            .is_some_and(|io| matches!(io.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut))
                    }) => {}
                Err(e) => return Err(e),
            }
        }
        if let Transport::Tcp(s) = &self.transport {
            s.set_read_timeout(patient)?;
        }
        match answer {
            Some(FromFc::HelloAck { accepted: true, .. }) => {}
            Some(other) => bail!("handshake refused: {other:?}"),
            None => bail!("no handshake answer after 50 tries"),
        }
        // Acknowledgements of repeated Hellos may still be queued: drop them.
        self.pending.retain(|m| !matches!(m, FromFc::HelloAck { .. }));
        self.last_setpoint = None;
        self.send(&ToFc::Select {
            controller,
            feedforward,
        })?;
        // Building a controller (an MPC's condensed QP and its iteration
        // bound) takes the flight controller a while; bytes sent meanwhile
        // would pile up in its receive queue. A heartbeat is answered only
        // after the selection is processed, so waiting for it paces the host.
        self.send(&ToFc::Heartbeat { seq: u32::MAX })?;
        // (Late acknowledgements of repeated Hellos may come first.)
        for _ in 0..64 {
            if let FromFc::Heartbeat { seq: u32::MAX } = self.receive()? {
                return Ok(());
            }
        }
        bail!("the flight controller did not confirm the controller selection")
    }

    /// One lockstep control step: setpoint (and preview), the state for step
    /// `seq`, and the flight controller's answer for that step.
    pub fn step(
        &mut self,
        seq: u32,
        t_us: u64,
        state: &[f32; 13],
        sp: &Setpoint<f32>,
        preview: &[Setpoint<f32>],
    ) -> Result<RemoteStep> {
        // The flight controller holds its setpoint: send it only when it
        // changes (a fixed target then costs one frame a step, not two).
        let w = setpoint_to_wire(sp);
        if self.last_setpoint != Some(w) {
            self.send(&ToFc::Setpoint(w))?;
            self.last_setpoint = Some(w);
        }
        for (k, p) in preview.iter().enumerate() {
            self.send(&ToFc::Preview {
                k: (k + 1) as u8,
                sp: setpoint_to_wire(p),
            })?;
        }
        self.send(&ToFc::Sensor {
            seq,
            t_us,
            state: *state,
        })?;
        let mut out = None;
        for _ in 0..8 {
            match self.receive()? {
                FromFc::Actuator { seq: s, u, failsafe } if s == seq => {
                    out = Some(RemoteStep {
                        u,
                        cycles: 0,
                        qp_iterations: 0,
                        failsafe,
                        counters: Default::default(),
                    });
                }
                FromFc::Telemetry {
                    seq: s,
                    cycles,
                    qp_iterations,
                    counters,
                    ..
                } if s == seq => {
                    let mut r = out.ok_or_else(|| anyhow::anyhow!("telemetry before the actuator frame"))?;
                    r.cycles = cycles;
                    r.qp_iterations = qp_iterations;
                    r.counters = counters;
                    return Ok(r);
                }
                _ => {}
            }
        }
        bail!("no answer for step {seq}")
    }
}

/// A TCP stream as the flight controller's byte link (non-blocking reads).
struct TcpLink(TcpStream);

impl ByteLink for TcpLink {
    type Error = std::io::Error;
    fn read(&mut self, buf: &mut [u8]) -> Result<usize, Self::Error> {
        match self.0.read(buf) {
            Ok(0) => Err(std::io::Error::new(ErrorKind::UnexpectedEof, "client hung up")),
            Ok(n) => Ok(n),
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => Ok(0),
            Err(e) => Err(e),
        }
    }
    fn write_all(&mut self, bytes: &[u8]) -> Result<(), Self::Error> {
        self.0.write_all(bytes)
    }
}

/// Serves the flight controller on `listener`, one client after another: each
/// client gets a fresh core; garbage is dropped and counted, a hang-up or an
/// idle client (no byte for `idle` time) ends only that session. Stops after
/// `max_clients` sessions when given.
pub fn serve(listener: TcpListener, idle: Duration, max_clients: Option<usize>, log: bool) -> Result<()> {
    let mut served = 0usize;
    for conn in listener.incoming() {
        let stream = match conn {
            Ok(s) => s,
            Err(e) => {
                if log {
                    eprintln!("serve: accept failed: {e}");
                }
                continue;
            }
        };
        let peer = stream.peer_addr().map(|a| a.to_string()).unwrap_or_else(|_| "?".into());
        let result = session(stream, idle);
        served += 1;
        if log {
            match &result {
                Ok(c) => eprintln!("serve: {peer} done: {c:?}"),
                Err(e) => eprintln!("serve: {peer} ended: {e}"),
            }
        }
        if max_clients.is_some_and(|m| served >= m) {
            break;
        }
    }
    Ok(())
}

fn session(stream: TcpStream, idle: Duration) -> Result<firmware::proto::Counters> {
    stream.set_nodelay(true)?;
    stream.set_read_timeout(Some(Duration::from_millis(5)))?;
    let mut link = TcpLink(stream);
    let mut fc = FlightCore::new(FcConfig::default()).map_err(|e| anyhow::anyhow!("{e:?}"))?;
    let clock = MonotonicClock::default();
    let t0 = Instant::now();
    let mut last_byte = Instant::now();
    loop {
        let before = fc.counters();
        match fc.service(&mut link, &clock, t0.elapsed().as_micros() as u64) {
            Ok(()) => {}
            Err(e) if e.kind() == ErrorKind::UnexpectedEof => return Ok(fc.counters()),
            Err(e) => return Err(e.into()),
        }
        if fc.counters() != before {
            last_byte = Instant::now();
        }
        if last_byte.elapsed() > idle {
            bail!("idle for {idle:?}");
        }
    }
}

/// SysTick counts per executed instruction under `-icount shift=0` on
/// netduinoplus2: one instruction is 1 ns of virtual time and SysTick runs at
/// the 168 MHz system clock (calibrated: 200 000 instructions → 33 601 counts).
pub const SYSTICK_PER_INSTRUCTION: f64 = 0.168;

/// The firmware image: `$SIL_FIRMWARE_ELF`, else the workspace's release
/// build, brought up to date with cargo first (a no-op when it is current,
/// and never a stale image).
pub fn firmware_elf() -> Result<std::path::PathBuf> {
    if let Some(p) = std::env::var_os("SIL_FIRMWARE_ELF") {
        return Ok(p.into());
    }
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let elf = root.join("target/thumbv7em-none-eabihf/release/firmware");
    let st = std::process::Command::new(std::env::var("CARGO").unwrap_or_else(|_| "cargo".into()))
        .args([
            "build",
            "-q",
            "-p",
            "firmware",
            "--release",
            "--target",
            "thumbv7em-none-eabihf",
        ])
        .current_dir(&root)
        .status()
        .context("running cargo to build the firmware image")?;
    if !st.success() {
        bail!("building the firmware image failed");
    }
    Ok(elf)
}

/// `qemu-system-arm` set up as every run of the image here uses it:
/// netduinoplus2 (an emulated STM32F405, FPU on), deterministic
/// (`-icount shift=0`: one instruction per ns of virtual time), semihosting to
/// standard output, USART1 on the chardev `serial` (e.g. `null` or
/// `tcp:HOST:PORT,server=on`), the ELF `elf` loaded. (The cargo runner in
/// `.cargo/config.toml` spells the same options.)
pub fn qemu_command(serial: &str, elf: &std::path::Path) -> std::process::Command {
    let mut c = std::process::Command::new("qemu-system-arm");
    c.args(["-machine", "netduinoplus2", "-display", "none", "-monitor", "none"])
        .args(["-icount", "shift=0"])
        .args(["-semihosting-config", "enable=on,target=native"])
        .args(["-serial", serial])
        .arg("-kernel")
        .arg(elf);
    c
}

/// QEMU's netduinoplus2 (an STM32F405, FPU on) running the firmware image,
/// deterministic (`-icount shift=0`), USART1 on a local TCP socket. Stopped
/// (killed and reaped) when dropped.
pub struct Qemu {
    child: std::process::Child,
    /// Where USART1 listens.
    pub addr: String,
    log: std::path::PathBuf,
    /// The guest's semihosting output (its defmt log frames).
    out: std::path::PathBuf,
    elf: std::path::PathBuf,
}

/// Decodes defmt log frames (`bytes`) with the format table of `elf`; one
/// line per frame, `timestamp level message`.
pub fn decode_defmt(elf: &std::path::Path, bytes: &[u8]) -> Result<Vec<String>> {
    let image = std::fs::read(elf).with_context(|| format!("reading {}", elf.display()))?;
    let table =
        defmt_decoder::Table::parse(&image)?.ok_or_else(|| anyhow::anyhow!("{} has no defmt table", elf.display()))?;
    let mut dec = table.new_stream_decoder();
    dec.received(bytes);
    let mut lines = Vec::new();
    loop {
        match dec.decode() {
            Ok(frame) => lines.push(frame.display(false).to_string()),
            Err(defmt_decoder::DecodeError::UnexpectedEof) => break,
            Err(defmt_decoder::DecodeError::Malformed) => {
                if table.encoding().can_recover() {
                    lines.push("(malformed defmt frame skipped)".into());
                } else {
                    bail!("malformed defmt frame");
                }
            }
        }
    }
    Ok(lines)
}

impl Qemu {
    /// Starts the image at `elf`.
    pub fn start(elf: &std::path::Path) -> Result<Self> {
        let port = TcpListener::bind("127.0.0.1:0")?.local_addr()?.port();
        let addr = format!("127.0.0.1:{port}");
        let log = std::env::temp_dir().join(format!("sil-host-qemu-{port}.log"));
        let out = std::env::temp_dir().join(format!("sil-host-qemu-{port}.defmt"));
        let child = qemu_command(&format!("tcp:{addr},server=on,wait=on,nodelay=on"), elf)
            // Semihosting output: the firmware's defmt log.
            .stdout(std::fs::File::create(&out)?)
            // QEMU's own messages go to a log file: an unread pipe would fill and stall it.
            .stderr(std::fs::File::create(&log)?)
            .spawn()
            .context("starting qemu-system-arm (Debian package qemu-system-arm)")?;
        Ok(Self {
            child,
            addr,
            log,
            out,
            elf: elf.to_path_buf(),
        })
    }

    /// A protocol client on the emulated USART. Connects only once QEMU says
    /// it is waiting for the connection, plus a short settle: connecting the
    /// moment the socket opens was seen to leave the guest's link silent
    /// (not understood yet; see the README).
    pub fn client(&mut self) -> Result<FcClient> {
        let t0 = Instant::now();
        while !std::fs::read_to_string(&self.log)
            .unwrap_or_default()
            .contains("waiting for connection")
        {
            if let Ok(Some(st)) = self.child.try_wait() {
                bail!("qemu exited: {st}; see {}", self.log.display());
            }
            if t0.elapsed() > Duration::from_secs(10) {
                bail!(
                    "qemu did not open {} within 10 s; see {}",
                    self.addr,
                    self.log.display()
                );
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        std::thread::sleep(Duration::from_millis(300));
        loop {
            if let Ok(s) = TcpStream::connect(&self.addr) {
                s.set_nodelay(true)?;
                s.set_read_timeout(Some(Duration::from_secs(30)))?;
                return Ok(FcClient::with(Transport::Tcp(s)));
            }
            if let Ok(Some(st)) = self.child.try_wait() {
                bail!("qemu exited before the link opened: {st}");
            }
            if t0.elapsed() > Duration::from_secs(10) {
                bail!("qemu did not open {} within 10 s", self.addr);
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

impl Qemu {
    /// Stops QEMU the way Ctrl-C does (so it flushes the guest's output),
    /// killing it after a second if it lingers.
    fn stop(&mut self) {
        if matches!(self.child.try_wait(), Ok(None)) {
            let _ = std::process::Command::new("kill")
                .args(["-INT", &self.child.id().to_string()])
                .status();
            let t0 = Instant::now();
            while matches!(self.child.try_wait(), Ok(None)) && t0.elapsed() < Duration::from_secs(1) {
                std::thread::sleep(Duration::from_millis(10));
            }
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// Stops QEMU and returns the firmware's defmt log, decoded.
    pub fn finish(mut self) -> Result<Vec<String>> {
        self.stop();
        let bytes = std::fs::read(&self.out).unwrap_or_default();
        decode_defmt(&self.elf, &bytes)
    }
}

impl Drop for Qemu {
    fn drop(&mut self) {
        self.stop();
        let _ = std::fs::remove_file(&self.log);
        let _ = std::fs::remove_file(&self.out);
    }
}
