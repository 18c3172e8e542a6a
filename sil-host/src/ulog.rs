//! ULog, PX4's flight-log format, written as a flight goes: pyulog,
//! PlotJuggler and PX4 Flight Review open the files.
//!
//! The layout follows PX4's "ULog File Format" specification: a 16-byte
//! header (magic, version 1, start time in µs), the definitions section
//! (flag bits `B`, one format `F` per topic, information `I`, initial
//! parameters `P`) and the data section (subscriptions `A`, samples `D`,
//! logged strings `L`, parameter changes `P`). Every multi-byte value is
//! little endian; every sample begins with its `uint64_t timestamp` (µs).
//!
//! [`ULogWriter`] holds nothing but its output and one scratch buffer:
//! memory is bounded whatever the flight's length. [`px4`] has the topics
//! under PX4's own names and field layouts (the fields this project
//! fills), so a PX4 user's tools read them as they read PX4's logs.

use anyhow::{bail, Context};
use std::io::Write;

/// One field of a topic: its C type as ULog names it and its name.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Field {
    /// ULog type: `uint64_t`, `float`, `uint8_t`, `uint32_t`, `bool`,
    /// optionally an array `float[4]`.
    pub ty: &'static str,
    /// Field name.
    pub name: &'static str,
}

/// A topic's format: name and fields, the first being `uint64_t timestamp`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Format {
    /// Topic (and format) name, e.g. `vehicle_attitude`.
    pub name: &'static str,
    /// Fields in order, packed without padding.
    pub fields: &'static [Field],
}

impl Format {
    /// Bytes of one sample (timestamp included).
    pub fn size(&self) -> usize {
        self.fields.iter().map(|f| field_size(f.ty)).sum()
    }

    /// The format message's text: `name:type field;type field;…`.
    fn text(&self) -> String {
        let mut s = format!("{}:", self.name);
        for f in self.fields {
            s.push_str(&format!("{} {};", f.ty, f.name));
        }
        s
    }
}

/// Size of a ULog type (`float[4]` is 16); 0 for a type this writer does not know.
fn field_size(ty: &str) -> usize {
    let (base, n) = match ty.split_once('[') {
        Some((b, rest)) => (b, rest.trim_end_matches(']').parse::<usize>().unwrap_or(0)),
        None => (ty, 1),
    };
    let one = match base {
        "uint8_t" | "int8_t" | "bool" | "char" => 1,
        "uint16_t" | "int16_t" => 2,
        "uint32_t" | "int32_t" | "float" => 4,
        "uint64_t" | "int64_t" | "double" => 8,
        _ => 0,
    };
    one * n
}

/// A parameter's value: ULog parameters are `int32_t` or `float`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum ParamValue {
    /// A whole-number parameter.
    Int(i32),
    /// A real parameter.
    Float(f32),
}

/// Log levels of logged strings (`L` messages), syslog's as PX4 uses them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Level {
    /// `'3'`: an error.
    Error,
    /// `'4'`: a warning.
    Warning,
    /// `'6'`: information.
    Info,
}

impl Level {
    fn byte(self) -> u8 {
        match self {
            Level::Error => b'3',
            Level::Warning => b'4',
            Level::Info => b'6',
        }
    }
}

/// One sample's fields, appended in the format's order.
#[derive(Debug, Default)]
pub struct Sample {
    buf: Vec<u8>,
}

impl Sample {
    /// A `float`.
    pub fn f32(&mut self, v: f32) -> &mut Self {
        self.buf.extend_from_slice(&v.to_le_bytes());
        self
    }
    /// A `float[N]`.
    pub fn f32s(&mut self, v: &[f32]) -> &mut Self {
        for x in v {
            self.f32(*x);
        }
        self
    }
    /// A `uint32_t`.
    pub fn u32(&mut self, v: u32) -> &mut Self {
        self.buf.extend_from_slice(&v.to_le_bytes());
        self
    }
    /// A `uint8_t`.
    pub fn u8(&mut self, v: u8) -> &mut Self {
        self.buf.push(v);
        self
    }
    /// A `bool`.
    pub fn bool(&mut self, v: bool) -> &mut Self {
        self.buf.push(u8::from(v));
        self
    }
}

/// A ULog file being written. Create it with every topic it will log and
/// the parameters in force at the start; then [`ULogWriter::sample`],
/// [`ULogWriter::log`] and [`ULogWriter::param`] as the flight goes, and
/// [`ULogWriter::finish`].
pub struct ULogWriter<W: Write> {
    w: W,
    formats: Vec<Format>,
    scratch: Sample,
    samples: u64,
}

