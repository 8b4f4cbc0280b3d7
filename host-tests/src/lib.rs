//! nanocal host library: recordings, fitting, validation, the digital twin, explain, device client.
#![warn(missing_docs)]
pub use nanocal_model as model;

pub mod campaign;
pub mod cli;
pub mod design;
pub mod device;
pub mod device_path;
pub mod dwell;
pub mod effects;
pub mod error_table;
pub mod explain;
pub mod fit;
pub mod gcsarray;
pub mod html_report;
pub mod iso9283;
pub mod kmz;
pub mod linalg;
pub mod memory;
pub mod plan;
pub mod plot;
pub mod procedure;
pub mod provenance;
#[cfg(feature = "test-support")]
pub mod proxy_fuzz;
pub mod published;
pub mod recording;
pub mod report;
pub mod stats;
pub mod stepwise;
pub mod twin;
pub mod uncertainty;
pub mod validate;
pub mod virtual_bench;
