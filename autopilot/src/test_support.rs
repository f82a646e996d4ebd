//! Inputs the unit tests of several stages share.

use protocol::{
    CaptureCounts, Estimate, EstimateFlags, FrameFit, LinkErrorCounts, StereoStatus, WireTime,
};

/// A valid estimate of `forward_mps` straight ahead, nothing in range over a view with depth
/// everywhere.
pub fn forward_estimate(forward_mps: f32) -> Estimate {
    estimate([forward_mps, 0.0], None)
}

/// A valid estimate of the body velocity `velocity_mps` (forward, sideways) with the nearest
/// obstacle at `obstacle_m`, over a view with depth everywhere; the frame's own fit agrees.
pub fn estimate(velocity_mps: [f32; 2], obstacle_m: Option<f32>) -> Estimate {
    Estimate {
        seq: 0,
        capture_us: WireTime(0),
        forward_mps: velocity_mps[0],
        sideways_mps: velocity_mps[1],
        obstacle_m,
        quality: 200,
        flags: EstimateFlags::NONE,
        processing_us: 0,
        depth_coverage: 255,
        near_columns: 0,
        fit: Some(FrameFit {
            forward_mps: velocity_mps[0],
            sideways_mps: velocity_mps[1],
            quality: 200,
        }),
        up_mps: 0.0,
        up_flags: EstimateFlags::NO_FLOW_MATCH,
        fit_r2: 0,
        divergence: None,
    }
}

/// A camera board's status report, its camera running or stopped.
pub fn camera_status(camera_stopped: bool) -> StereoStatus {
    StereoStatus {
        uptime_ms: 3_000,
        frame_rate_hz: 0.0,
        frames_processed: 50,
        frames_dropped: 0,
        link_errors: LinkErrorCounts::default(),
        max_processing_us: 0,
        capture: CaptureCounts::default(),
        camera_stopped,
    }
}

/// The board-clock instant `us` microseconds after boot.
pub fn at(us: u64) -> timebase::Instant {
    timebase::Instant::from_micros(us)
}