const MAGIC: [u8; 7] = [0x55, 0x4c, 0x6f, 0x67, 0x01, 0x12, 0x35];

impl<W: Write> ULogWriter<W> {
    /// Writes the header and the definitions: the flag bits, a format per
    /// topic, the `info` pairs (as `char[N]` strings) and the initial
    /// parameters; then subscribes every topic (message id = its index in
    /// `formats`).
    pub fn new(
        mut w: W,
        start_us: u64,
        formats: &[Format],
        info: &[(&str, &str)],
        params: &[(&str, ParamValue)],
    ) -> anyhow::Result<Self> {
        for f in formats {
            if f.fields.first().map(|x| (x.ty, x.name)) != Some(("uint64_t", "timestamp")) {
                bail!("ULog topic {} must begin with uint64_t timestamp", f.name);
            }
            if let Some(bad) = f.fields.iter().find(|x| field_size(x.ty) == 0) {
                bail!(
                    "ULog topic {}: type {} of {} is not a ULog type",
                    f.name,
                    bad.ty,
                    bad.name
                );
            }
        }
        if formats.len() > usize::from(u16::MAX) {
            bail!("ULog: {} topics are more than message ids can number", formats.len());
        }
        w.write_all(&MAGIC)?;
        w.write_all(&[1])?;
        w.write_all(&start_us.to_le_bytes())?;
        let mut this = ULogWriter {
            w,
            formats: formats.to_vec(),
            scratch: Sample::default(),
            samples: 0,
        };
        // Flag bits: no compatible or incompatible flags, nothing appended.
        this.message(b'B', &[0u8; 40])?;
        for f in formats {
            this.message(b'F', f.text().as_bytes())?;
        }
        for (k, v) in info {
            this.key_value(b'I', &format!("char[{}] {k}", v.len()), v.as_bytes())?;
        }
        for (name, v) in params {
            this.write_param(name, *v)?;
        }
        for (id, f) in formats.iter().enumerate() {
            let mut m = vec![0u8];
            m.extend_from_slice(&(id as u16).to_le_bytes());
            m.extend_from_slice(f.name.as_bytes());
            this.message(b'A', &m)?;
        }
        Ok(this)
    }

    fn message(&mut self, kind: u8, payload: &[u8]) -> anyhow::Result<()> {
        let n = u16::try_from(payload.len())
            .map_err(|_| anyhow::anyhow!("ULog message of {} B is over 65 535 B", payload.len()))?;
        self.w.write_all(&n.to_le_bytes())?;
        self.w.write_all(&[kind])?;
        self.w.write_all(payload)?;
        Ok(())
    }

    fn key_value(&mut self, kind: u8, key: &str, value: &[u8]) -> anyhow::Result<()> {
        let k = u8::try_from(key.len()).map_err(|_| anyhow::anyhow!("ULog key {key:?} is over 255 B"))?;
        let mut m = Vec::with_capacity(1 + key.len() + value.len());
        m.push(k);
        m.extend_from_slice(key.as_bytes());
        m.extend_from_slice(value);
        self.message(kind, &m)
    }

    fn write_param(&mut self, name: &str, v: ParamValue) -> anyhow::Result<()> {
        match v {
            ParamValue::Int(i) => self.key_value(b'P', &format!("int32_t {name}"), &i.to_le_bytes()),
            ParamValue::Float(x) => self.key_value(b'P', &format!("float {name}"), &x.to_le_bytes()),
        }
    }

    /// One sample of topic `id` (its index in the formats given to
    /// [`ULogWriter::new`]) at `t_us`: `fill` appends the fields after the
    /// timestamp, in the format's order; a sample whose size is not the
    /// format's is refused.
    pub fn sample(&mut self, id: usize, t_us: u64, fill: impl FnOnce(&mut Sample)) -> anyhow::Result<()> {
        let Some(f) = self.formats.get(id).copied() else {
            bail!("ULog: no topic with id {id}");
        };
        let mut s = std::mem::take(&mut self.scratch);
        s.buf.clear();
        s.buf.extend_from_slice(&(id as u16).to_le_bytes());
        s.buf.extend_from_slice(&t_us.to_le_bytes());
        fill(&mut s);
        let r = if s.buf.len() - 2 != f.size() {
            Err(anyhow::anyhow!(
                "ULog topic {}: a sample of {} B, its format has {} B",
                f.name,
                s.buf.len() - 2,
                f.size()
            ))
        } else {
            self.message(b'D', &s.buf)
        };
        self.scratch = s;
        self.samples += 1;
        r
    }

