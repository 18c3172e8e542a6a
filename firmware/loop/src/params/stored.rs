//! The settings a board boots with: its defaults, with the values a store
//! kept (a parameter by its index in [`PARAMS`]), each taken through the
//! same check as a ground station's write. The store is anything that reads
//! a value by index (`fc-storage`'s `Persist::param`); this module knows no
//! flash.

use super::{write, Settings, PARAMS};

/// What [`load`] did.
#[derive(Debug, Clone, Copy)]
pub struct Loaded {
    /// The settings to boot with: `base` with every stored value that
    /// passed its parameter's checks.
    pub settings: Settings,
    /// Stored values taken.
    pub taken: u16,
    /// Stored values refused (out of range now, or the settings as a whole
    /// refuse them): left out, their defaults kept; the first refused index.
    pub refused: (u16, Option<u16>),
}

/// `base` with the parameter values `stored` returns (`stored(i)`: the value
/// kept for [`PARAMS`]`[i]`, `None` if none is), each through the same check
/// as a write from a ground station (a stored value the settings refuse is
/// left out and counted). Err only if the store cannot be read: its own
/// error, the first one.
pub fn load<E>(base: Settings, mut stored: impl FnMut(u16) -> Result<Option<f32>, E>) -> Result<Loaded, E> {
    let mut out = Loaded {
        settings: base,
        taken: 0,
        refused: (0, None),
    };
    for i in 0..PARAMS.len() {
        let Some(v) = stored(i as u16)? else {
            continue;
        };
        match write(&out.settings, i, v) {
            Ok(next) => {
                out.settings = next;
                out.taken += 1;
            }
            Err(_) => {
                out.refused.0 += 1;
                out.refused.1 = out.refused.1.or(Some(i as u16));
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::super::index_of;
    use super::*;

    /// A stored gain is taken, a stored controller id no controller has is
    /// refused as a write would be (its default kept), and a store that
    /// cannot be read says so.
    #[test]
    fn stored_values_load_through_their_checks() {
        let gain = index_of(b"PD_ROLL_P").unwrap();
        let id = index_of(b"CTL_ID").unwrap();
        let base = Settings::os4();
        let v = (PARAMS[gain].get)(&base) * 2.0;
        let l = load(base, |i| {
            Ok::<_, ()>(match i as usize {
                i if i == gain => Some(v),
                i if i == id => Some(99.0),
                _ => None,
            })
        })
        .unwrap();
        assert_eq!((l.taken, l.refused), (1, (1, Some(id as u16))));
        assert_eq!((PARAMS[gain].get)(&l.settings), v);
        assert_eq!((PARAMS[id].get)(&l.settings), (PARAMS[id].get)(&base));
        assert_eq!(
            load(base, |i| if i == 2 { Err("flash") } else { Ok(None) }).err(),
            Some("flash")
        );
    }
}
