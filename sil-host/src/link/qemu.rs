//! The firmware image in QEMU's netduinoplus2: where the image is, how QEMU
//! is started, the USART1 socket a [`FcClient`] connects to, and the
//! decoding of the image's defmt log.

use super::client::FcClient;
use anyhow::{bail, Context, Result};
use std::net::{TcpListener, TcpStream};
use std::time::{Duration, Instant};

/// SysTick counts per executed instruction under `-icount shift=0` on
/// netduinoplus2: one instruction is 1 ns of virtual time and SysTick runs at
/// the 168 MHz system clock (calibrated: 200 000 instructions → 33 601 counts).
pub const SYSTICK_PER_INSTRUCTION: f64 = 0.168;

/// The firmware image: `$SIL_FIRMWARE_ELF` if set, else the image this
/// crate's build script built with cargo (`build.rs`: the `fc-stm32f405`
/// crate for `thumbv7em-none-eabihf`, release, into `target/firmware-image`;
/// rebuilt whenever the firmware's sources change). An error says why there
/// is none (e.g. the thumbv7em target is not installed).
pub fn firmware_elf() -> Result<std::path::PathBuf> {
    built_elf("SIL_FIRMWARE_ELF", env!("SIL_FIRMWARE_ELF_BUILT"))
}

/// The image that speaks MAVLink (binary `firmware-mavlink`):
/// `$SIL_FIRMWARE_MAVLINK_ELF` if set, else the one the build script built.
pub fn firmware_mavlink_elf() -> Result<std::path::PathBuf> {
    built_elf("SIL_FIRMWARE_MAVLINK_ELF", env!("SIL_FIRMWARE_MAVLINK_ELF_BUILT"))
}

/// The image that speaks CRTP over syslink (binary `firmware-crtp`):
/// `$SIL_FIRMWARE_CRTP_ELF` if set, else the one the build script built.
pub fn firmware_crtp_elf() -> Result<std::path::PathBuf> {
    built_elf("SIL_FIRMWARE_CRTP_ELF", env!("SIL_FIRMWARE_CRTP_ELF_BUILT"))
}

/// The Crazyflie 2.1 image (`fc-crazyflie`'s `firmware-crazyflie`, linked
/// at 0x08004000): `$SIL_FIRMWARE_CRAZYFLIE_ELF` if set, else the one the
/// build script built.
pub fn firmware_crazyflie_elf() -> Result<std::path::PathBuf> {
    built_elf("SIL_FIRMWARE_CRAZYFLIE_ELF", env!("SIL_FIRMWARE_CRAZYFLIE_ELF_BUILT"))
}

/// QEMU's stand-in for the Crazyflie bootloader (`fc-crazyflie`'s
/// `boot-shim`, 16 KiB at 0x08000000): `$SIL_BOOT_SHIM_ELF` if set, else
/// the one the build script built.
pub fn boot_shim_elf() -> Result<std::path::PathBuf> {
    built_elf("SIL_BOOT_SHIM_ELF", env!("SIL_BOOT_SHIM_ELF_BUILT"))
}

fn built_elf(var: &str, built: &str) -> Result<std::path::PathBuf> {
    if let Some(p) = std::env::var_os(var) {
        return Ok(p.into());
    }
    match built {
        "" => bail!(
            "no firmware image: sil-host's build could not build it ({}); \
             `rustup target add thumbv7em-none-eabihf` and rebuild, or set {var}",
            env!("SIL_FIRMWARE_BUILD_ERROR")
        ),
        p => {
            let p = std::path::PathBuf::from(p);
            if !p.exists() {
                bail!(
                    "the firmware image {} is gone; rebuild sil-host (cargo build -p sil-host)",
                    p.display()
                );
            }
            Ok(p)
        }
    }
}

/// `qemu-system-arm` set up as every run of the image here uses it:
/// netduinoplus2 (an emulated STM32F405, FPU on), deterministic
/// (`-icount shift=0`: one instruction per ns of virtual time), semihosting to
/// standard output, USART1 on the chardev `serial` (e.g. `null` or
/// `tcp:HOST:PORT,server=on`), the ELF `elf` loaded. (The cargo runner in
/// `.cargo/config.toml` spells the same options.) [`Boot::Shim`] loads a
/// boot program at 0x08000000 first and `elf` (linked behind it) beside it.
pub fn qemu_command(serial: &str, elf: &std::path::Path) -> std::process::Command {
    qemu_command_booting(serial, &Boot::Direct(elf.to_path_buf()))
}

/// How the emulated chip reaches the image.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Boot {
    /// The image's vector table is at 0x08000000: the core resets into it.
    Direct(std::path::PathBuf),
    /// A boot program at 0x08000000 (`shim`) jumps to the image, linked
    /// behind it (the Crazyflie's bootloader layout).
    Shim {
        /// The boot program.
        shim: std::path::PathBuf,
        /// The image it starts.
        image: std::path::PathBuf,
    },
}

