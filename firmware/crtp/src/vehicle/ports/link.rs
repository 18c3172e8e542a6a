//! Ports link (15) and platform (13): echo, source and sink; the protocol
//! and firmware versions, the device type name, the legacy arming and
//! recovery commands.

use crate::vehicle::*;

impl CrtpShared {
    pub(in crate::vehicle) fn on_link<S: CrtpSink>(&mut self, p: &Packet, out: &mut S) -> Handled<S::Error> {
        match p.channel() {
            0 => out.send(p)?,
            1 => {
                let mut name = [0u8; crate::MAX_PAYLOAD];
                name[..18].copy_from_slice(b"Bitcraze Crazyflie");
                out.send(&reply(Port::Link, 1, &name))?;
            }
            2 => {}
            _ => return Ok(Err(unsupported(p))),
        }
        Ok(Ok(()))
    }

    pub(in crate::vehicle) fn on_platform<S: CrtpSink>(&mut self, p: &Packet, out: &mut S) -> Handled<S::Error> {
        let d = p.payload();
        let Some(&cmd) = d.first() else {
            return Ok(Err(short(p)));
        };
        match (p.channel(), cmd) {
            (0, 0) | (0, 3) => {}
            (0, 1) => {
                let Some(&arm) = d.get(1) else {
                    return Ok(Err(short(p)));
                };
                let ok = self.request_arming(arm != 0);
                out.send(&reply(Port::Platform, 0, &[1, u8::from(ok), u8::from(self.armed())]))?;
            }
            (0, 2) => {
                let ok = self.client.recover();
                out.send(&reply(
                    Port::Platform,
                    0,
                    &[2, u8::from(ok), u8::from(!self.client.arming().tumbled())],
                ))?;
            }
            (1, 0) => {
                let mut b = [0u8; 5];
                b[1..].copy_from_slice(&crate::PROTOCOL_VERSION.to_le_bytes());
                out.send(&reply(Port::Platform, 1, &b))?;
            }
            (1, 1) | (1, 2) => {
                let text = if cmd == 1 { FIRMWARE_VERSION } else { DEVICE_TYPE_NAME };
                let mut r = reply(Port::Platform, 1, &[cmd]);
                let _ = r.extend(&text.as_bytes()[..text.len().min(r.room())]);
                out.send(&r)?;
            }
            _ => return Ok(Err(unsupported(p))),
        }
        Ok(Ok(()))
    }
}
