//! `sil-host serve`: the flight-controller core behind the wire protocol on
//! a TCP socket, one client after another.

use anyhow::{bail, Result};
use fc_loop::{FcConfig, FlightLoop};
use hal_shim::host::MonotonicClock;
use hal_shim::ByteLink;
use std::io::{ErrorKind, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::time::{Duration, Instant};

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

/// How `serve` keeps one client from holding its only slot.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ServeOptions {
    /// A session with no *valid* frame for this long ends (garbage, empty
    /// frames and bad frames do not keep it open). Also the write timeout: a
    /// client that does not read its replies for this long is dropped.
    pub idle: Duration,
    /// No session lasts longer than this, however busy.
    pub max_session: Duration,
    /// Stop after this many sessions (`None`: serve forever).
    pub max_clients: Option<usize>,
    /// Log each session's end on standard error.
    pub log: bool,
}

impl Default for ServeOptions {
    /// Idle 10 s, sessions up to 2 hours (the longest flight is one), forever, quiet.
    fn default() -> Self {
        Self {
            idle: Duration::from_secs(10),
            max_session: Duration::from_secs(7200),
            max_clients: None,
            log: false,
        }
    }
}

/// Serves the flight controller on `listener`, one client after another: each
/// client gets a fresh core; garbage is dropped and counted; a hang-up, an
/// idle client, one that does not read its replies, or a session over its
/// limit ends only that session (see [`ServeOptions`]).
pub fn serve(listener: TcpListener, o: &ServeOptions) -> Result<()> {
    let (max_clients, log) = (o.max_clients, o.log);
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
        let result = session(stream, o);
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

fn session(stream: TcpStream, o: &ServeOptions) -> Result<fc_proto::Counters> {
    let idle = o.idle;
    stream.set_nodelay(true)?;
    stream.set_read_timeout(Some(Duration::from_millis(5)))?;
    // A client that does not read its replies fills the socket buffer; the
    // write then fails after `idle` instead of blocking the server forever.
    stream.set_write_timeout(Some(idle))?;
    let mut link = TcpLink(stream);
    let mut fc = FlightLoop::new(FcConfig::default()).map_err(|e| anyhow::anyhow!("flight controller: {e}"))?;
    let clock = MonotonicClock::default();
    let t0 = Instant::now();
    let mut last_valid = Instant::now();
    loop {
        let before = fc.counters().ok;
        match fc.service(&mut link, &clock, t0.elapsed().as_micros() as u64) {
            Ok(()) => {}
            Err(e) if e.kind() == ErrorKind::UnexpectedEof => return Ok(fc.counters()),
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {
                bail!("the client did not read its replies for {idle:?}")
            }
            Err(e) => return Err(e.into()),
        }
        if fc.counters().ok != before {
            last_valid = Instant::now();
        }
        if last_valid.elapsed() > idle {
            bail!("no valid frame for {idle:?}");
        }
        if t0.elapsed() > o.max_session {
            bail!("session longer than {:?}", o.max_session);
        }
    }
}
