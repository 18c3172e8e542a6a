//! `ESTIMATOR_STATUS` (230), 2 Hz: what the estimator gives, its accuracy
//! and its fixes' innovation test ratios, as PX4's.

use super::Stream;
use crate::vehicle::{EstimatorStatusFlags, MavMessage, MavShared, NavMode, ESTIMATOR_STATUS_DATA};

/// The stream.
pub(super) const STREAM: Stream = Stream {
    id: 230,
    name: "ESTIMATOR_STATUS",
    interval_us: 500_000,
    build: MavShared::estimator_status,
};

impl MavShared {
    fn estimator_status(&self, t_us: u64) -> Option<MavMessage> {
        Some(MavMessage::ESTIMATOR_STATUS(self.estimator_status_data(t_us)))
    }

    /// `ESTIMATOR_STATUS`: what the estimator gives (attitude, velocity,
    /// position about the origin and, about the simulator's origin, a
    /// global one) while it navigates; its 1σ position accuracy; the latest
    /// fixes' innovation test ratios as PX4 gives them (the vertical one
    /// the larger of the position's and the barometer's, the heading's as
    /// `mag_ratio`; no height-above-ground or airspeed source: 0).
    fn estimator_status_data(&self, t_us: u64) -> ESTIMATOR_STATUS_DATA {
        use EstimatorStatusFlags as F;
        let nav = self.lp.navigator();
        let sig = nav.estimator().sigmas();
        let navigating = nav.mode() == NavMode::Navigating;
        let mut flags = F::empty();
        if navigating {
            flags = F::ESTIMATOR_ATTITUDE
                | F::ESTIMATOR_VELOCITY_HORIZ
                | F::ESTIMATOR_VELOCITY_VERT
                | F::ESTIMATOR_POS_HORIZ_REL
                | F::ESTIMATOR_POS_VERT_ABS
                | F::ESTIMATOR_PRED_POS_HORIZ_REL;
            if self.home.is_some() {
                flags |= F::ESTIMATOR_POS_HORIZ_ABS | F::ESTIMATOR_PRED_POS_HORIZ_ABS;
            }
        }
        // PX4 sends the square roots of the estimator's ratios.
        let r = nav.estimator().test_ratios();
        ESTIMATOR_STATUS_DATA {
            time_usec: t_us,
            vel_ratio: libm::sqrtf(r.vel),
            pos_horiz_ratio: libm::sqrtf(r.pos_horiz),
            pos_vert_ratio: libm::sqrtf(r.pos_vert.max(r.alt)),
            mag_ratio: libm::sqrtf(r.yaw),
            hagl_ratio: 0.0,
            tas_ratio: 0.0,
            pos_horiz_accuracy: sig[0].max(sig[1]),
            pos_vert_accuracy: sig[2],
            flags,
        }
    }
}