impl Boot {
    /// The image (whose defmt table decodes the log).
    pub fn image(&self) -> &std::path::Path {
        match self {
            Boot::Direct(p) | Boot::Shim { image: p, .. } => p,
        }
    }
}

/// [`qemu_command`] for either way of booting.
pub fn qemu_command_booting(serial: &str, boot: &Boot) -> std::process::Command {
    let mut c = std::process::Command::new("qemu-system-arm");
    c.args(["-machine", "netduinoplus2", "-display", "none", "-monitor", "none"])
        .args(["-icount", "shift=0"])
        .args(["-semihosting-config", "enable=on,target=native"])
        .args(["-serial", serial]);
    match boot {
        Boot::Direct(elf) => {
            c.arg("-kernel").arg(elf);
        }
        Boot::Shim { shim, image } => {
            c.arg("-kernel")
                .arg(shim)
                .arg("-device")
                .arg(format!("loader,file={}", image.display()));
        }
    }
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
    /// How long the firmware may take to say it is up, from the start.
    up_within: Duration,
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
        Self::spawn(&Boot::Direct(elf.to_path_buf()), &[], Duration::from_secs(10))
    }

    /// Starts the image as `boot` says with USART6 (QEMU's sixth `-serial`) also a
    /// TCP server at `syslink`: the Crazyflie's link to its nRF51 radio,
    /// for `tools/nrf51_bridge.py`. QEMU starts the guest once both USART1
    /// and USART6 have a client, so nothing the image says at boot
    /// (`RADIO_READY`) is lost; the bridge has `wait_s` to connect.
    pub fn start_with_syslink(boot: &Boot, syslink: &str, wait_s: f64) -> Result<Self> {
        let usart6 = format!("tcp:{syslink},server=on,wait=on,nodelay=on");
        let serials = ["null", "null", "null", "null", usart6.as_str()];
        Self::spawn(boot, &serials, Duration::from_secs_f64(wait_s.clamp(1.0, 3600.0)))
    }

    /// Starts QEMU with USART1 on a local TCP server and `more` as the
    /// chardevs of USART2, 3, ….
    fn spawn(boot: &Boot, more: &[&str], up_within: Duration) -> Result<Self> {
        let port = TcpListener::bind("127.0.0.1:0")?.local_addr()?.port();
        let addr = format!("127.0.0.1:{port}");
        let log = std::env::temp_dir().join(format!("sil-host-qemu-{port}.log"));
        let out = std::env::temp_dir().join(format!("sil-host-qemu-{port}.defmt"));
        let mut cmd = qemu_command_booting(&format!("tcp:{addr},server=on,wait=on,nodelay=on"), boot);
        for m in more {
            cmd.args(["-serial", m]);
        }
        let child = cmd
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
            elf: boot.image().to_path_buf(),
            up_within,
        })
    }

    /// A protocol client on the emulated USART (see [`Qemu::connect`]).
    pub fn client(&mut self) -> Result<FcClient> {
        Ok(FcClient::over(self.connect()?))
    }

    /// The emulated USART as a TCP stream. Connects only once QEMU says it
    /// is waiting for the connection, plus a short settle: connecting the
    /// moment the socket opens was seen to leave the guest's link silent
    /// (not understood yet; see the book's firmware chapter). Returns once the firmware has
    /// logged that it is up.
    pub fn connect(&mut self) -> Result<TcpStream> {
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
                // The guest starts when we connect (`wait=on`); bytes sent
                // before its USART is up are dropped, and a frame cut in half
                // is counted as a link error. Wait for its "up" log line.
                self.wait_until_up(t0)?;
                return Ok(s);
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
    /// Waits (up to 10 s from `t0`, or what [`Qemu::start_with_syslink`]
    /// allows) until the firmware has logged that its USART is up
    /// (`up: protocol vN, waiting on USART1`, `up: MAVLink 2, …`, `up: CRTP …`).
    fn wait_until_up(&mut self, t0: Instant) -> Result<()> {
        loop {
            let bytes = std::fs::read(&self.out).unwrap_or_default();
            if !bytes.is_empty()
                && decode_defmt(&self.elf, &bytes)?
                    .iter()
                    .any(|l| l.contains("up: protocol") || l.contains("up: MAVLink") || l.contains("up: CRTP"))
            {
                return Ok(());
            }
            if let Ok(Some(st)) = self.child.try_wait() {
                bail!("qemu exited before the firmware was up: {st}");
            }
            if t0.elapsed() > self.up_within {
                bail!(
                    "the firmware did not log that it is up within {:.0} s",
                    self.up_within.as_secs_f64()
                );
            }
            std::thread::sleep(Duration::from_millis(10));
        }
    }

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
