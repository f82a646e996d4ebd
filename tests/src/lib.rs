//! Shared helpers for the cross-crate integration tests in `tests/tests/`.

use std::path::PathBuf;

/// Path of the shared recorded data set used by tests and CI (`../shared/data/stereoboard_testing`
/// beside the checkout). The product itself never assumes this path.
pub fn shared_dataset_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/data/stereoboard_testing")
}