    /// A logged string (PX4's console messages, MAVLink's STATUSTEXT).
    pub fn log(&mut self, level: Level, t_us: u64, text: &str) -> anyhow::Result<()> {
        let mut m = Vec::with_capacity(9 + text.len());
        m.push(level.byte());
        m.extend_from_slice(&t_us.to_le_bytes());
        m.extend_from_slice(text.as_bytes());
        self.message(b'L', &m)
    }

    /// A parameter changed in flight.
    pub fn param(&mut self, name: &str, v: ParamValue) -> anyhow::Result<()> {
        self.write_param(name, v)
    }

    /// Samples written so far.
    pub fn samples(&self) -> u64 {
        self.samples
    }

    /// Flushes and returns the output.
    pub fn finish(mut self) -> anyhow::Result<W> {
        self.w.flush().context("flushing the ULog")?;
        Ok(self.w)
    }
}

/// PX4's topics, as this project logs them: PX4's names, and of each
/// topic the fields this project fills, with PX4's field names and types.
pub mod px4 {
    use super::{Field, Format};

    const fn f(ty: &'static str, name: &'static str) -> Field {
        Field { ty, name }
    }

    const fn topic(name: &'static str, fields: &'static [Field]) -> Format {
        Format { name, fields }
    }

    const LOCAL_POSITION: &[Field] = &[
        f("uint64_t", "timestamp"),
        f("float", "x"),
        f("float", "y"),
        f("float", "z"),
        f("float", "vx"),
        f("float", "vy"),
        f("float", "vz"),
        f("float", "heading"),
        f("bool", "xy_valid"),
        f("bool", "z_valid"),
        f("bool", "v_xy_valid"),
        f("bool", "v_z_valid"),
    ];
    const ATTITUDE: &[Field] = &[f("uint64_t", "timestamp"), f("float[4]", "q")];

