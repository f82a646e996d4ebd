//! The camera board's parameter table: the Edge-FS settings of [`EdgeFsParams`] by name,
//! kind, unit and bounds ([`CAMERA`]), served through the same
//! [`protocol::params::ParamTable`] as the autopilot's.
//!
//! The board runs the default mode ([`EdgeFsParams::default_config`], the table's defaults);
//! the mode itself is not a parameter. `stereo_shift` is the pair's calibration, signed, in
//! the protocol's convention ([`protocol::EdgeFsConfig::stereo_shift`]). The bounds lie inside
//! what [`crate::edge_fs::EdgeFs::new`] accepts unchanged, so a value that is set is the value
//! that runs; within them at least 44 of the 128 columns stay measurable
//! (`128 - 2·half_window - max(search_range, stereo_range) - |stereo_shift|`). A change takes
//! effect from the next frame on and clears the flow history. The firmware keeps the table in
//! its flash parameter sector ([`RECORD_BYTES`] of record: magic, format version, table hash,
//! the values, CRC-32) and boots on it; a blank, corrupt, older or other-table record means the
//! defaults, reported ([`crate::app::StereoBoardApp::load_params`]).

use crate::edge_fs::{EdgeFsParams, MAX_VERTICAL_SEARCH};
use protocol::params::ParamTable;
use protocol::{EdgeFsConfig, ParamEntry, ParamValue};

const MAX_SHIFT: i32 = EdgeFsConfig::MAX_STEREO_SHIFT as i32;

protocol::param_table! {
    /// The camera board's parameters, in the order they are listed and stored.
    pub TABLE, ACCESS: EdgeFsParams {
        "half_window": U32 ["px"] 1, EdgeFsConfig::MAX_HALF_WINDOW as u32, true => |p| p.half_window;
        "search_range": U32 ["px"] 1, EdgeFsConfig::MAX_SEARCH_RANGE as u32, true => |p| p.search_range;
        "max_horizon": U32 ["frames"] 1, EdgeFsConfig::MAX_HORIZON as u32, true => |p| p.max_horizon;
        "stereo_shift": I32 ["px"] -MAX_SHIFT, MAX_SHIFT, true => |p| p.stereo_shift_px;
        "stereo_range": U32 ["px"] 1, 2 * EdgeFsConfig::MAX_SEARCH_RANGE as u32, true => |p| p.stereo_range;
        "fov_x": F32 ["rad"] 0.5, 2.0, true => |p| p.fov_x_rad;
        "baseline": F32 ["m"] 0.01, 0.5, true => |p| p.baseline_m;
        "horizon_s": F32 ["s"] 0.0, 2.0, true => |p| p.horizon_s;
        "min_disparity": F32 ["px"] 0.1, 40.0, true => |p| p.min_disparity_px;
        "min_stereo_conf": F32 ["-"] 0.0, 10.0, true => |p| p.min_stereo_confidence;
        "min_flow_conf": F32 ["-"] 0.0, 10.0, true => |p| p.min_flow_confidence;
        "min_texture": U32 ["-"] 0, 1_000_000, true => |p| p.min_texture;
        "huber_k": F32 ["-"] 0.0, 10.0, true => |p| p.huber_k;
        "depth_weight_exp": F32 ["-"] 0.0, 4.0, true => |p| p.depth_weight_exp;
        "max_fit_rms": F32 ["m/s"] 0.01, 10.0, true => |p| p.max_fit_rms_mps;
        "min_fit_columns": U32 ["-"] 2, 64, true => |p| p.min_fit_columns;
        "output_median": U32 ["-"] 1, 5, true => |p| p.output_median;
        "max_obstacle": F32 ["m"] 0.1, 20.0, true => |p| p.max_obstacle_m;
        "filter_accel": F32 ["m/s2"] 0.0, 10.0, true => |p| p.filter_accel_mps2;
        "filter_gate": F32 ["-"] 0.0, 10.0, true => |p| p.filter_gate;
        "filter_noise_floor": F32 ["m/s"] 0.0, 2.0, true => |p| p.filter_noise_floor_mps;
        "filter_noise_scale": F32 ["-"] 0.0, 100.0, true => |p| p.filter_noise_scale;
        "filter_accel_tau": F32 ["s"] 0.0, 5.0, true => |p| p.filter_accel_tau_s;
        "max_rotation": F32 ["px"] 0.0, 40.0, true => |p| p.max_rotation_px;
        "gyro_age": F32 ["s"] 0.0, 0.5, true => |p| p.gyro_age_s;
        "max_derot_error": F32 ["px"] 0.0, 10.0, true => |p| p.max_derotation_error_px;
        "min_depth_coverage": F32 ["-"] 0.0, 1.0, true => |p| p.min_depth_coverage;
        "min_fit_spread": F32 ["px"] 0.0, 128.0, true => |p| p.min_fit_spread_px;
        "min_near_run": U32 ["px"] 0, 128, true => |p| p.min_near_run;
        "vertical_search": U32 ["px"] 0, MAX_VERTICAL_SEARCH as u32, true => |p| p.vertical_search_px;
        "lr_check": Bool ["-"] false, true, true => |p| p.lr_check;
    }
}

