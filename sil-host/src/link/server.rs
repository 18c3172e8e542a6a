//! `sil-host serve`: the flight-controller core behind the wire protocol on
//! a TCP socket, one client after another.

use anyhow::{bail, Result};
use fc_loop::{FcConfig, FlightCore};
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

fn session(stream: TcpStream, idle: Duration) -> Result<fc_proto::Counters> {
    stream.set_nodelay(true)?;
    stream.set_read_timeout(Some(Duration::from_millis(5)))?;
    let mut link = TcpLink(stream);
    let mut fc = FlightCore::new(FcConfig::default()).map_err(|e| anyhow::anyhow!("flight controller: {e}"))?;
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
