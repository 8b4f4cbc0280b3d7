//! Logging macros: defmt on boards that have it (STM32 over RTT), nothing on QEMU.
#![allow(unused_macros)]

#[cfg(feature = "defmt")]
macro_rules! info {
    ($($t:tt)*) => { ::defmt::info!($($t)*) };
}
#[cfg(feature = "defmt")]
macro_rules! warn {
    ($($t:tt)*) => { ::defmt::warn!($($t)*) };
}

#[cfg(not(feature = "defmt"))]
macro_rules! info {
    ($s:literal $(, $x:expr)* $(,)?) => {{ let _ = ($( & $x ),*); }};
}
#[cfg(not(feature = "defmt"))]
macro_rules! warn {
    ($s:literal $(, $x:expr)* $(,)?) => {{ let _ = ($( & $x ),*); }};
}
