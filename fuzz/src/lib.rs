//! The fuzz targets' checks, one function per decoder of outside input (`checks`), shared by the
//! cargo-fuzz targets in `fuzz_targets/` and by the normal test suite, which replays every
//! committed seed (`host-tests/tests/fuzz_seeds.rs`).

#[path = "../../host-tests/tests/proxy_rig/mod.rs"]
pub mod proxy_rig;

pub mod checks;
