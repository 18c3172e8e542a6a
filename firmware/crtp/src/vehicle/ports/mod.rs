//! One file per CRTP port: each decodes its packets into the vehicle's
//! commands and encodes its answers.

pub(super) mod generic;
pub(super) mod high_level;
pub(super) mod link;
pub(super) mod localization;
pub(super) mod logging;
pub(super) mod mem;
pub(super) mod param;
pub(super) mod supervisor;