/// The camera board's table with its accessors and defaults (every combination within the
/// bounds is consistent).
pub const CAMERA: ParamTable<EdgeFsParams> = ParamTable {
    specs: TABLE,
    access: ACCESS,
    defaults: EdgeFsParams::default_config,
    consistent: |_| Ok(()),
};

/// Number of parameters.
pub const COUNT: usize = TABLE.len();

/// Version of [`TABLE`] for flash records: see [`protocol::params::table_hash`].
pub const TABLE_HASH: u32 = CAMERA.hash();

/// Bytes of the camera board's flash record.
pub const RECORD_BYTES: usize = protocol::params::record_bytes(COUNT);

// A save encodes into a buffer of `MAX_RECORD_BYTES`.
const _: () = assert!(COUNT <= protocol::params::MAX_PARAMS);

/// Writes `p`'s values as a flash record ([`protocol::params::encode_record`]) into `out`;
/// returns its length, [`RECORD_BYTES`].
pub fn encode_record(
    p: &EdgeFsParams,
    out: &mut [u8],
) -> Result<usize, protocol::params::RecordError> {
    CAMERA.encode_record(p, out)
}

/// Index of the parameter called `name`.
pub fn index_of(name: &str) -> Option<usize> {
    CAMERA.index_of(name)
}

/// The value of parameter `index` in `p`.
pub fn get(p: &EdgeFsParams, index: usize) -> Option<ParamValue> {
    CAMERA.get(p, index)
}

/// Parameter `index` of `p` as it goes on the wire.
pub fn entry(p: &EdgeFsParams, index: usize) -> Option<ParamEntry> {
    CAMERA.entry(p, index)
}

#[cfg(test)]
mod tests {
    extern crate std;
    use super::*;
    use crate::edge_fs::EdgeFs;
    use protocol::ParamError;
    use std::boxed::Box;

    #[test]
    fn the_table_is_well_formed_and_the_defaults_are_valid() {
        let d = EdgeFsParams::default_config();
        CAMERA.validate(&d).unwrap();
        assert_eq!(TABLE.len(), ACCESS.len());
        for (i, spec) in TABLE.iter().enumerate() {
            assert!(spec.name.len() <= protocol::params::PARAM_NAME_LEN);
            assert!(spec.unit.len() <= protocol::params::PARAM_UNIT_LEN);
            assert_eq!(index_of(spec.name), Some(i), "{} twice", spec.name);
            assert_eq!(get(&d, i).unwrap().kind(), spec.kind, "{}", spec.name);
        }
    }

    #[test]
    fn every_parameter_reaches_its_field_and_runs_unclamped() {
        let d = EdgeFsParams::default_config();
        for (i, spec) in TABLE.iter().enumerate() {
            for v in [spec.min, spec.max] {
                let mut p = d;
                CAMERA.set(&mut p, i, v).unwrap();
                assert_eq!(get(&p, i), Some(v), "{}", spec.name);
                for j in (0..COUNT).filter(|&j| j != i) {
                    assert_eq!(
                        get(&p, j),
                        get(&d, j),
                        "{} changed {}",
                        spec.name,
                        TABLE[j].name
                    );
                }
                // Edge-FS takes the value as it is (no clamping inside the bounds).
                let ef = Box::new(EdgeFs::new(p));
                assert_eq!(get(ef.params(), i), Some(v), "{} clamped", spec.name);
            }
        }
    }

    #[test]
    fn a_signed_shift_is_set_and_out_of_bounds_values_are_refused() {
        let mut p = EdgeFsParams::default_config();
        CAMERA
            .set_by_name(&mut p, "stereo_shift", ParamValue::I32(-7))
            .unwrap();
        assert_eq!(p.stereo_shift_px, -7);
        assert_eq!(p.to_config().stereo_shift, -7);
        let r = CAMERA
            .set_by_name(&mut p, "stereo_shift", ParamValue::I32(21))
            .unwrap_err();
        assert_eq!(
            (r.name(), r.error),
            ("stereo_shift", ParamError::OutOfBounds)
        );
        let r = CAMERA
            .set_by_name(&mut p, "stereo_shift", ParamValue::U32(3))
            .unwrap_err();
        assert_eq!(r.error, ParamError::WrongKind);
        let r = CAMERA
            .set_by_name(&mut p, "half_window", ParamValue::U32(13))
            .unwrap_err();
        assert_eq!(r.error, ParamError::OutOfBounds);
        assert_eq!(p.stereo_shift_px, -7);
    }
}
