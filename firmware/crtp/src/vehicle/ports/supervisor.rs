//! Port supervisor (9): arming, recovery, emergency stop and the state
//! bits; the checks before a take-off.

use crate::vehicle::*;
use fc_loop::arming::ArmingState;
use fc_loop::commander::Priority;

impl CrtpShared {
    /// What the arming check looks at, with everything this vehicle's
    /// supervisor monitors.
    fn arming_state(&self) -> ArmingState {
        ArmingState {
            sensor_down: self.sensors.err().map(|d| (d.device, d.why)),
            battery_v: Some(self.vbat_v),
            battery_floor_v: BATTERY_FLOOR_V,
            nav: self.lp.navigator().mode(),
            started: self.lp.mixer().is_some(),
        }
    }

    /// The supervisor's "can fly" ([`fc_loop::client::ClientCommander::can_fly`]).
    pub(in crate::vehicle) fn can_fly(&self) -> bool {
        self.client.can_fly(&self.arming_state())
    }

    /// The supervisor's state bits (cflib's `Supervisor.STATES` order).
    pub fn supervisor_bits(&self) -> u16 {
        let commander = self.client.commander();
        let high = commander.priority() == Priority::Planned;
        let finished = commander.segment().is_none_or(|seg| seg.finished(self.now_us));
        let bits = [
            self.can_fly() && !self.armed(),
            self.armed(),
            false,
            self.can_fly(),
            self.flying(),
            self.client.arming().tumbled(),
            self.client.arming().locked(),
            self.client.arming().tumbled(),
            high,
            finished,
            false,
        ];
        bits.iter()
            .enumerate()
            .fold(0, |acc, (i, &b)| acc | (u16::from(b) << i))
    }

    /// Arms (if the supervisor allows) or disarms; the answer is whether it
    /// did, and whether it is armed now.
    pub(in crate::vehicle) fn request_arming(&mut self, arm: bool) -> bool {
        if !arm {
            self.client.disarm();
            self.say(format_args!("disarmed"));
            return true;
        }
        // The one arming check (fc_loop::arming).
        match self.client.arm(&self.arming_state()) {
            Ok(false) => {}
            Ok(true) => self.say(format_args!("armed")),
            Err(why) => {
                self.say(format_args!("arming refused: {why}"));
                return false;
            }
        }
        true
    }

    pub(in crate::vehicle) fn on_supervisor<S: CrtpSink>(&mut self, p: &Packet, out: &mut S) -> Handled<S::Error> {
        let d = p.payload();
        let Some(&cmd) = d.first() else {
            return Ok(Err(short(p)));
        };
        let bits = self.supervisor_bits();
        match (p.channel(), cmd) {
            (0, 0x0C) => {
                let b = bits.to_le_bytes();
                out.send(&reply(Port::Supervisor, 0, &[0x8C, b[0], b[1]]))?;
            }
            (0, 0x01..=0x0B) => {
                let bit = (bits >> (cmd - 1)) & 1;
                out.send(&reply(Port::Supervisor, 0, &[0x80 | cmd, bit as u8]))?;
            }
            (1, 0x01) => {
                let Some(&arm) = d.get(1) else {
                    return Ok(Err(short(p)));
                };
                let ok = self.request_arming(arm != 0);
                out.send(&reply(
                    Port::Supervisor,
                    1,
                    &[0x81, u8::from(ok), u8::from(self.armed())],
                ))?;
            }
            (1, 0x02) => {
                let ok = self.client.recover();
                out.send(&reply(
                    Port::Supervisor,
                    1,
                    &[0x82, u8::from(ok), u8::from(!self.client.arming().tumbled())],
                ))?;
            }
            (1, 0x03) => self.emergency_stop(),
            (1, 0x04) => {}
            _ => return Ok(Err(unsupported(p))),
        }
        Ok(Ok(()))
    }

    /// Motors off and locked until restarted, as the Crazyflie's emergency stop.
    pub(in crate::vehicle) fn emergency_stop(&mut self) {
        self.client.emergency_stop();
        self.say(format_args!("emergency stop: locked"));
    }
}
