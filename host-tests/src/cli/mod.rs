//! Command-line subcommands: one file each, a thin layer over the library.
pub mod campaign;
pub mod demo;
pub mod device;
pub mod explain;
pub mod export;
pub mod fit;
pub mod import;
pub mod memory;
pub mod report;
pub mod simulate;
pub mod stepwise;
pub mod trust;
pub mod validate;
