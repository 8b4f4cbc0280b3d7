//! Command-line subcommands: one file each, a thin layer over the library.
pub mod device;
pub mod simulate;
pub mod stepwise;