    /// The position estimate the controller flies on: NED m about home,
    /// m/s, heading rad.
    pub const VEHICLE_LOCAL_POSITION: Format = topic("vehicle_local_position", LOCAL_POSITION);
    /// The attitude estimate: unit quaternion body FRD → NED, scalar first.
    pub const VEHICLE_ATTITUDE: Format = topic("vehicle_attitude", ATTITUDE);
    /// The simulator's true position (PX4's SITL ground-truth topic).
    pub const VEHICLE_LOCAL_POSITION_GROUNDTRUTH: Format = topic("vehicle_local_position_groundtruth", LOCAL_POSITION);
    /// The simulator's true attitude.
    pub const VEHICLE_ATTITUDE_GROUNDTRUTH: Format = topic("vehicle_attitude_groundtruth", ATTITUDE);
    /// The set-point: NED m, m/s, m/s², yaw rad, yaw rate rad/s.
    pub const VEHICLE_LOCAL_POSITION_SETPOINT: Format = Format {
        name: "vehicle_local_position_setpoint",
        fields: &[
            f("uint64_t", "timestamp"),
            f("float", "x"),
            f("float", "y"),
            f("float", "z"),
            f("float", "vx"),
            f("float", "vy"),
            f("float", "vz"),
            f("float[3]", "acceleration"),
            f("float", "yaw"),
            f("float", "yawspeed"),
        ],
    };
    /// Motor outputs: `output[0..noutputs]`, each the rotor speed as a
    /// fraction of its largest (what HIL_ACTUATOR_CONTROLS carries).
    pub const ACTUATOR_OUTPUTS: Format = Format {
        name: "actuator_outputs",
        fields: &[
            f("uint64_t", "timestamp"),
            f("uint32_t", "noutputs"),
            f("float[16]", "output"),
        ],
    };
    /// The estimator's state and covariance diagonal: `states` =
    /// quaternion (4), velocity NED (3), position NED (3), gyro bias (3,
    /// rad/s), accelerometer bias (3, m/s²), as PX4's EKF2 orders them;
    /// `covariances` = the error state's variances in the same order
    /// (attitude error as 3 angles, so index 0..3 are the attitude's).
    pub const ESTIMATOR_STATES: Format = Format {
        name: "estimator_states",
        fields: &[
            f("uint64_t", "timestamp"),
            f("float[24]", "states"),
            f("uint8_t", "n_states"),
            f("float[24]", "covariances"),
        ],
    };
    /// Arming and navigation state: `arming_state` 1 standby, 2 armed
    /// (PX4's values); `failsafe` when the vehicle flies its failsafe.
    pub const VEHICLE_STATUS: Format = Format {
        name: "vehicle_status",
        fields: &[
            f("uint64_t", "timestamp"),
            f("uint8_t", "arming_state"),
            f("uint8_t", "nav_state"),
            f("bool", "failsafe"),
        ],
    };
    /// PX4's `arming_state` for standby (disarmed, ready).
    pub const ARMING_STATE_STANDBY: u8 = 1;
    /// PX4's `arming_state` for armed.
    pub const ARMING_STATE_ARMED: u8 = 2;
    /// PX4's `nav_state` for position control.
    pub const NAV_STATE_POSCTL: u8 = 2;
    /// PX4's `nav_state` for offboard (set-points from outside).
    pub const NAV_STATE_OFFBOARD: u8 = 14;
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The bytes of a small log, against the specification's layout.
    #[test]
    fn header_definitions_and_data_are_laid_out_as_the_spec_says() {
        let fmt = Format {
            name: "t",
            fields: &[
                Field {
                    ty: "uint64_t",
                    name: "timestamp",
                },
                Field { ty: "float", name: "x" },
            ],
        };
        let mut w = ULogWriter::new(
            Vec::new(),
            7,
            &[fmt],
            &[("sys_name", "ab")],
            &[("P1", ParamValue::Int(3))],
        )
        .unwrap();
        w.sample(0, 9, |s| {
            s.f32(1.5);
        })
        .unwrap();
        w.log(Level::Info, 9, "hi").unwrap();
        let b = w.finish().unwrap();
        assert_eq!(&b[..7], &MAGIC);
        assert_eq!(b[7], 1);
        assert_eq!(u64::from_le_bytes(b[8..16].try_into().unwrap()), 7);
        // Flag bits: size 40, type 'B'.
        assert_eq!(&b[16..19], &[40, 0, b'B']);
        let mut i = 19 + 40;
        let mut next = |b: &[u8]| {
            let n = usize::from(u16::from_le_bytes([b[i], b[i + 1]]));
            let m = (b[i + 2], b[i + 3..i + 3 + n].to_vec());
            i += 3 + n;
            m
        };
        assert_eq!(next(&b), (b'F', b"t:uint64_t timestamp;float x;".to_vec()));
        let (k, m) = next(&b);
        assert_eq!((k, &m[1..], m[0]), (b'I', &b"char[2] sys_nameab"[..], 16));
        let (k, m) = next(&b);
        assert_eq!((k, m[0]), (b'P', 10));
        assert_eq!(&m[1..11], b"int32_t P1");
        assert_eq!(i32::from_le_bytes(m[11..15].try_into().unwrap()), 3);
        assert_eq!(next(&b), (b'A', vec![0, 0, 0, b't']));
        let (k, m) = next(&b);
        assert_eq!(k, b'D');
        assert_eq!(&m[..2], &[0, 0]);
        assert_eq!(u64::from_le_bytes(m[2..10].try_into().unwrap()), 9);
        assert_eq!(f32::from_le_bytes(m[10..14].try_into().unwrap()), 1.5);
        let (k, m) = next(&b);
        assert_eq!((k, m[0]), (b'L', b'6'));
        assert_eq!(&m[9..], b"hi");
        assert_eq!(i, b.len());
    }

    #[test]
    fn a_sample_of_the_wrong_size_and_a_bad_format_are_refused() {
        let fmt = px4::VEHICLE_ATTITUDE;
        let mut w = ULogWriter::new(Vec::new(), 0, &[fmt], &[], &[]).unwrap();
        let e = w.sample(0, 1, |s| {
            s.f32s(&[1.0, 0.0, 0.0]);
        });
        assert!(e
            .unwrap_err()
            .to_string()
            .contains("vehicle_attitude: a sample of 20 B, its format has 24 B"));
        assert!(w.sample(1, 1, |_| {}).is_err());
        let bad = Format {
            name: "x",
            fields: &[Field { ty: "float", name: "x" }],
        };
        assert!(ULogWriter::new(Vec::new(), 0, &[bad], &[], &[]).is_err());
        let bad = Format {
            name: "x",
            fields: &[
                Field {
                    ty: "uint64_t",
                    name: "timestamp",
                },
                Field { ty: "quad", name: "y" },
            ],
        };
        assert!(ULogWriter::new(Vec::new(), 0, &[bad], &[], &[]).is_err());
    }

    #[test]
    fn px4_topic_sizes() {
        assert_eq!(px4::VEHICLE_LOCAL_POSITION.size(), 8 + 7 * 4 + 4);
        assert_eq!(px4::VEHICLE_ATTITUDE.size(), 24);
        assert_eq!(px4::ACTUATOR_OUTPUTS.size(), 8 + 4 + 64);
        assert_eq!(px4::ESTIMATOR_STATES.size(), 8 + 96 + 1 + 96);
    }
}
